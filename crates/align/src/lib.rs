//! # svbrdf-align
//!
//! The geometry stage (paper section 3.1): from a hand-held flash video and a
//! reference photo of four markers to a *registered capture*: for every kept frame, a
//! piecewise-homography map from its pixels to the plane, its camera position and its
//! flash position, in centimetres.
//!
//! Stages, in order: [`reference`] (world frame from the markers), frame decoding with
//! blur selection ([`blur`]) and per-frame markers and SIFT features, coarse alignment
//! (similarities between predicted overlaps, connectivity map, largest component),
//! fine alignment (homography-verified matches between connected frames and with the
//! reference photo), the global sub-frame solve ([`solve`]), poses ([`pose`]) and the
//! outputs ([`output`]).
#![deny(missing_docs)]
// `!(x > 0.0)` rejects NaN as well as out-of-range values; that is the point.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

pub mod blur;
mod checks;
mod coarse;
pub mod config;
pub mod corners;
pub mod densify;
pub mod exposure;
mod fine;
mod frames;
mod global;
pub mod hunt;
mod matching;
pub mod output;
pub mod partial;
mod patch;
pub mod pose;
pub mod recheck;
pub mod reference;
pub mod relief;
mod second;
pub mod selfcheck;
pub mod solve;
mod subframes;
mod summary;
pub mod support;
pub mod sync;
pub mod ties;
pub mod trace;

use std::path::{Path, PathBuf};
use std::time::Instant;

use svbrdf_core::CoreError;
use svbrdf_cv::CvError;

use checks::{apply_self_check, check_baseline, coverage, self_check};
pub use checks::{COVERAGE_VIEWS, GOOD_COVERAGE, MIN_COVERAGE, MIN_SWEEP_CM};
pub use coarse::Connectivity;
pub use config::{AlignConfig, CameraDescription, FineMethod};
use densify::{finer_step, prefer_finer};
pub use frames::FrameData;
pub use summary::{SecondStreamSummary, VideoDecoding};

/// Errors of the geometry stage.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum AlignError {
    /// Markers missing or unusable.
    #[error("{0}")]
    Markers(String),
    /// The video has no usable frames.
    #[error("{0}")]
    Video(String),
    /// Frames could not be connected.
    #[error("{0}")]
    Connect(String),
    /// The global solve failed.
    #[error("global solve: {0}")]
    Solve(String),
    /// The second video of a two-camera capture is unusable (no flash onset, longer
    /// than the flash video, or not alignable); `run` can fall back to one camera.
    #[error("{0}")]
    SecondStream(String),
    /// From the core.
    #[error(transparent)]
    Core(#[from] CoreError),
    /// From OpenCV.
    #[error(transparent)]
    Cv(#[from] CvError),
}

impl AlignError {
    /// An out-of-range setting.
    pub fn invalid(
        what: impl Into<String>,
        value: impl ToString,
        expected: impl Into<String>,
    ) -> Self {
        // The core already has the one-line "invalid X (expected Y)" error.
        Self::Core(CoreError::invalid(what, value, expected))
    }
}

pub use svbrdf_core::progress::{NoProgress, Progress};

/// Why frames were not kept.
#[derive(Debug, Clone, Default, serde::Serialize, serde::Deserialize)]
pub struct DropCounts {
    /// Frames decoded at the frame step.
    pub decoded: usize,
    /// Dropped by the blur metric.
    pub blurry: usize,
    /// Their frame numbers.
    #[serde(default)]
    pub blurry_frames: Vec<u64>,
    /// Every decoded frame's number and blur metric (eq. 1; higher is sharper).
    #[serde(default)]
    pub blur_metrics: Vec<(u64, f64)>,
    /// In a piece of the connectivity map that neither the reference photo nor a
    /// marker ties to the plane.
    pub disconnected: usize,
    /// No usable homography (too few fine matches).
    pub unregistered: usize,
    /// Camera pose outside the marker boundary.
    pub outside: usize,
    /// Registered, but where the reference photo shows its texture elsewhere (the
    /// self-check after the solve).
    #[serde(default)]
    pub inconsistent: usize,
    /// Registered, but fewer than `support::MIN_SUPPORTED_SHARE` of its sub-frames were
    /// fixed by correspondences of their own.
    #[serde(default)]
    pub unsupported: usize,
    /// Registered with plane ties (no reference-photo feature matches of its own), but
    /// the reference photo's texture could not be matched over at least half of the
    /// frame from where the ties placed it (`ties`).
    #[serde(default)]
    pub unconfirmed: usize,
    /// Kept.
    pub kept: usize,
}

impl DropCounts {
    /// One line for people: frames decoded, kept, and dropped by each reason.
    pub fn describe(&self) -> String {
        format!(
            "{} decoded, {} kept; dropped {} blurry, {} disconnected, {} unregistered, {} mostly extrapolated, {} outside the markers, {} inconsistent{}",
            self.decoded,
            self.kept,
            self.blurry,
            self.disconnected,
            self.unregistered,
            self.unsupported,
            self.outside,
            self.inconsistent,
            if self.unconfirmed > 0 {
                format!(", {} unconfirmed", self.unconfirmed)
            } else {
                String::new()
            }
        )
    }
}

/// What [`align`] did.
#[derive(Debug, Clone, serde::Serialize, serde::Deserialize)]
pub struct AlignSummary {
    /// Output folder.
    pub out: PathBuf,
    /// Frame accounting.
    pub frames: DropCounts,
    /// Coarse pairs tested and connected.
    pub coarse_pairs_tested: usize,
    /// Pairs in the connectivity map after filtering.
    pub connected_pairs: usize,
    /// Fine pairs used in the solve.
    pub fine_pairs: usize,
    /// Refined matches between frames dropped because one homography of their pair put
    /// them over `fine_recheck_px` away (on repetitive texture mostly coarse matches a
    /// period off; elsewhere a few per thousand).
    #[serde(default)]
    pub fine_matches_rechecked: usize,
    /// Matches between frames that the guided fill added where a sub-frame had fewer
    /// than `fine_fill` (features whose look-alikes elsewhere fail the ratio test,
    /// found from where the pair's homography puts them), after the recheck.
    #[serde(default)]
    pub fine_matches_guided: usize,
    /// Frames anchored to the reference photo by feature matches.
    pub reference_anchored: usize,
    /// Frames with markers.
    pub frames_with_markers: usize,
    /// Pieces of the connectivity map tied to the plane separately (1: the frames form
    /// one connected chain; more: breaks bridged by the reference photo or markers).
    #[serde(default)]
    pub pieces: usize,
    /// Per sampled sharp frame: (video frame number, matches with the reference photo
    /// its verification kept, whole markers seen); a frame is anchored with at least
    /// `reference_matches_needed` matches or one marker of the reference photo's.
    #[serde(default)]
    pub per_frame_anchors: Vec<(u64, usize, usize)>,
    /// Verified matches with the reference photo a frame needs to be anchored by them.
    #[serde(default)]
    pub reference_matches_needed: usize,
    /// Global solve statistics.
    pub solve_rms_cm: f64,
    /// Median residual after the solve, cm.
    pub solve_median_cm: f64,
    /// Gauss-Newton iterations of the global solve (factorisations).
    #[serde(default)]
    pub solve_iterations: usize,
    /// Further steps that reused a factorisation.
    #[serde(default)]
    pub solve_cheap_steps: usize,
    /// Unknowns in the solve.
    pub unknowns: usize,
    /// Wall-clock seconds per stage.
    pub timings: Vec<(String, f64)>,
    /// Coarse pairs verified by RANSAC, as (video frame, video frame, inliers).
    pub verified_pairs: Vec<(u64, u64, usize)>,
    /// The second stream of a two-camera capture.
    pub second: Option<SecondStreamSummary>,
    /// Doubts about the input or the result, one sentence each (also on stderr, in
    /// run.json and in the report).
    #[serde(default)]
    pub warnings: Vec<String>,
    /// The self-check of every registered frame against the reference photo.
    #[serde(default)]
    pub self_check: Vec<selfcheck::FrameCheck>,
    /// Share of the region seen by at least [`COVERAGE_VIEWS`] kept flash frames.
    #[serde(default)]
    pub coverage: f64,
    /// How the flash video's pixels were turned into R'G'B' (what its tags say and
    /// which Y'CbCr matrix was applied); `None` for photos.
    #[serde(default)]
    pub video_decoding: Option<VideoDecoding>,
    /// Each flash frame's exposure gain (auto-exposure drift), as estimated from
    /// overlapping frames or assumed fixed.
    #[serde(default)]
    pub exposure: Option<exposure::ExposureCurve>,
    /// Sub-frames left out because no correspondence of their own fixed their maps.
    #[serde(default)]
    pub support: support::SupportSummary,
    /// The marker hunt (every frame searched for markers the sampled frames missed),
    /// where it ran.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub marker_hunt: Option<hunt::MarkerHunt>,
    /// The pass at the camera's frame step and a second from twice as many frames,
    /// where the first left the region thin (`densify`); `frames` and every other
    /// field describe the pass written (`kept_finer`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub densified: Option<densify::Densified>,
    /// Plane ties (frames without reference-photo matches tied by the self-check's
    /// blocks, solved again), where they ran.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub plane_ties: Option<ties::PlaneTieSummary>,
    /// Corners of markers that detection missed (cut by a frame's edge, or blurred),
    /// found where the solved maps put them, where they ran.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub marker_corners: Option<partial::MarkerCornerSummary>,
    /// The relief shift measured with a rigid camera model, where it ran (`relief`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub relief: Option<relief::ReliefSummary>,
}

/// Inputs of [`align`].
#[derive(Debug, Clone)]
pub struct AlignInputs {
    /// The flash video (or `photos`).
    pub video: Option<PathBuf>,
    /// A folder of flash photos instead of a video: no time order, no blur pre-filter.
    pub photos: Option<PathBuf>,
    /// The reference photo.
    pub reference: PathBuf,
    /// The second, no-flash video of a two-camera capture (paper 3.3).
    pub second_video: Option<PathBuf>,
}

impl AlignInputs {
    /// Every file and folder given as input.
    pub fn paths(&self) -> Vec<PathBuf> {
        [&self.video, &self.photos, &self.second_video]
            .into_iter()
            .flatten()
            .cloned()
            .chain(std::iter::once(self.reference.clone()))
            .collect()
    }
}

struct Timer(Vec<(String, f64)>, Instant);

impl Timer {
    fn lap(&mut self, name: &str) {
        self.0.push((name.into(), self.1.elapsed().as_secs_f64()));
        self.1 = Instant::now();
    }
}

/// Read the reference photo, find its markers and set up the world frame on them.
pub(crate) fn reference_photo(
    path: &Path,
    cfg: &AlignConfig,
    dict: svbrdf_cv::aruco::Dictionary,
) -> Result<(svbrdf_core::image::ImageU8, reference::ReferenceFrame), AlignError> {
    let ref_img = svbrdf_cv::read_image(path)?;
    let ref_k = svbrdf_core::geometry::Intrinsics::from_fov(
        ref_img.width as u32,
        ref_img.height as u32,
        cfg.camera.fov_deg,
    )?;
    let found = svbrdf_cv::aruco::detect_markers(&ref_img, dict)?;
    let lum = corners::Luminance::new(&ref_img);
    let cells = dict.cells();
    let obs: Vec<reference::MarkerObservation> = found
        .iter()
        .map(|m| reference::MarkerObservation {
            id: m.id,
            corners: corners::refine_corners(
                &lum,
                &m.corners
                    .map(|c| svbrdf_core::geometry::Vec2::new(c[0], c[1])),
                cells,
            ),
        })
        .collect();
    let reference = reference::reference_frame(&ref_k, &obs, cfg.camera.marker_size_cm, 4)
        .map_err(|e| {
            AlignError::Markers(format!(
                "{}: {e} (dictionary {})",
                path.display(),
                dict.name()
            ))
        })?;
    Ok((ref_img, reference))
}

/// Run the geometry stage and write a registered capture into `out`.
pub fn align(
    inputs: &AlignInputs,
    cfg: &AlignConfig,
    out: &Path,
    overwrite: bool,
    progress: &dyn Progress,
) -> Result<AlignSummary, AlignError> {
    cfg.validate()?;
    // Refuse an output that would delete an input or needs --overwrite now, not after
    // minutes of work.
    if out.exists() && !overwrite && !output::is_refusal_record(out) {
        return Err(svbrdf_core::CoreError::invalid(
            "output folder",
            out.display(),
            "a path that does not exist yet (or pass --overwrite)",
        )
        .into());
    }
    svbrdf_core::fsutil::check_output_spares_inputs(out, &inputs.paths())?;
    let dict = svbrdf_cv::aruco::Dictionary::from_name(&cfg.camera.marker_dictionary)?;
    let mut timer = Timer(Vec::new(), Instant::now());

    // Reference photo and world frame.
    let (ref_img, reference) = reference_photo(&inputs.reference, cfg, dict)?;
    timer.lap("reference");

    let attempt = |c: &AlignConfig, timer: &mut Timer| {
        let mut trace = trace::AlignTrace::default();
        let decoded = decode_input(inputs, c, dict, &reference, progress, timer, &mut trace)?;
        let registered = register(
            inputs, c, progress, decoded, &ref_img, &reference, timer, &mut trace,
        );
        Ok::<_, AlignError>((registered, trace))
    };
    let first_lap = timer.0.len();
    let (mut registered, mut trace) = attempt(cfg, &mut timer)?;
    let mut used = cfg.clone();
    // Where the sampled frames leave the region thin, a second pass from twice as many
    // (`densify`).
    let finer = finer_step(cfg.camera.frame_step)
        .filter(|_| cfg.densify && inputs.video.is_some() && inputs.second_video.is_none());
    if let Some(step) = finer {
        let first = outcome(cfg.camera.frame_step, &registered, &trace);
        if first.thin() {
            let mut c = cfg.clone();
            c.camera.frame_step = step;
            // The stage timings name the first pass's stages as such.
            for (name, _) in timer.0.iter_mut().skip(first_lap) {
                *name = format!("first pass: {name}");
            }
            // A finer pass that cannot even decode leaves the first one as it was.
            let (again, again_trace) =
                attempt(&c, &mut timer).unwrap_or_else(|e| (Err(e), trace::AlignTrace::default()));
            let finer = outcome(step, &again, &again_trace);
            let kept_finer = prefer_finer(&first, &finer);
            // A refusal after both passes reports the finer pass, which tried more.
            let both_refused = registered.is_err() && again.is_err();
            if kept_finer || (both_refused && again_trace.per_frame.len() > trace.per_frame.len()) {
                (registered, trace, used) = (again, again_trace, c);
            }
            let d = densify::Densified {
                first,
                finer,
                kept_finer,
            };
            match &mut registered {
                Ok(r) => r.result.densified = Some(d),
                Err(_) => trace.densified = Some(d),
            }
        }
    }
    match registered {
        Ok(r) => output::write(
            inputs,
            &used,
            &reference,
            r.result,
            r.second,
            out,
            overwrite,
            std::mem::take(&mut timer.0),
            r.warnings,
            r.checks,
            r.covered,
            r.decoding,
            progress,
        ),
        Err(e) => Err(output::refuse(inputs, &used, &reference, &trace, e, out)),
    }
}

/// What a pass gave, from its result and trace.
fn outcome(
    frame_step: u32,
    registered: &Result<Registered, AlignError>,
    trace: &trace::AlignTrace,
) -> densify::PassOutcome {
    let flash = trace.per_frame.iter().filter(|t| t.stream == 0);
    densify::PassOutcome {
        frame_step,
        sampled: flash.clone().count(),
        kept: flash.filter(|t| t.fate == trace::Fate::Kept).count(),
        coverage: match registered {
            Ok(r) => Some(r.covered),
            Err(_) => trace.coverage,
        },
        refusal: registered.as_ref().err().map(|e| e.to_string()),
    }
}

/// Decode the flash frames (and run the marker hunt) or read the photos.
#[allow(clippy::too_many_arguments)]
fn decode_input(
    inputs: &AlignInputs,
    cfg: &AlignConfig,
    dict: svbrdf_cv::aruco::Dictionary,
    reference: &reference::ReferenceFrame,
    progress: &dyn Progress,
    timer: &mut Timer,
    trace: &mut trace::AlignTrace,
) -> Result<Decoded, AlignError> {
    let mut hunted = None;
    let (frames, ordered, decoding) = match (&inputs.video, &inputs.photos) {
        (Some(v), None) => {
            let (frames, decoding) = frames::decode_frames(v, cfg, dict, progress)?;
            timer.lap("decode + features");
            let ids: Vec<i32> = reference.markers.iter().map(|(id, _)| *id).collect();
            let (frames, found) = hunt::hunt(v, frames, &ids, cfg, dict, progress)?;
            if found.is_some() {
                timer.lap("marker hunt");
            }
            hunted = found;
            (frames, true, Some(decoding))
        }
        (None, Some(d)) => {
            let frames = frames::read_photos(d, cfg, dict, progress)?;
            timer.lap("decode + features");
            (frames, false, None)
        }
        _ => {
            return Err(AlignError::invalid(
                "frame input",
                "a video and a photo folder (or neither)",
                "exactly one of them",
            ))
        }
    };
    trace.add_frames(&frames);
    if let Some(h) = &hunted {
        for &f in &h.added {
            if let Some(t) = trace.frame_mut(0, f) {
                t.hunted = true;
            }
        }
    }
    trace.marker_hunt = hunted;
    Ok(Decoded {
        frames,
        ordered,
        decoding,
    })
}

/// The decoded input of [`register`].
struct Decoded {
    frames: Vec<FrameData>,
    ordered: bool,
    decoding: Option<VideoDecoding>,
}

/// A registration that passed its checks, ready for [`output::write`].
struct Registered {
    result: matching::Registration,
    second: Option<SecondStreamSummary>,
    warnings: Vec<String>,
    checks: Vec<selfcheck::FrameCheck>,
    covered: f64,
    decoding: Option<VideoDecoding>,
}

/// Everything after the frames are decoded: registration and its checks. `trace` says
/// what was tried when this fails.
#[allow(clippy::too_many_arguments)]
fn register(
    inputs: &AlignInputs,
    cfg: &AlignConfig,
    progress: &dyn Progress,
    decoded: Decoded,
    ref_img: &svbrdf_core::image::ImageU8,
    reference: &reference::ReferenceFrame,
    timer: &mut Timer,
    trace: &mut trace::AlignTrace,
) -> Result<Registered, AlignError> {
    let Decoded {
        frames: decoded,
        ordered,
        decoding,
    } = decoded;
    let dict = svbrdf_cv::aruco::Dictionary::from_name(&cfg.camera.marker_dictionary)?;
    let ref_features = if cfg.match_reference {
        Some(fine::reference_features(ref_img, reference, cfg)?)
    } else {
        None
    };
    timer.lap("reference features");

    let (second, mut second_summary) = match (&inputs.second_video, &inputs.video) {
        (None, _) => (None, None),
        (Some(_), None) => {
            return Err(AlignError::invalid(
                "second video",
                "with still photos",
                "a flash video to synchronise with",
            ))
        }
        (Some(v), Some(flash)) => {
            let (frames, summary) = second::second_stream(v, flash, cfg, dict, progress)?;
            timer.lap("second video: sync + features");
            trace.add_frames(&frames.frames);
            (Some(frames), Some(summary))
        }
    };

    let (result, mut matched) = matching::register(
        matching::Streams {
            frames: decoded,
            ordered,
            second,
        },
        reference,
        ref_features.as_ref(),
        cfg,
        progress,
        &mut |n| timer.lap(n),
        trace,
    )?;
    let mut result = result;
    result.marker_hunt = trace.marker_hunt.clone();
    if cfg.marker_corners {
        let crops = std::mem::take(&mut matched.marker_crops);
        let (found, mut summary) = partial::marker_corners(
            &matched.frames,
            &crops,
            &result,
            &reference.markers,
            dict.cells(),
        )?;
        drop(crops);
        if !found.is_empty() {
            for (i, a) in &found {
                matched.marker_anchors[*i].extend(a.iter().copied());
            }
            result.marker_hunt = trace.marker_hunt.clone();
            result = matched.solve_again(
                &Default::default(),
                &mut result,
                cfg,
                progress,
                &mut |n| timer.lap(n),
                trace,
            )?;
            summary.residual_px = partial::residuals(&matched.frames, &found, &result)?;
            timer.lap("marker corners");
        }
        if summary.frames_tried > 0 {
            result.marker_corners = Some(summary);
        }
    }
    if cfg.relief {
        let (summary, curve) = relief::estimate(&matched, &result, cfg.reference_weight)?;
        timer.lap("relief shift");
        if summary.applied {
            relief::correct(&mut matched, &result, &curve, summary.centre_weight);
            result = matched.solve_again(
                &Default::default(),
                &mut result,
                cfg,
                progress,
                &mut |n| timer.lap(n),
                trace,
            )?;
        }
        result.relief = Some(summary);
    }
    let sweep_cm = check_baseline(&result, &inputs.reference)?;
    trace.sweep_cm = Some(sweep_cm);
    let mut warnings = Vec::new();
    let region = cfg.region.unwrap_or_else(|| reference.marker_region());
    let checks = if cfg.self_check.enabled {
        let mut checks = self_check(&result, ref_img, reference, region)?;
        timer.lap("self-check");
        if cfg.plane_ties {
            let (tied, c) = ties::tie_to_plane(
                &matched,
                result,
                checks,
                (ref_img, reference, region),
                cfg,
                progress,
                &mut |n| timer.lap(n),
                trace,
            )?;
            result = tied;
            checks = c;
        }
        // The patch images kept for the plane ties are not needed any more.
        for f in &mut result.frames {
            f.grey = None;
        }
        apply_self_check(&mut result, &checks, cfg, &mut warnings, trace)?;
        checks::require_confirmation(&result, &checks)?;
        checks
    } else {
        Vec::new()
    };
    drop(matched);
    if let Some(s) = &mut second_summary {
        s.frames = result.second_drops.clone().unwrap_or_default();
        s.cross_pairs = result.cross_pairs;
        if s.frames.kept == 0 {
            return Err(AlignError::SecondStream(format!(
                "{}: none of its {} frames could be aligned to the flash video's panorama ({} blurry, {} without markers or matches, {} with an implausible pose or outside the flash video's time span)",
                s.video.display(),
                s.frames.decoded,
                s.frames.blurry,
                s.frames.unregistered,
                s.frames.outside
            )));
        }
    }
    // The sub-frames along the frames' edges are used only where their maps are fixed,
    // unless that alone takes the coverage below the minimum (then their edges are kept,
    // with a warning: a capture that a few pixels' doubt at frame edges would refuse).
    let uncut = result.mappings.clone();
    support::apply_edge_cuts(&mut result);
    let (mut covered, mut missed) = coverage(&result, region)?;
    if covered < MIN_COVERAGE && result.support.edge_cut > 0 {
        let cut = std::mem::replace(&mut result.mappings, uncut);
        let (uncut_covered, uncut_missed) = coverage(&result, region)?;
        if uncut_covered >= MIN_COVERAGE {
            let n = std::mem::take(&mut result.support.edge_cut);
            result.support.edge_cut_area = 0.0;
            result.support.edge_cut_waived = n;
            warnings.push(format!(
                "{n} sub-frames along frames' edges were used out to the edge although their maps are extrapolated there (noise gain above {}): cut back, only {:.1}% of the region would be seen by at least {COVERAGE_VIEWS} frames; the maps near those frames' edges may lie a few output px off",
                result.support.edge_noise_gain,
                100.0 * covered
            ));
            (covered, missed) = (uncut_covered, uncut_missed);
        } else {
            // Refused either way: the refusal describes the capture with the cuts.
            result.mappings = cut;
        }
    }
    trace.coverage = Some(covered);
    if covered < MIN_COVERAGE {
        let sup = &result.support;
        let mut why = if sup.removed > 0 {
            format!(
                " ({} of {} sub-frames were left out because no match, marker or reference-photo match of their own fixed where they lie: texture that matches only in places, such as brushed metal, or too few frames)",
                sup.removed, sup.subframes
            )
        } else {
            String::new()
        };
        if let Some(b) = sup.bent() {
            why += &format!(" ({b}, up to millimetres off)");
        }
        if let Some(e) = sup.edges() {
            why += &format!(" ({e})");
        }
        if result.drops.unconfirmed > 0 {
            why += &format!(
                " ({} frames placed by plane ties were left out: the reference photo's texture confirmed them over less than half of their features, so parts of them may lie millimetres off)",
                result.drops.unconfirmed
            );
        }
        return Err(AlignError::Video(format!(
            "only {:.1}% of the region is seen by at least {COVERAGE_VIEWS} registered frames (expected at least {:.0}%){why}; thin: {missed}. Film again sweeping over that part too, more slowly, or pass --region to capture less",
            100.0 * covered,
            100.0 * MIN_COVERAGE
        )));
    }
    if covered < GOOD_COVERAGE {
        warnings.push(format!(
            "only {:.1}% of the region is seen by at least {COVERAGE_VIEWS} registered frames; thin: {missed}; those parts will be filled from neighbouring clusters, not measured",
            100.0 * covered
        ));
    }
    if let Some(d) = result
        .relief
        .as_ref()
        .and_then(relief::ReliefSummary::doubt)
    {
        warnings.push(d);
    }
    if sweep_cm < 3.0 * MIN_SWEEP_CM {
        warnings.push(format!(
            "the camera swept only {sweep_cm:.1} cm: light directions are few, so the specular lobe is poorly constrained (expected a sweep across the whole surface)"
        ));
    }
    let d = &result.drops;
    if d.decoded > 0 && (d.unregistered + d.disconnected) * 5 > d.decoded {
        warnings.push(format!(
            "{} of {} sampled frames could not be registered ({} unregistered, {} disconnected): parts of the surface may be seen by few frames",
            d.unregistered + d.disconnected,
            d.decoded,
            d.unregistered,
            d.disconnected
        ));
    }
    Ok(Registered {
        result,
        second: second_summary,
        warnings,
        checks,
        covered,
        decoding,
    })
}
