//! Lobes from a pixel's neighbours (our addition to the paper), for pixels of
//! anisotropic clusters, such as brushed metal.
//!
//! The per-pixel specular step pulls a pixel's own lobe hard towards its cluster's
//! (`refine_prior` average observations, `refine_iterations` iterations), because a
//! pixel's 10-40 observations rarely pin a lobe's height and two widths down alone. On
//! an anisotropic highlight that prior keeps the lobe near the cluster's, which is
//! wrong where the cluster mixes a sharper and a softer groove direction: on `paper`
//! seed 1 (true registration) the brushed metal's light at 1 mm stayed at 82.5%.
//! Here such a pixel's lobe is first fitted almost freely (prior [`LOOSE_PRIOR_SHARE`]
//! of the usual, [`LOOSE_ITERATIONS`] iterations), which is noisy pixel by pixel; each
//! lobe parameter is then replaced by its median over the pixel's cluster within
//! `neighbour_lobes_radius_px` (its neighbours measured the same surface from slightly
//! different directions), and the pixel is refitted as usual from its own diffuse
//! albedo and normal and that median lobe.

use rayon::prelude::*;
use svbrdf_core::brdf::BrdfParams;

use crate::confidence::FLANK_MIN_VIEWS;
use crate::refine::{put_lobe, refine};
use crate::solver::Freedom;
use crate::tree::Context;
use crate::{FitConfig, Observations};

/// The loose fit's prior as a share of `refine_prior` (0.5 -> 0.01 at the defaults).
pub(crate) const LOOSE_PRIOR_SHARE: f64 = 0.02;
/// Gauss-Newton iterations of the loose fit.
pub(crate) const LOOSE_ITERATIONS: usize = 20;

/// How anisotropic a lobe is: its larger width over its smaller (1: isotropic).
pub(crate) fn anisotropy(lobe: &BrdfParams) -> f64 {
    let (a, b) = (lobe.alpha_x.max(1e-9), lobe.alpha_y.max(1e-9));
    (a / b).max(b / a)
}

/// The pixels whose lobe comes from their neighbours (empty when the setting is off):
/// of those whose observations measure their lobe (`measured`), the ones seen by at
/// least [`FLANK_MIN_VIEWS`] frames in a cluster whose lobe (`cluster_lobes`, by
/// cluster label) is at least `neighbour_lobes_min_anisotropy` anisotropic.
pub(crate) fn chosen(
    obs: &Observations,
    measured: &[bool],
    cluster: &[u32],
    cluster_lobes: &[BrdfParams],
    cfg: &FitConfig,
) -> Vec<bool> {
    let min = cfg.neighbour_lobes_min_anisotropy;
    if min <= 0.0 {
        return Vec::new();
    }
    let anisotropic: Vec<bool> = cluster_lobes.iter().map(|l| anisotropy(l) >= min).collect();
    (0..measured.len())
        .into_par_iter()
        .map(|p| measured[p] && anisotropic[cluster[p] as usize] && obs.count(p) >= FLANK_MIN_VIEWS)
        .collect()
}

/// A lobe's parameters as one array: specular albedo (RGB), then the two widths.
fn lobe(p: &BrdfParams) -> [f64; 5] {
    [p.rho_s[0], p.rho_s[1], p.rho_s[2], p.alpha_x, p.alpha_y]
}

/// Per pixel of `chosen` (its index in `pixels`), each lobe parameter's median over
/// the chosen pixels of its cluster within `radius` pixels (a square window, the pixel
/// itself included) on a grid `width` pixels wide.
fn neighbour_medians(
    params: &[BrdfParams],
    pixels: &[usize],
    chosen: &[bool],
    cluster: &[u32],
    width: usize,
    radius: usize,
) -> Vec<[f64; 5]> {
    let height = params.len() / width.max(1);
    pixels
        .par_iter()
        // One scratch per worker, not five allocations per pixel.
        .map_init(<[Vec<f64>; 5]>::default, |values, &p| {
            let (x, y) = (p % width, p / width);
            values.iter_mut().for_each(Vec::clear);
            for ny in y.saturating_sub(radius)..(y + radius + 1).min(height) {
                for nx in x.saturating_sub(radius)..(x + radius + 1).min(width) {
                    let q = ny * width + nx;
                    if chosen[q] && cluster[q] == cluster[p] {
                        for (v, l) in values.iter_mut().zip(lobe(&params[q])) {
                            v.push(l);
                        }
                    }
                }
            }
            let mut m = lobe(&params[p]);
            for (m, v) in m.iter_mut().zip(values.iter_mut()) {
                if !v.is_empty() {
                    v.sort_unstable_by(f64::total_cmp);
                    let n = v.len();
                    *m = if n % 2 == 1 {
                        v[n / 2]
                    } else {
                        0.5 * (v[n / 2 - 1] + v[n / 2])
                    };
                }
            }
            m
        })
        .collect()
}

/// Give every pixel of `chosen` a lobe from its neighbours (see the module's
/// documentation); returns how many pixels took it. `anchor` is the refinement's
/// (see [`refine`]).
pub(crate) fn neighbour_lobes<A>(
    ctx: &Context,
    params: &mut [BrdfParams],
    chosen: &[bool],
    cluster: &[u32],
    anchor: A,
) -> usize
where
    A: Fn(usize) -> ([f64; 2], f64) + Sync + Copy,
{
    let pixels: Vec<usize> = (0..chosen.len()).filter(|&p| chosen[p]).collect();
    if pixels.is_empty() {
        return 0;
    }
    // The pixels' diffuse albedo and normal as the refinement left them: the final
    // refit starts from these, not from the loose fit's (which trade them against the
    // lobe).
    let saved: Vec<BrdfParams> = pixels.iter().map(|&p| params[p]).collect();
    let mut loose_cfg = ctx.cfg.clone();
    loose_cfg.refine_prior *= LOOSE_PRIOR_SHARE;
    let loose = Context {
        cfg: &loose_cfg,
        ..*ctx
    };
    refine(
        &loose,
        params,
        chosen,
        anchor,
        LOOSE_ITERATIONS,
        Freedom::FULL,
    );
    let medians = neighbour_medians(
        params,
        &pixels,
        chosen,
        cluster,
        ctx.obs.grid.width,
        ctx.cfg.neighbour_lobes_radius_px,
    );
    for ((&p, s), m) in pixels.iter().zip(&saved).zip(&medians) {
        let mut q = *s;
        put_lobe(&mut q, [m[0], m[1], m[2]], m[3], m[4]);
        params[p] = q;
    }
    refine(
        ctx,
        params,
        chosen,
        anchor,
        ctx.cfg.refine_iterations,
        Freedom::FULL,
    );
    pixels.len()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn with_lobe(rho: f64, ax: f64, ay: f64) -> BrdfParams {
        BrdfParams {
            rho_d: [0.2; 3],
            rho_s: [rho; 3],
            alpha_x: ax,
            alpha_y: ay,
            normal_theta_x: 0.0,
            normal_theta_y: 0.0,
            tangent_rotation: 0.0,
        }
    }

    /// The median ignores an outlier, pixels of other clusters and pixels not chosen.
    #[test]
    fn the_median_takes_the_chosen_neighbours_of_the_same_cluster() {
        let width = 5;
        let mut params = vec![with_lobe(0.3, 0.1, 0.3); 25];
        let mut chosen = vec![true; 25];
        let mut cluster = vec![0u32; 25];
        // The centre pixel's loose fit went astray.
        params[12] = with_lobe(0.9, 0.5, 0.05);
        // Another cluster and an unchosen pixel beside it, both far off.
        params[11] = with_lobe(0.0, 0.9, 0.9);
        cluster[11] = 1;
        params[13] = with_lobe(0.0, 0.9, 0.9);
        chosen[13] = false;
        let pixels: Vec<usize> = (0..25).filter(|&p| chosen[p]).collect();
        let m = neighbour_medians(&params, &pixels, &chosen, &cluster, width, 1);
        let centre = pixels.iter().position(|&p| p == 12).expect("chosen");
        assert_eq!(m[centre], [0.3, 0.3, 0.3, 0.1, 0.3]);
        // The other cluster's pixel has no neighbour of its own cluster: it keeps its
        // own lobe.
        let other = pixels.iter().position(|&p| p == 11).expect("chosen");
        assert_eq!(m[other], [0.0, 0.0, 0.0, 0.9, 0.9]);
        // A corner pixel sees a 2 x 2 window.
        assert_eq!(m[0], [0.3, 0.3, 0.3, 0.1, 0.3]);
    }

    /// Brushed metal whose grooves sharpen across the sheet: the fit's clusters cut the
    /// gradient into steps, and the usual per-pixel step keeps each pixel's lobe near
    /// its cluster's; lobes from the neighbours follow the gradient.
    #[test]
    fn lobes_from_neighbours_follow_a_gradient_the_clusters_step() {
        use svbrdf_core::capture::{RegisteredCapture, Source, SourceKind};
        use svbrdf_core::geometry::Vec3;
        use svbrdf_core::plane::{PlaneGrid, Region};

        use crate::observations::{rendered, FrameGeometry};
        use crate::FitConfig;

        let region = Region::centred(4.0, 4.0);
        let grid = PlaneGrid::new(region, 10.0).expect("grid");
        let truth = |px: usize| BrdfParams {
            rho_d: [0.05, 0.1, 0.4],
            alpha_x: 0.07 + 0.07 * (px % grid.width) as f64 / grid.width as f64,
            ..with_lobe(0.3, 0.0, 0.22)
        };
        let frames: Vec<FrameGeometry> = (0..36)
            .map(|i| {
                let (u, v) = (f64::from(i % 6) - 2.5, f64::from(i / 6) - 2.5);
                let camera = Vec3::new(1.3 * u, 1.3 * v, 9.0 + f64::from(i % 3) * 0.3);
                FrameGeometry {
                    id: i,
                    camera,
                    light: camera + Vec3::new(1.4, -0.3, 0.0),
                    gain: 1.0,
                }
            })
            .collect();
        let mut obs = rendered(grid, frames, truth, 100.0, true);
        let mut cap = RegisteredCapture::new("test", region, 10.0);
        cap.light_intensity = Some([100.0; 3]);
        cap.sources.push(Source {
            kind: SourceKind::Video,
            path: "flash.mp4".into(),
            encoding: svbrdf_core::maps::Encoding::Srgb,
            stream: 0,
            video: None,
        });
        // Clusters that do not split: one lobe for the whole gradient.
        let base = FitConfig {
            select_folds: 0,
            k_min: 1,
            k_max: 1,
            max_depth: 2,
            neighbour_lobes_min_anisotropy: 0.0,
            ..FitConfig::default()
        };
        let on = FitConfig {
            neighbour_lobes_min_anisotropy: 1.5,
            ..base.clone()
        };
        let progress = svbrdf_core::progress::NoProgress;
        let (plain, plain_summary) =
            crate::fit(&mut obs.clone(), &cap, &base, &progress).expect("fit");
        let (near, summary) = crate::fit(&mut obs, &cap, &on, &progress).expect("fit");
        assert_eq!(plain_summary.neighbour_lobes, 0);
        assert!(summary.neighbour_lobes > 0, "{summary:?}");
        let changed: Vec<usize> = (0..near.params.len())
            .filter(|&p| near.params[p] != plain.params[p])
            .collect();
        let mean_error = |params: &[BrdfParams]| {
            changed
                .iter()
                .map(|&p| (params[p].alpha_x - truth(p).alpha_x).abs())
                .sum::<f64>()
                / changed.len().max(1) as f64
        };
        let (a, b) = (mean_error(&plain.params), mean_error(&near.params));
        eprintln!(
            "{} pixels changed; alpha_x error: usual {a:.4}, from neighbours {b:.4}; clusters {}",
            changed.len(),
            summary.final_clusters
        );
        assert!(b < 0.7 * a, "usual {a}, from neighbours {b}");
        assert!(near.params.iter().all(BrdfParams::is_physical));
    }

    #[test]
    fn anisotropy_is_symmetric() {
        assert!((anisotropy(&with_lobe(0.1, 0.1, 0.3)) - 3.0).abs() < 1e-12);
        assert_eq!(
            anisotropy(&with_lobe(0.1, 0.3, 0.1)),
            anisotropy(&with_lobe(0.1, 0.1, 0.3))
        );
        assert_eq!(anisotropy(&with_lobe(0.1, 0.2, 0.2)), 1.0);
    }
}
