//! Recursive clustered fitting (paper sections 3.2.1-3.2.3): fit each initial cluster
//! with an isotropic, flat-normal model, split its pixels at `median + MAD` of the
//! per-pixel error (eq. 8), fit each part with the full model starting from the parent,
//! and recurse down to the minimum cluster size. A split is kept only when it lowers
//! the squared error by at least `min_split_gain` (our addition: it stops splitting
//! clusters that are already explained to the noise level, which is most of the
//! paper's run time on homogeneous materials).

use std::collections::HashMap;
use std::hash::{BuildHasherDefault, Hasher};

use rayon::prelude::*;
use svbrdf_core::brdf::{BrdfModel, BrdfParams, LightView, ModelKind, Prepared};
use svbrdf_core::geometry::Vec3;

use crate::config::FitConfig;
use crate::observations::{residual, Observations};
use crate::solver::{Bounds, Freedom, Problem, Sample, Solution};

/// Everything a cluster fit needs.
pub struct Context<'a> {
    /// The observations.
    pub obs: &'a Observations,
    /// Model to fit.
    pub model: &'a dyn BrdfModel,
    /// Light intensity per channel.
    pub intensity: [f64; 3],
    /// Settings.
    pub cfg: &'a FitConfig,
}

impl Context<'_> {
    /// Bounds of eq. (11) from the settings.
    pub fn bounds(&self) -> Bounds {
        Bounds {
            diffuse_only: self.cfg.diffuse_only,
            ..Bounds::symmetric(
                self.cfg.alpha_min,
                self.cfg.alpha_max,
                self.cfg.max_normal_deg.to_radians(),
            )
        }
    }
}

/// A final cluster.
#[derive(Debug, Clone)]
pub struct Leaf {
    /// Its pixels (indices into the grid).
    pub pixels: Vec<u32>,
    /// Its BRDF.
    pub params: BrdfParams,
    /// Split level (0: an initial cluster).
    pub depth: usize,
    /// Summed squared error over its pixels' observations (at most
    /// `max_split_observations` of each pixel, as the split decisions use).
    pub sse: f64,
    /// Number of observations `sse` is over.
    pub observations: usize,
    /// Whether the solver converged (false: stopped at the iteration cap).
    pub converged: bool,
}

/// Multiply-shift hasher for bin keys (the std SipHash is several times slower here,
/// and keys are not attacker-controlled).
#[derive(Default)]
struct KeyHasher(u64);

impl Hasher for KeyHasher {
    fn finish(&self) -> u64 {
        self.0
    }
    fn write(&mut self, bytes: &[u8]) {
        for b in bytes {
            self.0 = (self.0.rotate_left(8) ^ u64::from(*b)).wrapping_mul(0x9E37_79B9_7F4A_7C15);
        }
    }
    fn write_u64(&mut self, v: u64) {
        self.0 = (v ^ 0x5bd1_e995).wrapping_mul(0x9E37_79B9_7F4A_7C15);
        self.0 ^= self.0 >> 29;
    }
}

/// At most `max` of `pixels`, spread evenly.
fn spread(pixels: &[u32], max: usize) -> impl Iterator<Item = &u32> {
    let step = pixels.len().div_ceil(max.max(1)).max(1);
    pixels.iter().step_by(step)
}

/// The paper's redundant-observation binning (3.2.2) over a cluster's pixels: one
/// averaged sample per bin, weighted by its count.
pub fn binned_samples(ctx: &Context, pixels: &[u32]) -> Vec<Sample> {
    #[derive(Default, Clone, Copy)]
    struct Acc {
        l: Vec3,
        v: Vec3,
        r2: f64,
        rgb: [f64; 3],
        n: f64,
        clipped: [bool; 3],
    }
    let obs = ctx.obs;
    let mut index: HashMap<u64, usize, BuildHasherDefault<KeyHasher>> = HashMap::default();
    let mut accs: Vec<Acc> = Vec::new();
    for &px in spread(pixels, ctx.cfg.max_fit_pixels) {
        let px = px as usize;
        for o in obs.range(px) {
            let cl = obs.clipped(o);
            // Clipped and unclipped observations never share a bin: one is a value, the
            // other a lower bound.
            let mask = u64::from(cl[0]) | u64::from(cl[1]) << 1 | u64::from(cl[2]) << 2;
            let slot = *index
                .entry(u64::from(obs.key[o]) | mask << 32)
                .or_insert_with(|| {
                    accs.push(Acc::default());
                    accs.len() - 1
                });
            let lv = obs.light_view(px, o);
            let c = obs.color(o);
            let a = &mut accs[slot];
            a.clipped = cl;
            a.l += lv.light;
            a.v += lv.view;
            a.r2 += lv.light_dist2;
            for k in 0..3 {
                a.rgb[k] += c[k];
            }
            a.n += 1.0;
        }
    }
    accs.into_iter()
        .filter_map(|a| {
            Some(Sample {
                lv: LightView {
                    light: a.l.try_normalize(1e-12)?,
                    view: a.v.try_normalize(1e-12)?,
                    light_dist2: a.r2 / a.n,
                },
                rgb: a.rgb.map(|v| v / a.n),
                weight: a.n,
                clipped: a.clipped,
            })
        })
        .collect()
}

/// Mean squared error (over observations and channels) per pixel, the summed squared
/// error and the number of observations it was computed over: at most
/// `max_split_observations` per pixel, spread evenly over its frames, so that the cost
/// of a split level does not grow with the length of the video.
pub fn pixel_errors(ctx: &Context, pixels: &[u32], params: &BrdfParams) -> (Vec<f64>, f64, usize) {
    let p = Prepared::new(*params);
    let obs = ctx.obs;
    let cap = ctx.cfg.max_split_observations;
    let ward = ctx.model.kind() == ModelKind::Ward;
    let per: Vec<(f64, usize)> = pixels
        .par_iter()
        .with_min_len(256)
        .map(|&px| {
            let px = px as usize;
            let mut s = 0.0;
            let r = obs.range(px);
            let step = r.len().div_ceil(cap).max(1);
            if ward {
                return crate::BATCH.with_borrow_mut(|b| {
                    b.gather(obs, px, step);
                    (b.sse(params, ctx.intensity), b.len())
                });
            }
            let mut n = 0;
            for o in r.step_by(step) {
                n += 1;
                let v = ctx.model.radiance(&p, &obs.light_view(px, o), 1.0);
                let c = obs.color(o);
                let cl = obs.clipped(o);
                for k in 0..3 {
                    s += residual(v[k] * ctx.intensity[k], c[k], cl[k]).powi(2);
                }
            }
            (s, n)
        })
        .collect();
    let sse = per.iter().map(|e| e.0).sum();
    let n = per.iter().map(|e| e.1).sum();
    let errs = per
        .into_iter()
        .map(|(s, n)| s / (3 * n.max(1)) as f64)
        .collect();
    (errs, sse, n)
}

/// The paper's initial values for a cluster: rho_d the mean colour and rho_s twice the
/// mean per-pixel standard deviation across frames, both in albedo units (each
/// observation divided by `I cos(theta_i) / (pi r^2)`), alpha 0.1, flat normal.
pub fn initial_params(ctx: &Context, pixels: &[u32]) -> BrdfParams {
    let obs = ctx.obs;
    let mut mean = [0.0; 3];
    let mut std = [0.0; 3];
    let mut n_px = 0.0;
    for &px in spread(pixels, ctx.cfg.max_fit_pixels) {
        let px = px as usize;
        let r = obs.range(px);
        if r.is_empty() {
            continue;
        }
        let mut s = [0.0; 3];
        let mut s2 = [0.0; 3];
        let n = r.len() as f64;
        for o in r {
            let lv = obs.light_view(px, o);
            let g = std::f64::consts::PI * lv.light_dist2 / lv.light.z.max(0.05);
            let c = obs.color(o);
            for k in 0..3 {
                let a = c[k] * g / ctx.intensity[k];
                s[k] += a;
                s2[k] += a * a;
            }
        }
        for k in 0..3 {
            let m = s[k] / n;
            mean[k] += m;
            std[k] += (s2[k] / n - m * m).max(0.0).sqrt();
        }
        n_px += 1.0;
    }
    let n_px = f64::max(n_px, 1.0);
    BrdfParams {
        rho_d: mean.map(|v| v / n_px),
        rho_s: std.map(|v| 2.0 * v / n_px),
        ..BrdfParams::default()
    }
}

/// The isotropic flat fit of an initial cluster alone (paper 3.2.1), optionally
/// without the energy bound: used to fix albedo units when the intensity is unknown.
pub fn initial_fit(ctx: &Context, pixels: &[u32], energy: bool) -> BrdfParams {
    let start = initial_params(ctx, pixels);
    best_solution(
        ctx,
        pixels,
        &starting_roughness(&start),
        &Freedom::ISOTROPIC_FLAT,
        energy,
    )
    .map_or(start, |s| s.params)
}

/// Bin a cluster's observations and fit from each start; the lowest-cost solution.
fn best_solution(
    ctx: &Context,
    pixels: &[u32],
    inits: &[BrdfParams],
    fr: &Freedom,
    energy: bool,
) -> Option<Solution> {
    let samples = binned_samples(ctx, pixels);
    let mut bounds = ctx.bounds();
    bounds.energy = energy;
    let prob = Problem {
        model: ctx.model,
        samples: &samples,
        intensity: ctx.intensity,
        bounds,
        tolerance: ctx.cfg.tolerance,
    };
    inits
        .iter()
        .map(|init| prob.solve(init, fr, None, ctx.cfg.max_iterations))
        .min_by(|a, b| a.cost.total_cmp(&b.cost))
}

/// The paper starts at alpha = 0.1; two more starting roughnesses cost little at the
/// initial level (one fit per initial cluster) and avoid a local minimum on very shiny
/// or very rough materials.
fn starting_roughness(start: &BrdfParams) -> Vec<BrdfParams> {
    [0.1, 0.04, 0.3]
        .iter()
        .map(|&a| BrdfParams {
            alpha_x: a,
            alpha_y: a,
            ..*start
        })
        .collect()
}

struct Fitted {
    params: BrdfParams,
    errs: Vec<f64>,
    sse: f64,
    n_obs: usize,
    converged: bool,
}

fn fit(ctx: &Context, pixels: &[u32], inits: &[BrdfParams], fr: &Freedom) -> Fitted {
    let (params, converged) = best_solution(ctx, pixels, inits, fr, true)
        .map_or((inits[0], false), |s| (s.params, s.converged));
    let (errs, sse, n_obs) = pixel_errors(ctx, pixels, &params);
    Fitted {
        params,
        errs,
        sse,
        n_obs,
        converged,
    }
}

/// Median and median absolute deviation.
pub fn median_mad(v: &[f64]) -> (f64, f64) {
    if v.is_empty() {
        return (0.0, 0.0);
    }
    let median = |mut w: Vec<f64>| {
        let m = w.len() / 2;
        *w.select_nth_unstable_by(m, f64::total_cmp).1
    };
    let med = median(v.to_vec());
    let mad = median(v.iter().map(|e| (e - med).abs()).collect());
    (med, mad)
}

/// Split a cluster's pixels at eq. (8): `(e <= t, e > t)` with `t = median + MAD`.
pub fn split(pixels: &[u32], errs: &[f64]) -> (Vec<u32>, Vec<u32>) {
    let (med, mad) = median_mad(errs);
    let t = med + mad;
    let mut low = Vec::new();
    let mut high = Vec::new();
    for (&p, &e) in pixels.iter().zip(errs) {
        if e > t {
            high.push(p);
        } else {
            low.push(p);
        }
    }
    (low, high)
}

fn node(ctx: &Context, pixels: Vec<u32>, f: Fitted, depth: usize) -> Vec<Leaf> {
    let min = ctx.cfg.min_cluster_px;
    let leaf = |pixels: Vec<u32>, f: &Fitted| {
        vec![Leaf {
            pixels,
            params: f.params,
            depth,
            sse: f.sse,
            observations: f.n_obs,
            converged: f.converged,
        }]
    };
    if depth >= ctx.cfg.max_depth || pixels.len() < 2 * min {
        return leaf(pixels, &f);
    }
    let (a, b) = split(&pixels, &f.errs);
    if a.len() < min || b.len() < min {
        return leaf(pixels, &f);
    }
    let init = [f.params];
    let (fa, fb) = rayon::join(
        || fit(ctx, &a, &init, &Freedom::FULL),
        || fit(ctx, &b, &init, &Freedom::FULL),
    );
    if fa.sse + fb.sse >= (1.0 - ctx.cfg.min_split_gain) * f.sse {
        return leaf(pixels, &f);
    }
    let (mut la, lb) = rayon::join(
        || node(ctx, a, fa, depth + 1),
        || node(ctx, b, fb, depth + 1),
    );
    la.extend(lb);
    la
}

/// Fit one initial cluster and everything below it.
pub fn fit_cluster(ctx: &Context, pixels: Vec<u32>) -> Vec<Leaf> {
    let inits = starting_roughness(&initial_params(ctx, &pixels));
    let f = fit(ctx, &pixels, &inits, &Freedom::ISOTROPIC_FLAT);
    node(ctx, pixels, f, 0)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn median_mad_and_split_follow_eq_8() {
        let e = [1.0, 2.0, 3.0, 4.0, 100.0];
        let (m, d) = median_mad(&e);
        assert_eq!((m, d), (3.0, 1.0));
        let px = [10, 11, 12, 13, 14];
        let (low, high) = split(&px, &e);
        // t = 4: pixels with error above 4 form the second cluster.
        assert_eq!(low, vec![10, 11, 12, 13]);
        assert_eq!(high, vec![14]);
    }
}
