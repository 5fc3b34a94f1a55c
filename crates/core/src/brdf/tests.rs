#![allow(clippy::needless_range_loop)]

use std::f64::consts::PI;

use proptest::prelude::*;

use super::*;

fn models() -> [&'static dyn BrdfModel; 2] {
    [&Ward, &Ggx]
}

fn dir(theta: f64, phi: f64) -> Vec3 {
    Vec3::new(
        theta.sin() * phi.cos(),
        theta.sin() * phi.sin(),
        theta.cos(),
    )
}

fn params(ax: f64, ay: f64, tx: f64, ty: f64) -> BrdfParams {
    BrdfParams {
        rho_d: [0.3, 0.5, 0.2],
        rho_s: [0.4, 0.2, 0.6],
        alpha_x: ax,
        alpha_y: ay,
        normal_theta_x: tx,
        normal_theta_y: ty,
        tangent_rotation: 0.0,
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(400))]

    #[test]
    fn derivatives_match_finite_differences(
        ax in 0.05f64..0.6, ay in 0.05f64..0.6, tx in -0.5f64..0.5, ty in -0.5f64..0.5,
        lx in -6.0f64..6.0, ly in -6.0f64..6.0, lz in 5.0f64..20.0,
        cx in -6.0f64..6.0, cy in -6.0f64..6.0, cz in 5.0f64..20.0,
        turn in -3.2f64..3.2,
    ) {
        // Half the cases with the tangent turned: the frame's derivatives turn with it.
        let base = BrdfParams { tangent_rotation: if turn > 0.0 { turn } else { 0.0 }, ..params(ax, ay, tx, ty) };
        let obs = LightView::from_points(Vec3::new(0.3, -0.2, 0.0), Vec3::new(lx, ly, lz), Vec3::new(cx, cy, cz));
        for m in models() {
            let p = Prepared::new(base);
            let grad = m.radiance_grad(&p, &obs, 300.0);
            let plain = m.radiance(&p, &obs, 300.0);
            for c in 0..3 {
                prop_assert!((grad.value[c] - plain[c]).abs() <= 1e-9 * (1.0 + plain[c].abs()));
            }
            if grad.value.iter().all(|v| *v == 0.0) {
                continue;
            }
            let arr = base.to_array();
            for k in 0..N_PARAMS {
                let h = 1e-6 * (1.0 + arr[k].abs());
                let mut up = arr;
                let mut dn = arr;
                up[k] += h;
                dn[k] -= h;
                let r = base.tangent_rotation;
                let fu = m.radiance(&Prepared::new(BrdfParams::from_array_rotated(&up, r)), &obs, 300.0);
                let fd = m.radiance(&Prepared::new(BrdfParams::from_array_rotated(&dn, r)), &obs, 300.0);
                for c in 0..3 {
                    let numeric = (fu[c] - fd[c]) / (2.0 * h);
                    let analytic = match k {
                        0..=2 => if k == c { grad.d_rho_d[c] } else { 0.0 },
                        3..=5 => if k - 3 == c { grad.d_rho_s[c] } else { 0.0 },
                        _ => grad.d_shared[k - 6][c],
                    };
                    let scale = 1.0 + numeric.abs().max(analytic.abs());
                    prop_assert!((numeric - analytic).abs() < 2e-4 * scale,
                        "{} param {} channel {}: numeric {} analytic {}", m.name(), k, c, numeric, analytic);
                }
            }
        }
    }

    #[test]
    fn reciprocity_and_non_negativity(
        ax in 0.03f64..0.8, ay in 0.03f64..0.8, tx in -0.6f64..0.6, ty in -0.6f64..0.6,
        ti in 0.0f64..1.5, pi_ in 0.0f64..6.0, tr in 0.0f64..1.5, pr in 0.0f64..6.0,
    ) {
        let p = Prepared::new(params(ax, ay, tx, ty));
        let (l, v) = (dir(ti, pi_), dir(tr, pr));
        for m in models() {
            let a = m.brdf(&p, l, v);
            let b = m.brdf(&p, v, l);
            for c in 0..3 {
                prop_assert!(a[c] >= 0.0 && a[c].is_finite());
                prop_assert!((a[c] - b[c]).abs() <= 1e-9 * (1.0 + a[c]), "{}", m.name());
            }
        }
    }

    #[test]
    fn isotropic_case_matches_textbook_formulas(
        a in 0.03f64..0.8, ti in 0.0f64..1.4, pi_ in 0.0f64..6.0, tr in 0.0f64..1.4, pr in 0.0f64..6.0,
    ) {
        let mut q = params(a, a, 0.0, 0.0);
        q.rho_d = [0.0; 3];
        q.rho_s = [1.0, 1.0, 1.0];
        let p = Prepared::new(q);
        let (l, v) = (dir(ti, pi_), dir(tr, pr));
        let h = (l + v).normalize();
        let th = h.z.acos();
        // Ward's isotropic form.
        let ward = (-(th.tan().powi(2)) / (a * a)).exp() / (4.0 * PI * a * a * (l.z * v.z).sqrt());
        prop_assert!((Ward.brdf(&p, l, v)[0] - ward).abs() <= 1e-9 * (1.0 + ward));
        // GGX (Trowbridge-Reitz) isotropic D with F = 1 and Smith G for rho_s = 1.
        let d = a * a / (PI * ((a * a - 1.0) * th.cos().powi(2) + 1.0).powi(2));
        let lam = |c: f64| 0.5 * ((1.0 + a * a * (1.0 - c * c) / (c * c)).sqrt() - 1.0);
        let g = 1.0 / (1.0 + lam(l.z) + lam(v.z));
        let ggx = d * g / (4.0 * l.z * v.z);
        prop_assert!((Ggx.brdf(&p, l, v)[0] - ggx).abs() <= 1e-8 * (1.0 + ggx));
    }
}

/// Directional albedo: integral of f cos(theta_r) over the hemisphere, by the midpoint
/// rule in (cos theta, phi), which is exact in the limit and fine enough for a lobe of
/// roughness >= 0.05 at this resolution.
fn albedo(m: &dyn BrdfModel, p: &Prepared, theta_i: f64) -> f64 {
    let l = dir(theta_i, 0.3);
    let (nu, np) = (600, 600);
    let mut sum = 0.0;
    for i in 0..nu {
        let mu = (i as f64 + 0.5) / nu as f64; // cos theta_r
        let st = (1.0 - mu * mu).sqrt();
        for j in 0..np {
            let phi = 2.0 * PI * (j as f64 + 0.5) / np as f64;
            let v = Vec3::new(st * phi.cos(), st * phi.sin(), mu);
            sum += m.brdf(p, l, v)[0] * mu;
        }
    }
    sum * 2.0 * PI / (nu * np) as f64
}

#[test]
fn white_furnace_energy_bound() {
    // rho_d + rho_s = 1 is the worst case allowed by eq. (11). Ward's normalisation is
    // known to exceed 1 at grazing incidence for rough lobes, so its domain is limited
    // to incidence <= 60 degrees and alpha <= 0.3 (docs/CONVENTIONS.md says so too).
    for &(rd, rs) in &[(1.0, 0.0), (0.5, 0.5), (0.0, 1.0), (0.2, 0.8)] {
        for &a in &[0.08, 0.15, 0.3] {
            for &ti in &[0.0f64, 30.0, 60.0] {
                let mut q = params(a, a * 1.5, 0.0, 0.0);
                q.rho_d = [rd; 3];
                q.rho_s = [rs; 3];
                let p = Prepared::new(q);
                let w = albedo(&Ward, &p, ti.to_radians());
                assert!(
                    w <= 1.0 + 2e-3,
                    "ward rd={rd} rs={rs} a={a} ti={ti}: albedo {w}"
                );
                let g = albedo(&Ggx, &p, ti.to_radians());
                assert!(
                    g <= 1.0 + 2e-3,
                    "ggx rd={rd} rs={rs} a={a} ti={ti}: albedo {g}"
                );
            }
        }
    }
    // GGX holds at grazing incidence and high roughness too.
    for &a in &[0.1, 0.5, 0.9] {
        let mut q = params(a, a, 0.0, 0.0);
        q.rho_d = [0.3; 3];
        q.rho_s = [0.7; 3];
        let g = albedo(&Ggx, &Prepared::new(q), 80f64.to_radians());
        assert!(g <= 1.0 + 2e-3, "ggx grazing a={a}: {g}");
    }
    // Lambertian part alone integrates to rho_d.
    let mut q = params(0.1, 0.1, 0.0, 0.0);
    q.rho_d = [0.7; 3];
    q.rho_s = [0.0; 3];
    let w = albedo(&Ward, &Prepared::new(q), 0.4);
    assert!((w - 0.7).abs() < 1e-3, "{w}");
}

#[test]
fn radiance_follows_inverse_square_and_cosine() {
    let p = Prepared::new(params(0.2, 0.2, 0.0, 0.0));
    let near = LightView::from_points(
        Vec3::zeros(),
        Vec3::new(0.0, 0.0, 10.0),
        Vec3::new(0.0, 0.0, 10.0),
    );
    let far = LightView::from_points(
        Vec3::zeros(),
        Vec3::new(0.0, 0.0, 20.0),
        Vec3::new(0.0, 0.0, 10.0),
    );
    let a = Ward.radiance(&p, &near, 100.0);
    let b = Ward.radiance(&p, &far, 100.0);
    // Same half vector (both along the normal), so only the falloff differs.
    assert!((a[0] / b[0] - 4.0).abs() < 1e-9);
    let below = LightView::from_points(
        Vec3::zeros(),
        Vec3::new(0.0, 0.0, -10.0),
        Vec3::new(0.0, 0.0, 10.0),
    );
    assert_eq!(Ward.radiance(&p, &below, 100.0), [0.0; 3]);
}

#[test]
fn normal_angles_round_trip() {
    for &(tx, ty) in &[(0.0, 0.0), (0.3, -0.2), (-0.7, 0.5)] {
        let q = params(0.1, 0.1, tx, ty);
        let (bx, by) = BrdfParams::angles_from_normal(q.normal());
        assert!((bx - tx).abs() < 1e-12 && (by - ty).abs() < 1e-12);
    }
    // theta_x tilts the normal towards -y (rotation about +x), theta_y towards +x.
    let n = params(0.1, 0.1, 0.2, 0.0).normal();
    assert!(n.y < 0.0 && n.x.abs() < 1e-12);
    let n = params(0.1, 0.1, 0.0, 0.2).normal();
    assert!(n.x > 0.0 && n.y.abs() < 1e-12);
}

#[test]
fn frame_from_normal_matches_angles() {
    let a = ShadingFrame::new(0.3, -0.4);
    let b = ShadingFrame::from_normal(a.n);
    assert!((a.n - b.n).norm() < 1e-12 && (a.t - b.t).norm() < 1e-12 && (a.b - b.b).norm() < 1e-12);
    assert!(a.t.dot(&a.n).abs() < 1e-12 && (a.b - a.n.cross(&a.t)).norm() < 1e-12);
    let c = ShadingFrame::for_evaluation(a.n);
    assert!((a.t - c.t).norm() < 1e-12 && (a.b - c.b).norm() < 1e-12);
}

#[test]
fn a_quarter_turn_swaps_the_roughnesses() {
    let lv = LightView::from_points(
        Vec3::new(0.3, -0.2, 0.0),
        Vec3::new(2.0, 1.0, 9.0),
        Vec3::new(0.5, 1.5, 10.0),
    );
    for m in models() {
        for turn in [0.0, 0.4, -1.1, 2.0] {
            let a = BrdfParams {
                tangent_rotation: turn,
                ..params(0.08, 0.3, 0.1, -0.2)
            };
            let b = BrdfParams {
                tangent_rotation: turn + std::f64::consts::FRAC_PI_2,
                ..params(0.3, 0.08, 0.1, -0.2)
            };
            let half = BrdfParams {
                tangent_rotation: turn + PI,
                ..a
            };
            let va = m.radiance(&Prepared::new(a), &lv, 300.0);
            for other in [b, half, a.canonical_rotation(), b.canonical_rotation()] {
                let v = m.radiance(&Prepared::new(other), &lv, 300.0);
                for c in 0..3 {
                    assert!(
                        (v[c] - va[c]).abs() <= 1e-9 * va[c].abs().max(1.0),
                        "{other:?}"
                    );
                }
            }
            let r = a.canonical_rotation().tangent_rotation;
            assert!((0.0..std::f64::consts::FRAC_PI_2).contains(&r));
            // Turned, the lobe is another: the highlight moves.
            let lobe = BrdfParams {
                rho_d: [0.0; 3],
                ..a
            };
            let turned = BrdfParams {
                tangent_rotation: turn + 0.5,
                ..lobe
            };
            let vl = m.radiance(&Prepared::new(lobe), &lv, 300.0);
            let vt = m.radiance(&Prepared::new(turned), &lv, 300.0);
            assert!(
                (vt[0] - vl[0]).abs() > 1e-2 * vl[0],
                "{} {vt:?} {vl:?}",
                m.name()
            );
        }
    }
}
