//! More frames where the sampled ones leave the region thin (issue 18 item 2: "when a
//! stretch of frames is not anchored at the chosen frame step, use more frames there
//! rather than give up").
//!
//! At the camera's `frame_step` a hand-held sweep over repetitive texture can leave
//! stretches of frames that neither a marker, the reference photo nor their
//! neighbours tie down well enough: they are left out (unconfirmed, disconnected,
//! unregistered), and the region they saw is seen by too few kept frames, or the run
//! is refused. Frames sampled twice as densely overlap their neighbours more and
//! shorten each stretch between anchors: on the three Mitsuba-rendered tiles captures
//! (session 41, docs/BENCHMARKS.md) every 5th frame was refused (55% of the region seen
//! by 3 kept frames) or left 63.8% and 91.0%, where every 2nd gave 97.2%, 100% and
//! 100%. So where the first pass is refused, or leaves less
//! than [`GOOD_COVERAGE`] of the region seen by [`COVERAGE_VIEWS`](crate::COVERAGE_VIEWS)
//! kept frames, the video is aligned again from every `frame_step / 2`-th frame, and
//! the pass that registers more of the region is written. `align.json`
//! (`summary.densified`, or the refusal's `trace.densified`) says what both passes
//! gave. The second pass is a whole pass, not the thin stretches alone: which frames
//! fail depends on every frame around them (the connectivity map, the global solve),
//! so frames added in one stretch change the others too.
use serde::{Deserialize, Serialize};

use crate::GOOD_COVERAGE;

/// What one pass over the video gave.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PassOutcome {
    /// Every `frame_step`-th frame (the sharpest of its window) was sampled.
    pub frame_step: u32,
    /// Frames sampled (flash video).
    pub sampled: usize,
    /// Frames kept.
    pub kept: usize,
    /// Share of the region seen by enough kept frames, where the pass registered (or
    /// got as far as measuring it).
    pub coverage: Option<f64>,
    /// Why the pass was refused, where it was.
    pub refusal: Option<String>,
}

impl PassOutcome {
    /// Whether this pass leaves the region thin enough to try more frames: refused, or
    /// seen by enough kept frames over less than [`GOOD_COVERAGE`] of it.
    pub fn thin(&self) -> bool {
        self.refusal.is_some() || self.coverage.is_none_or(|c| c < GOOD_COVERAGE)
    }

    /// One phrase for people: `every 5th frame: 16 of 26 kept, 63.8% of the region
    /// covered` or `every 5th frame: refused (...)`.
    pub fn describe(&self) -> String {
        let what = match (&self.refusal, self.coverage) {
            (Some(r), _) => {
                // The first clause is enough here; the record holds the whole line.
                let short = r.split(" (").next().unwrap_or(r);
                format!("refused ({short})")
            }
            (None, Some(c)) => format!("{:.1}% of the region covered", 100.0 * c),
            (None, None) => "registered".into(),
        };
        format!(
            "every {} frame: {} of {} kept, {what}",
            ordinal(self.frame_step),
            self.kept,
            self.sampled
        )
    }
}

/// Both passes, where the second ran.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Densified {
    /// At the camera's `frame_step`.
    pub first: PassOutcome,
    /// At half of it.
    pub finer: PassOutcome,
    /// Whether the finer pass is the one written.
    pub kept_finer: bool,
}

impl Densified {
    /// One line for people.
    pub fn describe(&self) -> String {
        format!(
            "frame step: {}; aligned again from {}; {} kept",
            self.first.describe(),
            self.finer.describe(),
            if self.kept_finer {
                "the finer pass"
            } else {
                "the first pass"
            }
        )
    }
}

/// The frame step of the second pass: half the first's, where that is at least 1.
pub fn finer_step(step: u32) -> Option<u32> {
    (step >= 2).then_some(step / 2)
}

/// Whether the finer pass is written instead of the first: where it registers and the
/// first was refused, or it covers more of the region.
pub fn prefer_finer(first: &PassOutcome, finer: &PassOutcome) -> bool {
    if finer.refusal.is_some() {
        return false;
    }
    if first.refusal.is_some() {
        return true;
    }
    finer.coverage.unwrap_or(0.0) > first.coverage.unwrap_or(0.0)
}

/// `2nd`, `3rd`, `5th`; `1` is `every frame` in English, written `1st` here.
fn ordinal(n: u32) -> String {
    let suffix = match (n % 10, n % 100) {
        (_, 11..=13) => "th",
        (1, _) => "st",
        (2, _) => "nd",
        (3, _) => "rd",
        _ => "th",
    };
    format!("{n}{suffix}")
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pass(step: u32, coverage: Option<f64>, refusal: Option<&str>) -> PassOutcome {
        PassOutcome {
            frame_step: step,
            sampled: 26,
            kept: 16,
            coverage,
            refusal: refusal.map(String::from),
        }
    }

    #[test]
    fn the_finer_step_halves_down_to_every_frame() {
        assert_eq!(finer_step(5), Some(2));
        assert_eq!(finer_step(10), Some(5));
        assert_eq!(finer_step(3), Some(1));
        assert_eq!(finer_step(2), Some(1));
        assert_eq!(finer_step(1), None);
    }

    #[test]
    fn a_pass_is_thin_when_refused_or_under_the_good_coverage() {
        assert!(pass(5, Some(0.6), None).thin());
        assert!(pass(5, None, Some("only 59.7% of the region")).thin());
        assert!(pass(5, Some(0.5), Some("only 50%")).thin());
        assert!(!pass(5, Some(GOOD_COVERAGE), None).thin());
        assert!(!pass(5, Some(1.0), None).thin());
    }

    #[test]
    fn the_finer_pass_is_kept_where_it_registers_more() {
        let refused = pass(5, Some(0.597), Some("only 59.7%"));
        let thin = pass(5, Some(0.638), None);
        let full = pass(2, Some(1.0), None);
        let less = pass(2, Some(0.61), None);
        let finer_refused = pass(2, None, Some("no frame could be tied"));
        assert!(prefer_finer(&refused, &full));
        assert!(prefer_finer(&refused, &less));
        assert!(prefer_finer(&thin, &full));
        assert!(!prefer_finer(&thin, &less));
        assert!(!prefer_finer(&thin, &finer_refused));
        // Both refused: the first pass's refusal stands (`align` reports the finer one's
        // trace, which tried more frames, but nothing is written either way).
        assert!(!prefer_finer(&refused, &finer_refused));
    }

    #[test]
    fn both_passes_are_described_in_one_line() {
        let d = Densified {
            first: pass(
                5,
                Some(0.597),
                Some("only 59.7% of the region is seen (72 of 360 sub-frames)"),
            ),
            finer: PassOutcome {
                frame_step: 2,
                sampled: 61,
                kept: 46,
                coverage: Some(0.972),
                refusal: None,
            },
            kept_finer: true,
        };
        assert_eq!(
            d.describe(),
            "frame step: every 5th frame: 16 of 26 kept, refused (only 59.7% of the region is seen); aligned again from every 2nd frame: 46 of 61 kept, 97.2% of the region covered; the finer pass kept"
        );
        assert_eq!(ordinal(1), "1st");
        assert_eq!(ordinal(3), "3rd");
        assert_eq!(ordinal(11), "11th");
        assert_eq!(ordinal(22), "22nd");
    }
}
