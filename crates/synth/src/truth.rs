//! The ground-truth file `ground_truth/truth.json` written next to each capture.

use serde::{Deserialize, Serialize};
use svbrdf_core::geometry::{Intrinsics, RadialDistortion};
use svbrdf_core::plane::Region;

use crate::config::SynthConfig;

/// Value of the `format` field.
pub const TRUTH_FORMAT: &str = "svbrdf-synth-ground-truth";

/// Everything the simulator knows about a capture it rendered.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct GroundTruth {
    /// Always [`TRUTH_FORMAT`].
    pub format: String,
    /// Format version (1).
    pub version: u32,
    /// Length unit of every position: `"cm"`.
    pub units: String,
    /// The settings used.
    pub config: SynthConfig,
    /// The material region (cm).
    pub region: Region,
    /// Light intensity `I` of eq. (9) (linear pixel value * cm^2), all channels.
    pub light_intensity: f64,
    /// Ambient term added during the video (`ambient * rho_d`, linear).
    pub ambient: f64,
    /// The markers.
    pub markers: Vec<MarkerTruth>,
    /// The reference photo.
    pub reference: ReferenceTruth,
    /// Video streams: index 0 is the flash camera, 1 the optional second camera.
    pub streams: Vec<StreamTruth>,
    /// Map files, relative to `ground_truth/`.
    pub maps: MapFiles,
    /// Held-out relighting images.
    pub holdout: Vec<HoldoutTruth>,
    /// Flash photos (`photos/photo_NN.jpg`), if rendered; `index` is NN, `time_s` 0.
    #[serde(default)]
    pub photos: Vec<FrameTruth>,
}

/// One marker.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct MarkerTruth {
    /// Id.
    pub id: i32,
    /// Corners in world cm (z = 0), OpenCV order.
    pub corners_cm: [[f64; 3]; 4],
}

/// A camera pose for one image.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct CameraTruth {
    /// Intrinsics.
    pub intrinsics: Intrinsics,
    /// Radial distortion.
    pub distortion: RadialDistortion,
    /// world_from_camera rotation, row-major.
    pub rotation: [[f64; 3]; 3],
    /// Camera centre, cm.
    pub position: [f64; 3],
}

/// The reference photo.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct ReferenceTruth {
    /// File name in the capture folder.
    pub file: String,
    /// Camera.
    pub camera: CameraTruth,
    /// Projected marker corners, pixels (centres at integers), per marker id.
    pub marker_corners_px: Vec<(i32, [[f64; 2]; 4])>,
}

/// One video stream.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct StreamTruth {
    /// File name in the capture folder.
    pub file: String,
    /// Whether this camera's flash is on.
    pub flash: bool,
    /// Frames per second.
    pub fps: f64,
    /// Width, pixels.
    pub width: u32,
    /// Height, pixels.
    pub height: u32,
    /// Time of this stream's frame 0 on the flash camera's clock, seconds (negative: the
    /// stream started earlier).
    pub start_time_s: f64,
    /// First frame in which the flash light is visible (rolling-shutter onset), if any.
    pub flash_onset_frame: Option<u64>,
    /// Per-frame truth.
    pub frames: Vec<FrameTruth>,
}

/// One video frame.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct FrameTruth {
    /// Frame index.
    pub index: u64,
    /// Time on the flash camera's clock, seconds (mid-exposure).
    pub time_s: f64,
    /// Camera at mid-exposure.
    pub camera: CameraTruth,
    /// Flash position at mid-exposure, cm, if the flash lights this frame.
    pub light_position: Option<[f64; 3]>,
    /// First lit row when the flash turns on during this frame's readout.
    pub first_lit_row: Option<u32>,
    /// Whether the frame was rendered with motion blur.
    pub motion_blur: bool,
    /// Ids of markers whose four corners are inside the frame.
    pub markers_visible: Vec<i32>,
    /// Exposure gain the frame was recorded at (auto-exposure; 1 when locked).
    #[serde(default = "unit_gain")]
    pub exposure_gain: f64,
}

fn unit_gain() -> f64 {
    1.0
}

/// File name, inside `photos/`, of the simulator's flash photo `index`.
pub fn photo_file(index: u64) -> String {
    format!("photo_{index:02}.jpg")
}

/// Map file names.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct MapFiles {
    /// Resolution, pixels per cm.
    pub px_per_cm: f64,
    /// Diffuse albedo: linear EXR (R, G, B).
    pub diffuse: String,
    /// Specular albedo: linear EXR.
    pub specular: String,
    /// Roughness: linear EXR (R = alpha_x, G = alpha_y, B = tangent rotation in turns).
    pub roughness: String,
    /// Tangent-space normal: linear EXR holding x, y, z in [-1, 1].
    pub normal: String,
    /// 1 where material is visible, 0 where marker paper covers it: linear EXR (R = G = B).
    pub mask: String,
}

/// One held-out relighting image, rectified to the map grid.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct HoldoutTruth {
    /// Linear EXR file (relative to `ground_truth/`).
    pub exr: String,
    /// sRGB PNG preview.
    pub png: String,
    /// Light position, cm.
    pub light_position: [f64; 3],
    /// Camera position, cm (each pixel is viewed from here).
    pub camera_position: [f64; 3],
}
