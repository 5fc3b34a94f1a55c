//! Video decoding and encoding.
//!
//! Decoding is a stream: one frame in memory at a time. Frames come out upright
//! (rotation metadata applied). 8-bit SDR video is decoded by OpenCV's FFmpeg backend
//! to 8-bit sRGB-coded RGB (with the stream's BT.709 matrix corrected for); 10-bit
//! and HDR video (HLG, PQ, BT.2020) by FFmpeg's libraries directly (`svbrdf-av`) to
//! linear RGB floats, so their extra precision and headroom reach the observations.

use std::path::{Path, PathBuf};

use opencv::core::{Mat, Size};
use opencv::prelude::*;
use opencv::videoio;
use svbrdf_core::color::{Srgb8Encoder, YcbcrMatrix};
use svbrdf_core::image::{FrameImage, ImageF32, ImageU8};

use crate::probe::DecodingMatrix;
use crate::{mat_to_rgb, rgb_to_mat, Context, CvError};

/// Stream properties reported by the container.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VideoInfo {
    /// Width after rotation, pixels.
    pub width: u32,
    /// Height after rotation, pixels.
    pub height: u32,
    /// Frames per second (the average, for variable frame rates).
    pub fps: f64,
    /// Frame count as the container states it (may be an estimate for some files).
    pub frame_count: u64,
}

/// Which decoder a reader uses.
enum Backend {
    /// OpenCV's FFmpeg backend (8-bit SDR).
    OpenCv {
        cap: videoio::VideoCapture,
        /// Colour correction after OpenCV's conversion (BGR order), where the stream's
        /// Y'CbCr matrix is not the BT.601 one OpenCV applies whatever the tags say.
        fix: Option<Mat>,
        frame: Mat,
    },
    /// FFmpeg's libraries (10-bit, HDR).
    Av {
        reader: Box<svbrdf_av::AvReader>,
        /// Linear level shown as white in the 8-bit pictures alignment works on.
        white: f64,
    },
}

/// A streaming video decoder.
pub struct VideoReader {
    probe: crate::probe::VideoProbe,
    backend: Backend,
    path: PathBuf,
    info: VideoInfo,
    next_index: u64,
    /// Time of the last frame returned, seconds.
    time_s: f64,
    pending: Option<(FrameImage, f64)>,
    encoder: Srgb8Encoder,
    /// OpenCV's timestamp of the first frame, seconds.
    opencv_t0: f64,
}

fn av_error(e: svbrdf_av::AvError) -> CvError {
    match e {
        svbrdf_av::AvError::File { path, message } => CvError::File { path, message },
    }
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
        let mut info = VideoInfo {
            width: 0,
            height: 0,
            fps: 0.0,
            frame_count: 0,
        };
        let backend = if probe.needs_linear_decoding() {
            let reader = svbrdf_av::AvReader::open(path).map_err(av_error)?;
            let i = reader.info();
            info.fps = i.fps;
            info.frame_count = i.stated_frames;
            Backend::Av {
                white: i.transfer.reference_white(),
                reader: Box::new(reader),
            }
        } else {
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
            info.fps = get(&cap, videoio::CAP_PROP_FPS)?;
            info.frame_count = get(&cap, videoio::CAP_PROP_FRAME_COUNT)?.max(0.0) as u64;
            let fix = match probe.decoding_matrix() {
                DecodingMatrix::Bt709 => Some(bgr_matrix(&svbrdf_core::color::ycbcr_matrix_fix(
                    YcbcrMatrix::BT709,
                    YcbcrMatrix::BT601,
                ))?),
                DecodingMatrix::Bt601 | DecodingMatrix::Bt2020 => None,
            };
            Backend::OpenCv {
                cap,
                fix,
                frame: Mat::default(),
            }
        };
        let mut reader = Self {
            probe,
            backend,
            path: path.into(),
            info,
            next_index: 0,
            time_s: 0.0,
            pending: None,
            encoder: Srgb8Encoder::new(),
            opencv_t0: 0.0,
        };
        // The container's size ignores rotation metadata while decoded frames honour it,
        // so take the size from the first frame (kept for the first `read`).
        let first = reader.decode()?.ok_or_else(|| CvError::File {
            path: path.into(),
            message: "the video has no decodable frames".into(),
        })?;
        let (w, h, _) = first.0.shape();
        reader.info.width = w as u32;
        reader.info.height = h as u32;
        reader.pending = Some(first);
        Ok(reader)
    }

    /// Decode the next frame into the OpenCV backend's `frame`; `false` at the end.
    fn decode_mat(&mut self) -> Result<bool, CvError> {
        let Backend::OpenCv { cap, fix, frame } = &mut self.backend else {
            return Ok(false);
        };
        let ok = cap
            .read(frame)
            .ctx(|| format!("decoding {}", self.path.display()))?;
        let ok = ok && !frame.empty();
        if let (true, Some(m)) = (ok, fix.as_ref()) {
            let mut fixed = Mat::default();
            opencv::core::transform(&*frame, &mut fixed, m)
                .ctx(|| format!("converting colours of {}", self.path.display()))?;
            *frame = fixed;
        }
        Ok(ok)
    }

    /// The next frame as decoded and its time, or `None` at the end.
    fn decode(&mut self) -> Result<Option<(FrameImage, f64)>, CvError> {
        match &mut self.backend {
            Backend::Av { reader, .. } => Ok(reader
                .read()
                .map_err(av_error)?
                .map(|f| (FrameImage::Linear(f.rgb), f.time_s))),
            Backend::OpenCv { .. } => {
                if !self.decode_mat()? {
                    return Ok(None);
                }
                let t = self.opencv_frame_time();
                let Backend::OpenCv { frame, .. } = &self.backend else {
                    return Ok(None);
                };
                Ok(Some((FrameImage::Srgb8(mat_to_rgb(frame)?), t)))
            }
        }
    }

    /// The OpenCV backend's time of the frame just decoded (index `next_index`),
    /// seconds from the first frame, from its timestamp. At the end of some streams
    /// OpenCV reports 0: a time not after the last frame's is replaced by the last
    /// one plus a frame interval.
    fn opencv_frame_time(&mut self) -> f64 {
        let Backend::OpenCv { cap, .. } = &self.backend else {
            return self.time_s;
        };
        let ms = cap
            .get(videoio::CAP_PROP_POS_MSEC)
            .ok()
            .filter(|ms| ms.is_finite());
        if self.next_index == 0 {
            self.opencv_t0 = ms.map_or(0.0, |ms| ms / 1000.0);
            return 0.0;
        }
        ms.map(|ms| ms / 1000.0 - self.opencv_t0)
            .filter(|t| *t > self.time_s)
            .unwrap_or(self.time_s + 1.0 / self.info.fps.max(1e-9))
    }

    /// Stream properties.
    pub fn info(&self) -> VideoInfo {
        self.info
    }

    /// The stream's description as FFmpeg read it (codec, colour tags, frame count).
    pub fn probe(&self) -> &crate::probe::VideoProbe {
        &self.probe
    }

    /// How the frames are turned into linear light, for records: the transfer curve,
    /// the primaries converted from and the bits kept.
    pub fn decoding(&self) -> Decoding {
        match &self.backend {
            Backend::Av { reader, .. } => {
                let i = reader.info();
                Decoding {
                    decoder: "ffmpeg-libraries",
                    transfer: i.transfer,
                    from_bt2020: i.primaries == svbrdf_av::Primaries::Bt2020,
                    bits: i.format.bits,
                }
            }
            Backend::OpenCv { .. } => Decoding {
                decoder: "opencv",
                transfer: svbrdf_core::color::Transfer::Sdr,
                from_bt2020: false,
                bits: 8,
            },
        }
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

    /// Time of the frame last returned (or skipped), seconds from the first frame:
    /// from the stream's timestamps for video decoded by FFmpeg's libraries (variable
    /// frame rates keep their timing), else index / frame rate.
    pub fn time_s(&self) -> f64 {
        self.time_s
    }

    /// Decode and drop the next frame without converting it (for skipping).
    pub fn skip(&mut self) -> Result<bool, CvError> {
        if let Some((_, t)) = self.pending.take() {
            self.next_index += 1;
            self.time_s = t;
            return Ok(true);
        }
        let t = match &mut self.backend {
            Backend::Av { reader, .. } => reader.skip().map_err(av_error)?,
            Backend::OpenCv { cap, .. } => {
                let grabbed = cap
                    .grab()
                    .ctx(|| format!("decoding {}", self.path.display()))?;
                grabbed.then(|| self.opencv_frame_time())
            }
        };
        if let Some(t) = t {
            self.next_index += 1;
            self.time_s = t;
        }
        Ok(t.is_some())
    }

    /// The next frame as decoded: 8-bit sRGB-coded (OpenCV) or linear floats (10-bit
    /// and HDR video), or `None` at the end of the stream.
    pub fn read_image(&mut self) -> Result<Option<FrameImage>, CvError> {
        let frame = match self.pending.take() {
            Some(f) => Some(f),
            None => self.decode()?,
        };
        Ok(frame.map(|(img, t)| {
            self.next_index += 1;
            self.time_s = t;
            img
        }))
    }

    /// The next frame as 8-bit sRGB-coded RGB, or `None` at the end of the stream.
    /// Linear frames are shown with the format's reference white at 255 (HDR
    /// highlights above it clip here, not in [`read_image`](Self::read_image)).
    pub fn read(&mut self) -> Result<Option<ImageU8>, CvError> {
        let white = match &self.backend {
            Backend::Av { white, .. } => *white,
            Backend::OpenCv { .. } => 1.0,
        };
        Ok(self.read_image()?.map(|img| match img {
            FrameImage::Srgb8(i) => i,
            FrameImage::Linear(i) => self.to_srgb8(&i, white),
        }))
    }

    fn to_srgb8(&self, img: &ImageF32, white: f64) -> ImageU8 {
        let inv = 1.0 / white;
        ImageU8 {
            width: img.width,
            height: img.height,
            channels: img.channels,
            data: img
                .data
                .iter()
                .map(|v| self.encoder.encode(f64::from(*v) * inv))
                .collect(),
        }
    }

    /// The next frame as luminance and a colour thumbnail (long side `thumb_long`), or
    /// `None` at the end of the stream: the full-resolution colour image never leaves
    /// OpenCV, which saves two 25 MB copies per 4K frame.
    pub fn read_luma(&mut self, thumb_long: u32) -> Result<Option<LumaFrame>, CvError> {
        self.with_next_bgr(|bgr| luma_frame_of_mat(bgr, thumb_long))
    }

    /// The next frame as luminance only (no thumbnail), or `None` at the end of the
    /// stream: the cheapest look at a frame, for searching every frame of a video for
    /// markers.
    pub fn read_grey(&mut self) -> Result<Option<ImageU8>, CvError> {
        self.with_next_bgr(grey_of_mat)
    }

    /// `f` of the next frame as an 8-bit BGR matrix (OpenCV's own decoded frame, not a
    /// copy, where OpenCV decodes), or `None` at the end of the stream.
    fn with_next_bgr<T>(
        &mut self,
        f: impl FnOnce(&Mat) -> Result<T, CvError>,
    ) -> Result<Option<T>, CvError> {
        if self.pending.is_some() || matches!(self.backend, Backend::Av { .. }) {
            return match self.read()? {
                Some(rgb) => f(&rgb_to_mat(&rgb)?).map(Some),
                None => Ok(None),
            };
        }
        if !self.decode_mat()? {
            return Ok(None);
        }
        self.time_s = self.opencv_frame_time();
        self.next_index += 1;
        let Backend::OpenCv { frame, .. } = &self.backend else {
            return Ok(None);
        };
        f(frame).map(Some)
    }
}

/// Luminance (Rec. 601 weights) of an 8-bit BGR matrix.
fn grey_of_mat(bgr: &Mat) -> Result<ImageU8, CvError> {
    let mut grey = Mat::default();
    opencv::imgproc::cvt_color_def(bgr, &mut grey, opencv::imgproc::COLOR_BGR2GRAY)
        .ctx(|| "converting to grey".into())?;
    crate::mat_to_grey(&grey)
}

/// How a reader turns frames into linear light.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub struct Decoding {
    /// `opencv` (8-bit SDR) or `ffmpeg-libraries` (10-bit, HDR).
    pub decoder: &'static str,
    /// Transfer curve applied.
    pub transfer: svbrdf_core::color::Transfer,
    /// Whether BT.2020 primaries were converted to BT.709.
    pub from_bt2020: bool,
    /// Bits per sample kept through to the observations.
    pub bits: u32,
}

/// A 3x3 map on RGB as an OpenCV matrix acting on BGR pixels.
fn bgr_matrix(m: &svbrdf_core::geometry::Mat3) -> Result<Mat, CvError> {
    // Reverse rows and columns: BGR = P RGB with P the anti-diagonal permutation.
    let rows: Vec<Vec<f32>> = (0..3)
        .map(|r| (0..3).map(|c| m[(2 - r, 2 - c)] as f32).collect())
        .collect();
    Mat::from_slice_2d(&rows).ctx(|| "colour matrix".into())
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
    Ok(LumaFrame {
        luma: grey_of_mat(bgr)?,
        thumb: linear_thumbnail(bgr, thumb_long)?,
    })
}

/// A colour thumbnail (long side `thumb_long`) averaged in linear light and stored
/// sRGB-coded: averaging the coded values would darken textured areas the more, the
/// more texture a thumbnail pixel covers, so the same surface would look darker from
/// farther away (which the exposure estimate would take for a gain).
fn linear_thumbnail(bgr: &Mat, thumb_long: u32) -> Result<ImageU8, CvError> {
    let long = bgr.cols().max(bgr.rows()).max(1);
    let s = (f64::from(thumb_long) / f64::from(long)).min(1.0);
    let table = svbrdf_core::color::srgb8_to_linear_table();
    let lut = Mat::from_slice(&table).ctx(|| "linearisation table".into())?;
    let mut linear = Mat::default();
    opencv::core::lut(bgr, &lut, &mut linear).ctx(|| "linearising".into())?;
    let mut small = Mat::default();
    opencv::imgproc::resize(
        &linear,
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
    let small = if small.is_continuous() {
        small
    } else {
        small.try_clone().ctx(|| "thumbnail".into())?
    };
    let (w, h) = (small.cols() as usize, small.rows() as usize);
    let data: &[opencv::core::Vec3f] = small.data_typed().ctx(|| "thumbnail".into())?;
    let enc = svbrdf_core::color::Srgb8Encoder::new();
    let mut out = ImageU8::new(w, h, 3);
    for (dst, src) in out.data.chunks_exact_mut(3).zip(data) {
        // BGR in, RGB out.
        for c in 0..3 {
            dst[c] = enc.encode(f64::from(src[2 - c]));
        }
    }
    Ok(out)
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
    /// For BT.709 output: the pre-correction (BGR order) that makes OpenCV's BT.601
    /// encoder store BT.709's Y'CbCr.
    bt709: Option<Mat>,
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
            bt709: None,
        })
    }

    /// As [`create`](Self::create), but the video is BT.709 limited range, tagged so
    /// (as phones record SDR video): frames are stored with BT.709's Y'CbCr matrix.
    pub fn create_bt709(path: &Path, fps: f64, width: u32, height: u32) -> Result<Self, CvError> {
        let mut w = Self::create(path, fps, width, height)?;
        w.bt709 = Some(bgr_matrix(&svbrdf_core::color::ycbcr_matrix_fix(
            YcbcrMatrix::BT601,
            YcbcrMatrix::BT709,
        ))?);
        Ok(w)
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
        let mut mat = rgb_to_mat(img)?;
        if let Some(m) = &self.bt709 {
            // OpenCV converts with BT.601: hand it the R'G'B' whose BT.601 Y'CbCr is the
            // BT.709 Y'CbCr of the frame (rounded; saturated colours clip).
            let mut pre = Mat::default();
            opencv::core::transform(&mat, &mut pre, m)
                .ctx(|| format!("converting colours for {}", self.path.display()))?;
            mat = pre;
        }
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
        if self.bt709.is_some() {
            tag_bt709(&self.path)?;
        }
        Ok(self.frames)
    }
}

/// Tag an H.264 file as BT.709 limited range in its bitstream (FFmpeg's
/// `h264_metadata` filter; the stream is copied, not re-encoded).
fn tag_bt709(path: &Path) -> Result<(), CvError> {
    let tmp = path.with_extension("tagging.mp4");
    let out = std::process::Command::new("ffmpeg")
        .args(["-v", "error", "-nostdin", "-y", "-i"])
        .arg(path)
        .args([
            "-c",
            "copy",
            "-bsf:v",
            "h264_metadata=colour_primaries=1:transfer_characteristics=1:matrix_coefficients=1:video_full_range_flag=0",
        ])
        .arg(&tmp)
        .output()
        .map_err(|e| CvError::File {
            path: path.into(),
            message: format!("running ffmpeg to tag the video as BT.709: {e} (install Debian's ffmpeg package)"),
        })?;
    if !out.status.success() {
        let _ = std::fs::remove_file(&tmp);
        return Err(CvError::File {
            path: path.into(),
            message: format!(
                "ffmpeg could not tag the video as BT.709: {}",
                String::from_utf8_lossy(&out.stderr).trim()
            ),
        });
    }
    std::fs::rename(&tmp, path).map_err(|e| CvError::File {
        path: path.into(),
        message: format!("replacing it with its tagged copy: {e}"),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Mean decoded colour of a video's first frame.
    fn first_colour(path: &Path) -> [f64; 3] {
        let mut r = VideoReader::open(path).expect("open");
        let img = r.read().expect("read").expect("frame");
        let mut sum = [0.0; 3];
        for px in img.data.chunks_exact(3) {
            for c in 0..3 {
                sum[c] += f64::from(px[c]);
            }
        }
        let n = (img.data.len() / 3) as f64;
        sum.map(|v| v / n)
    }

    fn close(a: [f64; 3], b: [f64; 3], tol: f64) -> bool {
        a.iter().zip(&b).all(|(x, y)| (x - y).abs() <= tol)
    }

    #[test]
    fn bt709_video_decodes_to_its_colours_written_by_ffmpeg_or_by_us() {
        let Ok(o) = std::process::Command::new("ffmpeg")
            .arg("-version")
            .output()
        else {
            eprintln!("SKIP: ffmpeg not installed (run scripts/setup.sh)");
            return;
        };
        assert!(o.status.success());
        let tmp = tempfile::tempdir().expect("tmp");
        let want = [200.0, 60.0, 30.0];
        // Files from FFmpeg's own encoder, with BT.709's matrix and tags and with
        // BT.601 untagged: we decode them as FFmpeg's converter does when told the
        // matrix (the reference decode).
        for (name, matrix, args) in [
            (
                "ffmpeg709.mp4",
                "bt709",
                &[
                    "-vf",
                    "scale=out_color_matrix=bt709:out_range=tv",
                    "-colorspace",
                    "bt709",
                    "-color_primaries",
                    "bt709",
                    "-color_trc",
                    "bt709",
                    "-color_range",
                    "tv",
                ][..],
            ),
            ("ffmpeg601.mp4", "bt601", &[][..]),
        ] {
            let p = tmp.path().join(name);
            let st = std::process::Command::new("ffmpeg")
                .args(["-v", "error", "-nostdin", "-f", "lavfi", "-i"])
                .arg("color=c=0xC83C1E:size=64x64:rate=10")
                .args(["-frames:v", "10", "-c:v", "libx264", "-pix_fmt", "yuv420p"])
                .args(args)
                .arg(&p)
                .status()
                .expect("ffmpeg");
            assert!(st.success());
            let o = std::process::Command::new("ffmpeg")
                .args(["-v", "error", "-nostdin", "-i"])
                .arg(&p)
                .args(["-frames:v", "1", "-vf"])
                .arg(format!("scale=in_color_matrix={matrix}:in_range=tv"))
                .args(["-f", "rawvideo", "-pix_fmt", "rgb24", "-"])
                .output()
                .expect("ffmpeg decode");
            assert!(o.status.success() && o.stdout.len() >= 3);
            let reference = [0, 1, 2].map(|c| f64::from(o.stdout[c]));
            let got = first_colour(&p);
            assert!(
                close(got, reference, 2.0),
                "{name}: {got:?} vs FFmpeg's {reference:?}"
            );
            // And near the colour asked for (FFmpeg's colour source is itself Y'CbCr).
            assert!(close(got, want, 6.0), "{name}: {got:?}");
        }
        // Our writer's BT.709 output: tagged, and the colours come back.
        let p = tmp.path().join("ours709.mp4");
        let mut w = VideoWriter::create_bt709(&p, 10.0, 64, 64).expect("writer");
        let mut img = ImageU8::new(64, 64, 3);
        for px in img.data.chunks_exact_mut(3) {
            px.copy_from_slice(&[200, 60, 30]);
        }
        for _ in 0..10 {
            w.write(&img).expect("write");
        }
        assert_eq!(w.finish().expect("finish"), 10);
        let probe = crate::probe::probe_video(&p).expect("probe");
        assert_eq!(probe.matrix.as_deref(), Some("bt709"));
        assert_eq!(probe.range.as_deref(), Some("tv"));
        assert_eq!(probe.decoding_matrix(), DecodingMatrix::Bt709);
        let got = first_colour(&p);
        assert!(close(got, want, 3.0), "ours: {got:?}");
    }
}
