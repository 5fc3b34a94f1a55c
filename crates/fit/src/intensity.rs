//! The light intensity of a fit: given, from the capture, or normalised from the data.

use svbrdf_core::capture::RegisteredCapture;

use crate::{FitConfig, FitError, IntensitySource, Observations};

/// The light intensity: from the configuration, the capture, or normalised from the
/// data (99th percentile of the per-pixel median of `pi L r^2 / cos(theta_i)` over
/// channels, mapped to `normalised_albedo`).
pub fn light_intensity(
    obs: &Observations,
    capture: &RegisteredCapture,
    cfg: &FitConfig,
) -> Result<([f64; 3], IntensitySource), FitError> {
    if let Some(i) = cfg.light_intensity {
        return Ok((i, IntensitySource::Config));
    }
    if let Some(i) = capture.light_intensity {
        return Ok((i, IntensitySource::Capture));
    }
    // Only the flash camera's observations set the scale: a second (two-camera)
    // stream sees the surface from other angles and would move the albedo scale, so
    // one- and two-camera fits of the same capture would not be comparable.
    let stream_of: std::collections::HashMap<u32, u32> = capture
        .frames
        .iter()
        .map(|f| (f.id, capture.sources.get(f.source).map_or(0, |s| s.stream)))
        .collect();
    let flash: Vec<bool> = obs
        .frames
        .iter()
        .map(|f| stream_of.get(&f.id).is_none_or(|s| *s == 0))
        .collect();
    let step = (obs.pixels() / 20_000).max(1);
    let mut medians: Vec<f64> = (0..obs.pixels())
        .step_by(step)
        .filter(|&p| obs.range(p).any(|o| flash[usize::from(obs.frame[o])]))
        .map(|p| {
            let mut a: Vec<f64> = obs
                .range(p)
                .filter(|&o| flash[usize::from(obs.frame[o])])
                .map(|o| {
                    let lv = obs.light_view(p, o);
                    let c = obs.color(o);
                    std::f64::consts::PI * lv.light_dist2 / lv.light.z.max(0.05)
                        * (c[0] + c[1] + c[2])
                        / 3.0
                })
                .collect();
            let m = a.len() / 2;
            *a.select_nth_unstable_by(m, f64::total_cmp).1
        })
        .collect();
    if medians.is_empty() {
        return Err(FitError::NoData(
            "no pixel of the region was observed".into(),
        ));
    }
    let k = ((medians.len() - 1) as f64 * 0.99).round() as usize;
    let p99 = *medians.select_nth_unstable_by(k, f64::total_cmp).1;
    if p99 <= 0.0 || !p99.is_finite() {
        return Err(FitError::NoData(
            "every observation is black: cannot normalise the light intensity".into(),
        ));
    }
    Ok((
        [p99 / cfg.normalised_albedo; 3],
        IntensitySource::Normalised,
    ))
}
