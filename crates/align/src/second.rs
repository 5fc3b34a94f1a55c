//! The second, no-flash stream of a two-camera capture (paper 3.3): synchronised with
//! the flash video (`sync`) and decoded at its own frame step, on the flash camera's
//! clock.

use std::path::Path;

use crate::{
    frames, matching, sync, AlignConfig, AlignError, DropCounts, Progress, SecondStreamSummary,
};

/// Synchronise the second video with the flash video and decode its frames at its
/// frame step, on the flash camera's clock.
pub(crate) fn second_stream(
    video: &Path,
    flash_video: &Path,
    cfg: &AlignConfig,
    dict: svbrdf_cv::aruco::Dictionary,
    progress: &dyn Progress,
) -> Result<(matching::SecondFrames, SecondStreamSummary), AlignError> {
    let flash = svbrdf_cv::video::VideoReader::open(flash_video)?.info();
    let flash_end_s = flash.frame_count.saturating_sub(1) as f64 / flash.fps.max(1e-9);
    let (sync_offset_s, onset) = match cfg.sync_offset_s {
        Some(o) => (o, None),
        None => {
            let (profiles, fps) = sync::decode_profiles(video, progress)?;
            let o = sync::find_onset(&profiles, fps, cfg.second_camera.readout_s).map_err(|e| {
                AlignError::SecondStream(format!(
                    "{}: {e}; give the second video's time (seconds) of the flash video's first frame with --sync-offset",
                    video.display()
                ))
            })?;
            (o.time_s, Some(o))
        }
    };
    let mut c2 = cfg.clone();
    c2.camera = cfg.second_camera.clone();
    let (decoded, _) = frames::decode_frames(video, &c2, dict, progress)?;
    let fps = svbrdf_cv::video::VideoReader::open(video)?.info().fps;
    let (mut before_onset, mut after_end) = (0, 0);
    let mut kept = Vec::with_capacity(decoded.len());
    for mut f in decoded {
        f.stream = 1;
        f.time_s = sync::flash_time(f.index, fps, sync_offset_s);
        if f.time_s < 0.0 {
            before_onset += 1;
        } else if f.time_s > flash_end_s + 0.5 / flash.fps.max(1e-9) {
            after_end += 1;
        } else {
            kept.push(f);
        }
    }
    if after_end > 0 && !cfg.trim_second {
        return Err(AlignError::SecondStream(format!(
            "{}: {after_end} frame(s) at the second frame step fall after the flash video ends ({flash_end_s:.2} s after the sync point): the second video must stop before the flash video (paper 3.3); trim it, or pass --trim-second to drop them",
            video.display()
        )));
    }
    if kept.is_empty() {
        return Err(AlignError::SecondStream(format!(
            "{}: no frame lies within the flash video's time span after synchronisation (offset {sync_offset_s:.3} s)",
            video.display()
        )));
    }
    let intrinsics = svbrdf_core::geometry::Intrinsics::from_fov(
        kept[0].width,
        kept[0].height,
        cfg.second_camera.fov_deg,
    )?;
    let summary = SecondStreamSummary {
        video: video.to_path_buf(),
        fps,
        sync_offset_s,
        onset,
        before_onset,
        after_end,
        frames: DropCounts::default(),
        cross_pairs: 0,
    };
    Ok((
        matching::SecondFrames {
            frames: kept,
            intrinsics,
        },
        summary,
    ))
}
