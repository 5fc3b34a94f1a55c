//! Measurements against the simulator's ground truth, for `svbrdf bench` and for the
//! truth section of a run's report: alignment and pose errors, map accuracy, truth |
//! fit | difference pictures.

use std::time::Instant;

use anyhow::Result;
use serde_json::json;
use svbrdf_core::brdf::ModelKind;
use svbrdf_core::geometry::Vec3;

use crate::bench::{machine, peak_memory_kb};

/// Alignment accuracy against simulator ground truth.
pub fn align_accuracy(
    capture_dir: &std::path::Path,
    synth_dir: &std::path::Path,
) -> Result<serde_json::Value> {
    use svbrdf_core::capture::{PreparedMapping, RegisteredCapture};
    use svbrdf_core::geometry::{mat3_from_rows, Camera, Pose, Vec2};
    let cap = RegisteredCapture::load(capture_dir)?;
    let text = std::fs::read_to_string(synth_dir.join("ground_truth/truth.json"))?;
    let truth: svbrdf_synth::truth::GroundTruth = serde_json::from_str(&text)?;
    let stream = &truth.streams[0];
    // Per camera stream: plane errors (px), camera and light position errors (mm).
    let mut errs = [Vec::new(), Vec::new()];
    // The flash stream's displacements (ours - truth, output px), for the part of the
    // error that is one shift of the whole panorama.
    let mut shifts: Vec<Vec2> = Vec::new();
    let mut frame_shifts: Vec<serde_json::Value> = Vec::new();
    let mut cam_errs = [Vec::new(), Vec::new()];
    let mut light_errs = [Vec::new(), Vec::new()];
    let mut per_frame: Vec<serde_json::Value> = Vec::new();
    for f in &cap.frames {
        let s = cap
            .sources
            .get(f.source)
            .map_or(0, |s| s.stream as usize)
            .min(1);
        // Video frames by frame number; the simulator's photos by file name.
        let (idx, gt) = match (f.frame_index, &f.image) {
            (Some(i), _) => (
                i,
                truth
                    .streams
                    .get(s)
                    .and_then(|st| st.frames.get(i as usize)),
            ),
            (None, Some(name)) => {
                let k = truth
                    .photos
                    .iter()
                    .position(|p| svbrdf_synth::truth::photo_file(p.index) == *name);
                (k.unwrap_or(0) as u64, k.and_then(|k| truth.photos.get(k)))
            }
            _ => continue,
        };
        let Some(gt) = gt else {
            continue;
        };
        let (errs, cam_errs, light_errs) = (&mut errs[s], &mut cam_errs[s], &mut light_errs[s]);
        let before = errs.len();
        let shift_start = shifts.len();
        let cam = Camera {
            intrinsics: gt.camera.intrinsics,
            distortion: gt.camera.distortion,
            pose: Pose {
                rotation: mat3_from_rows(&gt.camera.rotation),
                centre: Vec3::from(gt.camera.position),
            },
        };
        let pm = PreparedMapping::new(f)?;
        let step = (f.width.max(f.height) / 48).max(1) as usize;
        for y in (0..f.height as usize).step_by(step) {
            for x in (0..f.width as usize).step_by(step) {
                let p = Vec2::new(x as f64, y as f64);
                let (Some(ours), Some(true_p)) = (pm.pixel_to_plane(p), cam.pixel_to_plane(p))
                else {
                    continue;
                };
                if !cap.region.contains(true_p) {
                    continue;
                }
                errs.push((ours - true_p).norm() * cap.px_per_cm);
                if s == 0 {
                    shifts.push((ours - true_p) * cap.px_per_cm);
                }
            }
        }
        if s == 0 && shifts.len() > shift_start {
            let d = shifts[shift_start..]
                .iter()
                .fold(Vec2::zeros(), |a, d| a + d)
                / (shifts.len() - shift_start) as f64;
            frame_shifts.push(json!([idx, d.x, d.y]));
        }
        let mut mine: Vec<f64> = errs[before..].to_vec();
        mine.sort_by(f64::total_cmp);
        if !mine.is_empty() && s == 0 {
            per_frame.push(json!([
                idx,
                mine[mine.len() / 2],
                mine[(mine.len() - 1) * 95 / 100]
            ]));
        }
        cam_errs
            .push((Vec3::from(f.camera_position) - Vec3::from(gt.camera.position)).norm() * 10.0);
        if let Some(l) = gt.light_position {
            light_errs.push((Vec3::from(f.light_position) - Vec3::from(l)).norm() * 10.0);
        }
    }
    let q = |v: &mut Vec<f64>, f: f64| -> f64 {
        if v.is_empty() {
            return f64::NAN;
        }
        v.sort_by(f64::total_cmp);
        v[((v.len() - 1) as f64 * f).round() as usize]
    };
    // The pooled figures hide a few misregistered frames (they cost the fit far more
    // than their share of samples): the worst frame's p95 shows them.
    let worst = per_frame
        .iter()
        .filter_map(|v| Some((v[0].as_u64()?, v[2].as_f64()?)))
        .max_by(|a, b| a.1.total_cmp(&b.1));
    let mean_shift = shifts.iter().fold(Vec2::zeros(), |a, d| a + d) / shifts.len().max(1) as f64;
    let mut unshifted: Vec<f64> = shifts.iter().map(|d| (d - mean_shift).norm()).collect();
    let [mut errs, mut errs2] = errs;
    let [mut cam_errs, mut cam_errs2] = cam_errs;
    let [mut light_errs, mut light_errs2] = light_errs;
    let mut out = json!({
        "bench": "align_accuracy",
        "preset": truth.config.preset,
        "frames_kept": cap.frames.len() - cam_errs2.len(),
        "frames_in_video": stream.frames.len(),
        "px_per_cm": cap.px_per_cm,
        "samples": errs.len(),
        "align_error_px_median": q(&mut errs, 0.5),
        "align_error_px_p95": q(&mut errs, 0.95),
        // One shift of every frame (the panorama against the markers) moves the maps
        // and nothing else; what is left without it is what bends them.
        "mean_shift_px": [mean_shift.x, mean_shift.y],
        "align_error_px_median_without_mean_shift": q(&mut unshifted, 0.5),
        // Per flash frame: its mean displacement (world x, y, output px).
        "per_frame_mean_shift_px": frame_shifts,
        "camera_error_mm_median": q(&mut cam_errs, 0.5),
        "camera_error_mm_p95": q(&mut cam_errs, 0.95),
        "flash_error_mm_median": q(&mut light_errs, 0.5),
        "worst_frame_px_p95": worst.map(|w| w.1),
        "worst_frame": worst.map(|w| w.0),
        "per_frame_px_median_p95": per_frame,
    });
    if let Some(st) = truth.streams.get(1) {
        // The sync error: our offset against the truth's (the second stream's frame 0
        // is at start_time_s on the flash clock), in second-stream frames.
        let rec: Option<serde_json::Value> =
            svbrdf_core::fsutil::read_json(&capture_dir.join("align.json")).ok();
        let offset = rec
            .as_ref()
            .and_then(|r| r["summary"]["second"]["sync_offset_s"].as_f64());
        out["second_stream"] = json!({
            "frames_kept": cam_errs2.len(),
            "sync_offset_s": offset,
            "sync_offset_true_s": -st.start_time_s,
            "sync_error_frames": offset.map(|o| (o + st.start_time_s).abs() * st.fps),
            "align_error_px_median": q(&mut errs2, 0.5),
            "align_error_px_p95": q(&mut errs2, 0.95),
            "camera_error_mm_median": q(&mut cam_errs2, 0.5),
            "light_error_mm_median": q(&mut light_errs2, 0.5),
        });
    }
    Ok(out)
}

/// Load the simulator's ground-truth maps for [`svbrdf_fit::evaluate`].
pub fn load_truth(synth_dir: &std::path::Path) -> Result<svbrdf_fit::evaluate::Truth> {
    use svbrdf_core::maps::{read_image_linear, Encoding};
    let gt_dir = synth_dir.join("ground_truth");
    let truth: svbrdf_synth::truth::GroundTruth =
        svbrdf_core::fsutil::read_json(&gt_dir.join("truth.json"))?;
    let read = |f: &str| read_image_linear(&gt_dir.join(f), Encoding::Linear);
    // The held-out images in the decoder's linear units: an HDR video puts the
    // simulator's white at its format's reference white (HLG 0.265, PQ 0.203).
    let white = truth.config.video.format.white();
    let mut holdout = Vec::new();
    for h in &truth.holdout {
        let mut img = read(&h.exr)?;
        if white != 1.0 {
            img.data.iter_mut().for_each(|v| *v *= white as f32);
        }
        holdout.push((
            img,
            Vec3::from(h.light_position),
            Vec3::from(h.camera_position),
        ));
    }
    Ok(svbrdf_fit::evaluate::Truth {
        grid: svbrdf_core::plane::PlaneGrid::new(truth.region, truth.maps.px_per_cm)?,
        diffuse: read(&truth.maps.diffuse)?,
        specular: read(&truth.maps.specular)?,
        roughness: read(&truth.maps.roughness)?,
        normal: read(&truth.maps.normal)?,
        light_intensity: truth.light_intensity * white,
        mask: read(&truth.maps.mask)?,
        holdout,
        model: truth.config.brdf,
    })
}

/// Accuracy of the maps in a `svbrdf fit` output folder against the simulator's truth.
pub fn maps_accuracy(
    fit_dir: &std::path::Path,
    synth_dir: &std::path::Path,
) -> Result<(
    svbrdf_fit::evaluate::Accuracy,
    Option<svbrdf_fit::evaluate::ConfidenceBreakdown>,
    svbrdf_fit::evaluate::MaterialBreakdown,
)> {
    let (maps, intensity) = crate::run_cmd::load_fit(fit_dir)?;
    let truth = load_truth(synth_dir)?;
    let acc = svbrdf_fit::evaluate::evaluate(
        &maps.grid,
        &maps.params,
        maps.model.model(),
        intensity,
        &truth,
    );
    let by_confidence = maps.confidence.as_ref().map(|c| {
        svbrdf_fit::evaluate::relight_by_confidence(
            &maps.grid,
            &maps.params,
            &c.per_pixel,
            maps.model.model(),
            intensity,
            &truth,
        )
    });
    let by_material = svbrdf_fit::evaluate::relight_by_material(
        &maps.grid,
        &maps.params,
        maps.model.model(),
        intensity,
        &truth,
    );
    Ok((acc, by_confidence, by_material))
}

/// Fit a capture with the intensity withheld, with and without refinement, and compare
/// with the simulator's truth: one JSON object per setting.
pub fn fit_accuracy(
    capture_dir: &std::path::Path,
    synth_dir: &std::path::Path,
    model: &str,
    config: Option<&std::path::Path>,
    pictures: Option<&std::path::Path>,
) -> Result<Vec<serde_json::Value>> {
    use svbrdf_fit::FrameSource;
    svbrdf_cv::set_single_threaded()?;
    let truth = load_truth(synth_dir)?;
    let mut capture = svbrdf_core::capture::RegisteredCapture::load(capture_dir)?;
    capture.light_intensity = None;
    let mut cfg = crate::fit_cmd::fit_config(&crate::fit_cmd::FitOptions {
        config: config.map(Into::into),
        model: model.into(),
        px_per_cm: None,
        light_intensity: None,
        no_refine: true,
        no_room_light: false,
        seed: None,
        select_folds: Some(0),
    })?;
    let grid = svbrdf_fit::output_grid(&capture, &cfg)?;
    let t = Instant::now();
    let mut b = svbrdf_fit::ObservationBuilder::new(&capture, grid, &cfg)?;
    crate::fit_cmd::CvFrames.decode(&capture, capture_dir, &mut |k, img| b.add_frame(k, &img))?;
    let mut obs = b.finish();
    let t_obs = t.elapsed().as_secs_f64();
    let mut out = Vec::new();
    for refine in [false, true] {
        cfg.refine = refine;
        let t = Instant::now();
        let (maps, summary) =
            svbrdf_fit::fit(&mut obs, &capture, &cfg, &svbrdf_core::progress::NoProgress)?;
        let t_fit = t.elapsed().as_secs_f64();
        let acc = svbrdf_fit::evaluate::evaluate(
            &grid,
            &maps.params,
            cfg.model.model(),
            summary.light_intensity,
            &truth,
        );
        if let Some(dir) = pictures {
            truth_pictures(
                dir,
                &grid,
                &maps.params,
                cfg.model,
                summary.light_intensity,
                &acc,
                &truth,
                &format!("_refine_{refine}"),
            )?;
        }
        out.push(json!({
            "bench": "fit_accuracy",
            "capture": capture_dir.display().to_string(),
            "model": summary.model,
            "refine": refine,
            "grid": [grid.width, grid.height],
            "frames": capture.frames.len(),
            "observations": summary.observations,
            "initial_clusters": summary.initial_clusters,
            "final_clusters": summary.final_clusters,
            "accuracy": acc,
            "rerender_rmse": summary.rmse_final,
            "observation_seconds": t_obs,
            "fit_seconds": t_fit,
            "timings": summary.timings,
            "peak_memory_kb": peak_memory_kb(),
            "machine": machine(),
        }));
    }
    Ok(out)
}

/// Truth, fit and four times their absolute difference side by side, on the fit's
/// grid, at most 600 pixels wide per panel.
/// Ground-truth comparison pictures of fitted maps: the diffuse albedo and every
/// held-out light, each as truth | fit | 4 x |difference| (sRGB PNG).
#[allow(clippy::too_many_arguments)]
pub fn truth_pictures(
    dir: &std::path::Path,
    grid: &svbrdf_core::plane::PlaneGrid,
    params: &[svbrdf_core::brdf::BrdfParams],
    model: ModelKind,
    light_intensity: [f64; 3],
    acc: &svbrdf_fit::evaluate::Accuracy,
    truth: &svbrdf_fit::evaluate::Truth,
    suffix: &str,
) -> Result<()> {
    std::fs::create_dir_all(dir)?;
    let mut diffuse = svbrdf_core::image::ImageF32::new(grid.width, grid.height, 3);
    for (px, p) in diffuse.data.chunks_exact_mut(3).zip(params) {
        for (v, d) in px.iter_mut().zip(p.rho_d) {
            *v = (acc.albedo_scale * d) as f32;
        }
    }
    svbrdf_core::maps::write_png(
        &dir.join(format!("diffuse{suffix}.png")),
        &holdout_picture(grid, &diffuse, &truth.grid, &truth.diffuse),
        svbrdf_core::maps::Encoding::Srgb,
        svbrdf_core::maps::PngDepth::Eight,
        &[(
            "meaning",
            "diffuse albedo: truth | fit x global scale | 4 x |difference|, linear".into(),
        )],
    )?;
    for (k, (img, light, camera)) in truth.holdout.iter().enumerate() {
        let ours = svbrdf_fit::render::relight(
            grid,
            params,
            model.model(),
            light_intensity,
            *light,
            *camera,
        );
        let pic = holdout_picture(grid, &ours, &truth.grid, img);
        svbrdf_core::maps::write_png(
            &dir.join(format!("holdout_{k:02}{suffix}.png")),
            &pic,
            svbrdf_core::maps::Encoding::Srgb,
            svbrdf_core::maps::PngDepth::Eight,
            &[(
                "meaning",
                "held-out light: truth | fit | 4 x |difference|, linear radiance".into(),
            )],
        )?;
    }
    Ok(())
}

fn holdout_picture(
    grid: &svbrdf_core::plane::PlaneGrid,
    ours: &svbrdf_core::image::ImageF32,
    tgrid: &svbrdf_core::plane::PlaneGrid,
    truth: &svbrdf_core::image::ImageF32,
) -> svbrdf_core::image::ImageF32 {
    let d = grid.width.max(grid.height).div_ceil(600).max(1);
    let (w, h) = (grid.width / d, grid.height / d);
    let mut pic = svbrdf_core::image::ImageF32::new(3 * w + 8, h, 3);
    pic.data.fill(1.0);
    for y in 0..h {
        for x in 0..w {
            let (c, r) = (x * d + d / 2, y * d + d / 2);
            let tp = tgrid.to_pixel(grid.pixel_centre(c, r));
            let mut t = [0f32; 3];
            truth.sample_bilinear(tp.x, tp.y, &mut t);
            let o = ours.pixel(c, r);
            for k in 0..3 {
                pic.pixel_mut(x, y)[k] = t[k];
                pic.pixel_mut(w + 4 + x, y)[k] = o[k];
                pic.pixel_mut(2 * w + 8 + x, y)[k] = 4.0 * (o[k] - t[k]).abs();
            }
        }
    }
    pic
}

/// Compare a run folder made from a simulated capture with its ground truth: alignment
/// and map accuracy, written with truth | fit | difference pictures into `run/truth/`
/// (the report shows them).
pub fn truth_section(
    run: &std::path::Path,
    capture: &std::path::Path,
    maps: &svbrdf_export::MaterialMaps,
    light_intensity: [f64; 3],
) -> Result<(serde_json::Value, svbrdf_fit::evaluate::Accuracy)> {
    let align = align_accuracy(&run.join(crate::run_cmd::ALIGNED), capture)?;
    let truth = load_truth(capture)?;
    let acc = svbrdf_fit::evaluate::evaluate(
        &maps.grid,
        &maps.params,
        maps.model.model(),
        light_intensity,
        &truth,
    );
    let truth_dir = run.join("truth");
    truth_pictures(
        &truth_dir,
        &maps.grid,
        &maps.params,
        maps.model,
        light_intensity,
        &acc,
        &truth,
        "",
    )?;
    let mut figures = serde_json::to_value(&acc)?;
    for k in [
        "align_error_px_median",
        "align_error_px_p95",
        "camera_error_mm_median",
    ] {
        figures[k] = align[k].clone();
    }
    if align["second_stream"].is_object() {
        figures["second_stream"] = align["second_stream"].clone();
    }
    svbrdf_core::fsutil::write_json(&truth_dir.join("accuracy.json"), &figures)?;
    Ok((align, acc))
}
