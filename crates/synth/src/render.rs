//! The camera simulator: ray-casts each pixel onto the plane, shades it with the Ward
//! model (or GGX, `SynthConfig::brdf`) under the flash (eq. 9) plus weak ambient
//! light, averages sub-exposures for motion blur, adds sensor noise and encodes.

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};
use rayon::prelude::*;
use svbrdf_core::brdf::{LightView, ModelKind, Prepared};
use svbrdf_core::color::Srgb8Encoder;
use svbrdf_core::geometry::{Camera, UndistortTable, Vec2, Vec3};
use svbrdf_core::image::{ImageF32, ImageU8};

use crate::scene::Scene;

/// One sub-exposure: where the camera was and where the flash was.
#[derive(Debug, Clone, Copy)]
pub struct Exposure {
    /// The camera.
    pub camera: Camera,
    /// Flash position (cm), if the flash lights the scene.
    pub light: Option<Vec3>,
    /// Rows at or below this index see the light (rolling shutter at flash onset);
    /// 0 means the whole frame.
    pub first_lit_row: usize,
}

/// Illumination settings shared by all pixels.
#[derive(Debug, Clone, Copy)]
pub struct Lighting {
    /// Flash intensity `I` (linear value * cm^2).
    pub intensity: f64,
    /// Ambient term: adds `ambient * rho_d`.
    pub ambient: f64,
    /// Reflectance model of the material.
    pub model: ModelKind,
}

/// Linear radiance seen through one pixel position by one exposure.
#[inline]
pub fn shade(
    scene: &Scene,
    e: &Exposure,
    table: &UndistortTable,
    lighting: Lighting,
    px: Vec2,
    row: usize,
) -> [f64; 3] {
    let q = table.undistort(e.camera.intrinsics.pixel_to_normalized(px));
    let dir = e.camera.pose.camera_dir_to_world(Vec3::new(q.x, q.y, 1.0));
    let Some(p) = svbrdf_core::geometry::ray_plane(e.camera.pose.centre, dir) else {
        return [0.0; 3];
    };
    let light = e.light.filter(|_| row >= e.first_lit_row);
    shade_point(scene, p, light, e.camera.pose.centre, lighting)
}

/// Linear radiance of plane point `p` towards `camera`: the room light, plus the flash
/// at `light` if it is lit.
#[inline]
pub fn shade_point(
    scene: &Scene,
    p: Vec2,
    light: Option<Vec3>,
    camera: Vec3,
    lighting: Lighting,
) -> [f64; 3] {
    let (params, n) = scene.surface(p);
    let surf = Vec3::new(p.x, p.y, 0.0);
    let mut out = params.rho_d.map(|d| lighting.ambient * d);
    if let Some(light) = light {
        let prep = Prepared::for_evaluation(params, n);
        let obs = LightView::from_points(surf, light, camera);
        let l = lighting
            .model
            .model()
            .radiance(&prep, &obs, lighting.intensity);
        for c in 0..3 {
            out[c] += l[c];
        }
    }
    out
}

/// Render the mean of several exposures (all with the same image size) in linear
/// units, with `ss x ss` samples per pixel.
pub fn render_linear(
    scene: &Scene,
    exposures: &[Exposure],
    lighting: Lighting,
    ss: u32,
) -> ImageF32 {
    let intr = exposures[0].camera.intrinsics;
    let (w, h) = (intr.width as usize, intr.height as usize);
    let mut img = ImageF32::new(w, h, 3);
    let tables: Vec<UndistortTable> = exposures
        .iter()
        .map(|e| UndistortTable::for_image(&e.camera.distortion, &e.camera.intrinsics))
        .collect();
    // A generous pixel footprint on the plane, to find pixels near marker edges.
    let footprint: Vec<f64> = exposures
        .iter()
        .map(|e| 3.0 * e.camera.pose.centre.z.abs() / e.camera.intrinsics.fx)
        .collect();
    img.data
        .par_chunks_mut(w * 3)
        .enumerate()
        .for_each(|(row, line)| {
            for col in 0..w {
                let mut acc = [0.0; 3];
                for ((e, table), fp) in exposures.iter().zip(&tables).zip(&footprint) {
                    // Sensors integrate over the pixel area. Marker edges carry the
                    // world scale (via their detected corners), so pixels near them
                    // get at least 6 x 6 jittered samples; elsewhere `ss` per axis.
                    let centre = Vec2::new(col as f64, row as f64);
                    // The frame's undistortion table, not Newton steps: this runs per pixel.
                    let near = ss > 1 || {
                        let q = table.undistort(e.camera.intrinsics.pixel_to_normalized(centre));
                        let dir = e.camera.pose.camera_dir_to_world(Vec3::new(q.x, q.y, 1.0));
                        svbrdf_core::geometry::ray_plane(e.camera.pose.centre, dir)
                            .is_some_and(|p| scene.near_marker(p, *fp))
                    };
                    let n = if near { ss.max(6) } else { 1 };
                    let mut sub = [0.0; 3];
                    for sy in 0..n {
                        for sx in 0..n {
                            let (jx, jy) = if n > 1 {
                                jitter(col, row, sx, sy)
                            } else {
                                (0.5, 0.5)
                            };
                            let px = Vec2::new(
                                col as f64 + (f64::from(sx) + jx) / f64::from(n) - 0.5,
                                row as f64 + (f64::from(sy) + jy) / f64::from(n) - 0.5,
                            );
                            let v = shade(scene, e, table, lighting, px, row);
                            for c in 0..3 {
                                sub[c] += v[c];
                            }
                        }
                    }
                    for c in 0..3 {
                        acc[c] += sub[c] / f64::from(n * n);
                    }
                }
                for c in 0..3 {
                    line[col * 3 + c] = (acc[c] / exposures.len() as f64) as f32;
                }
            }
        });
    img
}

/// Deterministic jitter in [0, 1)^2 for stratified supersampling: regular sub-sample
/// grids quantise edge positions to 1/n pixel, which biases detected corners.
#[inline]
fn jitter(col: usize, row: usize, sx: u32, sy: u32) -> (f64, f64) {
    let mut h = (col as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15)
        ^ (row as u64).wrapping_mul(0xC2B2_AE3D_27D4_EB4F);
    h ^= (u64::from(sx) << 32 | u64::from(sy)).wrapping_mul(0x1656_67B1_9E37_79F9);
    h ^= h >> 29;
    h = h.wrapping_mul(0xBF58_476D_1CE4_E5B9);
    h ^= h >> 32;
    (
        (h & 0xFFFF_FFFF) as f64 / 4_294_967_296.0,
        (h >> 32) as f64 / 4_294_967_296.0,
    )
}

/// Sensor model: Gaussian noise with variance `shot * value + read^2`, then clipping
/// and 8-bit sRGB encoding. Deterministic for `(seed, frame)`.
pub fn expose(img: &ImageF32, shot: f64, read: f64, seed: u64, frame: u64) -> ImageU8 {
    let enc = Srgb8Encoder::new();
    let mut out = ImageU8::new(img.width, img.height, 3);
    noisy(img, &mut out.data, shot, read, seed, frame, |v| {
        enc.encode(v)
    });
    out
}

/// The same sensor noise as [`expose`] (the same draws), kept linear (negative values
/// clamped to 0) for encoders of more than 8 bits.
pub fn expose_linear(img: &ImageF32, shot: f64, read: f64, seed: u64, frame: u64) -> ImageF32 {
    let mut out = ImageF32::new(img.width, img.height, 3);
    noisy(img, &mut out.data, shot, read, seed, frame, |v| {
        v.max(0.0) as f32
    });
    out
}

/// Add the sensor's noise to every value of `img` and store `code(noisy value)`.
fn noisy<T: Send>(
    img: &ImageF32,
    out: &mut [T],
    shot: f64,
    read: f64,
    seed: u64,
    frame: u64,
    code: impl Fn(f64) -> T + Sync,
) {
    let w = img.width;
    out.par_chunks_mut(w * 3)
        .enumerate()
        .for_each(|(row, line)| {
            let mut rng = ChaCha8Rng::seed_from_u64(
                seed ^ frame.wrapping_mul(0x9E37_79B9) ^ ((row as u64) << 40),
            );
            for (o, v) in line.iter_mut().zip(img.row(row)) {
                let v = f64::from(*v);
                let sigma = (shot * v.max(0.0) + read * read).sqrt();
                let z: f64 = StandardNormal.sample(&mut rng);
                *o = code(v + sigma * z);
            }
        });
}
