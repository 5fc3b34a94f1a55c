//! Simulator settings: plain structs with documented units and `validate()` (the presets
//! are in `presets.rs`).

// `!(x >= 0.0)` rejects NaN as well as out-of-range values; that is the point.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

use std::path::PathBuf;

use serde::{Deserialize, Serialize};
use svbrdf_core::brdf::ModelKind;

use crate::SynthError;

/// Names accepted by `--preset`.
pub const PRESETS: &[&str] = &["tiny", "paper", "two-camera", "hard", "hard-small"];

/// Built-in procedural materials accepted by `--material`.
pub const MATERIALS: &[&str] = &[
    "patchwork",
    "leather",
    "brushed-metal",
    "tiles",
    "facets",
    "bathroom-tiles",
];

/// Where the material comes from.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum MaterialSource {
    /// A built-in procedural material (one of [`MATERIALS`]).
    Procedural(String),
    /// A folder with map images (see `docs/CONVENTIONS.md`, "Material maps for synth").
    Maps(PathBuf),
}

/// The printed markers.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MarkerSpec {
    /// OpenCV dictionary name.
    pub dictionary: String,
    /// Side of the black marker square, cm.
    pub size_cm: f64,
    /// White paper around each marker, cm on every side.
    pub paper_margin_cm: f64,
    /// Ids at the region's top-left, top-right, bottom-right, bottom-left corners.
    pub ids: [i32; 4],
}

/// A phone camera recording video.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct VideoSpec {
    /// Frame width, pixels (portrait phones: the shorter side).
    pub width: u32,
    /// Frame height, pixels.
    pub height: u32,
    /// Field of view across the longer image side, degrees, in (0, 180).
    pub fov_deg: f64,
    /// Frames per second, > 0.
    pub fps: f64,
    /// Recording length, seconds, > 0.
    pub duration_s: f64,
    /// Radial distortion k1 (negative: barrel).
    pub k1: f64,
    /// Radial distortion k2.
    pub k2: f64,
    /// Focus breathing: relative frame-to-frame change of k1 and of the focal length.
    pub breathing: f64,
    /// Phone-to-phone spread of k1: the capture's k1 is `k1` plus a seeded uniform
    /// draw in [-k1_spread, k1_spread] (0: exactly `k1`).
    #[serde(default)]
    pub k1_spread: f64,
    /// Store the video as phones record SDR: BT.709 Y'CbCr matrix, limited range,
    /// tagged so (false: BT.601, untagged, what FFmpeg assumes).
    #[serde(default)]
    pub bt709: bool,
    /// Auto-exposure as phones run it with the torch on (None: exposure locked, every
    /// frame at gain 1).
    #[serde(default)]
    pub auto_exposure: Option<AutoExposureSpec>,
    /// How the flash video is stored: 8-bit SDR H.264 (default), 10-bit SDR HEVC,
    /// 10-bit HLG or PQ HEVC (BT.2020).
    #[serde(default)]
    pub format: svbrdf_cv::encode::VideoFormat,
    /// Variable frame timing: frame `n` is taken and stamped at
    /// `n / fps + frame_jitter_s * sin(1.7 n)` seconds (0: constant rate), < 0.4 / fps.
    #[serde(default)]
    pub frame_jitter_s: f64,
    /// The same frames stored in these formats too, each as a complete capture folder
    /// beside the output, named `<out>.<format>` (one rendering, several encodings: the
    /// formats are compared on identical scenes and sweeps). Empty: none.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub also_formats: Vec<svbrdf_cv::encode::VideoFormat>,
}

/// A phone's auto-exposure: each frame is metered (mean linear level of what the
/// sensor sees at gain 1) and the gain moves towards `target / metered` with a lag,
/// so the brightness of the recorded video drifts as the phone moves closer and
/// farther (the flash's 1/d^2) and over bright or dark parts of the surface.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct AutoExposureSpec {
    /// Mean linear level the metering aims for, in (0, 1).
    pub target: f64,
    /// Time constant of the metering's response, seconds (>= 0; 0: instant).
    pub lag_s: f64,
    /// Largest gain change either way, EV (stops), > 0.
    pub max_ev: f64,
    /// Slow wander of the level aimed at, EV amplitude (>= 0): one period over the
    /// recording, seeded phase (a torch dimming as it warms, the app's exposure
    /// hunting). Makes the drift large even where the camera's distance varies little.
    #[serde(default)]
    pub wander_ev: f64,
}

impl Default for AutoExposureSpec {
    /// A phone's default: aims at 18% grey, reacts within about 0.4 s, +-3 EV, and
    /// the aim wanders by +-1 EV over the recording.
    fn default() -> Self {
        Self {
            target: 0.18,
            lag_s: 0.4,
            max_ev: 3.0,
            wander_ev: 1.0,
        }
    }
}

/// The hand-held sweep of the flash camera.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SweepSpec {
    /// Closest camera height above the plane, cm, > 0.
    pub distance_min_cm: f64,
    /// Farthest camera height, cm, >= `distance_min_cm`.
    pub distance_max_cm: f64,
    /// Side-to-side cycles over the whole recording.
    pub side_cycles: f64,
    /// Top-to-bottom half-cycles over the recording (1: one pass top to bottom).
    pub vertical_passes: f64,
    /// Standard deviation of the hand's tilt jitter, degrees.
    pub tilt_jitter_deg: f64,
    /// Probability that a frame is motion-blurred, in [0, 1].
    pub motion_blur_probability: f64,
    /// How far the sweep reaches towards the region's edges, as a fraction of its
    /// half-size (1: the camera passes over the markers at the corners).
    #[serde(default = "one")]
    pub reach: f64,
}

fn one() -> f64 {
    1.0
}

/// The reference photo.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ReferenceSpec {
    /// Width, pixels.
    pub width: u32,
    /// Height, pixels.
    pub height: u32,
    /// Field of view across the longer side, degrees.
    pub fov_deg: f64,
    /// Camera height above the plane, cm.
    pub distance_cm: f64,
    /// Tilt away from parallel, degrees (0: the paper's levelled photo).
    pub tilt_deg: f64,
    /// Rotation about the vertical (the photo's roll against the markers), degrees.
    #[serde(default)]
    pub roll_deg: f64,
    /// JPEG quality, 1-100.
    pub jpeg_quality: i32,
    /// Supersampling per axis (anti-aliasing of marker edges).
    pub supersample: u32,
}

/// Lights and sensor.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LightSpec {
    /// Flash intensity `I` of eq. (9), linear pixel value * cm^2.
    pub flash_intensity: f64,
    /// Flash position in the camera frame (x right, y down, z forward), cm.
    pub flash_offset_cm: [f64; 3],
    /// Uniform ambient light during the video: adds `ambient * rho_d` (linear).
    pub ambient: f64,
    /// Room light for the no-flash reference photo: adds `ambient * rho_d` (linear).
    pub reference_ambient: f64,
    /// Shot-noise gain: noise variance grows by `shot_noise * value` (linear units).
    pub shot_noise: f64,
    /// Read-noise standard deviation, linear units.
    pub read_noise: f64,
}

/// An optional second, no-flash camera filming from an oblique angle (paper 3.3).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SecondCameraSpec {
    /// Frame width, pixels.
    pub width: u32,
    /// Frame height, pixels.
    pub height: u32,
    /// Field of view across the longer side, degrees.
    pub fov_deg: f64,
    /// Frames per second.
    pub fps: f64,
    /// Angle between the view axis and the plane normal, degrees (30-50 typical).
    pub oblique_deg: f64,
    /// Azimuth of the camera around the region centre, degrees (0: from +x).
    pub azimuth_deg: f64,
    /// Distance from the region centre, cm.
    pub distance_cm: f64,
    /// How much earlier than the flash camera it starts recording, seconds, >= 0.
    pub lead_s: f64,
    /// Rolling-shutter readout time (top row to bottom row), seconds.
    pub readout_s: f64,
}

/// An optional set of flash photos (still images instead of a video, issue 7).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PhotoSpec {
    /// Number of photos, >= 2.
    pub count: u32,
    /// Photo width, pixels.
    pub width: u32,
    /// Photo height, pixels.
    pub height: u32,
    /// Field of view across the longer side, degrees.
    pub fov_deg: f64,
    /// Closest and farthest camera height, cm.
    pub distance_cm: [f64; 2],
    /// Largest tilt away from looking straight down, degrees.
    pub tilt_deg: f64,
    /// JPEG quality, 1-100.
    pub jpeg_quality: i32,
}

/// Everything `svbrdf synth` needs.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SynthConfig {
    /// Preset name this config started from.
    pub preset: String,
    /// Random seed; output is deterministic for a seed.
    pub seed: u64,
    /// The material.
    pub material: MaterialSource,
    /// Material region width and height, cm (the markers sit at its corners).
    pub region_cm: [f64; 2],
    /// Ground-truth map resolution, pixels per cm.
    pub map_px_per_cm: f64,
    /// Smallest feature of procedural materials, cm.
    pub feature_cm: f64,
    /// Procedural materials turned by this angle about the plane's normal,
    /// counter-clockwise seen from above (plane +x towards +y), degrees: the pattern
    /// and the anisotropy (brushed metal's grooves) turn together, as a sheet laid at
    /// an angle to the markers would. 0: grooves along plane x.
    #[serde(default)]
    pub grain_angle_deg: f64,
    /// Markers.
    pub markers: MarkerSpec,
    /// Flash video camera.
    pub video: VideoSpec,
    /// Hand motion.
    pub sweep: SweepSpec,
    /// Reference photo.
    pub reference: ReferenceSpec,
    /// Light and sensor.
    pub light: LightSpec,
    /// Every n-th frame goes into the ground-truth registered capture (paper: 5).
    pub frame_step: u32,
    /// Optional second camera.
    pub second_camera: Option<SecondCameraSpec>,
    /// Optional flash photos (`photos/`), each with all four markers in view.
    #[serde(default)]
    pub photos: Option<PhotoSpec>,
    /// Held-out light positions, cm (never visited by the flash).
    pub holdout_lights_cm: Vec<[f64; 3]>,
    /// Held-out overhead camera position, cm.
    pub holdout_camera_cm: [f64; 3],
    /// Reflectance model the scene is rendered with: Ward (the fit's default model)
    /// or GGX (to measure what fitting Ward to another model's material costs). The
    /// material's parameters are used as they are (GGX: `rho_s` is F0).
    #[serde(default)]
    pub brdf: ModelKind,
}

impl Default for SynthConfig {
    fn default() -> Self {
        Self::tiny()
    }
}

impl SynthConfig {
    /// Check every number; the error names the setting and its accepted range.
    pub fn validate(&self) -> Result<(), SynthError> {
        fn pos(what: &str, v: f64, unit: &str) -> Result<(), SynthError> {
            if v > 0.0 && v.is_finite() {
                Ok(())
            } else {
                Err(SynthError::invalid(
                    what,
                    v,
                    format!("{unit}, greater than 0"),
                ))
            }
        }
        fn fov(what: &str, v: f64) -> Result<(), SynthError> {
            if v > 0.0 && v < 180.0 {
                Ok(())
            } else {
                Err(SynthError::invalid(
                    what,
                    v,
                    "degrees, in the open range (0, 180)",
                ))
            }
        }
        fn size(what: &str, w: u32, h: u32) -> Result<(), SynthError> {
            if (16..=8192).contains(&w) && (16..=8192).contains(&h) {
                Ok(())
            } else {
                Err(SynthError::invalid(
                    what,
                    format!("{w}x{h}"),
                    "pixels, each side in [16, 8192]",
                ))
            }
        }
        pos("region width", self.region_cm[0], "cm")?;
        pos("region height", self.region_cm[1], "cm")?;
        pos("map resolution", self.map_px_per_cm, "pixels per cm")?;
        if !(self.grain_angle_deg.is_finite() && self.grain_angle_deg.abs() <= 360.0) {
            return Err(SynthError::invalid(
                "grain angle",
                self.grain_angle_deg,
                "degrees, in [-360, 360]",
            ));
        }
        if self.region_cm[0] * self.map_px_per_cm > 16384.0
            || self.region_cm[1] * self.map_px_per_cm > 16384.0
        {
            return Err(SynthError::invalid(
                "map size",
                format!(
                    "{:.0} px",
                    self.region_cm[0].max(self.region_cm[1]) * self.map_px_per_cm
                ),
                "at most 16384 px per side (lower --map-px-per-cm)",
            ));
        }
        pos("feature size", self.feature_cm, "cm")?;
        pos("marker size", self.markers.size_cm, "cm")?;
        if !(self.markers.paper_margin_cm >= 0.0) {
            return Err(SynthError::invalid(
                "paper margin",
                self.markers.paper_margin_cm,
                "cm, >= 0",
            ));
        }
        let v = &self.video;
        size("video size", v.width, v.height)?;
        fov("video field of view", v.fov_deg)?;
        pos("frame rate", v.fps, "frames per second")?;
        pos("duration", v.duration_s, "seconds")?;
        if v.fps * v.duration_s > 100_000.0 {
            return Err(SynthError::invalid(
                "frame count",
                v.fps * v.duration_s,
                "at most 100000 frames",
            ));
        }
        if !(v.k1.abs() < 0.5 && v.k2.abs() < 0.5) {
            return Err(SynthError::invalid(
                "distortion",
                format!("k1={} k2={}", v.k1, v.k2),
                "|k1|, |k2| < 0.5",
            ));
        }
        if !(v.frame_jitter_s >= 0.0 && v.frame_jitter_s < 0.4 / v.fps) {
            return Err(SynthError::invalid(
                "frame jitter",
                v.frame_jitter_s,
                format!(
                    "seconds in [0, {:.4}) (less than 0.4 frame intervals)",
                    0.4 / v.fps
                ),
            ));
        }
        if v.also_formats.contains(&v.format)
            || (1..v.also_formats.len()).any(|k| v.also_formats[..k].contains(&v.also_formats[k]))
        {
            return Err(SynthError::invalid(
                "extra video formats",
                v.also_formats
                    .iter()
                    .map(|f| f.name())
                    .collect::<Vec<_>>()
                    .join(","),
                format!(
                    "formats other than the main one ({}), each once",
                    v.format.name()
                ),
            ));
        }
        if !v.also_formats.is_empty() && (self.second_camera.is_some() || self.photos.is_some()) {
            // The extra folders hold the flash video only; a second camera's video or
            // the photos would be missing from them.
            return Err(SynthError::invalid(
                "extra video formats",
                "with a second camera or flash photos",
                "a flash video alone (render those captures once per format)",
            ));
        }
        if let Some(ae) = &v.auto_exposure {
            if !(ae.target > 0.0 && ae.target < 1.0) {
                return Err(SynthError::invalid(
                    "auto-exposure target",
                    ae.target,
                    "a mean linear level in (0, 1)",
                ));
            }
            if !(ae.lag_s >= 0.0 && ae.lag_s <= 10.0) {
                return Err(SynthError::invalid(
                    "auto-exposure lag",
                    ae.lag_s,
                    "seconds in [0, 10]",
                ));
            }
            if !(0.0..=3.0).contains(&ae.wander_ev) {
                return Err(SynthError::invalid(
                    "auto-exposure wander",
                    ae.wander_ev,
                    "stops in [0, 3]",
                ));
            }
            if !(ae.max_ev > 0.0 && ae.max_ev <= 6.0) {
                return Err(SynthError::invalid(
                    "auto-exposure range",
                    ae.max_ev,
                    "stops in (0, 6]",
                ));
            }
        }
        if !(0.0..0.2).contains(&v.breathing) {
            return Err(SynthError::invalid(
                "breathing",
                v.breathing,
                "a relative change in [0, 0.2)",
            ));
        }
        let s = &self.sweep;
        pos("minimum distance", s.distance_min_cm, "cm")?;
        pos("maximum distance", s.distance_max_cm, "cm")?;
        if s.distance_max_cm < s.distance_min_cm {
            return Err(SynthError::invalid(
                "maximum distance",
                s.distance_max_cm,
                format!("cm, at least the minimum distance {}", s.distance_min_cm),
            ));
        }
        if !(s.reach > 0.0 && s.reach <= 1.5) {
            return Err(SynthError::invalid(
                "sweep reach",
                s.reach,
                "a fraction of the region's half-size in (0, 1.5]",
            ));
        }
        if !(0.0..=1.0).contains(&s.motion_blur_probability) {
            return Err(SynthError::invalid(
                "motion blur probability",
                s.motion_blur_probability,
                "a probability in [0, 1]",
            ));
        }
        if !(s.tilt_jitter_deg >= 0.0 && s.tilt_jitter_deg < 30.0) {
            return Err(SynthError::invalid(
                "tilt jitter",
                s.tilt_jitter_deg,
                "degrees, in [0, 30)",
            ));
        }
        let r = &self.reference;
        size("reference size", r.width, r.height)?;
        fov("reference field of view", r.fov_deg)?;
        pos("reference distance", r.distance_cm, "cm")?;
        if !(r.tilt_deg.abs() < 30.0) {
            return Err(SynthError::invalid(
                "reference tilt",
                r.tilt_deg,
                "degrees, |tilt| < 30",
            ));
        }
        if !(1..=100).contains(&r.jpeg_quality) {
            return Err(SynthError::invalid(
                "JPEG quality",
                r.jpeg_quality,
                "1 to 100",
            ));
        }
        if !(1..=8).contains(&r.supersample) {
            return Err(SynthError::invalid(
                "supersampling",
                r.supersample,
                "1 to 8 samples per axis",
            ));
        }
        let l = &self.light;
        pos("flash intensity", l.flash_intensity, "linear value * cm^2")?;
        for (what, val) in [
            ("ambient", l.ambient),
            ("reference ambient", l.reference_ambient),
            ("shot noise", l.shot_noise),
            ("read noise", l.read_noise),
        ] {
            if !(val >= 0.0 && val.is_finite()) {
                return Err(SynthError::invalid(what, val, ">= 0"));
            }
        }
        if self.frame_step == 0 {
            return Err(SynthError::invalid("frame step", 0, "at least 1"));
        }
        if let Some(p) = &self.photos {
            if p.count < 2 || p.count > 200 {
                return Err(SynthError::invalid(
                    "photo count",
                    p.count,
                    "2 to 200 photos",
                ));
            }
            size("photo size", p.width, p.height)?;
            fov("photo field of view", p.fov_deg)?;
            pos("photo distance", p.distance_cm[0], "cm")?;
            if !(p.distance_cm[1] >= p.distance_cm[0]) {
                return Err(SynthError::invalid(
                    "photo distance range",
                    format!("{:?}", p.distance_cm),
                    "cm, [closest, farthest] with closest <= farthest",
                ));
            }
        }
        if let Some(c) = &self.second_camera {
            size("second camera size", c.width, c.height)?;
            fov("second camera field of view", c.fov_deg)?;
            pos("second camera frame rate", c.fps, "frames per second")?;
            pos("second camera distance", c.distance_cm, "cm")?;
            if !(c.oblique_deg >= 0.0 && c.oblique_deg < 80.0) {
                return Err(SynthError::invalid(
                    "second camera angle",
                    c.oblique_deg,
                    "degrees from the normal, in [0, 80)",
                ));
            }
            if !(c.lead_s >= 0.0 && c.lead_s < v.duration_s) {
                return Err(SynthError::invalid(
                    "second camera lead",
                    c.lead_s,
                    "seconds, in [0, duration)",
                ));
            }
            if !(c.readout_s >= 0.0 && c.readout_s < 1.0 / c.fps) {
                return Err(SynthError::invalid(
                    "rolling-shutter readout",
                    c.readout_s,
                    "seconds, in [0, 1/fps)",
                ));
            }
        }
        for p in &self.holdout_lights_cm {
            if !(p[2] > 0.0) {
                return Err(SynthError::invalid(
                    "held-out light height",
                    p[2],
                    "cm above the plane, > 0",
                ));
            }
        }
        pos("held-out camera height", self.holdout_camera_cm[2], "cm")?;
        if let MaterialSource::Procedural(name) = &self.material {
            if !MATERIALS.contains(&name.as_str()) {
                return Err(SynthError::invalid(
                    "material",
                    format!("{name:?}"),
                    format!("one of {}", MATERIALS.join(", ")),
                ));
            }
        }
        Ok(())
    }
}

impl Default for LightSpec {
    fn default() -> Self {
        Self {
            // White paper (rho_d 0.8) at 10 cm reads about 0.8 linear: bright but below clipping.
            flash_intensity: 320.0,
            flash_offset_cm: [1.4, -0.3, 0.0],
            ambient: 0.03,
            reference_ambient: 0.7,
            shot_noise: 4e-4,
            read_noise: 2e-3,
        }
    }
}

/// Oblique held-out lights: 20-25 cm from the centre at 30-50 degrees above the plane,
/// far from the flash's near-overhead positions.
pub(crate) fn default_holdout_lights() -> Vec<[f64; 3]> {
    [
        (0.0, 35.0, 22.0),
        (90.0, 45.0, 20.0),
        (200.0, 30.0, 25.0),
        (300.0, 50.0, 20.0),
    ]
    .iter()
    .map(|&(az, el, d): &(f64, f64, f64)| {
        let (az, el) = (az.to_radians(), el.to_radians());
        [
            d * el.cos() * az.cos(),
            d * el.cos() * az.sin(),
            d * el.sin(),
        ]
    })
    .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn presets_validate_and_bad_values_are_named() {
        for p in PRESETS {
            SynthConfig::preset(p).unwrap().validate().unwrap();
        }
        assert!(SynthConfig::preset("huge")
            .unwrap_err()
            .to_string()
            .contains("\"huge\""));
        let mut c = SynthConfig::tiny();
        c.video.fps = 0.0;
        let e = c.validate().unwrap_err().to_string();
        assert!(
            e.contains("frame rate 0") && e.contains("greater than 0"),
            "{e}"
        );
        let mut c = SynthConfig::tiny();
        c.video.fov_deg = 180.0;
        assert!(c.validate().unwrap_err().to_string().contains("(0, 180)"));
        let mut c = SynthConfig::tiny();
        c.sweep.distance_min_cm = -3.0;
        assert!(c
            .validate()
            .unwrap_err()
            .to_string()
            .contains("minimum distance -3"));
    }
}
