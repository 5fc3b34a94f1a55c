//! `svbrdf fit`: argument parsing and the OpenCV frame source.

use std::path::{Path, PathBuf};

use anyhow::Result;
use clap::Args;
use svbrdf_core::brdf::ModelKind;
use svbrdf_core::capture::RegisteredCapture;
use svbrdf_core::image::FrameImage;
use svbrdf_fit::{FitConfig, FitError, FrameSource};

#[derive(Args, Clone)]
#[command(allow_negative_numbers = true)]
pub struct FitArgs {
    /// Registered capture: a folder holding capture.json (from `svbrdf align`, the
    /// simulator's `registered/`, or any tool writing the documented format).
    #[arg(long)]
    pub capture: PathBuf,
    /// Output folder for the maps (must not exist unless --overwrite).
    #[arg(long)]
    pub out: PathBuf,
    #[command(flatten)]
    pub options: FitOptions,
    /// Replace the output folder if it exists.
    #[arg(long)]
    pub overwrite: bool,
}

/// How to fit: the settings `fit` and `eval` share.
#[derive(Args, Clone)]
pub struct FitOptions {
    /// Settings file (JSON; any subset of the fields of `svbrdf_fit::FitConfig`, e.g.
    /// `{"min_cluster_px": 100, "refine_prior": 4}`); the flags below override it.
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Reflectance model: `ward` (the paper's) or `ggx` (with Fresnel).
    #[arg(long, default_value = "ward")]
    pub model: String,
    /// Output resolution, pixels per cm (default: the capture's).
    #[arg(long)]
    pub px_per_cm: Option<f64>,
    /// Flash intensity in linear value * cm^2, one number or R,G,B (default: the
    /// capture's, else albedos are normalised: see docs/CONVENTIONS.md).
    #[arg(long, value_delimiter = ',')]
    pub light_intensity: Option<Vec<f64>>,
    /// Skip the per-pixel refinement (maps constant within each cluster, as the paper).
    #[arg(long)]
    pub no_refine: bool,
    /// Read every observation as lit by the flash alone (the paper's model) instead of
    /// estimating the room's light and fitting it with every observation.
    #[arg(long)]
    pub no_room_light: bool,
    /// Seed of the clustering's random choices.
    #[arg(long)]
    pub seed: Option<u64>,
    /// Choose the settings (specular lobe or none, cluster splitting, refinement
    /// prior, per-pixel specular) by how well each predicts frames held out in this
    /// many folds (default 3; 0 fits with the settings as given).
    #[arg(long, value_name = "K")]
    pub select_folds: Option<usize>,
}

pub fn fit_config(a: &FitOptions) -> Result<FitConfig> {
    let mut c: FitConfig = match &a.config {
        Some(p) => svbrdf_core::fsutil::read_json_settings(p)?,
        None => FitConfig::default(),
    };
    c.model = match a.model.as_str() {
        "ward" => ModelKind::Ward,
        "ggx" => ModelKind::Ggx,
        m => anyhow::bail!("invalid model {m:?} (expected ward or ggx)"),
    };
    if a.px_per_cm.is_some() {
        c.px_per_cm = a.px_per_cm;
    }
    if a.no_refine {
        c.refine = false;
    }
    if a.no_room_light {
        c.room_light = svbrdf_fit::RoomLightMode::Off;
    }
    if let Some(i) = &a.light_intensity {
        c.light_intensity = Some(match i.as_slice() {
            [v] => [*v; 3],
            [r, g, b] => [*r, *g, *b],
            _ => {
                anyhow::bail!("invalid light intensity {i:?} (expected one number or three: R,G,B)")
            }
        });
    }
    if let Some(s) = a.seed {
        c.seed = s;
    }
    if let Some(k) = a.select_folds {
        c.select_folds = k;
    }
    c.validate()?;
    Ok(c)
}

/// Frames through OpenCV's decoder.
pub struct CvFrames;

impl FrameSource for CvFrames {
    fn decode(
        &self,
        capture: &RegisteredCapture,
        dir: &Path,
        sink: &mut dyn FnMut(usize, FrameImage) -> Result<(), FitError>,
    ) -> Result<(), FitError> {
        svbrdf_cv::capture::decode_frames::<anyhow::Error>(capture, dir, &mut |k, img| {
            sink(k, img).map_err(anyhow::Error::from)
        })
        .map_err(|e| match e.downcast::<FitError>() {
            Ok(f) => f,
            Err(e) => FitError::Source(format!("{e:#}")),
        })
    }
}

pub fn run_fit(a: &FitArgs) -> Result<svbrdf_fit::FitRun> {
    let cfg = fit_config(&a.options)?;
    if let Some(c) = &a.options.config {
        svbrdf_core::fsutil::check_output_spares_inputs(&a.out, std::slice::from_ref(c))?;
    }
    svbrdf_cv::set_single_threaded()?;
    crate::alloc::retain_freed_pages(false);
    let progress = crate::progress::Bars::new();
    let run = svbrdf_fit::run(&a.capture, &a.out, a.overwrite, &cfg, &CvFrames, &progress)?;
    let s = &run.manifest.summary;
    say!("wrote {}", run.out.display());
    say!(
        "observations: {} ({} with a clipped channel{}); {} of {} pixels observed at least {} times",
        s.observations,
        s.clipped_observations,
        s.clipped_near_mirror
            .map(|c| format!(
                "; {:.0}% clipped within {} degrees of the mirror direction",
                100.0 * c,
                svbrdf_fit::NEAR_MIRROR_DEG
            ))
            .unwrap_or_default(),
        s.covered_pixels,
        s.pixels,
        cfg.min_observations
    );
    if let Some(sel) = &s.selection {
        say!("settings: {} ({})", sel.chosen, sel.reason);
        if !sel.candidates.is_empty() {
            say!(
                "  held-out RMS error (sRGB values) per candidate, {} folds: {}",
                sel.folds,
                sel.candidates
                    .iter()
                    .map(|c| {
                        let dropped = c
                            .dropped_after
                            .map_or(String::new(), |n| format!(" (left out after fold {n})"));
                        format!("{} {:.4}{dropped}", c.name, c.held_out_srgb_rmse)
                    })
                    .collect::<Vec<_>>()
                    .join(", ")
            );
        }
    }
    say!(
        "clusters: {} initial (k-means elbow), {} final, deepest split level {}; {} stopped at the iteration cap; {} pixels moved to a neighbouring cluster that fits them better",
        s.initial_clusters,
        s.final_clusters,
        s.max_depth,
        s.unconverged_clusters.len(),
        s.reassigned_pixels
    );
    if s.lobe_refits > 0 {
        say!(
            "lobe refits with the refined normals: {}; {} of {} clusters took the refitted lobe",
            s.lobe_refits,
            s.refitted_clusters,
            s.final_clusters
        );
    }
    if s.pixel_lobes > 0 {
        say!(
            "specular lobes of their own (their observations measure the highlight's peak or its flank): {} of {} observed pixels; the others carry their cluster's (fit.json: pixel_lobes)",
            s.pixel_lobes,
            s.covered_pixels
        );
    }
    if s.neighbour_lobes > 0 {
        say!(
            "of those, {} in anisotropic clusters took their lobe from their neighbours' (fit.json: neighbour_lobes)",
            s.neighbour_lobes
        );
    }
    if let Some(g) = &s.turned_grain {
        say!(
            "anisotropy turned from the markers' axes on {:.0}% of the surface (median {:.0} degrees from +x towards +y; maps/roughness.exr B)",
            100.0 * g.share,
            g.median_deg
        );
    }
    say!(
        "light intensity {:.1} ({:?}); model {}",
        s.light_intensity[1],
        s.light_intensity_source,
        s.model
    );
    if let Some(r) = s.room_light.filter(|r| r.applied) {
        say!(
            "room light: {:.0}% of the flash's diffuse light on the surface (fitted with every observation and kept out of the maps; --no-room-light to read all light as the flash's)",
            100.0 * r.share_of_flash
        );
    }
    let worst = s.frames.iter().map(|f| f.relative).fold(0.0f64, f64::max);
    say!(
        "re-rendering error (linear RMS): clusters only {:.4}, final {:.4}; worst frame {:.1}% of its mean",
        s.rmse_clusters,
        s.rmse_final,
        100.0 * worst
    );
    if let Some(c) = &s.confidence {
        say!(
            "confidence (maps/confidence.png): {} Final clusters whose highlight peak no pixel saw: {} of {} (clusters.json: specular_seen).",
            c.sentence(),
            s.clusters_without_peak,
            s.final_clusters
        );
    }
    if s.lobes_from_parent > 0 {
        say!(
            "{} of {} final clusters kept their parent's lobe: no frame saw the highlight of the lobe their own observations gave, so it is not invented (clusters.json: lobe_from_parent).",
            s.lobes_from_parent,
            s.final_clusters
        );
    }
    crate::print_timings(&s.timings);
    crate::print_warnings(&s.warnings);
    Ok(run)
}
