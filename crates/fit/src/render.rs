//! Rendering from fitted maps: re-rendering every observation (the paper's supplemental
//! comparison, done in the plane's rectified frame so that no frame has to be decoded
//! again), the side-by-side strip, per-pixel residuals and relighting under a new light.

use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use svbrdf_core::brdf::{BrdfModel, BrdfParams, LightView, ModelKind, Prepared};
use svbrdf_core::geometry::Vec3;
use svbrdf_core::image::ImageF32;
use svbrdf_core::plane::PlaneGrid;

use crate::observations::{residual, Observations};

/// Re-rendering error of one input frame.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct FrameError {
    /// Frame id in the capture.
    pub id: u32,
    /// Observations of this frame inside the output region.
    pub observations: usize,
    /// Root mean square error of linear radiance over observations and channels.
    pub rmse: f64,
    /// Mean observed linear radiance.
    pub mean: f64,
    /// `rmse / mean`.
    pub relative: f64,
}

/// Predicted linear radiance of observation `o` of pixel `px`.
#[inline]
fn predict(
    obs: &Observations,
    model: &dyn BrdfModel,
    prep: &Prepared,
    intensity: [f64; 3],
    px: usize,
    o: usize,
) -> [f64; 3] {
    let v = model.radiance(prep, &obs.light_view(px, o), 1.0);
    [
        v[0] * intensity[0],
        v[1] * intensity[1],
        v[2] * intensity[2],
    ]
}

/// Summed squared re-rendering errors of a set of observations (held-out frames), in
/// linear radiance and in sRGB-encoded values (highlights weigh less), with clipped
/// channels as censored values in both.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct SquaredErrors {
    /// Sum over observations and channels, linear radiance.
    pub linear: f64,
    /// The same of sRGB-encoded values (the curve continued above 1).
    pub srgb: f64,
    /// Observations (each three channels).
    pub observations: usize,
}

impl SquaredErrors {
    /// Root mean square error in linear radiance.
    pub fn linear_rmse(&self) -> f64 {
        (self.linear / (3 * self.observations.max(1)) as f64).sqrt()
    }

    /// Root mean square error of sRGB-encoded values.
    pub fn srgb_rmse(&self) -> f64 {
        (self.srgb / (3 * self.observations.max(1)) as f64).sqrt()
    }
}

impl std::ops::Add for SquaredErrors {
    type Output = Self;

    /// Both sums of two sets.
    fn add(self, o: Self) -> Self {
        Self {
            linear: self.linear + o.linear,
            srgb: self.srgb + o.srgb,
            observations: self.observations + o.observations,
        }
    }
}

/// [`SquaredErrors`] of `params` re-rendered against every observation of `obs`.
pub fn squared_errors(
    obs: &Observations,
    params: &[BrdfParams],
    model: &dyn BrdfModel,
    intensity: [f64; 3],
) -> SquaredErrors {
    use svbrdf_core::color::linear_to_srgb;
    // Per pixel in parallel, summed in pixel order: a parallel reduction would add in
    // an order that depends on thread scheduling, and identical inputs must give
    // identical bytes.
    let per_pixel: Vec<SquaredErrors> = (0..obs.pixels())
        .into_par_iter()
        .with_min_len(256)
        .map(|px| {
            let mut e = SquaredErrors::default();
            if obs.count(px) == 0 {
                return e;
            }
            let prep = Prepared::new(params[px]);
            for o in obs.range(px) {
                let v = predict(obs, model, &prep, intensity, px, o);
                let c = obs.color(o);
                let cl = obs.clipped(o);
                for k in 0..3 {
                    e.linear += residual(v[k], c[k], cl[k]).powi(2);
                    let s = linear_to_srgb(v[k].max(0.0)) - linear_to_srgb(c[k].max(0.0));
                    e.srgb += if cl[k] { s.min(0.0) } else { s }.powi(2);
                }
                e.observations += 1;
            }
            e
        })
        .collect();
    per_pixel
        .into_iter()
        .fold(SquaredErrors::default(), |a, b| a + b)
}

/// Re-render every observation once and report the error both ways: RMS per pixel
/// over its observations (linear radiance; 0 where unobserved) and per input frame.
pub fn rerender_check(
    obs: &Observations,
    params: &[BrdfParams],
    model: &dyn BrdfModel,
    intensity: [f64; 3],
) -> (Vec<f32>, Vec<FrameError>) {
    let nf = obs.frames.len();
    // Per frame: squared error, observed sum, observation count.
    type FrameAcc = Vec<(f64, f64, usize)>;
    let (residuals, acc): (Vec<f32>, FrameAcc) = (0..obs.pixels())
        .into_par_iter()
        .with_min_len(1024)
        .fold(
            || (Vec::new(), vec![(0.0f64, 0.0f64, 0usize); nf]),
            |(mut res, mut acc), px| {
                let n = obs.count(px);
                if n == 0 {
                    res.push(0.0);
                    return (res, acc);
                }
                if model.kind() == ModelKind::Ward {
                    let s = crate::BATCH.with_borrow_mut(|b| {
                        b.gather(obs, px, 1);
                        let mut e = Vec::new();
                        b.errors(&params[px], intensity, &mut e);
                        let mut s = 0.0;
                        for i in 0..b.len() {
                            let a = &mut acc[usize::from(b.frame[i])];
                            let ei = f64::from(e[i]);
                            s += ei;
                            a.0 += ei;
                            a.1 += (0..3).map(|k| f64::from(b.rgb[k][i])).sum::<f64>();
                            a.2 += 1;
                        }
                        s
                    });
                    res.push((s / (3 * n) as f64).sqrt() as f32);
                    return (res, acc);
                }
                let prep = Prepared::new(params[px]);
                let mut s = 0.0;
                for o in obs.range(px) {
                    let v = predict(obs, model, &prep, intensity, px, o);
                    let c = obs.color(o);
                    let cl = obs.clipped(o);
                    let a = &mut acc[usize::from(obs.frame[o])];
                    for k in 0..3 {
                        let e = residual(v[k], c[k], cl[k]).powi(2);
                        s += e;
                        a.0 += e;
                        a.1 += c[k];
                    }
                    a.2 += 1;
                }
                res.push((s / (3 * n) as f64).sqrt() as f32);
                (res, acc)
            },
        )
        .reduce(
            || (Vec::new(), vec![(0.0, 0.0, 0); nf]),
            |(mut ra, mut aa), (rb, ab)| {
                // Rayon keeps the order of the folded chunks, so appending keeps pixels
                // in grid order.
                ra.extend(rb);
                for (x, y) in aa.iter_mut().zip(ab) {
                    x.0 += y.0;
                    x.1 += y.1;
                    x.2 += y.2;
                }
                (ra, aa)
            },
        );
    let frames = acc
        .into_iter()
        .enumerate()
        .map(|(k, (sse, sum, n))| {
            let m = (3 * n).max(1) as f64;
            let rmse = (sse / m).sqrt();
            let mean = sum / m;
            FrameError {
                id: obs.frames[k].id,
                observations: n,
                rmse,
                mean,
                relative: if mean > 0.0 { rmse / mean } else { 0.0 },
            }
        })
        .collect();
    (residuals, frames)
}

/// Side-by-side strip: for each chosen frame number, the observed frame rectified onto
/// the plane (top row) above its re-rendering from the maps (bottom row), each tile
/// block-averaged to at most `max_tile` pixels on its long side. Unobserved: dark grey.
pub fn strip(
    obs: &Observations,
    params: &[BrdfParams],
    model: &dyn BrdfModel,
    intensity: [f64; 3],
    frames: &[usize],
    max_tile: usize,
) -> ImageF32 {
    let g = obs.grid;
    let d = g.width.max(g.height).div_ceil(max_tile.max(1)).max(1);
    let (tw, th) = (g.width.div_ceil(d), g.height.div_ceil(d));
    let gap = 4;
    let n = frames.len().max(1);
    let mut img = ImageF32::new(n * tw + (n + 1) * gap, 2 * th + 3 * gap, 3);
    img.data.fill(1.0);
    for (i, &f) in frames.iter().enumerate() {
        // Sums per tile pixel: observed rgb, rendered rgb, count.
        let mut acc = vec![[0.0f64; 7]; tw * th];
        for px in 0..obs.pixels() {
            let range = obs.range(px);
            let Some(o) = range.clone().find(|&o| usize::from(obs.frame[o]) == f) else {
                continue;
            };
            let prep = Prepared::new(params[px]);
            let v = predict(obs, model, &prep, intensity, px, o);
            let c = obs.color(o);
            let t = (px / g.width / d) * tw + (px % g.width) / d;
            for k in 0..3 {
                acc[t][k] += c[k];
                acc[t][3 + k] += v[k];
            }
            acc[t][6] += 1.0;
        }
        for ty in 0..th {
            for tx in 0..tw {
                let a = acc[ty * tw + tx];
                for (row, off) in [(0usize, 0usize), (1, 3)] {
                    let x = gap + i * (tw + gap) + tx;
                    let y = gap + row * (th + gap) + ty;
                    let p = img.pixel_mut(x, y);
                    for k in 0..3 {
                        p[k] = if a[6] > 0.0 {
                            (a[off + k] / a[6]) as f32
                        } else {
                            0.05
                        };
                    }
                }
            }
        }
    }
    img
}

/// Linear radiance of every grid pixel under a point light, seen from `camera` (the
/// simulator's held-out relighting images use the same set-up).
pub fn relight(
    grid: &PlaneGrid,
    params: &[BrdfParams],
    model: &dyn BrdfModel,
    intensity: [f64; 3],
    light: Vec3,
    camera: Vec3,
) -> ImageF32 {
    relight_in_room(grid, params, model, intensity, light, camera, 0.0)
}

/// [`relight`] with the room light `ambient` ([`LightView::ambient`]) added: what a
/// photo taken in the capture's room records (held-out frames of the capture).
pub fn relight_in_room(
    grid: &PlaneGrid,
    params: &[BrdfParams],
    model: &dyn BrdfModel,
    intensity: [f64; 3],
    light: Vec3,
    camera: Vec3,
    ambient: f64,
) -> ImageF32 {
    let mut img = ImageF32::new(grid.width, grid.height, 3);
    img.data
        .par_chunks_mut(grid.width * 3)
        .enumerate()
        .for_each(|(r, line)| {
            for c in 0..grid.width {
                let q = grid.pixel_centre(c, r);
                let lv = LightView::from_points(Vec3::new(q.x, q.y, 0.0), light, camera)
                    .with_ambient(ambient);
                let v = model.radiance(&Prepared::new(params[r * grid.width + c]), &lv, 1.0);
                for k in 0..3 {
                    line[c * 3 + k] = (v[k] * intensity[k]) as f32;
                }
            }
        });
    img
}
