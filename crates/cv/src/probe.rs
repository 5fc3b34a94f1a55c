//! What a video file holds, as FFmpeg's `ffprobe` reads it from the container and the
//! stream headers: codec, pixel format, colour tags, frame count, duration. Read once
//! per file before decoding, so that a video we would decode wrongly (HDR, anamorphic)
//! or only in part (truncated, damaged) is named instead of fitted.
//!
//! OpenCV's decoder hides these tags; until decoding moves to FFmpeg's libraries this
//! is the one place that asks FFmpeg directly.

use std::path::{Path, PathBuf};
use std::process::Command;

use serde::Deserialize;

use crate::CvError;

/// The first video stream of a file.
#[derive(Debug, Clone, PartialEq)]
pub struct VideoProbe {
    /// Container format names (e.g. `mov,mp4,m4a,3gp,3g2,mj2`).
    pub container: String,
    /// Codec (e.g. `h264`, `hevc`, `vp9`, `av1`, `png`).
    pub codec: String,
    /// Pixel format (e.g. `yuv420p`, `yuv420p10le`).
    pub pix_fmt: String,
    /// Bits per sample of the stored pixels.
    pub bit_depth: u32,
    /// Transfer characteristic tag (`bt709`, `arib-std-b67` = HLG, `smpte2084` = PQ...).
    pub transfer: Option<String>,
    /// Colour primaries tag (`bt709`, `bt2020`...).
    pub primaries: Option<String>,
    /// YUV matrix tag (`bt709`, `bt2020nc`...).
    pub matrix: Option<String>,
    /// `tv` (limited) or `pc` (full).
    pub range: Option<String>,
    /// Sample aspect ratio as `N:D` (`1:1` square pixels; `0:1` unknown).
    pub sample_aspect_ratio: Option<String>,
    /// Stored width and height, pixels (before rotation).
    pub size: (u32, u32),
    /// Frame count the container states.
    pub stated_frames: Option<u64>,
    /// Packets actually present in the file (counted by demuxing it).
    pub packets: Option<u64>,
    /// Stream or container duration, seconds.
    pub duration_s: Option<f64>,
}

#[derive(Deserialize)]
struct Output {
    #[serde(default)]
    streams: Vec<Stream>,
    format: Option<Format>,
}

#[derive(Deserialize)]
struct Stream {
    codec_type: Option<String>,
    codec_name: Option<String>,
    pix_fmt: Option<String>,
    bits_per_raw_sample: Option<String>,
    color_transfer: Option<String>,
    color_primaries: Option<String>,
    color_space: Option<String>,
    color_range: Option<String>,
    sample_aspect_ratio: Option<String>,
    width: Option<u32>,
    height: Option<u32>,
    nb_frames: Option<String>,
    nb_read_packets: Option<String>,
    duration: Option<String>,
}

#[derive(Deserialize)]
struct Format {
    format_name: Option<String>,
    duration: Option<String>,
}

fn file_error(path: &Path, message: impl Into<String>) -> CvError {
    CvError::File {
        path: PathBuf::from(path),
        message: message.into(),
    }
}

/// Bits per sample of a pixel format name (`yuv420p10le` -> 10; plain formats 8).
fn bit_depth_of(pix_fmt: &str) -> u32 {
    let digits: String = pix_fmt
        .trim_end_matches("le")
        .trim_end_matches("be")
        .chars()
        .rev()
        .take_while(char::is_ascii_digit)
        .collect::<Vec<_>>()
        .into_iter()
        .rev()
        .collect();
    match digits.parse::<u32>() {
        Ok(d @ 9..=16)
            if pix_fmt.starts_with("yuv")
                || pix_fmt.starts_with("gray")
                || pix_fmt.starts_with("p0") =>
        {
            d
        }
        _ if pix_fmt.starts_with("p010") => 10,
        _ => 8,
    }
}

/// Read the first video stream's description. Errors name the file and what was
/// found: not a media file, no video stream, ffprobe missing.
pub fn probe_video(path: &Path) -> Result<VideoProbe, CvError> {
    let out = Command::new("ffprobe")
        .args([
            "-v",
            "error",
            "-count_packets",
            "-show_entries",
            "stream=codec_type,codec_name,pix_fmt,bits_per_raw_sample,color_transfer,color_primaries,color_space,color_range,sample_aspect_ratio,width,height,nb_frames,nb_read_packets,duration:format=format_name,duration",
            "-of",
            "json",
        ])
        .arg(path)
        .output()
        .map_err(|e| {
            file_error(
                path,
                format!("cannot run ffprobe to read the video's stream description ({e}; expected FFmpeg's ffprobe on PATH: apt-get install ffmpeg)"),
            )
        })?;
    let parsed: Option<Output> = serde_json::from_slice(&out.stdout).ok();
    let Some(parsed) = parsed.filter(|p| p.format.is_some()) else {
        let why = String::from_utf8_lossy(&out.stderr);
        let why = why.lines().last().unwrap_or("").trim();
        return Err(file_error(
            path,
            format!(
                "not a video FFmpeg can read{} (expected an MP4/MOV/MKV video from the phone's camera)",
                if why.is_empty() { String::new() } else { format!(": {}", why.rsplit(": ").next().unwrap_or(why)) }
            ),
        ));
    };
    let container = parsed
        .format
        .as_ref()
        .and_then(|f| f.format_name.clone())
        .unwrap_or_default();
    let Some(s) = parsed
        .streams
        .into_iter()
        .find(|s| s.codec_type.as_deref() == Some("video"))
    else {
        return Err(file_error(
            path,
            format!(
                "holds no video stream (container {container}; expected a video, not audio only)"
            ),
        ));
    };
    let num = |v: &Option<String>| v.as_deref().and_then(|t| t.parse::<f64>().ok());
    let pix_fmt = s.pix_fmt.clone().unwrap_or_default();
    let bit_depth = s
        .bits_per_raw_sample
        .as_deref()
        .and_then(|b| b.parse().ok())
        .unwrap_or_else(|| bit_depth_of(&pix_fmt));
    let unknown = |v: Option<String>| v.filter(|t| t != "unknown" && !t.is_empty());
    Ok(VideoProbe {
        container,
        codec: s.codec_name.unwrap_or_default(),
        pix_fmt,
        bit_depth,
        transfer: unknown(s.color_transfer),
        primaries: unknown(s.color_primaries),
        matrix: unknown(s.color_space),
        range: unknown(s.color_range),
        sample_aspect_ratio: s.sample_aspect_ratio,
        size: (s.width.unwrap_or(0), s.height.unwrap_or(0)),
        stated_frames: num(&s.nb_frames).map(|v| v as u64),
        packets: num(&s.nb_read_packets).map(|v| v as u64),
        duration_s: num(&s.duration).or_else(|| parsed.format.and_then(|f| num(&f.duration))),
    })
}

/// Which Y'CbCr matrix frames are decoded with.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum DecodingMatrix {
    /// BT.601: tagged so (`bt470bg`, `smpte170m`) or untagged (what FFmpeg assumes).
    Bt601,
    /// BT.709, as tagged (phones' SDR video).
    Bt709,
    /// BT.2020 non-constant luminance, as tagged (HDR video; decoded by FFmpeg's
    /// libraries).
    Bt2020,
}

impl DecodingMatrix {
    /// Its name for people (`BT.601`, `BT.709`).
    pub fn label(self) -> &'static str {
        match self {
            Self::Bt601 => "BT.601",
            Self::Bt709 => "BT.709",
            Self::Bt2020 => "BT.2020",
        }
    }
}

impl VideoProbe {
    /// The Y'CbCr matrix the frames are decoded with: the stream's own where it is
    /// tagged BT.709, else BT.601.
    pub fn decoding_matrix(&self) -> DecodingMatrix {
        match self.matrix.as_deref() {
            Some("bt709") => DecodingMatrix::Bt709,
            Some("bt2020nc") => DecodingMatrix::Bt2020,
            None if self.primaries.as_deref() == Some("bt2020") => DecodingMatrix::Bt2020,
            _ => DecodingMatrix::Bt601,
        }
    }

    /// Whether the frames need FFmpeg's libraries to reach linear light right: more
    /// than 8 bits, an HDR transfer (HLG, PQ), BT.2020 colours, or full range (some
    /// Android phones): OpenCV would decode them to 8-bit SDR, limited range.
    pub fn needs_linear_decoding(&self) -> bool {
        self.bit_depth > 8
            || self.range.as_deref() == Some("pc")
            || self.pix_fmt.starts_with("yuvj")
            || matches!(
                self.transfer.as_deref(),
                Some("arib-std-b67" | "smpte2084" | "bt2020-10" | "bt2020-12")
            )
            || matches!(self.primaries.as_deref(), Some("bt2020"))
            || matches!(self.matrix.as_deref(), Some("bt2020nc" | "bt2020c"))
    }

    /// Refuse what the decoder would read wrongly: still images, HDR or wide-gamut
    /// video (decoded as if it were sRGB), non-square pixels. The error names what was
    /// found and what to record instead.
    pub fn check_supported(&self, path: &Path) -> Result<(), CvError> {
        let image_formats = [
            "image2",
            "png_pipe",
            "jpeg_pipe",
            "bmp_pipe",
            "webp_pipe",
            "tiff_pipe",
            "gif",
        ];
        if image_formats
            .iter()
            .any(|f| self.container.split(',').any(|c| c == *f))
            || matches!(
                self.codec.as_str(),
                "png" | "mjpeg" | "bmp" | "tiff" | "webp"
            ) && self.packets.unwrap_or(1) <= 1
        {
            return Err(file_error(
                path,
                format!(
                    "is a still image ({} in {}), not a video (expected the flash video; for still photos use `align --photos FOLDER`)",
                    self.codec, self.container
                ),
            ));
        }
        // What FFmpeg's libraries cannot bring to linear light right is refused by
        // `svbrdf_av::AvReader::open` with the tag it found (other transfers, Display
        // P3 or other primaries, constant-luminance BT.2020).
        if let Some(sar) = &self.sample_aspect_ratio {
            let parts: Vec<f64> = sar.split(':').filter_map(|p| p.parse().ok()).collect();
            if let [n, d] = parts.as_slice() {
                if *n > 0.0 && *d > 0.0 && (n / d - 1.0).abs() > 1e-3 {
                    return Err(file_error(
                        path,
                        format!(
                            "has non-square pixels (sample aspect ratio {sar}, anamorphic), which would distort the geometry (expected square pixels, 1:1, as phone cameras record)"
                        ),
                    ));
                }
            }
        }
        Ok(())
    }

    /// The number of frames the file should decode to: the larger of the container's
    /// statement and the packets present.
    pub fn expected_frames(&self) -> Option<u64> {
        match (self.stated_frames, self.packets) {
            (Some(a), Some(b)) => Some(a.max(b)),
            (a, b) => a.or(b),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bit_depths_from_pixel_formats() {
        assert_eq!(bit_depth_of("yuv420p"), 8);
        assert_eq!(bit_depth_of("yuv420p10le"), 10);
        assert_eq!(bit_depth_of("yuv422p12be"), 12);
        assert_eq!(bit_depth_of("p010le"), 10);
        assert_eq!(bit_depth_of("rgb24"), 8);
    }

    fn probe(transfer: Option<&str>, primaries: Option<&str>, sar: &str) -> VideoProbe {
        VideoProbe {
            container: "mov,mp4,m4a,3gp,3g2,mj2".into(),
            codec: "hevc".into(),
            pix_fmt: "yuv420p10le".into(),
            bit_depth: 10,
            transfer: transfer.map(Into::into),
            primaries: primaries.map(Into::into),
            matrix: None,
            range: Some("tv".into()),
            sample_aspect_ratio: Some(sar.into()),
            size: (3840, 2160),
            stated_frames: Some(300),
            packets: Some(300),
            duration_s: Some(10.0),
        }
    }

    #[test]
    fn hdr_goes_to_linear_decoding_and_anamorphic_is_refused() {
        let p = Path::new("v.mov");
        let hlg = probe(Some("arib-std-b67"), Some("bt2020"), "1:1");
        assert!(hlg.check_supported(p).is_ok());
        assert!(hlg.needs_linear_decoding());
        assert_eq!(hlg.decoding_matrix(), DecodingMatrix::Bt2020);
        let mut sdr8 = probe(Some("bt709"), Some("bt709"), "1:1");
        sdr8.bit_depth = 8;
        sdr8.pix_fmt = "yuv420p".into();
        assert!(!sdr8.needs_linear_decoding());
        let mut full = sdr8.clone();
        full.range = Some("pc".into());
        assert!(full.needs_linear_decoding());
        let e = probe(Some("bt709"), Some("bt709"), "4:3")
            .check_supported(p)
            .unwrap_err()
            .to_string();
        assert!(e.contains("anamorphic"), "{e}");
        assert!(probe(None, None, "0:1").check_supported(p).is_ok());
    }
}
