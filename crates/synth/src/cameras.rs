//! The simulator's other cameras: a second, no-flash video filmed beside the flash
//! video, and flash photos with every marker in view.

use std::path::Path;

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use svbrdf_core::fsutil::write_json;
use svbrdf_core::geometry::{Camera, Intrinsics, Pose, RadialDistortion, Vec3};
use svbrdf_core::CoreError;
use svbrdf_cv::video::VideoWriter;

use crate::config::{self, SynthConfig};
use crate::render::{expose, render_linear, Exposure, Lighting};
use crate::scene::Scene;
use crate::truth::*;
use crate::{cam_truth, visible_markers, CameraDescription, Progress, SynthError};

#[allow(clippy::too_many_arguments)]
pub(crate) fn render_second_camera(
    cfg: &SynthConfig,
    sc: &config::SecondCameraSpec,
    scene: &Scene,
    flash_camera_at: &dyn Fn(f64) -> Camera,
    flash_offset: Vec3,
    lighting: Lighting,
    dir: &Path,
    progress: &dyn Progress,
) -> Result<StreamTruth, SynthError> {
    let v = &cfg.video;
    let intr = Intrinsics::from_fov(sc.width, sc.height, sc.fov_deg)?;
    // It starts `lead_s` early and stops a little before the flash camera, as the paper requires.
    let length = sc.lead_s + v.duration_s - 2.0 / v.fps;
    let n = (length * sc.fps).floor().max(1.0) as u64;
    let (az, el) = (
        sc.azimuth_deg.to_radians(),
        (90.0 - sc.oblique_deg).to_radians(),
    );
    let base = Vec3::new(el.cos() * az.cos(), el.cos() * az.sin(), el.sin()) * sc.distance_cm;
    let mut rng = ChaCha8Rng::seed_from_u64(cfg.seed ^ 0x2CA3);
    let (p1, p2) = (
        rng.random_range(0.0..std::f64::consts::TAU),
        rng.random_range(0.0..std::f64::consts::TAU),
    );
    let reach = 0.5 * cfg.region_cm[0].max(cfg.region_cm[1]);
    let mut writer = VideoWriter::create(&dir.join("second.mp4"), sc.fps, sc.width, sc.height)?;
    let mut frames = Vec::with_capacity(n as usize);
    let mut onset = None;
    progress.stage("second camera", n);
    for j in 0..n {
        let t2 = j as f64 / sc.fps;
        let t = t2 - sc.lead_s; // flash camera clock
        let wob = Vec3::new((0.7 * t2 + p1).sin(), (0.5 * t2 + p2).sin(), 0.0) * 0.6;
        // Aim a little towards the near side, which perspective makes larger, so
        // that the whole marker square stays in view.
        let aim = Vec3::new(base.x, base.y, 0.0).normalize() * 0.15 * reach;
        let pose = Pose::look_at(base + wob, wob * 0.5 + aim, Vec3::z())?;
        let cam = Camera {
            intrinsics: intr,
            distortion: RadialDistortion { k1: -0.04, k2: 0.0 },
            pose,
        };
        // Rolling shutter: row r is read at t + r/H * readout.
        let h = f64::from(sc.height);
        let first_lit = if t >= 0.0 {
            Some(0usize)
        } else if t + sc.readout_s >= 0.0 {
            Some(((-t / sc.readout_s) * h).ceil() as usize)
        } else {
            None
        };
        let light = first_lit.map(|_| {
            flash_camera_at(t.max(0.0))
                .pose
                .camera_to_world(flash_offset)
        });
        if onset.is_none() && first_lit.is_some_and(|r| r < sc.height as usize) {
            onset = Some(j);
        }
        let e = Exposure {
            camera: cam,
            light,
            first_lit_row: first_lit.unwrap_or(usize::MAX),
        };
        let lin = render_linear(scene, &[e], lighting, 1);
        writer.write(&expose(
            &lin,
            cfg.light.shot_noise,
            cfg.light.read_noise,
            cfg.seed ^ 0x2222,
            j,
        ))?;
        frames.push(FrameTruth {
            index: j,
            time_s: t,
            camera: cam_truth(&cam),
            light_position: light.map(Into::into),
            first_lit_row: first_lit.map(|r| r.min(sc.height as usize) as u32),
            motion_blur: false,
            markers_visible: visible_markers(&cam, scene),
            exposure_gain: 1.0,
        });
        progress.advance(1);
    }
    writer.finish()?;
    progress.finish();
    Ok(StreamTruth {
        file: "second.mp4".into(),
        flash: false,
        fps: sc.fps,
        width: sc.width,
        height: sc.height,
        start_time_s: -sc.lead_s,
        flash_onset_frame: onset,
        frames,
    })
}

/// Flash photos from random positions above the region, each with all four markers in
/// view, as JPEGs in `photos/`, and their camera description.
pub(crate) fn render_photos(
    cfg: &SynthConfig,
    ps: &config::PhotoSpec,
    scene: &Scene,
    lighting: Lighting,
    dir: &Path,
    progress: &dyn Progress,
) -> Result<Vec<FrameTruth>, SynthError> {
    let out = dir.join("photos");
    std::fs::create_dir_all(&out).map_err(|e| CoreError::io(&out, e))?;
    let intr = Intrinsics::from_fov(ps.width, ps.height, ps.fov_deg)?;
    let flash_offset = Vec3::from(cfg.light.flash_offset_cm);
    let mut rng = ChaCha8Rng::seed_from_u64(cfg.seed ^ 0x9407);
    let reach = 0.25 * cfg.region_cm[0].min(cfg.region_cm[1]);
    let mut truth = Vec::with_capacity(ps.count as usize);
    progress.stage("flash photos", u64::from(ps.count));
    for k in 0..ps.count {
        // Draw until the four markers are inside the photo.
        let mut found = None;
        for _ in 0..200 {
            let h = rng.random_range(ps.distance_cm[0]..=ps.distance_cm[1]);
            let c = Vec3::new(
                rng.random_range(-reach..=reach),
                rng.random_range(-reach..=reach),
                h,
            );
            let tilt = ps.tilt_deg.to_radians();
            let target = Vec3::new(
                c.x + h * rng.random_range(-tilt..=tilt).tan(),
                c.y + h * rng.random_range(-tilt..=tilt).tan(),
                0.0,
            );
            let cam = Camera {
                intrinsics: intr,
                distortion: RadialDistortion::default(),
                pose: Pose::look_at(c, target, Vec3::y())?,
            };
            if visible_markers(&cam, scene).len() == scene.markers.len() {
                found = Some(cam);
                break;
            }
        }
        let cam = found.ok_or_else(|| {
            SynthError::invalid(
                "photo distance",
                format!("{:?} cm", ps.distance_cm),
                "a distance at which all four markers fit in the photo",
            )
        })?;
        let light = cam.pose.camera_to_world(flash_offset);
        let lin = render_linear(
            scene,
            &[Exposure {
                camera: cam,
                light: Some(light),
                first_lit_row: 0,
            }],
            lighting,
            2,
        );
        let img = expose(
            &lin,
            cfg.light.shot_noise,
            cfg.light.read_noise,
            cfg.seed ^ 0x9407,
            u64::from(k),
        );
        svbrdf_cv::write_jpeg(
            &out.join(crate::truth::photo_file(u64::from(k))),
            &img,
            ps.jpeg_quality,
        )?;
        truth.push(FrameTruth {
            index: u64::from(k),
            time_s: 0.0,
            camera: cam_truth(&cam),
            light_position: Some(light.into()),
            first_lit_row: None,
            motion_blur: false,
            markers_visible: visible_markers(&cam, scene),
            exposure_gain: 1.0,
        });
        progress.advance(1);
    }
    progress.finish();
    write_json(
        &dir.join("photos_camera.json"),
        &CameraDescription {
            fov_deg: ps.fov_deg,
            flash_offset_cm: cfg.light.flash_offset_cm,
            marker_size_cm: cfg.markers.size_cm,
            marker_dictionary: cfg.markers.dictionary.clone(),
            frame_step: 1,
            readout_s: 0.0,
        },
    )?;
    Ok(truth)
}
