//! # svbrdf-synth
//!
//! Renders complete phone captures of known flat materials, as the paper's users
//! record them, with exact ground truth: a reference photo with four ArUco markers,
//! a hand-held flash video (H.264 in MP4), optionally a second no-flash camera, the
//! svBRDF maps, per-frame cameras and flash positions, held-out relighting images, and
//! the same truth as a registered capture so fitting can be measured with perfect poses.
//!
//! Output folder layout (see `docs/ARCHITECTURE.md`):
//! ```text
//! OUT/reference.jpg            reference photo (sRGB JPEG)
//! OUT/flash.mp4                flash video (H.264, sRGB)
//! OUT/second.mp4               second camera (optional)
//! OUT/camera.json              the phone description that `align` takes
//! OUT/second_camera.json       the second phone's description (optional)
//! OUT/photos/photo_NN.jpg      flash photos with all markers in view (optional)
//! OUT/photos_camera.json       their camera description (optional)
//! OUT/ground_truth/truth.json  cameras, lights, markers, settings
//! OUT/ground_truth/maps/*.exr  linear maps (+ PNG previews)
//! OUT/ground_truth/holdout/*   held-out relighting (linear EXR + sRGB PNG)
//! OUT/registered/capture.json  ground truth as a registered capture
//! ```
#![deny(missing_docs)]

pub mod config;
pub mod material;
mod noise;
pub mod render;
pub mod scene;
pub mod trajectory;
pub mod truth;

use std::path::{Path, PathBuf};

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use svbrdf_core::brdf::{LightView, ModelKind, Prepared};
use svbrdf_core::capture::{Frame, FrameMapping, RegisteredCapture, Source, SourceKind};
use svbrdf_core::fsutil::{write_json, StagingDir};
use svbrdf_core::geometry::{
    mat3_to_rows, rot_x, rot_z, Camera, Intrinsics, Mat3, Pose, RadialDistortion, Vec2, Vec3,
};
use svbrdf_core::image::ImageF32;
use svbrdf_core::maps::{write_exr, write_png, Encoding, PngDepth};
use svbrdf_core::plane::{PlaneGrid, Region};
use svbrdf_core::CoreError;
use svbrdf_cv::aruco::{marker_pattern, Dictionary};
use svbrdf_cv::encode::{FfmpegWriter, VideoFormat};
use svbrdf_cv::video::VideoWriter;
use svbrdf_cv::CvError;

pub use config::{MaterialSource, SynthConfig};
use material::MaterialMaps;
use render::{expose, expose_linear, render_linear, Exposure, Lighting};
use scene::Scene;
use trajectory::Sweep;
use truth::*;

/// Errors of the simulator.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum SynthError {
    /// From the core (files, geometry).
    #[error(transparent)]
    Core(#[from] CoreError),
    /// From OpenCV (markers, video).
    #[error(transparent)]
    Cv(#[from] CvError),
}

impl SynthError {
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

pub use svbrdf_core::camera_description::CameraDescription;
pub use svbrdf_core::progress::{NoProgress, Progress};

/// What `synthesize` wrote.
#[derive(Debug, Clone)]
pub struct SynthSummary {
    /// The output folder.
    pub out: PathBuf,
    /// Files written, relative to `out`.
    pub files: Vec<String>,
    /// Frames in the flash video.
    pub frames: u64,
    /// Frames in which at least one marker is fully visible.
    pub frames_with_markers: u64,
    /// Motion-blurred frames.
    pub blurred_frames: u64,
    /// Frames of the second camera, if any.
    pub second_frames: Option<u64>,
    /// The same capture stored in other formats (`VideoSpec::also_formats`).
    pub also: Vec<std::path::PathBuf>,
}

fn cam_truth(c: &Camera) -> CameraTruth {
    CameraTruth {
        intrinsics: c.intrinsics,
        distortion: c.distortion,
        rotation: mat3_to_rows(&c.pose.rotation),
        position: c.pose.centre.into(),
    }
}

fn visible_markers(cam: &Camera, scene: &Scene) -> Vec<i32> {
    scene
        .markers
        .iter()
        .filter(|m| {
            m.corners.iter().all(|c| {
                cam.project(Vec3::from(*c))
                    .is_some_and(|p| cam.intrinsics.contains(p))
            })
        })
        .map(|m| m.id)
        .collect()
}

/// Render a complete capture into `out` (which must not exist unless `overwrite`).
/// Everything is written into a temporary sibling folder that is renamed at the end,
/// so an interrupted run never leaves a folder that looks complete.
pub fn synthesize(
    cfg: &SynthConfig,
    out: &Path,
    overwrite: bool,
    progress: &dyn Progress,
) -> Result<SynthSummary, SynthError> {
    cfg.validate()?;
    let inputs: Vec<std::path::PathBuf> = match &cfg.material {
        MaterialSource::Maps(p) => vec![p.clone()],
        MaterialSource::Procedural(_) => Vec::new(),
    };
    let staging = StagingDir::new(out, overwrite, &inputs)?;
    let dir = staging.path().to_path_buf();
    // Folders of the same capture stored in other formats (refused before any work if
    // they exist without `overwrite`).
    let also: Vec<(VideoFormat, StagingDir)> = cfg
        .video
        .also_formats
        .iter()
        .map(|&f| Ok((f, StagingDir::new(&also_path(out, f), overwrite, &inputs)?)))
        .collect::<Result<_, SynthError>>()?;
    let mut files = Vec::new();
    let region = Region::centred(cfg.region_cm[0], cfg.region_cm[1]);
    let dict = Dictionary::from_name(&cfg.markers.dictionary)?;

    // Material, rasterised over the region and the markers' surroundings.
    progress.stage("material", 1);
    // A whole number of texels, so the ground-truth crop shares the render raster exactly.
    let margin = ((cfg.markers.size_cm + cfg.markers.paper_margin_cm + 2.0) * cfg.map_px_per_cm)
        .ceil()
        / cfg.map_px_per_cm;
    let grid = PlaneGrid::new(region.expanded(margin), cfg.map_px_per_cm)?;
    let material = match &cfg.material {
        MaterialSource::Procedural(name) => {
            MaterialMaps::procedural(name, grid, cfg.feature_cm, cfg.seed)?
        }
        MaterialSource::Maps(path) => MaterialMaps::from_folder(path, grid, region)?,
    };
    let patterns = cfg
        .markers
        .ids
        .iter()
        .map(|&id| marker_pattern(dict, id).map(|p| (id, p.cells, p.white)))
        .collect::<Result<Vec<_>, _>>()?;
    let scene = Scene::new(
        material,
        region,
        patterns,
        cfg.markers.size_cm,
        cfg.markers.paper_margin_cm,
        cfg.seed,
    );
    progress.finish();

    // Ground-truth maps.
    progress.stage("ground-truth maps", 1);
    let gt_dir = dir.join("ground_truth");
    let maps = write_truth_maps(
        &scene,
        region,
        cfg.map_px_per_cm,
        cfg.brdf,
        &gt_dir.join("maps"),
    )?;
    files.push("ground_truth/maps/".into());
    progress.finish();

    // Reference photo: levelled (or tilted by `tilt_deg`) above the origin, room light.
    progress.stage("reference photo", 1);
    let r = &cfg.reference;
    let down = Mat3::new(1.0, 0.0, 0.0, 0.0, -1.0, 0.0, 0.0, 0.0, -1.0);
    let ref_cam = Camera {
        intrinsics: Intrinsics::from_fov(r.width, r.height, r.fov_deg)?,
        distortion: RadialDistortion::default(),
        pose: Pose {
            rotation: rot_z(r.roll_deg.to_radians()) * rot_x(r.tilt_deg.to_radians()) * down,
            centre: Vec3::new(0.0, 0.0, r.distance_cm),
        },
    };
    let ref_lin = render_linear(
        &scene,
        &[Exposure {
            camera: ref_cam,
            light: None,
            first_lit_row: 0,
        }],
        Lighting {
            intensity: 0.0,
            ambient: cfg.light.reference_ambient,
            model: cfg.brdf,
        },
        r.supersample,
    );
    let ref_img = expose(
        &ref_lin,
        cfg.light.shot_noise,
        cfg.light.read_noise,
        cfg.seed,
        u64::MAX,
    );
    svbrdf_cv::write_jpeg(&dir.join("reference.jpg"), &ref_img, r.jpeg_quality)?;
    files.push("reference.jpg".into());
    for m in &scene.markers {
        for c in &m.corners {
            let inside = ref_cam
                .project(Vec3::from(*c))
                .is_some_and(|p| ref_cam.intrinsics.contains(p));
            if !inside {
                return Err(SynthError::invalid(
                    "reference distance",
                    format!("{} cm", r.distance_cm),
                    format!(
                        "a distance at which all four markers fit in the {}x{} reference photo",
                        r.width, r.height
                    ),
                ));
            }
        }
    }
    let marker_corners_px = scene
        .markers
        .iter()
        .map(|m| {
            let c = m.corners.map(|c| {
                let p = ref_cam.project(Vec3::from(c)).unwrap_or_else(Vec2::zeros);
                [p.x, p.y]
            });
            (m.id, c)
        })
        .collect();
    progress.finish();

    // Flash video.
    let v = &cfg.video;
    let n_frames = (v.fps * v.duration_s).round().max(1.0) as u64;
    let sweep = Sweep::new(
        &cfg.sweep,
        v,
        0.5 * cfg.region_cm[0],
        0.5 * cfg.region_cm[1],
        cfg.seed,
    );
    let base_intr = Intrinsics::from_fov(v.width, v.height, v.fov_deg)?;
    let flash_offset = Vec3::from(cfg.light.flash_offset_cm);
    let camera_at = |t: f64| {
        let s = sweep.at(t);
        let mut intr = base_intr;
        intr.fx *= s.focal_scale;
        intr.fy *= s.focal_scale;
        Camera {
            intrinsics: intr,
            distortion: RadialDistortion { k1: s.k1, k2: v.k2 },
            pose: s.pose,
        }
    };
    let lighting = Lighting {
        intensity: cfg.light.flash_intensity,
        ambient: cfg.light.ambient,
        model: cfg.brdf,
    };
    let mut blur_rng = ChaCha8Rng::seed_from_u64(cfg.seed ^ 0xB1B1);
    let mut writer = if v.format == VideoFormat::H264Sdr8 && v.frame_jitter_s == 0.0 {
        FlashWriter::OpenCv(if v.bt709 {
            VideoWriter::create_bt709(&dir.join("flash.mp4"), v.fps, v.width, v.height)?
        } else {
            VideoWriter::create(&dir.join("flash.mp4"), v.fps, v.width, v.height)?
        })
    } else {
        FlashWriter::Ffmpeg(FfmpegWriter::create(
            &dir.join("flash.mp4"),
            v.fps,
            v.width,
            v.height,
            v.format,
            v.frame_jitter_s,
        )?)
    };
    let mut also_writers: Vec<FfmpegWriter> = also
        .iter()
        .map(|(f, st)| {
            FfmpegWriter::create(
                &st.path().join("flash.mp4"),
                v.fps,
                v.width,
                v.height,
                *f,
                v.frame_jitter_s,
            )
        })
        .collect::<Result<_, _>>()?;
    let mut flash_frames = Vec::with_capacity(n_frames as usize);
    let mut auto_exposure = AutoExposure::default();
    let wander_phase = (cfg.seed % 1000) as f64 * 0.618_034 * std::f64::consts::TAU;
    progress.stage("flash video", n_frames);
    for i in 0..n_frames {
        let t = i as f64 / v.fps + v.frame_jitter_s * (1.7 * i as f64).sin();
        let cam = camera_at(t);
        let blurred = blur_rng.random_bool(cfg.sweep.motion_blur_probability);
        let exposures: Vec<Exposure> = if blurred {
            let jerk = sweep.jerk(t);
            (0..6)
                .map(|k| {
                    let f = k as f64 / 5.0 - 0.5;
                    let mut c = camera_at(t + f / v.fps);
                    c.pose.centre += jerk * f;
                    Exposure {
                        camera: c,
                        light: Some(c.pose.camera_to_world(flash_offset)),
                        first_lit_row: 0,
                    }
                })
                .collect()
        } else {
            vec![Exposure {
                camera: cam,
                light: Some(cam.pose.camera_to_world(flash_offset)),
                first_lit_row: 0,
            }]
        };
        let mut lin = render_linear(&scene, &exposures, lighting, 1);
        let gain = match &v.auto_exposure {
            Some(ae) => {
                let wander =
                    ae.wander_ev * (std::f64::consts::TAU * t / v.duration_s + wander_phase).sin();
                let g = auto_exposure.step(ae, mean_level(&lin), wander, 1.0 / v.fps);
                for x in &mut lin.data {
                    *x *= g as f32;
                }
                g
            }
            None => 1.0,
        };
        match &mut writer {
            FlashWriter::OpenCv(w) => w.write(&expose(
                &lin,
                cfg.light.shot_noise,
                cfg.light.read_noise,
                cfg.seed,
                i,
            ))?,
            FlashWriter::Ffmpeg(w) => w.write(&expose_linear(
                &lin,
                cfg.light.shot_noise,
                cfg.light.read_noise,
                cfg.seed,
                i,
            ))?,
        }
        if !also_writers.is_empty() {
            let frame = expose_linear(
                &lin,
                cfg.light.shot_noise,
                cfg.light.read_noise,
                cfg.seed,
                i,
            );
            for w in &mut also_writers {
                w.write(&frame)?;
            }
        }
        flash_frames.push(FrameTruth {
            index: i,
            time_s: t,
            camera: cam_truth(&cam),
            light_position: Some(cam.pose.camera_to_world(flash_offset).into()),
            first_lit_row: None,
            motion_blur: blurred,
            markers_visible: visible_markers(&cam, &scene),
            exposure_gain: gain,
        });
        progress.advance(1);
    }
    let written = match writer {
        FlashWriter::OpenCv(w) => w.finish()?,
        FlashWriter::Ffmpeg(w) => w.finish()?,
    };
    for w in also_writers {
        w.finish()?;
    }
    progress.finish();
    files.push("flash.mp4".into());
    let mut streams = vec![StreamTruth {
        file: "flash.mp4".into(),
        flash: true,
        fps: v.fps,
        width: v.width,
        height: v.height,
        start_time_s: 0.0,
        flash_onset_frame: Some(0),
        frames: flash_frames,
    }];

    // Optional second, no-flash camera.
    if let Some(sc) = &cfg.second_camera {
        streams.push(render_second_camera(
            cfg,
            sc,
            &scene,
            &camera_at,
            flash_offset,
            lighting,
            &dir,
            progress,
        )?);
        files.push("second.mp4".into());
    }

    // Optional flash photos.
    let photos = match &cfg.photos {
        Some(ps) => {
            let t = render_photos(cfg, ps, &scene, lighting, &dir, progress)?;
            files.push("photos/".into());
            files.push("photos_camera.json".into());
            t
        }
        None => Vec::new(),
    };

    // Held-out relighting, rectified to the map grid.
    let holdout = render_holdout(cfg, &scene, region, &gt_dir.join("holdout"), progress)?;
    files.push("ground_truth/holdout/".into());

    // Camera description, truth, registered capture.
    let camdesc = CameraDescription {
        fov_deg: v.fov_deg,
        flash_offset_cm: cfg.light.flash_offset_cm,
        marker_size_cm: cfg.markers.size_cm,
        marker_dictionary: cfg.markers.dictionary.clone(),
        frame_step: cfg.frame_step,
        readout_s: 0.0,
    };
    write_json(&dir.join("camera.json"), &camdesc)?;
    files.push("camera.json".into());
    if let Some(sc) = &cfg.second_camera {
        // The second phone's own description: its lens, and the paper's frame step
        // for two-camera captures (every 10th) on captures of 10 s or more; a shorter
        // one uses every 5th, or a 3 s capture keeps 8 second-stream frames (measured
        // on the two-camera preset: relighting error 2.70 with 8 frames against 1.71
        // with 16, one camera 2.24). Its flash offset is unused (its flash is off).
        write_json(
            &dir.join("second_camera.json"),
            &CameraDescription {
                fov_deg: sc.fov_deg,
                frame_step: if cfg.video.duration_s < 10.0 { 5 } else { 10 },
                readout_s: sc.readout_s,
                ..camdesc.clone()
            },
        )?;
        files.push("second_camera.json".into());
    }
    let truth = GroundTruth {
        format: TRUTH_FORMAT.into(),
        version: 1,
        units: "cm".into(),
        config: cfg.clone(),
        region,
        light_intensity: cfg.light.flash_intensity,
        ambient: cfg.light.ambient,
        markers: scene
            .markers
            .iter()
            .map(|m| MarkerTruth {
                id: m.id,
                corners_cm: m.corners,
            })
            .collect(),
        reference: ReferenceTruth {
            file: "reference.jpg".into(),
            camera: cam_truth(&ref_cam),
            marker_corners_px,
        },
        streams,
        maps,
        holdout,
        photos,
    };
    write_json(&gt_dir.join("truth.json"), &truth)?;
    files.push("ground_truth/truth.json".into());
    let capture = registered_from_truth(&truth, cfg);
    let reg_dir = dir.join("registered");
    std::fs::create_dir_all(&reg_dir).map_err(|e| CoreError::io(&reg_dir, e))?;
    capture.save(&reg_dir)?;
    files.push("registered/capture.json".into());

    // The other formats: the same capture with another flash video.
    let mut also_written = Vec::new();
    for (f, st) in also {
        write_also(&dir, st.path(), &truth, cfg, f)?;
        also_written.push(st.commit()?);
    }

    let summary = SynthSummary {
        out: staging.commit()?,
        files,
        frames: written,
        frames_with_markers: truth.streams[0]
            .frames
            .iter()
            .filter(|f| !f.markers_visible.is_empty())
            .count() as u64,
        blurred_frames: truth.streams[0]
            .frames
            .iter()
            .filter(|f| f.motion_blur)
            .count() as u64,
        second_frames: truth.streams.get(1).map(|s| s.frames.len() as u64),
        also: also_written,
    };
    Ok(summary)
}

/// Where `out` stored in format `f` goes: `<out>.<format>` beside it.
pub fn also_path(out: &Path, f: VideoFormat) -> std::path::PathBuf {
    let name = out
        .file_name()
        .map_or_else(|| "capture".into(), |n| n.to_string_lossy().into_owned());
    out.with_file_name(format!("{name}.{}", f.name()))
}

/// Complete the capture folder `to` (whose `flash.mp4` is written) from the finished
/// one in `from`: the same reference photo, camera description and ground truth, the
/// truth's configuration and registered capture stated for format `f`.
fn write_also(
    from: &Path,
    to: &Path,
    truth: &GroundTruth,
    cfg: &SynthConfig,
    f: VideoFormat,
) -> Result<(), SynthError> {
    for name in ["reference.jpg", "camera.json"] {
        std::fs::copy(from.join(name), to.join(name))
            .map_err(|e| CoreError::io(to.join(name), e))?;
    }
    for sub in ["ground_truth/maps", "ground_truth/holdout"] {
        let (src, dst) = (from.join(sub), to.join(sub));
        std::fs::create_dir_all(&dst).map_err(|e| CoreError::io(&dst, e))?;
        for entry in std::fs::read_dir(&src).map_err(|e| CoreError::io(&src, e))? {
            let entry = entry.map_err(|e| CoreError::io(&src, e))?;
            let target = dst.join(entry.file_name());
            // A hard link where the file system allows (the maps of the paper preset
            // are hundreds of MB), else a copy.
            if std::fs::hard_link(entry.path(), &target).is_err() {
                std::fs::copy(entry.path(), &target).map_err(|e| CoreError::io(&target, e))?;
            }
        }
    }
    let mut cfg_f = cfg.clone();
    cfg_f.video.format = f;
    cfg_f.video.also_formats.clear();
    let mut truth_f = truth.clone();
    truth_f.config = cfg_f.clone();
    write_json(&to.join("ground_truth/truth.json"), &truth_f)?;
    let reg_dir = to.join("registered");
    std::fs::create_dir_all(&reg_dir).map_err(|e| CoreError::io(&reg_dir, e))?;
    registered_from_truth(&truth_f, &cfg_f).save(&reg_dir)?;
    Ok(())
}

/// The flash video's encoder.
enum FlashWriter {
    /// OpenCV's 8-bit H.264 (constant frame rate).
    OpenCv(VideoWriter),
    /// `ffmpeg` for 10-bit, HDR and variable frame timing.
    Ffmpeg(FfmpegWriter),
}

/// Mean linear level of a frame at gain 1 (what a phone's metering sees).
fn mean_level(img: &svbrdf_core::image::ImageF32) -> f64 {
    let n = img.data.len().max(1);
    img.data.iter().map(|v| f64::from(*v)).sum::<f64>() / n as f64
}

/// The state of a simulated auto-exposure loop.
#[derive(Debug, Default)]
struct AutoExposure {
    /// Current gain, log2 (EV); `None` before the first frame.
    ev: Option<f64>,
}

impl AutoExposure {
    /// The gain of the next frame, `dt` seconds after the last, when the sensor sees
    /// a mean level `metered` at gain 1: the gain moves towards `target / metered` with
    /// time constant `lag_s` (a phone's metering reacts to the frames it has seen),
    /// plus `wander` EV, clamped to +-`max_ev`. The first frame starts converged.
    fn step(&mut self, spec: &config::AutoExposureSpec, metered: f64, wander: f64, dt: f64) -> f64 {
        let want =
            ((spec.target / metered.max(1e-6)).log2() + wander).clamp(-spec.max_ev, spec.max_ev);
        let ev = match self.ev {
            None => want,
            Some(ev) if spec.lag_s > 0.0 => ev + (1.0 - (-dt / spec.lag_s).exp()) * (want - ev),
            Some(_) => want,
        };
        self.ev = Some(ev);
        ev.exp2()
    }
}

#[allow(clippy::too_many_arguments)]
fn render_second_camera(
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
fn render_photos(
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
            &out.join(truth::photo_file(u64::from(k))),
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

fn write_truth_maps(
    scene: &Scene,
    region: Region,
    px_per_cm: f64,
    model: ModelKind,
    dir: &Path,
) -> Result<MapFiles, SynthError> {
    let m = scene.material.crop(region)?;
    let grid = m.grid;
    let mut rough3 = ImageF32::new(grid.width, grid.height, 3);
    let mut normal01 = ImageF32::new(grid.width, grid.height, 3);
    let mut mask = ImageF32::new(grid.width, grid.height, 3);
    let rough_max = m
        .roughness
        .data
        .iter()
        .fold(0f32, |a, b| a.max(*b))
        .max(1e-6);
    for r in 0..grid.height {
        for c in 0..grid.width {
            let a = m.roughness.pixel(c, r);
            rough3.pixel_mut(c, r).copy_from_slice(&[a[0], a[1], 0.0]);
            let n = m.normal.pixel(c, r);
            normal01.pixel_mut(c, r).copy_from_slice(&[
                n[0] * 0.5 + 0.5,
                n[1] * 0.5 + 0.5,
                n[2] * 0.5 + 0.5,
            ]);
            mask.pixel_mut(c, r)[0] =
                f32::from(u8::from(scene.is_material(grid.pixel_centre(c, r))));
        }
    }
    let base = |map: &str, enc: Encoding, extra: &str| -> Vec<(&'static str, String)> {
        vec![
            ("map", map.to_string()),
            ("encoding", enc.as_str().to_string()),
            ("units", extra.to_string()),
            ("px_per_cm", px_per_cm.to_string()),
            (
                "region_cm",
                format!(
                    "{} {} {} {}",
                    region.x_min, region.x_max, region.y_min, region.y_max
                ),
            ),
            ("source", "svbrdf synth ground truth".to_string()),
        ]
    };
    let rgb = ["R", "G", "B"];
    write_exr(
        &dir.join("diffuse.exr"),
        &m.diffuse,
        &rgb,
        &base("diffuse_albedo", Encoding::Linear, "albedo, linear RGB"),
    )?;
    write_exr(
        &dir.join("specular.exr"),
        &m.specular,
        &rgb,
        &base("specular_albedo", Encoding::Linear, "albedo, linear RGB"),
    )?;
    write_exr(
        &dir.join("roughness.exr"),
        &rough3,
        &rgb,
        &base(
            "roughness",
            Encoding::Linear,
            match model {
                ModelKind::Ward => "R = alpha_x, G = alpha_y (Ward)",
                ModelKind::Ggx => "R = alpha_x, G = alpha_y (GGX)",
            },
        ),
    )?;
    write_exr(
        &dir.join("normal.exr"),
        &m.normal,
        &rgb,
        &base(
            "normal",
            Encoding::Linear,
            "tangent-space unit normal x y z, +y = plane +y (OpenGL)",
        ),
    )?;
    write_exr(
        &dir.join("mask.exr"),
        &mask,
        &rgb,
        &base(
            "material_mask",
            Encoding::Linear,
            "1 = material, 0 = marker paper",
        ),
    )?;
    // Previews: colours in sRGB, data maps linear.
    write_png(
        &dir.join("diffuse.png"),
        &m.diffuse,
        Encoding::Srgb,
        PngDepth::Eight,
        &base("diffuse_albedo", Encoding::Srgb, "albedo"),
    )?;
    write_png(
        &dir.join("specular.png"),
        &m.specular,
        Encoding::Srgb,
        PngDepth::Eight,
        &base("specular_albedo", Encoding::Srgb, "albedo"),
    )?;
    let mut rough_vis = rough3.clone();
    rough_vis.data.iter_mut().for_each(|v| *v /= rough_max);
    write_png(
        &dir.join("roughness.png"),
        &rough_vis,
        Encoding::Linear,
        PngDepth::Sixteen,
        &base(
            "roughness",
            Encoding::Linear,
            &format!("alpha / {rough_max}"),
        ),
    )?;
    write_png(
        &dir.join("normal.png"),
        &normal01,
        Encoding::Linear,
        PngDepth::Sixteen,
        &base("normal", Encoding::Linear, "0.5 * n + 0.5, OpenGL (+y up)"),
    )?;
    Ok(MapFiles {
        px_per_cm,
        diffuse: "maps/diffuse.exr".into(),
        specular: "maps/specular.exr".into(),
        roughness: "maps/roughness.exr".into(),
        normal: "maps/normal.exr".into(),
        mask: "maps/mask.exr".into(),
    })
}

fn render_holdout(
    cfg: &SynthConfig,
    scene: &Scene,
    region: Region,
    dir: &Path,
    progress: &dyn Progress,
) -> Result<Vec<HoldoutTruth>, SynthError> {
    let grid = PlaneGrid::new(region, cfg.map_px_per_cm)?;
    let cam = Vec3::from(cfg.holdout_camera_cm);
    let mut out = Vec::new();
    progress.stage("held-out relighting", cfg.holdout_lights_cm.len() as u64);
    for (k, light) in cfg.holdout_lights_cm.iter().enumerate() {
        let light_v = Vec3::from(*light);
        let mut img = ImageF32::new(grid.width, grid.height, 3);
        img.data
            .par_chunks_mut(grid.width * 3)
            .enumerate()
            .for_each(|(r, line)| {
                for c in 0..grid.width {
                    let p = grid.pixel_centre(c, r);
                    let (params, n) = scene.surface(p);
                    let obs = LightView::from_points(Vec3::new(p.x, p.y, 0.0), light_v, cam);
                    let l = cfg.brdf.model().radiance(
                        &Prepared::from_normal(params, n),
                        &obs,
                        cfg.light.flash_intensity,
                    );
                    for ch in 0..3 {
                        line[c * 3 + ch] = l[ch] as f32;
                    }
                }
            });
        let meta = vec![
            ("map", "holdout_relighting".to_string()),
            (
                "light_position_cm",
                format!("{} {} {}", light[0], light[1], light[2]),
            ),
            (
                "camera_position_cm",
                format!("{} {} {}", cam.x, cam.y, cam.z),
            ),
            (
                "units",
                "linear radiance, same scale as the video before sRGB encoding".to_string(),
            ),
        ];
        let exr = format!("holdout/light_{k:02}.exr");
        let png = format!("holdout/light_{k:02}.png");
        write_exr(
            &dir.join(format!("light_{k:02}.exr")),
            &img,
            &["R", "G", "B"],
            &meta,
        )?;
        write_png(
            &dir.join(format!("light_{k:02}.png")),
            &img,
            Encoding::Srgb,
            PngDepth::Eight,
            &meta,
        )?;
        out.push(HoldoutTruth {
            exr,
            png,
            light_position: *light,
            camera_position: cfg.holdout_camera_cm,
        });
        progress.advance(1);
    }
    progress.finish();
    Ok(out)
}

/// The ground truth as a registered capture: every `frame_step`-th frame of each stream
/// whose flash light is on, with its exact camera as a pinhole mapping. Frames rendered
/// with motion blur are left out, as the geometry stage's blur test (paper eq. 1)
/// leaves them out of an aligned capture: the ground truth stands for perfect
/// alignment, and on the paper preset its five blurred frames of 120 raised the fit's
/// diffuse error by 8% and its relighting error by a quarter.
pub fn registered_from_truth(truth: &GroundTruth, cfg: &SynthConfig) -> RegisteredCapture {
    let mut cap =
        RegisteredCapture::new("svbrdf synth ground truth", truth.region, cfg.map_px_per_cm);
    // In the decoder's linear units: an HDR video puts the simulator's white at the
    // format's reference white.
    let white = cfg.video.format.white();
    cap.light_intensity = Some([truth.light_intensity * white; 3]);
    let mut id = 0;
    for (s, stream) in truth.streams.iter().enumerate() {
        cap.sources.push(Source {
            video: None,
            kind: SourceKind::Video,
            path: format!("../{}", stream.file),
            encoding: Encoding::Srgb,
            stream: s as u32,
        });
        for f in stream.frames.iter().step_by(cfg.frame_step as usize) {
            let (Some(light), None | Some(0), false) =
                (f.light_position, f.first_lit_row, f.motion_blur)
            else {
                continue;
            };
            cap.frames.push(Frame {
                id,
                source: s,
                frame_index: Some(f.index),
                image: None,
                time_s: Some(f.time_s),
                width: stream.width,
                height: stream.height,
                mapping: FrameMapping::Pinhole {
                    intrinsics: f.camera.intrinsics,
                    distortion: f.camera.distortion,
                    rotation: f.camera.rotation,
                },
                camera_position: f.camera.position,
                light_position: light,
                exposure_gain: (f.exposure_gain != 1.0).then_some(f.exposure_gain),
            });
            id += 1;
        }
    }
    cap
}
