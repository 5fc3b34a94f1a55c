//! # svbrdf-fit
//!
//! The appearance stage (paper section 3.2): from a registered capture's observations
//! to spatially varying BRDF maps. Pure Rust; frames arrive already decoded (the
//! binary decodes them through `svbrdf-cv`), so this crate builds and tests without
//! OpenCV.
//!
//! Steps: [`observations`] (per-pixel linear colours, streamed frame by frame),
//! [`cluster`] (k-means++ on average colour in L*a*b*, elbow choice of k), [`tree`]
//! (recursive constrained fitting with the redundant-observation binning),
//! per-pixel refinement of diffuse albedo and normal, [`render`] (re-rendering check,
//! relighting) and [`output`] (maps as EXR and PNG with a JSON manifest).
#![deny(missing_docs)]
// Per-channel and per-parameter loops index several parallel arrays at once; iterator
// chains over three of them read worse than the index.
#![allow(clippy::needless_range_loop)]

pub mod cluster;
pub mod confidence;
pub mod config;
pub mod evaluate;
pub mod fast;
pub mod holdout;
pub mod observations;
pub mod output;
pub mod render;
pub mod select;
pub mod solver;
pub mod tree;

use std::collections::VecDeque;
use std::time::Instant;

use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use svbrdf_core::brdf::{BrdfParams, ModelKind};
use svbrdf_core::capture::RegisteredCapture;
use svbrdf_core::plane::PlaneGrid;
use svbrdf_core::progress::Progress;
use svbrdf_core::CoreError;

pub use config::FitConfig;
pub use observations::{ObservationBuilder, Observations};

use crate::solver::{Freedom, Problem, Sample};
use crate::tree::Context;

/// Errors of the appearance stage.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum FitError {
    /// From the core (files, formats, invalid values).
    #[error(transparent)]
    Core(#[from] CoreError),
    /// Nothing to fit.
    #[error("{0}")]
    NoData(String),
    /// The frame source (video decoder, image reader) failed.
    #[error("{0}")]
    Source(String),
}

/// Supplies the decoded frames of a capture (the binary implements it with OpenCV's
/// video decoder; tests can feed images directly).
pub trait FrameSource {
    /// Call `sink(k, linear_rgb)` for every frame `k` of `capture.frames`; `dir` holds
    /// `capture.json`.
    fn decode(
        &self,
        capture: &RegisteredCapture,
        dir: &std::path::Path,
        sink: &mut dyn FnMut(usize, svbrdf_core::image::FrameImage) -> Result<(), FitError>,
    ) -> Result<(), FitError>;
}

/// What [`run`] wrote.
#[derive(Debug, Clone)]
pub struct FitRun {
    /// The output folder.
    pub out: std::path::PathBuf,
    /// Its manifest.
    pub manifest: output::FitManifest,
}

/// The whole stage: read the registered capture in `capture_dir`, gather observations
/// frame by frame, fit, and write the output folder `out` (built under a temporary
/// name and renamed when complete).
pub fn run(
    capture_dir: &std::path::Path,
    out: &std::path::Path,
    overwrite: bool,
    cfg: &FitConfig,
    source: &dyn FrameSource,
    progress: &dyn Progress,
) -> Result<FitRun, FitError> {
    cfg.validate()?;
    let (capture, dir) = RegisteredCapture::load_with_folder(capture_dir)?;
    if capture.frames.is_empty() {
        return Err(FitError::NoData(format!(
            "{}: the capture has no frames",
            capture_dir.display()
        )));
    }
    let grid = output_grid(&capture, cfg)?;
    let staging = svbrdf_core::fsutil::StagingDir::new(out, overwrite, &capture.input_paths(&dir))?;
    let t = Instant::now();
    progress.stage("observations", capture.frames.len() as u64);
    let mut builder = ObservationBuilder::new(&capture, grid, cfg)?;
    let mut sampling = 0.0;
    source.decode(&capture, &dir, &mut |k, img| {
        let t = Instant::now();
        builder.add_frame(k, &img)?;
        sampling += t.elapsed().as_secs_f64();
        progress.advance(1);
        Ok(())
    })?;
    let obs = builder.finish();
    progress.finish();
    let t_obs = t.elapsed().as_secs_f64();
    let (maps, mut summary) = fit(&obs, &capture, cfg, progress)?;
    summary
        .timings
        .insert(0, ("observations: sampling frames".into(), sampling));
    summary.timings.insert(
        0,
        ("observations: decoding frames".into(), t_obs - sampling),
    );
    let nf = obs.frames.len();
    let n = cfg.strip_frames.clamp(1, nf);
    let chosen: Vec<usize> = (0..n)
        .map(|i| {
            if n == 1 {
                nf / 2
            } else {
                i * (nf - 1) / (n - 1)
            }
        })
        .collect();
    let strip = render::strip(
        &obs,
        &maps.params,
        cfg.model.model(),
        summary.light_intensity,
        &chosen,
        512,
    );
    let manifest = output::write_outputs(staging.path(), &maps, &summary, &strip)?;
    let out = staging.commit()?;
    Ok(FitRun { out, manifest })
}

impl FitError {
    /// An out-of-range value (see [`CoreError::invalid`]).
    pub fn invalid(
        what: impl Into<String>,
        value: impl ToString,
        expected: impl Into<String>,
    ) -> Self {
        Self::Core(CoreError::invalid(what, value, expected))
    }
}

/// The output grid of a capture under a configuration.
pub fn output_grid(capture: &RegisteredCapture, cfg: &FitConfig) -> Result<PlaneGrid, FitError> {
    let px_per_cm = cfg.px_per_cm.unwrap_or(capture.px_per_cm);
    // Size the grid from the region before allocating it: an absurd resolution must be
    // refused with a figure, not end in an allocation failure minutes later.
    let (w, h) = (
        capture.region.width() * px_per_cm,
        capture.region.height() * px_per_cm,
    );
    let need = estimated_fit_bytes(w * h, capture.frames.len());
    let available = available_memory_bytes();
    if need > available.unwrap_or(f64::INFINITY) || w * h > MAX_GRID_PIXELS {
        return Err(FitError::invalid(
            "output resolution",
            format!(
                "{px_per_cm} px/cm (a {:.0} x {:.0} pixel grid over the {:.2} x {:.2} cm region, needing about {})",
                w,
                h,
                capture.region.width(),
                capture.region.height(),
                human_bytes(need)
            ),
            format!(
                "a grid that fits in memory ({} available, at most {MAX_GRID_PIXELS:.0} pixels): lower --px-per-cm or px_per_cm in capture.json",
                available.map_or("unknown".into(), human_bytes)
            ),
        ));
    }
    Ok(PlaneGrid::new(capture.region, px_per_cm)?)
}

/// Above this share of the observed surface whose highlight was never seen, the fit
/// warns.
pub const SPECULAR_UNSEEN_WARNING: f64 = 0.25;

/// Largest output grid, pixels (a 20 x 20 cm region at 1000 px/cm).
pub const MAX_GRID_PIXELS: f64 = 4.0e8;

/// A rough upper estimate of the fit's peak memory, bytes: per-pixel maps and state
/// (~400 B) plus the observations (about a third of the frames see each pixel, 24 B
/// each; session 9's paper-preset fit: 4 Mpx, 115 frames, 4.5 GB measured, 5.3 GB
/// estimated).
pub fn estimated_fit_bytes(pixels: f64, frames: usize) -> f64 {
    pixels * (400.0 + frames as f64 / 3.0 * 24.0)
}

/// Memory the system can give without swapping (Linux `MemAvailable`), bytes.
pub fn available_memory_bytes() -> Option<f64> {
    let text = std::fs::read_to_string("/proc/meminfo").ok()?;
    let line = text.lines().find(|l| l.starts_with("MemAvailable:"))?;
    let kb: f64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb * 1024.0)
}

fn human_bytes(b: f64) -> String {
    match b {
        b if b >= 1e12 => format!("{:.1} TB", b / 1e12),
        b if b >= 1e9 => format!("{:.1} GB", b / 1e9),
        b => format!("{:.0} MB", b / 1e6),
    }
}

/// Fitted maps on the output grid.
#[derive(Debug, Clone)]
pub struct FittedMaps {
    /// The grid.
    pub grid: PlaneGrid,
    /// BRDF per pixel (row-major).
    pub params: Vec<BrdfParams>,
    /// Final cluster per pixel.
    pub cluster: Vec<u32>,
    /// Observations per pixel (0: filled from the nearest observed pixel's cluster).
    pub coverage: Vec<u32>,
    /// Mean observed linear colour per pixel.
    pub average: Vec<[f64; 3]>,
    /// RMS re-rendering error per pixel (linear radiance).
    pub residual: Vec<f32>,
    /// Confidence per pixel in [0, 1]: diffuse, specular lobe, normal (see
    /// [`confidence`]).
    pub confidence: Vec<[f32; 3]>,
    /// The final clusters, indexed by the ids in `cluster`.
    pub clusters: Vec<ClusterInfo>,
}

/// One final cluster as written to `clusters.json`.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct ClusterInfo {
    /// Id (value in the cluster map).
    pub id: u32,
    /// Pixels (observed ones; filled pixels are not counted).
    pub pixels: usize,
    /// Split level (0: an initial k-means cluster).
    pub depth: usize,
    /// The initial (k-means) cluster it was split from.
    #[serde(default)]
    pub initial: u32,
    /// The cluster's BRDF (before per-pixel refinement).
    pub params: BrdfParams,
    /// The specular lobe of the last accepted lobe refit (`rho_s`, `alpha_x`,
    /// `alpha_y`; its `rho_d` and normal are zero: those are per pixel in the maps),
    /// which the maps use; absent where no refit ran or none was accepted (see
    /// [`tree::refit_lobe`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub refitted_lobe: Option<BrdfParams>,
    /// RMS error over its pixels' observations (at most `max_split_observations` per
    /// pixel), linear radiance.
    pub rmse: f64,
    /// Whether its solver converged before the iteration cap.
    pub converged: bool,
    /// Shares of its pixels whose highlight peak was seen unclipped, only its flank or
    /// clipped, or never (see [`confidence`]): a cluster none of whose pixels saw the
    /// peak has a lobe fitted on flanks alone.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub specular_seen: Option<[f64; 3]>,
}

/// How the light intensity was obtained.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum IntensitySource {
    /// Given on the command line or in the configuration.
    Config,
    /// From the registered capture (the simulator knows it).
    Capture,
    /// Normalised so that the bright end of the material has albedo
    /// [`FitConfig::normalised_albedo`]: albedos are relative.
    Normalised,
}

/// Figures of one fit.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct FitSummary {
    /// Model name.
    pub model: String,
    /// Light intensity used per channel.
    pub light_intensity: [f64; 3],
    /// Where it came from.
    pub light_intensity_source: IntensitySource,
    /// Observations used.
    pub observations: usize,
    /// Observations with a clipped channel (dropped, or kept as censored values with
    /// `censor_clipped`).
    pub clipped_observations: u64,
    /// Share of the observations within [`NEAR_MIRROR_DEG`] of the mirror direction
    /// (half vector against the plane's normal) that have a clipped channel: how
    /// much of the highlights' peaks the video's range lost (`None` when clipped
    /// observations were dropped, or none lie that close).
    #[serde(default)]
    pub clipped_near_mirror: Option<f64>,
    /// Pixels with at least `min_observations`.
    pub covered_pixels: usize,
    /// All pixels.
    pub pixels: usize,
    /// Doubts about the input or the result, one sentence each (also on stderr, in
    /// run.json and in the report).
    #[serde(default)]
    pub warnings: Vec<String>,
    /// Chosen k of the initial clustering.
    pub initial_clusters: usize,
    /// Summed squared k-means error per k from `k_min`.
    pub kmeans_sse: Vec<f64>,
    /// Final clusters.
    pub final_clusters: usize,
    /// Deepest split level reached.
    pub max_depth: usize,
    /// Final clusters whose solver stopped at the iteration cap (reported, not fatal).
    pub unconverged_clusters: Vec<u32>,
    /// Whether the per-pixel refinement ran.
    pub refined: bool,
    /// Lobe refits run after the refinement (each after a refinement pass).
    #[serde(default)]
    pub lobe_refits: usize,
    /// Clusters whose maps use a refitted lobe.
    #[serde(default)]
    pub refitted_clusters: usize,
    /// Pixels with a lobe of their own (`refine_specular`: where the highlight's peak
    /// was seen unclipped); the others carry their cluster's.
    #[serde(default)]
    pub pixel_lobes: usize,
    /// RMS error of the cluster solutions (before refinement, linear), over the
    /// observations the split decisions use: at most `max_split_observations` per pixel.
    pub rmse_clusters: f64,
    /// RMS re-rendering error of the final maps over every observation.
    pub rmse_final: f64,
    /// Re-rendering error per input frame.
    pub frames: Vec<render::FrameError>,
    /// What the confidence maps say (see [`confidence`]); absent in fits written
    /// before they existed.
    #[serde(default)]
    pub confidence: Option<confidence::ConfidenceSummary>,
    /// Final clusters none of whose pixels saw the highlight's peak unclipped: their
    /// lobe rests on flanks, clipped peaks or nothing.
    #[serde(default)]
    pub clusters_without_peak: usize,
    /// How the settings were chosen on held-out frames (absent when not validated).
    #[serde(default)]
    pub selection: Option<select::Selection>,
    /// Seconds per step.
    pub timings: Vec<(String, f64)>,
}

/// With an unknown intensity, the brightest initial cluster's `rho_d + rho_s` is kept
/// at or below this.
const ENERGY_MARGIN: f64 = 0.95;

/// The light intensity: from the configuration, the capture, or normalised from the
/// data (99th percentile of the per-pixel median of `pi L r^2 / cos(theta_i)` over
/// channels, mapped to `normalised_albedo`).
pub fn light_intensity(
    obs: &Observations,
    capture: &RegisteredCapture,
    cfg: &FitConfig,
) -> Result<([f64; 3], IntensitySource), FitError> {
    if let Some(i) = cfg.light_intensity {
        return Ok((i, IntensitySource::Config));
    }
    if let Some(i) = capture.light_intensity {
        return Ok((i, IntensitySource::Capture));
    }
    // Only the flash camera's observations set the scale: a second (two-camera)
    // stream sees the surface from other angles and would move the albedo scale, so
    // one- and two-camera fits of the same capture would not be comparable.
    let stream_of: std::collections::HashMap<u32, u32> = capture
        .frames
        .iter()
        .map(|f| (f.id, capture.sources.get(f.source).map_or(0, |s| s.stream)))
        .collect();
    let flash: Vec<bool> = obs
        .frames
        .iter()
        .map(|f| stream_of.get(&f.id).is_none_or(|s| *s == 0))
        .collect();
    let step = (obs.pixels() / 20_000).max(1);
    let mut medians: Vec<f64> = (0..obs.pixels())
        .step_by(step)
        .filter(|&p| obs.range(p).any(|o| flash[usize::from(obs.frame[o])]))
        .map(|p| {
            let mut a: Vec<f64> = obs
                .range(p)
                .filter(|&o| flash[usize::from(obs.frame[o])])
                .map(|o| {
                    let lv = obs.light_view(p, o);
                    let c = obs.color(o);
                    std::f64::consts::PI * lv.light_dist2 / lv.light.z.max(0.05)
                        * (c[0] + c[1] + c[2])
                        / 3.0
                })
                .collect();
            let m = a.len() / 2;
            *a.select_nth_unstable_by(m, f64::total_cmp).1
        })
        .collect();
    if medians.is_empty() {
        return Err(FitError::NoData(
            "no pixel of the region was observed".into(),
        ));
    }
    let k = ((medians.len() - 1) as f64 * 0.99).round() as usize;
    let p99 = *medians.select_nth_unstable_by(k, f64::total_cmp).1;
    if p99 <= 0.0 || !p99.is_finite() {
        return Err(FitError::NoData(
            "every observation is black: cannot normalise the light intensity".into(),
        ));
    }
    Ok((
        [p99 / cfg.normalised_albedo; 3],
        IntensitySource::Normalised,
    ))
}

/// Give every unobserved pixel the cluster of its nearest observed pixel (4-connected
/// breadth-first fill), so that no output pixel is left without a BRDF.
fn fill_unobserved(grid: &PlaneGrid, cluster: &mut [u32], known: &[bool]) {
    let (w, h) = (grid.width, grid.height);
    let mut seen = known.to_vec();
    let mut queue: VecDeque<usize> = (0..w * h).filter(|&p| known[p]).collect();
    while let Some(p) = queue.pop_front() {
        let (x, y) = (p % w, p / w);
        let mut push = |q: usize| {
            if !seen[q] {
                seen[q] = true;
                cluster[q] = cluster[p];
                queue.push_back(q);
            }
        };
        if x > 0 {
            push(p - 1);
        }
        if x + 1 < w {
            push(p + 1);
        }
        if y > 0 {
            push(p - w);
        }
        if y + 1 < h {
            push(p + w);
        }
    }
}

thread_local! {
    /// Per-thread scratch of the Ward fast paths (one pixel's observations).
    pub(crate) static BATCH: std::cell::RefCell<fast::PixelBatch> =
        std::cell::RefCell::new(fast::PixelBatch::default());
}

/// Per-pixel refinement of diffuse albedo and normal (our addition to the paper: its
/// maps are constant within a cluster). Each pixel is fitted to its own raw
/// observations, pulled towards its cluster's solution by a prior as strong as
/// `refine_prior` average observations of each parameter.
/// The normal's trust region is centred on `anchor(pixel)` (the cluster's normal
/// angles), so that a second pass cannot walk further from the cluster than the first.
fn refine(
    ctx: &Context,
    params: &mut [BrdfParams],
    covered: &[bool],
    anchor: impl Fn(usize) -> [f64; 2] + Sync,
    iterations: usize,
    freedom: Freedom,
) {
    let obs = ctx.obs;
    let global = ctx.bounds();
    let delta = ctx.cfg.refine_max_normal_change_deg.to_radians();
    // The batch path refines diffuse albedo and normal only.
    let ward_fast = ctx.model.kind() == ModelKind::Ward && freedom == Freedom::DIFFUSE_AND_NORMAL;
    let prior = ctx.cfg.refine_prior;
    let settings = fast::RefineSettings {
        prior,
        iterations,
        robust: ctx.cfg.refine_robust,
        rounds: ctx.cfg.refine_rounds,
    };
    params
        .par_iter_mut()
        .with_min_len(256)
        .enumerate()
        .for_each(|(px, p)| {
            if !covered[px] {
                return;
            }
            let a = anchor(px);
            let mut bounds = global;
            for k in 0..2 {
                bounds.normal_lo[k] = (a[k] - delta).max(global.normal_lo[k]);
                bounds.normal_hi[k] = (a[k] + delta).min(global.normal_hi[k]);
            }
            let q = if ward_fast {
                BATCH.with_borrow_mut(|b| {
                    b.gather(obs, px, 1);
                    fast::refine_pixel(b, p, ctx.intensity, &bounds, &settings)
                })
            } else {
                let samples: Vec<Sample> = obs
                    .range(px)
                    .map(|o| Sample {
                        lv: obs.light_view(px, o),
                        rgb: obs.color(o),
                        weight: 1.0,
                        clipped: obs.clipped(o),
                    })
                    .collect();
                let prob = Problem {
                    model: ctx.model,
                    samples: &samples,
                    intensity: ctx.intensity,
                    bounds,
                    tolerance: ctx.cfg.tolerance,
                };
                prob.solve_near(p, &freedom, prior, iterations).params
            };
            if q.is_physical() {
                *p = q;
            }
        });
}

/// Fit maps to observations. `progress` sees the validation, clustering, fitting and
/// refinement. With `select_folds` > 0 the settings are first chosen by how well they
/// predict held-out frames ([`select`]), and the record lands in the summary.
pub fn fit(
    obs: &Observations,
    capture: &RegisteredCapture,
    cfg: &FitConfig,
    progress: &dyn Progress,
) -> Result<(FittedMaps, FitSummary), FitError> {
    cfg.validate()?;
    let Some((chosen, record)) = select::select(obs, capture, cfg, progress)? else {
        return fit_once(obs, capture, cfg, progress);
    };
    let (maps, mut summary) = fit_once(obs, capture, &chosen, progress)?;
    summary
        .timings
        .insert(0, ("choosing settings".to_string(), record.seconds));
    summary.selection = Some(record);
    Ok((maps, summary))
}

/// [`fit`] with the settings as given.
pub(crate) fn fit_once(
    obs: &Observations,
    capture: &RegisteredCapture,
    cfg: &FitConfig,
    progress: &dyn Progress,
) -> Result<(FittedMaps, FitSummary), FitError> {
    cfg.validate()?;
    let mut timings = Vec::new();
    let t = Instant::now();
    let (mut intensity, source) = light_intensity(obs, capture, cfg)?;
    let model = cfg.model.model();
    let npx = obs.pixels();
    let average = obs.mean_colors();
    let covered: Vec<bool> = (0..npx)
        .map(|p| obs.count(p) >= cfg.min_observations)
        .collect();
    let covered_px: Vec<u32> = (0..npx as u32).filter(|&p| covered[p as usize]).collect();
    if covered_px.len() < cfg.min_cluster_px {
        return Err(FitError::NoData(format!(
            "only {} of {} output pixels have at least {} observations (need {}): \
             the frames do not cover the region",
            covered_px.len(),
            npx,
            cfg.min_observations,
            cfg.min_cluster_px
        )));
    }

    progress.stage("initial clusters", 1);
    let colors: Vec<[f64; 3]> = covered_px.iter().map(|&p| average[p as usize]).collect();
    let init =
        cluster::initial_clusters(&colors, cfg.k_min, cfg.k_max, cfg.kmeans_sample, cfg.seed);
    let mut members: Vec<Vec<u32>> = vec![Vec::new(); init.k];
    for (&p, &l) in covered_px.iter().zip(&init.labels) {
        members[l as usize].push(p);
    }
    if source == IntensitySource::Normalised {
        // The percentile rule reads a shiny dark material (brushed metal) as bright,
        // because highlight tails inflate its diffuse estimate; its specular albedo
        // would then hit the rho_d + rho_s <= 1 bound and the fit would clip every
        // highlight. Fit the initial clusters without that bound and raise the
        // intensity until the brightest one fits under it with a margin.
        let probe = Context {
            obs,
            model,
            intensity,
            cfg,
        };
        let peak = members
            .par_iter()
            .filter(|m| !m.is_empty())
            .map(|m| {
                let p = tree::initial_fit(&probe, m, false);
                (0..3).map(|c| p.rho_d[c] + p.rho_s[c]).fold(0.0, f64::max)
            })
            .reduce(|| 0.0, f64::max);
        if peak > ENERGY_MARGIN {
            intensity = intensity.map(|v| v * peak / ENERGY_MARGIN);
        }
    }
    let ctx = Context {
        obs,
        model,
        intensity,
        cfg,
    };
    progress.finish();
    timings.push(("initial clusters".to_string(), t.elapsed().as_secs_f64()));

    let t = Instant::now();
    progress.stage("cluster fits", init.k as u64);
    let (roots, leaves): (Vec<u32>, Vec<tree::Leaf>) = members
        .into_par_iter()
        .enumerate()
        .filter(|(_, m)| !m.is_empty())
        .flat_map_iter(|(k, m)| {
            let l = tree::fit_cluster(&ctx, m);
            progress.advance(1);
            l.into_iter().map(move |leaf| (k as u32, leaf))
        })
        .unzip();
    progress.finish();
    timings.push(("cluster fits".to_string(), t.elapsed().as_secs_f64()));

    let mut cluster = vec![u32::MAX; npx];
    let mut params = vec![BrdfParams::default(); npx];
    let mut unconverged = Vec::new();
    for (i, leaf) in leaves.iter().enumerate() {
        for &p in &leaf.pixels {
            cluster[p as usize] = i as u32;
        }
        if !leaf.converged {
            unconverged.push(i as u32);
        }
    }
    fill_unobserved(&obs.grid, &mut cluster, &covered);
    for (p, c) in params.iter_mut().zip(&cluster) {
        *p = leaves[*c as usize].params;
    }
    let sse_clusters: f64 = leaves.iter().map(|l| l.sse).sum();
    let n_obs_fit: usize = leaves.iter().map(|l| l.observations).sum();
    let rmse_clusters = (sse_clusters / (3 * n_obs_fit.max(1)) as f64).sqrt();

    let t = Instant::now();
    let mut refits = 0;
    let mut pixel_lobes = 0;
    let mut lobes: Vec<Option<BrdfParams>> = vec![None; leaves.len()];
    if cfg.refine {
        progress.stage("per-pixel refinement", 1);
        let anchor = |px: usize| {
            let l = &leaves[cluster[px] as usize].params;
            [l.normal_theta_x, l.normal_theta_y]
        };
        refits = if model.kind() == ModelKind::Ward && !cfg.diffuse_only {
            cfg.lobe_refits
        } else {
            0
        };
        // The iterations are spread over the passes between lobe refits: each pass
        // starts from a sharper lobe, which is worth more than further iterations
        // against the first one.
        let iterations = cfg.refine_iterations.div_ceil(refits.max(1));
        let diffuse = Freedom::DIFFUSE_AND_NORMAL;
        refine(&ctx, &mut params, &covered, anchor, iterations, diffuse);
        progress.finish();
        timings.push((
            "per-pixel refinement".to_string(),
            t.elapsed().as_secs_f64(),
        ));
        // Clusters whose lobe the last refit moved: only their pixels are refined again.
        let mut moved = vec![true; leaves.len()];
        for pass in 0..refits {
            let t = Instant::now();
            if pass > 0 {
                progress.stage("per-pixel refinement", 1);
                let last = pass + 1 == refits;
                let again: Vec<bool> = covered
                    .iter()
                    .zip(&cluster)
                    .map(|(&c, &l)| c && (last || !cfg.refine_moved_only || moved[l as usize]))
                    .collect();
                refine(&ctx, &mut params, &again, anchor, iterations, diffuse);
                progress.finish();
                timings.push((
                    "per-pixel refinement".to_string(),
                    t.elapsed().as_secs_f64(),
                ));
            }
            let t = Instant::now();
            progress.stage("lobe refit", 1);
            let new: Vec<Option<BrdfParams>> = leaves
                .par_iter()
                .map(|l| tree::refit_lobe(&ctx, l, &params))
                .collect();
            for (i, q) in new.into_iter().enumerate() {
                let before = lobes[i].unwrap_or(leaves[i].params);
                moved[i] = q.is_some_and(|q| tree::lobe_moved(&before, &q));
                if q.is_some() {
                    lobes[i] = q;
                }
            }
            for (p, &c) in params.iter_mut().zip(&cluster) {
                if let Some(q) = lobes[c as usize] {
                    for k in 0..3 {
                        p.rho_s[k] = q.rho_s[k].min(1.0 - p.rho_d[k]).max(0.0);
                    }
                    p.alpha_x = q.alpha_x;
                    p.alpha_y = q.alpha_y;
                }
            }
            progress.finish();
            timings.push(("lobe refit".to_string(), t.elapsed().as_secs_f64()));
        }
        if cfg.refine_specular && !cfg.diffuse_only {
            // Where the highlight's peak was seen unclipped, the pixel's own lobe:
            // specular albedo and roughness too, pulled towards its cluster's.
            let t = Instant::now();
            progress.stage("per-pixel specular", 1);
            let peak: Vec<bool> = (0..npx)
                .into_par_iter()
                .map(|p| covered[p] && confidence::peak_seen(obs, p, &params[p]))
                .collect();
            pixel_lobes = peak.iter().filter(|&&b| b).count();
            refine(
                &ctx,
                &mut params,
                &peak,
                anchor,
                cfg.refine_iterations,
                Freedom::FULL,
            );
            progress.finish();
            timings.push(("per-pixel specular".to_string(), t.elapsed().as_secs_f64()));
        }
    }

    let t = Instant::now();
    progress.stage("re-rendering check", 1);
    let (residual, frames) = render::rerender_check(obs, &params, model, intensity);
    progress.finish();
    timings.push(("re-rendering check".to_string(), t.elapsed().as_secs_f64()));
    let (sse, n): (f64, usize) = frames
        .iter()
        .map(|f| {
            (
                f.rmse * f.rmse * (3 * f.observations) as f64,
                f.observations,
            )
        })
        .fold((0.0, 0), |a, b| (a.0 + b.0, a.1 + b.1));
    let rmse_final = (sse / (3 * n.max(1)) as f64).sqrt();

    let coverage = (0..npx).map(|p| obs.count(p) as u32).collect();
    let t = Instant::now();
    let (confidence, confidence_summary) = confidence::confidence(obs, &params);
    timings.push(("confidence".to_string(), t.elapsed().as_secs_f64()));
    let cluster_specular = confidence::cluster_specular(obs, &confidence, &cluster, leaves.len());
    let mut warnings = Vec::new();
    if confidence_summary.specular_unseen > SPECULAR_UNSEEN_WARNING {
        warnings.push(format!(
            "the highlight was never seen on {:.0}% of the surface: their gloss is copied from similar regions, not measured (see maps/confidence.png, green channel); sweep the phone over those parts too",
            100.0 * confidence_summary.specular_unseen
        ));
    }
    let unseen = npx - covered_px.len();
    if unseen * 20 > npx {
        warnings.push(format!(
            "{:.0}% of the output pixels ({unseen} of {npx}) were seen by fewer than {} frames: their parameters are copied from the nearest fitted cluster, not measured (see maps/coverage.png)",
            100.0 * unseen as f64 / npx as f64,
            cfg.min_observations
        ));
    }
    // Clipped observations are among `obs` when kept as censored values, else dropped.
    let all_obs = obs.len() as u64 + if cfg.censor_clipped { 0 } else { obs.clipped };
    if all_obs > 0 && obs.clipped * 4 > all_obs {
        warnings.push(format!(
            "{:.0}% of the observations have a clipped channel: the video is overexposed, so highlights are measured only in part (lower the exposure)",
            100.0 * obs.clipped as f64 / all_obs as f64
        ));
    }
    let summary = FitSummary {
        warnings,
        model: model.name().to_string(),
        light_intensity: intensity,
        light_intensity_source: source,
        observations: obs.len(),
        clipped_observations: obs.clipped,
        clipped_near_mirror: if cfg.censor_clipped {
            clipped_near_mirror(obs)
        } else {
            None
        },
        covered_pixels: covered_px.len(),
        pixels: npx,
        initial_clusters: init.k,
        kmeans_sse: init.sse,
        final_clusters: leaves.len(),
        max_depth: leaves.iter().map(|l| l.depth).max().unwrap_or(0),
        unconverged_clusters: unconverged,
        refined: cfg.refine,
        lobe_refits: refits,
        refitted_clusters: lobes.iter().filter(|l| l.is_some()).count(),
        pixel_lobes,
        rmse_clusters,
        rmse_final,
        frames,
        timings,
        confidence: Some(confidence_summary),
        clusters_without_peak: cluster_specular
            .iter()
            .filter(|c| c.is_some_and(|c| c[0] == 0.0))
            .count(),
        selection: None,
    };
    Ok((
        FittedMaps {
            grid: obs.grid,
            params,
            cluster,
            coverage,
            average,
            residual,
            confidence,
            clusters: leaves
                .iter()
                .enumerate()
                .map(|(i, l)| ClusterInfo {
                    id: i as u32,
                    initial: roots[i],
                    pixels: l.pixels.len(),
                    depth: l.depth,
                    params: l.params,
                    refitted_lobe: lobes[i],
                    rmse: (l.sse / (3 * l.observations.max(1)) as f64).sqrt(),
                    converged: l.converged,
                    specular_seen: cluster_specular[i],
                })
                .collect(),
        },
        summary,
    ))
}

/// Half-vector angle from the plane's normal within which an observation counts as
/// near the mirror direction, degrees.
pub const NEAR_MIRROR_DEG: f64 = 4.0;

/// Share of the observations near the mirror direction that are clipped.
fn clipped_near_mirror(obs: &Observations) -> Option<f64> {
    let cos_limit = NEAR_MIRROR_DEG.to_radians().cos();
    let (near, clipped) = (0..obs.pixels())
        .into_par_iter()
        .map(|p| {
            let (mut n, mut c) = (0u64, 0u64);
            for o in obs.range(p) {
                let lv = obs.light_view(p, o);
                let h = lv.light + lv.view;
                if h.z / h.norm().max(1e-12) >= cos_limit {
                    n += 1;
                    c += u64::from(obs.clipped(o).iter().any(|x| *x));
                }
            }
            (n, c)
        })
        .reduce(|| (0, 0), |a, b| (a.0 + b.0, a.1 + b.1));
    (near > 0).then(|| clipped as f64 / near as f64)
}

#[cfg(test)]
mod tests {
    use super::*;
    use svbrdf_core::brdf::{BrdfModel, Prepared, Ward};
    use svbrdf_core::geometry::Vec3;
    use svbrdf_core::plane::Region;
    use svbrdf_core::progress::NoProgress;

    /// Two materials (left half matte red, right half shiny blue) observed by a
    /// flash camera sweeping over the plane; observations rendered exactly with Ward.
    fn two_materials() -> (Observations, RegisteredCapture, [BrdfParams; 2]) {
        let truth = [
            BrdfParams {
                rho_d: [0.6, 0.15, 0.1],
                rho_s: [0.03; 3],
                alpha_x: 0.3,
                alpha_y: 0.3,
                ..BrdfParams::default()
            },
            BrdfParams {
                rho_d: [0.05, 0.1, 0.4],
                rho_s: [0.3, 0.3, 0.3],
                alpha_x: 0.12,
                alpha_y: 0.2,
                ..BrdfParams::default()
            },
        ];
        let region = Region::centred(4.0, 4.0);
        let grid = PlaneGrid::new(region, 10.0).unwrap();
        let mut frames = Vec::new();
        for i in 0..25 {
            let (u, v) = ((i % 5) as f64 - 2.0, (i / 5) as f64 - 2.0);
            let camera = Vec3::new(1.5 * u, 1.5 * v, 9.0 + 0.3 * i as f64 % 3.0);
            frames.push(observations::FrameGeometry {
                id: i,
                camera,
                light: camera + Vec3::new(1.4, -0.3, 0.0),
                gain: 1.0,
            });
        }
        let obs = observations::rendered(
            grid,
            frames,
            |px| truth[usize::from(grid.pixel_centre(px % grid.width, px / grid.width).x > 0.0)],
            100.0,
            true,
        );
        let mut cap = RegisteredCapture::new("test", region, 10.0);
        cap.light_intensity = Some([100.0; 3]);
        (obs, cap, truth)
    }

    #[test]
    fn recovers_two_materials_and_respects_the_minimum_cluster_size() {
        let (obs, cap, truth) = two_materials();
        let cfg = FitConfig {
            refine: false,
            ..FitConfig::default()
        };
        let (maps, summary) = fit(&obs, &cap, &cfg, &NoProgress).unwrap();
        // Average colour varies inside each material (falloff, highlights), so the
        // elbow may pick more than two clusters, but no cluster mixes the materials.
        assert!(summary.initial_clusters >= 2, "{:?}", summary.kmeans_sse);
        let mut side = vec![[false; 2]; maps.clusters.len()];
        for (px, c) in maps.cluster.iter().enumerate() {
            side[*c as usize][usize::from(px % 40 >= 20)] = true;
        }
        assert!(
            side.iter().all(|s| !(s[0] && s[1])),
            "a cluster mixes both materials"
        );
        assert!(maps.clusters.iter().all(|c| c.pixels >= cfg.min_cluster_px));
        // Exact data: the fit reproduces it almost exactly...
        assert!(
            summary.rmse_clusters < 2e-3,
            "rmse {}",
            summary.rmse_clusters
        );
        // ...and finds each material's parameters.
        for (px, t) in [(5 * 40 + 5, truth[0]), (30 * 40 + 35, truth[1])] {
            let p = maps.params[px];
            for c in 0..3 {
                assert!((p.rho_d[c] - t.rho_d[c]).abs() < 0.01, "{p:?} vs {t:?}");
                assert!((p.rho_s[c] - t.rho_s[c]).abs() < 0.03, "{p:?} vs {t:?}");
            }
            assert!((p.alpha_x - t.alpha_x).abs() < 0.03, "{p:?} vs {t:?}");
            assert!((p.alpha_y - t.alpha_y).abs() < 0.03, "{p:?} vs {t:?}");
            assert!(p.normal().z > 0.999);
        }
        assert!(maps.params.iter().all(BrdfParams::is_physical));
    }

    #[test]
    fn rerender_check_keeps_pixels_in_grid_order() {
        let (obs, _, truth) = two_materials();
        // Wrong on purpose on the right half, so residuals differ by pixel.
        let params: Vec<BrdfParams> = (0..obs.pixels())
            .map(|p| truth[usize::from(p % 40 >= 20)])
            .collect();
        let mut off = params.clone();
        for (p, q) in off.iter_mut().enumerate() {
            q.rho_d[0] *= 1.0 + (p % 7) as f64 * 0.05;
        }
        let (res, frames) = render::rerender_check(&obs, &off, &Ward, [100.0; 3]);
        assert_eq!(res.len(), obs.pixels());
        for px in [0, 17, 40 * 13 + 5, 40 * 39 + 39] {
            let prep = Prepared::new(off[px]);
            let mut s = 0.0;
            for o in obs.range(px) {
                let v = Ward.radiance(&prep, &obs.light_view(px, o), 100.0);
                let c = obs.color(o);
                s += (0..3).map(|k| (v[k] - c[k]).powi(2)).sum::<f64>();
            }
            let want = (s / (3 * obs.count(px)) as f64).sqrt();
            assert!((f64::from(res[px]) - want).abs() < 1e-6, "pixel {px}");
        }
        assert_eq!(
            frames.iter().map(|f| f.observations).sum::<usize>(),
            obs.len()
        );
        let (exact, _) = render::rerender_check(&obs, &params, &Ward, [100.0; 3]);
        assert!(exact.iter().all(|r| *r < 1e-4));
    }

    #[test]
    fn refinement_recovers_a_per_pixel_albedo_step_inside_a_cluster() {
        let (mut obs, cap, _) = two_materials();
        // Darken one pixel of the matte half by 20%: too small to be its own cluster.
        let px = 12 * 40 + 8;
        for o in obs.range(px) {
            obs.rgb[o] = obs.rgb[o].map(|v| (f64::from(v) * 0.8) as u16);
        }
        let cfg = FitConfig::default();
        let (maps, _) = fit(&obs, &cap, &cfg, &NoProgress).unwrap();
        let ratio = maps.params[px].rho_d[0] / maps.params[px + 1].rho_d[0];
        assert!((ratio - 0.8).abs() < 0.05, "ratio {ratio}");
    }

    #[test]
    fn pixels_whose_peak_was_seen_get_their_own_lobe_with_refine_specular() {
        let (mut obs, cap, truth) = two_materials();
        // A 2 x 2 patch of the shiny half reflects 40% more specular light: too small
        // to be its own cluster, so only a per-pixel lobe can follow it. It lies where
        // the camera above the centre sees its highlight (x 0.7, y -0.15 cm).
        let patch: Vec<usize> = [(26, 21), (27, 21), (26, 22), (27, 22)]
            .iter()
            .map(|(x, y)| y * 40 + x)
            .collect();
        let brighter = BrdfParams {
            rho_s: [0.42; 3],
            ..truth[1]
        };
        for &px in &patch {
            let prep = Prepared::new(brighter);
            for o in obs.range(px) {
                let v = Ward.radiance(&prep, &obs.light_view(px, o), 100.0);
                if obs.clipped(o).iter().all(|c| !c) {
                    obs.rgb[o] = v.map(|x| (x * observations::RGB_SCALE).round() as u16);
                }
            }
        }
        let base = FitConfig {
            select_folds: 0,
            refine_specular: false,
            ..FitConfig::default()
        };
        let (plain, plain_summary) = fit(&obs, &cap, &base, &NoProgress).unwrap();
        let cfg = FitConfig {
            refine_specular: true,
            ..base
        };
        let (own, summary) = fit(&obs, &cap, &cfg, &NoProgress).unwrap();
        assert_eq!(plain_summary.pixel_lobes, 0);
        assert!(summary.pixel_lobes > 0);
        let seen: Vec<usize> = patch
            .iter()
            .copied()
            .filter(|&p| confidence::peak_seen(&obs, p, &own.params[p]))
            .collect();
        assert!(!seen.is_empty(), "no patch pixel saw its peak");
        for &px in &seen {
            let (a, b) = (plain.params[px].rho_s[1], own.params[px].rho_s[1]);
            eprintln!("pixel {px}: cluster lobe {a:.3}, own {b:.3}");
            assert!(
                (b - 0.42).abs() < 0.5 * (a - 0.42).abs(),
                "pixel {px}: cluster lobe {a}, own lobe {b}, truth 0.42"
            );
        }
        // A pixel far from the patch whose peak was never seen keeps its cluster's lobe.
        let unseen = (0..obs.pixels())
            .find(|&p| obs.count(p) > 0 && !confidence::peak_seen(&obs, p, &own.params[p]));
        if let Some(p) = unseen {
            assert_eq!(own.params[p].rho_s, plain.params[p].rho_s, "pixel {p}");
        }
        assert!(own.params.iter().all(BrdfParams::is_physical));
    }

    #[test]
    fn unobserved_pixels_get_a_neighbours_cluster_and_no_nan() {
        let (mut obs, cap, _) = two_materials();
        // Remove every observation of a 3x3 block.
        let mut keep = vec![true; obs.len()];
        for y in 10..13 {
            for x in 10..13 {
                for o in obs.range(y * 40 + x) {
                    keep[o] = false;
                }
            }
        }
        let mut start = vec![0];
        let (mut f, mut r, mut k) = (Vec::new(), Vec::new(), Vec::new());
        for px in 0..obs.pixels() {
            for o in obs.range(px).filter(|o| keep[*o]) {
                f.push(obs.frame[o]);
                r.push(obs.rgb[o]);
                k.push(obs.key[o]);
            }
            start.push(f.len());
        }
        (obs.start, obs.frame, obs.rgb, obs.key) = (start, f, r, k);
        let (maps, summary) = fit(&obs, &cap, &FitConfig::default(), &NoProgress).unwrap();
        assert_eq!(summary.covered_pixels, 40 * 40 - 9);
        assert_eq!(maps.coverage[11 * 40 + 11], 0);
        assert_eq!(maps.cluster[11 * 40 + 11], maps.cluster[11 * 40 + 9]);
        assert!(maps.params.iter().all(BrdfParams::is_physical));
    }
}
