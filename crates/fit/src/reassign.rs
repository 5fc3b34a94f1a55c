//! Pixels moved to a neighbouring cluster whose BRDF explains them far better (our
//! addition to the paper). The initial clusters group pixels by colour and the tree
//! splits a cluster by its pixels' error, so a few hundred glossy pixels that read
//! like a matte cluster (gold where the highlight brightened it, next to white
//! paint) can stay in it when they are too few among its poorly fitted pixels for a
//! split to pay; the per-pixel refinement then turns their highlight into a bright
//! blotch of diffuse albedo (hard-small patchwork: a gold patch half covered by the
//! white paint's cluster, its diffuse albedo four times the truth there).
//!
//! Each pixel whose error under its cluster's BRDF is above half the cluster's
//! median pixel error tries the BRDFs of the clusters around it, diffuse albedo
//! included (the refinement that follows pulls each pixel towards its cluster's: a
//! white tile's pixels scored with their own albedo under a blue tile's lobe moved
//! there and came out purple), and moves where the error falls below [`ACCEPT`] of
//! its own. Two passes, so that a patch is taken in from its edge inwards.

use rayon::prelude::*;
use svbrdf_core::brdf::{BrdfParams, ModelKind, Prepared};

use crate::tree::{Context, Leaf};

/// A pixel moves when another cluster's lobe leaves less than this share of its
/// squared error.
pub const ACCEPT: f64 = 0.5;

/// A pixel tries other clusters when its error exceeds this many times its cluster's
/// median pixel error. Not only the outliers: in a cluster that mixes materials the
/// median itself is high, and the glossy pixels left in a matte cluster lie near it
/// (drifting hard-small patchwork 1: their median 1.5 times the cluster's, 6% over 3
/// times). Session 29 (docs/BENCHMARKS.md): 3 -> 0.5 lowered the diffuse error on 12
/// of 12 hard-small captures, that blotch's capture 0.047 -> 0.033.
pub const TRY_ABOVE: f64 = 0.5;

/// Observations per pixel that score a lobe (spread evenly over its frames).
const SCORED_OBSERVATIONS: usize = 16;

/// Probe distances (output pixels) around a pixel, in eight directions each.
const PROBE_RADII: [isize; 3] = [3, 8, 20];

/// Passes over the pixels.
const PASSES: usize = 2;

/// The clusters' BRDFs, ready to score pixels with.
struct Scorers<'a> {
    ctx: &'a Context<'a>,
    params: Vec<BrdfParams>,
    prepared: Vec<Prepared>,
    ward: bool,
}

impl<'a> Scorers<'a> {
    fn new(ctx: &'a Context<'a>, leaves: &[Leaf]) -> Self {
        let params: Vec<BrdfParams> = leaves.iter().map(|l| l.params).collect();
        Self {
            ctx,
            prepared: params.iter().map(|p| Prepared::new(*p)).collect(),
            params,
            ward: ctx.model.kind() == ModelKind::Ward,
        }
    }

    /// Mean squared error of pixel `px` under each cluster in `clusters`, over at most
    /// [`SCORED_OBSERVATIONS`] of its observations, gathered once (infinite where it
    /// has none).
    fn errors(&self, px: usize, clusters: &[u32]) -> Vec<f64> {
        let ctx = self.ctx;
        if self.ward {
            let step = ctx.obs.range(px).len().div_ceil(SCORED_OBSERVATIONS).max(1);
            return crate::BATCH.with_borrow_mut(|b| {
                b.gather(ctx.obs, px, step);
                let n = b.len();
                clusters
                    .iter()
                    .map(|&q| match n {
                        0 => f64::INFINITY,
                        n => b.sse(&self.params[q as usize], ctx.intensity) / (3 * n) as f64,
                    })
                    .collect()
            });
        }
        clusters
            .iter()
            .map(|&q| {
                let p = &self.prepared[q as usize];
                match crate::tree::pixel_sse(ctx, px, p, SCORED_OBSERVATIONS) {
                    (_, 0) => f64::INFINITY,
                    (sse, n) => sse / (3 * n) as f64,
                }
            })
            .collect()
    }
}

/// Move pixels between `leaves` (their pixel lists and the per-pixel `cluster` labels
/// of a `width`-wide grid, `u32::MAX` where unobserved) as the module describes; the
/// number of moves (summed over the passes).
pub(crate) fn reassign(
    ctx: &Context,
    width: usize,
    leaves: &mut [Leaf],
    cluster: &mut [u32],
) -> usize {
    let obs = ctx.obs;
    let height = cluster.len() / width.max(1);
    let scorers = Scorers::new(ctx, leaves);
    // Every observed pixel's error under its own cluster's lobe.
    let own: Vec<f64> = (0..cluster.len())
        .into_par_iter()
        .with_min_len(256)
        .map(|px| match cluster[px] {
            c if c == u32::MAX || obs.count(px) < ctx.cfg.min_observations.max(1) => f64::NAN,
            c => scorers.errors(px, &[c])[0],
        })
        .collect();
    // Each cluster's median pixel error.
    let typical: Vec<f64> = leaves
        .par_iter()
        .map(|l| {
            let mut e: Vec<f64> = l
                .pixels
                .iter()
                .map(|&p| own[p as usize])
                .filter(|v| v.is_finite())
                .collect();
            if e.is_empty() {
                return f64::INFINITY;
            }
            let mid = e.len() / 2;
            e.select_nth_unstable_by(mid, f64::total_cmp);
            e[mid]
        })
        .collect();
    let mut err = own;
    let mut moves = 0;
    let mut changed = vec![false; leaves.len()];
    let min = ctx.cfg.min_cluster_px;
    let mut size: Vec<usize> = leaves.iter().map(|l| l.pixels.len()).collect();
    let offsets: Vec<(isize, isize)> = PROBE_RADII
        .iter()
        .flat_map(|&r| {
            [
                (1, 0),
                (1, 1),
                (0, 1),
                (-1, 1),
                (-1, 0),
                (-1, -1),
                (0, -1),
                (1, -1),
            ]
            .map(|(dx, dy)| (dx * r, dy * r))
        })
        .collect();
    for _ in 0..PASSES {
        let labels: &[u32] = cluster;
        let moved: Vec<(usize, u32, f64)> = (0..labels.len())
            .into_par_iter()
            .with_min_len(256)
            .filter_map(|px| {
                let c = labels[px];
                let e = err[px];
                if c == u32::MAX || !e.is_finite() || e <= TRY_ABOVE * typical[c as usize] {
                    return None;
                }
                let (x, y) = ((px % width) as isize, (px / width) as isize);
                let mut seen: Vec<u32> = Vec::with_capacity(offsets.len());
                for &(dx, dy) in &offsets {
                    let (qx, qy) = (x + dx, y + dy);
                    if qx < 0 || qy < 0 || qx >= width as isize || qy >= height as isize {
                        continue;
                    }
                    let q = labels[qy as usize * width + qx as usize];
                    if q != u32::MAX && q != c && !seen.contains(&q) {
                        seen.push(q);
                    }
                }
                if seen.is_empty() {
                    return None;
                }
                seen.iter()
                    .copied()
                    .zip(scorers.errors(px, &seen))
                    .min_by(|a, b| a.1.total_cmp(&b.1).then(a.0.cmp(&b.0)))
                    .filter(|&(_, eq)| eq < ACCEPT * e)
                    .map(|(q, eq)| (px, q, eq))
            })
            .collect();
        for (px, q, e) in moved {
            // A cluster keeps at least `min_cluster_px` pixels, as the tree's splits
            // do: fewer would fit a lobe to a handful of pixels in the lobe refit (and
            // none is ever emptied).
            let c = cluster[px] as usize;
            if size[c] <= min {
                continue;
            }
            size[c] -= 1;
            size[q as usize] += 1;
            moves += 1;
            changed[c] = true;
            changed[q as usize] = true;
            cluster[px] = q;
            err[px] = e;
        }
    }
    if moves > 0 {
        for l in leaves.iter_mut() {
            l.pixels.clear();
        }
        for (px, &c) in cluster.iter().enumerate() {
            if c != u32::MAX {
                leaves[c as usize].pixels.push(px as u32);
            }
        }
        // The error records of the clusters that gained or lost pixels, over their
        // pixels now (what `clusters.json` reports and the summary's cluster RMSE).
        for (l, _) in leaves.iter_mut().zip(changed).filter(|(_, c)| *c) {
            let (_, sse, count) = crate::tree::pixel_errors(ctx, &l.pixels, &l.params);
            l.sse = sse;
            l.observations = count;
        }
    }
    moves
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::FitConfig;
    use svbrdf_core::geometry::Vec3;
    use svbrdf_core::plane::{PlaneGrid, Region};

    #[test]
    fn glossy_pixels_left_in_a_matte_cluster_move_to_the_glossy_one_next_to_them() {
        // White paint around a 2 x 2 cm gold patch whose left half the clustering left
        // in the paint's cluster; filmed by a flash camera on a 7 x 7 grid.
        let grid = PlaneGrid::new(Region::centred(4.0, 4.0), 10.0).unwrap();
        let frames = crate::observations::flash_frames(49, |i| {
            Vec3::new(f64::from(i % 7) - 3.0, f64::from(i / 7) - 3.0, 10.0)
        });
        let paint = BrdfParams {
            rho_d: [0.45, 0.44, 0.40],
            rho_s: [0.05; 3],
            alpha_x: 0.15,
            alpha_y: 0.15,
            ..BrdfParams::default()
        };
        let gold = BrdfParams {
            rho_d: [0.10, 0.07, 0.02],
            rho_s: [0.60, 0.45, 0.16],
            alpha_x: 0.16,
            alpha_y: 0.16,
            ..BrdfParams::default()
        };
        let w = grid.width;
        let in_gold = |px: usize| (10..30).contains(&(px % w)) && (10..30).contains(&(px / w));
        let obs = crate::observations::rendered(
            grid,
            frames,
            |px| if in_gold(px) { gold } else { paint },
            100.0,
            false,
        );
        let cfg = FitConfig::default();
        let ctx = Context {
            obs: &obs,
            model: &svbrdf_core::brdf::Ward,
            intensity: [100.0; 3],
            cfg: &cfg,
        };
        let mut cluster: Vec<u32> = (0..obs.pixels())
            .map(|px| u32::from(in_gold(px) && px % w >= 20))
            .collect();
        let leaf = |id: u32, params: BrdfParams| Leaf {
            pixels: (0..obs.pixels() as u32)
                .filter(|&p| cluster[p as usize] == id)
                .collect(),
            params,
            depth: 0,
            sse: 0.0,
            observations: 0,
            converged: true,
            lobe_from_parent: false,
        };
        let mut leaves = vec![leaf(0, paint), leaf(1, gold)];
        let moves = reassign(&ctx, w, &mut leaves, &mut cluster);
        // Every gold pixel ends in the gold cluster, every paint pixel stays.
        for (px, &c) in cluster.iter().enumerate() {
            assert_eq!(c, u32::from(in_gold(px)), "pixel {px}");
        }
        assert_eq!(moves, 200);
        assert_eq!(leaves[1].pixels.len(), 400);
        assert_eq!(leaves[0].pixels.len(), obs.pixels() - 400);
        // The clusters' error records are over their pixels now: the paint cluster's
        // (set to 0 above) counts its pixels' observations again.
        assert!(leaves[0].observations > 0 && leaves[0].sse.is_finite());
        assert!(leaves[1].observations > 0);
        // A second run finds nothing to move.
        assert_eq!(reassign(&ctx, w, &mut leaves, &mut cluster), 0);
    }
}
