//! Alignment settings: the phone description (`camera.json`) and the stage parameters
//! of the paper's Table 1, scaled with resolution.

use serde::{Deserialize, Serialize};
use svbrdf_core::plane::Region;

use crate::AlignError;

pub use svbrdf_core::camera_description::CameraDescription;

/// How fine correspondences between frames are found.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum FineMethod {
    /// Coarse SIFT matches refined at full resolution by patch correlation (ours:
    /// about 3x more precise than full-resolution SIFT and far cheaper).
    #[default]
    Patch,
    /// The paper's: SIFT at full resolution (`fine_features` per frame), matched anew.
    Sift,
}

/// Stage parameters. Pixel distances are given at the paper's 3840-pixel long side and
/// scaled to the actual resolution.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct AlignConfig {
    /// The phone.
    pub camera: CameraDescription,
    /// Output region on the plane (cm); default: bounded by the markers' inner corners.
    pub region: Option<Region>,
    /// Output resolution, pixels per cm; default: half the frames' mean sampling density.
    pub px_per_cm: Option<f64>,
    /// Drop frames whose blur metric is this many standard deviations below the mean.
    pub blur_sigmas: f64,
    /// Instead of every `frame_step`-th frame itself, use the sharpest (eq. 1) of the
    /// frames within this many frames of it: a hand jerk blurs a frame or two, and the
    /// neighbours show nearly the same content, so eq. 1 compares them fairly (0: the
    /// paper's fixed sampling). Larger windows leave larger gaps between the frames
    /// used (measured: choosing anywhere in a window of 5 disconnected a third of the
    /// frames on hard-small leather).
    #[serde(default)]
    pub sharpest_within: u32,
    /// Long side of the coarse images, pixels (paper: 1/4 of 3840 = 960).
    pub coarse_long_side: u32,
    /// SIFT features per coarse image (paper: 3,000).
    pub coarse_features: usize,
    /// Coarse similarity inlier distance at 960 px (paper: 20).
    pub coarse_inlier_px: f64,
    /// Minimum coarse inliers for a connection (paper: 20).
    pub coarse_min_inliers: usize,
    /// Radius of the flash highlight whose features are dropped, as a fraction of the
    /// image's long side (paper: 75 px at 960).
    pub highlight_radius: f64,
    /// How fine correspondences are found.
    pub fine_method: FineMethod,
    /// Patch half-width for `FineMethod::Patch` at 3840 px (scaled, at least 5 px).
    pub patch_radius_px: f64,
    /// Long side of the images for fine features, pixels (paper: full scale, 3840).
    pub fine_long_side: u32,
    /// SIFT features per fine image (paper: 12,000).
    pub fine_features: usize,
    /// Fine homography inlier distance at 3840 px (paper: 60).
    pub fine_inlier_px: f64,
    /// Refined correspondences (patch method) farther than this from one homography
    /// fitted to a pair's refined matches are dropped, pixels at 3840 px (ours; the
    /// coarse `fine_inlier_px` admits matches one period off on repetitive texture).
    #[serde(default = "default_fine_recheck_px")]
    pub fine_recheck_px: f64,
    /// Minimum fine inliers for a pair (paper: 60).
    pub fine_min_inliers: usize,
    /// Guided matches (patch method, ours): where a sub-frame of either frame of a pair
    /// holds fewer refined correspondences than this, the pair's other features there
    /// are predicted through the pair's homography and refined by patches (the ratio
    /// test rejects features that look alike, as every grout crossing of a tiled floor
    /// does). Correspondences per sub-frame; 0 turns it off. Not used on two-camera
    /// captures (measured to worsen their fit; docs/BENCHMARKS.md, session 38) nor on
    /// frames (video or still photos) whose long side exceeds 1920 px
    /// (`fine::FILL_MAX_LONG_SIDE`; measured to worsen the `paper` preset at 4K,
    /// session 39).
    #[serde(default = "default_fine_fill")]
    pub fine_fill: usize,
    /// Sub-frame grid (columns, rows); default scales the paper's 5 x 11 at 2160 x 3840.
    pub subframes: Option<(u32, u32)>,
    /// SIFT contrast threshold (OpenCV's default is 0.04; materials are often low-contrast).
    pub sift_contrast: f64,
    /// Match every frame against the reference photo for absolute constraints.
    pub match_reference: bool,
    /// Tie frames without reference-photo matches of their own to the plane by the
    /// blocks the self-check matched with the reference photo, and solve again
    /// (`ties`); needs the self-check.
    #[serde(default = "default_true")]
    pub plane_ties: bool,
    /// Find the corners of markers that detection missed in a frame (cut by the
    /// frame's edge, or blurred) where the frame's map puts them, and solve again
    /// (`partial`).
    #[serde(default = "default_true")]
    pub marker_corners: bool,
    /// Measure the relief shift (texture that appears moved towards the flash on a
    /// material with relief) with a rigid camera model, correct the texture
    /// correspondences by it and solve again where it explains at least
    /// [`MIN_GAIN`](crate::relief::MIN_GAIN) of that model's residual (`relief`).
    #[serde(default = "default_true")]
    pub relief: bool,
    /// Where the frames sampled at the camera's `frame_step` leave the region thin
    /// (seen by at least 3 kept frames over less than
    /// [`GOOD_COVERAGE`](crate::GOOD_COVERAGE) of it) or cannot be registered at all,
    /// align the video again from every `frame_step / 2`-th frame and keep that pass
    /// where it covers more (`densify`; videos of one camera only).
    #[serde(default = "default_true")]
    pub densify: bool,
    /// The check of every kept frame against the reference photo after the solve.
    #[serde(default)]
    pub self_check: crate::selfcheck::SelfCheckConfig,
    /// Weight of a match with the reference photo relative to a match between frames:
    /// the reference is coarser and lit differently, so its features are less precise.
    pub reference_weight: f64,
    /// Weight of sub-frame agreement in their overlaps, relative to a feature match
    /// (4: measured on the paper preset, 95th percentile 0.57 -> 0.52 px against 1; 16
    /// is worse).
    pub overlap_weight: f64,
    /// Largest noise gain a sub-frame's map may have and still be used (see
    /// `support`): the standard deviation of its corners' plane positions in units of
    /// one constraint's noise. Sub-frames above it are extrapolations, not
    /// measurements, and are left out of the registered capture. 4: on simulated
    /// captures with texture everywhere every sub-frame but a handful stays below 4 and
    /// those above were 0.3-1.1 mm off; on brushed metal, 1-7 cm. Unitless, > 0.
    #[serde(default = "default_max_noise_gain")]
    pub max_noise_gain: f64,
    /// Largest noise gain (as `max_noise_gain`) at which a sub-frame on the frame's
    /// edge is used out to that edge: beyond it the sub-frame's map is extrapolated
    /// past its correspondences, and it is used only up to where the gain falls to
    /// this (at most to the middle of its cell; `support::apply_edge_cuts`). 1.5: on
    /// the Mitsuba-rendered tiles sub-frames with gains of 2-4 were over 1 output px
    /// off in 30-45% of cases, 1-2 in 12-17%, under 1 in 1-3% (docs/BENCHMARKS.md,
    /// session 40). 0 turns it off. Unitless, >= 0.
    #[serde(default = "default_edge_noise_gain")]
    pub edge_noise_gain: f64,
    /// Gauss-Newton iterations of the global solve.
    pub iterations: usize,
    /// At most this many fine pairs per frame (its strongest coarse connections; the
    /// time chain is always kept). Each pair couples two frames' sub-frames in the
    /// global solve, whose factorisation grows with the coupling. On the paper preset
    /// 6 gives the same alignment figures as 8 (median and p95 over all samples) but
    /// leaves a few frames misregistered towards the map's corners: the fit from that
    /// alignment had twice the diffuse error (0.054 against 0.025) and frames that
    /// re-render with 79% error (26% with 8).
    pub max_pairs_per_frame: usize,
    /// Test every pair in coarse matching instead of predicted overlaps (benchmarks).
    pub all_pairs: bool,
    /// The second (no-flash) phone of a two-camera capture; its `frame_step` is the
    /// second stream's (paper: 10).
    pub second_camera: CameraDescription,
    /// Second-stream time of the flash video's first frame, seconds; `None` finds it
    /// from the flash onset.
    pub sync_offset_s: Option<f64>,
    /// Drop second-stream frames after the flash video's end instead of refusing the
    /// capture (the paper requires the second stream to end first).
    pub trim_second: bool,
    /// Flash frames (nearest in time) each second-stream frame is matched with.
    pub cross_pairs_per_frame: usize,
    /// Assume every flash frame was recorded at the same exposure instead of
    /// estimating one gain per frame (for captures with exposure locked).
    #[serde(default)]
    pub fixed_exposure: bool,
    /// The per-frame gain estimate's settings.
    #[serde(default)]
    pub exposure: svbrdf_core::exposure::ExposureConfig,
    /// Views of each reference marker wanted among the frames registered: when the
    /// sampled frames show a marker whole fewer times, every other frame of the video
    /// is searched for it and the sharpest frame of each pass over it is added (the
    /// marker hunt, `hunt`). 0 turns the hunt off. Frames, 0 to 8.
    #[serde(default = "default_marker_views")]
    pub marker_views: u32,
}

impl Default for AlignConfig {
    fn default() -> Self {
        Self {
            camera: CameraDescription::default(),
            region: None,
            px_per_cm: None,
            blur_sigmas: 3.0,
            sharpest_within: 1,
            coarse_long_side: 960,
            coarse_features: 3000,
            coarse_inlier_px: 20.0,
            coarse_min_inliers: 20,
            highlight_radius: 75.0 / 960.0,
            fine_method: FineMethod::Patch,
            patch_radius_px: 12.0,
            fine_long_side: 3840,
            fine_features: 12000,
            fine_inlier_px: 60.0,
            fine_recheck_px: default_fine_recheck_px(),
            fine_min_inliers: 60,
            fine_fill: default_fine_fill(),
            subframes: None,
            sift_contrast: 0.02,
            match_reference: true,
            plane_ties: true,
            marker_corners: true,
            relief: true,
            densify: true,
            self_check: crate::selfcheck::SelfCheckConfig::default(),
            reference_weight: 1.0,
            overlap_weight: 4.0,
            max_noise_gain: default_max_noise_gain(),
            edge_noise_gain: default_edge_noise_gain(),
            iterations: 8,
            max_pairs_per_frame: 8,
            all_pairs: false,
            fixed_exposure: false,
            exposure: svbrdf_core::exposure::ExposureConfig::default(),
            second_camera: CameraDescription {
                frame_step: 10,
                ..CameraDescription::default()
            },
            sync_offset_s: None,
            trim_second: false,
            cross_pairs_per_frame: 3,
            marker_views: default_marker_views(),
        }
    }
}

fn default_max_noise_gain() -> f64 {
    4.0
}

fn default_edge_noise_gain() -> f64 {
    1.5
}

/// 8 px at 3840 (2 px at 960): on Mitsuba-rendered tiles it keeps 96% of the right
/// refined matches and drops 70-78% of those over 2 output px off.
fn default_fine_recheck_px() -> f64 {
    8.0
}

fn default_fine_fill() -> usize {
    8
}

fn default_true() -> bool {
    true
}

fn default_marker_views() -> u32 {
    2
}

impl AlignConfig {
    /// A minimum inlier count given for the paper's image size (`base_area` pixels),
    /// scaled with the square root of the actual area, never below 12.
    pub fn scaled_min(base: usize, base_area: f64, area: f64) -> usize {
        ((base as f64 * (area / base_area).sqrt()).round() as usize).clamp(12.min(base), base)
    }

    /// Check the numbers.
    pub fn validate(&self) -> Result<(), AlignError> {
        self.camera.validate()?;
        self.second_camera.validate()?;
        if let Some(o) = self.sync_offset_s {
            if !o.is_finite() {
                return Err(AlignError::invalid(
                    "sync offset",
                    o,
                    "seconds on the second video's clock, a finite number",
                ));
            }
        }
        if let Some(r) = &self.region {
            r.validate()?;
        }
        if let Some(p) = self.px_per_cm {
            if !(p > 0.0 && p <= 1000.0) {
                return Err(AlignError::invalid(
                    "output resolution",
                    p,
                    "pixels per cm, in (0, 1000]",
                ));
            }
        }
        if !(self.blur_sigmas > 0.0) {
            return Err(AlignError::invalid(
                "blur threshold",
                self.blur_sigmas,
                "standard deviations, > 0",
            ));
        }
        if self.coarse_long_side < 64 || self.fine_long_side < 64 {
            return Err(AlignError::invalid(
                "image size for features",
                self.coarse_long_side.min(self.fine_long_side),
                "at least 64 px",
            ));
        }
        if self.coarse_features < 10 || self.fine_features < 10 {
            return Err(AlignError::invalid(
                "feature count",
                self.coarse_features.min(self.fine_features),
                "at least 10",
            ));
        }
        if let Some((c, r)) = self.subframes {
            if c == 0 || r == 0 || c > 64 || r > 64 {
                return Err(AlignError::invalid(
                    "sub-frame grid",
                    format!("{c}x{r}"),
                    "1 to 64 in each direction",
                ));
            }
        }
        if !(self.fine_recheck_px > 0.0 && self.fine_recheck_px.is_finite()) {
            return Err(AlignError::invalid(
                "fine recheck distance",
                self.fine_recheck_px,
                "pixels at 3840 px, > 0 (a large value turns the check off)",
            ));
        }
        if self.fine_fill > 1000 {
            return Err(AlignError::invalid(
                "guided fill",
                self.fine_fill,
                "correspondences per sub-frame, 0 (off) to 1000",
            ));
        }
        if !(self.fine_inlier_px > 0.0 && self.coarse_inlier_px > 0.0) {
            return Err(AlignError::invalid(
                "inlier distance",
                self.fine_inlier_px.min(self.coarse_inlier_px),
                "pixels, > 0",
            ));
        }
        if !(self.patch_radius_px >= 2.0 && self.patch_radius_px <= 64.0) {
            return Err(AlignError::invalid(
                "patch radius",
                self.patch_radius_px,
                "pixels at 3840 px, in [2, 64]",
            ));
        }
        if !(self.overlap_weight >= 0.0 && self.overlap_weight < 1e6) {
            return Err(AlignError::invalid(
                "overlap weight",
                self.overlap_weight,
                "a finite weight >= 0",
            ));
        }
        if !(self.max_noise_gain > 0.0 && self.max_noise_gain.is_finite()) {
            return Err(AlignError::invalid(
                "largest sub-frame noise gain",
                self.max_noise_gain,
                "a finite number > 0 (default 4; larger keeps more extrapolated sub-frames)",
            ));
        }
        if !(self.edge_noise_gain >= 0.0 && self.edge_noise_gain.is_finite()) {
            return Err(AlignError::invalid(
                "sub-frame noise gain at the frame's edge",
                self.edge_noise_gain,
                "a finite number >= 0 (default 1.5; 0 uses every sub-frame out to the frame's edge)",
            ));
        }
        if self.marker_views > 8 {
            return Err(AlignError::invalid(
                "marker views",
                self.marker_views,
                "0 (no marker hunt) to 8 frames per marker",
            ));
        }
        if self.sharpest_within > 30 {
            return Err(AlignError::invalid(
                "sharpest-within window",
                self.sharpest_within,
                "0 to 30 frames on each side",
            ));
        }
        let sc = &self.self_check;
        if !(sc.max_shift_mm > 0.0 && sc.max_shift_mm <= 100.0) {
            return Err(AlignError::invalid(
                "self-check offset limit",
                sc.max_shift_mm,
                "mm, in (0, 100]",
            ));
        }
        if !(0.0..=1.0).contains(&sc.max_inconsistent_share) {
            return Err(AlignError::invalid(
                "self-check inconsistent share",
                sc.max_inconsistent_share,
                "a fraction in [0, 1]",
            ));
        }
        if !(0.0..0.5).contains(&self.highlight_radius) {
            return Err(AlignError::invalid(
                "highlight radius",
                self.highlight_radius,
                "a fraction of the long side in [0, 0.5)",
            ));
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_defaults_validate_and_a_bad_recheck_distance_is_named() {
        assert!(AlignConfig::default().validate().is_ok());
        for v in [0.0, -1.0, f64::NAN, f64::INFINITY] {
            let c = AlignConfig {
                fine_recheck_px: v,
                ..AlignConfig::default()
            };
            let e = c.validate().expect_err("refused").to_string();
            assert!(e.contains("fine recheck distance"), "{e}");
        }
    }

    #[test]
    fn a_config_written_before_the_recheck_reads_with_its_default() {
        let mut v = serde_json::to_value(AlignConfig::default()).expect("serialises");
        v.as_object_mut()
            .expect("an object")
            .remove("fine_recheck_px");
        let c: AlignConfig = serde_json::from_value(v).expect("reads");
        assert_eq!(c.fine_recheck_px, 8.0);
    }
}
