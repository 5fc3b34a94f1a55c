//! The marker hunt (issue 18): on a hand-held sweep each marker is fully in view for a
//! moment only (10-20% of the frames on a 10-15 cm sweep), so sampling every
//! `frame_step`-th frame can miss a marker altogether, and a missed marker anchors
//! nothing. When a marker of the reference photo is seen whole in fewer than
//! `marker_views` of the sampled frames, every other frame of the video is decoded and
//! searched for markers only (no features: a tenth of a sampled frame's work), and the
//! sharpest frame of each pass over such a marker joins the frames to register, until
//! the marker is seen `marker_views` times or the passes run out.

use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;
use std::time::Instant;

use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use svbrdf_core::image::ImageU8;
use svbrdf_cv::aruco::{detect_markers, Dictionary};
use svbrdf_cv::video::VideoReader;

use crate::blur::blur_threshold;
use crate::config::AlignConfig;
use crate::frames::{blur_of, coarse_image, process, FrameData, THUMB_LONG};
use crate::{AlignError, Progress};

/// Frames of one pass over a marker lie at most this many frames apart (the sampled
/// frames, which the hunt does not search, sit between them).
const PASS_GAP: u64 = 3;

/// At most this many frames are added in all (and never more than the views still
/// wanted): a bound on the extra work.
const MAX_ADDED: usize = 16;

/// What the marker hunt did, as `align.json` records it.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct MarkerHunt {
    /// The reference photo's markers that the sampled frames showed whole fewer than
    /// `views_wanted` times: (id, sampled frames showing it whole).
    pub wanted: Vec<(i32, usize)>,
    /// Views of each marker wanted (`marker_views`).
    pub views_wanted: u32,
    /// Frames searched: every decoded frame the sampling had not used.
    pub searched: usize,
    /// Frames among them that showed a wanted marker whole.
    pub sightings: usize,
    /// Passes over wanted markers (runs of sightings), over all wanted markers.
    pub passes: usize,
    /// Frames added to those registered (video frame numbers), the sharpest of their
    /// pass, each showing a wanted marker whole.
    pub added: Vec<u64>,
    /// Wanted markers still seen whole fewer than `views_wanted` times after the hunt:
    /// (id, frames showing it whole).
    pub still_short: Vec<(i32, usize)>,
    /// Wall-clock seconds.
    pub seconds: f64,
}

impl MarkerHunt {
    /// One line for the summary.
    pub fn describe(&self) -> String {
        let ids = |v: &[(i32, usize)]| {
            v.iter()
                .map(|(id, n)| format!("{id} ({n}x)"))
                .collect::<Vec<_>>()
                .join(", ")
        };
        let mut s = format!(
            "marker hunt: markers {} were seen whole in fewer than {} sampled frames; {} other frames searched, {} showed one in {} passes, {} added",
            ids(&self.wanted),
            self.views_wanted,
            self.searched,
            self.sightings,
            self.passes,
            self.added.len()
        );
        if !self.added.is_empty() {
            let list: Vec<String> = self.added.iter().map(u64::to_string).collect();
            s += &format!(" (frames {})", list.join(", "));
        }
        if !self.still_short.is_empty() {
            s += &format!("; still short: {}", ids(&self.still_short));
        }
        s += &format!(", {:.1} s", self.seconds);
        s
    }
}

/// A searched frame that showed a wanted marker whole.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Sighting {
    /// Frame number.
    pub index: u64,
    /// Wanted markers seen whole.
    pub ids: Vec<i32>,
    /// Eq. (1) at the coarse scale (higher is sharper).
    pub blur: f64,
}

/// The frames to add: for every wanted marker (id -> views still needed), the
/// sharpest frame of each pass over it (sightings at most `gap` frames apart), sharpest
/// passes first, until it has the views it needs; never a frame with eq. (1) below
/// `min_blur`; at most `cap` frames. A frame chosen for one marker counts for every
/// wanted marker it shows. Returns (frames in time order, passes found).
pub(crate) fn choose(
    sightings: &[Sighting],
    need: &BTreeMap<i32, usize>,
    min_blur: f64,
    gap: u64,
    cap: usize,
) -> (Vec<u64>, usize) {
    // (blur, frame, id) of the best frame of every pass over every wanted marker.
    let mut passes: Vec<(f64, u64, i32)> = Vec::new();
    let mut found = 0;
    for &id in need.keys() {
        let mut seen: Vec<&Sighting> = sightings.iter().filter(|s| s.ids.contains(&id)).collect();
        seen.sort_by_key(|s| s.index);
        let mut start = 0;
        for k in 1..=seen.len() {
            if k == seen.len() || seen[k].index > seen[k - 1].index + gap {
                found += 1;
                let best = seen[start..k]
                    .iter()
                    .filter(|s| s.blur.is_finite() && s.blur >= min_blur)
                    .max_by(|a, b| a.blur.total_cmp(&b.blur).then(b.index.cmp(&a.index)));
                if let Some(b) = best {
                    passes.push((b.blur, b.index, id));
                }
                start = k;
            }
        }
    }
    passes.sort_by(|a, b| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1)));
    let mut need = need.clone();
    let mut chosen = BTreeSet::new();
    for (_, frame, id) in passes {
        if chosen.len() >= cap {
            break;
        }
        if need.get(&id).copied().unwrap_or(0) == 0 || chosen.contains(&frame) {
            continue;
        }
        chosen.insert(frame);
        let shows = sightings
            .iter()
            .find(|s| s.index == frame)
            .map_or(&[][..], |s| &s.ids[..]);
        for i in shows {
            if let Some(n) = need.get_mut(i) {
                *n = n.saturating_sub(1);
            }
        }
    }
    (chosen.into_iter().collect(), found)
}

/// Whole markers of `ids` in a grey frame (searched at the coarse scale, as in
/// [`process`]), and eq. (1) there when one was found.
fn search(
    grey: &ImageU8,
    ids: &BTreeSet<i32>,
    cfg: &AlignConfig,
    dict: Dictionary,
) -> Result<Option<(Vec<i32>, f64)>, AlignError> {
    let coarse = coarse_image(grey, cfg)?;
    let mut found: Vec<i32> = detect_markers(&coarse, dict)?
        .into_iter()
        .map(|m| m.id)
        .filter(|id| ids.contains(id))
        .collect();
    if found.is_empty() {
        return Ok(None);
    }
    found.sort_unstable();
    found.dedup();
    Ok(Some((found, blur_of(&coarse))))
}

/// Views of each id among the frames' whole markers.
fn views(frames: &[FrameData], ids: &[i32]) -> BTreeMap<i32, usize> {
    ids.iter()
        .map(|&id| {
            let n = frames
                .iter()
                .filter(|f| f.markers.iter().any(|m| m.id == id))
                .count();
            (id, n)
        })
        .collect()
}

/// Run the hunt on the flash video when a marker of the reference photo (`ids`) was
/// seen whole in fewer than `cfg.marker_views` sampled frames; returns the frames with
/// those found added (time order) and what was done (`None`: not needed or disabled).
pub fn hunt(
    video: &Path,
    mut frames: Vec<FrameData>,
    ids: &[i32],
    cfg: &AlignConfig,
    dict: Dictionary,
    progress: &dyn Progress,
) -> Result<(Vec<FrameData>, Option<MarkerHunt>), AlignError> {
    let wanted_views = cfg.marker_views as usize;
    let before = views(&frames, ids);
    let need: BTreeMap<i32, usize> = before
        .iter()
        .filter(|(_, &n)| n < wanted_views)
        .map(|(&id, &n)| (id, wanted_views - n))
        .collect();
    if need.is_empty() {
        return Ok((frames, None));
    }
    let start = Instant::now();
    let wanted: BTreeSet<i32> = need.keys().copied().collect();
    let used: BTreeSet<u64> = frames.iter().map(|f| f.index).collect();

    // Search every frame the sampling did not use, a batch at a time in parallel.
    let mut reader = VideoReader::open(video)?;
    let info = reader.info();
    progress.stage("marker hunt", info.frame_count);
    let batch_size = 2 * rayon::current_num_threads().max(1);
    let mut sightings = Vec::new();
    let mut searched = 0usize;
    let mut batch: Vec<(u64, ImageU8)> = Vec::with_capacity(batch_size);
    let mut flush = |batch: &mut Vec<(u64, ImageU8)>| -> Result<(), AlignError> {
        let found: Vec<Option<Sighting>> = std::mem::take(batch)
            .into_par_iter()
            .map(|(index, grey)| {
                Ok(
                    search(&grey, &wanted, cfg, dict)?.map(|(ids, blur)| Sighting {
                        index,
                        ids,
                        blur,
                    }),
                )
            })
            .collect::<Result<_, AlignError>>()?;
        sightings.extend(found.into_iter().flatten());
        Ok(())
    };
    loop {
        let index = reader.next_index();
        if used.contains(&index) {
            if !reader.skip()? {
                break;
            }
            progress.advance(1);
            continue;
        }
        let Some(grey) = reader.read_grey()? else {
            break;
        };
        searched += 1;
        batch.push((index, grey));
        if batch.len() == batch_size {
            flush(&mut batch)?;
        }
        progress.advance(1);
    }
    flush(&mut batch)?;
    progress.finish();

    // Sharp enough: not below what the blur selection would drop among the sampled
    // frames (eq. 1 at the same scale).
    let metrics: Vec<f64> = frames.iter().map(|f| f.blur).collect();
    let min_blur = blur_threshold(&metrics, cfg.blur_sigmas).unwrap_or(f64::NEG_INFINITY);
    let cap = (need.values().sum::<usize>()).min(MAX_ADDED);
    let (chosen, passes) = choose(&sightings, &need, min_blur, PASS_GAP, cap);

    // Decode the chosen frames again and do the full per-frame work on them.
    let mut added = Vec::new();
    if let Some(&last) = chosen.last() {
        let chosen_set: BTreeSet<u64> = chosen.iter().copied().collect();
        let mut reader = VideoReader::open(video)?;
        let mut luma = Vec::new();
        while reader.next_index() <= last {
            let index = reader.next_index();
            if chosen_set.contains(&index) {
                match reader.read_luma(THUMB_LONG)? {
                    Some(f) => luma.push((index, reader.time_s(), f)),
                    None => break,
                }
            } else if !reader.skip()? {
                break;
            }
        }
        let processed: Vec<FrameData> = luma
            .into_par_iter()
            .map(|(index, time_s, f)| {
                let mut d = process(f, None, index, info.fps, cfg, dict)?;
                d.time_s = time_s;
                Ok(d)
            })
            .collect::<Result<_, AlignError>>()?;
        for d in processed {
            // The full-resolution search must agree with the coarse one.
            if d.markers.iter().any(|m| wanted.contains(&m.id)) {
                added.push(d.index);
                frames.push(d);
            }
        }
        frames.sort_by_key(|f| f.index);
    }
    let after = views(&frames, ids);
    let still_short = after
        .iter()
        .filter(|(id, &n)| wanted.contains(id) && n < wanted_views)
        .map(|(&id, &n)| (id, n))
        .collect();
    Ok((
        frames,
        Some(MarkerHunt {
            wanted: before
                .into_iter()
                .filter(|(id, _)| wanted.contains(id))
                .collect(),
            views_wanted: cfg.marker_views,
            searched,
            sightings: sightings.len(),
            passes,
            added,
            still_short,
            seconds: start.elapsed().as_secs_f64(),
        }),
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn s(index: u64, ids: &[i32], blur: f64) -> Sighting {
        Sighting {
            index,
            ids: ids.to_vec(),
            blur,
        }
    }

    #[test]
    fn sharpest_frame_of_each_pass_sharpest_pass_first() {
        // Marker 2: a pass over frames 10-13 (sharpest 12) and one over 40-41 (41).
        let sightings = vec![
            s(10, &[2], -1.0),
            s(11, &[2], -0.9),
            s(12, &[2], -0.5),
            s(13, &[2], -0.8),
            s(40, &[2], -0.7),
            s(41, &[2], -0.6),
        ];
        let need = BTreeMap::from([(2, 1)]);
        assert_eq!(choose(&sightings, &need, -10.0, 3, 8), (vec![12], 2));
        let need = BTreeMap::from([(2, 2)]);
        assert_eq!(choose(&sightings, &need, -10.0, 3, 8), (vec![12, 41], 2));
        // A third view is wanted but there are only two passes.
        let need = BTreeMap::from([(2, 3)]);
        assert_eq!(choose(&sightings, &need, -10.0, 3, 8).0, vec![12, 41]);
        // The cap holds.
        assert_eq!(choose(&sightings, &need, -10.0, 3, 1).0, vec![12]);
    }

    #[test]
    fn blurry_frames_are_never_chosen_and_passes_split_at_gaps() {
        // Frames 10 and 14 are 4 apart: two passes at gap 3, one at gap 4.
        let sightings = vec![s(10, &[1], -0.4), s(14, &[1], -2.0)];
        let need = BTreeMap::from([(1, 2)]);
        assert_eq!(choose(&sightings, &need, -1.0, 3, 8), (vec![10], 2));
        assert_eq!(choose(&sightings, &need, -1.0, 4, 8), (vec![10], 1));
        // Every frame of the pass blurry: nothing, although the marker is wanted.
        assert_eq!(choose(&sightings, &need, 0.0, 3, 8), (vec![], 2));
        // A NaN metric is never chosen.
        let sightings = vec![s(5, &[1], f64::NAN)];
        assert_eq!(choose(&sightings, &need, -1.0, 3, 8).0, Vec::<u64>::new());
    }

    #[test]
    fn a_frame_showing_two_wanted_markers_counts_for_both() {
        let sightings = vec![s(20, &[0, 3], -0.3), s(50, &[3], -0.4), s(80, &[0], -0.5)];
        let need = BTreeMap::from([(0, 1), (3, 1)]);
        assert_eq!(choose(&sightings, &need, -1.0, 3, 8).0, vec![20]);
        // Markers nobody wants are ignored.
        let need = BTreeMap::from([(3, 2)]);
        assert_eq!(choose(&sightings, &need, -1.0, 3, 8).0, vec![20, 50]);
    }
}
