//! # svbrdf-av
//!
//! Video decoding through FFmpeg's own libraries (`ffmpeg-next` against the system's
//! FFmpeg): every frame of the first video stream, with its presentation time (so
//! variable frame rates keep their timing), turned upright by the stream's rotation
//! and converted to **linear RGB with the sRGB/BT.709 primaries** using the stream's
//! own Y'CbCr matrix, range, transfer characteristic (SDR, HLG or PQ) and primaries
//! (BT.709 or BT.2020). Ten-bit streams keep their precision: frames come out as
//! floats. What cannot be converted right is refused with what was found.
//!
//! Linear scale: SDR 1 = the format's white (sRGB curve, as the rest of svbrdf);
//! HLG 1 = the format's peak (scene light; reference white 0.265); PQ 1 = 1000 cd/m^2
//! (reference white 0.203; brighter clips).

mod convert;

use std::path::{Path, PathBuf};

use ffmpeg_next as ff;
use svbrdf_core::color::{Transfer, YcbcrMatrix};
use svbrdf_core::image::ImageF32;

pub use convert::{Layout, YuvFormat};

/// Errors of this crate.
#[derive(Debug, thiserror::Error)]
pub enum AvError {
    /// The file cannot be decoded right; the message names what was found and what to do.
    #[error("{}: {message}", path.display())]
    File {
        /// The video.
        path: PathBuf,
        /// What was found.
        message: String,
    },
}

fn file_error(path: &Path, message: impl Into<String>) -> AvError {
    AvError::File {
        path: path.to_path_buf(),
        message: message.into(),
    }
}

/// Colour primaries of the stream.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Primaries {
    /// BT.709 / sRGB (also BT.601's, close enough for phones' SDR, and untagged).
    Bt709,
    /// BT.2020 (HDR video): converted to BT.709 in linear light.
    Bt2020,
}

/// What the stream is and how its frames are converted.
#[derive(Debug, Clone, PartialEq)]
pub struct StreamInfo {
    /// Codec name (`h264`, `hevc`, ...).
    pub codec: String,
    /// Pixel layout of the decoded frames.
    pub format: YuvFormat,
    /// Stored width and height (before rotation), pixels.
    pub stored: (u32, u32),
    /// Clockwise rotation applied to make frames upright, degrees (0, 90, 180, 270).
    pub rotation_deg: u32,
    /// Y'CbCr matrix used.
    pub matrix: YcbcrMatrix,
    /// Matrix name for records (`bt601`, `bt709`, `bt2020`).
    pub matrix_name: &'static str,
    /// Full range (`pc`) or limited (`tv`).
    pub full_range: bool,
    /// Transfer characteristic used.
    pub transfer: Transfer,
    /// Primaries converted from.
    pub primaries: Primaries,
    /// Stream time base, seconds per tick.
    pub time_base: f64,
    /// Average frame rate the stream states, frames per second (0: unknown).
    pub fps: f64,
    /// Frame count the container states (0: unknown).
    pub stated_frames: u64,
}

impl StreamInfo {
    /// Upright width and height, pixels.
    pub fn size(&self) -> (u32, u32) {
        if self.rotation_deg % 180 == 90 {
            (self.stored.1, self.stored.0)
        } else {
            self.stored
        }
    }
}

/// A decoded frame.
#[derive(Debug, Clone)]
pub struct Frame {
    /// Presentation time from the stream's timestamps, seconds from the first frame.
    pub time_s: f64,
    /// Linear RGB (BT.709 primaries), upright.
    pub rgb: ImageF32,
}

/// A streaming decoder: one frame in memory at a time.
pub struct AvReader {
    path: PathBuf,
    input: ff::format::context::Input,
    decoder: ff::decoder::Video,
    stream: usize,
    info: StreamInfo,
    frame: ff::frame::Video,
    eof_sent: bool,
    first_pts: Option<i64>,
    last_time: f64,
    lut: Vec<f32>,
}

/// Rotation (clockwise degrees, a multiple of 90) from a display matrix (nine
/// 32-bit little-endian numbers, as FFmpeg stores it), as FFmpeg's own
/// autorotation reads it; `None` for angles that are not a multiple of 90.
pub fn rotation_of_display_matrix(data: &[u8]) -> Option<u32> {
    if data.len() < 36 {
        return None;
    }
    let m: Vec<f64> = data
        .chunks_exact(4)
        .take(9)
        .map(|c| f64::from(i32::from_le_bytes([c[0], c[1], c[2], c[3]])))
        .collect();
    let (s0, s1) = (m[0].hypot(m[3]), m[1].hypot(m[4]));
    if s0 == 0.0 || s1 == 0.0 {
        return None;
    }
    // FFmpeg: av_display_rotation_get = -atan2(m1 / s1, m0 / s0); autorotation turns
    // the picture clockwise by its negative.
    let theta = (m[1] / s1).atan2(m[0] / s0).to_degrees();
    let theta = theta.rem_euclid(360.0);
    let q = (theta / 90.0).round();
    ((theta - 90.0 * q).abs() < 1.0).then(|| (q as u32 % 4) * 90)
}

impl AvReader {
    /// Open the first video stream of `path`.
    pub fn open(path: &Path) -> Result<Self, AvError> {
        ff::init()
            .map_err(|e| file_error(path, format!("FFmpeg's libraries failed to start ({e})")))?;
        ff::util::log::set_level(ff::util::log::Level::Error);
        let input = ff::format::input(&path)
            .map_err(|e| file_error(path, format!("not a video FFmpeg can read ({e})")))?;
        let (stream, params, time_base, stated, rotation, fps) = {
            let s = input
                .streams()
                .best(ff::media::Type::Video)
                .ok_or_else(|| file_error(path, "holds no video stream"))?;
            let tb = s.time_base();
            let rotation = s
                .side_data()
                .find(|d| d.kind() == ff::codec::packet::side_data::Type::DisplayMatrix)
                .map(|d| rotation_of_display_matrix(d.data()));
            (
                s.index(),
                s.parameters(),
                f64::from(tb.numerator()) / f64::from(tb.denominator().max(1)),
                s.frames().max(0) as u64,
                rotation,
                {
                    let r = s.avg_frame_rate();
                    if r.denominator() > 0 {
                        f64::from(r.numerator()) / f64::from(r.denominator())
                    } else {
                        0.0
                    }
                },
            )
        };
        let rotation_deg = match rotation {
            None => 0,
            Some(Some(r)) => r,
            Some(None) => {
                return Err(file_error(
                    path,
                    "has a rotation that is not a multiple of 90 degrees (expected a phone video: upright, or turned by 90, 180 or 270 degrees)",
                ))
            }
        };
        let mut ctx = ff::codec::context::Context::from_parameters(params)
            .map_err(|e| file_error(path, format!("cannot read its codec parameters ({e})")))?;
        // Frame threads, as many as the machine has (FFmpeg's default is one).
        ctx.set_threading(ff::codec::threading::Config {
            kind: ff::codec::threading::Type::Frame,
            count: 0,
            ..Default::default()
        });
        let decoder = ctx.decoder().video().map_err(|e| {
            file_error(
                path,
                format!("no decoder for its video stream ({e}); expected H.264 or HEVC"),
            )
        })?;
        let codec = decoder
            .codec()
            .map(|c| c.name().to_string())
            .unwrap_or_else(|| "unknown".into());
        let format = YuvFormat::of(decoder.format()).ok_or_else(|| {
            file_error(
                path,
                format!(
                    "decodes to pixel format {:?}, which svbrdf cannot convert (expected planar Y'CbCr 4:2:0, 4:2:2 or 4:4:4 at 8 or 10 bits, as phones record)",
                    decoder.format()
                ),
            )
        })?;
        let transfer = match decoder.color_transfer_characteristic() {
            ff::color::TransferCharacteristic::ARIB_STD_B67 => Transfer::Hlg,
            ff::color::TransferCharacteristic::SMPTE2084 => Transfer::Pq,
            ff::color::TransferCharacteristic::BT709
            | ff::color::TransferCharacteristic::Unspecified
            | ff::color::TransferCharacteristic::SMPTE170M
            | ff::color::TransferCharacteristic::GAMMA28
            | ff::color::TransferCharacteristic::IEC61966_2_1
            | ff::color::TransferCharacteristic::BT2020_10
            | ff::color::TransferCharacteristic::BT2020_12
            | ff::color::TransferCharacteristic::GAMMA22 => Transfer::Sdr,
            other => {
                return Err(file_error(
                    path,
                    format!(
                        "has transfer characteristic {other:?}, which svbrdf cannot convert to linear light (expected SDR (BT.709, sRGB), HLG or PQ)"
                    ),
                ))
            }
        };
        let primaries = match decoder.color_primaries() {
            ff::color::Primaries::BT2020 => Primaries::Bt2020,
            ff::color::Primaries::BT709
            | ff::color::Primaries::Unspecified
            | ff::color::Primaries::BT470BG
            | ff::color::Primaries::SMPTE170M => Primaries::Bt709,
            other => {
                return Err(file_error(
                    path,
                    format!(
                        "has colour primaries {other:?}, which svbrdf cannot convert (expected BT.709 for SDR or BT.2020 for HDR)"
                    ),
                ))
            }
        };
        let (matrix, matrix_name) = match decoder.color_space() {
            ff::color::Space::BT2020NCL => (YcbcrMatrix::BT2020, "bt2020"),
            ff::color::Space::BT709 => (YcbcrMatrix::BT709, "bt709"),
            ff::color::Space::Unspecified if primaries == Primaries::Bt2020 => {
                (YcbcrMatrix::BT2020, "bt2020")
            }
            ff::color::Space::Unspecified | ff::color::Space::BT470BG | ff::color::Space::SMPTE170M => {
                (YcbcrMatrix::BT601, "bt601")
            }
            other => {
                return Err(file_error(
                    path,
                    format!(
                        "has Y'CbCr matrix {other:?}, which svbrdf cannot convert (expected BT.601, BT.709 or BT.2020 non-constant luminance)"
                    ),
                ))
            }
        };
        let full_range =
            decoder.color_range() == ff::color::Range::JPEG || format.full_range_by_name;
        let info = StreamInfo {
            codec,
            format,
            stored: (decoder.width(), decoder.height()),
            rotation_deg,
            matrix,
            matrix_name,
            full_range,
            transfer,
            primaries,
            time_base,
            fps,
            stated_frames: stated,
        };
        let lut = convert::transfer_table(transfer);
        Ok(Self {
            path: path.to_path_buf(),
            input,
            decoder,
            stream,
            info,
            frame: ff::frame::Video::empty(),
            eof_sent: false,
            first_pts: None,
            last_time: -1.0,
            lut,
        })
    }

    /// What the stream is and how it is converted.
    pub fn info(&self) -> &StreamInfo {
        &self.info
    }

    /// Decode the next frame into `self.frame`; `false` at the end.
    fn decode_next(&mut self) -> Result<bool, AvError> {
        loop {
            match self.decoder.receive_frame(&mut self.frame) {
                Ok(()) => return Ok(true),
                Err(ff::Error::Eof) => return Ok(false),
                Err(ff::Error::Other { errno }) if errno == ff::util::error::EAGAIN => {}
                Err(e) => {
                    return Err(file_error(
                        &self.path,
                        format!(
                        "decoding failed ({e}); the file is damaged: copy it from the phone again"
                    ),
                    ))
                }
            }
            if self.eof_sent {
                return Ok(false);
            }
            let mut sent = false;
            for (s, packet) in self.input.packets() {
                if s.index() != self.stream {
                    continue;
                }
                self.decoder.send_packet(&packet).map_err(|e| {
                    file_error(
                        &self.path,
                        format!("a damaged packet ({e}); copy the file from the phone again"),
                    )
                })?;
                sent = true;
                break;
            }
            if !sent {
                self.decoder.send_eof().map_err(|e| {
                    file_error(&self.path, format!("decoding failed at the end ({e})"))
                })?;
                self.eof_sent = true;
            }
        }
    }

    /// The current frame's time, seconds from the first frame: from its timestamp,
    /// or one frame duration after the last where it has none.
    fn frame_time(&mut self) -> f64 {
        let t = match self.frame.timestamp().or_else(|| self.frame.pts()) {
            Some(pts) => {
                let first = *self.first_pts.get_or_insert(pts);
                (pts - first) as f64 * self.info.time_base
            }
            None => self.last_time + 1.0 / 30.0,
        };
        let t = if t > self.last_time {
            t
        } else {
            self.last_time + 1e-6
        };
        self.last_time = t;
        t
    }

    /// Decode the next frame and only return its time (for skipping), or `None` at
    /// the end.
    pub fn skip(&mut self) -> Result<Option<f64>, AvError> {
        if !self.decode_next()? {
            return Ok(None);
        }
        Ok(Some(self.frame_time()))
    }

    /// The next frame, converted, or `None` at the end.
    pub fn read(&mut self) -> Result<Option<Frame>, AvError> {
        if !self.decode_next()? {
            return Ok(None);
        }
        let time_s = self.frame_time();
        let layout = Layout {
            format: self.info.format,
            width: self.frame.width() as usize,
            height: self.frame.height() as usize,
            strides: [
                self.frame.stride(0),
                self.frame.stride(1),
                self.frame.stride(2),
            ],
        };
        let planes = [self.frame.data(0), self.frame.data(1), self.frame.data(2)];
        let rgb = convert::to_linear_rgb(
            &layout,
            planes,
            self.info.matrix,
            self.info.full_range,
            &self.lut,
            self.info.primaries == Primaries::Bt2020,
        )
        .map_err(|m| file_error(&self.path, m))?;
        Ok(Some(Frame {
            time_s,
            rgb: convert::rotate(rgb, self.info.rotation_deg),
        }))
    }
}
