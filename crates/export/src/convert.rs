//! From the fitted model to what other renderers understand.
//!
//! **Roughness.** Ward's lobe `exp(-tan^2(theta_h)/alpha^2) / (4 pi alpha^2 sqrt(cos_i
//! cos_r))` is close to a Beckmann microfacet lobe, and GGX with the same `alpha` has the
//! same peak but longer tails. [`WARD_TO_GGX_ALPHA`] is the least-squares scale between
//! the two (specular lobe times cosine over the light hemisphere, three view angles,
//! alpha 0.05-0.4); the test below recomputes it from the core's own models and checks
//! the remaining lobe difference. GGX fits need no conversion.
//!
//! **glTF** (metallic-roughness, dielectric, `KHR_materials_specular`,
//! `KHR_materials_anisotropy`): glTF's `alpha = roughness^2` is the *smaller* of the two
//! GGX alphas; the larger one is `mix(alpha, 1, strength^2)` along the anisotropy
//! direction (per pixel: the tangent, plane +x turned by the fitted tangent rotation,
//! or the bitangent, whichever has the larger alpha). The specular colour is F0 = `rho_s` (at normal
//! incidence Ward's specular albedo and the Fresnel reflectance agree to first order),
//! stored as `specularColorFactor * texture` with `dielectric F0 = 0.04` (ior 1.5). glTF
//! scales the diffuse layer by `1 - max(F0)`, so the base colour is `rho_d / (1 -
//! max(F0))`, which keeps the rendered diffuse equal to the fitted one.
use svbrdf_core::brdf::{BrdfParams, ModelKind};
use svbrdf_core::geometry::Vec3;

/// GGX alpha = this x Ward alpha (see the module documentation).
pub const WARD_TO_GGX_ALPHA: f64 = 1.03;

/// glTF's dielectric F0 at its default ior of 1.5.
pub const GLTF_DIELECTRIC_F0: f64 = 0.04;

/// The smallest alpha written (glTF renderers clamp near-mirror lobes anyway).
pub const MIN_ALPHA: f64 = 1e-3;

/// GGX roughness (alpha_x, alpha_y) for a fitted parameter set.
pub fn ggx_alphas(model: ModelKind, p: &BrdfParams) -> (f64, f64) {
    let k = match model {
        ModelKind::Ward => WARD_TO_GGX_ALPHA,
        ModelKind::Ggx => 1.0,
    };
    (
        (k * p.alpha_x).clamp(MIN_ALPHA, 1.0),
        (k * p.alpha_y).clamp(MIN_ALPHA, 1.0),
    )
}

/// One texel of the glTF material, before encoding.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GltfTexel {
    /// Base colour, linear RGB in [0, 1].
    pub base_color: [f64; 3],
    /// glTF roughness (sqrt of the smaller GGX alpha).
    pub roughness: f64,
    /// F0, linear RGB in [0, 1].
    pub f0: [f64; 3],
    /// Anisotropy direction in tangent space (unit; (1, 0) = plane +x).
    pub anisotropy_direction: [f64; 2],
    /// Anisotropy strength in [0, 1].
    pub anisotropy_strength: f64,
    /// Tangent-space unit normal (+x = plane +x, +y = plane +y).
    pub normal: Vec3,
}

/// Convert one parameter set.
pub fn gltf_texel(model: ModelKind, p: &BrdfParams) -> GltfTexel {
    let f0 = p.rho_s.map(|v| v.clamp(0.0, 1.0));
    let fmax = f0.iter().copied().fold(0.0, f64::max).min(0.99);
    let base_color = p.rho_d.map(|v| (v.max(0.0) / (1.0 - fmax)).min(1.0));
    let (ax, ay) = ggx_alphas(model, p);
    let (lo, hi) = (ax.min(ay), ax.max(ay));
    let strength = if hi > lo {
        ((hi - lo) / (1.0 - lo).max(1e-9)).sqrt().clamp(0.0, 1.0)
    } else {
        0.0
    };
    // The long axis of the lobe: the turned tangent where alpha_x is the larger, the
    // turned bitangent otherwise.
    let (sin, cos) = p.tangent_rotation.sin_cos();
    let anisotropy_direction = if ax >= ay { [cos, sin] } else { [-sin, cos] };
    GltfTexel {
        base_color,
        roughness: lo.sqrt(),
        f0,
        anisotropy_direction,
        anisotropy_strength: strength,
        normal: p.normal(),
    }
}

/// The two GGX alphas a glTF renderer uses for a texel (along the anisotropy
/// direction, across it), per `KHR_materials_anisotropy`.
pub fn gltf_alphas(t: &GltfTexel) -> (f64, f64) {
    let a = t.roughness * t.roughness;
    let s2 = t.anisotropy_strength * t.anisotropy_strength;
    (a + (1.0 - a) * s2, a)
}

#[cfg(test)]
mod tests {
    use super::*;
    use svbrdf_core::brdf::{BrdfModel, Ggx, Prepared, Ward};

    /// Relative L2 difference of the specular lobes (times cos_i) of Ward at `alpha`
    /// and GGX at `k * alpha`, over the light hemisphere for three view directions.
    fn lobe_difference(alpha: f64, k: f64) -> f64 {
        let spec = |a: f64| {
            let p = BrdfParams {
                rho_d: [0.0; 3],
                rho_s: [1.0; 3],
                alpha_x: a,
                alpha_y: a,
                normal_theta_x: 0.0,
                normal_theta_y: 0.0,
                tangent_rotation: 0.0,
            };
            Prepared::new(p)
        };
        let (w, pw): (&dyn BrdfModel, _) = (&Ward, spec(alpha));
        let (g, pg): (&dyn BrdfModel, _) = (&Ggx, spec(k * alpha));
        let (mut err, mut norm) = (0.0, 0.0);
        for view_deg in [0.0f64, 25.0, 50.0] {
            let v = Vec3::new(
                view_deg.to_radians().sin(),
                0.0,
                view_deg.to_radians().cos(),
            );
            let n = 120;
            for i in 0..n {
                let theta = (i as f64 + 0.5) / n as f64 * std::f64::consts::FRAC_PI_2 * 0.98;
                for j in 0..(2 * n) {
                    let phi = (j as f64 + 0.5) / (2 * n) as f64 * std::f64::consts::TAU;
                    let l = Vec3::new(
                        theta.sin() * phi.cos(),
                        theta.sin() * phi.sin(),
                        theta.cos(),
                    );
                    let dw = theta.sin();
                    let a = w.brdf(&pw, l, v)[0] * l.z;
                    let b = g.brdf(&pg, l, v)[0] * l.z;
                    err += (a - b) * (a - b) * dw;
                    norm += a * a * dw;
                }
            }
        }
        (err / norm).sqrt()
    }

    #[test]
    fn ward_to_ggx_scale_is_the_least_squares_one_and_lobes_agree() {
        for alpha in [0.08, 0.15, 0.3] {
            let ks: Vec<f64> = (0..=30).map(|i| 0.8 + 0.02 * i as f64).collect();
            let errs: Vec<f64> = ks.iter().map(|k| lobe_difference(alpha, *k)).collect();
            let (best, _) = ks
                .iter()
                .zip(&errs)
                .min_by(|a, b| a.1.total_cmp(b.1))
                .expect("non-empty");
            assert!(
                (best - WARD_TO_GGX_ALPHA).abs() <= 0.06,
                "alpha {alpha}: best scale {best}, constant {WARD_TO_GGX_ALPHA}"
            );
            let at_constant = lobe_difference(alpha, WARD_TO_GGX_ALPHA);
            // What remains is GGX's longer tail and its shadowing term (measured
            // 0.23-0.25 here); a 25% scale error is clearly worse.
            assert!(
                at_constant < 0.3,
                "alpha {alpha}: lobe difference {at_constant}"
            );
            for wrong in [0.8, 1.3] {
                let e = lobe_difference(alpha, wrong);
                assert!(
                    at_constant < 0.75 * e,
                    "alpha {alpha}: {at_constant} vs {e} at {wrong}"
                );
            }
        }
    }

    #[test]
    fn gltf_anisotropy_direction_turns_with_the_tangent() {
        let p = BrdfParams {
            alpha_x: 0.08,
            alpha_y: 0.3,
            tangent_rotation: 30f64.to_radians(),
            ..BrdfParams::default()
        };
        // alpha_y is the larger: its axis, the bitangent, is plane +y turned by 30
        // degrees towards -x.
        let d = gltf_texel(ModelKind::Ward, &p).anisotropy_direction;
        let want = [-(30f64.to_radians().sin()), 30f64.to_radians().cos()];
        assert!(
            (d[0] - want[0]).abs() < 1e-12 && (d[1] - want[1]).abs() < 1e-12,
            "{d:?}"
        );
        let q = BrdfParams {
            alpha_x: 0.3,
            alpha_y: 0.08,
            ..p
        };
        let d = gltf_texel(ModelKind::Ward, &q).anisotropy_direction;
        let want = [30f64.to_radians().cos(), 30f64.to_radians().sin()];
        assert!(
            (d[0] - want[0]).abs() < 1e-12 && (d[1] - want[1]).abs() < 1e-12,
            "{d:?}"
        );
    }

    #[test]
    fn gltf_anisotropy_reproduces_both_alphas() {
        for (ax, ay) in [(0.1, 0.1), (0.3, 0.05), (0.04, 0.2), (0.5, 0.49)] {
            let p = BrdfParams {
                rho_d: [0.3, 0.2, 0.1],
                rho_s: [0.1, 0.1, 0.1],
                alpha_x: ax,
                alpha_y: ay,
                normal_theta_x: 0.1,
                normal_theta_y: -0.2,
                tangent_rotation: 0.0,
            };
            let t = gltf_texel(ModelKind::Ggx, &p);
            let (along, across) = gltf_alphas(&t);
            let (want_along, want_across) = if ax >= ay { (ax, ay) } else { (ay, ax) };
            assert!((along - want_along).abs() < 1e-9, "{ax} {ay}: {along}");
            assert!((across - want_across).abs() < 1e-9, "{ax} {ay}: {across}");
            let dir = if ax >= ay { [1.0, 0.0] } else { [0.0, 1.0] };
            assert_eq!(t.anisotropy_direction, dir);
            assert!((t.normal - p.normal()).norm() < 1e-12);
        }
    }

    #[test]
    fn base_colour_compensates_the_specular_layer() {
        let p = BrdfParams {
            rho_d: [0.5, 0.4, 0.1],
            rho_s: [0.2, 0.1, 0.05],
            ..BrdfParams::default()
        };
        let t = gltf_texel(ModelKind::Ward, &p);
        for c in 0..3 {
            assert!((t.base_color[c] * (1.0 - 0.2) - p.rho_d[c]).abs() < 1e-12);
        }
        assert_eq!(t.f0, p.rho_s);
    }
}
