//! The fit's confidence maps as other stages read them: what share of a material's
//! surface had its diffuse albedo, specular lobe and normal measured well (computed by
//! `svbrdf-fit`'s `confidence` module; carried by the exports and the report).

use serde::{Deserialize, Serialize};

/// Frames at which a pixel's diffuse confidence is full.
pub const DIFFUSE_FULL_VIEWS: usize = 8;

/// File name of the confidence map beside each export's files (not a material texture).
pub const CONFIDENCE_FILE: &str = "confidence.png";

/// What a confidence map's channels hold (linear values in [0, 1], not colours).
pub const CONFIDENCE_MEANING: &str = "confidence in [0, 1] per parameter group, linear: R = diffuse albedo (frames that saw the pixel, full at 8), G = specular lobe (1: the highlight's peak seen unclipped, 0.5: only its flank or clipped, 0: never seen, the lobe is its cluster's), B = normal (spread of the light directions, full at 0.15)";

/// What a pixel's specular confidence (the map's G channel) says about its highlight.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SpecularSeen {
    /// The peak was seen unclipped (confidence 1).
    Peak = 0,
    /// Only its flank, or a clipped peak (confidence between 0 and 1).
    Flank = 1,
    /// Never seen (confidence 0): the pixel carries its cluster's lobe.
    Never = 2,
}

impl SpecularSeen {
    /// The class of a specular confidence value.
    pub fn of(specular: f32) -> Self {
        if specular >= 1.0 {
            Self::Peak
        } else if specular > 0.0 {
            Self::Flank
        } else {
            Self::Never
        }
    }
}

/// What the confidence maps say over the observed pixels, as shares in [0, 1].
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct ConfidenceSummary {
    /// Pixels seen by at least one frame (the shares below are over these).
    pub observed_pixels: usize,
    /// Share whose diffuse confidence is below 0.5 (fewer than half of
    /// [`DIFFUSE_FULL_VIEWS`] frames).
    pub diffuse_low: f64,
    /// Share whose highlight peak was seen unclipped.
    pub specular_peak: f64,
    /// Share whose highlight was seen only on its flank or clipped.
    pub specular_flank: f64,
    /// Share whose highlight was never seen (lobe copied from the cluster).
    pub specular_unseen: f64,
    /// Share whose normal confidence is below 0.5.
    pub normal_low: f64,
}

impl ConfidenceSummary {
    /// One sentence a user understands, naming the shares that matter.
    pub fn sentence(&self) -> String {
        let pct = |v: f64| format!("{:.0}%", 100.0 * v);
        let mut s = format!(
            "The highlight's peak was seen on {} of the surface",
            pct(self.specular_peak)
        );
        if self.specular_flank > 0.005 {
            s += &format!(
                ", only its flank or clipped on {} (gloss strength extrapolated there)",
                pct(self.specular_flank)
            );
        }
        if self.specular_unseen > 0.005 {
            s += &format!(
                "; on {} it was never seen, so their gloss is a guess from similar regions (their cluster's lobe)",
                pct(self.specular_unseen)
            );
        }
        s += ".";
        if self.normal_low > 0.005 {
            s += &format!(
                " On {} the light came from too narrow a range of directions to measure the normal well.",
                pct(self.normal_low)
            );
        }
        if self.diffuse_low > 0.005 {
            s += &format!(
                " {} was seen by fewer than {} frames (colour less certain).",
                pct(self.diffuse_low),
                DIFFUSE_FULL_VIEWS / 2
            );
        }
        s
    }
}

/// A confidence map with its summary, as the exports and the report carry it.
#[derive(Debug, Clone, PartialEq)]
pub struct ConfidenceMap {
    /// Per map pixel (row-major, top row = largest y): diffuse, specular, normal.
    pub per_pixel: Vec<[f32; 3]>,
    /// What it says over the observed pixels.
    pub summary: ConfidenceSummary,
}

impl ConfidenceMap {
    /// The map as a linear RGB image of `width` x `height` (R diffuse, G specular,
    /// B normal).
    pub fn image(&self, width: usize, height: usize) -> crate::image::ImageF32 {
        let mut img = crate::image::ImageF32::new(width, height, 3);
        for (o, v) in img.data.chunks_exact_mut(3).zip(&self.per_pixel) {
            o.copy_from_slice(v);
        }
        img
    }

    /// Write it as [`CONFIDENCE_FILE`] (linear 8-bit PNG) into `dir`.
    pub fn write_png(
        &self,
        dir: &std::path::Path,
        width: usize,
        height: usize,
    ) -> Result<(), crate::CoreError> {
        crate::maps::write_png(
            &dir.join(CONFIDENCE_FILE),
            &self.image(width, height),
            crate::maps::Encoding::Linear,
            crate::maps::PngDepth::Eight,
            &[
                ("map", CONFIDENCE_MEANING.to_string()),
                ("encoding", "linear".into()),
            ],
        )
    }
}
