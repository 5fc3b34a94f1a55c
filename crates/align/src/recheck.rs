//! Checking a registered capture after the fact (`svbrdf check`): every frame of a
//! capture folder (written by `align` or `import`, or edited by hand) is compared with
//! the reference photo by the same self-check that alignment runs before it writes
//! (see [`crate::selfcheck`]). A frame whose mapping disagrees with what the reference
//! photo shows of the same plane points is named with its offset.

use std::path::Path;

use svbrdf_core::capture::{PreparedMapping, RegisteredCapture};
use svbrdf_core::color::Srgb8Encoder;
use svbrdf_core::image::{FrameImage, ImageU8};
use svbrdf_core::progress::Progress;

use crate::selfcheck::{self, CheckedFrame, FrameCheck};
use crate::{AlignConfig, AlignError};

/// The outcome of checking a capture.
#[derive(Debug, Clone)]
pub struct CaptureCheck {
    /// One check per frame of the capture, in the capture's frame order
    /// (`kept_index` is the position in `capture.json`'s `frames`).
    pub frames: Vec<FrameCheck>,
    /// Offset (mm) beyond which a frame counts as inconsistent.
    pub limit_mm: f64,
}

impl CaptureCheck {
    /// Frame numbers (video frame index, or position for photos) of the frames that
    /// disagree with the reference photo.
    pub fn inconsistent(&self) -> Vec<u64> {
        self.frames
            .iter()
            .filter(|c| c.inconsistent(self.limit_mm))
            .map(|c| c.frame)
            .collect()
    }

    /// Frames no block of which matched the reference photo clearly.
    pub fn unverified(&self) -> usize {
        self.frames
            .iter()
            .filter(|c| c.offset_mm().is_none())
            .count()
    }
}

/// Compare every frame of the registered capture in `capture_dir` with the reference
/// photo at `reference` (whose markers define the world frame, as in `align`).
pub fn check_capture(
    capture_dir: &Path,
    reference: &Path,
    cfg: &AlignConfig,
    progress: &dyn Progress,
) -> Result<CaptureCheck, AlignError> {
    cfg.validate()?;
    let (capture, dir) = RegisteredCapture::load_with_folder(capture_dir)?;
    let dict = svbrdf_cv::aruco::Dictionary::from_name(&cfg.camera.marker_dictionary)?;
    let (ref_img, frame) = crate::reference_photo(reference, cfg, dict)?;
    progress.stage("decode", capture.frames.len() as u64);
    let mut thumbs: Vec<Option<ImageU8>> = vec![None; capture.frames.len()];
    let enc = Srgb8Encoder::new();
    svbrdf_cv::capture::decode_frames(&capture, &dir, &mut |k, img| -> Result<(), AlignError> {
        let rgb = match img {
            FrameImage::Srgb8(img) => img,
            FrameImage::Linear(img) => ImageU8 {
                width: img.width,
                height: img.height,
                channels: img.channels,
                data: img.data.iter().map(|&v| enc.encode(f64::from(v))).collect(),
            },
        };
        let thumb = svbrdf_cv::video::luma_frame_of(&rgb, crate::frames::THUMB_LONG)?.thumb;
        if let Some(slot) = thumbs.get_mut(k) {
            *slot = Some(thumb);
        }
        progress.advance(1);
        Ok(())
    })?;
    progress.finish();
    let mut frames = Vec::with_capacity(capture.frames.len());
    for (k, (f, thumb)) in capture.frames.iter().zip(&thumbs).enumerate() {
        let Some(thumb) = thumb else {
            return Err(AlignError::invalid(
                "frame",
                format!("{} of {}", k, capture_dir.display()),
                "a frame its source can provide",
            ));
        };
        frames.push(CheckedFrame {
            frame: f.frame_index.unwrap_or(k as u64),
            stream: capture.sources.get(f.source).map_or(0, |s| s.stream),
            thumb,
            width: f.width,
            mapping: PreparedMapping::new(f)?,
        });
    }
    progress.stage("self-check", 1);
    let checks = selfcheck::check(&ref_img, &frame.plane_from_pixel, capture.region, &frames);
    progress.finish();
    Ok(CaptureCheck {
        frames: checks,
        limit_mm: cfg.self_check.max_shift_mm,
    })
}
