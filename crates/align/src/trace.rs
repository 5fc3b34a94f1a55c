//! What alignment tried, frame by frame (issue 18 item 5): every sampled frame's blur
//! metric, the whole markers it showed, how many matches with the reference photo its
//! verification kept, the piece of the connectivity map it fell in, and what became of
//! it. A refused alignment writes this into `align.json` (`status: "refused"`) so that
//! the refusal can be read frame by frame instead of guessed from one line.

use crate::frames::FrameData;

/// What became of a sampled frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Fate {
    /// Registered and written into the capture.
    Kept,
    /// Dropped by the blur metric (eq. 1).
    Blurry,
    /// In a piece of the connectivity map that nothing tied to the plane.
    Disconnected,
    /// In a tied piece, but no usable homography (too few fine matches, no pose).
    Unregistered,
    /// Registered, but too few of its sub-frames fixed by correspondences of their own.
    Unsupported,
    /// Camera pose outside the marker boundary (or, second stream, outside the flash
    /// video's time span).
    Outside,
    /// Dropped by the self-check against the reference photo.
    Inconsistent,
    /// Registered with plane ties, but not confirmed by the reference photo's texture.
    Unconfirmed,
    /// Alignment stopped before this frame's fate was decided.
    NotReached,
}

impl Fate {
    fn label(self) -> &'static str {
        match self {
            Self::Kept => "kept",
            Self::Blurry => "blurry",
            Self::Disconnected => "disconnected",
            Self::Unregistered => "unregistered",
            Self::Unsupported => "mostly extrapolated",
            Self::Outside => "outside",
            Self::Inconsistent => "inconsistent",
            Self::Unconfirmed => "unconfirmed",
            Self::NotReached => "not reached",
        }
    }
}

/// One sampled frame, as alignment saw it.
#[derive(Debug, Clone, serde::Serialize, serde::Deserialize)]
pub struct FrameTrace {
    /// Frame number in its video.
    pub frame: u64,
    /// Camera stream: 0 the flash video, 1 the second video.
    pub stream: u32,
    /// File name, for still photos.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub file: Option<String>,
    /// Time on the flash camera's clock, seconds.
    pub time_s: f64,
    /// Eq. (1) (higher is sharper).
    pub blur: f64,
    /// Ids of the whole markers found in the frame (of the camera's dictionary).
    pub markers: Vec<i32>,
    /// Matches with the reference photo that the frame's verification kept (`None`:
    /// not tried, because the frame was dropped before or alignment stopped earlier).
    pub reference_matches: Option<usize>,
    /// Index into [`AlignTrace::pieces`] (`None`: blurry, second stream, or not reached).
    pub piece: Option<usize>,
    /// What became of it.
    pub fate: Fate,
    /// Added by the marker hunt (not one of the `frame_step` samples).
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub hunted: bool,
}

/// Alignment's record of what it tried.
#[derive(Debug, Clone, Default, serde::Serialize, serde::Deserialize)]
pub struct AlignTrace {
    /// Every sampled frame, in the order decoded (flash stream, then the second).
    pub per_frame: Vec<FrameTrace>,
    /// The pieces of the coarse connectivity map, largest first: the flash frames (video
    /// frame numbers) of each.
    pub pieces: Vec<Vec<u64>>,
    /// Verified matches with the reference photo that a frame needs to be anchored by
    /// them (a whole marker of the reference photo's anchors it too).
    pub reference_matches_needed: Option<usize>,
    /// Coarse pairs tested and pairs verified by RANSAC.
    pub coarse_pairs_tested: usize,
    /// Coarse pairs verified.
    pub coarse_pairs_verified: usize,
    /// Extent of the registered flash camera's positions, cm (once measured).
    pub sweep_cm: Option<f64>,
    /// Share of the region seen by enough registered frames (once measured).
    pub coverage: Option<f64>,
    /// The marker hunt, where it ran.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub marker_hunt: Option<crate::hunt::MarkerHunt>,
    /// The first pass and a second from more frames, where both ran (`densify`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub densified: Option<crate::densify::Densified>,
}

impl AlignTrace {
    /// Add decoded frames (all not reached yet).
    pub fn add_frames(&mut self, frames: &[FrameData]) {
        self.per_frame.extend(frames.iter().map(|f| FrameTrace {
            frame: f.index,
            stream: f.stream,
            file: f.file.clone(),
            time_s: f.time_s,
            blur: f.blur,
            markers: f.markers.iter().map(|m| m.id).collect(),
            reference_matches: None,
            piece: None,
            fate: Fate::NotReached,
            hunted: false,
        }));
    }

    /// The record of one frame.
    pub fn frame_mut(&mut self, stream: u32, frame: u64) -> Option<&mut FrameTrace> {
        self.per_frame
            .iter_mut()
            .find(|t| t.stream == stream && t.frame == frame)
    }

    /// Say what became of a frame (unknown frames are ignored).
    pub fn set_fate(&mut self, f: &FrameData, fate: Fate) {
        if let Some(t) = self.frame_mut(f.stream, f.index) {
            t.fate = fate;
        }
    }

    /// Frames of the flash stream per fate, for people: `12 kept, 3 blurry, ...`.
    pub fn describe(&self) -> String {
        let order = [
            Fate::Kept,
            Fate::Blurry,
            Fate::Disconnected,
            Fate::Unregistered,
            Fate::Unsupported,
            Fate::Outside,
            Fate::Inconsistent,
            Fate::Unconfirmed,
            Fate::NotReached,
        ];
        let flash: Vec<&FrameTrace> = self.per_frame.iter().filter(|t| t.stream == 0).collect();
        let parts: Vec<String> = order
            .iter()
            .filter_map(|&fate| {
                let n = flash.iter().filter(|t| t.fate == fate).count();
                (n > 0).then(|| format!("{n} {}", fate.label()))
            })
            .collect();
        let markers = flash.iter().filter(|t| !t.markers.is_empty()).count();
        let best = flash
            .iter()
            .filter_map(|t| t.reference_matches.map(|m| (m, t.frame)))
            .max_by_key(|&(m, f)| (m, std::cmp::Reverse(f)));
        let mut line = format!(
            "{} sampled frames: {}; {markers} showed a whole marker",
            flash.len(),
            if parts.is_empty() {
                "none".to_string()
            } else {
                parts.join(", ")
            }
        );
        if let (Some((m, f)), Some(need)) = (best, self.reference_matches_needed) {
            line.push_str(&format!(
                "; most reference-photo matches: {m} (frame {f}, {need} needed)"
            ));
        }
        if self.pieces.len() > 1 {
            line.push_str(&format!(
                "; the connectivity map fell into {} pieces",
                self.pieces.len()
            ));
        }
        if let Some(d) = &self.densified {
            line.push_str(&format!("; before: {}", d.first.describe()));
        }
        line
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frame(frame: u64, fate: Fate, markers: Vec<i32>, matches: Option<usize>) -> FrameTrace {
        FrameTrace {
            frame,
            stream: 0,
            file: None,
            time_s: frame as f64 / 30.0,
            blur: 1.0,
            markers,
            reference_matches: matches,
            piece: None,
            fate,
            hunted: false,
        }
    }

    #[test]
    fn the_line_counts_fates_and_names_the_closest_frame() {
        let mut t = AlignTrace {
            per_frame: vec![
                frame(0, Fate::Blurry, vec![], None),
                frame(5, Fate::Unregistered, vec![2], Some(3)),
                frame(10, Fate::Unregistered, vec![], Some(7)),
                frame(15, Fate::Disconnected, vec![], Some(7)),
            ],
            pieces: vec![vec![5, 10], vec![15]],
            reference_matches_needed: Some(12),
            ..AlignTrace::default()
        };
        let line = t.describe();
        assert_eq!(
            line,
            "4 sampled frames: 1 blurry, 1 disconnected, 2 unregistered; 1 showed a whole marker; most reference-photo matches: 7 (frame 10, 12 needed); the connectivity map fell into 2 pieces"
        );
        if let Some(f) = t.frame_mut(0, 15) {
            f.fate = Fate::Kept;
        }
        assert!(t
            .describe()
            .starts_with("4 sampled frames: 1 kept, 1 blurry,"));
        assert!(t.frame_mut(1, 15).is_none());
    }

    #[test]
    fn fates_serialise_in_snake_case() {
        let v = serde_json::to_value(Fate::NotReached).unwrap_or_default();
        assert_eq!(v, serde_json::json!("not_reached"));
        let back: Fate =
            serde_json::from_value(serde_json::json!("unsupported")).unwrap_or(Fate::Kept);
        assert_eq!(back, Fate::Unsupported);
    }
}
