//! Exposure that moves: one gain per frame, estimated from what overlapping frames
//! see of the same plane points.
//!
//! Phones rarely lock exposure with the torch on: the gain follows the metered
//! brightness (the flash's 1/d^2 as the phone moves), and the torch dims as it warms.
//! A plane point seen in several frames is lit by the same flash from known places,
//! so what it shows in frame `f` is modelled as
//!
//! `I = g_f * (a_p * G * S(theta_h) + c_p)`
//!
//! with `G = cos(theta_l) / d^2` the flash's irradiance factor (known from the
//! frame's camera and light positions), `a_p` the point's (unknown) diffuse
//! brightness, `c_p` its (unknown) ambient light, `S` one shared function of the
//! half-vector angle (what the surface's average gloss adds or its roughness takes
//! away from Lambert's law) and `g_f` the frame's gain. Observations near the
//! mirror direction and clipped ones are left out by the caller; the rest are
//! fitted by alternating weighted least squares with Cauchy weights on the relative
//! residual, so texture that the frames see differently and stray highlights count
//! little. Gains are normalised to a geometric mean of 1: the flash's absolute
//! intensity is not known and is fitted later with the albedo.

use serde::{Deserialize, Serialize};

/// One sample: a plane point as one frame saw it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ExposureSample {
    /// Frame number (0-based, index into the caller's frame list).
    pub frame: u32,
    /// Plane point number (0-based).
    pub point: u32,
    /// Linear brightness observed (mean of the linear RGB channels), > 0.
    pub value: f64,
    /// Flash irradiance factor `cos(theta_l) / d^2`, 1/cm^2, > 0.
    pub irradiance: f64,
    /// Half-vector angle from the plane's normal, radians.
    pub half_angle: f64,
}

/// Settings of the gain estimate.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ExposureConfig {
    /// Model ambient light (`c_p`); off: flash only.
    pub ambient: bool,
    /// The ambient light is one room irradiance `A` shared by every point and
    /// reflected by its diffuse brightness (`c_p = a_p * A`, the fit's room-light
    /// model); off: a free `c_p` per point.
    #[serde(default)]
    pub shared_ambient: bool,
    /// Width of the half-angle bins of the shared gloss term `S`, degrees (> 0).
    pub bin_deg: f64,
    /// Alternating rounds (>= 1).
    pub rounds: usize,
    /// Fewest samples a frame needs for its own gain; frames with fewer get the gain
    /// interpolated in time from their neighbours.
    pub min_frame_samples: usize,
}

impl Default for ExposureConfig {
    fn default() -> Self {
        Self {
            ambient: true,
            shared_ambient: true,
            bin_deg: 4.0,
            rounds: 30,
            min_frame_samples: 30,
        }
    }
}

/// The estimate.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct GainEstimate {
    /// Gain per frame (geometric mean 1 over the frames that had their own estimate).
    pub gains: Vec<f64>,
    /// Samples that set each frame's gain (0: interpolated).
    pub frame_samples: Vec<usize>,
    /// Robust spread of the relative residual (1.4826 x MAD): how well one gain per
    /// frame explains what overlapping frames saw; a few percent when it does.
    pub residual_spread: f64,
    /// The same with every gain held at 1 (fixed exposure): much larger than
    /// `residual_spread` when the exposure really drifted, about equal when not.
    pub residual_spread_fixed: f64,
    /// Samples used (points seen in at least two frames).
    pub samples: usize,
    /// The shared room irradiance `A` (with `shared_ambient`), in units of the
    /// flash's irradiance factor `cos(theta_l) / d^2` (1/cm^2): the room light as
    /// bright as the flash at that factor. `None` with a per-point or no ambient term.
    pub ambient_irradiance: Option<f64>,
}

impl GainEstimate {
    /// Largest and smallest gain, in stops relative to the geometric mean.
    pub fn range_ev(&self) -> (f64, f64) {
        let ev: Vec<f64> = self.gains.iter().map(|g| g.log2()).collect();
        (
            ev.iter().copied().fold(f64::INFINITY, f64::min),
            ev.iter().copied().fold(f64::NEG_INFINITY, f64::max),
        )
    }
}

/// Why no gains could be estimated.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ExposureError {
    /// Too few usable samples or frames.
    #[error("exposure gains: {0}")]
    TooFew(String),
}

/// Cauchy weight of a relative residual `r` at scale `s`.
fn weight(r: f64, s: f64) -> f64 {
    1.0 / (1.0 + (r / s).powi(2))
}

/// Estimate one gain per frame (`frames` frames, `points` plane points) from
/// `samples`. Frames without samples of their own get a gain interpolated (in log)
/// over `times` (one per frame, seconds, or frame order when `None`).
pub fn estimate_gains(
    samples: &[ExposureSample],
    frames: usize,
    points: usize,
    times: Option<&[f64]>,
    cfg: &ExposureConfig,
) -> Result<GainEstimate, ExposureError> {
    // Keep valid samples of points seen by at least two frames. Per point: the first
    // frame that saw it, and whether another did too.
    let mut frames_of_point: Vec<(u32, bool)> = vec![(u32::MAX, false); points];
    for s in samples {
        if let Some(e) = frames_of_point.get_mut(s.point as usize) {
            if e.0 == u32::MAX {
                e.0 = s.frame;
            } else if e.0 != s.frame {
                e.1 = true;
            }
        }
    }
    let valid = |s: &&ExposureSample| {
        (s.frame as usize) < frames
            && (s.point as usize) < points
            && s.value.is_finite()
            && s.value > 0.0
            && s.irradiance.is_finite()
            && s.irradiance > 0.0
            && s.half_angle.is_finite()
            && frames_of_point[s.point as usize].1
    };
    let used: Vec<ExposureSample> = samples.iter().filter(valid).copied().collect();
    if used.len() < 100 {
        return Err(ExposureError::TooFew(format!(
            "{} samples of plane points seen by two or more frames (expected at least 100: the frames overlap too little, or the surface is clipped or dark everywhere)",
            used.len()
        )));
    }
    let bin_rad = cfg.bin_deg.max(0.1).to_radians();
    // The gloss term is piecewise linear (in log) between nodes one bin apart.
    let nodes = used
        .iter()
        .map(|s| (s.half_angle / bin_rad).ceil() as usize)
        .max()
        .unwrap_or(0)
        + 2;
    let bin_of = |s: &ExposureSample| {
        let v = (s.half_angle / bin_rad).max(0.0);
        let k = (v.floor() as usize).min(nodes - 2);
        (k, (v - k as f64).clamp(0.0, 1.0))
    };
    let mut count_in_bin = vec![0usize; nodes];
    for s in &used {
        count_in_bin[bin_of(s).0] += 1;
    }
    let ref_bin = count_in_bin
        .iter()
        .enumerate()
        .max_by_key(|(_, n)| **n)
        .map_or(0, |(b, _)| b);
    let mut counts = vec![0usize; frames];
    for s in &used {
        counts[s.frame as usize] += 1;
    }
    // Frames with enough samples for a gain of their own; the others are interpolated.
    let own_frame: Vec<bool> = counts.iter().map(|n| *n >= cfg.min_frame_samples).collect();
    let own: Vec<usize> = (0..frames).filter(|&f| own_frame[f]).collect();
    if own.len() < 2 {
        return Err(ExposureError::TooFew(format!(
            "{} frames with at least {} samples (expected at least 2)",
            own.len(),
            cfg.min_frame_samples
        )));
    }
    let model = Model {
        used: &used,
        bin_of: &bin_of,
        ambient: cfg.ambient,
        shared: cfg.ambient && cfg.shared_ambient,
        frozen_gains: false,
    };
    // Unknowns: log gain per frame, log gloss per bin (the fullest bin fixed at 0),
    // and per point a_p, c_p (eliminated in each step: their blocks are 2x2).
    let mut x = Params {
        u: vec![0.0; frames],
        s: vec![0.0; nodes],
        a: vec![0.0; points],
        c: vec![0.0; points],
        amb: 0.0,
    };
    {
        let (mut num, mut den) = (vec![0.0; points], vec![0.0; points]);
        for s in &used {
            num[s.point as usize] += s.value / s.irradiance;
            den[s.point as usize] += 1.0;
        }
        for p in 0..points {
            x.a[p] = if den[p] > 0.0 { num[p] / den[p] } else { 0.0 };
        }
    }
    // The same model with every gain held at 1: how much the gains explain.
    let fixed_model = Model {
        frozen_gains: true,
        ..model
    };
    let (_, spread_fixed) = solve(&fixed_model, x.clone(), cfg.rounds, ref_bin, &own_frame);
    let (x, scale) = solve(&model, x, cfg.rounds, ref_bin, &own_frame);
    let g: Vec<f64> = x.u.iter().map(|u| u.exp()).collect();
    // Frames with too few samples: interpolate log gain over time.
    let t = |f: usize| times.and_then(|t| t.get(f).copied()).unwrap_or(f as f64);
    let mut gains = g.clone();
    for f in 0..frames {
        if own_frame[f] {
            continue;
        }
        let before = own.iter().rev().find(|&&k| t(k) <= t(f));
        let after = own.iter().find(|&&k| t(k) >= t(f));
        gains[f] = match (before, after) {
            (Some(&b), Some(&e)) if t(e) > t(b) => {
                let u = (t(f) - t(b)) / (t(e) - t(b));
                (g[b].ln() * (1.0 - u) + g[e].ln() * u).exp()
            }
            (Some(&b), _) => g[b],
            (_, Some(&e)) => g[e],
            _ => 1.0,
        };
    }
    // Normalise over the frames with their own estimate.
    let gm = (own.iter().map(|&f| gains[f].ln()).sum::<f64>() / own.len() as f64).exp();
    for v in &mut gains {
        *v /= gm;
    }
    if !gains.iter().all(|v| v.is_finite() && *v > 0.0) {
        return Err(ExposureError::TooFew(
            "the estimate did not converge to positive finite gains".into(),
        ));
    }
    Ok(GainEstimate {
        gains,
        frame_samples: (0..frames)
            .map(|f| if own_frame[f] { counts[f] } else { 0 })
            .collect(),
        residual_spread: scale,
        residual_spread_fixed: spread_fixed,
        samples: used.len(),
        ambient_irradiance: model.shared.then_some(x.amb),
    })
}

/// Robust Levenberg-Marquardt from `x`: the solution and its residual spread.
fn solve(
    model: &Model<'_>,
    mut x: Params,
    rounds: usize,
    ref_bin: usize,
    own_frame: &[bool],
) -> (Params, f64) {
    let mut scale = 0.3f64;
    let mut lambda = 1e-3;
    for _ in 0..rounds.max(1) {
        let w = model.weights(&x, scale);
        let cost = model.cost(&x, &w);
        let mut accepted = false;
        for _ in 0..8 {
            let Some(next) = model.step(&x, &w, lambda, ref_bin, own_frame) else {
                lambda *= 10.0;
                continue;
            };
            if model.cost(&next, &w) <= cost {
                x = next;
                lambda = (lambda * 0.3).max(1e-9);
                accepted = true;
                break;
            }
            lambda *= 10.0;
        }
        scale = model.spread(&x).max(0.005);
        if !accepted {
            break;
        }
    }
    (x, scale)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Samples of a textured plane seen by `frames` frames of a sweep whose gain
    /// follows `gain(f)`, with a room irradiance `ambient` (1/cm^2, reflected by the
    /// albedo), a gloss term and a few highlights.
    fn sweep(frames: usize, gain: impl Fn(usize) -> f64, ambient: f64) -> Vec<ExposureSample> {
        let side = 24;
        let mut out = Vec::new();
        for f in 0..frames {
            let t = f as f64 / frames as f64;
            let cam = [
                6.0 * (6.0 * t).sin(),
                5.0 * (2.0 * t + 0.4).cos(),
                10.0 + 6.0 * (3.0 * t).sin().abs(),
            ];
            for p in 0..side * side {
                let (x, y) = ((p % side) as f64 - 11.5, (p / side) as f64 * 0.9 - 10.0);
                let d = [cam[0] - x, cam[1] - y, cam[2]];
                let d2 = d[0] * d[0] + d[1] * d[1] + d[2] * d[2];
                let cos = d[2] / d2.sqrt();
                if cos < 0.6 {
                    continue;
                }
                let half = cos.acos();
                let albedo = 0.2 + 0.15 * ((p * 7919) % 13) as f64 / 13.0;
                let gloss = 1.0 + 0.5 * (-half / 0.3).exp();
                let mut v = gain(f) * albedo * 200.0 * (cos / d2 * gloss + ambient);
                if (p + f) % 37 == 0 {
                    v *= 3.0; // a stray highlight
                }
                out.push(ExposureSample {
                    frame: f as u32,
                    point: p as u32,
                    value: v,
                    irradiance: cos / d2,
                    half_angle: half,
                });
            }
        }
        out
    }

    fn check(
        frames: usize,
        gain: impl Fn(usize) -> f64 + Copy,
        ambient: f64,
        tol: f64,
    ) -> GainEstimate {
        check_with(frames, gain, ambient, tol, &ExposureConfig::default())
    }

    fn check_with(
        frames: usize,
        gain: impl Fn(usize) -> f64 + Copy,
        ambient: f64,
        tol: f64,
        cfg: &ExposureConfig,
    ) -> GainEstimate {
        let s = sweep(frames, gain, ambient);
        let e = estimate_gains(&s, frames, 24 * 24, None, cfg).unwrap();
        let gm = ((0..frames).map(|f| gain(f).ln()).sum::<f64>() / frames as f64).exp();
        // Holding the gains at 1 explains a drift much worse, a steady exposure as well.
        let drifts = (0..frames).any(|f| (gain(f) / gm).log2().abs() > 0.2);
        let ratio = e.residual_spread_fixed / e.residual_spread;
        assert_eq!(ratio > 1.3, drifts, "spread ratio {ratio}");
        for f in 0..frames {
            let want = gain(f) / gm;
            assert!(
                (e.gains[f] / want - 1.0).abs() < tol,
                "frame {f}: {} against {want} ({e:?})",
                e.gains[f]
            );
        }
        e
    }

    #[test]
    fn drifting_gains_are_recovered_despite_texture_gloss_and_highlights() {
        check(40, |f| (0.05 * f as f64).sin().exp2() * 1.3, 0.0, 0.01);
    }

    #[test]
    fn room_light_does_not_bias_the_gains_and_is_found() {
        // About 15% of the flash's light at the sweep's distances.
        let e = check(40, |f| ((f as f64) / 13.0).cos().exp2(), 0.001, 0.01);
        let a = e.ambient_irradiance.unwrap();
        assert!((a / 0.001 - 1.0).abs() < 0.1, "room irradiance {a}");
        // A free ambient term per point also keeps the gains.
        let per_point = ExposureConfig {
            shared_ambient: false,
            ..ExposureConfig::default()
        };
        let e = check_with(
            40,
            |f| ((f as f64) / 13.0).cos().exp2(),
            0.001,
            0.01,
            &per_point,
        );
        assert_eq!(e.ambient_irradiance, None);
    }

    #[test]
    fn fixed_exposure_comes_out_flat() {
        let e = check(30, |_| 1.0, 0.0004, 0.01);
        let a = e.ambient_irradiance.unwrap();
        assert!((a / 0.0004 - 1.0).abs() < 0.1, "room irradiance {a}");
    }

    #[test]
    fn a_frame_without_samples_is_interpolated_and_too_little_overlap_is_refused() {
        let gain = |f: usize| 1.0 + 0.02 * f as f64;
        let mut s = sweep(20, gain, 0.0);
        s.retain(|x| x.frame != 7);
        let e = estimate_gains(&s, 20, 24 * 24, None, &ExposureConfig::default()).unwrap();
        assert_eq!(e.frame_samples[7], 0);
        let ratio = e.gains[7] / ((e.gains[6] * e.gains[8]).sqrt());
        assert!((ratio - 1.0).abs() < 0.01, "{e:?}");
        let one: Vec<ExposureSample> = s.iter().filter(|x| x.frame == 0).copied().collect();
        let err = estimate_gains(&one, 20, 24 * 24, None, &ExposureConfig::default()).unwrap_err();
        assert!(err.to_string().contains("expected at least 100"), "{err}");
    }
}

/// The unknowns of the gain model.
#[derive(Debug, Clone)]
struct Params {
    /// Log gain per frame.
    u: Vec<f64>,
    /// Log gloss term per half-angle bin.
    s: Vec<f64>,
    /// Diffuse brightness per point.
    a: Vec<f64>,
    /// Ambient light per point (>= 0), when not shared.
    c: Vec<f64>,
    /// Shared room irradiance (>= 0), in units of the irradiance factor.
    amb: f64,
}

/// The samples and how they are binned.
struct Model<'a> {
    used: &'a [ExposureSample],
    bin_of: &'a dyn Fn(&ExposureSample) -> (usize, f64),
    ambient: bool,
    /// One room irradiance for every point (`c_p = a_p * amb`).
    shared: bool,
    /// Hold every gain at 1 (the fixed-exposure model, for comparison).
    frozen_gains: bool,
}

impl Model<'_> {
    /// Whether each point has a free ambient term `c_p` (not shared, not off).
    fn per_point(&self) -> bool {
        self.ambient && !self.shared
    }

    /// Relative residual of sample `s`, the prediction's parts (g, G S) and its value.
    fn residual(&self, x: &Params, s: &ExposureSample) -> (f64, f64, f64, f64) {
        let p = s.point as usize;
        let g = x.u[s.frame as usize].exp();
        let (k, t) = (self.bin_of)(s);
        let gs = s.irradiance * (x.s[k] * (1.0 - t) + x.s[k + 1] * t).exp();
        let c = if self.shared { x.a[p] * x.amb } else { x.c[p] };
        let m = g * (x.a[p] * gs + c);
        ((s.value - m) / s.value, g, gs, m)
    }

    fn weights(&self, x: &Params, scale: f64) -> Vec<f64> {
        self.used
            .iter()
            .map(|s| weight(self.residual(x, s).0, scale))
            .collect()
    }

    fn cost(&self, x: &Params, w: &[f64]) -> f64 {
        self.used
            .iter()
            .zip(w)
            .map(|(s, wi)| wi * self.residual(x, s).0.powi(2))
            .sum()
    }

    /// Robust spread (1.4826 x MAD) of the relative residuals.
    fn spread(&self, x: &Params) -> f64 {
        let mut abs: Vec<f64> = self
            .used
            .iter()
            .map(|s| self.residual(x, s).0.abs())
            .collect();
        let mid = abs.len() / 2;
        abs.select_nth_unstable_by(mid, f64::total_cmp);
        1.4826 * abs[mid]
    }

    /// One damped Gauss-Newton step with the point unknowns eliminated (Schur
    /// complement), or `None` when the reduced system is singular. Gauges: the gloss
    /// of `ref_bin` stays 0 and the mean log gain over `own` frames is held at 0.
    fn step(
        &self,
        x: &Params,
        w: &[f64],
        lambda: f64,
        ref_bin: usize,
        own: &[bool],
    ) -> Option<Params> {
        let (nf, nb, np) = (x.u.len(), x.s.len(), x.a.len());
        let n = nf + nb + usize::from(self.shared);
        let mut h = nalgebra::DMatrix::<f64>::zeros(n, n);
        let mut rhs = nalgebra::DVector::<f64>::zeros(n);
        // Per point: 2x2 block, its gradient and its coupling to the globals (sparse).
        let mut hpp = vec![[0.0f64; 3]; np];
        let mut gp = vec![[0.0f64; 2]; np];
        let mut coupling: Vec<Vec<(usize, [f64; 2])>> = vec![Vec::new(); np];
        for (s, wi) in self.used.iter().zip(w) {
            let (r, g, gs, m) = self.residual(x, s);
            let p = s.point as usize;
            let iv = 1.0 / s.value;
            // r = (I - m) / I: derivatives of r.
            let jf = -m * iv;
            let jb = -g * x.a[p] * gs * iv;
            let (k, t) = (self.bin_of)(s);
            let mut js = [
                (s.frame as usize, jf),
                (nf + k, jb * (1.0 - t)),
                (nf + k + 1, jb * t),
                (0, 0.0),
            ];
            let (ja, jc) = if self.shared {
                js[3] = (nf + nb, -g * x.a[p] * iv);
                (-g * (gs + x.amb) * iv, 0.0)
            } else if self.per_point() {
                (-g * gs * iv, -g * iv)
            } else {
                (-g * gs * iv, 0.0)
            };
            let js = &js[..if self.shared { 4 } else { 3 }];
            for &(i, ji) in js {
                rhs[i] += wi * ji * r;
                for &(l, jl) in js {
                    h[(i, l)] += wi * ji * jl;
                }
            }
            let hb = &mut hpp[p];
            hb[0] += wi * ja * ja;
            hb[1] += wi * ja * jc;
            hb[2] += wi * jc * jc;
            gp[p][0] += wi * ja * r;
            gp[p][1] += wi * jc * r;
            let cp = &mut coupling[p];
            for &(k, j) in js {
                let add = [wi * ja * j, wi * jc * j];
                match cp.iter_mut().find(|e| e.0 == k) {
                    Some(e) => {
                        e.1[0] += add[0];
                        e.1[1] += add[1];
                    }
                    None => cp.push((k, add)),
                }
            }
        }
        // Damping of the point blocks, and their inverses.
        let inv: Vec<Option<[f64; 3]>> = hpp
            .iter()
            .map(|b| {
                let d0 = b[0] * (1.0 + lambda) + 1e-12;
                let d2 = if self.per_point() {
                    b[2] * (1.0 + lambda) + 1e-12
                } else {
                    1.0
                };
                let det = d0 * d2 - b[1] * b[1];
                (b[0] > 0.0 && det > 0.0).then(|| [d2 / det, -b[1] / det, d0 / det])
            })
            .collect();
        for p in 0..np {
            let Some(iv) = inv[p] else { continue };
            let cp = &coupling[p];
            // H_Fp Hpp^-1 H_pF and H_Fp Hpp^-1 g_p.
            let t: Vec<(usize, [f64; 2])> = cp
                .iter()
                .map(|(k, v)| {
                    (
                        *k,
                        [iv[0] * v[0] + iv[1] * v[1], iv[1] * v[0] + iv[2] * v[1]],
                    )
                })
                .collect();
            for (k, tk) in &t {
                rhs[*k] -= tk[0] * gp[p][0] + tk[1] * gp[p][1];
                for (l, vl) in cp {
                    h[(*k, *l)] -= tk[0] * vl[0] + tk[1] * vl[1];
                }
            }
        }
        for k in 0..n {
            h[(k, k)] *= 1.0 + lambda;
            h[(k, k)] += 1e-12;
        }
        // Gauges: the reference bin is fixed (its row and column replaced by the
        // identity); the mean log gain over the frames with their own samples is 0.
        let fixed: Vec<usize> = if self.frozen_gains {
            (0..nf).chain([nf + ref_bin]).collect()
        } else {
            vec![nf + ref_bin]
        };
        for &rb in &fixed {
            for k in 0..n {
                h[(rb, k)] = 0.0;
                h[(k, rb)] = 0.0;
            }
            h[(rb, rb)] = 1.0;
            rhs[rb] = 0.0;
        }
        let own: Vec<bool> = own.iter().map(|o| *o && !self.frozen_gains).collect();
        let nown = own.iter().filter(|o| **o).count().max(1) as f64;
        let strength = h.diagonal().iter().take(nf).sum::<f64>() / nf.max(1) as f64;
        let mean_u: f64 = (0..nf).filter(|&f| own[f]).map(|f| x.u[f]).sum::<f64>() / nown;
        for f in (0..nf).filter(|&f| own[f]) {
            rhs[f] += strength * mean_u / nown;
            for l in (0..nf).filter(|&l| own[l]) {
                h[(f, l)] += strength / (nown * nown);
            }
        }
        let delta = h.cholesky()?.solve(&(-rhs));
        let mut next = x.clone();
        for f in 0..nf {
            next.u[f] += delta[f];
        }
        for b in 0..nb {
            next.s[b] += delta[nf + b];
        }
        if self.shared {
            next.amb = (x.amb + delta[nf + nb]).max(0.0);
        }
        for p in 0..np {
            let Some(iv) = inv[p] else { continue };
            let mut v = [gp[p][0], gp[p][1]];
            for (k, c) in &coupling[p] {
                v[0] += c[0] * delta[*k];
                v[1] += c[1] * delta[*k];
            }
            let da = -(iv[0] * v[0] + iv[1] * v[1]);
            let dc = -(iv[1] * v[0] + iv[2] * v[1]);
            next.a[p] = (x.a[p] + da).max(0.0);
            next.c[p] = if self.per_point() {
                (x.c[p] + dc).max(0.0)
            } else {
                0.0
            };
        }
        if next.u.iter().chain(&next.s).all(|v| v.is_finite()) && next.amb.is_finite() {
            Some(next)
        } else {
            None
        }
    }
}
