//! Bounded Levenberg-Marquardt for eq. (11): minimise the weighted squared radiance
//! error of one BRDF over a set of observations, subject to `rho_d, rho_s >= 0`,
//! `rho_d + rho_s <= 1` per channel, `alpha_min <= alpha <= alpha_max` and
//! `|theta| <= max_normal`, with the analytic derivatives of the core's models.
//!
//! Constraints are kept by projection: bound-active parameters whose gradient points
//! out of the feasible box are frozen for the step (an active-set rule), the step is
//! clipped back into the box, and a channel whose `rho_d + rho_s` exceeds 1 is scaled
//! back onto the constraint. Every iterate is feasible, so a fit stopped early is still
//! a physical material.

use nalgebra::{SMatrix, SVector};

use crate::observations::residual;
use svbrdf_core::brdf::{BrdfModel, BrdfParams, LightView, ModelKind, Prepared, N_PARAMS};

use crate::sample_batch::SampleBatch;

type Mat = SMatrix<f64, N_PARAMS, N_PARAMS>;
type Vector = SVector<f64, N_PARAMS>;

/// One (possibly binned) observation.
#[derive(Debug, Clone, Copy)]
pub struct Sample {
    /// Geometry.
    pub lv: LightView,
    /// Observed linear RGB.
    pub rgb: [f64; 3],
    /// Weight (the number of raw observations averaged into it).
    pub weight: f64,
    /// Channels that were clipped: `rgb` is then a lower bound (see
    /// [`crate::observations::residual`]).
    pub clipped: [bool; 3],
}

/// Which parameters move.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Freedom {
    /// Per parameter (order of [`BrdfParams::to_array`]): free or fixed.
    pub free: [bool; N_PARAMS],
    /// `alpha_y` follows `alpha_x` (isotropic model).
    pub isotropic: bool,
}

impl Freedom {
    /// The paper's first fit: isotropic, flat normal.
    pub const ISOTROPIC_FLAT: Self = Self {
        free: [
            true, true, true, true, true, true, true, false, false, false,
        ],
        isotropic: true,
    };
    /// Anisotropic with a normal offset: all ten.
    pub const FULL: Self = Self {
        free: [true; N_PARAMS],
        isotropic: false,
    };
    /// Per-pixel refinement: diffuse albedo and normal.
    pub const DIFFUSE_AND_NORMAL: Self = Self {
        free: [
            true, true, true, false, false, false, false, false, true, true,
        ],
        isotropic: false,
    };
}

/// Bounds of eq. (11).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Bounds {
    /// Smallest alpha.
    pub alpha_min: f64,
    /// Largest alpha.
    pub alpha_max: f64,
    /// Lower bounds of the two normal angles, radians.
    pub normal_lo: [f64; 2],
    /// Upper bounds of the two normal angles, radians.
    pub normal_hi: [f64; 2],
    /// Enforce `rho_d + rho_s <= 1` per channel (off only while the light intensity
    /// is being normalised, when albedo units are not fixed yet).
    pub energy: bool,
    /// Hold `rho_s = 0`: the diffuse-only baseline of held-out evaluation.
    pub diffuse_only: bool,
}

impl Bounds {
    /// Bounds with `|theta| <= max_normal` for both normal angles.
    pub fn symmetric(alpha_min: f64, alpha_max: f64, max_normal: f64) -> Self {
        Self {
            alpha_min,
            alpha_max,
            normal_lo: [-max_normal; 2],
            normal_hi: [max_normal; 2],
            energy: true,
            diffuse_only: false,
        }
    }

    /// Project a parameter vector into the feasible set.
    pub fn project(&self, x: &mut [f64; N_PARAMS], fr: &Freedom) {
        let b = self;
        for v in x.iter_mut().take(6) {
            *v = if v.is_finite() { v.max(0.0) } else { 0.0 };
        }
        if b.diffuse_only {
            x[3..6].fill(0.0);
        }
        for c in 0..3 {
            let s = x[c] + x[3 + c];
            if b.energy && s > 1.0 {
                x[c] /= s;
                x[3 + c] /= s;
            }
        }
        for k in 6..8 {
            x[k] = if x[k].is_finite() {
                x[k].clamp(b.alpha_min, b.alpha_max)
            } else {
                0.1_f64.clamp(b.alpha_min, b.alpha_max)
            };
        }
        if fr.isotropic {
            x[7] = x[6];
        }
        for k in 8..10 {
            x[k] = if x[k].is_finite() {
                x[k].clamp(b.normal_lo[k - 8], b.normal_hi[k - 8])
            } else {
                0.0
            };
        }
    }
}

/// A quadratic pull towards `centre`: adds `sum_k weight[k] * (x_k - centre_k)^2`.
#[derive(Debug, Clone, Copy)]
pub struct Prior {
    /// Where the pull points.
    pub centre: [f64; N_PARAMS],
    /// Weight per parameter.
    pub weight: [f64; N_PARAMS],
}

/// One damped Gauss-Newton step of `a x = rhs` (`rhs` is minus the gradient):
/// parameters marked `frozen` (fixed, or pressed against a bound by the gradient) get no
/// step, the others Marquardt's damping `lambda * a_kk`. `None` when the damped matrix
/// is not positive definite (raise `lambda`).
pub fn damped_step<const N: usize>(
    mut a: SMatrix<f64, N, N>,
    mut rhs: SVector<f64, N>,
    frozen: &[bool; N],
    lambda: f64,
) -> Option<SVector<f64, N>> {
    for k in 0..N {
        if frozen[k] {
            for j in 0..N {
                a[(k, j)] = 0.0;
                a[(j, k)] = 0.0;
            }
            a[(k, k)] = 1.0;
            rhs[k] = 0.0;
        } else {
            a[(k, k)] += lambda * a[(k, k)].max(1e-12);
        }
    }
    a.cholesky().map(|c| c.solve(&rhs))
}

/// Outcome of one fit.
#[derive(Debug, Clone, Copy)]
pub struct Solution {
    /// Fitted parameters (always feasible).
    pub params: BrdfParams,
    /// Final weighted sum of squared errors (without the prior).
    pub cost: f64,
    /// Accepted iterations.
    pub iterations: usize,
    /// Whether it stopped because progress stalled rather than at the iteration cap.
    pub converged: bool,
}

/// The problem: model, data, per-channel light intensity.
pub struct Problem<'a> {
    /// Reflectance model.
    pub model: &'a dyn BrdfModel,
    /// Observations.
    pub samples: &'a [Sample],
    /// Light intensity per channel.
    pub intensity: [f64; 3],
    /// Bounds.
    pub bounds: Bounds,
    /// Stop when an accepted step lowers the cost by less than this fraction.
    pub tolerance: f64,
}

impl Problem<'_> {
    /// Project a parameter vector into the feasible set.
    pub fn project(&self, x: &mut [f64; N_PARAMS], fr: &Freedom) {
        self.bounds.project(x, fr);
    }

    /// Weighted sum of squared errors at `x` with the tangent rotated by `rotation`
    /// radians ([`BrdfParams::tangent_rotation`]).
    pub fn cost(&self, x: &[f64; N_PARAMS], rotation: f64) -> f64 {
        let p = Prepared::new(BrdfParams::from_array_rotated(x, rotation));
        let mut s = 0.0;
        for o in self.samples {
            let v = self.model.radiance(&p, &o.lv, 1.0);
            let mut e = 0.0;
            for c in 0..3 {
                e += residual(v[c] * self.intensity[c], o.rgb[c], o.clipped[c]).powi(2);
            }
            s += o.weight * e;
        }
        s
    }

    /// Cost, J^T W J and J^T W r at `x`.
    fn linearise(&self, x: &[f64; N_PARAMS], fr: &Freedom, rotation: f64) -> (f64, Mat, Vector) {
        let p = Prepared::new(BrdfParams::from_array_rotated(x, rotation));
        let mut jtj = Mat::zeros();
        let mut jtr = Vector::zeros();
        let mut cost = 0.0;
        for o in self.samples {
            let g = self.model.radiance_grad(&p, &o.lv, 1.0);
            for c in 0..3 {
                let i = self.intensity[c];
                let r = residual(g.value[c] * i, o.rgb[c], o.clipped[c]);
                if r == 0.0 && o.clipped[c] {
                    continue;
                }
                cost += o.weight * r * r;
                // Non-zero Jacobian entries of this channel's residual.
                let mut idx = [0usize; 6];
                let mut val = [0.0; 6];
                idx[0] = c;
                val[0] = g.d_rho_d[c] * i;
                idx[1] = 3 + c;
                val[1] = g.d_rho_s[c] * i;
                let mut n = 2;
                if fr.isotropic {
                    idx[n] = 6;
                    val[n] = (g.d_shared[0][c] + g.d_shared[1][c]) * i;
                    n += 1;
                } else {
                    idx[n] = 6;
                    val[n] = g.d_shared[0][c] * i;
                    idx[n + 1] = 7;
                    val[n + 1] = g.d_shared[1][c] * i;
                    n += 2;
                }
                idx[n] = 8;
                val[n] = g.d_shared[2][c] * i;
                idx[n + 1] = 9;
                val[n + 1] = g.d_shared[3][c] * i;
                n += 2;
                for a in 0..n {
                    let wa = o.weight * val[a];
                    jtr[idx[a]] += wa * r;
                    for b in 0..n {
                        jtj[(idx[a], idx[b])] += wa * val[b];
                    }
                }
            }
        }
        (cost, jtj, jtr)
    }

    /// Fit from `init`, pulled towards `init` by a prior as strong as `strength`
    /// average samples of each parameter: weight `strength * (J^T W J)_kk / n` from the
    /// Jacobian at `init` (scale-free: no per-parameter tuning). Ward takes the f32
    /// batch path ([`solve_near_ward`]).
    pub fn solve_near(
        &self,
        init: &BrdfParams,
        fr: &Freedom,
        strength: f64,
        max_iterations: usize,
    ) -> Solution {
        if self.model.kind() == ModelKind::Ward {
            let mut batch = SampleBatch::new(self.samples);
            return solve_near_ward(
                &mut batch,
                &self.settings(),
                init,
                fr,
                strength,
                max_iterations,
            );
        }
        let mut data = Generic {
            problem: self,
            fr,
            rotation: init.tangent_rotation,
        };
        near(
            &mut data,
            &self.settings(),
            init,
            fr,
            strength,
            max_iterations,
        )
    }

    /// Fit from `init` with the given freedom, optional prior and iteration cap.
    pub fn solve(
        &self,
        init: &BrdfParams,
        fr: &Freedom,
        prior: Option<&Prior>,
        max_iterations: usize,
    ) -> Solution {
        let mut x = init.to_array();
        self.project(&mut x, fr);
        let rotation = init.tangent_rotation;
        let settings = self.settings();
        let fit = |data: &mut dyn DataTerm| {
            levenberg_marquardt(data, x, fr, &settings, prior, max_iterations, None)
        };
        if self.model.kind() == ModelKind::Ward {
            // The f32 batch path: the same figures to about 1e-5 relative.
            let mut batch = SampleBatch::new(self.samples);
            fit(&mut WardBatch {
                batch: &mut batch,
                intensity: self.intensity,
                isotropic: fr.isotropic,
                rotation,
            })
        } else {
            fit(&mut Generic {
                problem: self,
                fr,
                rotation,
            })
        }
    }

    /// What the solver loop needs of the problem besides its data.
    fn settings(&self) -> SolveSettings {
        SolveSettings {
            intensity: self.intensity,
            bounds: self.bounds,
            tolerance: self.tolerance,
        }
    }
}

/// Light intensity, bounds and stopping tolerance of one fit (the fields of
/// [`Problem`] other than its model and samples).
#[derive(Debug, Clone, Copy)]
pub(crate) struct SolveSettings {
    /// Light intensity per channel.
    pub intensity: [f64; 3],
    /// Bounds.
    pub bounds: Bounds,
    /// Stop when an accepted step lowers the cost by less than this fraction.
    pub tolerance: f64,
}

/// The data term of a fit: its cost, and its cost with `J^T W J` and `J^T W r`, at a
/// parameter vector (the tangent rotation is the data term's, held fixed).
trait DataTerm {
    /// Cost, `J^T W J` and `J^T W r` at `x`.
    fn linearise(&mut self, x: &[f64; N_PARAMS]) -> (f64, Mat, Vector);
    /// Cost at `x`.
    fn cost(&mut self, x: &[f64; N_PARAMS]) -> f64;
    /// Samples (the prior's average is over them).
    fn len(&self) -> usize;
    /// The tangent rotation, radians.
    fn rotation(&self) -> f64;
}

/// Any model on [`Sample`]s, in f64.
struct Generic<'a, 'b> {
    problem: &'a Problem<'b>,
    fr: &'a Freedom,
    rotation: f64,
}

impl DataTerm for Generic<'_, '_> {
    fn linearise(&mut self, x: &[f64; N_PARAMS]) -> (f64, Mat, Vector) {
        self.problem.linearise(x, self.fr, self.rotation)
    }
    fn cost(&mut self, x: &[f64; N_PARAMS]) -> f64 {
        self.problem.cost(x, self.rotation)
    }
    fn len(&self) -> usize {
        self.problem.samples.len()
    }
    fn rotation(&self) -> f64 {
        self.rotation
    }
}

/// Ward on a [`SampleBatch`], in f32 lanes.
struct WardBatch<'a> {
    batch: &'a mut SampleBatch,
    intensity: [f64; 3],
    isotropic: bool,
    rotation: f64,
}

impl DataTerm for WardBatch<'_> {
    fn linearise(&mut self, x: &[f64; N_PARAMS]) -> (f64, Mat, Vector) {
        let p = BrdfParams::from_array_rotated(x, self.rotation);
        self.batch.linearise(&p, self.intensity, self.isotropic)
    }
    fn cost(&mut self, x: &[f64; N_PARAMS]) -> f64 {
        let p = BrdfParams::from_array_rotated(x, self.rotation);
        self.batch.cost(&p, self.intensity)
    }
    fn len(&self) -> usize {
        self.batch.len()
    }
    fn rotation(&self) -> f64 {
        self.rotation
    }
}

/// [`Problem::solve_near`] for Ward on samples already in batch form (the per-pixel
/// specular refinement gathers each pixel's raw observations straight into one,
/// without building [`Sample`]s).
pub(crate) fn solve_near_ward(
    batch: &mut SampleBatch,
    settings: &SolveSettings,
    init: &BrdfParams,
    fr: &Freedom,
    strength: f64,
    max_iterations: usize,
) -> Solution {
    let mut data = WardBatch {
        batch,
        intensity: settings.intensity,
        isotropic: fr.isotropic,
        rotation: init.tangent_rotation,
    };
    near(&mut data, settings, init, fr, strength, max_iterations)
}

/// [`Problem::solve_near`] on any data term.
fn near(
    data: &mut dyn DataTerm,
    settings: &SolveSettings,
    init: &BrdfParams,
    fr: &Freedom,
    strength: f64,
    max_iterations: usize,
) -> Solution {
    let mut x = init.to_array();
    settings.bounds.project(&mut x, fr);
    let first = data.linearise(&x);
    let n = data.len().max(1) as f64;
    let prior = Prior {
        centre: x,
        weight: std::array::from_fn(|k| strength * first.1[(k, k)].max(1e-12) / n),
    };
    levenberg_marquardt(
        data,
        x,
        fr,
        settings,
        Some(&prior),
        max_iterations,
        Some(first),
    )
}

/// The solver loop from the feasible `x` (the data term's tangent rotation is held
/// fixed); `first` is the data term's linearisation at `x` when already known.
fn levenberg_marquardt(
    data: &mut dyn DataTerm,
    mut x: [f64; N_PARAMS],
    fr: &Freedom,
    settings: &SolveSettings,
    prior: Option<&Prior>,
    max_iterations: usize,
    first: Option<(f64, Mat, Vector)>,
) -> Solution {
    let prior_cost = |x: &[f64; N_PARAMS]| {
        prior.map_or(0.0, |p| {
            (0..N_PARAMS)
                .map(|k| p.weight[k] * (x[k] - p.centre[k]).powi(2))
                .sum()
        })
    };
    let add_prior = |x: &[f64; N_PARAMS], (c, mut a, mut g): (f64, Mat, Vector)| {
        if let Some(p) = prior {
            for k in 0..N_PARAMS {
                a[(k, k)] += p.weight[k];
                g[k] += p.weight[k] * (x[k] - p.centre[k]);
            }
        }
        (c, a, g)
    };
    let first = match first {
        Some(f) => f,
        None => data.linearise(&x),
    };
    let (mut data_cost, mut jtj, mut jtr) = add_prior(&x, first);
    let mut total = data_cost + prior_cost(&x);
    let mut lambda = 1e-3;
    let mut iterations = 0;
    let mut converged = false;
    let b = settings.bounds;
    for it in 0..max_iterations {
        // Active set: fixed parameters and parameters pressed against a bound.
        let mut active = [false; N_PARAMS];
        for k in 0..N_PARAMS {
            let g = jtr[k];
            let at_low = match k {
                0..=5 => x[k] <= 0.0,
                6 | 7 => x[k] <= b.alpha_min,
                _ => x[k] <= b.normal_lo[k - 8],
            };
            let at_high = match k {
                0..=5 => false,
                6 | 7 => x[k] >= b.alpha_max,
                _ => x[k] >= b.normal_hi[k - 8],
            };
            active[k] = !fr.free[k]
                || (fr.isotropic && k == 7)
                || (at_low && g > 0.0)
                || (at_high && g < 0.0);
        }
        let Some(step) = damped_step(jtj, -jtr, &active, lambda) else {
            lambda *= 10.0;
            if lambda > 1e10 {
                converged = true;
                break;
            }
            continue;
        };

        let mut trial = x;
        for k in 0..N_PARAMS {
            trial[k] += step[k];
        }
        b.project(&mut trial, fr);
        let new_data = data.cost(&trial);
        let new_total = new_data + prior_cost(&trial);
        if new_total.is_finite() && new_total < total {
            let rel = (total - new_total) / total.max(1e-300);
            x = trial;
            iterations += 1;
            lambda = (lambda / 3.0).max(1e-9);
            // No linearisation at the last point: nothing would use it (the per-pixel
            // refinements stop after three iterations, so this is one of seven).
            converged = rel < settings.tolerance;
            if converged || it + 1 == max_iterations {
                data_cost = new_data;
                break;
            }
            (data_cost, jtj, jtr) = add_prior(&x, data.linearise(&x));
            total = data_cost + prior_cost(&x);
        } else {
            lambda *= 4.0;
            if lambda > 1e10 {
                converged = true;
                break;
            }
        }
    }
    Solution {
        params: BrdfParams::from_array_rotated(&x, data.rotation()),
        cost: data_cost,
        iterations,
        converged,
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;
    use svbrdf_core::brdf::{Ggx, Ward};
    use svbrdf_core::geometry::Vec3;

    /// Flash-like observations of one surface point from a hand-held sweep.
    /// Flash observations of one surface from a hand-held sweep over a 4 cm patch.
    pub(crate) fn samples(
        model: &dyn BrdfModel,
        truth: &BrdfParams,
        n: usize,
        seed: u64,
    ) -> Vec<Sample> {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let p = Prepared::new(*truth);
        (0..n)
            .map(|_| {
                let cam = Vec3::new(
                    rng.random_range(-6.0..6.0),
                    rng.random_range(-6.0..6.0),
                    rng.random_range(9.0..16.0),
                );
                let surf = Vec3::new(
                    rng.random_range(-2.0..2.0),
                    rng.random_range(-2.0..2.0),
                    0.0,
                );
                let lv = LightView::from_points(surf, cam + Vec3::new(1.4, -0.3, 0.0), cam);
                let v = model.radiance(&p, &lv, 300.0);
                Sample {
                    lv,
                    rgb: v,
                    weight: 1.0,
                    clipped: [false; 3],
                }
            })
            .collect()
    }

    pub(crate) const BOUNDS: Bounds = Bounds {
        alpha_min: 0.02,
        alpha_max: 1.0,
        normal_lo: [-0.785; 2],
        normal_hi: [0.785; 2],
        energy: true,
        diffuse_only: false,
    };

    fn truth() -> BrdfParams {
        BrdfParams {
            rho_d: [0.4, 0.25, 0.1],
            rho_s: [0.12, 0.1, 0.08],
            alpha_x: 0.15,
            alpha_y: 0.3,
            normal_theta_x: 0.08,
            normal_theta_y: -0.05,
            tangent_rotation: 0.0,
        }
    }

    #[test]
    fn recovers_anisotropic_ward_with_normal_from_paper_start() {
        let t = truth();
        let s = samples(&Ward, &t, 600, 1);
        let prob = Problem {
            model: &Ward,
            samples: &s,
            intensity: [300.0; 3],
            bounds: BOUNDS,
            tolerance: 1e-9,
        };
        // Isotropic flat fit first, then full, as in the paper.
        let init = BrdfParams {
            rho_d: [0.3; 3],
            rho_s: [0.2; 3],
            ..BrdfParams::default()
        };
        let iso = prob.solve(&init, &Freedom::ISOTROPIC_FLAT, None, 100);
        assert!(iso.params.is_physical());
        assert_eq!(iso.params.alpha_x, iso.params.alpha_y);
        let full = prob.solve(&iso.params, &Freedom::FULL, None, 200);
        let f = full.params;
        assert!(full.cost < 1e-8 * s.len() as f64, "cost {}", full.cost);
        for c in 0..3 {
            assert!((f.rho_d[c] - t.rho_d[c]).abs() < 1e-3, "{f:?}");
            assert!((f.rho_s[c] - t.rho_s[c]).abs() < 1e-3, "{f:?}");
        }
        assert!((f.alpha_x - t.alpha_x).abs() < 1e-3 && (f.alpha_y - t.alpha_y).abs() < 1e-3);
        assert!((f.normal_theta_x - t.normal_theta_x).abs() < 1e-3);
        assert!((f.normal_theta_y - t.normal_theta_y).abs() < 1e-3);
    }

    #[test]
    fn ward_batch_path_matches_the_generic_linearisation() {
        let t = truth();
        let mut s = samples(&Ward, &t, 77, 5);
        for (i, o) in s.iter_mut().enumerate() {
            o.weight = 1.0 + (i % 4) as f64;
            // Censor some channels, below and above the prediction.
            if i % 9 == 0 {
                o.clipped = [true, false, i % 2 == 0];
                o.rgb[0] *= if i % 2 == 0 { 0.5 } else { 2.0 };
            }
        }
        let prob = Problem {
            model: &Ward,
            samples: &s,
            intensity: [300.0, 280.0, 310.0],
            bounds: BOUNDS,
            tolerance: 1e-9,
        };
        let x = BrdfParams {
            rho_d: [0.3, 0.3, 0.15],
            alpha_x: 0.2,
            normal_theta_y: 0.02,
            ..t
        };
        for fr in [Freedom::FULL, Freedom::ISOTROPIC_FLAT] {
            let (c, a, g) = prob.linearise(&x.to_array(), &fr, x.tangent_rotation);
            let (cb, ab, gb) = SampleBatch::new(&s).linearise(&x, prob.intensity, fr.isotropic);
            assert!((c - cb).abs() <= 1e-4 * c, "{c} vs {cb}");
            let close = |u: f64, v: f64, scale: f64| (u - v).abs() <= 1e-4 * scale + 1e-12;
            let amax = a.iter().fold(0.0f64, |m, v| m.max(v.abs()));
            let gmax = g.iter().fold(0.0f64, |m, v| m.max(v.abs()));
            for i in 0..N_PARAMS {
                assert!(close(g[i], gb[i], gmax), "grad {i}: {} vs {}", g[i], gb[i]);
                for j in 0..N_PARAMS {
                    assert!(close(a[(i, j)], ab[(i, j)], amax), "({i},{j})");
                }
            }
            let cost = SampleBatch::new(&s).cost(&x, prob.intensity);
            assert!((cost - prob.cost(&x.to_array(), x.tangent_rotation)).abs() <= 1e-4 * cost);
        }
    }

    #[test]
    fn recovers_ggx() {
        let t = truth();
        let s = samples(&Ggx, &t, 600, 2);
        let prob = Problem {
            model: &Ggx,
            samples: &s,
            intensity: [300.0; 3],
            bounds: BOUNDS,
            tolerance: 1e-9,
        };
        let init = BrdfParams {
            alpha_x: 0.2,
            alpha_y: 0.2,
            ..t
        };
        let full = prob.solve(&init, &Freedom::FULL, None, 200);
        assert!(
            (full.params.alpha_y - t.alpha_y).abs() < 1e-3,
            "{:?}",
            full.params
        );
        assert!((full.params.rho_d[0] - t.rho_d[0]).abs() < 1e-3);
    }

    #[test]
    fn constraints_hold_when_data_push_outside() {
        // A surface brighter than any physical albedo: the fit must stop on the
        // rho_d + rho_s = 1 face, never beyond.
        let t = BrdfParams {
            rho_d: [0.9; 3],
            rho_s: [0.3; 3],
            ..truth()
        };
        let s = samples(&Ward, &t, 300, 3);
        let prob = Problem {
            model: &Ward,
            samples: &s,
            intensity: [300.0; 3],
            bounds: BOUNDS,
            tolerance: 1e-9,
        };
        let sol = prob.solve(&BrdfParams::default(), &Freedom::FULL, None, 100);
        assert!(sol.params.is_physical(), "{:?}", sol.params);
        for c in 0..3 {
            assert!(sol.params.rho_d[c] + sol.params.rho_s[c] <= 1.0 + 1e-12);
        }
        assert!(sol.params.alpha_x >= BOUNDS.alpha_min);
    }

    #[test]
    fn strong_prior_holds_parameters() {
        let t = truth();
        let s = samples(&Ward, &t, 100, 4);
        let prob = Problem {
            model: &Ward,
            samples: &s,
            intensity: [300.0; 3],
            bounds: BOUNDS,
            tolerance: 1e-9,
        };
        let centre = BrdfParams {
            rho_d: [0.2; 3],
            ..t
        };
        let prior = Prior {
            centre: centre.to_array(),
            weight: [1e12; N_PARAMS],
        };
        let sol = prob.solve(&centre, &Freedom::DIFFUSE_AND_NORMAL, Some(&prior), 20);
        assert!((sol.params.rho_d[0] - 0.2).abs() < 1e-6);
        let free = prob.solve(&centre, &Freedom::DIFFUSE_AND_NORMAL, None, 50);
        assert!(
            (free.params.rho_d[0] - t.rho_d[0]).abs() < 1e-4,
            "{:?}",
            free.params
        );
    }
}
