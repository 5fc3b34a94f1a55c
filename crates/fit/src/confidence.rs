//! What each pixel's observations can tell about its parameters: a confidence per
//! parameter group (diffuse albedo, specular lobe, normal), each in [0, 1].
//!
//! - **Diffuse**: the number of frames that saw the pixel; full at
//!   [`DIFFUSE_FULL_VIEWS`] (the diffuse albedo is a mean over views, so its noise falls
//!   with their number).
//! - **Specular**: whether the highlight's peak was seen. For each observation the
//!   half-vector's offset from the fitted normal is measured in lobe widths (`e`, the
//!   Ward exponent `tan^2 theta_h (cos^2 phi / alpha_x^2 + sin^2 phi / alpha_y^2)`:
//!   `e < 1` is within one lobe width of the mirror direction, where the lobe is above
//!   37% of its peak). [`SPECULAR_PEAK`] (1) where at least [`PEAK_VIEWS`] unclipped
//!   observations lie within one width; [`SPECULAR_FLANK`] (0.5) where the peak was
//!   seen only clipped (the lobe's height is then a lower bound) or at least
//!   [`PEAK_VIEWS`] observations lie within two widths (its flank: the height is an
//!   extrapolation); 0 where neither: the highlight was never seen, and the pixel's
//!   lobe is its cluster's, fitted on other pixels.
//! - **Normal**: the spread of the directions the light came from. A normal is read
//!   from how shading changes with the light direction, so it needs light from
//!   different sides: the smaller standard deviation of the unit light vector's plane
//!   components (the covariance's smaller eigenvalue), full at
//!   [`NORMAL_FULL_SPREAD`]; 0 below [`MIN_VIEWS`] frames.
//!
//! The refinement moves the diffuse albedo and the normal per pixel; the specular lobe
//! is its cluster's, except (with `refine_specular`) where the pixel's observations
//! measure it ([`lobe_measured`]: the peak seen unclipped, or the flank's fall-off), so
//! a pixel whose highlight was never seen always carries its cluster's lobe; the
//! confidence says so.

use rayon::prelude::*;
use svbrdf_core::brdf::{BrdfParams, Prepared};

use crate::observations::Observations;

pub use svbrdf_core::confidence::{ConfidenceSummary, SpecularSeen, DIFFUSE_FULL_VIEWS};
/// Frames a pixel needs for any normal or specular confidence.
pub const MIN_VIEWS: usize = 3;
/// Observations within one (unclipped) or two lobe widths a pixel needs.
pub const PEAK_VIEWS: usize = 2;
/// Ward exponent of the flank: observations within two lobe widths (the lobe above
/// `exp(-4)` = 2% of its peak).
pub const FLANK_REACH: f64 = 4.0;
/// Ward exponent within which unclipped observations measure a lobe's fall-off (three
/// lobe widths: the lobe at `exp(-9)` = 0.01% of its peak).
pub const LOBE_REACH: f64 = 9.0;
/// Unclipped observations within [`LOBE_REACH`] a pixel needs for a lobe of its own.
pub const LOBE_VIEWS: usize = 4;
/// Frames a pixel needs before its flank alone may give it a lobe of its own: the lobe
/// has ten free parameters with the diffuse albedo and the normal, and the flank pins
/// them only with many views. Measured: 38 views per pixel (the 4K `paper` video)
/// gained (light 1 at 1 mm 104% -> 83% on seed 1, 62% -> 47% on seed 2); 6-9
/// (`hard-small`, `tiny`) changed nothing beyond a point or two; seven photos of a
/// simulated patchwork set predicted the held-out photos worse (FLIP 0.058 -> 0.072).
pub const FLANK_MIN_VIEWS: usize = 16;
/// Specular confidence where the peak was seen unclipped.
pub const SPECULAR_PEAK: f32 = 1.0;
/// Specular confidence where only the flank or a clipped peak was seen.
pub const SPECULAR_FLANK: f32 = 0.5;
/// Standard deviation of the light direction's plane components (in the direction
/// where it is smallest) at which the normal confidence is full (0.15: about 9 degrees).
pub const NORMAL_FULL_SPREAD: f64 = 0.15;

/// Per-pixel confidences (`[diffuse, specular, normal]`, row-major like the maps) and
/// their summary. `params` are the final per-pixel parameters.
pub fn confidence(obs: &Observations, params: &[BrdfParams]) -> (Vec<[f32; 3]>, ConfidenceSummary) {
    let per_pixel: Vec<[f32; 3]> = (0..obs.pixels())
        .into_par_iter()
        .map(|p| pixel_confidence(obs, p, &params[p]))
        .collect();
    let observed: Vec<&[f32; 3]> = per_pixel
        .iter()
        .enumerate()
        .filter(|(p, _)| obs.count(*p) > 0)
        .map(|(_, c)| c)
        .collect();
    let n = observed.len().max(1) as f64;
    let share = |f: &dyn Fn(&[f32; 3]) -> bool| observed.iter().filter(|c| f(c)).count() as f64 / n;
    let summary = ConfidenceSummary {
        observed_pixels: observed.len(),
        diffuse_low: share(&|c| c[0] < 0.5),
        specular_peak: share(&|c| SpecularSeen::of(c[1]) == SpecularSeen::Peak),
        specular_flank: share(&|c| SpecularSeen::of(c[1]) == SpecularSeen::Flank),
        specular_unseen: share(&|c| SpecularSeen::of(c[1]) == SpecularSeen::Never),
        normal_low: share(&|c| c[2] < 0.5),
    };
    (per_pixel, summary)
}

/// Per cluster (ids as in `cluster`, `clusters` of them): the shares of its observed
/// pixels whose highlight was seen at the peak, only on its flank, or never
/// ([`SpecularSeen`] order); `None` for a cluster without observed pixels.
pub fn cluster_specular(
    obs: &Observations,
    confidence: &[[f32; 3]],
    cluster: &[u32],
    clusters: usize,
) -> Vec<Option<[f64; 3]>> {
    let mut counts = vec![[0usize; 3]; clusters];
    for (p, &c) in cluster.iter().enumerate() {
        if obs.count(p) == 0 {
            continue;
        }
        if let Some(row) = counts.get_mut(c as usize) {
            row[SpecularSeen::of(confidence[p][1]) as usize] += 1;
        }
    }
    counts
        .iter()
        .map(|c| {
            let n = c.iter().sum::<usize>();
            (n > 0).then(|| c.map(|v| v as f64 / n as f64))
        })
        .collect()
}

/// Whether at least [`PEAK_VIEWS`] unclipped observations of pixel `p` lie within one
/// lobe width of `params`' mirror direction (specular confidence [`SPECULAR_PEAK`]).
pub fn peak_seen(obs: &Observations, p: usize, params: &BrdfParams) -> bool {
    pixel_confidence(obs, p, params)[1] >= SPECULAR_PEAK
}

/// Whether pixel `p`'s own observations measure its lobe under `params`, so that the
/// per-pixel specular step may fit one: the peak seen unclipped ([`peak_seen`]), or, in
/// at least [`FLANK_MIN_VIEWS`] frames, its flank (at least [`PEAK_VIEWS`] unclipped
/// observations within two lobe widths, and at least [`LOBE_VIEWS`] within
/// [`LOBE_REACH`]), whose fall-off gives the lobe's width and height where the peak
/// itself clipped (the 8-bit video clips about half of the observations near a polished
/// metal's mirror direction; they count in the fit as lower bounds, but not here). A
/// pixel with either has specular confidence of at least [`SPECULAR_FLANK`].
pub fn lobe_measured(obs: &Observations, p: usize, params: &BrdfParams) -> bool {
    let n = obs.count(p);
    if n < MIN_VIEWS {
        return false;
    }
    let by_flank = n >= FLANK_MIN_VIEWS;
    let lobe = Lobe::new(params);
    let (mut peak, mut flank, mut reach) = (0usize, 0usize, 0usize);
    for o in obs.range(p) {
        if obs.clipped(o).iter().any(|&c| c) {
            continue;
        }
        let Some(e) = lobe.exponent(&obs.light_view(p, o)) else {
            continue;
        };
        peak += usize::from(e < 1.0);
        flank += usize::from(e < FLANK_REACH);
        reach += usize::from(e < LOBE_REACH);
        if peak >= PEAK_VIEWS || (by_flank && flank >= PEAK_VIEWS && reach >= LOBE_VIEWS) {
            return true;
        }
    }
    false
}

/// A pixel's lobe, for measuring observations' half-vectors in lobe widths.
struct Lobe {
    frame: svbrdf_core::brdf::ShadingFrame,
    ax: f64,
    ay: f64,
}

impl Lobe {
    fn new(params: &BrdfParams) -> Self {
        Self {
            frame: Prepared::new(*params).frame,
            ax: params.alpha_x.max(1e-4),
            ay: params.alpha_y.max(1e-4),
        }
    }

    /// The Ward exponent `tan^2 theta_h (cos^2 phi / alpha_x^2 + sin^2 phi / alpha_y^2)`
    /// of one observation (1: one lobe width from the mirror direction); `None` where the
    /// half-vector lies below the surface.
    fn exponent(&self, lv: &svbrdf_core::brdf::LightView) -> Option<f64> {
        let h = lv.light + lv.view;
        let (hn, ht, hb) = (
            h.dot(&self.frame.n),
            h.dot(&self.frame.t),
            h.dot(&self.frame.b),
        );
        (hn > 1e-9).then(|| (ht / hn / self.ax).powi(2) + (hb / hn / self.ay).powi(2))
    }
}

/// The share of `pixels` (at most `max` of them, spread evenly) whose highlight under
/// `params` was seen at its peak or on its flank (specular confidence above 0): how
/// much of a lobe the observations constrain at all.
pub fn lobe_seen_share(obs: &Observations, pixels: &[u32], params: &BrdfParams, max: usize) -> f64 {
    let step = pixels.len().div_ceil(max.max(1)).max(1);
    let (mut seen, mut n) = (0usize, 0usize);
    for &p in pixels.iter().step_by(step) {
        n += 1;
        if pixel_confidence(obs, p as usize, params)[1] > 0.0 {
            seen += 1;
        }
    }
    seen as f64 / n.max(1) as f64
}

/// Normal confidence of one pixel: the smaller standard deviation of the plane
/// components of the unit vectors towards the light, over its observations, against
/// [`NORMAL_FULL_SPREAD`]; 0 below [`MIN_VIEWS`] frames.
pub(crate) fn normal_confidence(obs: &Observations, p: usize) -> f32 {
    let range = obs.range(p);
    if range.len() < MIN_VIEWS {
        return 0.0;
    }
    let mut spread = LightSpread::default();
    for o in range {
        spread.add(&obs.light_view(p, o));
    }
    spread.confidence()
}

/// Running sums of the light direction's plane components, for the normal confidence.
#[derive(Default)]
struct LightSpread {
    n: usize,
    sx: f64,
    sy: f64,
    sxx: f64,
    syy: f64,
    sxy: f64,
}

impl LightSpread {
    fn add(&mut self, lv: &svbrdf_core::brdf::LightView) {
        let (x, y) = (lv.light.x, lv.light.y);
        self.n += 1;
        self.sx += x;
        self.sy += y;
        self.sxx += x * x;
        self.syy += y * y;
        self.sxy += x * y;
    }

    /// The smaller standard deviation over [`NORMAL_FULL_SPREAD`], at most 1.
    fn confidence(&self) -> f32 {
        let m = self.n.max(1) as f64;
        let (cxx, cyy, cxy) = (
            self.sxx / m - (self.sx / m).powi(2),
            self.syy / m - (self.sy / m).powi(2),
            self.sxy / m - (self.sx / m) * (self.sy / m),
        );
        // Smaller eigenvalue of the 2x2 covariance.
        let half_trace = 0.5 * (cxx + cyy);
        let lambda_min = half_trace - (0.25 * (cxx - cyy).powi(2) + cxy * cxy).sqrt();
        (lambda_min.max(0.0).sqrt() / NORMAL_FULL_SPREAD).min(1.0) as f32
    }
}

/// Confidences of one pixel.
fn pixel_confidence(obs: &Observations, p: usize, params: &BrdfParams) -> [f32; 3] {
    let range = obs.range(p);
    let n = range.len();
    if n == 0 {
        return [0.0; 3];
    }
    let diffuse = (n as f64 / DIFFUSE_FULL_VIEWS as f64).min(1.0) as f32;
    if n < MIN_VIEWS {
        return [diffuse, 0.0, 0.0];
    }
    let lobe = Lobe::new(params);
    let (mut peak, mut peak_clipped, mut flank) = (0usize, 0usize, 0usize);
    let mut spread = LightSpread::default();
    for o in range {
        let lv = obs.light_view(p, o);
        spread.add(&lv);
        let Some(e) = lobe.exponent(&lv) else {
            continue;
        };
        if e < 1.0 {
            if obs.clipped(o).iter().any(|&c| c) {
                peak_clipped += 1;
            } else {
                peak += 1;
            }
        }
        if e < FLANK_REACH {
            flank += 1;
        }
    }
    let specular = if peak >= PEAK_VIEWS {
        SPECULAR_PEAK
    } else if peak + peak_clipped > 0 || flank >= PEAK_VIEWS {
        SPECULAR_FLANK
    } else {
        0.0
    };
    [diffuse, specular, spread.confidence()]
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::observations::{rendered, FrameGeometry};
    use svbrdf_core::geometry::Vec3;
    use svbrdf_core::plane::{PlaneGrid, Region};

    /// A glossy material on a 16 x 4 cm strip; the flash camera sweeps over the left
    /// half only (x from -7 to -1 cm), at 8-12 cm.
    fn left_sweep() -> Observations {
        let grid = PlaneGrid::new(Region::centred(16.0, 4.0), 2.0).unwrap();
        let mut frames = Vec::new();
        for i in 0..40u32 {
            let x = -7.0 + 6.0 * f64::from(i % 10) / 9.0;
            let y = -1.5 + f64::from(i / 10);
            let camera = Vec3::new(x, y, 8.0 + f64::from(i % 3) * 2.0);
            frames.push(FrameGeometry {
                id: i,
                camera,
                light: camera + Vec3::new(1.4, -0.3, 0.0),
                gain: 1.0,
            });
        }
        rendered(
            grid,
            frames,
            |_| BrdfParams {
                rho_d: [0.2; 3],
                rho_s: [0.03; 3],
                alpha_x: 0.08,
                alpha_y: 0.08,
                ..BrdfParams::default()
            },
            100.0,
            false,
        )
    }

    #[test]
    fn a_region_whose_mirror_direction_was_never_visited_has_no_specular_confidence() {
        let obs = left_sweep();
        let params = vec![
            BrdfParams {
                alpha_x: 0.08,
                alpha_y: 0.08,
                ..BrdfParams::default()
            };
            obs.pixels()
        ];
        let (conf, summary) = confidence(&obs, &params);
        let w = obs.grid.width;
        let at = |x_cm: f64| {
            let col = ((x_cm + 8.0) * 2.0) as usize;
            conf[(obs.grid.height / 2) * w + col]
        };
        // Under the sweep: the highlight's peak was seen; every frame saw the pixel.
        let under = at(-4.0);
        assert_eq!(under[1], SPECULAR_PEAK, "{under:?}");
        assert_eq!(under[0], 1.0);
        // Far right (7 cm from the nearest camera position): seen, never near the
        // mirror direction.
        let far = at(7.5);
        assert!(far[0] > 0.0, "{far:?}");
        assert_eq!(far[1], 0.0, "{far:?}");
        assert!(summary.specular_unseen > 0.2, "{summary:?}");
        assert!(summary.specular_peak > 0.2, "{summary:?}");
        assert!(
            summary.sentence().contains("never seen"),
            "{}",
            summary.sentence()
        );
    }

    #[test]
    fn a_lobe_is_seen_under_the_sweep_and_not_beyond_it() {
        let obs = left_sweep();
        let lobe = BrdfParams {
            alpha_x: 0.08,
            alpha_y: 0.08,
            ..BrdfParams::default()
        };
        let w = obs.grid.width as u32;
        let columns = |from_cm: f64, to_cm: f64| -> Vec<u32> {
            let (a, b) = (((from_cm + 8.0) * 2.0) as u32, ((to_cm + 8.0) * 2.0) as u32);
            (0..obs.pixels() as u32)
                .filter(|p| (a..b).contains(&(p % w)))
                .collect()
        };
        let under = columns(-6.0, -2.0);
        let beyond = columns(6.0, 8.0);
        assert_eq!(lobe_seen_share(&obs, &under, &lobe, 1000), 1.0);
        assert_eq!(lobe_seen_share(&obs, &beyond, &lobe, 1000), 0.0);
        // A sample of the pixels gives the same answer; no pixels, no share.
        assert_eq!(lobe_seen_share(&obs, &under, &lobe, 3), 1.0);
        assert_eq!(lobe_seen_share(&obs, &[], &lobe, 10), 0.0);
    }

    #[test]
    fn a_normal_lit_from_one_side_only_has_low_confidence() {
        let obs = left_sweep();
        let params = vec![BrdfParams::default(); obs.pixels()];
        let (conf, _) = confidence(&obs, &params);
        let w = obs.grid.width;
        let row = obs.grid.height / 2;
        let under = conf[row * w + 8];
        let far = conf[row * w + w - 1];
        // Under the sweep the light comes from all sides; at the far end it always
        // comes from the left, in a narrow cone.
        assert!(under[2] > 0.5, "{under:?}");
        assert!(far[2] < under[2], "{far:?} vs {under:?}");
    }

    #[test]
    fn unobserved_pixels_have_no_confidence() {
        let mut obs = left_sweep();
        // Drop every observation of pixel 0.
        let n0 = obs.count(0);
        obs.frame.drain(0..n0);
        obs.rgb.drain(0..n0);
        obs.key.drain(0..n0);
        for s in obs.start.iter_mut().skip(1) {
            *s -= n0;
        }
        let params = vec![BrdfParams::default(); obs.pixels()];
        let (conf, summary) = confidence(&obs, &params);
        assert_eq!(conf[0], [0.0; 3]);
        assert_eq!(summary.observed_pixels, obs.pixels() - 1);
    }
}
