//! Writing the registered capture and the pictures a person wants to look at: the
//! average-colour panorama, the camera and flash trajectory, and the connectivity map.

use std::path::Path;

use svbrdf_core::capture::{
    Frame, FrameMapping, PreparedMapping, RegisteredCapture, Source, SourceKind, SubFrame,
    VideoCoding, CAPTURE_FILE, MAX_EXPOSURE_GAIN,
};
use svbrdf_core::color::srgb_to_linear;
use svbrdf_core::fsutil::{write_json, StagingDir};
use svbrdf_core::geometry::{mat3_to_rows, Vec2};
use svbrdf_core::image::ImageF32;
use svbrdf_core::maps::{write_png, Encoding, PngDepth};
use svbrdf_core::plane::PlaneGrid;

use crate::exposure::{
    ExposureCurve, ExposureMode, FrameGain, GainInput, DOUBTFUL_SPREAD, SIGNIFICANT_SPREAD_RATIO,
};
use crate::matching::Registration;
use crate::reference::ReferenceFrame;
use crate::{AlignConfig, AlignError, AlignInputs, AlignSummary, Progress};

/// File names inside an alignment output folder.
pub const PANORAMA: &str = "panorama.png";
/// Trajectory picture.
pub const TRAJECTORY: &str = "trajectory.png";
/// Connectivity picture.
pub const CONNECTIVITY: &str = "connectivity.png";
/// Summary and settings.
pub const SUMMARY: &str = svbrdf_core::capture::ALIGN_RECORD;
/// Exposure gain curve picture.
pub const EXPOSURE: &str = "exposure.png";

fn dot(img: &mut ImageF32, x: f64, y: f64, r: f64, rgb: [f32; 3]) {
    let (x0, x1) = (
        (x - r).floor().max(0.0) as usize,
        (x + r).ceil().max(0.0) as usize,
    );
    let (y0, y1) = (
        (y - r).floor().max(0.0) as usize,
        (y + r).ceil().max(0.0) as usize,
    );
    for yy in y0..=y1.min(img.height.saturating_sub(1)) {
        for xx in x0..=x1.min(img.width.saturating_sub(1)) {
            if (xx as f64 - x).hypot(yy as f64 - y) <= r {
                img.pixel_mut(xx, yy).copy_from_slice(&rgb);
            }
        }
    }
}

/// The reference photo's camera and the markers in the world frame, as `align.json`
/// records them (so that others can check the frame the capture is in).
#[derive(Debug, Clone, serde::Serialize)]
struct ReferenceCamera {
    /// Where the world axes come from: `markers` or `reference photo`.
    axes: String,
    /// Intrinsics of the reference photo (pixels; no distortion is modelled).
    intrinsics: svbrdf_core::geometry::Intrinsics,
    /// world_from_camera rotation, row-major (camera: x right, y down, z forward).
    rotation: [[f64; 3]; 3],
    /// Camera centre, world cm.
    position: [f64; 3],
    /// Each marker's corners in world cm (OpenCV's order: the marker's own top-left,
    /// top-right, bottom-right, bottom-left).
    marker_corners_cm: Vec<(i32, [[f64; 2]; 4])>,
}

/// What every `align.json` starts with, registered or refused.
#[derive(serde::Serialize)]
struct RecordHead<'a> {
    format: &'static str,
    version: u32,
    status: &'a str,
    settings: &'a AlignConfig,
    video: Option<String>,
    photos: Option<String>,
    second_video: Option<String>,
    reference: String,
    reference_tilt_deg: f64,
    reference_height_cm: f64,
    reference_camera: ReferenceCamera,
}

impl<'a> RecordHead<'a> {
    fn of(
        status: &'a str,
        inputs: &AlignInputs,
        cfg: &'a AlignConfig,
        rf: &ReferenceFrame,
    ) -> Self {
        let show = |p: &Option<std::path::PathBuf>| p.as_ref().map(|v| v.display().to_string());
        Self {
            format: svbrdf_core::capture::ALIGN_FORMAT,
            version: svbrdf_core::capture::ALIGN_VERSION,
            status,
            settings: cfg,
            video: show(&inputs.video),
            photos: show(&inputs.photos),
            second_video: show(&inputs.second_video),
            reference: inputs.reference.display().to_string(),
            reference_tilt_deg: rf.tilt.to_degrees(),
            reference_height_cm: rf.height,
            reference_camera: ReferenceCamera::of(rf),
        }
    }
}

impl ReferenceCamera {
    fn of(rf: &ReferenceFrame) -> Self {
        Self {
            axes: rf.axes.clone(),
            intrinsics: rf.intrinsics,
            rotation: mat3_to_rows(&rf.pose.rotation),
            position: rf.pose.centre.into(),
            marker_corners_cm: rf
                .markers
                .iter()
                .map(|(id, c)| (*id, c.map(|p| [p.x, p.y])))
                .collect(),
        }
    }
}

/// `align.json` `status` of a registered capture.
pub const STATUS_REGISTERED: &str = "registered";
/// `align.json` `status` of a refused alignment (the folder holds nothing else).
pub const STATUS_REFUSED: &str = svbrdf_core::capture::ALIGN_STATUS_REFUSED;

/// Whether `out` is a folder that holds only a refused alignment's `align.json`: the
/// next `align` may replace it without `--overwrite`.
pub fn is_refusal_record(out: &Path) -> bool {
    let Ok(entries) = std::fs::read_dir(out) else {
        return false;
    };
    let names: Vec<std::ffi::OsString> = entries.flatten().map(|e| e.file_name()).collect();
    if names.len() != 1 || names[0] != SUMMARY {
        return false;
    }
    svbrdf_core::capture::refused_alignment(out).is_some()
}

/// Record a refused alignment and return its error, with what was tried (one clause)
/// and the record's path added. The record, `OUT/align.json` with `status: "refused"`,
/// holds the error, the settings, the reference camera and the trace of every sampled
/// frame (see `trace`); it is written only where `out` does not exist or holds an
/// earlier refusal, so a registered capture of an earlier run is never replaced by a
/// refusal. Errors that are not alignment's judgement (files, settings, OpenCV) are
/// returned as they are, and so is the error when the record cannot be written.
pub fn refuse(
    inputs: &AlignInputs,
    cfg: &AlignConfig,
    rf: &ReferenceFrame,
    trace: &crate::trace::AlignTrace,
    err: AlignError,
    out: &Path,
) -> AlignError {
    let message = match &err {
        AlignError::Markers(m)
        | AlignError::Video(m)
        | AlignError::Connect(m)
        | AlignError::Solve(m) => m.clone(),
        // The second video's own refusals (no flash onset, not alignable) name that
        // video; `run --one-camera-fallback` retries without it: no record.
        _ => return err,
    };
    let tried = trace.describe();
    let free = !out.exists() || is_refusal_record(out);
    let written = free
        .then(|| write_refusal(inputs, cfg, rf, trace, &err.to_string(), &tried, out).ok())
        .flatten();
    let more = match written {
        Some(path) => format!(" (tried: {tried}; frame by frame in {})", path.display()),
        None if !free => format!(
            " (tried: {tried}; {} holds an earlier result and was left as it was)",
            out.display()
        ),
        None => format!(" (tried: {tried})"),
    };
    let message = format!("{message}{more}");
    match err {
        AlignError::Markers(_) => AlignError::Markers(message),
        AlignError::Video(_) => AlignError::Video(message),
        AlignError::Connect(_) => AlignError::Connect(message),
        _ => AlignError::Solve(message),
    }
}

fn write_refusal(
    inputs: &AlignInputs,
    cfg: &AlignConfig,
    rf: &ReferenceFrame,
    trace: &crate::trace::AlignTrace,
    error: &str,
    tried: &str,
    out: &Path,
) -> Result<std::path::PathBuf, AlignError> {
    #[derive(serde::Serialize)]
    struct Refusal<'a> {
        #[serde(flatten)]
        head: RecordHead<'a>,
        error: &'a str,
        tried: &'a str,
        trace: &'a crate::trace::AlignTrace,
    }
    let staging = StagingDir::new(out, true, &inputs.paths())?;
    write_json(
        &staging.path().join(SUMMARY),
        &Refusal {
            head: RecordHead::of(STATUS_REFUSED, inputs, cfg, rf),
            error,
            tried,
            trace,
        },
    )?;
    Ok(staging.commit()?.join(SUMMARY))
}

/// Estimate the flash frames' exposure gains into `cap` (unless `fixed_exposure`),
/// and the curve for `align.json`; a failed or doubtful estimate is warned.
fn exposure_gains(
    reg: &Registration,
    cap: &mut RegisteredCapture,
    cfg: &AlignConfig,
    region: svbrdf_core::plane::Region,
    warnings: &mut Vec<String>,
) -> ExposureCurve {
    let flash: Vec<usize> = (0..cap.frames.len())
        .filter(|&k| reg.frames[k].stream == 0)
        .collect();
    let curve = |mode, gains: &dyn Fn(usize) -> (f64, usize), note: Option<String>| {
        let frames: Vec<FrameGain> = flash
            .iter()
            .enumerate()
            .map(|(i, &k)| {
                let f = &cap.frames[k];
                let (gain, samples) = gains(i);
                FrameGain {
                    id: f.id,
                    frame_index: f.frame_index,
                    time_s: f.time_s,
                    gain,
                    samples,
                }
            })
            .collect();
        ExposureCurve {
            mode,
            range_ev: None,
            residual_spread: None,
            residual_spread_fixed: None,
            samples: 0,
            ambient_irradiance: None,
            frames,
            note,
        }
    };
    if cfg.fixed_exposure {
        return curve(ExposureMode::Fixed, &|_| (1.0, 0), None);
    }
    let inputs: Vec<GainInput<'_>> = flash
        .iter()
        .map(|&k| GainInput {
            frame: &cap.frames[k],
            thumb: &reg.frames[k].thumb,
        })
        .collect();
    let estimate = crate::exposure::estimate(&inputs, region, &cfg.exposure).and_then(|est| {
        // Gains beyond the registered capture's bounds are not exposure drift.
        let (lo, hi) = est.range_ev();
        let bound = MAX_EXPOSURE_GAIN.log2();
        if lo < -bound || hi > bound {
            Err(AlignError::invalid(
                "exposure gain range",
                format!("{lo:+.1} to {hi:+.1} EV"),
                format!("within +-{bound:.0} EV of the mean"),
            ))
        } else {
            Ok(est)
        }
    });
    match estimate {
        Ok(est) => {
            let (lo, hi) = est.range_ev();
            let doubtful = (est.residual_spread > DOUBTFUL_SPREAD).then(|| {
                format!(
                    "the frames' brightness varies in ways one exposure gain per frame does not explain (residual spread {:.0}%, expected under {:.0}%): flicker within frames, a moving shadow or strong room light; the gains were applied but the diffuse albedo may be uneven",
                    100.0 * est.residual_spread,
                    100.0 * DOUBTFUL_SPREAD
                )
            });
            if let Some(w) = &doubtful {
                warnings.push(w.clone());
            }
            let drift = est.residual_spread_fixed > SIGNIFICANT_SPREAD_RATIO * est.residual_spread;
            let mut c = curve(
                if drift {
                    ExposureMode::Estimated
                } else {
                    ExposureMode::Steady
                },
                &|i| (est.gains[i], est.frame_samples[i]),
                doubtful,
            );
            c.range_ev = Some([lo, hi]);
            c.residual_spread = Some(est.residual_spread);
            c.residual_spread_fixed = Some(est.residual_spread_fixed);
            c.samples = est.samples;
            c.ambient_irradiance = est.ambient_irradiance;
            if drift {
                for (i, &k) in flash.iter().enumerate() {
                    cap.frames[k].exposure_gain = Some(est.gains[i]);
                }
            }
            c
        }
        Err(e) => {
            let why = e.to_string();
            warnings.push(format!(
                "the frames' exposure gains could not be estimated ({why}); frames are taken as equally exposed, so auto-exposure drift would show in the albedo (lock exposure when filming, or pass --fixed-exposure if it was locked)"
            ));
            curve(ExposureMode::Failed, &|_| (1.0, 0), Some(why))
        }
    }
}

/// The gain curve as a picture: time left to right, gain bottom to top (log scale),
/// grey lines every stop, the brighter one at the geometric mean; dots blue where the
/// frame had its own estimate, orange where it was interpolated, grey where the gains
/// were not applied (steady or fixed exposure).
fn gain_plot(curve: &ExposureCurve) -> ImageF32 {
    let (w, h) = (480usize, 160usize);
    let mut img = ImageF32::new(w, h, 3);
    img.data.iter_mut().for_each(|v| *v = 0.04);
    let ev: Vec<f64> = curve.frames.iter().map(|f| f.gain.log2()).collect();
    let span = ev
        .iter()
        .fold(1.0f64, |m, v| m.max(v.abs()))
        .ceil()
        .min(6.0);
    let y_of = |e: f64| (0.5 - 0.45 * e / span) * h as f64;
    let mut stop = -span;
    while stop <= span + 1e-9 {
        let y = y_of(stop).round().clamp(0.0, (h - 1) as f64) as usize;
        let v = if stop.abs() < 1e-9 { 0.5 } else { 0.18 };
        for x in 0..w {
            img.pixel_mut(x, y).copy_from_slice(&[v, v, v]);
        }
        stop += 1.0;
    }
    let n = curve.frames.len().max(2) - 1;
    for (k, (f, e)) in curve.frames.iter().zip(&ev).enumerate() {
        let x = 6.0 + (w as f64 - 12.0) * k as f64 / n as f64;
        let colour = if curve.mode != ExposureMode::Estimated {
            [0.55, 0.55, 0.55]
        } else if f.samples > 0 {
            [0.2, 0.5, 1.0]
        } else {
            [1.0, 0.6, 0.1]
        };
        dot(&mut img, x, y_of(*e), 2.0, colour);
    }
    img
}

/// The output resolution, pixels per cm: `cfg.px_per_cm`, or by default half of the
/// flash frames' median sampling density on the plane (1 where no flash frame is kept).
pub(crate) fn px_per_cm(reg: &Registration, cfg: &AlignConfig) -> f64 {
    cfg.px_per_cm.unwrap_or_else(|| {
        let mut heights: Vec<f64> = reg
            .poses
            .iter()
            .zip(&reg.frames)
            .filter(|(_, f)| f.stream == 0)
            .map(|(p, _)| p.centre.z)
            .collect();
        heights.sort_by(f64::total_cmp);
        heights
            .get(heights.len() / 2)
            .map_or(1.0, |h| (0.5 * reg.intrinsics.fx / h).max(1.0).round())
    })
}

/// Write everything into `out` (atomically).
#[allow(clippy::too_many_arguments)]
pub fn write(
    inputs: &AlignInputs,
    cfg: &AlignConfig,
    rf: &ReferenceFrame,
    reg: Registration,
    second: Option<crate::SecondStreamSummary>,
    out: &Path,
    overwrite: bool,
    mut timings: Vec<(String, f64)>,
    mut warnings: Vec<String>,
    self_check: Vec<crate::selfcheck::FrameCheck>,
    coverage: f64,
    video_decoding: Option<crate::VideoDecoding>,
    progress: &dyn Progress,
) -> Result<AlignSummary, AlignError> {
    let t0 = std::time::Instant::now();
    let overwrite = overwrite || is_refusal_record(out);
    let staging = StagingDir::new(out, overwrite, &inputs.paths())?;
    let dir = staging.path();
    let region = cfg.region.unwrap_or_else(|| rf.marker_region());
    let px_per_cm = px_per_cm(&reg, cfg);

    let (kind, input) = match (&inputs.video, &inputs.photos) {
        (Some(v), _) => (SourceKind::Video, v.clone()),
        (None, Some(d)) => (SourceKind::Images, d.clone()),
        (None, None) => (SourceKind::Video, std::path::PathBuf::new()),
    };
    let input = std::path::absolute(&input).unwrap_or(input);
    let mut cap = RegisteredCapture::new("svbrdf align", region, px_per_cm);
    cap.sources.push(Source {
        kind,
        path: input.to_string_lossy().into_owned(),
        encoding: Encoding::Srgb,
        stream: 0,
        video: video_decoding.as_ref().map(|v| VideoCoding {
            codec: v.codec.clone(),
            pix_fmt: v.pix_fmt.clone(),
            transfer: v.transfer,
            from_bt2020: v.from_bt2020,
            bits: if v.decoder == "opencv" {
                8
            } else {
                v.bit_depth
            },
            decoder: v.decoder.clone(),
        }),
    });
    if let Some(s) = &second {
        let v = std::path::absolute(&s.video).unwrap_or_else(|_| s.video.clone());
        cap.sources.push(Source {
            kind: SourceKind::Video,
            path: v.to_string_lossy().into_owned(),
            encoding: Encoding::Srgb,
            stream: 1,
            video: None,
        });
    }
    for (k, (((f, m), pose), light)) in reg
        .frames
        .iter()
        .zip(&reg.mappings)
        .zip(&reg.poses)
        .zip(&reg.lights)
        .enumerate()
    {
        cap.frames.push(Frame {
            id: k as u32,
            source: f.stream as usize,
            frame_index: f.file.is_none().then_some(f.index),
            image: f.file.clone(),
            time_s: f.file.is_none().then_some(f.time_s),
            width: f.width,
            height: f.height,
            mapping: FrameMapping::Homographies {
                subframes: m
                    .iter()
                    .map(|(rect, h)| SubFrame {
                        rect: *rect,
                        plane_from_pixel: mat3_to_rows(h),
                    })
                    .collect(),
            },
            camera_position: pose.centre.into(),
            light_position: (*light).into(),
            exposure_gain: None,
        });
    }
    let exposure = exposure_gains(&reg, &mut cap, cfg, region, &mut warnings);
    cap.save(dir)?;

    // Average-colour panorama (linear average, shown in sRGB) at up to 400 px.
    progress.stage("pictures", 3);
    let pano_res = (400.0 / region.width().max(region.height())).min(px_per_cm);
    let grid = PlaneGrid::new(region, pano_res)?;
    let mut sum = ImageF32::new(grid.width, grid.height, 3);
    let mut count = vec![0u32; grid.len()];
    for (f, frame) in reg.frames.iter().zip(&cap.frames) {
        let pm = PreparedMapping::new(frame)?;
        let s = f.thumb.width as f64 / f64::from(f.width);
        for r in 0..grid.height {
            for c in 0..grid.width {
                if let Some(p) = pm.plane_to_pixel(grid.pixel_centre(c, r)) {
                    let (tx, ty) = (
                        ((p.x + 0.5) * s - 0.5).round(),
                        ((p.y + 0.5) * s - 0.5).round(),
                    );
                    if tx >= 0.0
                        && ty >= 0.0
                        && (tx as usize) < f.thumb.width
                        && (ty as usize) < f.thumb.height
                    {
                        let px = f.thumb.pixel(tx as usize, ty as usize);
                        let dst = sum.pixel_mut(c, r);
                        let inv = 1.0 / frame.gain();
                        for ch in 0..3 {
                            dst[ch] += (inv * srgb_to_linear(f64::from(px[ch]) / 255.0)) as f32;
                        }
                        count[r * grid.width + c] += 1;
                    }
                }
            }
        }
    }
    let mut pano = sum.clone();
    for (i, n) in count.iter().enumerate() {
        for ch in 0..3 {
            pano.data[i * 3 + ch] = if *n > 0 {
                sum.data[i * 3 + ch] / *n as f32
            } else {
                0.0
            };
        }
    }
    let meta = |what: &str| {
        vec![
            ("map", what.to_string()),
            ("px_per_cm", pano_res.to_string()),
        ]
    };
    write_png(
        &dir.join(PANORAMA),
        &pano,
        Encoding::Srgb,
        PngDepth::Eight,
        &meta("average_colour_panorama"),
    )?;
    progress.advance(1);

    // Trajectory over a dimmed panorama: cameras blue (second camera cyan, usually
    // outside the picture), flashes yellow, markers red.
    let mut traj = pano.clone();
    traj.data.iter_mut().for_each(|v| *v *= 0.5);
    for ((pose, light), f) in reg.poses.iter().zip(&reg.lights).zip(&reg.frames) {
        let c = grid.to_pixel(Vec2::new(pose.centre.x, pose.centre.y));
        let colour = if f.stream == 0 {
            [0.1, 0.3, 1.0]
        } else {
            [0.1, 0.9, 0.9]
        };
        dot(&mut traj, c.x, c.y, 2.0, colour);
        let lp = grid.to_pixel(Vec2::new(light.x, light.y));
        dot(&mut traj, lp.x, lp.y, 1.5, [1.0, 0.85, 0.1]);
    }
    for (_, corners) in &rf.markers {
        for p in corners {
            let q = grid.to_pixel(*p);
            dot(&mut traj, q.x, q.y, 2.0, [1.0, 0.1, 0.1]);
        }
    }
    write_png(
        &dir.join(TRAJECTORY),
        &traj,
        Encoding::Srgb,
        PngDepth::Eight,
        &meta("camera_blue_flash_yellow_markers_red"),
    )?;
    progress.advance(1);

    // Exposure gain curve: one dot per flash frame over time, lines every 1 EV.
    write_png(
        &dir.join(EXPOSURE),
        &gain_plot(&exposure),
        Encoding::Srgb,
        PngDepth::Eight,
        &meta("exposure_gain_per_frame_ev_lines_every_stop"),
    )?;

    // Connectivity map: grey = tested and matched, white = kept after filtering.
    let n = reg.connectivity.frames.max(1);
    let mut conn = ImageF32::new(n, n, 3);
    let maxc = reg.connectivity.counts.values().copied().max().unwrap_or(1) as f32;
    for (&(i, j), &c) in &reg.connectivity.counts {
        let v = 0.15 + 0.45 * c as f32 / maxc;
        for (a, b) in [(i, j), (j, i)] {
            conn.pixel_mut(a, b).copy_from_slice(&[v, v, v]);
        }
    }
    for &(i, j) in &reg.connectivity.kept {
        for (a, b) in [(i, j), (j, i)] {
            conn.pixel_mut(a, b).copy_from_slice(&[1.0, 1.0, 1.0]);
        }
    }
    write_png(
        &dir.join(CONNECTIVITY),
        &conn,
        Encoding::Linear,
        PngDepth::Eight,
        &meta("connectivity_map"),
    )?;
    progress.advance(1);
    progress.finish();
    timings.push(("write".into(), t0.elapsed().as_secs_f64()));

    let mut summary = AlignSummary {
        out: out.to_path_buf(),
        frames: reg.drops.clone(),
        coarse_pairs_tested: reg.coarse_tested,
        connected_pairs: reg.connectivity.kept.len(),
        fine_pairs: reg.fine_pairs,
        fine_matches_rechecked: reg.fine_rechecked,
        fine_matches_guided: reg.fine_guided,
        reference_anchored: reg.reference_tied.len(),
        frames_with_markers: reg.with_markers,
        pieces: reg.pieces,
        per_frame_anchors: reg.per_frame_anchors.clone(),
        reference_matches_needed: reg
            .frames
            .first()
            .map_or(cfg.fine_min_inliers, |f| crate::fine::fine_min(f, cfg)),
        solve_rms_cm: reg.solve.rms_after,
        solve_median_cm: reg.solve.median_after,
        solve_iterations: reg.solve.iterations,
        solve_cheap_steps: reg.solve.cheap_steps,
        unknowns: reg.solve.unknowns,
        timings,
        verified_pairs: reg.verified_pairs.clone(),
        second,
        warnings,
        self_check,
        coverage,
        video_decoding,
        exposure: Some(exposure),
        support: reg.support.clone(),
        marker_hunt: reg.marker_hunt.clone(),
        densified: reg.densified.clone(),
        plane_ties: reg.plane_ties.clone(),
        marker_corners: reg.marker_corners.clone(),
        relief: reg.relief.clone(),
    };
    #[derive(serde::Serialize)]
    struct Record<'a> {
        #[serde(flatten)]
        head: RecordHead<'a>,
        summary: &'a AlignSummary,
    }
    write_json(
        &dir.join(SUMMARY),
        &Record {
            head: RecordHead::of(STATUS_REGISTERED, inputs, cfg, rf),
            summary: &summary,
        },
    )?;
    summary.out = staging.commit()?;
    debug_assert!(summary.out.join(CAPTURE_FILE).is_file());
    Ok(summary)
}
