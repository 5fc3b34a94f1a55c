//! Two-camera synchronisation (paper 3.3): find where the flash first lights the scene
//! in the second (no-flash) stream and put every second-stream frame on the flash
//! camera's clock.
//!
//! Assumption, as in the paper's capture protocol: the flash camera's first frame is
//! the moment its flash turns on (the phone lights the torch as it starts recording),
//! so flash-clock time 0 is the onset seen by the second camera.
//!
//! A rolling shutter reads rows top to bottom, so in the frame where the flash comes on
//! only the rows read after the onset are lit. The first lit row places the onset
//! within that frame: `t_onset = t_frame + row / height * readout`.

use std::path::Path;

use svbrdf_core::color::srgb8_to_linear_table;
use svbrdf_core::geometry::Vec3;
use svbrdf_core::image::ImageU8;
use svbrdf_cv::video::VideoReader;

use crate::{AlignError, Progress};

/// Horizontal bands per frame in the brightness profile.
pub const BANDS: usize = 48;

/// Mean linear luminance of each horizontal band of a frame (every 4th pixel).
pub fn band_profile(img: &ImageU8, lut: &[f32; 256]) -> Vec<f64> {
    let mut sum = vec![0f64; BANDS];
    let mut n = vec![0u32; BANDS];
    for y in (0..img.height).step_by(2) {
        let b = (y * BANDS / img.height.max(1)).min(BANDS - 1);
        let row = &img.data[y * img.width * 3..(y + 1) * img.width * 3];
        for p in row.chunks_exact(3).step_by(4) {
            sum[b] += f64::from(
                0.2126 * lut[p[0] as usize]
                    + 0.7152 * lut[p[1] as usize]
                    + 0.0722 * lut[p[2] as usize],
            );
            n[b] += 1;
        }
    }
    sum.iter()
        .zip(&n)
        .map(|(s, c)| s / f64::from((*c).max(1)))
        .collect()
}

/// Where the flash comes on in the second stream.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Onset {
    /// Onset time on the second stream's clock (its frame 0 at 0 s), seconds.
    pub time_s: f64,
    /// First frame with any lit rows.
    pub frame: u64,
    /// Fraction of that frame's rows (from the top) still unlit, in [0, 1).
    pub unlit_fraction: f64,
    /// Brightness before and after the onset (mean linear luminance).
    pub before: f64,
    /// See `before`.
    pub after: f64,
}

/// Find the flash onset in per-frame band profiles. `readout_s` of 0 means unknown:
/// the readout is then taken as the whole frame period, which bounds the error by one
/// frame.
pub fn find_onset(profiles: &[Vec<f64>], fps: f64, readout_s: f64) -> Result<Onset, String> {
    let n = profiles.len();
    if n < 3 {
        return Err(format!(
            "only {n} frames: too short to find the flash onset"
        ));
    }
    let mean = |p: &Vec<f64>| p.iter().sum::<f64>() / p.len().max(1) as f64;
    let m: Vec<f64> = profiles.iter().map(mean).collect();
    // The onset spreads over at most two frames (rolling shutter); take the largest
    // two-frame rise, then the first frame of it that has lit rows.
    let (mut best, mut at) = (f64::NEG_INFINITY, 0usize);
    for j in 1..n - 1 {
        let rise = m[j + 1] - m[j - 1];
        if rise > best {
            best = rise;
            at = j;
        }
    }
    // Levels: everything before the rise, and the few frames after it.
    let lo_end = at; // frames [0, at) are candidates for "dark"
    let before_frames = &m[..lo_end.max(1)];
    let before = before_frames.iter().copied().fold(f64::INFINITY, f64::min);
    let after_frames = &m[(at + 1).min(n - 1)..(at + 6).min(n)];
    let after = after_frames.iter().sum::<f64>() / after_frames.len().max(1) as f64;
    // Noise of the dark level, from the frames before the rise.
    let spread = before_frames
        .iter()
        .map(|v| (v - before).abs())
        .fold(0.0, f64::max);
    if !(after > 1.5 * before + 0.01 && after - before > 4.0 * spread) {
        return Err(format!(
            "no flash onset found: the brightness never jumps (darkest {before:.4}, after the largest rise {after:.4}, linear); does the second video start before the flash video?"
        ));
    }
    // The first frame whose bottom band is lit.
    let profile_lit =
        |p: &Vec<f64>, b: usize, lo: &Vec<f64>, hi: &Vec<f64>| p[b] > 0.5 * (lo[b] + hi[b]);
    let dark = &profiles[at.saturating_sub(1)];
    let lit = &profiles[(at + 2).min(n - 1)];
    let mut frame = at;
    if at >= 1 && profile_lit(&profiles[at - 1], BANDS - 1, dark, lit) {
        frame = at - 1;
    }
    while frame < n - 1 && !profile_lit(&profiles[frame], BANDS - 1, dark, lit) {
        frame += 1;
    }
    let p = &profiles[frame];
    let first_lit_band = (0..BANDS)
        .find(|&b| profile_lit(p, b, dark, lit))
        .unwrap_or(0);
    let period = 1.0 / fps;
    let readout = if readout_s > 0.0 { readout_s } else { period };
    let time_s = if first_lit_band == 0 {
        // Fully lit: the onset fell between the previous frame's last row and this
        // frame's first row.
        let prev_end = (frame as f64 - 1.0) * period + readout;
        0.5 * (prev_end.min(frame as f64 * period) + frame as f64 * period)
    } else {
        frame as f64 * period + first_lit_band as f64 / BANDS as f64 * readout
    };
    Ok(Onset {
        time_s,
        frame: frame as u64,
        unlit_fraction: first_lit_band as f64 / BANDS as f64,
        before,
        after,
    })
}

/// Decode every frame of the second video (onset detection needs each one) and return
/// the band profiles and frame rate. Memory: one profile per frame.
pub fn decode_profiles(
    video: &Path,
    progress: &dyn Progress,
) -> Result<(Vec<Vec<f64>>, f64), AlignError> {
    let mut reader = VideoReader::open(video)?;
    let info = reader.info();
    let lut = srgb8_to_linear_table();
    progress.stage("second video: flash onset", info.frame_count);
    let mut out = Vec::with_capacity(info.frame_count as usize);
    while let Some(img) = reader.read()? {
        out.push(band_profile(&img, &lut));
        progress.advance(1);
    }
    progress.finish();
    Ok((out, info.fps))
}

/// The flash-clock time of second-stream frame `index`, given the onset on the second
/// stream's clock (seconds) and its frame rate.
pub fn flash_time(index: u64, fps: f64, onset_s: f64) -> f64 {
    index as f64 / fps - onset_s
}

/// Linear interpolation of a time-sorted track; `None` outside its span (one
/// millisecond of slack at either end).
pub fn interpolate_track(track: &[(f64, Vec3)], t: f64) -> Option<Vec3> {
    let (first, last) = (track.first()?, track.last()?);
    if t < first.0 - 1e-3 || t > last.0 + 1e-3 {
        return None;
    }
    let k = track.partition_point(|(tt, _)| *tt <= t);
    if k == 0 {
        return Some(first.1);
    }
    if k == track.len() {
        return Some(last.1);
    }
    let ((t0, a), (t1, b)) = (track[k - 1], track[k]);
    let u = if t1 > t0 { (t - t0) / (t1 - t0) } else { 0.0 };
    Some(a + (b - a) * u)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Profiles of a synthetic stream: dark until `onset` (seconds), then lit, with a
    /// rolling shutter of `readout` seconds.
    fn stream(n: usize, fps: f64, onset: f64, readout: f64) -> Vec<Vec<f64>> {
        (0..n)
            .map(|j| {
                (0..BANDS)
                    .map(|b| {
                        let t = j as f64 / fps + (b as f64 + 0.5) / BANDS as f64 * readout;
                        let tex = 0.02 * ((j * 7 + b * 3) % 5) as f64 / 5.0;
                        if t >= onset {
                            0.3 + tex
                        } else {
                            0.02 + 0.2 * tex
                        }
                    })
                    .collect()
            })
            .collect()
    }

    #[test]
    fn onset_within_a_frame_with_and_without_readout() {
        // Second phones at other frame rates than the flash phone's 30 fps.
        for fps in [24.0, 30.0, 60.0] {
            let readout = 0.6 / fps;
            for onset in [0.2, 0.413, 0.5001, 1.0] {
                let p = stream(90, fps, onset, readout);
                let o = find_onset(&p, fps, readout).unwrap();
                // Between two frames, the gap (period - readout) bounds the onset.
                assert!((o.time_s - onset).abs() < 0.5 / fps, "{fps} {onset}: {o:?}");
                let o = find_onset(&p, fps, 0.0).unwrap();
                assert!((o.time_s - onset).abs() < 1.0 / fps, "{fps} {onset}: {o:?}");
                // Frame times on the flash clock follow.
                let j = o.frame + 3;
                let t = flash_time(j, fps, o.time_s);
                assert!((t - (j as f64 / fps - onset)).abs() < 1.0 / fps);
            }
        }
    }

    #[test]
    fn no_onset_is_an_error_that_says_so() {
        let p = stream(60, 30.0, -1.0, 0.02);
        let e = find_onset(&p, 30.0, 0.02).unwrap_err();
        assert!(e.contains("no flash onset"), "{e}");
        assert!(find_onset(&p[..2], 30.0, 0.02).is_err());
    }

    #[test]
    fn light_track_interpolates_inside_and_refuses_outside() {
        let track = vec![
            (0.0, Vec3::new(0.0, 0.0, 10.0)),
            (0.5, Vec3::new(1.0, 2.0, 12.0)),
            (1.0, Vec3::new(3.0, 2.0, 12.0)),
        ];
        let p = interpolate_track(&track, 0.25).unwrap();
        assert!((p - Vec3::new(0.5, 1.0, 11.0)).norm() < 1e-12);
        let p = interpolate_track(&track, 0.75).unwrap();
        assert!((p - Vec3::new(2.0, 2.0, 12.0)).norm() < 1e-12);
        assert_eq!(interpolate_track(&track, 1.0), Some(track[2].1));
        assert!(interpolate_track(&track, -0.01).is_none());
        assert!(interpolate_track(&track, 1.01).is_none());
        assert!(interpolate_track(&[], 0.0).is_none());
    }
}
