//! `camera.json`: what the paper measures once per phone. Written by the simulator,
//! read by alignment. Missing fields take the paper's values.

use std::path::Path;

use serde::{Deserialize, Serialize};

use crate::CoreError;

/// The phone description.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct CameraDescription {
    /// Field of view across the longer image side, degrees (paper: 70).
    pub fov_deg: f64,
    /// Flash position in the camera frame (x right, y down, z forward), cm
    /// (paper: [1.4, -0.3, 0]).
    pub flash_offset_cm: [f64; 3],
    /// Side of the printed black marker square, cm (paper: 1.6).
    pub marker_size_cm: f64,
    /// OpenCV marker dictionary name (paper: DICT_6X6_250).
    pub marker_dictionary: String,
    /// Keep every n-th video frame (paper: 5 for the flash video; 10 for both streams
    /// of a two-camera capture).
    pub frame_step: u32,
    /// Rolling-shutter readout time, top row to bottom row, seconds; 0 when unknown.
    /// Only the two-camera synchronisation uses it, to place the flash onset within
    /// a frame.
    pub readout_s: f64,
}

impl Default for CameraDescription {
    fn default() -> Self {
        Self {
            fov_deg: 70.0,
            flash_offset_cm: [1.4, -0.3, 0.0],
            marker_size_cm: 1.6,
            marker_dictionary: "DICT_6X6_250".into(),
            frame_step: 5,
            readout_s: 0.0,
        }
    }
}

impl CameraDescription {
    /// Read and validate `camera.json`.
    pub fn load(path: &Path) -> Result<Self, CoreError> {
        let c: Self = crate::fsutil::read_json_settings(path)?;
        c.validate()
            .map_err(|e| CoreError::format(path, e.to_string()))?;
        Ok(c)
    }

    /// Check the numbers.
    pub fn validate(&self) -> Result<(), CoreError> {
        if !(self.fov_deg > 0.0 && self.fov_deg < 180.0) {
            return Err(CoreError::invalid(
                "field of view",
                self.fov_deg,
                "degrees, in (0, 180)",
            ));
        }
        if !(self.marker_size_cm > 0.0 && self.marker_size_cm.is_finite()) {
            return Err(CoreError::invalid(
                "marker size",
                self.marker_size_cm,
                "cm, > 0",
            ));
        }
        if !(self.readout_s >= 0.0 && self.readout_s < 1.0) {
            return Err(CoreError::invalid(
                "rolling-shutter readout",
                self.readout_s,
                "seconds, in [0, 1)",
            ));
        }
        if self.frame_step == 0 {
            return Err(CoreError::invalid("frame step", 0, "at least 1"));
        }
        if !self
            .flash_offset_cm
            .iter()
            .all(|v| v.is_finite() && v.abs() < 50.0)
        {
            return Err(CoreError::invalid(
                "flash offset",
                format!("{:?}", self.flash_offset_cm),
                "cm, each |v| < 50",
            ));
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn missing_fields_take_paper_values_and_bad_ones_are_named() {
        let c: CameraDescription = serde_json::from_str(r#"{"fov_deg": 65}"#).unwrap();
        assert_eq!(c.marker_size_cm, 1.6);
        assert_eq!(c.frame_step, 5);
        let bad = CameraDescription {
            fov_deg: 190.0,
            ..CameraDescription::default()
        };
        assert!(bad
            .validate()
            .unwrap_err()
            .to_string()
            .contains("field of view 190"));
    }
}
