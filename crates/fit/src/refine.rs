//! Per-pixel refinement (our addition to the paper, whose maps are constant within a
//! cluster): each pixel fitted to its own observations, pulled towards its cluster.

use rayon::prelude::*;
use svbrdf_core::brdf::{BrdfParams, ModelKind};

use crate::fast;
use crate::sample_batch::SampleBatch;
use crate::solver::{solve_near_ward, Freedom, Problem, Sample, SolveSettings};
use crate::tree::Context;

thread_local! {
    /// Per-thread scratch of the Ward fast paths (one pixel's observations).
    pub(crate) static BATCH: std::cell::RefCell<fast::PixelBatch> =
        std::cell::RefCell::new(fast::PixelBatch::default());
    /// Per-thread scratch of the Ward refinement of all ten parameters.
    static SAMPLES: std::cell::RefCell<SampleBatch> =
        std::cell::RefCell::new(SampleBatch::default());
}

/// Per-pixel refinement of diffuse albedo and normal (our addition to the paper: its
/// maps are constant within a cluster). Each pixel is fitted to its own raw
/// observations, pulled towards its cluster's solution by a prior as strong as
/// `refine_prior` average observations of each parameter.
/// The normal's trust region is centred on `anchor(pixel).0` (the cluster's normal
/// angles), so that a second pass cannot walk further from the cluster than the first;
/// its half-width is `refine_max_normal_change_deg` times `anchor(pixel).1` (in [0, 1]:
/// how well the pixel's light directions and frames measure its normal).
pub(crate) fn refine(
    ctx: &Context,
    params: &mut [BrdfParams],
    covered: &[bool],
    anchor: impl Fn(usize) -> ([f64; 2], f64) + Sync,
    iterations: usize,
    freedom: Freedom,
) {
    let obs = ctx.obs;
    let global = ctx.bounds();
    let delta = ctx.cfg.refine_max_normal_change_deg.to_radians();
    // The pixel batch path refines diffuse albedo and normal only; other Ward
    // refinements gather straight into a sample batch.
    let ward = ctx.model.kind() == ModelKind::Ward;
    let ward_fast = ward && freedom == Freedom::DIFFUSE_AND_NORMAL;
    let solve = SolveSettings {
        intensity: ctx.intensity,
        bounds: global,
        tolerance: ctx.cfg.tolerance,
    };
    let prior = ctx.cfg.refine_prior;
    let settings = fast::RefineSettings {
        prior,
        iterations,
        robust: ctx.cfg.refine_robust,
        rounds: ctx.cfg.refine_rounds,
    };
    params
        .par_iter_mut()
        .with_min_len(256)
        .enumerate()
        .for_each(|(px, p)| {
            if !covered[px] {
                return;
            }
            let (a, trust) = anchor(px);
            let reach = delta * trust;
            let mut bounds = global;
            for k in 0..2 {
                bounds.normal_lo[k] = (a[k] - reach).max(global.normal_lo[k]);
                bounds.normal_hi[k] = (a[k] + reach).min(global.normal_hi[k]);
            }
            let q = if ward_fast {
                BATCH.with_borrow_mut(|b| {
                    b.gather(obs, px, 1);
                    fast::refine_pixel(b, p, ctx.intensity, &bounds, &settings)
                })
            } else if ward {
                SAMPLES.with_borrow_mut(|b| {
                    b.gather(obs, px);
                    let settings = SolveSettings { bounds, ..solve };
                    solve_near_ward(b, &settings, p, &freedom, prior, iterations).params
                })
            } else {
                let samples = pixel_samples(obs, px);
                let prob = Problem {
                    model: ctx.model,
                    samples: &samples,
                    intensity: ctx.intensity,
                    bounds,
                    tolerance: ctx.cfg.tolerance,
                };
                prob.solve_near(p, &freedom, prior, iterations).params
            };
            if q.is_physical() {
                *p = q;
            }
        });
}

/// Give a pixel the lobe `rho_s`, `alpha_x`, `alpha_y`, its specular albedo cut to
/// what its diffuse albedo leaves (energy conservation).
pub(crate) fn put_lobe(p: &mut BrdfParams, rho_s: [f64; 3], alpha_x: f64, alpha_y: f64) {
    for k in 0..3 {
        p.rho_s[k] = rho_s[k].min(1.0 - p.rho_d[k]).max(0.0);
    }
    (p.alpha_x, p.alpha_y) = (alpha_x, alpha_y);
}

/// Pixel `px`'s raw observations as solver samples, each of weight 1.
fn pixel_samples(obs: &crate::observations::Observations, px: usize) -> Vec<Sample> {
    obs.range(px)
        .map(|o| Sample {
            lv: obs.light_view(px, o),
            rgb: obs.color(o),
            weight: 1.0,
            clipped: obs.clipped(o),
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use svbrdf_core::brdf::Ward;
    use svbrdf_core::geometry::Vec3;
    use svbrdf_core::plane::{PlaneGrid, Region};

    use crate::observations::{rendered, FrameGeometry};
    use crate::solver::Bounds;

    /// The per-pixel specular refinement gathers each pixel's observations straight into
    /// a sample batch; it must fit what the [`Problem`] path fits from samples.
    #[test]
    fn gathered_specular_refinement_equals_the_sample_path() {
        let truth = BrdfParams {
            rho_d: [0.3, 0.2, 0.1],
            rho_s: [0.25, 0.2, 0.2],
            alpha_x: 0.12,
            alpha_y: 0.3,
            normal_theta_x: 0.05,
            normal_theta_y: -0.03,
            tangent_rotation: 0.4,
        };
        let grid = PlaneGrid::new(Region::centred(0.3, 0.3), 10.0).unwrap();
        let frames: Vec<FrameGeometry> = (0..40)
            .map(|i| {
                let a = f64::from(i) * 0.7;
                let camera = Vec3::new(4.0 * a.cos(), 3.0 * a.sin(), 10.0 + f64::from(i % 3));
                FrameGeometry {
                    id: i,
                    camera,
                    light: camera + Vec3::new(1.4, -0.3, 0.0),
                    gain: 1.0 + 0.1 * f64::from(i % 4),
                }
            })
            .collect();
        // Bright enough that some of the highlight clips.
        let obs = rendered(grid, frames, |_| truth, 600.0, false);
        assert!(obs.clipped > 0);
        let start = BrdfParams {
            rho_s: [0.15; 3],
            alpha_x: 0.2,
            alpha_y: 0.2,
            normal_theta_x: 0.0,
            normal_theta_y: 0.0,
            ..truth
        };
        let bounds = Bounds::symmetric(0.02, 1.0, 0.3);
        let settings = SolveSettings {
            intensity: [600.0; 3],
            bounds,
            tolerance: 1e-6,
        };
        let mut batch = SampleBatch::default();
        for px in [0, 4, 8] {
            let samples = pixel_samples(&obs, px);
            let prob = Problem {
                model: &Ward,
                samples: &samples,
                intensity: settings.intensity,
                bounds,
                tolerance: settings.tolerance,
            };
            let want = prob.solve_near(&start, &Freedom::FULL, 0.5, 20);
            batch.gather(&obs, px);
            let got = solve_near_ward(&mut batch, &settings, &start, &Freedom::FULL, 0.5, 20);
            let (a, b) = (want.params.to_array(), got.params.to_array());
            // Both are f32 batch fits; geometry rounded differently moves twenty
            // iterations along a flat valley by about 2e-4.
            for k in 0..a.len() {
                assert!((a[k] - b[k]).abs() < 1e-3, "pixel {px}: {a:?} vs {b:?}");
            }
            assert_eq!(got.params.tangent_rotation, start.tangent_rotation);
            // It moved towards the truth.
            assert!((got.params.alpha_x - truth.alpha_x).abs() < 0.05, "{got:?}");
        }
    }

    /// A pixel lit from one direction cannot tell a tilted normal from a darker albedo:
    /// its normal stays at its cluster's. One lit from all sides reads its tilt.
    #[test]
    fn the_normal_moves_only_as_far_as_its_light_directions_measure_it() {
        let truth = BrdfParams {
            rho_d: [0.3, 0.25, 0.2],
            rho_s: [0.05; 3],
            alpha_x: 0.3,
            alpha_y: 0.3,
            normal_theta_x: 0.03,
            normal_theta_y: -0.02,
            tangent_rotation: 0.0,
        };
        let grid = PlaneGrid::new(Region::centred(0.2, 0.2), 10.0).unwrap();
        let sweep = |spread: f64| -> Vec<FrameGeometry> {
            (0..40)
                .map(|i| {
                    let a = f64::from(i) * 0.7;
                    let camera = Vec3::new(
                        6.0 + spread * a.cos(),
                        spread * a.sin(),
                        10.0 + 0.5 * f64::from(i % 3),
                    );
                    FrameGeometry {
                        id: i,
                        camera,
                        light: camera + Vec3::new(0.8, 0.0, 0.0),
                        gain: 1.0,
                    }
                })
                .collect()
        };
        let cfg = crate::FitConfig {
            normal_trust_full_confidence: 1.0,
            ..Default::default()
        };
        let delta = cfg.refine_max_normal_change_deg.to_radians();
        for (spread, wide) in [(0.02, false), (8.0, true)] {
            let obs = rendered(grid, sweep(spread), |_| truth, 150.0, false);
            let covered = vec![true; obs.pixels()];
            let trust = crate::stages::normal_trust(&obs, &covered, &cfg).expect("limit on");
            let ctx = Context {
                obs: &obs,
                model: &Ward,
                intensity: [150.0; 3],
                cfg: &cfg,
            };
            let flat = BrdfParams {
                normal_theta_x: 0.0,
                normal_theta_y: 0.0,
                ..truth
            };
            let mut params = vec![flat; obs.pixels()];
            let anchor = |p: usize| ([0.0, 0.0], trust[p]);
            refine(
                &ctx,
                &mut params,
                &covered,
                anchor,
                10,
                Freedom::DIFFUSE_AND_NORMAL,
            );
            for (p, q) in params.iter().enumerate() {
                let (tx, ty) = (q.normal_theta_x, q.normal_theta_y);
                if wide {
                    assert_eq!(trust[p], 1.0, "pixel {p}");
                    assert!(
                        (tx - 0.03).abs() < 0.01 && (ty + 0.02).abs() < 0.01,
                        "{q:?}"
                    );
                } else {
                    assert!(trust[p] < 0.1, "pixel {p}: {}", trust[p]);
                    assert!(tx.abs().max(ty.abs()) <= trust[p] * delta + 1e-12, "{q:?}");
                }
            }
        }
    }
}
