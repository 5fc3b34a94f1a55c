//! The ground truth written beside a capture: the true maps, held-out relighting
//! images, and the truth as a registered capture.

use std::path::Path;

use rayon::prelude::*;
use svbrdf_core::brdf::{LightView, ModelKind, Prepared};
use svbrdf_core::capture::{Frame, FrameMapping, RegisteredCapture, Source, SourceKind};
use svbrdf_core::geometry::Vec3;
use svbrdf_core::image::ImageF32;
use svbrdf_core::maps::{write_exr, write_png, Encoding, PngDepth};
use svbrdf_core::plane::{PlaneGrid, Region};

use crate::config::SynthConfig;
use crate::scene::Scene;
use crate::truth::*;
use crate::{Progress, SynthError};

pub(crate) fn write_truth_maps(
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
        .chunks_exact(3)
        .fold(0f32, |a, b| a.max(b[0]).max(b[1]))
        .max(1e-6);
    for r in 0..grid.height {
        for c in 0..grid.width {
            let a = m.roughness.pixel(c, r);
            rough3.pixel_mut(c, r).copy_from_slice(&[
                a[0],
                a[1],
                (f64::from(a[2]) / std::f64::consts::TAU) as f32,
            ]);
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
                ModelKind::Ward => {
                    "R = alpha_x, G = alpha_y (Ward), B = tangent rotation in turns (plane +x towards +y)"
                }
                ModelKind::Ggx => {
                    "R = alpha_x, G = alpha_y (GGX), B = tangent rotation in turns (plane +x towards +y)"
                }
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
    for px in rough_vis.data.chunks_exact_mut(3) {
        px[0] /= rough_max;
        px[1] /= rough_max;
    }
    write_png(
        &dir.join("roughness.png"),
        &rough_vis,
        Encoding::Linear,
        PngDepth::Sixteen,
        &base(
            "roughness",
            Encoding::Linear,
            &format!("R, G = alpha / {rough_max}; B = tangent rotation in turns"),
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

pub(crate) fn render_holdout(
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
