//! Flash photos in the MaterialGAN / svbrdf-diff-renderer layout (what `svbrdf import`
//! reads): a few photos of a small patch of the material, already rectified onto the
//! plane, each lit by a flash at (or next to) its camera, 16-19 cm above the surface.
//! This is the capture format of the public real sets (cards-blue in `../shared`, and
//! the glass-mosaic set on which the full fit once lost to a diffuse-only one), so the
//! held-out comparison (`svbrdf eval --baseline`) can be run on any material of the
//! simulator with its truth beside it.
//!
//! Layout written (see `docs/CONVENTIONS.md`, "Imported image sets"):
//! ```text
//! OUT/00.png ... NN.png          8-bit sRGB photos; pixel (i, j) is plane point
//!                                (-w/2 + (i + 0.5) w / W, w/2 - (j + 0.5) w / W)
//! OUT/camera_pos.txt             x,y,z per photo, cm
//! OUT/light_pos.txt              the flash's x,y,z per photo, cm
//! OUT/image_size.txt             w, the photos' width in cm
//! OUT/light_power.txt            the flash intensity I of eq. (9), r,g,b
//! OUT/ground_truth/maps/         the patch's true maps (linear EXR + PNG previews)
//! OUT/ground_truth/materialgan.json   settings, cameras and lights
//! ```

use std::path::Path;

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use svbrdf_core::fsutil::{write_json, StagingDir};
use svbrdf_core::geometry::{Vec2, Vec3};
use svbrdf_core::image::ImageF32;
use svbrdf_core::maps::{write_png_u8, Encoding};
use svbrdf_core::plane::{PlaneGrid, Region};
use svbrdf_core::CoreError;

use crate::config::SynthConfig;
use crate::render::{expose, shade_point, Lighting};
use crate::scene::Scene;
use crate::{Progress, SynthError};

/// Settings of a MaterialGAN-layout photo set.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MaterialGanSpec {
    /// Number of photos (2-100).
    pub photos: u32,
    /// Width and height of every photo, pixels (square, as the format has them).
    pub size_px: u32,
    /// Width of the patch the photos show, cm (cards-blue: 6.848).
    pub width_cm: f64,
    /// Lowest and highest camera height above the plane, cm (cards-blue: 16.4-18.8).
    pub distance_cm: [f64; 2],
    /// Camera positions are drawn within this distance of the patch centre along x
    /// and y, cm (cards-blue: within 3 cm).
    pub spread_cm: f64,
    /// Flash position relative to the camera, cm, in the plane's axes (0: collocated,
    /// as the format assumes; `light_pos.txt` records where it really was).
    pub flash_offset_cm: [f64; 3],
    /// Samples per pixel along each axis (box filter over the pixel).
    pub supersample: u32,
}

impl Default for MaterialGanSpec {
    fn default() -> Self {
        Self {
            photos: 9,
            size_px: 512,
            width_cm: 6.848,
            distance_cm: [16.0, 19.0],
            spread_cm: 3.0,
            flash_offset_cm: [0.0; 3],
            supersample: 2,
        }
    }
}

impl MaterialGanSpec {
    /// Check every setting; one line per problem, naming the value and what was expected.
    pub fn validate(&self) -> Result<(), SynthError> {
        if !(2..=100).contains(&self.photos) {
            return Err(SynthError::invalid("photo count", self.photos, "2 to 100"));
        }
        if !(16..=4096).contains(&self.size_px) {
            return Err(SynthError::invalid(
                "photo size",
                format!("{} px", self.size_px),
                "16 to 4096 px",
            ));
        }
        if !(self.width_cm > 0.0 && self.width_cm <= 50.0) {
            return Err(SynthError::invalid(
                "patch width",
                format!("{} cm", self.width_cm),
                "in (0, 50] cm",
            ));
        }
        let [lo, hi] = self.distance_cm;
        if !(lo > 0.0 && hi >= lo && hi.is_finite()) {
            return Err(SynthError::invalid(
                "camera heights",
                format!("{lo}-{hi} cm"),
                "0 < lowest <= highest",
            ));
        }
        if !(self.spread_cm >= 0.0 && self.spread_cm.is_finite()) {
            return Err(SynthError::invalid(
                "camera spread",
                format!("{} cm", self.spread_cm),
                ">= 0 cm",
            ));
        }
        if self.flash_offset_cm.iter().any(|v| !v.is_finite()) {
            return Err(SynthError::invalid(
                "flash offset",
                format!("{:?} cm", self.flash_offset_cm),
                "finite numbers",
            ));
        }
        if !(1..=8).contains(&self.supersample) {
            return Err(SynthError::invalid(
                "supersampling",
                self.supersample,
                "1 to 8",
            ));
        }
        Ok(())
    }
}

/// `OUT/ground_truth/materialgan.json`.
#[derive(Debug, Clone, Serialize)]
struct MaterialGanTruth<'a> {
    format: &'static str,
    version: u32,
    units: &'static str,
    /// The photos' colour encoding.
    encoding: &'static str,
    spec: &'a MaterialGanSpec,
    config: &'a SynthConfig,
    px_per_cm: f64,
    light_intensity: f64,
    cameras_cm: Vec<[f64; 3]>,
    lights_cm: Vec<[f64; 3]>,
    maps: crate::truth::MapFiles,
}

/// What [`synthesize_materialgan`] wrote.
#[derive(Debug, Clone)]
pub struct MaterialGanSummary {
    /// The output folder.
    pub out: std::path::PathBuf,
    /// Files written, relative to `out`.
    pub files: Vec<String>,
    /// Share of all photo pixels with a clipped channel (the flash highlights).
    pub clipped_share: f64,
}

/// Camera positions of the photos: the first above the patch centre's neighbourhood,
/// the rest spread uniformly; deterministic for the seed.
fn cameras(spec: &MaterialGanSpec, seed: u64) -> Vec<Vec3> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x4D47_414E);
    let s = spec.spread_cm;
    let [lo, hi] = spec.distance_cm;
    (0..spec.photos)
        .map(|k| {
            let r = if k == 0 { 0.3 * s } else { s };
            Vec3::new(
                rng.random_range(-r..=r),
                rng.random_range(-r..=r),
                rng.random_range(lo..=hi),
            )
        })
        .collect()
}

/// Linear radiance of the patch seen from `camera` under the flash at `light`, on the
/// photo grid, `ss x ss` samples per pixel (box filter), plus the room light of `cfg`.
fn render_photo(
    cfg: &SynthConfig,
    scene: &Scene,
    grid: &PlaneGrid,
    ss: u32,
    camera: Vec3,
    light: Vec3,
) -> ImageF32 {
    let lighting = Lighting {
        intensity: cfg.light.flash_intensity,
        ambient: cfg.light.ambient,
        model: cfg.brdf,
    };
    let step = 1.0 / (grid.px_per_cm * f64::from(ss));
    let offset = |i: u32| (f64::from(i) + 0.5 - 0.5 * f64::from(ss)) * step;
    let n = f64::from(ss * ss);
    let mut img = ImageF32::new(grid.width, grid.height, 3);
    img.data
        .par_chunks_mut(grid.width * 3)
        .enumerate()
        .for_each(|(r, line)| {
            for c in 0..grid.width {
                let centre = grid.pixel_centre(c, r);
                let mut acc = [0.0f64; 3];
                for sy in 0..ss {
                    for sx in 0..ss {
                        let p = Vec2::new(centre.x + offset(sx), centre.y - offset(sy));
                        let l = shade_point(scene, p, Some(light), camera, lighting);
                        for k in 0..3 {
                            acc[k] += l[k];
                        }
                    }
                }
                for k in 0..3 {
                    line[c * 3 + k] = (acc[k] / n) as f32;
                }
            }
        });
    img
}

fn write_text(path: &Path, text: &str) -> Result<(), SynthError> {
    std::fs::write(path, text).map_err(|e| SynthError::Core(CoreError::io(path, e)))
}

fn triple(v: Vec3) -> String {
    format!("{:.4},{:.4},{:.4}\n", v.x, v.y, v.z)
}

/// Render a MaterialGAN-layout photo set of `cfg`'s material (its seed, model, flash
/// intensity, room light and sensor noise) into `out`, through a staging folder so an
/// interrupted run leaves nothing that looks complete.
pub fn synthesize_materialgan(
    cfg: &SynthConfig,
    spec: &MaterialGanSpec,
    out: &Path,
    overwrite: bool,
    progress: &dyn Progress,
) -> Result<MaterialGanSummary, SynthError> {
    cfg.validate()?;
    spec.validate()?;
    let inputs: Vec<std::path::PathBuf> = match &cfg.material {
        crate::MaterialSource::Maps(p) => vec![p.clone()],
        crate::MaterialSource::Procedural(_) => Vec::new(),
    };
    let staging = StagingDir::new(out, overwrite, &inputs)?;
    let dir = staging.path().to_path_buf();
    let region = Region::centred(spec.width_cm, spec.width_cm);
    let px_per_cm = f64::from(spec.size_px) / spec.width_cm;
    // The material is rasterised at the photos' sampling density, so every sample of
    // the box filter reads its own texel.
    progress.stage("material", 1);
    let scene = crate::build_scene(cfg, region, px_per_cm * f64::from(spec.supersample))?;
    progress.finish();
    let grid = PlaneGrid::new(region, px_per_cm)?;
    let mut files = Vec::new();
    let cams = cameras(spec, cfg.seed);
    let offset = Vec3::from(spec.flash_offset_cm);
    let lights: Vec<Vec3> = cams.iter().map(|c| c + offset).collect();
    let (mut clipped, mut total) = (0u64, 0u64);
    progress.stage("photos (MaterialGAN layout)", u64::from(spec.photos));
    for (k, (cam, light)) in cams.iter().zip(&lights).enumerate() {
        let lin = render_photo(cfg, &scene, &grid, spec.supersample, *cam, *light);
        let img = expose(
            &lin,
            cfg.light.shot_noise,
            cfg.light.read_noise,
            cfg.seed ^ 0x4D47,
            k as u64,
        );
        clipped += img
            .data
            .chunks_exact(3)
            .filter(|p| p.contains(&255))
            .count() as u64;
        total += (img.width * img.height) as u64;
        let name = format!("{k:02}.png");
        write_png_u8(
            &dir.join(&name),
            &img,
            Encoding::Srgb,
            &[
                ("synthetic", "svbrdf synth --materialgan".to_string()),
                ("encoding", "srgb".to_string()),
            ],
        )?;
        files.push(name);
        progress.advance(1);
    }
    progress.finish();
    let lines = |v: &[Vec3]| v.iter().map(|p| triple(*p)).collect::<String>();
    write_text(&dir.join("camera_pos.txt"), &lines(&cams))?;
    write_text(&dir.join("light_pos.txt"), &lines(&lights))?;
    write_text(
        &dir.join("image_size.txt"),
        &format!("{:.4}\n", spec.width_cm),
    )?;
    let i = cfg.light.flash_intensity;
    write_text(
        &dir.join("light_power.txt"),
        &format!("{i:.4},{i:.4},{i:.4}\n"),
    )?;
    files.extend(
        [
            "camera_pos.txt",
            "light_pos.txt",
            "image_size.txt",
            "light_power.txt",
        ]
        .map(String::from),
    );
    progress.stage("ground-truth maps", 1);
    let gt = dir.join("ground_truth");
    let maps = crate::truth_out::write_truth_maps(
        &scene,
        region,
        px_per_cm * f64::from(spec.supersample),
        cfg.brdf,
        &gt.join("maps"),
    )?;
    write_json(
        &gt.join("materialgan.json"),
        &MaterialGanTruth {
            format: "svbrdf-synth-materialgan",
            version: 1,
            units: "cm",
            encoding: "photos: 8-bit sRGB; maps: see their own metadata (linear EXR)",
            spec,
            config: cfg,
            px_per_cm,
            light_intensity: i,
            cameras_cm: cams.iter().map(|c| (*c).into()).collect(),
            lights_cm: lights.iter().map(|c| (*c).into()).collect(),
            maps,
        },
    )?;
    files.push("ground_truth/".into());
    progress.finish();
    staging.commit()?;
    Ok(MaterialGanSummary {
        out: out.to_path_buf(),
        files,
        clipped_share: clipped as f64 / total.max(1) as f64,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn invalid_settings_are_refused_with_the_value() {
        let bad = MaterialGanSpec {
            photos: 1,
            ..Default::default()
        };
        let e = bad.validate().unwrap_err().to_string();
        assert!(e.contains('1') && e.contains("2 to 100"), "{e}");
        let bad = MaterialGanSpec {
            distance_cm: [18.0, 16.0],
            ..Default::default()
        };
        assert!(bad.validate().is_err());
        assert!(MaterialGanSpec::default().validate().is_ok());
    }

    #[test]
    fn cameras_lie_within_the_spread_and_heights() {
        let spec = MaterialGanSpec::default();
        let c = cameras(&spec, 3);
        assert_eq!(c.len(), 9);
        for p in &c {
            assert!(p.x.abs() <= 3.0 && p.y.abs() <= 3.0, "{p:?}");
            assert!((16.0..=19.0).contains(&p.z), "{p:?}");
        }
        assert_eq!(c, cameras(&spec, 3), "deterministic for a seed");
        assert_ne!(c, cameras(&spec, 4));
    }
}
