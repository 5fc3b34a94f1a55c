//! Per-pixel refinement (our addition to the paper, whose maps are constant within a
//! cluster): each pixel fitted to its own observations, pulled towards its cluster.

use rayon::prelude::*;
use svbrdf_core::brdf::{BrdfParams, ModelKind};

use crate::fast;
use crate::solver::{Freedom, Problem, Sample};
use crate::tree::Context;

thread_local! {
    /// Per-thread scratch of the Ward fast paths (one pixel's observations).
    pub(crate) static BATCH: std::cell::RefCell<fast::PixelBatch> =
        std::cell::RefCell::new(fast::PixelBatch::default());
}

/// Per-pixel refinement of diffuse albedo and normal (our addition to the paper: its
/// maps are constant within a cluster). Each pixel is fitted to its own raw
/// observations, pulled towards its cluster's solution by a prior as strong as
/// `refine_prior` average observations of each parameter.
/// The normal's trust region is centred on `anchor(pixel)` (the cluster's normal
/// angles), so that a second pass cannot walk further from the cluster than the first.
pub(crate) fn refine(
    ctx: &Context,
    params: &mut [BrdfParams],
    covered: &[bool],
    anchor: impl Fn(usize) -> [f64; 2] + Sync,
    iterations: usize,
    freedom: Freedom,
) {
    let obs = ctx.obs;
    let global = ctx.bounds();
    let delta = ctx.cfg.refine_max_normal_change_deg.to_radians();
    // The batch path refines diffuse albedo and normal only.
    let ward_fast = ctx.model.kind() == ModelKind::Ward && freedom == Freedom::DIFFUSE_AND_NORMAL;
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
            let a = anchor(px);
            let mut bounds = global;
            for k in 0..2 {
                bounds.normal_lo[k] = (a[k] - delta).max(global.normal_lo[k]);
                bounds.normal_hi[k] = (a[k] + delta).min(global.normal_hi[k]);
            }
            let q = if ward_fast {
                BATCH.with_borrow_mut(|b| {
                    b.gather(obs, px, 1);
                    fast::refine_pixel(b, p, ctx.intensity, &bounds, &settings)
                })
            } else {
                let samples: Vec<Sample> = obs
                    .range(px)
                    .map(|o| Sample {
                        lv: obs.light_view(px, o),
                        rgb: obs.color(o),
                        weight: 1.0,
                        clipped: obs.clipped(o),
                    })
                    .collect();
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
