//! Ward fast paths of the loops over raw observations: per-pixel split errors,
//! per-pixel refinement and the re-rendering check (the cluster fits' ten-parameter
//! batch is [`crate::sample_batch`]). They run on the core's f32 batch
//! kernel ([`svbrdf_core::brdf::batch`]) and give the same results as the generic f64
//! path to about 1e-5 relative; GGX fits take the generic path.

use nalgebra::{SMatrix, SVector};
use svbrdf_core::brdf::batch::{shapes, shapes_grad, GeometryBatch, Shapes, WardF32, LANES};
use svbrdf_core::brdf::{BrdfParams, Prepared};

use crate::observations::{Observations, CLIPPED, RGB_SCALE};
use crate::solver::{damped_step, Bounds};

/// One pixel's observations in structure-of-arrays form, padded to [`LANES`].
#[derive(Debug, Clone, Default)]
pub struct PixelBatch {
    /// Geometry.
    pub geom: GeometryBatch,
    /// Observed linear RGB (0 in the padding).
    pub rgb: [Vec<f32>; 3],
    /// 1 where the channel was clipped (a lower bound), else 0.
    pub censor: [Vec<f32>; 3],
    /// Frame number per observation (not padded).
    pub frame: Vec<u16>,
    /// Square root of each observation's robust weight in the refinement (1 after
    /// `gather`; padded).
    pub robust: Vec<f32>,
    shapes: Shapes,
    scratch: Vec<f32>,
    rows: Rows<4>,
}

impl PixelBatch {
    /// Gather every `step`-th observation of pixel `px`.
    pub fn gather(&mut self, obs: &Observations, px: usize, step: usize) {
        let r = obs.range(px);
        let step = step.max(1);
        let n = r.len().div_ceil(step);
        self.geom.begin(n);
        self.geom.ambient = obs.ambient as f32;
        let padded = self.geom.padded_len();
        for a in self.rgb.iter_mut().chain(self.censor.iter_mut()) {
            a.clear();
            a.resize(padded, 0.0);
        }
        self.frame.clear();
        self.robust.clear();
        self.robust.resize(padded, 1.0);
        let s = obs.surface(px);
        let sat = obs.saturation as f32;
        let scale = (1.0 / RGB_SCALE) as f32;
        for (i, o) in r.step_by(step).enumerate() {
            let fr = obs.frame[o];
            let f = &obs.frames[usize::from(fr)];
            let dl = f.light - s;
            let dv = f.camera - s;
            self.geom.set(
                i,
                [dl.x as f32, dl.y as f32, dl.z as f32],
                [dv.x as f32, dv.y as f32, dv.z as f32],
            );
            let inv = (1.0 / f.gain) as f32;
            for (k, v) in obs.rgb[o].iter().enumerate() {
                let clipped = *v == CLIPPED;
                self.rgb[k][i] = inv * if clipped { sat } else { f32::from(*v) * scale };
                self.censor[k][i] = if clipped { 1.0 } else { 0.0 };
            }
            self.frame.push(fr);
        }
        self.geom.finish();
    }

    /// Observations gathered.
    pub fn len(&self) -> usize {
        self.geom.len()
    }

    /// Whether none were gathered.
    pub fn is_empty(&self) -> bool {
        self.geom.is_empty()
    }

    /// Squared error (summed over channels) of every observation under `p`, into
    /// `out` (padded length; padding is 0).
    pub fn errors(&mut self, p: &BrdfParams, intensity: [f64; 3], out: &mut Vec<f32>) {
        let w = WardF32::new(&Prepared::new(*p));
        shapes(&w, &self.geom, &mut self.shapes);
        self.errors_from_shapes(p, intensity, out);
    }

    /// [`errors`](Self::errors) with `self.shapes` already evaluated under `p`.
    fn errors_from_shapes(&self, p: &BrdfParams, intensity: [f64; 3], out: &mut Vec<f32>) {
        let n = self.geom.padded_len();
        out.clear();
        out.resize(n, 0.0);
        for c in 0..3 {
            let (kd, ks) = (
                (p.rho_d[c] * intensity[c]) as f32,
                (p.rho_s[c] * intensity[c]) as f32,
            );
            let (d, s, y, cen) = (
                &self.shapes.d[..n],
                &self.shapes.s[..n],
                &self.rgb[c][..n],
                &self.censor[c][..n],
            );
            for i in 0..n {
                let r = kd * d[i] + ks * s[i] - y[i];
                let r = r - cen[i] * r.max(0.0);
                out[i] += r * r;
            }
        }
    }

    /// Summed squared error over observations and channels under `p`.
    pub fn sse(&mut self, p: &BrdfParams, intensity: [f64; 3]) -> f64 {
        let mut e = std::mem::take(&mut self.scratch);
        self.errors(p, intensity, &mut e);
        let s = lane_sum(&e);
        self.scratch = e;
        s
    }
}

/// Squared residual of a prediction, zero for a censored channel predicted above its
/// bound (`cen` is 1 for a clipped channel).
#[inline(always)]
pub(crate) fn r0_sq(r: f32, cen: f32) -> f32 {
    let r = r - cen * r.max(0.0);
    r * r
}

/// A padded buffer as arrays of [`LANES`] values (the padding makes its length a
/// multiple of [`LANES`]).
#[inline(always)]
pub(crate) fn lanes(v: &[f32]) -> std::slice::Iter<'_, [f32; LANES]> {
    v.as_chunks::<LANES>().0.iter()
}

/// `N` scratch buffers of per-observation values, kept between calls.
#[derive(Debug, Clone)]
pub(crate) struct Rows<const N: usize>([Vec<f32>; N]);

impl<const N: usize> Default for Rows<N> {
    fn default() -> Self {
        Self(std::array::from_fn(|_| Vec::new()))
    }
}

impl<const N: usize> Rows<N> {
    /// The buffers, each `n` long (their values are whatever the last call left).
    pub(crate) fn get(&mut self, n: usize) -> [&mut [f32]; N] {
        self.0.each_mut().map(|v| {
            v.resize(n, 0.0);
            &mut v[..n]
        })
    }
}

/// Sum with [`LANES`] partial sums, so that the loop vectorises.
fn lane_sum(v: &[f32]) -> f64 {
    let mut acc = [0f64; LANES];
    for chunk in v.chunks_exact(LANES) {
        for j in 0..LANES {
            acc[j] += f64::from(chunk[j]);
        }
    }
    let tail: f64 = v
        .chunks_exact(LANES)
        .remainder()
        .iter()
        .map(|e| f64::from(*e))
        .sum();
    acc.iter().sum::<f64>() + tail
}

type Mat5 = SMatrix<f64, 5, 5>;
type Vec5 = SVector<f64, 5>;

/// Cauchy weights (as square roots, into `b.robust`) from the residuals under `p`,
/// with the scale `k` times the robust spread of the pixel's residuals (1.4826 x their
/// median) and at least [`ROBUST_FLOOR`]. The cluster's specular lobe cannot follow a
/// pixel's own normal and roughness detail finer than the video resolves, so a few
/// frames near the highlight disagree with it by far more than the noise; in plain
/// least squares they pull the pixel's diffuse albedo and show as streaks and as the
/// outlines of those frames' footprints.
/// `b.shapes` must hold the shape terms under `p`.
fn cauchy_weights(b: &mut PixelBatch, p: &BrdfParams, intensity: [f64; 3], k: f64) {
    let mut e = std::mem::take(&mut b.scratch);
    b.errors_from_shapes(p, intensity, &mut e);
    let n = b.len();
    if n == 0 {
        b.scratch = e;
        return;
    }
    // The median of the squared errors, found in `robust` (overwritten below, in the
    // observations' order, from `e`): the same element as the median of their roots.
    b.robust[..n].copy_from_slice(&e[..n]);
    let med2 = *b.robust[..n]
        .select_nth_unstable_by(n / 2, f32::total_cmp)
        .1;
    let c = (k as f32 * 1.4826 * med2.sqrt()).max(ROBUST_FLOOR);
    let inv_c2 = 1.0 / (c * c);
    for (w, err2) in b.robust[..n].iter_mut().zip(&e[..n]) {
        *w = (1.0 / (1.0 + err2 * inv_c2)).sqrt();
    }
    b.scratch = e;
}

/// Smallest Cauchy scale of the refinement, linear RGB residual: about the noise of
/// a mid-grey 8-bit value.
const ROBUST_FLOOR: f32 = 0.004;

/// Cost, normal matrix and gradient of the refinement's five parameters (rho_d per
/// channel, then the two normal angles) at `p`; leaves `b.shapes` evaluated under `p`.
fn linearise(b: &mut PixelBatch, p: &BrdfParams, intensity: [f64; 3]) -> (f64, Mat5, Vec5) {
    shape_terms(b, p);
    accumulate(b, p, intensity)
}

/// The model's shape terms and their derivatives under `p`, into `b.shapes`.
fn shape_terms(b: &mut PixelBatch, p: &BrdfParams) {
    shapes_grad(&WardF32::new(&Prepared::new(*p)), &b.geom, &mut b.shapes);
}

/// [`linearise`] from shape terms already evaluated under `p` (a new set of robust
/// weights needs no new evaluation of the model).
fn accumulate(b: &mut PixelBatch, p: &BrdfParams, intensity: [f64; 3]) -> (f64, Mat5, Vec5) {
    let n = b.geom.padded_len();
    let sh = &b.shapes;
    let mut a = Mat5::zeros();
    let mut g = Vec5::zeros();
    let mut cost = 0.0;
    for c in 0..3 {
        let ic = intensity[c] as f32;
        let (rd, rs) = (p.rho_d[c] as f32, p.rho_s[c] as f32);
        // Lane-wise partial sums: cost, J_d^2, J_d J_t0, J_d J_t1, J_t0^2, J_t0 J_t1,
        // J_t1^2, J_d r, J_t0 r, J_t1 r.
        let mut acc = [[0f32; LANES]; 10];
        let mut acc_cost = [0f64; LANES];
        let (d, s, y, cen) = (&sh.d[..n], &sh.s[..n], &b.rgb[c][..n], &b.censor[c][..n]);
        let rw = &b.robust[..n];
        let (dd0, dd1, r2, r3) = (
            &sh.dd[0][..n],
            &sh.dd[1][..n],
            &sh.rel[2][..n],
            &sh.rel[3][..n],
        );
        // The weighted residuals and Jacobian rows in one pass over every observation
        // (it vectorises as the shape terms do), then their products in lanes.
        let [rr, jd, j0, j1] = b.rows.get(n);
        for i in 0..n {
            let r = ic * (rd * d[i] + rs * s[i]) - y[i];
            // A censored channel predicted above its bound has no residual and no
            // Jacobian row.
            let live = (1.0 - cen[i] * f32::from(u8::from(r > 0.0))) * rw[i];
            rr[i] = r * live;
            jd[i] = ic * d[i] * live;
            j0[i] = ic * (rd * dd0[i] + rs * s[i] * r2[i]) * live;
            j1[i] = ic * (rd * dd1[i] + rs * s[i] * r3[i]) * live;
        }
        for (((r, jd), j0), j1) in lanes(rr).zip(lanes(jd)).zip(lanes(j0)).zip(lanes(j1)) {
            for j in 0..LANES {
                acc_cost[j] += f64::from(r[j] * r[j]);
                acc[1][j] += jd[j] * jd[j];
                acc[2][j] += jd[j] * j0[j];
                acc[3][j] += jd[j] * j1[j];
                acc[4][j] += j0[j] * j0[j];
                acc[5][j] += j0[j] * j1[j];
                acc[6][j] += j1[j] * j1[j];
                acc[7][j] += jd[j] * r[j];
                acc[8][j] += j0[j] * r[j];
                acc[9][j] += j1[j] * r[j];
            }
        }
        let t: [f64; 10] = acc.map(|l| l.iter().map(|v| f64::from(*v)).sum());
        cost += acc_cost.iter().sum::<f64>();
        a[(c, c)] += t[1];
        a[(c, 3)] += t[2];
        a[(3, c)] += t[2];
        a[(c, 4)] += t[3];
        a[(4, c)] += t[3];
        a[(3, 3)] += t[4];
        a[(3, 4)] += t[5];
        a[(4, 3)] += t[5];
        a[(4, 4)] += t[6];
        g[c] += t[7];
        g[3] += t[8];
        g[4] += t[9];
    }
    (cost, a, g)
}

/// How [`refine_pixel`] fits (the `refine_*` fields of [`crate::FitConfig`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RefineSettings {
    /// Strength of the pull towards the start, in average observations.
    pub prior: f64,
    /// Levenberg-Marquardt iterations per round.
    pub iterations: usize,
    /// Cauchy scale in units of the pixel's robust residual spread (0: least squares).
    pub robust: f64,
    /// Rounds; each after the first recomputes the Cauchy weights (>= 1).
    pub rounds: usize,
}

/// Per-pixel refinement of diffuse albedo and the normal angles (the other parameters
/// stay at the cluster's `init`), pulled towards `init` by a prior as strong as
/// `strength` average observations of each parameter: bounded Levenberg-Marquardt as
/// in [`crate::solver::Problem::solve_near`], with `0 <= rho_d <= 1 - rho_s` and the
/// normal angles inside `bounds`.
pub fn refine_pixel(
    b: &mut PixelBatch,
    init: &BrdfParams,
    intensity: [f64; 3],
    bounds: &Bounds,
    settings: &RefineSettings,
) -> BrdfParams {
    let RefineSettings {
        prior: strength,
        iterations: max_iterations,
        robust,
        rounds,
    } = *settings;
    let hi: [f64; 5] = [
        (1.0 - init.rho_s[0]).max(0.0),
        (1.0 - init.rho_s[1]).max(0.0),
        (1.0 - init.rho_s[2]).max(0.0),
        bounds.normal_hi[0],
        bounds.normal_hi[1],
    ];
    let lo: [f64; 5] = [0.0, 0.0, 0.0, bounds.normal_lo[0], bounds.normal_lo[1]];
    let to_x = |p: &BrdfParams| -> [f64; 5] {
        [
            p.rho_d[0],
            p.rho_d[1],
            p.rho_d[2],
            p.normal_theta_x,
            p.normal_theta_y,
        ]
    };
    let of_x = |x: &[f64; 5]| BrdfParams {
        rho_d: [x[0], x[1], x[2]],
        normal_theta_x: x[3],
        normal_theta_y: x[4],
        ..*init
    };
    let project = |x: &mut [f64; 5]| {
        for k in 0..5 {
            x[k] = if x[k].is_finite() {
                x[k].clamp(lo[k], hi[k].max(lo[k]))
            } else {
                lo[k].max(0.0).min(hi[k])
            };
        }
    };
    let mut x = to_x(init);
    project(&mut x);
    let centre = x;
    shape_terms(b, &of_x(&x));
    if robust > 0.0 {
        cauchy_weights(b, &of_x(&x), intensity, robust);
    }
    let (mut data, mut jtj, mut jtr) = accumulate(b, &of_x(&x), intensity);
    // Whether `b.shapes` holds the model under `x` (not under a rejected trial).
    let mut shapes_at_x = true;
    let n = b.len().max(1) as f64;
    let weight: [f64; 5] = std::array::from_fn(|k| strength * jtj[(k, k)].max(1e-12) / n);
    let prior_cost =
        |x: &[f64; 5]| -> f64 { (0..5).map(|k| weight[k] * (x[k] - centre[k]).powi(2)).sum() };
    // Iteratively reweighted: each further round recomputes the Cauchy weights from the
    // residuals at the pixel's own solution instead of its cluster's.
    for round in 0..rounds.max(1) {
        if round > 0 {
            if robust <= 0.0 {
                break;
            }
            if !shapes_at_x {
                shape_terms(b, &of_x(&x));
            }
            cauchy_weights(b, &of_x(&x), intensity, robust);
            (data, jtj, jtr) = accumulate(b, &of_x(&x), intensity);
            shapes_at_x = true;
        }
        let mut total = data + prior_cost(&x);
        let mut lambda = 1e-3;
        for _ in 0..max_iterations {
            let mut a = jtj;
            let mut rhs = -jtr;
            for k in 0..5 {
                a[(k, k)] += weight[k];
                rhs[k] -= weight[k] * (x[k] - centre[k]);
            }
            let pressed: [bool; 5] = std::array::from_fn(|k| {
                let grad = -rhs[k];
                (x[k] <= lo[k] && grad > 0.0) || (x[k] >= hi[k] && grad < 0.0)
            });
            let Some(step) = damped_step(a, rhs, &pressed, lambda) else {
                lambda *= 10.0;
                if lambda > 1e10 {
                    break;
                }
                continue;
            };
            let mut trial = x;
            for k in 0..5 {
                trial[k] += step[k];
            }
            project(&mut trial);
            let (d, a2, g2) = linearise(b, &of_x(&trial), intensity);
            let t = d + prior_cost(&trial);
            shapes_at_x = t.is_finite() && t < total;
            if shapes_at_x {
                (x, jtj, jtr, total) = (trial, a2, g2, t);
                lambda = (lambda / 3.0).max(1e-9);
            } else {
                lambda *= 4.0;
                if lambda > 1e10 {
                    break;
                }
            }
        }
    }
    of_x(&x)
}

#[cfg(test)]
mod tests {
    use super::*;
    use svbrdf_core::brdf::{BrdfModel, Ward};
    use svbrdf_core::geometry::Vec3;
    use svbrdf_core::plane::{PlaneGrid, Region};

    use crate::observations::FrameGeometry;

    /// One 3x3-pixel patch observed from 30 flash positions, rendered with Ward.
    fn observed(truth: &BrdfParams, intensity: f64) -> Observations {
        let grid = PlaneGrid::new(Region::centred(0.3, 0.3), 10.0).unwrap();
        let frames: Vec<FrameGeometry> = (0..30)
            .map(|i| {
                let a = f64::from(i) * 0.9;
                let camera = Vec3::new(5.0 * a.cos(), 4.0 * a.sin(), 9.0 + f64::from(i % 4));
                FrameGeometry {
                    id: i,
                    camera,
                    light: camera + Vec3::new(1.3, -0.2, 0.0),
                    gain: 1.0,
                }
            })
            .collect();
        crate::observations::rendered(grid, frames, |_| *truth, intensity, false)
    }

    fn truth() -> BrdfParams {
        BrdfParams {
            rho_d: [0.35, 0.2, 0.1],
            rho_s: [0.2, 0.2, 0.2],
            alpha_x: 0.15,
            alpha_y: 0.25,
            normal_theta_x: 0.06,
            normal_theta_y: -0.04,
            tangent_rotation: 0.0,
        }
    }

    #[test]
    fn errors_match_the_generic_model_with_censoring() {
        let t = truth();
        let obs = observed(&t, 200.0);
        let mut b = PixelBatch::default();
        b.gather(&obs, 4, 1);
        let off = BrdfParams {
            rho_d: [0.3, 0.25, 0.1],
            ..t
        };
        let mut e = Vec::new();
        b.errors(&off, [200.0; 3], &mut e);
        let prep = Prepared::new(off);
        let mut total = 0.0;
        for (i, o) in obs.range(4).enumerate() {
            let v = Ward.radiance(&prep, &obs.light_view(4, o), 200.0);
            let c = obs.color(o);
            let cl = obs.clipped(o);
            let want: f64 = (0..3)
                .map(|k| crate::observations::residual(v[k], c[k], cl[k]).powi(2))
                .sum();
            assert!(
                (f64::from(e[i]) - want).abs() <= 1e-4 * want + 1e-9,
                "{i}: {} vs {want}",
                e[i]
            );
            total += want;
        }
        let sse = b.sse(&off, [200.0; 3]);
        assert!((sse - total).abs() <= 1e-4 * total);
    }

    #[test]
    fn refinement_finds_albedo_and_normal_from_a_nearby_start() {
        let t = truth();
        let obs = observed(&t, 200.0);
        let mut b = PixelBatch::default();
        b.gather(&obs, 4, 1);
        let start = BrdfParams {
            rho_d: [0.3, 0.25, 0.12],
            normal_theta_x: 0.0,
            normal_theta_y: 0.0,
            ..t
        };
        let bounds = Bounds::symmetric(0.02, 1.0, 0.2);
        let p = refine_pixel(&mut b, &start, [200.0; 3], &bounds, &settings(0.0, 0.0, 1));
        for c in 0..3 {
            assert!((p.rho_d[c] - t.rho_d[c]).abs() < 2e-3, "{p:?}");
        }
        assert!((p.normal_theta_x - t.normal_theta_x).abs() < 2e-3, "{p:?}");
        assert!((p.normal_theta_y - t.normal_theta_y).abs() < 2e-3, "{p:?}");
        // A strong prior holds the start; tight bounds hold the normal.
        let held = refine_pixel(&mut b, &start, [200.0; 3], &bounds, &settings(1e9, 0.0, 1));
        assert!((held.rho_d[0] - start.rho_d[0]).abs() < 1e-4, "{held:?}");
        let tight = Bounds {
            normal_lo: [-0.01; 2],
            normal_hi: [0.01; 2],
            ..bounds
        };
        let p = refine_pixel(&mut b, &start, [200.0; 3], &tight, &settings(0.0, 0.0, 1));
        assert!(p.normal_theta_x <= 0.01 + 1e-12 && p.normal_theta_y >= -0.01 - 1e-12);
        assert!(p.is_physical());
    }

    fn settings(prior: f64, robust: f64, rounds: usize) -> RefineSettings {
        RefineSettings {
            prior,
            iterations: 30,
            robust,
            rounds,
        }
    }

    #[test]
    fn robust_refinement_discounts_observations_the_lobe_cannot_explain() {
        let t = truth();
        let mut obs = observed(&t, 200.0);
        // Three of the pixel's thirty observations carry light the model's lobe does
        // not predict (a neighbour's highlight blurred in, a glint).
        let r = obs.range(4);
        for o in r.step_by(10) {
            for v in obs.rgb[o].iter_mut() {
                if *v != CLIPPED {
                    *v = (*v)
                        .saturating_add((0.4 * RGB_SCALE) as u16)
                        .min(CLIPPED - 1);
                }
            }
        }
        let mut b = PixelBatch::default();
        let start = BrdfParams {
            rho_d: [0.3, 0.25, 0.12],
            ..t
        };
        let bounds = Bounds::symmetric(0.02, 1.0, 0.2);
        let err = |p: &BrdfParams| {
            (0..3)
                .map(|c| (p.rho_d[c] - t.rho_d[c]).abs())
                .fold(0.0, f64::max)
        };
        b.gather(&obs, 4, 1);
        let plain = refine_pixel(&mut b, &start, [200.0; 3], &bounds, &settings(0.0, 0.0, 1));
        b.gather(&obs, 4, 1);
        let robust = refine_pixel(&mut b, &start, [200.0; 3], &bounds, &settings(0.0, 1.0, 1));
        assert!(
            err(&plain) > 0.02,
            "outliers should bias least squares: {plain:?}"
        );
        assert!(err(&robust) < 0.25 * err(&plain), "{robust:?} vs {plain:?}");
        assert!(robust.is_physical());
        // Reweighting at the pixel's own solution does not undo it.
        b.gather(&obs, 4, 1);
        let rounds = refine_pixel(&mut b, &start, [200.0; 3], &bounds, &settings(0.0, 1.0, 3));
        assert!(
            err(&rounds) <= err(&robust) + 1e-4,
            "{rounds:?} vs {robust:?}"
        );
        // Gathering again resets the weights.
        b.gather(&obs, 4, 1);
        assert!(b.robust.iter().all(|w| *w == 1.0));
    }
}
