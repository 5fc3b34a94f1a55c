//! A small CPU renderer (rayon) for previews of fitted maps: the material on a sphere
//! under a directional light plus a sky, and on its own plane seen obliquely under a
//! point light. Shading uses the fitted model itself (Ward or GGX from the core), so a
//! preview shows exactly what was fitted, before any conversion for other renderers.
//! Output is linear RGB; callers encode it (sRGB PNG) for display.
use rayon::prelude::*;
use svbrdf_core::brdf::{BrdfParams, Prepared};
use svbrdf_core::geometry::Vec3;
use svbrdf_core::image::ImageF32;

use crate::MaterialMaps;

/// Sky directions for the environment term (a fixed Fibonacci set).
const SKY_DIRECTIONS: usize = 24;

fn texel(maps: &MaterialMaps, u: f64, v: f64) -> &BrdfParams {
    let (w, h) = (maps.grid.width, maps.grid.height);
    let c = ((u.rem_euclid(1.0) * w as f64) as usize).min(w - 1);
    let r = ((v.rem_euclid(1.0) * h as f64) as usize).min(h - 1);
    &maps.params[r * w + c]
}

/// Sky light as (direction, radiance x solid angle) samples, in a frame whose zenith
/// is `up`: brighter towards the zenith, dim below the horizon (a fixed Fibonacci set).
fn sky(up: Vec3, level: f64) -> Vec<(Vec3, f64)> {
    let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
    let w = 4.0 * std::f64::consts::PI / SKY_DIRECTIONS as f64;
    let (e1, e2) = {
        let a = if up.x.abs() < 0.9 {
            Vec3::x()
        } else {
            Vec3::y()
        };
        let e1 = up.cross(&a).normalize();
        (e1, up.cross(&e1))
    };
    (0..SKY_DIRECTIONS)
        .map(|i| {
            let h = 1.0 - 2.0 * (i as f64 + 0.5) / SKY_DIRECTIONS as f64;
            let r = (1.0 - h * h).sqrt();
            let phi = golden * i as f64;
            let d = up * h + e1 * (r * phi.cos()) + e2 * (r * phi.sin());
            let radiance = if h > 0.0 {
                level * (0.6 + 0.4 * h)
            } else {
                0.25 * level
            };
            (d, radiance * w)
        })
        .collect()
}

/// Radiance towards `view` of a surface point with local frame (t, b, n) lit by
/// directional lights and sky samples, each given as (unit direction, irradiance at
/// normal incidence).
fn shade(
    maps: &MaterialMaps,
    p: &BrdfParams,
    frame: [Vec3; 3],
    view: Vec3,
    lights: &[(Vec3, f64)],
) -> [f64; 3] {
    let [t, b, n] = frame;
    let local = |d: Vec3| Vec3::new(d.dot(&t), d.dot(&b), d.dot(&n));
    let prepared = Prepared::new(*p);
    let model = maps.model.model();
    let v = local(view);
    let mut out = [0.0; 3];
    if v.dot(&prepared.frame.n) <= 0.0 {
        return out;
    }
    for (d, e) in lights {
        let l = local(*d);
        let cos_i = l.dot(&prepared.frame.n);
        // Light from below the geometric surface is blocked even if the fitted normal
        // faces it.
        if cos_i <= 0.0 || l.z <= 0.0 {
            continue;
        }
        let f = model.brdf(&prepared, l, v);
        for c in 0..3 {
            out[c] += e * f[c] * cos_i;
        }
    }
    out
}

/// The material on a sphere of `size` x `size` pixels, seen from +z (orthographic),
/// textured at its physical scale (radius = half the smaller side of the maps'
/// region), lit by a directional light from `light` (world: +x right, +y up, +z towards
/// the viewer) and a sky. Pixels off the sphere are transparent black (alpha channel).
pub fn sphere(maps: &MaterialMaps, size: usize, light: Vec3) -> ImageF32 {
    let region = &maps.grid.region;
    let radius_cm = 0.5 * region.width().min(region.height());
    let u_tiles = std::f64::consts::TAU * radius_cm / region.width();
    let v_tiles = std::f64::consts::PI * radius_cm / region.height();
    let light = light.try_normalize(1e-12).unwrap_or_else(Vec3::z);
    let mut lights = vec![(light, 0.85 * std::f64::consts::PI)];
    lights.extend(sky(Vec3::y(), 0.12));
    let mut img = ImageF32::new(size, size, 4);
    img.data
        .par_chunks_mut(4 * size)
        .enumerate()
        .for_each(|(row, out)| {
            let y = 1.0 - 2.0 * (row as f64 + 0.5) / size as f64;
            for col in 0..size {
                let x = 2.0 * (col as f64 + 0.5) / size as f64 - 1.0;
                let r2 = x * x + y * y;
                if r2 >= 1.0 {
                    continue;
                }
                let n = Vec3::new(x, y, (1.0 - r2).sqrt());
                // East (growing u) and north (towards the top of the map).
                let t = Vec3::new(n.z, 0.0, -n.x)
                    .try_normalize(1e-9)
                    .unwrap_or_else(Vec3::x);
                let b = n.cross(&t);
                let u = n.x.atan2(n.z) / std::f64::consts::TAU + 0.5;
                let v = n.y.clamp(-1.0, 1.0).acos() / std::f64::consts::PI;
                let p = texel(maps, u * u_tiles, v * v_tiles);
                let rgb = shade(maps, p, [t, b, n], Vec3::z(), &lights);
                let o = &mut out[4 * col..4 * col + 4];
                for c in 0..3 {
                    o[c] = rgb[c] as f32;
                }
                o[3] = 1.0;
            }
        });
    img
}

/// The flat material seen obliquely (camera 50 degrees from the normal, from the -y
/// side) under a point light from the upper left, `width` pixels wide (3:2). Plane
/// frame (+z out of the surface, cm).
pub fn plane(maps: &MaterialMaps, width: usize) -> ImageF32 {
    let height = (width * 2).div_ceil(3);
    let region = &maps.grid.region;
    let c = Vec3::new(
        0.5 * (region.x_min + region.x_max),
        0.5 * (region.y_min + region.y_max),
        0.0,
    );
    let extent = region.width().max(region.height());
    let elev = 40f64.to_radians();
    let eye = c + Vec3::new(0.0, -elev.cos(), elev.sin()) * (1.15 * extent);
    let fwd = (c - eye).normalize();
    let right = fwd.cross(&Vec3::z()).normalize();
    let up = right.cross(&fwd);
    let tan_half = (35f64.to_radians()).tan();
    let light_pos = c + Vec3::new(-0.45 * extent, 0.25 * extent, 0.9 * extent);
    let r0 = (light_pos - c).norm();
    let intensity = 0.85 * std::f64::consts::PI * r0 * r0;
    let sky_light = sky(Vec3::z(), 0.12);
    let mut img = ImageF32::new(width, height, 4);
    img.data
        .par_chunks_mut(4 * width)
        .enumerate()
        .for_each(|(row, out)| {
            let sy = 1.0 - 2.0 * (row as f64 + 0.5) / height as f64;
            for col in 0..width {
                let sx = 2.0 * (col as f64 + 0.5) / width as f64 - 1.0;
                let dir = (fwd
                    + right * (sx * tan_half)
                    + up * (sy * tan_half * height as f64 / width as f64))
                    .normalize();
                if dir.z >= -1e-9 {
                    continue;
                }
                let s = -eye.z / dir.z;
                let hit = eye + dir * s;
                if hit.x < region.x_min
                    || hit.x > region.x_max
                    || hit.y < region.y_min
                    || hit.y > region.y_max
                {
                    continue;
                }
                let u = (hit.x - region.x_min) / region.width();
                let v = (region.y_max - hit.y) / region.height();
                let p = texel(maps, u.min(0.999_999), v.min(0.999_999));
                let to_light = light_pos - hit;
                let r2 = to_light.norm_squared();
                let mut lights = Vec::with_capacity(1 + sky_light.len());
                lights.push((to_light / r2.sqrt(), intensity / r2));
                lights.extend_from_slice(&sky_light);
                let frame = [Vec3::x(), Vec3::y(), Vec3::z()];
                let rgb = shade(maps, p, frame, -dir, &lights);
                let o = &mut out[4 * col..4 * col + 4];
                for k in 0..3 {
                    o[k] = rgb[k] as f32;
                }
                o[3] = 1.0;
            }
        });
    img
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::gltf::tests::checker;
    use svbrdf_core::brdf::ModelKind;

    #[test]
    fn sphere_is_lit_on_the_light_side_and_finite() {
        let maps = checker(ModelKind::Ward);
        let img = sphere(&maps, 64, Vec3::new(-1.0, 0.5, 1.0));
        assert!(img.data.iter().all(|v| v.is_finite()));
        let lum = |c: usize, r: usize| {
            let p = img.pixel(c, r);
            p[0] + p[1] + p[2]
        };
        // Left (towards the light) brighter than right; corners empty.
        assert!(lum(12, 32) > lum(52, 32), "{} {}", lum(12, 32), lum(52, 32));
        assert_eq!(img.pixel(0, 0)[3], 0.0);
        assert_eq!(img.pixel(32, 32)[3], 1.0);
    }

    #[test]
    fn plane_render_covers_the_material_and_is_finite() {
        let maps = checker(ModelKind::Ggx);
        let img = plane(&maps, 90);
        assert!(img.data.iter().all(|v| v.is_finite()));
        let covered = img.data.chunks_exact(4).filter(|p| p[3] > 0.0).count();
        assert!(covered > 90 * 60 / 10, "{covered}");
        assert!(img.data.chunks_exact(4).any(|p| p[0] > 0.05));
    }
}
