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

mod cameras;
pub mod config;
pub mod material;
pub mod materialgan;
mod noise;
mod presets;
pub mod render;
pub mod scene;
pub mod trajectory;
pub mod truth;
mod truth_out;

use std::path::{Path, PathBuf};

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use svbrdf_core::fsutil::{write_json, StagingDir};
use svbrdf_core::geometry::{
    mat3_to_rows, rot_x, rot_z, Camera, Intrinsics, Mat3, Pose, RadialDistortion, Vec2, Vec3,
};
use svbrdf_core::plane::{PlaneGrid, Region};
use svbrdf_core::CoreError;
use svbrdf_cv::aruco::{marker_pattern, Dictionary};
use svbrdf_cv::encode::{FfmpegWriter, VideoFormat};
use svbrdf_cv::video::VideoWriter;
use svbrdf_cv::CvError;

use cameras::{render_photos, render_second_camera};
pub use config::{MaterialSource, SynthConfig};
use material::MaterialMaps;
pub use materialgan::{synthesize_materialgan, MaterialGanSpec, MaterialGanSummary};
use render::{expose, expose_linear, render_linear, Exposure, Lighting};
use scene::Scene;
use trajectory::Sweep;
use truth::*;
pub use truth_out::registered_from_truth;
use truth_out::{render_holdout, write_truth_maps};

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

/// The scene of `cfg` (its material, rasterised at `map_px_per_cm` over `region` and
/// the markers' surroundings, and the four markers at the region's corners).
pub(crate) fn build_scene(
    cfg: &SynthConfig,
    region: Region,
    map_px_per_cm: f64,
) -> Result<Scene, SynthError> {
    let dict = Dictionary::from_name(&cfg.markers.dictionary)?;
    // A whole number of texels, so the ground-truth crop shares the render raster exactly.
    let margin = ((cfg.markers.size_cm + cfg.markers.paper_margin_cm + 2.0) * map_px_per_cm).ceil()
        / map_px_per_cm;
    let grid = PlaneGrid::new(region.expanded(margin), map_px_per_cm)?;
    let material = match &cfg.material {
        MaterialSource::Procedural(name) => MaterialMaps::procedural(
            name,
            grid,
            cfg.feature_cm,
            cfg.grain_angle_deg.to_radians(),
            cfg.seed,
        )?,
        MaterialSource::Maps(path) => MaterialMaps::from_folder(path, grid, region)?,
    };
    let patterns = cfg
        .markers
        .ids
        .iter()
        .map(|&id| marker_pattern(dict, id).map(|p| (id, p.cells, p.white)))
        .collect::<Result<Vec<_>, _>>()?;
    Ok(Scene::new(
        material,
        region,
        patterns,
        cfg.markers.size_cm,
        cfg.markers.paper_margin_cm,
        cfg.seed,
    ))
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

    // Material, rasterised over the region and the markers' surroundings.
    progress.stage("material", 1);
    let scene = build_scene(cfg, region, cfg.map_px_per_cm)?;
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
