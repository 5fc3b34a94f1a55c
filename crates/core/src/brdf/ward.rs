use std::f64::consts::PI;

use super::{BrdfModel, LightView, Prepared, RadianceGrad};
use crate::geometry::Vec3;

/// The anisotropic Ward model of the paper's eq. (10):
///
/// `f = rho_d / pi + rho_s * exp(-((h.t/ax)^2 + (h.b/ay)^2) / (h.n)^2) / (4 pi ax ay sqrt(cos_i cos_r))`
///
/// The exponent is the paper's `-tan^2(theta_h) (cos^2(phi_h)/ax^2 + sin^2(phi_h)/ay^2)`
/// written with dot products, which avoids every trigonometric call.
#[derive(Debug, Clone, Copy, Default)]
pub struct Ward;

/// Dot products of one observation with the frame.
struct Dots {
    h: Vec3,
    cos_i: f64,
    cos_r: f64,
    hn: f64,
    ht: f64,
    hb: f64,
}

#[inline]
fn dots(p: &Prepared, l: Vec3, v: Vec3) -> Option<Dots> {
    let f = &p.frame;
    let cos_i = l.dot(&f.n);
    let cos_r = v.dot(&f.n);
    if cos_i <= 0.0 || cos_r <= 0.0 {
        return None;
    }
    let hs = l + v;
    let h = hs / hs.norm().max(1e-300);
    Some(Dots {
        h,
        cos_i,
        cos_r,
        hn: h.dot(&f.n),
        ht: h.dot(&f.t),
        hb: h.dot(&f.b),
    })
}

impl BrdfModel for Ward {
    fn kind(&self) -> super::ModelKind {
        super::ModelKind::Ward
    }

    fn name(&self) -> &'static str {
        "ward"
    }

    #[inline]
    fn brdf(&self, p: &Prepared, light: Vec3, view: Vec3) -> [f64; 3] {
        let q = &p.params;
        let Some(d) = dots(p, light, view) else {
            return [0.0; 3];
        };
        let (ax, ay) = (q.alpha_x, q.alpha_y);
        let e = -((d.ht / ax).powi(2) + (d.hb / ay).powi(2)) / (d.hn * d.hn);
        let spec = e.exp() / (4.0 * PI * ax * ay * (d.cos_i * d.cos_r).sqrt());
        [0, 1, 2].map(|c| q.rho_d[c] / PI + q.rho_s[c] * spec)
    }

    #[inline]
    fn radiance_grad(&self, p: &Prepared, obs: &LightView, intensity: f64) -> RadianceGrad {
        let q = &p.params;
        let f = &p.frame;
        let Some(d) = dots(p, obs.light, obs.view) else {
            return RadianceGrad::default();
        };
        let g = intensity / obs.light_dist2;
        let (ax, ay) = (q.alpha_x, q.alpha_y);
        let (tx, ty) = (d.ht / ax, d.hb / ay);
        let hn2 = d.hn * d.hn;
        let quad = tx * tx + ty * ty;
        let e = -quad / hn2;
        // S = f_spec * cos_i / rho_s.
        let s = e.exp() * d.cos_i.sqrt() / (4.0 * PI * ax * ay * d.cos_r.sqrt());

        // Relative derivatives dS/S for the shared parameters.
        let mut rel = [0.0; 4];
        rel[0] = 2.0 * tx * tx / (ax * hn2) - 1.0 / ax;
        rel[1] = 2.0 * ty * ty / (ay * hn2) - 1.0 / ay;
        let mut dcos_i = [0.0; 2];
        for k in 0..2 {
            let dhn = d.h.dot(&f.dn[k]);
            let dht = d.h.dot(&f.dt[k]);
            let dhb = d.h.dot(&f.db[k]);
            dcos_i[k] = obs.light.dot(&f.dn[k]);
            let dcos_r = obs.view.dot(&f.dn[k]);
            let de = -2.0 * (d.ht * dht / (ax * ax) + d.hb * dhb / (ay * ay)) / hn2
                + 2.0 * quad * dhn / (hn2 * d.hn);
            rel[2 + k] = de + 0.5 * dcos_i[k] / d.cos_i - 0.5 * dcos_r / d.cos_r;
        }

        // Room light (`LightView::ambient`): diffuse only, independent of the normal.
        let amb = intensity * obs.ambient / PI;
        let mut out = RadianceGrad::default();
        for c in 0..3 {
            let diff = q.rho_d[c] / PI;
            let spec = q.rho_s[c] * s;
            out.value[c] = amb * q.rho_d[c] + g * (diff * d.cos_i + spec);
            out.d_rho_d[c] = amb + g * d.cos_i / PI;
            out.d_rho_s[c] = g * s;
            out.d_shared[0][c] = g * spec * rel[0];
            out.d_shared[1][c] = g * spec * rel[1];
            for k in 0..2 {
                out.d_shared[2 + k][c] = g * (diff * dcos_i[k] + spec * rel[2 + k]);
            }
        }
        out
    }
}
