//! Ward (eq. 10) for many observations of one surface point at once: f32 and
//! structure-of-arrays buffers padded to a multiple of [`LANES`], with `exp` as a
//! polynomial, so that the compiler turns every loop into SIMD code. The fitter's hot
//! loops (per-pixel errors, refinement, re-rendering) evaluate tens of millions of
//! observations per split level; the scalar f64 path of [`Ward`](super::Ward) stays
//! the reference that the tests compare against.
//!
//! Radiance of channel `c` factors into two shape terms that do not depend on the
//! albedos: `L_c = I_c * (rho_d_c * D + rho_s_c * S)` with
//! `D = (cos_i / r^2 + ambient) / pi` (the room light of
//! [`LightView::ambient`](super::LightView)) and
//! `S = exp(-((h.t/ax)^2 + (h.b/ay)^2) / (h.n)^2) * sqrt(cos_i / cos_r) / (4 pi ax ay r^2)`
//! (zero when the light or the camera is below the offset surface).

use super::Prepared;
use crate::geometry::Vec3;

/// Buffers are padded to a multiple of this many observations.
pub const LANES: usize = 8;

const INV_PI: f32 = std::f32::consts::FRAC_1_PI;

/// Observation geometry of one surface point: unit light and view directions and the
/// inverse squared light distance, one entry per observation, padded with entries
/// whose shape terms are zero.
#[derive(Debug, Clone, Default)]
pub struct GeometryBatch {
    /// Light direction, x, y, z.
    pub l: [Vec<f32>; 3],
    /// View direction, x, y, z.
    pub v: [Vec<f32>; 3],
    /// `1 / r^2`, cm^-2.
    pub inv_r2: Vec<f32>,
    /// Room light of every observation ([`LightView::ambient`](super::LightView), cm^-2):
    /// added to `cos_i / r^2` in `D`. Set by the caller; [`begin`](Self::begin) keeps it.
    pub ambient: f32,
    len: usize,
}

impl GeometryBatch {
    /// Empty, keeping the allocations.
    pub fn clear(&mut self) {
        for a in self.l.iter_mut().chain(self.v.iter_mut()) {
            a.clear();
        }
        self.inv_r2.clear();
        self.len = 0;
    }

    /// Observations pushed (without padding).
    pub fn len(&self) -> usize {
        self.len
    }

    /// Whether there are none.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// The seven columns (light x, y, z, view x, y, z, `1 / r^2`), padded length.
    pub fn columns(&self) -> [&[f32]; 7] {
        let n = self.padded_len();
        [
            &self.l[0][..n],
            &self.l[1][..n],
            &self.l[2][..n],
            &self.v[0][..n],
            &self.v[1][..n],
            &self.v[2][..n],
            &self.inv_r2[..n],
        ]
    }

    /// Length with padding.
    pub fn padded_len(&self) -> usize {
        self.inv_r2.len()
    }

    /// Make room for `n` observations (padded to a multiple of [`LANES`]; the padding
    /// points the light straight down, so its shape terms are zero); fill them with
    /// [`set`](Self::set), then call [`finish`](Self::finish).
    pub fn begin(&mut self, n: usize) {
        self.clear();
        let padded = n.div_ceil(LANES) * LANES;
        let [lx, ly, lz] = &mut self.l;
        let [vx, vy, vz] = &mut self.v;
        for (a, fill) in [
            (lx, 0.0),
            (ly, 0.0),
            (lz, -1.0),
            (vx, 0.0),
            (vy, 0.0),
            (vz, 1.0),
            (&mut self.inv_r2, 0.0),
        ] {
            a.resize(padded, fill);
        }
        self.len = n;
    }

    /// Observation `i` from the offsets surface->light and surface->camera (cm).
    #[inline]
    pub fn set(&mut self, i: usize, to_light: [f32; 3], to_camera: [f32; 3]) {
        for k in 0..3 {
            self.l[k][i] = to_light[k];
            self.v[k][i] = to_camera[k];
        }
    }

    /// Normalise the offsets set since [`begin`](Self::begin).
    pub fn finish(&mut self) {
        let n = self.len;
        let [lx, ly, lz] = &mut self.l;
        let [vx, vy, vz] = &mut self.v;
        let r = &mut self.inv_r2;
        let (lx, ly, lz, vx, vy, vz, r) = (
            &mut lx[..n],
            &mut ly[..n],
            &mut lz[..n],
            &mut vx[..n],
            &mut vy[..n],
            &mut vz[..n],
            &mut r[..n],
        );
        for i in 0..n {
            let l2 = (lx[i] * lx[i] + ly[i] * ly[i] + lz[i] * lz[i]).max(1e-12);
            let il = 1.0 / l2.sqrt();
            lx[i] *= il;
            ly[i] *= il;
            lz[i] *= il;
            r[i] = 1.0 / l2;
            let v2 = (vx[i] * vx[i] + vy[i] * vy[i] + vz[i] * vz[i]).max(1e-12);
            let iv = 1.0 / v2.sqrt();
            vx[i] *= iv;
            vy[i] *= iv;
            vz[i] *= iv;
        }
    }
}

/// Shape terms per observation (see the module documentation), and optionally their
/// derivatives.
#[derive(Debug, Clone, Default)]
pub struct Shapes {
    /// `D`.
    pub d: Vec<f32>,
    /// `S`.
    pub s: Vec<f32>,
    /// `dD / d theta_x`, `dD / d theta_y`.
    pub dd: [Vec<f32>; 2],
    /// Relative derivatives `(dS / dp) / S` for p = alpha_x, alpha_y, theta_x, theta_y.
    pub rel: [Vec<f32>; 4],
}

impl Shapes {
    fn resize(&mut self, n: usize, grad: bool) {
        self.d.resize(n, 0.0);
        self.s.resize(n, 0.0);
        if grad {
            for a in self.dd.iter_mut().chain(self.rel.iter_mut()) {
                a.resize(n, 0.0);
            }
        }
    }
}

/// A Ward parameter set's frame and roughness in f32.
#[derive(Debug, Clone, Copy)]
pub struct WardF32 {
    n: [f32; 3],
    t: [f32; 3],
    b: [f32; 3],
    dn: [[f32; 3]; 2],
    dt: [[f32; 3]; 2],
    db: [[f32; 3]; 2],
    ax: f32,
    ay: f32,
    norm: f32,
}

fn f3(v: Vec3) -> [f32; 3] {
    [v.x as f32, v.y as f32, v.z as f32]
}

impl WardF32 {
    /// From a prepared parameter set (its frame derivatives are used by
    /// [`shapes_grad`]).
    pub fn new(p: &Prepared) -> Self {
        let f = &p.frame;
        let (ax, ay) = (p.params.alpha_x, p.params.alpha_y);
        Self {
            n: f3(f.n),
            t: f3(f.t),
            b: f3(f.b),
            dn: f.dn.map(f3),
            dt: f.dt.map(f3),
            db: f.db.map(f3),
            ax: ax as f32,
            ay: ay as f32,
            norm: (1.0 / (4.0 * std::f64::consts::PI * ax * ay)) as f32,
        }
    }
}

/// `exp(x)` for `x <= 0` to about 2e-7 relative (Cephes' polynomial with round-to-
/// nearest by a magic constant, so that it vectorises); 0 below -87.
#[inline(always)]
pub fn exp_neg(x: f32) -> f32 {
    let x = x.clamp(-87.0, 0.0);
    const MAGIC: f32 = 12_582_912.0; // 1.5 * 2^23
    let nf = (x * std::f32::consts::LOG2_E + MAGIC) - MAGIC;
    let r = x - nf * 0.693_359_4 + nf * 2.121_944_4e-4;
    let p = ((((1.987_569_1e-4 * r + 1.398_199_9e-3) * r + 8.333_452e-3) * r + 4.166_579_6e-2) * r
        + 1.666_666_5e-1)
        * r
        + 0.5;
    let p = p * r * r + r + 1.0;
    let scale = f32::from_bits(((nf as i32 + 127) as u32) << 23);
    p * scale
}

#[inline(always)]
fn dot(a: [f32; 3], x: f32, y: f32, z: f32) -> f32 {
    a[0] * x + a[1] * y + a[2] * z
}

/// Shape terms `D` and `S` of every (padded) observation into `out.d`, `out.s`.
pub fn shapes(w: &WardF32, g: &GeometryBatch, out: &mut Shapes) {
    let n = g.padded_len();
    out.resize(n, false);
    let (iax2, iay2) = (1.0 / (w.ax * w.ax), 1.0 / (w.ay * w.ay));
    let [lx, ly, lz, vx, vy, vz, ir] = g.columns();
    let (d, s) = (&mut out.d[..n], &mut out.s[..n]);
    for i in 0..n {
        let ci = dot(w.n, lx[i], ly[i], lz[i]);
        let cr = dot(w.n, vx[i], vy[i], vz[i]);
        let (hx, hy, hz) = (lx[i] + vx[i], ly[i] + vy[i], lz[i] + vz[i]);
        let hn = dot(w.n, hx, hy, hz);
        let ht = dot(w.t, hx, hy, hz);
        let hb = dot(w.b, hx, hy, hz);
        // h need not be normalised: its length cancels in (h.t / h.n)^2.
        let e = -(ht * ht * iax2 + hb * hb * iay2) / (hn * hn).max(1e-20);
        let valid = ci > 0.0 && cr > 0.0;
        let cis = ci.max(1e-6);
        let crs = cr.max(1e-6);
        let sv = exp_neg(e) * (cis / crs).sqrt() * w.norm * ir[i];
        d[i] = if valid {
            (cis * ir[i] + g.ambient) * INV_PI
        } else {
            0.0
        };
        s[i] = if valid { sv } else { 0.0 };
    }
}

/// Shape terms and their derivatives (roughness and normal angles).
pub fn shapes_grad(w: &WardF32, g: &GeometryBatch, out: &mut Shapes) {
    let n = g.padded_len();
    out.resize(n, true);
    let (iax2, iay2) = (1.0 / (w.ax * w.ax), 1.0 / (w.ay * w.ay));
    let (iax, iay) = (1.0 / w.ax, 1.0 / w.ay);
    let [lx, ly, lz, vx, vy, vz, ir] = g.columns();
    let Shapes { d, s, dd, rel } = out;
    let (d, s) = (&mut d[..n], &mut s[..n]);
    let [dd0, dd1] = dd;
    let (dd0, dd1) = (&mut dd0[..n], &mut dd1[..n]);
    let [r0, r1, r2, r3] = rel;
    let (r0, r1, r2, r3) = (&mut r0[..n], &mut r1[..n], &mut r2[..n], &mut r3[..n]);
    for i in 0..n {
        let (l, v) = ([lx[i], ly[i], lz[i]], [vx[i], vy[i], vz[i]]);
        let ci = dot(w.n, l[0], l[1], l[2]);
        let cr = dot(w.n, v[0], v[1], v[2]);
        let (hx, hy, hz) = (l[0] + v[0], l[1] + v[1], l[2] + v[2]);
        let ih = 1.0 / (hx * hx + hy * hy + hz * hz).max(1e-12).sqrt();
        let (hx, hy, hz) = (hx * ih, hy * ih, hz * ih);
        let hn = dot(w.n, hx, hy, hz);
        let ht = dot(w.t, hx, hy, hz);
        let hb = dot(w.b, hx, hy, hz);
        let hn2 = (hn * hn).max(1e-20);
        let ihn2 = 1.0 / hn2;
        let quad = ht * ht * iax2 + hb * hb * iay2;
        let valid = ci > 0.0 && cr > 0.0;
        let cis = ci.max(1e-6);
        let crs = cr.max(1e-6);
        let (icis, icrs) = (1.0 / cis, 1.0 / crs);
        let sv = exp_neg(-quad * ihn2) * (cis * icrs).sqrt() * w.norm * ir[i];
        d[i] = if valid {
            (cis * ir[i] + g.ambient) * INV_PI
        } else {
            0.0
        };
        s[i] = if valid { sv } else { 0.0 };
        // Invalid lanes (padding: h = 0) would give 0/0; their S is 0, but 0 * NaN is
        // not, so every derivative is masked too.
        r0[i] = if valid {
            2.0 * ht * ht * iax2 * iax * ihn2 - iax
        } else {
            0.0
        };
        r1[i] = if valid {
            2.0 * hb * hb * iay2 * iay * ihn2 - iay
        } else {
            0.0
        };
        for k in 0..2 {
            let dhn = dot(w.dn[k], hx, hy, hz);
            let dht = dot(w.dt[k], hx, hy, hz);
            let dhb = dot(w.db[k], hx, hy, hz);
            let dci = dot(w.dn[k], l[0], l[1], l[2]);
            let dcr = dot(w.dn[k], v[0], v[1], v[2]);
            let de =
                -2.0 * (ht * dht * iax2 + hb * dhb * iay2) * ihn2 + 2.0 * quad * dhn * ihn2 / hn;
            let rk = if valid {
                de + 0.5 * dci * icis - 0.5 * dcr * icrs
            } else {
                0.0
            };
            let ddk = if valid { dci * ir[i] * INV_PI } else { 0.0 };
            if k == 0 {
                r2[i] = rk;
                dd0[i] = ddk;
            } else {
                r3[i] = rk;
                dd1[i] = ddk;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::brdf::{BrdfModel, BrdfParams, LightView, Ward};

    /// A tilted anisotropic lobe for the comparisons with the f64 model.
    fn tilted_anisotropic() -> BrdfParams {
        BrdfParams {
            rho_d: [0.4, 0.2, 0.1],
            rho_s: [0.3, 0.25, 0.2],
            alpha_x: 0.12,
            alpha_y: 0.25,
            normal_theta_x: 0.1,
            normal_theta_y: -0.07,
            tangent_rotation: 0.0,
        }
    }

    fn setup() -> (Vec<LightView>, GeometryBatch) {
        let mut lvs = Vec::new();
        let mut g = GeometryBatch::default();
        g.begin(38);
        let surf = Vec3::new(0.3, -0.2, 0.0);
        for i in 0..37 {
            let a = i as f64 * 0.7;
            let cam = Vec3::new(4.0 * a.cos(), 3.0 * a.sin(), 10.0 + (i % 5) as f64);
            let light = cam + Vec3::new(1.2, -0.4, 0.1);
            lvs.push(LightView::from_points(surf, light, cam));
            g.set(i, f3(light - surf), f3(cam - surf));
        }
        // One observation from below the surface: zero.
        let below = Vec3::new(20.0, 0.0, -0.5);
        lvs.push(LightView::from_points(
            surf,
            below,
            Vec3::new(0.0, 0.0, 10.0),
        ));
        g.set(37, f3(below - surf), [-0.3, 0.2, 10.0]);
        g.finish();
        (lvs, g)
    }

    #[test]
    fn room_light_adds_to_the_diffuse_shape_as_in_the_f64_models() {
        let (lvs, mut g) = setup();
        g.ambient = 0.004;
        let params = tilted_anisotropic();
        let p = Prepared::new(params);
        let mut sh = Shapes::default();
        shapes(&WardF32::new(&p), &g, &mut sh);
        for (i, lv) in lvs.iter().enumerate().take(lvs.len() - 1) {
            let lit = lv.with_ambient(0.004);
            let (want, dark) = (
                Ward.radiance_grad(&p, &lit, 2.0),
                Ward.radiance(&p, lv, 2.0),
            );
            let generic = Ward.radiance(&p, &lit, 2.0);
            for c in 0..3 {
                let room = 2.0 * 0.004 / std::f64::consts::PI * params.rho_d[c];
                let got = 2.0
                    * (params.rho_d[c] * f64::from(sh.d[i]) + params.rho_s[c] * f64::from(sh.s[i]));
                assert!(
                    (got - want.value[c]).abs() <= 1e-5 * want.value[c],
                    "obs {i}: {got} vs {}",
                    want.value[c]
                );
                assert!((want.value[c] - dark[c] - room).abs() <= 1e-12, "obs {i}");
                assert!((generic[c] - want.value[c]).abs() <= 1e-12, "obs {i}");
                let d_rho_d = Ward.radiance_grad(&p, lv, 2.0).d_rho_d[c];
                assert!(
                    (want.d_rho_d[c] - d_rho_d - 2.0 * 0.004 / std::f64::consts::PI).abs() < 1e-12
                );
            }
        }
        // Padding stays dark.
        for i in lvs.len()..g.padded_len() {
            assert_eq!(sh.d[i], 0.0);
        }
    }

    #[test]
    fn exp_neg_matches_libm() {
        for i in 0..1740 {
            let x = -(i as f32) * 0.05;
            let (a, b) = (exp_neg(x), x.exp());
            assert!((a - b).abs() <= 3e-7 * b + 1e-38, "{x}: {a} vs {b}");
        }
        assert_eq!(exp_neg(-1000.0), (-87.0f32).exp());
    }

    #[test]
    fn shapes_and_derivatives_match_the_f64_model() {
        let (lvs, g) = setup();
        assert_eq!(g.padded_len() % LANES, 0);
        let params = tilted_anisotropic();
        let p = Prepared::new(params);
        let w = WardF32::new(&p);
        let mut sh = Shapes::default();
        let mut sg = Shapes::default();
        shapes(&w, &g, &mut sh);
        shapes_grad(&w, &g, &mut sg);
        for (i, lv) in lvs.iter().enumerate() {
            let want = Ward.radiance_grad(&p, lv, 1.0);
            for c in 0..3 {
                for (sv, dv) in [(sh.s[i], sh.d[i]), (sg.s[i], sg.d[i])] {
                    let got = params.rho_d[c] * f64::from(dv) + params.rho_s[c] * f64::from(sv);
                    assert!(
                        (got - want.value[c]).abs() <= 1e-5 * want.value[c].abs() + 1e-9,
                        "obs {i} value {got} vs {}",
                        want.value[c]
                    );
                }
                for k in 0..2 {
                    let got = params.rho_s[c] * f64::from(sg.s[i] * sg.rel[k][i]);
                    let w = want.d_shared[k][c];
                    assert!(
                        (got - w).abs() <= 1e-4 * w.abs() + 1e-8,
                        "alpha {k} {got} vs {w}"
                    );
                    let got = params.rho_d[c] * f64::from(sg.dd[k][i])
                        + params.rho_s[c] * f64::from(sg.s[i] * sg.rel[2 + k][i]);
                    let w = want.d_shared[2 + k][c];
                    assert!(
                        (got - w).abs() <= 1e-4 * w.abs() + 1e-8,
                        "normal {k} {got} vs {w}"
                    );
                }
            }
        }
        // Padding and the observation from below contribute nothing, derivatives
        // included.
        for i in lvs.len() - 1..g.padded_len() {
            assert_eq!((sh.d[i], sh.s[i]), (0.0, 0.0));
            assert!(sg.dd.iter().chain(&sg.rel).all(|a| a[i] == 0.0));
        }
    }
}
