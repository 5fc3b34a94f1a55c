use std::f64::consts::PI;

use super::{BrdfModel, LightView, Prepared, RadianceGrad};
use crate::geometry::Vec3;

/// Anisotropic GGX / Cook-Torrance microfacet model with Schlick's Fresnel and the
/// height-correlated Smith masking-shadowing term:
///
/// `f = rho_d / pi + D G F / (4 cos_i cos_r)`, `F = rho_s + (1 - rho_s - rho_d)(1 - l.h)^5`.
///
/// `rho_s` is the Fresnel reflectance at normal incidence (F0). Fresnel rises towards
/// `1 - rho_d` (not 1) at grazing angles, so that with `rho_d + rho_s <= 1` the
/// directional albedo is at most `rho_d + (1 - rho_d) = 1`: energy is conserved by
/// construction, with no extra diffuse weighting.
#[derive(Debug, Clone, Copy, Default)]
pub struct Ggx;

/// Smith Lambda for a direction with frame components (wt, wb, wn), and its derivatives
/// with respect to alpha_x, alpha_y and the direction components.
#[inline]
fn lambda(ax: f64, ay: f64, wt: f64, wb: f64, wn: f64) -> (f64, [f64; 5]) {
    let wn2 = wn * wn;
    let s = (ax * ax * wt * wt + ay * ay * wb * wb) / wn2;
    let root = (1.0 + s).sqrt();
    let l = 0.5 * (root - 1.0);
    let k = 0.25 / root; // d lambda / d s
    (
        l,
        [
            k * 2.0 * ax * wt * wt / wn2,
            k * 2.0 * ay * wb * wb / wn2,
            k * 2.0 * ax * ax * wt / wn2,
            k * 2.0 * ay * ay * wb / wn2,
            k * (-2.0 * s / wn),
        ],
    )
}

impl BrdfModel for Ggx {
    fn kind(&self) -> super::ModelKind {
        super::ModelKind::Ggx
    }

    fn name(&self) -> &'static str {
        "ggx"
    }

    #[inline]
    fn brdf(&self, p: &Prepared, light: Vec3, view: Vec3) -> [f64; 3] {
        let q = &p.params;
        let f = &p.frame;
        let cos_i = light.dot(&f.n);
        let cos_r = view.dot(&f.n);
        if cos_i <= 0.0 || cos_r <= 0.0 {
            return [0.0; 3];
        }
        let hs = light + view;
        let h = hs / hs.norm().max(1e-300);
        let (ax, ay) = (q.alpha_x, q.alpha_y);
        let (ht, hb, hn) = (h.dot(&f.t), h.dot(&f.b), h.dot(&f.n));
        let qd = ht * ht / (ax * ax) + hb * hb / (ay * ay) + hn * hn;
        let dist = 1.0 / (PI * ax * ay * qd * qd);
        let (ll, _) = lambda(ax, ay, light.dot(&f.t), light.dot(&f.b), cos_i);
        let (lv, _) = lambda(ax, ay, view.dot(&f.t), view.dot(&f.b), cos_r);
        let g2 = 1.0 / (1.0 + ll + lv);
        let w = (1.0 - light.dot(&h)).clamp(0.0, 1.0).powi(5);
        [0, 1, 2].map(|c| {
            let fr = q.rho_s[c] + (1.0 - q.rho_s[c] - q.rho_d[c]) * w;
            q.rho_d[c] / PI + dist * g2 * fr / (4.0 * cos_i * cos_r)
        })
    }

    #[inline]
    fn radiance_grad(&self, p: &Prepared, obs: &LightView, intensity: f64) -> RadianceGrad {
        let q = &p.params;
        let f = &p.frame;
        let (l, v) = (obs.light, obs.view);
        let cos_i = l.dot(&f.n);
        let cos_r = v.dot(&f.n);
        if cos_i <= 0.0 || cos_r <= 0.0 {
            return RadianceGrad::default();
        }
        let g = intensity / obs.light_dist2;
        let hs = l + v;
        let h = hs / hs.norm().max(1e-300);
        let (ax, ay) = (q.alpha_x, q.alpha_y);
        let (ht, hb, hn) = (h.dot(&f.t), h.dot(&f.b), h.dot(&f.n));
        let qd = ht * ht / (ax * ax) + hb * hb / (ay * ay) + hn * hn;
        let dist = 1.0 / (PI * ax * ay * qd * qd);
        let (lt, lb) = (l.dot(&f.t), l.dot(&f.b));
        let (vt, vb) = (v.dot(&f.t), v.dot(&f.b));
        let (ll, dll) = lambda(ax, ay, lt, lb, cos_i);
        let (lv, dlv) = lambda(ax, ay, vt, vb, cos_r);
        let g2 = 1.0 / (1.0 + ll + lv);
        let w = (1.0 - l.dot(&h)).clamp(0.0, 1.0).powi(5);

        // Specular kernel K = D G2 / (4 cos_r) (radiance = g * (cos_i rho_d/pi + F K)).
        let kern = dist * g2 / (4.0 * cos_r);
        // d ln D and d G2 for the shared parameters.
        let mut dk = [0.0; 4];
        {
            let dln_d_ax = -1.0 / ax + 4.0 * ht * ht / (ax * ax * ax * qd);
            let dln_d_ay = -1.0 / ay + 4.0 * hb * hb / (ay * ay * ay * qd);
            let dg2_ax = -g2 * g2 * (dll[0] + dlv[0]);
            let dg2_ay = -g2 * g2 * (dll[1] + dlv[1]);
            dk[0] = kern * dln_d_ax + dist * dg2_ax / (4.0 * cos_r);
            dk[1] = kern * dln_d_ay + dist * dg2_ay / (4.0 * cos_r);
        }
        let mut dcos_i = [0.0; 2];
        for k in 0..2 {
            let (dn, dt, db) = (f.dn[k], f.dt[k], f.db[k]);
            let dq = 2.0 * ht * h.dot(&dt) / (ax * ax)
                + 2.0 * hb * h.dot(&db) / (ay * ay)
                + 2.0 * hn * h.dot(&dn);
            let dln_d = -2.0 * dq / qd;
            dcos_i[k] = l.dot(&dn);
            let dcos_r = v.dot(&dn);
            let dl_l = dll[2] * l.dot(&dt) + dll[3] * l.dot(&db) + dll[4] * dcos_i[k];
            let dl_v = dlv[2] * v.dot(&dt) + dlv[3] * v.dot(&db) + dlv[4] * dcos_r;
            let dg2 = -g2 * g2 * (dl_l + dl_v);
            dk[2 + k] = kern * (dln_d - dcos_r / cos_r) + dist * dg2 / (4.0 * cos_r);
        }

        // Room light (`LightView::ambient`): diffuse only, independent of the normal.
        let amb = intensity * obs.ambient / PI;
        let mut out = RadianceGrad::default();
        for c in 0..3 {
            let fr = q.rho_s[c] + (1.0 - q.rho_s[c] - q.rho_d[c]) * w;
            let diff = q.rho_d[c] / PI;
            out.value[c] = amb * q.rho_d[c] + g * (cos_i * diff + fr * kern);
            out.d_rho_d[c] = amb + g * (cos_i / PI - w * kern);
            out.d_rho_s[c] = g * (1.0 - w) * kern;
            out.d_shared[0][c] = g * fr * dk[0];
            out.d_shared[1][c] = g * fr * dk[1];
            for k in 0..2 {
                out.d_shared[2 + k][c] = g * (dcos_i[k] * diff + fr * dk[2 + k]);
            }
        }
        out
    }
}
