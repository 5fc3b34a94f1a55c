//! A cluster's binned samples, or one pixel's raw observations, in the core's f32 batch
//! form, for the Ward Levenberg-Marquardt iterations over all ten parameters: the
//! cluster fits, the lobe refits and the per-pixel lobes
//! ([`crate::solver::solve_near_ward`]). The generic f64 path of
//! [`crate::solver::Problem`] is the reference the tests compare against.

use nalgebra::{SMatrix, SVector};
use svbrdf_core::brdf::batch::{shapes, shapes_grad, GeometryBatch, Shapes, WardF32, LANES};
use svbrdf_core::brdf::{BrdfParams, Prepared, N_PARAMS};

use crate::fast::{lanes, r0_sq, Rows};
use crate::observations::Observations;
use crate::solver::Sample;

/// Binned samples (weighted, possibly censored) of a cluster in batch form, for the
/// cluster fits' Levenberg-Marquardt iterations.
#[derive(Debug, Clone, Default)]
pub struct SampleBatch {
    geom: GeometryBatch,
    rgb: [Vec<f32>; 3],
    censor: [Vec<f32>; 3],
    weight: Vec<f32>,
    shapes: Shapes,
    rows: Rows<8>,
}

type Mat10 = SMatrix<f64, N_PARAMS, N_PARAMS>;
type Vec10 = SVector<f64, N_PARAMS>;

impl SampleBatch {
    /// From samples.
    pub fn new(samples: &[Sample]) -> Self {
        let mut b = Self::default();
        b.geom.begin(samples.len());
        b.geom.ambient = samples.first().map_or(0.0, |s| s.lv.ambient as f32);
        let padded = b.geom.padded_len();
        for a in b.rgb.iter_mut().chain(b.censor.iter_mut()) {
            a.resize(padded, 0.0);
        }
        b.weight.resize(padded, 0.0);
        for (i, o) in samples.iter().enumerate() {
            // Unit directions and r^2: offsets of length r along the light, any
            // length along the view.
            let r = o.lv.light_dist2.sqrt();
            let l = o.lv.light * r;
            b.geom.set(
                i,
                [l.x as f32, l.y as f32, l.z as f32],
                [o.lv.view.x as f32, o.lv.view.y as f32, o.lv.view.z as f32],
            );
            for k in 0..3 {
                b.rgb[k][i] = o.rgb[k] as f32;
                b.censor[k][i] = if o.clipped[k] { 1.0 } else { 0.0 };
            }
            b.weight[i] = o.weight as f32;
        }
        b.geom.finish();
        b
    }

    /// The raw observations of pixel `px`, each of weight 1 (what
    /// [`new`](Self::new) makes of [`Observations::light_view`] and
    /// [`Observations::color`] samples, without building them); reuses the buffers.
    pub fn gather(&mut self, obs: &Observations, px: usize) {
        let r = obs.range(px);
        self.geom.begin(r.len());
        self.geom.ambient = obs.ambient as f32;
        let padded = self.geom.padded_len();
        for a in self.rgb.iter_mut().chain(self.censor.iter_mut()) {
            a.clear();
            a.resize(padded, 0.0);
        }
        self.weight.clear();
        self.weight.resize(padded, 0.0);
        let s = obs.surface(px);
        for (i, o) in r.enumerate() {
            let f = &obs.frames[usize::from(obs.frame[o])];
            let (dl, dv) = (f.light - s, f.camera - s);
            self.geom.set(
                i,
                [dl.x as f32, dl.y as f32, dl.z as f32],
                [dv.x as f32, dv.y as f32, dv.z as f32],
            );
            let (rgb, clipped) = (obs.color(o), obs.clipped(o));
            for k in 0..3 {
                self.rgb[k][i] = rgb[k] as f32;
                self.censor[k][i] = if clipped[k] { 1.0 } else { 0.0 };
            }
            self.weight[i] = 1.0;
        }
        self.geom.finish();
    }

    /// Samples held.
    pub fn len(&self) -> usize {
        self.geom.len()
    }

    /// Whether none are held.
    pub fn is_empty(&self) -> bool {
        self.geom.is_empty()
    }

    /// Weighted sum of squared errors.
    pub fn cost(&mut self, p: &BrdfParams, intensity: [f64; 3]) -> f64 {
        let w = WardF32::new(&Prepared::new(*p));
        shapes(&w, &self.geom, &mut self.shapes);
        let n = self.geom.padded_len();
        // Costs are summed in f64: the solver compares them to 1e-4 relative over tens
        // of thousands of samples.
        let mut acc = [0f64; LANES];
        for c in 0..3 {
            let (kd, ks) = (
                (p.rho_d[c] * intensity[c]) as f32,
                (p.rho_s[c] * intensity[c]) as f32,
            );
            let (d, s, y, cen, wt) = (
                &self.shapes.d[..n],
                &self.shapes.s[..n],
                &self.rgb[c][..n],
                &self.censor[c][..n],
                &self.weight[..n],
            );
            // The weighted squares in one pass (it vectorises), then summed in lanes.
            let [sq, ..] = self.rows.get(n);
            for i in 0..n {
                let r = kd * d[i] + ks * s[i] - y[i];
                let r = r - cen[i] * r.max(0.0);
                sq[i] = wt[i] * r * r;
            }
            for sq in lanes(sq) {
                for j in 0..LANES {
                    acc[j] += f64::from(sq[j]);
                }
            }
        }
        acc.iter().sum()
    }

    /// Cost, `J^T W J` and `J^T W r` over all ten parameters (with `isotropic`,
    /// `alpha_y` follows `alpha_x`: its derivative is added to index 6 and index 7 is
    /// left empty), as [`crate::solver::Problem`]'s generic path computes them.
    pub fn linearise(
        &mut self,
        p: &BrdfParams,
        intensity: [f64; 3],
        isotropic: bool,
    ) -> (f64, Mat10, Vec10) {
        let w = WardF32::new(&Prepared::new(*p));
        shapes_grad(&w, &self.geom, &mut self.shapes);
        let n = self.geom.padded_len();
        let sh = &self.shapes;
        let mut a = Mat10::zeros();
        let mut g = Vec10::zeros();
        let mut cost = 0.0;
        for c in 0..3 {
            let ic = intensity[c] as f32;
            let (rd, rs) = (p.rho_d[c] as f32, p.rho_s[c] as f32);
            // Lane sums: cost, the 21 products of the upper triangle of the 6x6 block
            // (rho_d, rho_s, alpha_x, alpha_y, theta_x, theta_y), then 6 of J r.
            let mut acc = [[0f32; LANES]; 28];
            let mut acc_cost = [0f64; LANES];
            let (d, s, y, cen, wt) = (
                &sh.d[..n],
                &sh.s[..n],
                &self.rgb[c][..n],
                &self.censor[c][..n],
                &self.weight[..n],
            );
            let (dd0, dd1) = (&sh.dd[0][..n], &sh.dd[1][..n]);
            let (r0, r1, r2, r3) = (
                &sh.rel[0][..n],
                &sh.rel[1][..n],
                &sh.rel[2][..n],
                &sh.rel[3][..n],
            );
            // The weighted Jacobian rows, residuals and squared errors in one pass over
            // every sample (it vectorises as the shape terms do), then their sums in lanes.
            let [j0, j1, j2, j3, j4, j5, res, sq] = self.rows.get(n);
            for i in 0..n {
                let r = ic * (rd * d[i] + rs * s[i]) - y[i];
                sq[i] = wt[i] * r0_sq(r, cen[i]);
                let live = 1.0 - cen[i] * f32::from(u8::from(r > 0.0));
                let sw = wt[i].sqrt() * live;
                res[i] = r * sw;
                let ss = ic * rs * s[i] * sw;
                j0[i] = ic * d[i] * sw;
                j1[i] = ic * s[i] * sw;
                j2[i] = ss * r0[i];
                j3[i] = ss * r1[i];
                j4[i] = ic * rd * dd0[i] * sw + ss * r2[i];
                j5[i] = ic * rd * dd1[i] * sw + ss * r3[i];
            }
            for sq in lanes(sq) {
                for l in 0..LANES {
                    acc_cost[l] += f64::from(sq[l]);
                }
            }
            let [j0, j1, j2, j3, j4, j5, res] = [j0, j1, j2, j3, j4, j5, res].map(|v| &*v);
            let jv = [j0, j1, j2, j3, j4, j5].map(|v| v.as_chunks::<LANES>().0);
            for (k, res) in lanes(res).enumerate() {
                let block = jv.map(|v| v[k]);
                let mut m = 1;
                for x in 0..6 {
                    for y2 in x..6 {
                        for l in 0..LANES {
                            acc[m][l] += block[x][l] * block[y2][l];
                        }
                        m += 1;
                    }
                }
                for x in 0..6 {
                    for l in 0..LANES {
                        acc[22 + x][l] += block[x][l] * res[l];
                    }
                }
            }
            let t: [f64; 28] = acc.map(|v| v.iter().map(|e| f64::from(*e)).sum());
            cost += acc_cost.iter().sum::<f64>();
            let mut block = [[0.0; 6]; 6];
            let mut m = 1;
            for x in 0..6 {
                for y2 in x..6 {
                    block[x][y2] = t[m];
                    block[y2][x] = t[m];
                    m += 1;
                }
            }
            let mut grad: [f64; 6] = std::array::from_fn(|x| t[22 + x]);
            if isotropic {
                // d/d alpha = d/d alpha_x + d/d alpha_y.
                for x in 0..6 {
                    block[x][2] += block[x][3];
                }
                for y2 in 0..6 {
                    block[2][y2] += block[3][y2];
                }
                grad[2] += grad[3];
                for x in 0..6 {
                    block[x][3] = 0.0;
                    block[3][x] = 0.0;
                }
                grad[3] = 0.0;
            }
            let idx = [c, 3 + c, 6, 7, 8, 9];
            for x in 0..6 {
                g[idx[x]] += grad[x];
                for y2 in 0..6 {
                    a[(idx[x], idx[y2])] += block[x][y2];
                }
            }
        }
        (cost, a, g)
    }
}
