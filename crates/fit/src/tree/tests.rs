//! Unit tests of the cluster tree (`tree.rs`).

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

/// One shiny material whose pixels' normals are tilted by up to 1.7 degrees,
/// filmed by a flash camera on a 7 x 7 grid and rendered exactly with Ward (clipped
/// channels stored as clipped).
fn tilted_patch(truth: BrdfParams) -> (Observations, Vec<BrdfParams>) {
    use svbrdf_core::plane::{PlaneGrid, Region};
    let grid = PlaneGrid::new(Region::centred(4.0, 4.0), 10.0).unwrap();
    let frames = crate::observations::flash_frames(49, |i| {
        Vec3::new((i % 7) as f64 - 3.0, (i / 7) as f64 - 3.0, 10.0)
    });
    let params: Vec<BrdfParams> = (0..grid.len())
        .map(|px| BrdfParams {
            normal_theta_x: 0.03 * (px as f64 * 1.7).sin(),
            normal_theta_y: 0.03 * (px as f64 * 2.3).cos(),
            ..truth
        })
        .collect();
    let obs = crate::observations::rendered(grid, frames, |px| params[px], 100.0, false);
    (obs, params)
}

#[test]
fn a_taller_lobe_that_most_of_the_part_never_saw_is_invented() {
    let lobe = |rho_s: f64, alpha: f64| BrdfParams {
        rho_s: [rho_s; 3],
        alpha_x: alpha,
        alpha_y: alpha,
        ..BrdfParams::default()
    };
    let parent = lobe(0.2, 0.2);
    let (sharper, wider) = (lobe(0.9, 0.03), lobe(0.3, 0.4));
    assert!(invented(&sharper, &parent, 0.0));
    assert!(invented(&sharper, &parent, 0.49));
    // Seen on most of the part: measured, not invented.
    assert!(!invented(&sharper, &parent, 0.5));
    // No taller than the parent's: nothing is added where no frame looked.
    assert!(!invented(&wider, &parent, 0.0));
    assert!(!invented(&parent, &parent, 0.0));
}

#[test]
fn a_part_whose_highlight_no_frame_saw_keeps_its_parents_lobe() {
    use svbrdf_core::plane::{PlaneGrid, Region};
    // A glossy 1 x 1 cm part filmed only from one side, 20-30 degrees off its
    // normal: the flank of a broad lobe shows, the peak of a sharp one never.
    let grid = PlaneGrid::new(Region::centred(1.0, 1.0), 10.0).unwrap();
    let frames = crate::observations::flash_frames(30, |i| {
        Vec3::new(4.0 + 0.1 * f64::from(i), 0.2 * f64::from(i % 5), 10.0)
    });
    let truth = BrdfParams {
        rho_d: [0.3, 0.25, 0.2],
        rho_s: [0.1; 3],
        alpha_x: 0.3,
        alpha_y: 0.3,
        ..BrdfParams::default()
    };
    let obs = crate::observations::rendered(grid, frames, |_| truth, 100.0, false);
    let cfg = FitConfig::default();
    let ctx = Context {
        obs: &obs,
        model: &svbrdf_core::brdf::Ward,
        intensity: [100.0; 3],
        cfg: &cfg,
    };
    let part: Vec<u32> = (0..obs.pixels() as u32).collect();
    let samples = binned_samples(&ctx, &part);
    let prob = problem(&ctx, &samples, true);
    let solution = |params: BrdfParams| Solution {
        params,
        cost: prob.cost(&params.to_array(), 0.0),
        iterations: 1,
        converged: true,
    };
    let seen = |p: &BrdfParams| crate::confidence::lobe_seen_share(&obs, &part, p, 500);
    let parent = BrdfParams {
        rho_s: [0.15; 3],
        ..truth
    };
    assert!(seen(&parent) > 0.5, "{}", seen(&parent));
    // A sharp lobe no frame saw, with the flank's light moved into the diffuse
    // albedo: the parent's lobe comes back and the albedo is fitted under it.
    let invented = BrdfParams {
        rho_d: [0.33, 0.28, 0.23],
        rho_s: [0.5, 0.3, 0.5],
        alpha_x: 0.02,
        alpha_y: 0.03,
        ..truth
    };
    assert!(seen(&invented) < NEVER_SEEN);
    let (held, from_parent) = hold_unseen_lobe(&ctx, &prob, &part, &parent, solution(invented));
    assert!(from_parent);
    let held = held.params;
    assert_eq!(
        (held.alpha_x, held.alpha_y, held.rho_s),
        (parent.alpha_x, parent.alpha_y, parent.rho_s)
    );
    assert!(
        (held.rho_d[0] - truth.rho_d[0]).abs() < 0.02,
        "{held:?} (truth {truth:?})"
    );
    // A fit whose lobe the frames saw, or one no taller than the parent's, stays.
    for kept in [
        truth,
        // Unseen, but its peak (0.6) below the parent's (1.1): nothing invented.
        BrdfParams {
            rho_s: [0.001; 3],
            alpha_x: 0.04,
            alpha_y: 0.04,
            ..truth
        },
    ] {
        let (out, from_parent) = hold_unseen_lobe(&ctx, &prob, &part, &truth, solution(kept));
        assert!(!from_parent);
        assert_eq!(out.params.to_array(), kept.to_array());
    }
}

#[test]
fn lobe_refit_with_the_pixels_normals_undoes_the_widening_of_one_normal() {
    let truth = BrdfParams {
        rho_d: [0.1; 3],
        rho_s: [0.4; 3],
        alpha_x: 0.08,
        alpha_y: 0.15,
        ..BrdfParams::default()
    };
    let (obs, pixel_params) = tilted_patch(truth);
    assert!(obs.clipped > 0, "the highlight should clip");
    let cfg = FitConfig::default();
    let ctx = Context {
        obs: &obs,
        model: &svbrdf_core::brdf::Ward,
        intensity: [100.0; 3],
        cfg: &cfg,
    };
    let pixels: Vec<u32> = (0..obs.pixels() as u32).collect();
    // One normal for all pixels, as the tree fits: a wider, lower lobe.
    let one = fit(&ctx, &pixels, &[truth], &Freedom::FULL);
    let peak = |p: &BrdfParams| p.rho_s[0] / (p.alpha_x * p.alpha_y);
    assert!(
        peak(&one.params) < 0.85 * peak(&truth),
        "one normal: {:?}",
        one.params
    );
    let leaf = Leaf {
        pixels,
        params: one.params,
        depth: 1,
        sse: one.sse,
        observations: one.n_obs,
        converged: one.converged,
        lobe_from_parent: false,
    };
    let q = refit_lobe(&ctx, &leaf, &pixel_params).expect("the refit lowers the error");
    for (got, want) in [
        (q.alpha_x, truth.alpha_x),
        (q.alpha_y, truth.alpha_y),
        (q.rho_s[1], truth.rho_s[1]),
    ] {
        assert!((got / want - 1.0).abs() < 0.02, "{q:?}");
    }
    assert_eq!(q.rho_d, [0.0; 3]);
    assert!(lobe_moved(&one.params, &q));
    assert!(!lobe_moved(&q, &q));
    // A change far beyond a correction is refused: a sharper lobe, or a matte
    // cluster given a highlight.
    assert!(lobe_correction(&one.params, &q));
    let sharper = BrdfParams {
        alpha_x: one.params.alpha_x / 1.5,
        ..one.params
    };
    assert!(!lobe_correction(&one.params, &sharper));
    let matte = BrdfParams {
        rho_s: [0.001; 3],
        ..truth
    };
    let shiny = BrdfParams {
        rho_s: [0.04; 3],
        ..matte
    };
    assert!(!lobe_correction(&matte, &shiny));
}
