//! What a fit needs of the machine: the output grid's size against the memory there is.

use svbrdf_core::capture::RegisteredCapture;
use svbrdf_core::plane::PlaneGrid;

use crate::{FitConfig, FitError};

/// The output grid of a capture under a configuration.
pub fn output_grid(capture: &RegisteredCapture, cfg: &FitConfig) -> Result<PlaneGrid, FitError> {
    let px_per_cm = cfg.px_per_cm.unwrap_or(capture.px_per_cm);
    // Size the grid from the region before allocating it: an absurd resolution must be
    // refused with a figure, not end in an allocation failure minutes later.
    let (w, h) = (
        capture.region.width() * px_per_cm,
        capture.region.height() * px_per_cm,
    );
    let need = estimated_fit_bytes(w * h, capture.frames.len());
    let available = available_memory_bytes();
    if need > available.unwrap_or(f64::INFINITY) || w * h > MAX_GRID_PIXELS {
        return Err(FitError::invalid(
            "output resolution",
            format!(
                "{px_per_cm} px/cm (a {:.0} x {:.0} pixel grid over the {:.2} x {:.2} cm region, needing about {})",
                w,
                h,
                capture.region.width(),
                capture.region.height(),
                human_bytes(need)
            ),
            format!(
                "a grid that fits in memory ({} available, at most {MAX_GRID_PIXELS:.0} pixels): lower --px-per-cm or px_per_cm in capture.json",
                available.map_or("unknown".into(), human_bytes)
            ),
        ));
    }
    Ok(PlaneGrid::new(capture.region, px_per_cm)?)
}

/// Largest output grid, pixels (a 20 x 20 cm region at 1000 px/cm).
pub const MAX_GRID_PIXELS: f64 = 4.0e8;

/// A rough upper estimate of the fit's peak memory, bytes: per-pixel maps and state
/// (~400 B) plus the observations (about a third of the frames see each pixel, 24 B
/// each; session 9's paper-preset fit: 4 Mpx, 115 frames, 4.5 GB measured, 5.3 GB
/// estimated).
pub fn estimated_fit_bytes(pixels: f64, frames: usize) -> f64 {
    pixels * (400.0 + frames as f64 / 3.0 * 24.0)
}

/// Memory the system can give without swapping (Linux `MemAvailable`), bytes.
pub fn available_memory_bytes() -> Option<f64> {
    let text = std::fs::read_to_string("/proc/meminfo").ok()?;
    let line = text.lines().find(|l| l.starts_with("MemAvailable:"))?;
    let kb: f64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb * 1024.0)
}

fn human_bytes(b: f64) -> String {
    match b {
        b if b >= 1e12 => format!("{:.1} TB", b / 1e12),
        b if b >= 1e9 => format!("{:.1} GB", b / 1e9),
        b => format!("{:.0} MB", b / 1e6),
    }
}
