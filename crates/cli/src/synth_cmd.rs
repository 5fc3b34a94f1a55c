//! `svbrdf synth` and `svbrdf demo`: the simulator's settings from the command line,
//! and the demo that runs the whole pipeline on a capture it synthesizes.

use std::path::PathBuf;

use anyhow::{Context, Result};
use clap::Args;
use svbrdf_synth::{synthesize, MaterialSource, SynthConfig};

use crate::{print_timings, progress, run_cmd};

#[derive(Args)]
#[command(allow_negative_numbers = true)]
pub struct SynthArgs {
    /// Output folder (must not exist unless --overwrite).
    #[arg(long)]
    out: PathBuf,
    /// Preset: `tiny` (270x480, 3 s, 8x8 cm; seconds to render), `paper` (2160x3840
    /// at 30 fps, 20 s, 20x20 cm, 100 px/cm maps; the paper's setting), `hard` (4K,
    /// 10 s: bathroom tiles, markers rarely in view, a tilted no-flash reference, room
    /// light), `hard-small` (`hard` at 540x960, 4 s) or `two-camera` (`tiny` with a
    /// second, no-flash camera).
    #[arg(long, default_value = "tiny")]
    preset: String,
    /// Random seed; the output is deterministic for a seed.
    #[arg(long)]
    seed: Option<u64>,
    /// Built-in material: patchwork, leather, brushed-metal, tiles, bathroom-tiles or
    /// facets (default: the preset's).
    #[arg(long, conflicts_with = "maps")]
    material: Option<String>,
    /// Folder of map images to use as the material: diffuse (sRGB PNG/JPEG or linear
    /// EXR), optional specular, roughness (R = alpha_x, G = alpha_y), normal (OpenGL).
    #[arg(long)]
    maps: Option<PathBuf>,
    /// Video frame rate, frames per second (> 0). Default: the preset's (30).
    #[arg(long)]
    fps: Option<f64>,
    /// Video length, seconds (> 0).
    #[arg(long)]
    duration: Option<f64>,
    /// Field of view across the longer image side, degrees, in (0, 180). Default 70.
    #[arg(long)]
    fov: Option<f64>,
    /// Closest camera height above the surface during the sweep, cm (> 0).
    #[arg(long)]
    distance_min: Option<f64>,
    /// Farthest camera height, cm (>= --distance-min).
    #[arg(long)]
    distance_max: Option<f64>,
    /// How far the sweep reaches towards the region's edges, as a fraction of its
    /// half-size, in (0, 1.5] (1: the camera passes over the corners; smaller leaves
    /// the edges seen only obliquely).
    #[arg(long)]
    reach: Option<f64>,
    /// Record the flash video with auto-exposure running, as most phones do with the
    /// torch on: each frame's gain follows the metered brightness with a 0.4 s lag,
    /// aiming at this mean linear level (0.18 if given without a value; e.g. 0.18 drifts
    /// about +-1 EV on a 10-20 cm sweep). The truth records each frame's gain.
    #[arg(long, num_args = 0..=1, default_missing_value = "0.18", value_name = "TARGET")]
    auto_exposure: Option<f64>,
    /// How the flash video is stored: h264-sdr8 (default), hevc-sdr10, hevc-hlg
    /// (10-bit HLG, BT.2020, as iPhones record by default) or hevc-pq (HDR10).
    #[arg(long, value_parser = ["h264-sdr8", "hevc-sdr10", "hevc-hlg", "hevc-pq"])]
    video_format: Option<String>,
    /// Store the same frames in these formats too (comma-separated, as --video-format),
    /// each as a complete capture folder `OUT.FORMAT` beside OUT: one rendering,
    /// several encodings, for comparing formats on identical scenes.
    #[arg(long, value_delimiter = ',', value_parser = ["h264-sdr8", "hevc-sdr10", "hevc-hlg", "hevc-pq"])]
    also_video_format: Vec<String>,
    /// Variable frame rate: frame n is taken and stamped at n / fps + J sin(1.7 n)
    /// seconds, J this many seconds (less than 0.4 frame intervals).
    #[arg(long, value_name = "J")]
    frame_jitter: Option<f64>,
    /// Room light during the flash video (>= 0; 0: a dark room): adds this times the
    /// diffuse albedo to every pixel's linear value, where the flash adds
    /// `I rho_d cos / (pi r^2)` with I = 320 (so 0.1 is 14% of the flash's diffuse light
    /// at 12 cm). Default: the preset's (0.03; the hard presets 0.1).
    #[arg(long, value_name = "A")]
    ambient: Option<f64>,
    /// Turn the built-in material by this angle about the surface normal, degrees,
    /// counter-clockwise seen from above (from the markers' +x towards +y): brushed
    /// metal's grooves at an angle to the markers, as a sheet laid askew. Default 0.
    #[arg(long, value_name = "DEG", allow_hyphen_values = true)]
    grain_angle: Option<f64>,
    /// Reflectance model the material is rendered with: ward (default, the fit's own
    /// model) or ggx (with Fresnel; fit it with Ward to measure model mismatch).
    #[arg(long, value_parser = ["ward", "ggx"])]
    brdf: Option<String>,
    /// Also render a second, no-flash camera at an oblique angle (paper section 3.3).
    #[arg(long)]
    second_camera: bool,
    /// Marker dictionary, as OpenCV names it (default DICT_6X6_250; e.g.
    /// DICT_APRILTAG_36h11).
    #[arg(long)]
    marker_dictionary: Option<String>,
    /// Also render this many flash photos (2-200) with all four markers in view, into
    /// photos/ with their camera description photos_camera.json (for `align --photos`).
    #[arg(long)]
    photos: Option<u32>,
    /// Instead of a video capture, render this many flash photos (2-100) of a 6.85 cm
    /// patch in the MaterialGAN layout that `svbrdf import` reads (photos already
    /// rectified onto the plane, flash at the camera 16-19 cm above it, as the public
    /// real sets), with the patch's true maps in OUT/ground_truth/.
    #[arg(long, value_name = "N", conflicts_with_all = ["photos", "second_camera", "also_video_format"])]
    materialgan: Option<u32>,
    /// Width and height of the --materialgan photos, pixels (default 512).
    #[arg(long, value_name = "PX", requires = "materialgan")]
    materialgan_px: Option<u32>,
    /// Replace the output folder if it exists.
    #[arg(long)]
    overwrite: bool,
}

#[derive(Args)]
pub struct DemoArgs {
    /// Output folder.
    #[arg(long, default_value = "demo-out")]
    out: PathBuf,
}

/// `svbrdf synth`: render the capture the arguments describe and list what was written.
pub fn run(a: &SynthArgs) -> Result<()> {
    let cfg = synth_config(a)?;
    if let Some(photos) = a.materialgan {
        let mut spec = svbrdf_synth::MaterialGanSpec {
            photos,
            ..Default::default()
        };
        if let Some(px) = a.materialgan_px {
            spec.size_px = px;
        }
        svbrdf_cv::set_single_threaded()?;
        let progress = progress::Bars::new();
        let s = svbrdf_synth::synthesize_materialgan(&cfg, &spec, &a.out, a.overwrite, &progress)
            .with_context(|| format!("synthesizing into {}", a.out.display()))?;
        print_timings(&progress.timings());
        print_materialgan_summary(&s, &spec, &cfg);
        return Ok(());
    }
    print_summary(&run_synth(&cfg, &a.out, a.overwrite)?);
    Ok(())
}

fn synth_config(a: &SynthArgs) -> Result<SynthConfig> {
    let mut c = SynthConfig::preset(&a.preset)?;
    if let Some(s) = a.seed {
        c.seed = s;
    }
    if let Some(m) = &a.material {
        c.material = MaterialSource::Procedural(m.clone());
    }
    if let Some(p) = &a.maps {
        c.material = MaterialSource::Maps(p.clone());
    }
    if let Some(v) = a.fps {
        c.video.fps = v;
    }
    if let Some(v) = a.duration {
        c.video.duration_s = v;
    }
    if let Some(v) = a.fov {
        c.video.fov_deg = v;
    }
    if let Some(v) = a.distance_min {
        c.sweep.distance_min_cm = v;
    }
    if let Some(v) = a.distance_max {
        c.sweep.distance_max_cm = v;
    }
    if let Some(v) = a.reach {
        c.sweep.reach = v;
    }
    if let Some(f) = &a.video_format {
        c.video.format = serde_json::from_value(serde_json::Value::String(f.clone()))?;
    }
    if let Some(j) = a.frame_jitter {
        c.video.frame_jitter_s = j;
    }
    if let Some(v) = a.ambient {
        c.light.ambient = v;
    }
    if let Some(v) = a.grain_angle {
        c.grain_angle_deg = v;
    }
    for f in &a.also_video_format {
        c.video
            .also_formats
            .push(serde_json::from_value(serde_json::Value::String(
                f.clone(),
            ))?);
    }
    if let Some(b) = &a.brdf {
        c.brdf = serde_json::from_value(serde_json::Value::String(b.clone()))?;
    }
    if let Some(target) = a.auto_exposure {
        c.video.auto_exposure = Some(svbrdf_synth::config::AutoExposureSpec {
            target,
            ..Default::default()
        });
    }
    if a.second_camera {
        c.second_camera = Some(c.default_second_camera());
    }
    if let Some(n) = a.photos {
        c.photos = Some(c.default_photos(n));
    }
    if let Some(d) = &a.marker_dictionary {
        c.markers.dictionary = d.clone();
    }
    c.validate()?;
    Ok(c)
}

fn run_synth(
    cfg: &SynthConfig,
    out: &std::path::Path,
    overwrite: bool,
) -> Result<svbrdf_synth::SynthSummary> {
    svbrdf_cv::set_single_threaded()?;
    let progress = progress::Bars::new();
    let summary = synthesize(cfg, out, overwrite, &progress)
        .with_context(|| format!("synthesizing into {}", out.display()))?;
    print_timings(&progress.timings());
    Ok(summary)
}

/// The main job: synthesize a small capture, run the whole pipeline on it (align, fit,
/// export, report) and compare every stage with the ground truth.
pub fn run_demo(a: &DemoArgs) -> Result<()> {
    let cfg = SynthConfig::tiny();
    let capture = a.out.join("capture");
    println!(
        "== synthesizing a {} capture of the built-in material",
        cfg.preset
    );
    let s = run_synth(&cfg, &capture, true)?;
    print_summary(&s);
    println!();
    let run_args =
        run_cmd::RunArgs::for_synthetic_capture(&capture, a.out.join("run"), cfg.map_px_per_cm);
    let outcome = run_cmd::run_pipeline(&run_args)?;
    println!("== accuracy against the simulator's ground truth");
    let Some((acc, m)) = &outcome.truth else {
        anyhow::bail!("the pipeline did not compare with the truth");
    };
    let get = |k: &str| acc[k].as_f64().unwrap_or(f64::NAN);
    println!(
        "alignment error: median {:.3} px, 95th percentile {:.3} px (output pixels at {} px/cm)",
        get("align_error_px_median"),
        get("align_error_px_p95"),
        cfg.map_px_per_cm
    );
    println!(
        "camera position error: median {:.2} mm; flash position error: median {:.2} mm",
        get("camera_error_mm_median"),
        get("flash_error_mm_median")
    );
    println!(
        "diffuse albedo RMSE {:.3} (after one global scale {:.3}: the flash intensity is unknown to the fit)",
        m.diffuse_rmse, m.albedo_scale
    );
    println!(
        "normal error: mean {:.2} deg, median {:.2} deg",
        m.normal_mean_deg, m.normal_median_deg
    );
    println!(
        "relighting under {} held-out lights: relative RMSE {:.1}% (mean)",
        m.relight_relative_rmse.len(),
        100.0 * m.relight_relative_rmse_mean
    );
    println!();
    run_cmd::print_run_summary(&outcome)?;
    Ok(())
}

/// What `synth --materialgan` wrote, and the share of clipped pixels.
fn print_materialgan_summary(
    s: &svbrdf_synth::MaterialGanSummary,
    spec: &svbrdf_synth::MaterialGanSpec,
    cfg: &SynthConfig,
) {
    println!("wrote {}", s.out.display());
    for f in &s.files {
        println!("  {f}");
    }
    println!(
        "{} photos of a {} cm patch at {} px ({} material, {} model); {:.2}% of the pixels have a clipped channel",
        spec.photos,
        spec.width_cm,
        spec.size_px,
        match &cfg.material {
            MaterialSource::Procedural(m) => m.clone(),
            MaterialSource::Maps(p) => p.display().to_string(),
        },
        format!("{:?}", cfg.brdf).to_lowercase(),
        100.0 * s.clipped_share
    );
}

fn print_summary(s: &svbrdf_synth::SynthSummary) {
    println!("wrote {}", s.out.display());
    for f in &s.files {
        println!("  {f}");
    }
    println!(
        "flash video: {} frames, {} with a marker fully visible, {} motion-blurred",
        s.frames, s.frames_with_markers, s.blurred_frames
    );
    for p in &s.also {
        println!("the same capture in another format: {}", p.display());
    }
    if let Some(n) = s.second_frames {
        println!("second camera: {n} frames");
    }
}
