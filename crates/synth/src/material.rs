//! Ground-truth material maps: procedural presets or maps loaded from image files,
//! rasterised on a plane grid and sampled bilinearly by the renderer.

use std::path::Path;

use rayon::prelude::*;
use svbrdf_core::brdf::BrdfParams;
use svbrdf_core::geometry::{Vec2, Vec3};
use svbrdf_core::image::ImageF32;
use svbrdf_core::maps::{read_image_linear, Encoding};
use svbrdf_core::plane::{PlaneGrid, Region};

use crate::noise::{fbm, value, voronoi};
use crate::SynthError;

/// svBRDF maps on a plane grid. Colours are linear RGB; `normal` is the tangent-space
/// unit normal (x along plane +x, y along plane +y, z out of the surface).
#[derive(Debug, Clone)]
pub struct MaterialMaps {
    /// The grid the maps cover.
    pub grid: PlaneGrid,
    /// Diffuse albedo rho_d, linear RGB.
    pub diffuse: ImageF32,
    /// Specular albedo rho_s, linear RGB.
    pub specular: ImageF32,
    /// Roughness (alpha_x, alpha_y) and the tangent rotation, radians
    /// ([`BrdfParams::tangent_rotation`]).
    pub roughness: ImageF32,
    /// Unit normal (x, y, z).
    pub normal: ImageF32,
    /// All of the above interleaved per texel (rho_d, rho_s, alpha, rotation, normal:
    /// 12 values), so the renderer computes bilinear weights once per sample.
    packed: Vec<[f32; PACKED]>,
}

/// Values per texel in [`MaterialMaps::packed`].
const PACKED: usize = 12;

/// One texel before normals are derived.
#[derive(Debug, Clone, Copy)]
struct Texel {
    rho_d: [f64; 3],
    rho_s: [f64; 3],
    alpha: [f64; 2],
    height_cm: f64,
    /// Extra surface slope (dh/dx, dh/dy) on top of the height field's: facets tilt
    /// without the height steps at their borders that a tilted height field would need.
    slope: [f64; 2],
}

/// A base material of the procedural presets.
#[derive(Debug, Clone, Copy)]
struct Base {
    rho_d: [f64; 3],
    rho_s: [f64; 3],
    alpha: [f64; 2],
}

const LEATHER: Base = Base {
    rho_d: [0.30, 0.05, 0.04],
    rho_s: [0.06; 3],
    alpha: [0.22, 0.22],
};
const BRUSHED: Base = Base {
    rho_d: [0.06, 0.06, 0.06],
    rho_s: [0.50, 0.50, 0.50],
    alpha: [0.08, 0.22],
};
const FABRIC: Base = Base {
    rho_d: [0.04, 0.08, 0.30],
    rho_s: [0.03; 3],
    alpha: [0.35, 0.25],
};
const GOLD: Base = Base {
    rho_d: [0.10, 0.07, 0.02],
    rho_s: [0.60, 0.45, 0.16],
    alpha: [0.16, 0.16],
};
const PAINT: Base = Base {
    rho_d: [0.70, 0.68, 0.62],
    rho_s: [0.12; 3],
    alpha: [0.12, 0.12],
};
const GROUT: Base = Base {
    rho_d: [0.15, 0.14, 0.12],
    rho_s: [0.02; 3],
    alpha: [0.5, 0.5],
};

impl MaterialMaps {
    /// Rasterise a built-in material over `grid`. `feature_cm` is its smallest detail;
    /// the pattern and its anisotropy are turned by `grain_angle` radians about the
    /// normal (counter-clockwise seen from above).
    pub fn procedural(
        name: &str,
        grid: PlaneGrid,
        feature_cm: f64,
        grain_angle: f64,
        seed: u64,
    ) -> Result<Self, SynthError> {
        let f = feature_cm;
        let cell = (grid.region.width().min(grid.region.height()) / 4.0).clamp(1.0, 3.0);
        let texel = |x: f64, y: f64| -> Texel {
            match name {
                "leather" => leather(seed, x, y, f),
                "brushed-metal" => brushed(seed, x, y, f),
                "tiles" => tiles(seed, x, y, f, cell),
                "bathroom-tiles" => bathroom_tiles(seed, x, y, f),
                "facets" => facets(seed, x, y, f, cell),
                _ => patchwork(seed, x, y, f, cell),
            }
        };
        if !crate::config::MATERIALS.contains(&name) {
            return Err(SynthError::invalid(
                "material",
                format!("{name:?}"),
                crate::config::MATERIALS.join(", "),
            ));
        }
        let (s_a, c_a) = grain_angle.sin_cos();
        let texels: Vec<Texel> = (0..grid.height)
            .into_par_iter()
            .flat_map_iter(|r| (0..grid.width).map(move |c| (c, r)).collect::<Vec<_>>())
            .map(|(c, r)| {
                let p = grid.pixel_centre(c, r);
                // The pattern's own coordinates: the plane point turned back.
                let (u, v) = (c_a * p.x + s_a * p.y, -s_a * p.x + c_a * p.y);
                let mut t = texel(u, v);
                // Its slope was along the pattern's axes: turn it with the pattern.
                let [sx, sy] = t.slope;
                t.slope = [c_a * sx - s_a * sy, s_a * sx + c_a * sy];
                t
            })
            .collect();
        Ok(Self::from_texels(grid, &texels, grain_angle))
    }

    /// Maps of `texels` (row-major over `grid`), every texel's tangent turned by
    /// `rotation` radians.
    fn from_texels(grid: PlaneGrid, texels: &[Texel], rotation: f64) -> Self {
        let (w, h) = (grid.width, grid.height);
        let mut diffuse = ImageF32::new(w, h, 3);
        let mut specular = ImageF32::new(w, h, 3);
        let mut roughness = ImageF32::new(w, h, 3);
        let mut normal = ImageF32::new(w, h, 3);
        let step = 1.0 / grid.px_per_cm;
        for r in 0..h {
            for c in 0..w {
                let t = &texels[r * w + c];
                for k in 0..3 {
                    // Clamp in f32, the stored precision, so rho_d + rho_s <= 1 holds
                    // exactly for the stored values.
                    let d = (t.rho_d[k] as f32).clamp(0.0, 0.95);
                    diffuse.pixel_mut(c, r)[k] = d;
                    specular.pixel_mut(c, r)[k] = (t.rho_s[k] as f32).clamp(0.0, 1.0 - d);
                }
                roughness.pixel_mut(c, r).copy_from_slice(&[
                    t.alpha[0] as f32,
                    t.alpha[1] as f32,
                    rotation as f32,
                ]);
                // Central differences of the height field; +y is towards row 0.
                let hx = |cc: usize| texels[r * w + cc].height_cm;
                let hy = |rr: usize| texels[rr * w + c].height_cm;
                let (c0, c1) = (c.saturating_sub(1), (c + 1).min(w - 1));
                let (r0, r1) = (r.saturating_sub(1), (r + 1).min(h - 1));
                let dhdx = (hx(c1) - hx(c0)) / (step * (c1 - c0).max(1) as f64) + t.slope[0];
                let dhdy = (hy(r0) - hy(r1)) / (step * (r1 - r0).max(1) as f64) + t.slope[1];
                let n = Vec3::new(-dhdx, -dhdy, 1.0).normalize();
                normal
                    .pixel_mut(c, r)
                    .copy_from_slice(&[n.x as f32, n.y as f32, n.z as f32]);
            }
        }
        Self::assemble(grid, diffuse, specular, roughness, normal)
    }

    fn assemble(
        grid: PlaneGrid,
        diffuse: ImageF32,
        specular: ImageF32,
        roughness: ImageF32,
        normal: ImageF32,
    ) -> Self {
        let packed = (0..grid.len())
            .map(|i| {
                let mut t = [0f32; PACKED];
                t[0..3].copy_from_slice(&diffuse.data[3 * i..3 * i + 3]);
                t[3..6].copy_from_slice(&specular.data[3 * i..3 * i + 3]);
                t[6..9].copy_from_slice(&roughness.data[3 * i..3 * i + 3]);
                t[9..12].copy_from_slice(&normal.data[3 * i..3 * i + 3]);
                t
            })
            .collect();
        Self {
            grid,
            diffuse,
            specular,
            roughness,
            normal,
            packed,
        }
    }

    /// Load maps from a folder: `diffuse`, and optionally `specular`, `roughness`,
    /// `normal`, each `.png`, `.jpg` or `.exr`. PNG/JPEG colour maps are sRGB; roughness
    /// (R = alpha_x, G = alpha_y) and normal maps (OpenGL convention, `0.5 * n + 0.5`)
    /// are linear; EXR files are linear with normals stored as they are. Images are
    /// stretched over the grid's region; outside it they are mirrored.
    pub fn from_folder(dir: &Path, grid: PlaneGrid, region: Region) -> Result<Self, SynthError> {
        let find = |stem: &str| -> Option<std::path::PathBuf> {
            ["png", "exr", "jpg", "jpeg"]
                .iter()
                .map(|e| dir.join(format!("{stem}.{e}")))
                .find(|p| p.is_file())
        };
        let load = |stem: &str, enc: Encoding| -> Result<Option<(ImageF32, bool)>, SynthError> {
            match find(stem) {
                None => Ok(None),
                Some(p) => {
                    let is_exr = p.extension().is_some_and(|e| e.eq_ignore_ascii_case("exr"));
                    Ok(Some((read_image_linear(&p, enc)?, is_exr)))
                }
            }
        };
        if !dir.is_dir() {
            return Err(SynthError::invalid(
                "maps folder",
                dir.display(),
                "an existing folder with diffuse.png / .exr",
            ));
        }
        let diffuse = load("diffuse", Encoding::Srgb)?.ok_or_else(|| {
            SynthError::invalid(
                "maps folder",
                dir.display(),
                "a folder containing diffuse.png, diffuse.exr or diffuse.jpg",
            )
        })?;
        let specular = load("specular", Encoding::Srgb)?;
        let roughness = load("roughness", Encoding::Linear)?;
        let normal = load("normal", Encoding::Linear)?;
        let sample = |img: &ImageF32, x: f64, y: f64, out: &mut [f32; 3]| {
            // Mirror-repeat outside the region, so the surround keeps texture.
            let u = mirror((x - region.x_min) / region.width());
            let v = mirror((region.y_max - y) / region.height());
            img.sample_bilinear(u * img.width as f64 - 0.5, v * img.height as f64 - 0.5, out);
        };
        let texels: Vec<Texel> = (0..grid.len())
            .into_par_iter()
            .map(|i| {
                let p = grid.pixel_centre(i % grid.width, i / grid.width);
                let mut d = [0f32; 3];
                sample(&diffuse.0, p.x, p.y, &mut d);
                let mut s = [0.04f32; 3];
                if let Some((img, _)) = &specular {
                    sample(img, p.x, p.y, &mut s);
                }
                let mut a = [0.3f32; 3];
                if let Some((img, _)) = &roughness {
                    sample(img, p.x, p.y, &mut a);
                }
                Texel {
                    rho_d: d.map(f64::from),
                    rho_s: s.map(f64::from),
                    alpha: [f64::from(a[0]).max(0.01), f64::from(a[1]).max(0.01)],
                    height_cm: 0.0,
                    slope: [0.0; 2],
                }
            })
            .collect();
        let mut maps = Self::from_texels(grid, &texels, 0.0);
        if let Some((img, is_exr)) = &normal {
            let mut nmap = maps.normal.clone();
            for i in 0..grid.len() {
                let (c, r) = (i % grid.width, i / grid.width);
                let p = grid.pixel_centre(c, r);
                let mut n = [0f32; 3];
                sample(img, p.x, p.y, &mut n);
                let v = if *is_exr {
                    Vec3::new(n[0].into(), n[1].into(), n[2].into())
                } else {
                    Vec3::new(
                        f64::from(n[0]) * 2.0 - 1.0,
                        f64::from(n[1]) * 2.0 - 1.0,
                        f64::from(n[2]) * 2.0 - 1.0,
                    )
                };
                let v = if v.z > 0.05 { v.normalize() } else { Vec3::z() };
                nmap.pixel_mut(c, r)
                    .copy_from_slice(&[v.x as f32, v.y as f32, v.z as f32]);
            }
            maps = Self::assemble(maps.grid, maps.diffuse, maps.specular, maps.roughness, nmap);
        }
        Ok(maps)
    }

    /// Whether a plane point is covered by the maps.
    pub fn covers(&self, p: Vec2) -> bool {
        self.grid.region.contains(p)
    }

    /// Bilinearly sampled parameters and unit normal at a plane point (clamped at the
    /// border).
    #[inline]
    pub fn sample(&self, p: Vec2) -> (BrdfParams, Vec3) {
        let q = self.grid.to_pixel(p);
        let (w, h) = (self.grid.width, self.grid.height);
        let x = q.x.clamp(0.0, (w - 1) as f64);
        let y = q.y.clamp(0.0, (h - 1) as f64);
        let (x0, y0) = (x as usize, y as usize);
        let (x1, y1) = ((x0 + 1).min(w - 1), (y0 + 1).min(h - 1));
        let (fx, fy) = ((x - x0 as f64) as f32, (y - y0 as f64) as f32);
        let weights = [
            (1.0 - fx) * (1.0 - fy),
            fx * (1.0 - fy),
            (1.0 - fx) * fy,
            fx * fy,
        ];
        let texels = [y0 * w + x0, y0 * w + x1, y1 * w + x0, y1 * w + x1];
        let mut t = [0f32; PACKED];
        for (wt, i) in weights.iter().zip(texels) {
            let src = &self.packed[i];
            for k in 0..PACKED {
                t[k] += wt * src[k];
            }
        }
        let nv = Vec3::new(t[9].into(), t[10].into(), t[11].into());
        let nv = nv.try_normalize(1e-9).unwrap_or_else(Vec3::z);
        (
            BrdfParams {
                rho_d: [t[0].into(), t[1].into(), t[2].into()],
                rho_s: [t[3].into(), t[4].into(), t[5].into()],
                alpha_x: t[6].into(),
                alpha_y: t[7].into(),
                normal_theta_x: 0.0,
                normal_theta_y: 0.0,
                tangent_rotation: t[8].into(),
            },
            nv,
        )
    }

    /// The maps cropped to a sub-grid (same resolution) for writing ground truth.
    pub fn crop(&self, region: Region) -> Result<Self, SynthError> {
        let sub = PlaneGrid::new(region, self.grid.px_per_cm)?;
        let off = self.grid.to_pixel(sub.pixel_centre(0, 0));
        let (ox, oy) = (off.x.round() as isize, off.y.round() as isize);
        let crop = |img: &ImageF32| {
            let mut out = ImageF32::new(sub.width, sub.height, img.channels);
            for r in 0..sub.height {
                for c in 0..sub.width {
                    let sc = (c as isize + ox).clamp(0, img.width as isize - 1) as usize;
                    let sr = (r as isize + oy).clamp(0, img.height as isize - 1) as usize;
                    out.pixel_mut(c, r).copy_from_slice(img.pixel(sc, sr));
                }
            }
            out
        };
        Ok(Self::assemble(
            sub,
            crop(&self.diffuse),
            crop(&self.specular),
            crop(&self.roughness),
            crop(&self.normal),
        ))
    }
}

fn mirror(t: f64) -> f64 {
    let m = t.rem_euclid(2.0);
    if m > 1.0 {
        2.0 - m
    } else {
        m
    }
}

fn scale(b: Base, kd: f64, ks: f64) -> ([f64; 3], [f64; 3]) {
    (b.rho_d.map(|v| v * kd), b.rho_s.map(|v| v * ks))
}

fn base_texel(seed: u64, b: Base, x: f64, y: f64, f: f64, height_cm: f64) -> Texel {
    // Medium-scale albedo variation (needed by feature-based alignment, paper 3.1).
    // Contrast-stretched fBm plus sparse dark speckles: real surfaces (grain, pores,
    // dust, print) have such detail at many scales, and alignment depends on it.
    let t = ((fbm(seed, x / (4.0 * f), y / (4.0 * f), 5) - 0.5) * 2.5 + 0.5).clamp(0.0, 1.0);
    let speck = value(seed ^ 0x5BEC, x / (0.7 * f), y / (0.7 * f));
    let tex = (0.55 + 0.9 * t) * if speck > 0.82 { 0.55 } else { 1.0 };
    let (rho_d, rho_s) = scale(
        b,
        tex,
        0.8 + 0.4 * value(seed ^ 0x77, x / (20.0 * f), y / (20.0 * f)),
    );
    Texel {
        rho_d,
        rho_s,
        alpha: b.alpha,
        height_cm,
        slope: [0.0; 2],
    }
}

fn leather(seed: u64, x: f64, y: f64, f: f64) -> Texel {
    let (_, d1, d2) = voronoi(seed ^ 0x1EA7, x / (3.0 * f), y / (3.0 * f));
    let grain = (d2 - d1).min(0.3) / 0.3; // 0 at cell borders
    let h = 0.004 * grain + 0.002 * fbm(seed ^ 3, x / (8.0 * f), y / (8.0 * f), 3);
    let mut t = base_texel(seed, LEATHER, x, y, f, h);
    let crease = 0.75 + 0.25 * grain;
    t.rho_d = t.rho_d.map(|v| v * crease);
    t
}

fn brushed(seed: u64, x: f64, y: f64, f: f64) -> Texel {
    // Grooves run along x, so the highlight stretches along y: alpha_x < alpha_y.
    let h = 0.0015 * fbm(seed ^ 5, x / (40.0 * f), y / (0.8 * f), 3);
    let mut t = base_texel(seed, BRUSHED, x, y, f, h);
    let scratch = value(seed ^ 9, x / (60.0 * f), y / (2.0 * f));
    t.alpha = [BRUSHED.alpha[0] * (0.8 + 0.4 * scratch), BRUSHED.alpha[1]];
    t
}

fn fabric(seed: u64, x: f64, y: f64, f: f64) -> Texel {
    let p = 2.0 * f;
    let (sx, sy) = (
        (x / p * std::f64::consts::TAU).sin(),
        (y / p * std::f64::consts::TAU).sin(),
    );
    let h = 0.003 * (sx * sy);
    let mut t = base_texel(seed, FABRIC, x, y, f, h);
    let weave = 0.85 + 0.15 * sx * sy;
    t.rho_d = t.rho_d.map(|v| v * weave);
    t
}

fn gold(seed: u64, x: f64, y: f64, f: f64) -> Texel {
    let (_, d1, _) = voronoi(seed ^ 0x601D, x / (5.0 * f), y / (5.0 * f));
    let h = 0.006 * (1.0 - (d1 / 0.7).min(1.0)).powi(2);
    base_texel(seed, GOLD, x, y, f, h)
}

fn paint(seed: u64, x: f64, y: f64, f: f64) -> Texel {
    let h = 0.003 * fbm(seed ^ 11, x / (25.0 * f), y / (4.0 * f), 3);
    base_texel(seed, PAINT, x, y, f, h)
}

fn patchwork(seed: u64, x: f64, y: f64, f: f64, cell: f64) -> Texel {
    let (id, d1, d2) = voronoi(seed, x / cell, y / cell);
    // Thin seams between patches.
    if (d2 - d1) * cell < 1.2 * f {
        let mut t = base_texel(seed, GROUT, x, y, f, -0.004);
        t.alpha = GROUT.alpha;
        return t;
    }
    match id % 5 {
        0 => leather(seed, x, y, f),
        1 => brushed(seed, x, y, f),
        2 => fabric(seed, x, y, f),
        3 => gold(seed, x, y, f),
        _ => paint(seed, x, y, f),
    }
}

const GLOSS: Base = Base {
    rho_d: [0.08, 0.16, 0.10],
    rho_s: [0.45, 0.45, 0.45],
    alpha: [0.10, 0.10],
};

/// The two-camera test material (paper 3.3): glossy Voronoi facets, each tilted by
/// 15-30 degrees in its own direction. With the light always beside the camera, a
/// bright facet tilted away is hard to tell from a darker one facing the camera.
fn facets(seed: u64, x: f64, y: f64, f: f64, cell: f64) -> Texel {
    let (id, d1, d2) = voronoi(seed ^ 0xFACE, x / cell, y / cell);
    if (d2 - d1) * cell < 1.2 * f {
        let mut t = base_texel(seed, GROUT, x, y, f, 0.0);
        t.alpha = GROUT.alpha;
        return t;
    }
    let h = |k: u64| {
        let v = id.wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ k;
        ((v >> 11) as f64) / ((1u64 << 53) as f64)
    };
    let tilt = (15.0 + 15.0 * h(1)).to_radians();
    let az = std::f64::consts::TAU * h(2);
    let base = if id % 2 == 0 { GLOSS } else { GOLD };
    let mut t = base_texel(seed, base, x, y, f, 0.0);
    t.slope = [tilt.tan() * az.cos(), tilt.tan() * az.sin()];
    t
}

fn tiles(seed: u64, x: f64, y: f64, f: f64, cell: f64) -> Texel {
    let (u, v) = (x / cell, y / cell);
    let (fu, fv) = (u - u.floor(), v - v.floor());
    let grout = 1.5 * f / cell;
    if fu < grout || fv < grout {
        return base_texel(seed, GROUT, x, y, f, -0.01);
    }
    let id = ((u.floor() as i64) + (v.floor() as i64)).rem_euclid(2);
    if id == 0 {
        paint(seed, x, y, f)
    } else {
        gold(seed, x, y, f)
    }
}

/// Side of a bathroom tile, grout included, cm.
const BATHROOM_TILE_CM: f64 = 2.5;

/// Glazed tiles on a regular grid, the repetitive texture the paper names as a
/// limitation of feature matching: each tile one of five colours (chosen by a hash of
/// its index), with little texture of its own, a glossy glaze, every fourth tile with
/// the same printed motif, and grout lines between them.
fn bathroom_tiles(seed: u64, x: f64, y: f64, f: f64) -> Texel {
    const COLOURS: [[f64; 3]; 5] = [
        [0.62, 0.64, 0.66],
        [0.20, 0.36, 0.55],
        [0.55, 0.52, 0.40],
        [0.18, 0.45, 0.38],
        [0.70, 0.42, 0.30],
    ];
    let c = BATHROOM_TILE_CM;
    let (u, v) = (x / c, y / c);
    let (iu, iv) = (u.floor() as i64, v.floor() as i64);
    let (fu, fv) = (u - u.floor(), v - v.floor());
    let grout = 0.08;
    if fu < grout || fv < grout {
        let mut t = base_texel(seed, GROUT, x, y, f, -0.02);
        t.alpha = GROUT.alpha;
        return t;
    }
    let h = crate::noise::hash2(seed ^ 0x711E, iu, iv);
    let colour = COLOURS[((h * 5.0) as usize).min(4)];
    // The glaze: weak, smooth variation (real tiles are nearly uniform).
    let t = fbm(seed ^ 0x61A2, x / (6.0 * f), y / (6.0 * f), 4);
    let tex = 0.98 + 0.04 * t;
    let mut rho_d = colour.map(|v| v * tex);
    // The motif, identical on every motif tile: a dark ring and a centred diamond.
    if crate::noise::hash2(seed ^ 0x3071F, iu, iv) < 0.25 {
        let (px, py) = (
            (fu - grout) / (1.0 - grout) - 0.5,
            (fv - grout) / (1.0 - grout) - 0.5,
        );
        let r = (px * px + py * py).sqrt();
        let ring = (r - 0.32).abs() < 0.035;
        let diamond = px.abs() + py.abs() < 0.14;
        if ring || diamond {
            rho_d = [0.08, 0.06, 0.05];
        }
    }
    Texel {
        rho_d,
        rho_s: [0.25; 3],
        alpha: [0.07, 0.07],
        height_cm: 0.0,
        slope: [0.0; 2],
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn procedural_maps_are_physical_and_deterministic() {
        let grid = PlaneGrid::new(Region::centred(4.0, 4.0), 10.0).unwrap();
        for name in crate::config::MATERIALS {
            let a = MaterialMaps::procedural(name, grid, 0.25, 0.0, 7).unwrap();
            let b = MaterialMaps::procedural(name, grid, 0.25, 0.0, 7).unwrap();
            assert_eq!(a.diffuse, b.diffuse);
            for i in 0..grid.len() {
                let (c, r) = (i % grid.width, i / grid.width);
                let (p, n) = a.sample(grid.pixel_centre(c, r));
                assert!(p.is_physical(), "{name}: {p:?}");
                assert!((n.norm() - 1.0).abs() < 1e-6 && n.z > 0.5);
            }
        }
        assert!(MaterialMaps::procedural("velvet", grid, 0.25, 0.0, 7).is_err());
        // Turned a quarter: the rotation is in every texel, and the grooves that ran
        // along x run along y.
        let flat = MaterialMaps::procedural("brushed-metal", grid, 0.25, 0.0, 7).unwrap();
        let turned =
            MaterialMaps::procedural("brushed-metal", grid, 0.25, std::f64::consts::FRAC_PI_2, 7)
                .unwrap();
        let p = Vec2::new(0.3, -0.2);
        let (a, _) = turned.sample(p);
        assert!((a.tangent_rotation - std::f64::consts::FRAC_PI_2).abs() < 1e-6);
        assert_eq!(flat.sample(p).0.tangent_rotation, 0.0);
        // The pattern at p turned is the flat pattern at p turned back.
        let back = Vec2::new(p.y, -p.x);
        assert!((a.rho_d[0] - flat.sample(back).0.rho_d[0]).abs() < 0.02);
    }
}
