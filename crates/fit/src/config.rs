//! Settings of the appearance stage.

use serde::{Deserialize, Serialize};
use svbrdf_core::brdf::ModelKind;

use crate::FitError;

/// When the fit applies the room light ([`FitConfig::room_light`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum RoomLightMode {
    /// Estimated for video captures; applied unless at the top of the range searched.
    #[default]
    Auto,
    /// Estimated and applied whatever it is.
    On,
    /// Not estimated (the paper's model).
    Off,
}

/// Which per-pixel colour the initial clusters group ([`FitConfig::cluster_colour`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ClusterColour {
    /// The mean of the pixel's observations (the paper's average colour).
    #[default]
    Mean,
    /// The median of its unclipped observations over the flash's `cos / r^2`
    /// ([`crate::observations::Observations::albedo_colors`]): not brightened where a
    /// highlight passed, nor darkened where the frames were far.
    Albedo,
}

/// Relative drop of a part's solver cost for which a turned tangent is kept
/// ([`FitConfig::tangent_rotation_depth`]): below it the turn is noise (an isotropic
/// lobe's cost does not depend on it).
pub const ROTATION_MIN_GAIN: f64 = 0.01;

/// Settings of `svbrdf fit`. Every field has the paper's value or a measured default.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct FitConfig {
    /// Reflectance model fitted per cluster.
    pub model: ModelKind,
    /// Output resolution, pixels per cm; `None` uses the capture's suggestion.
    pub px_per_cm: Option<f64>,
    /// Light intensity `I` of eq. (9) per channel (linear pixel value * cm^2); `None`
    /// uses the capture's value or, when it has none, the normalisation described in
    /// `docs/CONVENTIONS.md` (the 99th percentile of the first diffuse estimate's
    /// luminance becomes [`FitConfig::normalised_albedo`]).
    pub light_intensity: Option<[f64; 3]>,
    /// Target of the intensity normalisation when the intensity is unknown.
    pub normalised_albedo: f64,
    /// Channels whose linear value reaches this count as clipped. The 8-bit video
    /// saturates in flash highlights and H.264 ringing pulls clipped areas a few code
    /// values below 255, so the threshold sits well below 1 (0.9 linear is sRGB code
    /// 243); measured on the simulator, 0.98 let ringing highlights through as exact
    /// values and 0.8 censored too much.
    pub saturation: f64,
    /// Keep clipped channels as censored observations ("at least the saturation
    /// value") instead of dropping the observation. Dropping them makes the pixels
    /// whose highlight clipped look matte: on the simulator's brushed metal, censoring
    /// lowers the held-out relighting error from about 120% to 40%.
    pub censor_clipped: bool,
    /// Whether to estimate the room light (one constant irradiance over the capture, see
    /// [`crate::room`]) and fit every observation as flash plus room light, so that the
    /// maps hold the material alone: `auto` for captures whose flash frames come from a
    /// video (a sweep over distances tells it from albedo), applied unless it reached the
    /// top of the range searched (as bright as the flash); `on` for any capture (photo
    /// sets too), applied whatever it is; `off`: every observation is read as lit by the
    /// flash alone (the paper's model).
    pub room_light: RoomLightMode,
    /// Observations within this many frame pixels of the image border are dropped.
    pub border_px: f64,
    /// Sample frames bicubically (Catmull-Rom) instead of bilinearly, except next to
    /// clipped pixels. A bilinear sample is a one-pixel tent blur, and at 10-20 cm the
    /// video's pixels are about the size of an output pixel, so pixel-scale texture was
    /// blurred twice; on the paper preset bicubic samples (with the prior at 0.5) took
    /// the diffuse RMSE from 0.0236 to 0.0222 for 8% more observation time.
    pub bicubic: bool,
    /// Pixels with fewer observations are not fitted on their own: they take their
    /// neighbour's cluster and are marked in the coverage map.
    pub min_observations: usize,
    /// Range of k for the initial k-means (paper: 2..=20).
    pub k_min: usize,
    /// Upper end of the k range.
    pub k_max: usize,
    /// Pixels drawn for choosing k and for the k-means iterations (all pixels are then
    /// assigned to the nearest centre).
    pub kmeans_sample: usize,
    /// Seed of every random choice (k-means++ seeding, samples): same seed, same maps.
    pub seed: u64,
    /// Smallest cluster (pixels): a cluster is split only if both parts keep at least
    /// this many (paper: 50).
    pub min_cluster_px: usize,
    /// Where a cluster less than this many levels deep is split, each part is also
    /// fitted from its own starting values (the paper starts only from the parent) and
    /// the better fit kept, unless it invents a highlight that the part's frames never
    /// saw (0: never, as the paper). Shallow splits separate materials, whose pixels
    /// can lie far from the parent's solution; deep ones separate near-identical
    /// pixels (on `tiny` tiles every own fit more than 5% better came from levels 1-4).
    /// On 8 `tiny` captures (tiles, brushed metal, leather, patchwork; 2 scene seeds; 3
    /// clustering seeds each, true registration) the diffuse RMSE went from 0.0359 to
    /// 0.0270 on average and its spread over clustering seeds from 13% to 6% (tiles seed
    /// 1: 0.050-0.086 -> 0.041-0.050); neutral on `hard-small` and `paper` (docs/
    /// BENCHMARKS.md, session 19). On the 20 s `paper` capture 254 of 7,400 splits lie
    /// above level 6, so the limit costs little there; restarting at every level cost
    /// 50 s for diffuse RMSE 0.0216 -> 0.0213.
    pub split_restart_depth: usize,
    /// The colour the initial clusters group. `albedo` with `reassign_pixels` was
    /// measured on 12 hard-small captures (docs/BENCHMARKS.md, session 28): diffuse
    /// RMSE lower on 11 and normals better on 11, tiles relit at 1 mm 59 -> 35% and
    /// 76 -> 50% on the worst light, but one patchwork capture got a lobe no frame saw
    /// (its light 1 at 1 mm 218 -> 612%) and a toy two-material capture splits by
    /// position into six initial clusters; not the default until both are solved.
    pub cluster_colour: ClusterColour,
    /// Move pixels whose error under their cluster's BRDF is several times the
    /// cluster's typical error to a neighbouring cluster whose BRDF explains them far
    /// better ([`crate::reassign`]; our addition). Measured (docs/BENCHMARKS.md,
    /// session 28): diffuse RMSE lower on 9 of 12 hard-small captures (patchwork by
    /// 22-30%), up to 2.4% higher on 3; on `paper` every figure better (diffuse 0.0162
    /// -> 0.0161, relit at 1 mm [20, 93, 21, 29] -> [18, 86, 18, 27]%) for 7 s.
    pub reassign_pixels: bool,
    /// Whether lobes may be turned away from the plane's axes (see
    /// [`tangent_rotation_depth`](Self::tangent_rotation_depth)): `None` (default)
    /// lets the held-out validation decide ([`crate::select`], candidate
    /// `turned-grain`; without validation, no turn); `Some(true)` always,
    /// `Some(false)` never. Not on by default: on shallow clusters that mix
    /// materials a turned lobe lowers the training error of isotropic tiles too (by
    /// up to 36% on `tiny` tiles), and the tree it leads to fitted them worse
    /// (docs/BENCHMARKS.md, session 23).
    pub turned_grain: Option<bool>,
    /// Where turning is on ([`turned_grain`](Self::turned_grain)) and a cluster less
    /// than this many levels deep is split, each part's lobe is also fitted with its
    /// tangent turned (the anisotropy's direction,
    /// [`svbrdf_core::brdf::BrdfParams::tangent_rotation`]) by 22.5, 45 and 67.5
    /// degrees from its parent's, then refined to about 1.4 degrees; the turn is kept
    /// where it lowers the part's error by over [`ROTATION_MIN_GAIN`]. Deeper parts
    /// inherit their parent's. Brushed metal laid askew of the markers has its
    /// grooves at an angle that the plane's axes cannot describe (0: never turn,
    /// alpha_x along plane x as in the paper).
    pub tangent_rotation_depth: usize,
    /// A split is kept only if the children's summed squared error is below
    /// `1 - min_split_gain` times the parent's; otherwise the parent is final. Stops
    /// splitting clusters that are already explained to the noise level.
    pub min_split_gain: f64,
    /// Deepest split level.
    pub max_depth: usize,
    /// At most this many pixels of a cluster feed its binned observations (spread
    /// evenly); per-pixel errors always use every observation.
    pub max_fit_pixels: usize,
    /// The per-pixel errors that drive the splits (eq. 8) and the split-gain test use
    /// at most this many observations of each pixel, spread evenly over its frames.
    /// Every split level visits every pixel, so this bounds the tree's cost per pixel
    /// whatever the video length; the final residual map and re-rendering check use
    /// every observation. Measured on a 20 s `tiny` capture (62 observations per
    /// pixel): 32 cut the cluster-fit time from 1.5 to 1.1 s with diffuse RMSE 0.036 ->
    /// 0.032 and mean relighting error 48% -> 52%; 16 cost more accuracy (60%).
    pub max_split_observations: usize,
    /// Bin width of the four angles of the redundant-observation binning, degrees
    /// (paper: 5).
    pub bin_deg: f64,
    /// Bin width of the light distance, cm (paper: 1).
    pub bin_cm: f64,
    /// Levenberg-Marquardt iterations per cluster fit.
    pub max_iterations: usize,
    /// Levenberg-Marquardt stops when an accepted step lowers the cost by less than
    /// this fraction.
    pub tolerance: f64,
    /// Smallest roughness alpha.
    pub alpha_min: f64,
    /// Largest roughness alpha.
    pub alpha_max: f64,
    /// Largest normal-offset angle about either axis, degrees (paper: 45).
    pub max_normal_deg: f64,
    /// Per-pixel refinement of diffuse albedo and normal after clustering.
    pub refine: bool,
    /// Strength of the refinement's pull towards the cluster solution, in observations:
    /// the prior weighs as much as this many average observations of each parameter.
    pub refine_prior: f64,
    /// Largest change of either normal angle the refinement may make, degrees: a trust
    /// region that keeps a pixel's normal near its cluster's. Without it a few pixels
    /// with a sharp specular lobe tilt to the bound and light up under oblique light.
    pub refine_max_normal_change_deg: f64,
    /// Opt-in (0, the default: off): how far each pixel's normal may move, as a share
    /// of `refine_max_normal_change_deg`, is its normal confidence (`confidence`: the
    /// spread of the directions the light came from, in [0, 1]) over this value, times
    /// `sqrt(frames / normal_trust_full_views)`, at most 1; a pixel lit from a single
    /// direction keeps its cluster's normal. A normal is read from how the shading
    /// changes with the light's direction, so its noise grows as that spread narrows and
    /// falls with the square root of the views. Measured with 1 (session 46, true
    /// registration, docs/BENCHMARKS.md): on 10 `hard-small` captures (4-10 frames per
    /// pixel) the normal error fell on 9 (brushed metal 1.03 -> 0.70 degrees, tiles 2.22
    /// -> 1.81, bathroom tiles 2.77 -> 2.31); `paper` unchanged (1.991 -> 1.994); but on
    /// the 4K `hard` leather (11-25 frames per pixel) it rose 2.08 -> 2.30 degrees, with
    /// diffuse 0.0132 -> 0.0137: there the normals it holds back were measured. So it is
    /// off unless asked for: worth trying on flat, dark or metallic surfaces filmed
    /// briefly.
    pub normal_trust_full_confidence: f64,
    /// Frames at which that share is full, with `normal_trust_full_confidence` set (0:
    /// the number of frames does not count).
    pub normal_trust_full_views: usize,
    /// After the lobe refits, give each pixel whose observations measure its lobe its
    /// own lobe (`confidence::lobe_measured`: at least two unclipped observations
    /// within one lobe width of its mirror direction, or, where the peak clipped and at
    /// least 16 frames saw the pixel, at least two within two widths and four within
    /// three): specular albedo and roughness refined with the diffuse albedo and
    /// normal, pulled towards the cluster's by the same prior. Elsewhere the cluster's
    /// lobe stays: nothing measured it. Measured on the 20 s `paper` capture (true
    /// registration), with the peak rule alone (session 14): diffuse RMSE 0.0237 ->
    /// 0.0216, normal 2.13 -> 2.08 degrees, relighting at 1 mm [18, 128, 22, 36]% ->
    /// [17, 127, 22, 34]%; with the flank rule too (session 43): relighting at 1 mm
    /// [16, 104, 17, 24]% -> [11, 83, 16, 14]%, normal 2.04 -> 1.99 degrees, 99.8% of
    /// the pixels with their own lobe (seen by 6-9 frames, `hard-small` pixels keep the
    /// peak rule alone).
    pub refine_specular: bool,
    /// With `refine_specular`: where a pixel's cluster lobe is at least this anisotropic
    /// (larger width over smaller) and the pixel's highlight was measured by at least
    /// 16 frames, its lobe comes from its neighbours instead (`neighbour` module: fitted
    /// almost freely, then each lobe parameter the median over its cluster's such
    /// pixels within `neighbour_lobes_radius_px`, then refitted as usual). 0: off.
    /// Measured on `paper` (true registration, session 47): relighting at 1 mm under
    /// the brushed metal's light 84 -> 41% (seed 1) and 46 -> 28% (seed 2), light 3
    /// 13.5 -> 10.7% and 26 -> 12%, diffuse and normal error slightly lower, the
    /// validation's held-out error lower; 12-16 s more fitting. Lobe features smaller
    /// than the median's window (under 0.5 mm at 100 px/cm) are smoothed away.
    pub neighbour_lobes_min_anisotropy: f64,
    /// Half-width (output pixels) of the square window of that median.
    pub neighbour_lobes_radius_px: usize,
    /// Robust per-pixel refinement: Cauchy weights with this scale, in units of the
    /// pixel's robust residual spread at its cluster's solution (0: plain least squares).
    pub refine_robust: f64,
    /// Gauss-Newton iterations of the per-pixel refinement (per round), spread over
    /// the passes when lobe refits run (3 iterations and 3 refits: one per pass).
    pub refine_iterations: usize,
    /// Rounds of the robust refinement: each further round recomputes the Cauchy
    /// weights at the pixel's own solution (iteratively reweighted least squares).
    pub refine_rounds: usize,
    /// After the refinement, refit each cluster's specular lobe (rho_s, alpha_x,
    /// alpha_y) with its pixels' refined normals and diffuse albedos held (Ward only),
    /// this many times, refining the pixels again between refits (0: no refit; only
    /// with `refine`). Measured on the paper preset with true poses: relighting 81% ->
    /// 70%, diffuse RMSE 0.0222 -> 0.0206, for about 12% more fitting time.
    pub lobe_refits: usize,
    /// Pixels of a cluster (spread evenly) whose observations feed its lobe refit.
    pub refit_lobe_pixels: usize,
    /// Between lobe refits, refine again only the pixels of clusters whose lobe the
    /// last refit moved (by more than 2%), except in the last pass, which refines every
    /// pixel so that each gets all of `refine_iterations`. False: every pass refines
    /// every pixel.
    pub refine_moved_only: bool,
    /// Frames shown in the re-rendering strip.
    pub strip_frames: usize,
    /// Fit a Lambertian material only (`rho_s = 0` everywhere): the baseline that
    /// shows what the specular fit adds (`svbrdf eval --diffuse-only`).
    pub diffuse_only: bool,
    /// Choose the settings by prediction: fit each of [`crate::select::CANDIDATES`]
    /// without each of this many folds of frames and keep the one that predicts the
    /// held-out frames best (0: fit with the settings as given; else 2-8).
    pub select_folds: usize,
    /// The validation fits use every n-th output pixel in each direction, n the
    /// smallest step that leaves at most this many pixels. Measured on the 20 s
    /// `paper` capture (3.3 million pixels): every 2nd pixel made the validation take
    /// 300 s, six times the fit; every 7th (100,000 pixels) 36 s with the same ranking
    /// of the candidates; every 8th keeps the whole fit under 150 s.
    pub select_pixels: usize,
    /// After each fold, a candidate whose held-out error so far (sRGB) is more than
    /// this many times the defaults' is not fitted on the remaining folds and cannot
    /// be chosen (0: every candidate on every fold; else > 1). To be chosen a
    /// candidate must end at least `MARGIN` (5%) below the defaults, so one 25% above
    /// them after a fold would need the remaining folds to reverse it. Measured
    /// (session 49) on `paper` seeds 1 and 2, 10 `tiny` captures (brushed metal Ward
    /// and GGX, leather, patchwork, tiles; seeds 1 and 2) and `hard-small` leather and
    /// bathroom tiles: the same candidate chosen and the same maps to the last bit on
    /// every one, the validation 15% shorter on `paper` seed 2 (31.4 -> 26.7 s) and
    /// 8-28% on `tiny`. A choice, like `MARGIN`, not a validated constant.
    pub select_drop_ratio: f64,
}

impl Default for FitConfig {
    fn default() -> Self {
        Self {
            model: ModelKind::Ward,
            px_per_cm: None,
            light_intensity: None,
            normalised_albedo: 0.8,
            saturation: 0.9,
            censor_clipped: true,
            room_light: RoomLightMode::Auto,
            border_px: 2.0,
            bicubic: true,
            min_observations: 3,
            k_min: 2,
            k_max: 20,
            kmeans_sample: 20_000,
            seed: 1,
            min_cluster_px: 50,
            min_split_gain: 0.02,
            split_restart_depth: 6,
            cluster_colour: ClusterColour::Mean,
            reassign_pixels: true,
            tangent_rotation_depth: 3,
            turned_grain: None,
            max_depth: 24,
            max_fit_pixels: 4000,
            max_split_observations: 32,
            bin_deg: 5.0,
            bin_cm: 1.0,
            max_iterations: 60,
            tolerance: 1e-4,
            alpha_min: 0.02,
            alpha_max: 1.0,
            max_normal_deg: 45.0,
            refine: true,
            refine_prior: 0.5,
            refine_iterations: 3,
            refine_rounds: 1,
            lobe_refits: 3,
            refit_lobe_pixels: 4000,
            refine_moved_only: true,
            refine_robust: 1.0,
            refine_specular: true,
            neighbour_lobes_min_anisotropy: 1.5,
            neighbour_lobes_radius_px: 2,
            refine_max_normal_change_deg: 3.0,
            normal_trust_full_confidence: 0.0,
            normal_trust_full_views: 16,
            strip_frames: 4,
            diffuse_only: false,
            select_folds: 3,
            select_pixels: 60_000,
            select_drop_ratio: 1.25,
        }
    }
}

impl FitConfig {
    /// Check every field; the error names the field, the value and the accepted range.
    pub fn validate(&self) -> Result<(), FitError> {
        let bad = |what: &str, v: &dyn std::fmt::Display, exp: &str| {
            Err(FitError::invalid(what, v.to_string(), exp))
        };
        if self.tangent_rotation_depth > 64 {
            return bad(
                "tangent rotation depth",
                &self.tangent_rotation_depth,
                "split levels in [0, 64]",
            );
        }
        if let Some(s) = self.px_per_cm {
            if !(s > 0.0 && s <= 1000.0) {
                return bad("resolution", &s, "pixels per cm in (0, 1000]");
            }
        }
        if let Some(i) = self.light_intensity {
            if !i.iter().all(|v| *v > 0.0 && v.is_finite()) {
                return bad(
                    "light intensity",
                    &format!("{i:?}"),
                    "three positive numbers (linear value * cm^2)",
                );
            }
        }
        if !(self.normalised_albedo > 0.0 && self.normalised_albedo <= 1.0) {
            return bad("normalised albedo", &self.normalised_albedo, "(0, 1]");
        }
        if !(self.saturation > 0.0 && self.saturation <= 1.0) {
            return bad("saturation", &self.saturation, "a linear value in (0, 1]");
        }
        if !(self.border_px >= 0.0 && self.border_px < 1000.0) {
            return bad("border", &self.border_px, "pixels in [0, 1000)");
        }
        if self.min_observations < 1 {
            return bad("minimum observations", &self.min_observations, ">= 1");
        }
        if self.k_min < 1 || self.k_max < self.k_min || self.k_max > 64 {
            return bad(
                "k range",
                &format!("{}..={}", self.k_min, self.k_max),
                "1 <= k_min <= k_max <= 64",
            );
        }
        if self.kmeans_sample < self.k_max {
            return bad(
                "k-means sample",
                &self.kmeans_sample,
                "at least k_max pixels",
            );
        }
        if self.min_cluster_px < 1 {
            return bad("minimum cluster size", &self.min_cluster_px, ">= 1 pixel");
        }
        if !(0.0..1.0).contains(&self.min_split_gain) {
            return bad("minimum split gain", &self.min_split_gain, "[0, 1)");
        }
        if self.max_fit_pixels < self.min_cluster_px {
            return bad(
                "fit pixels per cluster",
                &self.max_fit_pixels,
                "at least the minimum cluster size",
            );
        }
        if self.max_split_observations < 1 {
            return bad(
                "split observations per pixel",
                &self.max_split_observations,
                ">= 1",
            );
        }
        if !(self.bin_deg >= 3.0 && self.bin_deg <= 45.0) {
            return bad("angle bin", &self.bin_deg, "degrees in [3, 45]");
        }
        if !(self.bin_cm > 0.0 && self.bin_cm <= 100.0) {
            return bad("distance bin", &self.bin_cm, "cm in (0, 100]");
        }
        if !(self.tolerance > 0.0 && self.tolerance < 0.1) {
            return bad(
                "solver tolerance",
                &self.tolerance,
                "a fraction in (0, 0.1)",
            );
        }
        if self.max_iterations == 0 {
            return bad("iterations", &self.max_iterations, ">= 1");
        }
        if !(self.alpha_min > 0.0 && self.alpha_min < self.alpha_max && self.alpha_max <= 2.0) {
            return bad(
                "roughness range",
                &format!("{}..{}", self.alpha_min, self.alpha_max),
                "0 < alpha_min < alpha_max <= 2",
            );
        }
        if !(self.max_normal_deg >= 0.0 && self.max_normal_deg < 80.0) {
            return bad("normal bound", &self.max_normal_deg, "degrees in [0, 80)");
        }
        if !(self.refine_max_normal_change_deg >= 0.0 && self.refine_max_normal_change_deg <= 90.0)
        {
            return bad(
                "refinement normal change",
                &self.refine_max_normal_change_deg,
                "degrees in [0, 90]",
            );
        }
        if !(0.0..=1.0).contains(&self.normal_trust_full_confidence) {
            return bad(
                "normal trust's full confidence",
                &self.normal_trust_full_confidence,
                "a confidence in [0, 1]",
            );
        }
        if self.normal_trust_full_views > 10_000 {
            return bad(
                "normal trust's full views",
                &self.normal_trust_full_views,
                "frames in 0-10000",
            );
        }
        let a = self.neighbour_lobes_min_anisotropy;
        if !(a == 0.0 || (1.0..=100.0).contains(&a)) {
            return bad(
                "neighbour lobes' minimum anisotropy",
                &a,
                "0 (off) or a width ratio in 1-100",
            );
        }
        if !(1..=16).contains(&self.neighbour_lobes_radius_px) {
            return bad(
                "neighbour lobes' radius",
                &self.neighbour_lobes_radius_px,
                "1-16 output pixels",
            );
        }
        if !(self.refine_robust >= 0.0 && self.refine_robust.is_finite()) {
            return bad("refinement robust scale", &self.refine_robust, ">= 0");
        }
        if !(self.refine_prior >= 0.0 && self.refine_prior.is_finite()) {
            return bad("refinement prior", &self.refine_prior, ">= 0");
        }
        if self.refine_rounds == 0 {
            return bad("refinement rounds", &self.refine_rounds, ">= 1");
        }
        if self.select_folds == 1 || self.select_folds > 8 {
            return bad("validation folds", &self.select_folds, "0 (off) or 2-8");
        }
        if !(self.select_drop_ratio == 0.0 || self.select_drop_ratio > 1.0) {
            return bad(
                "validation drop ratio",
                &self.select_drop_ratio,
                "0 (off) or above 1",
            );
        }
        if self.select_pixels < 1000 {
            return bad("validation pixels", &self.select_pixels, ">= 1000");
        }
        if self.lobe_refits > 0 && self.refit_lobe_pixels == 0 {
            return bad("lobe refit pixels", &self.refit_lobe_pixels, ">= 1");
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn default_is_valid_and_bad_values_are_named() {
        FitConfig::default().validate().unwrap();
        let c = FitConfig {
            k_min: 5,
            k_max: 3,
            ..FitConfig::default()
        };
        let e = c.validate().unwrap_err().to_string();
        assert!(e.contains("k range 5..=3"), "{e}");
        let c = FitConfig {
            saturation: 1.5,
            ..FitConfig::default()
        };
        assert!(c.validate().unwrap_err().to_string().contains("1.5"));
    }
}
