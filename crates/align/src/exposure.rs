//! The exposure gain of every flash frame, from what overlapping frames' thumbnails
//! show of the same plane points once registration is done (see
//! `svbrdf_core::exposure` for the model). The result goes into each frame's
//! `exposure_gain` in the registered capture and, as a curve, into `align.json`.

use serde::{Deserialize, Serialize};
use svbrdf_core::capture::{Frame, PreparedMapping};
use svbrdf_core::color::srgb8_to_linear_table;
use svbrdf_core::exposure::{estimate_gains, ExposureConfig, ExposureSample, GainEstimate};
use svbrdf_core::geometry::{Vec2, Vec3};
use svbrdf_core::image::ImageU8;
use svbrdf_core::plane::Region;

use crate::AlignError;

/// Plane points per side of the sampling grid.
pub const GRID_SIDE: usize = 48;
/// Samples within this half-vector angle of the normal (the flash highlight) are left
/// out, degrees. Measured on 18 simulated captures (tiny and hard-small, three
/// materials, two seeds, with and without auto-exposure): 12 degrees let glossy
/// patches' highlights bias one capture by 0.25 EV rms, 30 left too few angles on the
/// 7-10 cm tiny sweeps (0.1-0.38 EV); 20 kept every capture within 0.043 EV rms.
pub const MIRROR_EXCLUSION_DEG: f64 = 20.0;
/// A thumbnail tap at or above this 8-bit code counts as clipped.
pub const CLIPPED_CODE: u8 = 250;
/// Samples darker than this linear level are left out (8-bit quantisation).
pub const DARKEST: f64 = 0.01;
/// Above this robust residual spread the gains are doubtful (warned).
pub const DOUBTFUL_SPREAD: f64 = 0.15;
/// Gains are applied only where holding them at 1 leaves this many times the
/// residual spread. Measured on 24 simulated captures: 0.85-1.15 without drift (the
/// estimate then only fits noise, +-0.04-0.08 EV, which cost one capture 22% of
/// diffuse accuracy), 3.0-9.1 with +-1 EV of auto-exposure.
pub const SIGNIFICANT_SPREAD_RATIO: f64 = 1.3;

/// How the frames' exposure was handled.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ExposureMode {
    /// One gain per frame estimated and written into the registered capture.
    Estimated,
    /// Estimated, but the gains explain no more than fixed exposure does: frames
    /// taken as equally exposed (nothing written into the registered capture).
    Steady,
    /// Assumed fixed (`--fixed-exposure`): every gain 1.
    Fixed,
    /// The estimate failed (too little overlap); frames taken as equally exposed.
    Failed,
}

/// One frame's gain.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FrameGain {
    /// Frame id in the registered capture.
    pub id: u32,
    /// Frame number in the video (for video sources).
    pub frame_index: Option<u64>,
    /// Time, seconds.
    pub time_s: Option<f64>,
    /// Relative gain (geometric mean 1 over the flash frames).
    pub gain: f64,
    /// Samples that set it (0: interpolated from its neighbours in time).
    pub samples: usize,
}

/// The gain curve as `align.json` records it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ExposureCurve {
    /// What was done.
    pub mode: ExposureMode,
    /// Lowest and highest gain, EV (stops) from the geometric mean.
    pub range_ev: Option<[f64; 2]>,
    /// Robust spread of the model's relative residual (a few percent when one gain
    /// per frame explains what the frames saw).
    pub residual_spread: Option<f64>,
    /// The same with every gain held at 1 (fixed exposure).
    #[serde(default)]
    pub residual_spread_fixed: Option<f64>,
    /// Samples used.
    pub samples: usize,
    /// The room light the gain model found: one irradiance reflected by every
    /// point's diffuse brightness, in units of the flash's `cos(theta_l) / d^2`
    /// (1/cm^2; e.g. 0.001 is as bright as the flash at 1/sqrt(0.001) = 32 cm).
    #[serde(default)]
    pub ambient_irradiance: Option<f64>,
    /// Per flash frame.
    pub frames: Vec<FrameGain>,
    /// Why it failed, or what is doubtful.
    pub note: Option<String>,
}

impl ExposureCurve {
    /// One line for people.
    pub fn describe(&self) -> String {
        match (self.mode, self.range_ev) {
            (ExposureMode::Estimated, Some([lo, hi])) => format!(
                "exposure: one gain per frame estimated from overlapping frames, {lo:+.2} to {hi:+.2} EV (residual spread {:.1}%)",
                100.0 * self.residual_spread.unwrap_or(0.0)
            ),
            (ExposureMode::Steady, _) => format!(
                "exposure: steady (one gain per frame explains no more than fixed exposure: residual spread {:.1}% against {:.1}%); frames taken as equally exposed",
                100.0 * self.residual_spread.unwrap_or(0.0),
                100.0 * self.residual_spread_fixed.unwrap_or(0.0)
            ),
            (ExposureMode::Fixed, _) => {
                "exposure: assumed fixed (--fixed-exposure): every frame at gain 1".into()
            }
            _ => format!(
                "exposure: not estimated ({}); frames taken as equally exposed",
                self.note.as_deref().unwrap_or("no reason recorded")
            ),
        }
    }
}

/// A frame as the estimate needs it.
pub struct GainInput<'a> {
    /// Its registered-capture record (mapping, camera and light positions).
    pub frame: &'a Frame,
    /// Its thumbnail (sRGB-coded, the frame's full extent).
    pub thumb: &'a ImageU8,
}

/// Bilinear linear-light sample of a thumbnail at full-resolution pixel `p`: mean of
/// the linear channels, or `None` outside, clipped or dark.
fn sample(thumb: &ImageU8, full_width: u32, p: Vec2, lut: &[f32; 256]) -> Option<f64> {
    let s = thumb.width as f64 / f64::from(full_width);
    let (x, y) = ((p.x + 0.5) * s - 0.5, (p.y + 0.5) * s - 0.5);
    if !(x >= 0.0 && y >= 0.0) {
        return None;
    }
    let (x0, y0) = (x.floor() as usize, y.floor() as usize);
    if x0 + 1 >= thumb.width || y0 + 1 >= thumb.height {
        return None;
    }
    let (fx, fy) = (x - x0 as f64, y - y0 as f64);
    let mut v = 0.0;
    for (dx, dy, w) in [
        (0, 0, (1.0 - fx) * (1.0 - fy)),
        (1, 0, fx * (1.0 - fy)),
        (0, 1, (1.0 - fx) * fy),
        (1, 1, fx * fy),
    ] {
        let px = thumb.pixel(x0 + dx, y0 + dy);
        if px.iter().any(|c| *c >= CLIPPED_CODE) {
            return None;
        }
        let mean = px
            .iter()
            .map(|c| f64::from(lut[usize::from(*c)]))
            .sum::<f64>()
            / 3.0;
        v += w * mean;
    }
    (v >= DARKEST).then_some(v)
}

/// Estimate the gains of `frames` (flash frames only) over `region`.
pub fn estimate(
    frames: &[GainInput<'_>],
    region: Region,
    cfg: &ExposureConfig,
) -> Result<GainEstimate, AlignError> {
    let lut = srgb8_to_linear_table();
    let mut samples = Vec::new();
    let exclusion = MIRROR_EXCLUSION_DEG.to_radians();
    for (k, f) in frames.iter().enumerate() {
        let mapping = PreparedMapping::new(f.frame)?;
        let (cam, light) = (
            Vec3::from(f.frame.camera_position),
            Vec3::from(f.frame.light_position),
        );
        for p in 0..GRID_SIDE * GRID_SIDE {
            let (i, j) = (p % GRID_SIDE, p / GRID_SIDE);
            let q = Vec2::new(
                region.x_min + (i as f64 + 0.5) / GRID_SIDE as f64 * region.width(),
                region.y_min + (j as f64 + 0.5) / GRID_SIDE as f64 * region.height(),
            );
            let Some(px) = mapping.plane_to_pixel(q) else {
                continue;
            };
            let Some(value) = sample(f.thumb, f.frame.width, px, &lut) else {
                continue;
            };
            let x = Vec3::new(q.x, q.y, 0.0);
            let (dl, dv) = (light - x, cam - x);
            let d2 = dl.norm_squared();
            if !(d2 > 0.0 && dl.z > 0.0 && dv.z > 0.0) {
                continue;
            }
            let h = dl / d2.sqrt() + dv / dv.norm().max(1e-12);
            let half_angle = (h.z / h.norm().max(1e-12)).clamp(-1.0, 1.0).acos();
            if half_angle < exclusion {
                continue;
            }
            samples.push(ExposureSample {
                frame: k as u32,
                point: p as u32,
                value,
                irradiance: dl.z / d2.sqrt() / d2,
                half_angle,
            });
        }
    }
    let times: Vec<f64> = frames
        .iter()
        .enumerate()
        .map(|(k, f)| f.frame.time_s.unwrap_or(k as f64))
        .collect();
    estimate_gains(
        &samples,
        frames.len(),
        GRID_SIDE * GRID_SIDE,
        Some(&times),
        cfg,
    )
    .map_err(|e| AlignError::invalid("exposure", e.to_string(), "overlapping flash frames"))
}
