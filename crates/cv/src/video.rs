//! Video decoding and encoding through OpenCV's FFmpeg backend.
//!
//! Decoding is a stream: one frame in memory at a time. Frames come out upright
//! (rotation metadata applied) as 8-bit sRGB-encoded RGB.

use std::path::{Path, PathBuf};

use opencv::core::{Mat, Size};
use opencv::prelude::*;
use opencv::videoio;
use svbrdf_core::image::ImageU8;

use crate::{mat_to_rgb, rgb_to_mat, Context, CvError};

/// Stream properties reported by the container.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VideoInfo {
    /// Width after rotation, pixels.
    pub width: u32,
    /// Height after rotation, pixels.
    pub height: u32,
    /// Frames per second.
    pub fps: f64,
    /// Frame count as the container states it (may be an estimate for some files).
    pub frame_count: u64,
}

/// A streaming video decoder.
pub struct VideoReader {
    probe: crate::probe::VideoProbe,
    cap: videoio::VideoCapture,
    path: PathBuf,
    info: VideoInfo,
    next_index: u64,
    frame: Mat,
    pending: Option<ImageU8>,
}

impl VideoReader {
    /// Open a video file.
    pub fn open(path: &Path) -> Result<Self, CvError> {
        if !path.is_file() {
            return Err(CvError::File {
                path: path.into(),
                message: "no such video file".into(),
            });
        }
        if std::fs::metadata(path)
            .map(|m| m.len() == 0)
            .unwrap_or(false)
        {
            return Err(CvError::File {
                path: path.into(),
                message: "the video file is empty".into(),
            });
        }
        let probe = crate::probe::probe_video(path)?;
        probe.check_supported(path)?;
        let name = path.to_string_lossy().into_owned();
        let mut cap = videoio::VideoCapture::from_file(&name, videoio::CAP_FFMPEG)
            .ctx(|| format!("opening {name}"))?;
        if !cap.is_opened().ctx(|| format!("opening {name}"))? {
            return Err(CvError::File {
                path: path.into(),
                message: "OpenCV/FFmpeg cannot decode this video".into(),
            });
        }
        // Phone videos are stored landscape with a rotation tag; we want upright frames.
        let _ = cap.set(videoio::CAP_PROP_ORIENTATION_AUTO, 1.0);
        let get = |cap: &videoio::VideoCapture, p: i32| {
            cap.get(p).ctx(|| format!("reading properties of {name}"))
        };
        let info = VideoInfo {
            width: get(&cap, videoio::CAP_PROP_FRAME_WIDTH)? as u32,
            height: get(&cap, videoio::CAP_PROP_FRAME_HEIGHT)? as u32,
            fps: get(&cap, videoio::CAP_PROP_FPS)?,
            frame_count: get(&cap, videoio::CAP_PROP_FRAME_COUNT)?.max(0.0) as u64,
        };
        let mut reader = Self {
            probe,
            cap,
            path: path.into(),
            info,
            next_index: 0,
            frame: Mat::default(),
            pending: None,
        };
        // The container's size ignores rotation metadata while decoded frames honour it,
        // so take the size from the first frame (kept for the first `read`).
        let first = reader.decode()?.ok_or_else(|| CvError::File {
            path: path.into(),
            message: "the video has no decodable frames".into(),
        })?;
        reader.info.width = first.width as u32;
        reader.info.height = first.height as u32;
        reader.pending = Some(first);
        Ok(reader)
    }

    /// Decode the next frame into `self.frame`; `false` at the end of the stream.
    fn decode_mat(&mut self) -> Result<bool, CvError> {
        let ok = self
            .cap
            .read(&mut self.frame)
            .ctx(|| format!("decoding {}", self.path.display()))?;
        Ok(ok && !self.frame.empty())
    }

    fn decode(&mut self) -> Result<Option<ImageU8>, CvError> {
        if !self.decode_mat()? {
            return Ok(None);
        }
        mat_to_rgb(&self.frame).map(Some)
    }

    /// Stream properties.
    pub fn info(&self) -> VideoInfo {
        self.info
    }

    /// The stream's description as FFmpeg read it (codec, colour tags, frame count).
    pub fn probe(&self) -> &crate::probe::VideoProbe {
        &self.probe
    }

    /// Refuse a stream that ended early: after the last frame was read, fewer frames
    /// decoded than the file holds (truncated, or damaged in the middle).
    pub fn check_complete(&self) -> Result<(), CvError> {
        let decoded = self.next_index;
        if let Some(expected) = self.probe.expected_frames() {
            let tolerance = (expected / 100).max(2);
            if decoded + tolerance < expected {
                return Err(CvError::File {
                    path: self.path.clone(),
                    message: format!(
                        "only {decoded} of its {expected} frames decode (the file is truncated or damaged after frame {decoded}; expected a complete video: copy it from the phone again)"
                    ),
                });
            }
        }
        Ok(())
    }

    /// Index of the frame the next [`read`](Self::read) returns.
    pub fn next_index(&self) -> u64 {
        self.next_index
    }

    /// Decode and drop the next frame without converting it (for skipping).
    pub fn skip(&mut self) -> Result<bool, CvError> {
        if self.pending.take().is_some() {
            self.next_index += 1;
            return Ok(true);
        }
        let ok = self
            .cap
            .grab()
            .ctx(|| format!("decoding {}", self.path.display()))?;
        if ok {
            self.next_index += 1;
        }
        Ok(ok)
    }

    /// The next frame, or `None` at the end of the stream.
    pub fn read(&mut self) -> Result<Option<ImageU8>, CvError> {
        let frame = match self.pending.take() {
            Some(f) => Some(f),
            None => self.decode()?,
        };
        if frame.is_some() {
            self.next_index += 1;
        }
        Ok(frame)
    }

    /// The next frame as luminance and a colour thumbnail (long side `thumb_long`), or
    /// `None` at the end of the stream: the full-resolution colour image never leaves
    /// OpenCV, which saves two 25 MB copies per 4K frame.
    pub fn read_luma(&mut self, thumb_long: u32) -> Result<Option<LumaFrame>, CvError> {
        if let Some(rgb) = self.pending.take() {
            self.next_index += 1;
            return luma_frame_of(&rgb, thumb_long).map(Some);
        }
        if !self.decode_mat()? {
            return Ok(None);
        }
        self.next_index += 1;
        luma_frame_of_mat(&self.frame, thumb_long).map(Some)
    }
}

/// A decoded frame reduced to what alignment keeps of it.
#[derive(Debug, Clone)]
pub struct LumaFrame {
    /// Luminance (Rec. 601 weights of the sRGB-coded channels), one channel.
    pub luma: ImageU8,
    /// Colour thumbnail (RGB), area-averaged.
    pub thumb: ImageU8,
}

fn luma_frame_of_mat(bgr: &Mat, thumb_long: u32) -> Result<LumaFrame, CvError> {
    let mut grey = Mat::default();
    opencv::imgproc::cvt_color_def(bgr, &mut grey, opencv::imgproc::COLOR_BGR2GRAY)
        .ctx(|| "converting to grey".into())?;
    let long = bgr.cols().max(bgr.rows()).max(1);
    let s = (f64::from(thumb_long) / f64::from(long)).min(1.0);
    let mut small = Mat::default();
    opencv::imgproc::resize(
        bgr,
        &mut small,
        opencv::core::Size::new(
            ((f64::from(bgr.cols()) * s).round() as i32).max(1),
            ((f64::from(bgr.rows()) * s).round() as i32).max(1),
        ),
        0.0,
        0.0,
        opencv::imgproc::INTER_AREA,
    )
    .ctx(|| "thumbnail".into())?;
    Ok(LumaFrame {
        luma: crate::mat_to_grey(&grey)?,
        thumb: mat_to_rgb(&small)?,
    })
}

/// [`LumaFrame`] of an RGB image (still photos, or a frame already decoded).
pub fn luma_frame_of(rgb: &ImageU8, thumb_long: u32) -> Result<LumaFrame, CvError> {
    luma_frame_of_mat(&crate::rgb_to_mat(rgb)?, thumb_long)
}

/// An H.264 video encoder writing an `.mp4`.
pub struct VideoWriter {
    writer: videoio::VideoWriter,
    path: PathBuf,
    width: u32,
    height: u32,
    frames: u64,
}

impl VideoWriter {
    /// Create `path` (H.264 in MP4, fourcc `avc1`).
    pub fn create(path: &Path, fps: f64, width: u32, height: u32) -> Result<Self, CvError> {
        if !(fps > 0.0 && fps.is_finite()) {
            return Err(CvError::Invalid {
                what: "frame rate".into(),
                value: fps.to_string(),
                expected: "frames per second > 0".into(),
            });
        }
        let name = path.to_string_lossy().into_owned();
        let fourcc = videoio::VideoWriter::fourcc('a', 'v', 'c', '1').ctx(|| "fourcc".into())?;
        let size = Size::new(width as i32, height as i32);
        let writer = videoio::VideoWriter::new_with_backend(
            &name,
            videoio::CAP_FFMPEG,
            fourcc,
            fps,
            size,
            true,
        )
        .ctx(|| format!("creating {name}"))?;
        if !writer.is_opened().ctx(|| format!("creating {name}"))? {
            return Err(CvError::File {
                path: path.into(),
                message: "OpenCV/FFmpeg cannot open an H.264 (avc1) writer for this file".into(),
            });
        }
        Ok(Self {
            writer,
            path: path.into(),
            width,
            height,
            frames: 0,
        })
    }

    /// Append a frame (must match the size given at creation).
    pub fn write(&mut self, img: &ImageU8) -> Result<(), CvError> {
        if img.width != self.width as usize || img.height != self.height as usize {
            return Err(CvError::Invalid {
                what: "frame size".into(),
                value: format!("{}x{}", img.width, img.height),
                expected: format!("{}x{} as the video was created", self.width, self.height),
            });
        }
        let mat = rgb_to_mat(img)?;
        self.writer
            .write(&mat)
            .ctx(|| format!("encoding {}", self.path.display()))?;
        self.frames += 1;
        Ok(())
    }

    /// Flush and close; returns the number of frames written.
    pub fn finish(mut self) -> Result<u64, CvError> {
        self.writer
            .release()
            .ctx(|| format!("closing {}", self.path.display()))?;
        Ok(self.frames)
    }
}
