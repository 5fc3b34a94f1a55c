//! Writing the simulator's videos in the formats phones record beyond 8-bit SDR:
//! 10-bit SDR HEVC, 10-bit HLG and PQ HEVC with BT.2020 primaries, and variable
//! frame timing. Frames are handed over in linear light and coded here; one `ffmpeg`
//! process per video encodes them (its libx264/libx265 and colour conversion).

use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::{Child, ChildStdin, Command, Stdio};

use serde::{Deserialize, Serialize};
use svbrdf_core::color::{mul3, Transfer, BT709_TO_BT2020};
use svbrdf_core::image::ImageF32;

use crate::CvError;

/// How a simulated video is stored.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum VideoFormat {
    /// 8-bit SDR H.264 (OpenCV's encoder unless the frame times are jittered).
    #[default]
    H264Sdr8,
    /// 10-bit SDR HEVC, BT.709.
    HevcSdr10,
    /// 10-bit HLG HEVC, BT.2020 (iPhones' default): SDR white at HLG's reference
    /// white, so highlights keep about 3.8x of headroom.
    HevcHlg,
    /// 10-bit PQ (HDR10) HEVC, BT.2020: SDR white at 203 cd/m^2, clipping at 1000.
    HevcPq,
}

impl VideoFormat {
    /// Its transfer curve.
    pub fn transfer(self) -> Transfer {
        match self {
            Self::H264Sdr8 | Self::HevcSdr10 => Transfer::Sdr,
            Self::HevcHlg => Transfer::Hlg,
            Self::HevcPq => Transfer::Pq,
        }
    }

    /// Linear level, in the decoder's units, of the simulator's linear 1 (SDR white).
    pub fn white(self) -> f64 {
        self.transfer().reference_white()
    }

    /// Name for people and flags.
    pub fn name(self) -> &'static str {
        match self {
            Self::H264Sdr8 => "h264-sdr8",
            Self::HevcSdr10 => "hevc-sdr10",
            Self::HevcHlg => "hevc-hlg",
            Self::HevcPq => "hevc-pq",
        }
    }
}

/// A video written through the `ffmpeg` program.
pub struct FfmpegWriter {
    child: Option<Child>,
    stdin: Option<ChildStdin>,
    path: PathBuf,
    format: VideoFormat,
    width: usize,
    height: usize,
    frames: u64,
    buf: Vec<u8>,
}

impl FfmpegWriter {
    /// Start writing `path`: `fps` frames per second, frame `n` stamped at
    /// `n / fps + jitter_s * sin(1.7 n)` seconds.
    pub fn create(
        path: &Path,
        fps: f64,
        width: u32,
        height: u32,
        format: VideoFormat,
        jitter_s: f64,
    ) -> Result<Self, CvError> {
        let (pix, codec, prim, trc, space, params) = match format {
            VideoFormat::H264Sdr8 => ("yuv420p", "libx264", "bt709", "bt709", "bt709", None),
            VideoFormat::HevcSdr10 => (
                "yuv420p10le",
                "libx265",
                "bt709",
                "bt709",
                "bt709",
                Some("colorprim=bt709:transfer=bt709:colormatrix=bt709"),
            ),
            VideoFormat::HevcHlg => (
                "yuv420p10le",
                "libx265",
                "bt2020",
                "arib-std-b67",
                "bt2020nc",
                Some("colorprim=bt2020:transfer=arib-std-b67:colormatrix=bt2020nc"),
            ),
            VideoFormat::HevcPq => (
                "yuv420p10le",
                "libx265",
                "bt2020",
                "smpte2084",
                "bt2020nc",
                Some("colorprim=bt2020:transfer=smpte2084:colormatrix=bt2020nc"),
            ),
        };
        let matrix = if space == "bt709" { "bt709" } else { "bt2020" };
        let timing = if jitter_s > 0.0 {
            format!("settb=1/100000,setpts=(N/{fps}+{jitter_s}*sin(N*1.7))/TB,")
        } else {
            String::new()
        };
        let mut cmd = Command::new("ffmpeg");
        cmd.args(["-v", "error", "-y", "-f", "rawvideo", "-pix_fmt", "rgb48le", "-s"])
            .arg(format!("{width}x{height}"))
            .args(["-r", &fps.to_string(), "-i", "-", "-vf"])
            .arg(format!(
                "{timing}scale=out_color_matrix={matrix}:out_range=tv:flags=accurate_rnd+full_chroma_int,format={pix}"
            ))
            .args(["-c:v", codec, "-preset", "fast", "-crf", "16"]);
        if let Some(p) = params {
            cmd.args([
                "-x265-params",
                &format!("{p}:range=limited:log-level=error"),
            ]);
        }
        if jitter_s > 0.0 {
            cmd.args(["-fps_mode", "passthrough", "-enc_time_base:v", "1:100000"]);
        }
        cmd.args([
            "-color_primaries",
            prim,
            "-color_trc",
            trc,
            "-colorspace",
            space,
            "-color_range",
            "tv",
            "-tag:v",
            if codec == "libx265" { "hvc1" } else { "avc1" },
        ])
        .arg(path)
        .stdin(Stdio::piped())
        .stdout(Stdio::null())
        .stderr(Stdio::piped());
        let mut child = cmd.spawn().map_err(|e| CvError::File {
            path: path.into(),
            message: format!(
                "cannot run ffmpeg to write the {} video ({e}; expected FFmpeg's ffmpeg with libx264 and libx265 on PATH: apt-get install ffmpeg)",
                format.name()
            ),
        })?;
        let stdin = child.stdin.take();
        Ok(Self {
            child: Some(child),
            stdin,
            path: path.into(),
            format,
            width: width as usize,
            height: height as usize,
            frames: 0,
            buf: Vec::new(),
        })
    }

    /// Append a frame in the simulator's linear units (1 = SDR white, BT.709
    /// primaries); values beyond the format's range clip.
    pub fn write(&mut self, img: &ImageF32) -> Result<(), CvError> {
        if img.width != self.width || img.height != self.height || img.channels != 3 {
            return Err(CvError::Invalid {
                what: "frame size".into(),
                value: format!("{}x{}x{}", img.width, img.height, img.channels),
                expected: format!("{}x{}x3 as the video was created", self.width, self.height),
            });
        }
        let t = self.format.transfer();
        let (white, wide) = (self.format.white(), t != Transfer::Sdr);
        self.buf.clear();
        self.buf.reserve(img.data.len() * 2);
        for px in img.data.chunks_exact(3) {
            let lin = [0, 1, 2].map(|c| f64::from(px[c]) * white);
            let lin = if wide {
                mul3(&BT709_TO_BT2020, lin)
            } else {
                lin
            };
            for v in lin {
                let code = (t.from_linear(v.max(0.0)) * 65535.0).round() as u16;
                self.buf.extend_from_slice(&code.to_le_bytes());
            }
        }
        let Some(stdin) = self.stdin.as_mut() else {
            return Err(self.failed("the encoder's input is closed"));
        };
        if let Err(e) = stdin.write_all(&self.buf) {
            return Err(self.failed(&format!("writing a frame to ffmpeg failed ({e})")));
        }
        self.frames += 1;
        Ok(())
    }

    fn failed(&mut self, what: &str) -> CvError {
        drop(self.stdin.take());
        let mut err = String::new();
        if let Some(mut child) = self.child.take() {
            if let Some(mut e) = child.stderr.take() {
                let _ = std::io::Read::read_to_string(&mut e, &mut err);
            }
            let _ = child.wait();
        }
        CvError::File {
            path: self.path.clone(),
            message: format!("{what}: {}", err.trim()),
        }
    }

    /// Finish the file; returns the number of frames written.
    pub fn finish(mut self) -> Result<u64, CvError> {
        drop(self.stdin.take());
        let Some(child) = self.child.take() else {
            return Err(self.failed("the encoder stopped early"));
        };
        let out = child.wait_with_output().map_err(|e| CvError::File {
            path: self.path.clone(),
            message: format!("ffmpeg did not finish ({e})"),
        })?;
        if !out.status.success() {
            return Err(CvError::File {
                path: self.path.clone(),
                message: format!(
                    "ffmpeg failed to encode the {} video: {}",
                    self.format.name(),
                    String::from_utf8_lossy(&out.stderr).trim()
                ),
            });
        }
        Ok(self.frames)
    }
}

impl Drop for FfmpegWriter {
    /// An unfinished video is abandoned: the encoder is stopped.
    fn drop(&mut self) {
        drop(self.stdin.take());
        if let Some(mut c) = self.child.take() {
            let _ = c.kill();
            let _ = c.wait();
        }
    }
}
