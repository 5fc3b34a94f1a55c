//! What [`crate::align`] records about the videos it read: how a stream's colours were
//! decoded, and what happened to the second stream of a two-camera capture.

use std::path::PathBuf;

use crate::{sync, DropCounts};

/// What a video's stream says about its colours and what decoding did with it.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct VideoDecoding {
    /// Codec and pixel format (e.g. `h264`, `yuv420p`).
    pub codec: String,
    /// Pixel format.
    pub pix_fmt: String,
    /// The stream's Y'CbCr matrix tag (`bt709`, `smpte170m`; `None`: untagged).
    pub matrix_tag: Option<String>,
    /// Its range tag (`tv` limited, `pc` full).
    pub range_tag: Option<String>,
    /// Its transfer tag.
    pub transfer_tag: Option<String>,
    /// The Y'CbCr matrix the frames were decoded with (`bt709` or `bt2020` where
    /// tagged so, else `bt601`).
    pub decoded_with: svbrdf_cv::probe::DecodingMatrix,
    /// Its primaries tag.
    #[serde(default)]
    pub primaries_tag: Option<String>,
    /// Bits per sample.
    #[serde(default)]
    pub bit_depth: u32,
    /// How R'G'B' became linear light: `sdr` (the sRGB curve), `hlg` or `pq`.
    #[serde(default = "sdr_transfer")]
    pub transfer: svbrdf_core::color::Transfer,
    /// Whether BT.2020 primaries were converted to BT.709 in linear light.
    #[serde(default)]
    pub from_bt2020: bool,
    /// `opencv` (8-bit SDR: 8 bits kept) or `ffmpeg-libraries` (10-bit and HDR:
    /// linear floats kept through to the observations).
    #[serde(default)]
    pub decoder: String,
}

fn sdr_transfer() -> svbrdf_core::color::Transfer {
    svbrdf_core::color::Transfer::Sdr
}

impl VideoDecoding {
    /// From FFmpeg's description of the stream and what the reader did with it.
    pub fn of(p: &svbrdf_cv::probe::VideoProbe, d: &svbrdf_cv::video::Decoding) -> Self {
        Self {
            codec: p.codec.clone(),
            pix_fmt: p.pix_fmt.clone(),
            matrix_tag: p.matrix.clone(),
            range_tag: p.range.clone(),
            transfer_tag: p.transfer.clone(),
            decoded_with: p.decoding_matrix(),
            primaries_tag: p.primaries.clone(),
            bit_depth: p.bit_depth,
            transfer: d.transfer,
            from_bt2020: d.from_bt2020,
            decoder: d.decoder.into(),
        }
    }
}

/// What happened to the second stream of a two-camera capture.
#[derive(Debug, Clone, serde::Serialize, serde::Deserialize)]
pub struct SecondStreamSummary {
    /// The second video.
    pub video: PathBuf,
    /// Its frame rate.
    pub fps: f64,
    /// Time on the second video's clock of the flash video's first frame, seconds.
    pub sync_offset_s: f64,
    /// The detected flash onset (absent when the offset was given by hand).
    pub onset: Option<sync::Onset>,
    /// Frames at the second frame step that were recorded before the flash came on.
    pub before_onset: usize,
    /// Frames at the second frame step after the flash video's end (dropped with
    /// `trim_second`, refused otherwise).
    pub after_end: usize,
    /// Frame accounting after synchronisation (`disconnected` is unused).
    pub frames: DropCounts,
    /// Second-stream frames with verified matches to a flash frame.
    pub cross_pairs: usize,
}

impl SecondStreamSummary {
    /// One line for people: synchronisation and frame accounting.
    pub fn describe(&self) -> String {
        let g = &self.frames;
        format!(
            "flash video starts at {:.3} s of the second video{}; left out {} frames before the flash onset and {} after the flash video's end; of {} frames {} kept, dropped {} blurry, {} unregistered, {} implausible; {} matched with flash frames",
            self.sync_offset_s,
            if self.onset.is_some() { " (flash onset)" } else { " (given)" },
            self.before_onset,
            self.after_end,
            g.decoded,
            g.kept,
            g.blurry,
            g.unregistered,
            g.outside,
            self.cross_pairs
        )
    }
}
