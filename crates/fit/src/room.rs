//! Room light: the constant light a room adds to every frame of a flash video.
//!
//! Phones film with the room lights on (10-20% of the flash's light on a surface at
//! 10-20 cm is common). The point-light model of eq. (9) cannot tell that light from
//! albedo: it reads it as brighter diffuse albedo and a wider, weaker lobe, and the maps
//! then render too bright under any light without the room. The room's light is modelled
//! as one irradiance `ambient` per unit flash intensity (cm^-2, the units of
//! `cos(theta_i) / r^2`, [`LightView::ambient`]) shared by the whole capture: a
//! Lambertian surface then records `I * rho_d / pi * (cos(theta_i) / r^2 + ambient)`.
//!
//! What separates it from albedo is distance: the flash's light falls off as `1 / r^2`
//! over the sweep, the room's does not. Per pixel, with its initial cluster's lobe shape
//! fixed, the observations are linear in `rho_d` and `rho_s`, so for any `ambient` the
//! best albedos and their squared error follow in closed form (variable projection);
//! `ambient` is the value that minimises the summed error over a sample of pixels, on a
//! grid of 1% steps of the flash's diffuse light. Clipped observations are left out.

use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use svbrdf_core::brdf::{BrdfModel, BrdfParams, Prepared};

use crate::Observations;

/// The estimate, as written in `fit.json`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct RoomLight {
    /// Irradiance per unit flash intensity, cm^-2 ([`LightView::ambient`]).
    ///
    /// [`LightView::ambient`]: svbrdf_core::brdf::LightView::ambient
    pub ambient: f64,
    /// Whether the fit applied it to every observation (not when it reached the top of
    /// the range searched, [`MAX_SHARE`], with `room_light` `auto`).
    #[serde(default)]
    pub applied: bool,
    /// The same as a share of the flash's diffuse light on the surface, at the median
    /// `cos(theta_i) / r^2` of the observations used.
    pub share_of_flash: f64,
    /// Relative drop of the sampled pixels' squared error from no room light to
    /// `ambient` (0: the data do not ask for room light).
    pub residual_drop: f64,
    /// Pixels and unclipped observations the estimate used.
    pub pixels: usize,
    /// See `pixels`.
    pub observations: usize,
}

impl RoomLight {
    /// Whether the estimate reached the top of the range searched ([`MAX_SHARE`]).
    pub fn at_bound(&self) -> bool {
        self.share_of_flash >= MAX_SHARE
    }

    /// The warning an estimate at the top of the range searched calls for.
    pub fn warning(&self) -> Option<String> {
        let share = 100.0 * self.share_of_flash;
        match (self.at_bound(), self.applied) {
            (false, _) => None,
            (true, true) => Some(format!(
                "the room light came out at the top of the range searched ({share:.0}% of the flash's light on the surface) and was applied (room_light on): the maps' albedos are doubtful"
            )),
            (true, false) => Some(format!(
                "the room light could not be told from the material (its estimate reached the top of the range searched, {share:.0}% of the flash's light on the surface): fitted as lit by the flash alone, so any room light is in the albedos"
            )),
        }
    }
}

/// The largest room light considered, as a share of the flash's diffuse light.
pub const MAX_SHARE: f64 = 1.0;

/// Grid steps over `[0, MAX_SHARE]`.
const STEPS: usize = 100;

/// At most this many pixels (spread evenly over every initial cluster) are used.
pub const MAX_PIXELS: usize = 40_000;

/// A pixel needs this many unclipped observations to take part.
const MIN_OBSERVATIONS: usize = 6;

/// Per-pixel sums of the flash's diffuse shape `d` (`cos_i / (pi r^2)`), the lobe's
/// shape `s` (radiance for `rho_s` = 1, unit intensity) and the observations `y`
/// (divided by the intensity), per channel.
#[derive(Debug, Clone, Copy, Default)]
struct Sums {
    n: f64,
    d: f64,
    dd: f64,
    s: f64,
    ds: f64,
    ss: f64,
    y: [f64; 3],
    dy: [f64; 3],
    sy: [f64; 3],
    yy: [f64; 3],
}

impl Sums {
    /// Add one observation: diffuse shape `d`, lobe shape `s`, values `y` (divided by
    /// the intensity).
    fn push(&mut self, d: f64, s: f64, y: [f64; 3]) {
        self.n += 1.0;
        self.d += d;
        self.dd += d * d;
        self.s += s;
        self.ds += d * s;
        self.ss += s * s;
        for (c, yc) in y.into_iter().enumerate() {
            self.y[c] += yc;
            self.dy[c] += d * yc;
            self.sy[c] += s * yc;
            self.yy[c] += yc * yc;
        }
    }

    /// Least-squares error of `y = rho_d (d + k) + rho_s s` per channel with
    /// `rho_d, rho_s >= 0`, summed over the channels.
    fn error(&self, k: f64) -> f64 {
        let a11 = self.dd + 2.0 * k * self.d + self.n * k * k;
        let (a12, a22) = (self.ds + k * self.s, self.ss);
        let det = a11 * a22 - a12 * a12;
        let mut e = 0.0;
        for c in 0..3 {
            let (b1, b2) = (self.dy[c] + k * self.y[c], self.sy[c]);
            // Unconstrained solution, or where it leaves the non-negative quadrant the
            // better of the one-albedo fits.
            let (x1, x2) = ((a22 * b1 - a12 * b2) / det, (a11 * b2 - a12 * b1) / det);
            let explained = if det > 1e-12 * a11 * a22 && x1 >= 0.0 && x2 >= 0.0 {
                x1 * b1 + x2 * b2
            } else {
                let one = |b: f64, a: f64| if a > 0.0 { b.max(0.0).powi(2) / a } else { 0.0 };
                one(b1, a11).max(one(b2, a22))
            };
            e += (self.yy[c] - explained).max(0.0);
        }
        e
    }
}

/// Sums of one pixel's unclipped observations under `lobe` (its initial cluster's
/// parameters; only the roughness and normal matter); `None` with too few.
fn pixel_sums(
    obs: &Observations,
    px: usize,
    lobe: &Prepared,
    model: &dyn BrdfModel,
    intensity: [f64; 3],
    median_d: &mut Vec<f64>,
) -> Option<Sums> {
    let mut t = Sums::default();
    let n = lobe.frame.n;
    for o in obs.range(px) {
        if obs.clipped(o).iter().any(|&c| c) {
            continue;
        }
        let mut lv = obs.light_view(px, o);
        lv.ambient = 0.0;
        let (ci, cr) = (lv.light.dot(&n), lv.view.dot(&n));
        if ci <= 0.0 || cr <= 0.0 {
            continue;
        }
        let d = ci / (std::f64::consts::PI * lv.light_dist2);
        let s = model.radiance(lobe, &lv, 1.0)[0];
        let y = obs.color(o);
        t.push(d, s, std::array::from_fn(|c| y[c] / intensity[c]));
        median_d.push(d);
    }
    (t.n >= MIN_OBSERVATIONS as f64).then_some(t)
}

/// Estimate the room light from `clusters` (pixels and the lobe fitted to them, one
/// entry per initial cluster) under a light of `intensity`. `None` when no pixel has
/// enough unclipped observations.
pub fn estimate(
    obs: &Observations,
    clusters: &[(Vec<u32>, BrdfParams)],
    model: &dyn BrdfModel,
    intensity: [f64; 3],
) -> Option<RoomLight> {
    let total: usize = clusters.iter().map(|(p, _)| p.len()).sum();
    let step = total.div_ceil(MAX_PIXELS).max(1);
    let work: Vec<(u32, usize)> = clusters
        .iter()
        .enumerate()
        .flat_map(|(k, (px, _))| px.iter().step_by(step).map(move |&p| (p, k)))
        .collect();
    let lobes: Vec<Prepared> = clusters
        .iter()
        .map(|(_, p)| {
            Prepared::new(BrdfParams {
                rho_d: [0.0; 3],
                rho_s: [1.0; 3],
                ..*p
            })
        })
        .collect();
    let (sums, mut ds): (Vec<Sums>, Vec<f64>) = work
        .par_iter()
        .fold(
            || (Vec::new(), Vec::new()),
            |(mut sums, mut ds), &(px, k)| {
                if let Some(t) = pixel_sums(obs, px as usize, &lobes[k], model, intensity, &mut ds)
                {
                    sums.push(t);
                }
                (sums, ds)
            },
        )
        .reduce(
            || (Vec::new(), Vec::new()),
            |(mut a, mut b), (c, d)| {
                a.extend(c);
                b.extend(d);
                (a, b)
            },
        );
    if sums.is_empty() {
        return None;
    }
    let mid = ds.len() / 2;
    let (_, median, _) = ds.select_nth_unstable_by(mid, f64::total_cmp);
    // `d` carries the 1/pi of the diffuse lobe; the room light's `ambient` does not.
    let flash = *median;
    // Summed in order, so that the same capture always gives the same estimate.
    let error = |share: f64| -> f64 { sums.iter().map(|t| t.error(share * flash)).sum() };
    let at_zero = error(0.0);
    let (mut best, mut best_err) = (0.0, at_zero);
    for i in 1..=STEPS {
        let share = MAX_SHARE * i as f64 / STEPS as f64;
        let e = error(share);
        if e < best_err {
            (best, best_err) = (share, e);
        }
    }
    let observations = sums.iter().map(|t| t.n as usize).sum();
    Some(RoomLight {
        ambient: best * flash * std::f64::consts::PI,
        applied: true,
        share_of_flash: best,
        residual_drop: if at_zero > 0.0 {
            1.0 - best_err / at_zero
        } else {
            0.0
        },
        pixels: sums.len(),
        observations,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use svbrdf_core::brdf::{LightView, Ward};
    use svbrdf_core::geometry::Vec3;

    /// Sums of a pixel seen from `n` flash positions at 9-15 cm under room light
    /// `ambient`.
    fn pixel(p: &BrdfParams, ambient: f64, n: usize) -> Sums {
        let prep = Prepared::new(*p);
        let lobe = Prepared::new(BrdfParams {
            rho_d: [0.0; 3],
            rho_s: [1.0; 3],
            ..*p
        });
        let mut t = Sums::default();
        for i in 0..n {
            let a = i as f64 * 0.9;
            let h = 9.0 + 6.0 * (i as f64 / n as f64);
            let cam = Vec3::new(3.0 * a.cos(), 2.0 * a.sin(), h);
            let lv = LightView::from_points(Vec3::zeros(), cam + Vec3::new(1.4, -0.3, 0.0), cam);
            let y = Ward.radiance(&prep, &lv.with_ambient(ambient), 1.0);
            let d = lv.light.z / (std::f64::consts::PI * lv.light_dist2);
            t.push(d, Ward.radiance(&lobe, &lv, 1.0)[0], y);
        }
        t
    }

    #[test]
    fn the_error_is_smallest_at_the_true_room_light() {
        let p = BrdfParams {
            rho_d: [0.5, 0.3, 0.2],
            rho_s: [0.2; 3],
            alpha_x: 0.15,
            alpha_y: 0.15,
            ..BrdfParams::default()
        };
        for ambient in [0.0, 0.001, 0.003] {
            let t = pixel(&p, ambient, 40);
            // `k` is in the units of `d` (with its 1/pi).
            let k = ambient / std::f64::consts::PI;
            let (at, yy) = (t.error(k), t.yy.iter().sum::<f64>());
            assert!(at < 1e-12 * yy, "{ambient}: {at} of {yy}");
            assert!(t.error(k + 0.0003) > 1e-6 * yy, "{ambient}");
            if ambient > 0.0 {
                assert!(t.error(0.0) > 1e-6 * yy, "{ambient}");
            }
        }
    }

    #[test]
    fn constrained_albedos_never_explain_more_than_the_data() {
        // A pixel whose data would want a negative specular albedo: the error stays
        // non-negative and finite.
        let p = BrdfParams {
            rho_d: [0.4; 3],
            rho_s: [0.0; 3],
            alpha_x: 0.3,
            alpha_y: 0.3,
            ..BrdfParams::default()
        };
        let t = pixel(&p, 0.002, 30);
        for k in [0.0, 0.001, 0.01] {
            let e = t.error(k);
            assert!(e.is_finite() && e >= 0.0, "{k}: {e}");
        }
    }
}
