//! The self-check after the global solve: every kept frame, warped to the plane with
//! its own solution, is compared with the reference photo, which the markers alone tie
//! to the plane. The solve's residual only says how well the frames agree with each
//! other; a chain of frames that drifted together, or a capture anchored one tile off
//! on a repetitive texture, has a small residual and a large error. The reference
//! photo does not share those errors.
//!
//! Per frame, blocks of the plane (4 cm) are matched between the frame and the
//! reference by normalised cross-correlation of their colours (per channel, so the
//! flash-versus-room lighting change and the colour of the light cancel), first at
//! 4 mm cells over +-4 cm, then at 1 mm cells around the best coarse shift, with a
//! sub-cell parabola. Clipped pixels (the flash highlight) are left out. A frame's
//! displacement is the median over its blocks that match clearly.

use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use svbrdf_core::capture::PreparedMapping;
use svbrdf_core::geometry::Vec2;
use svbrdf_core::homography::Homography;
use svbrdf_core::image::ImageU8;
use svbrdf_core::plane::{PlaneGrid, Region};

mod consensus;
mod plane_image;
mod trim;

pub use consensus::agreeing_blocks;
#[cfg(test)]
pub(crate) use consensus::tests::lattice;
use consensus::{consensus, warp};
use plane_image::{best_shift, parabola, rectify, PlaneImage, MIN_VALID};
pub use trim::{bent_blocks, leave_out_bent, on_blocks, MAX_BEND_MM};

/// Fine cells per cm of the comparison grid.
const FINE_PX_PER_CM: f64 = 10.0;
/// Coarse cells are this many fine cells.
const COARSE: usize = 4;
/// Block side in coarse cells (4 cm).
const BLOCK_COARSE: usize = 10;
/// Coarse search radius in coarse cells (4 cm).
const SEARCH_COARSE: i32 = 10;
/// Fine search radius around the coarse shift, fine cells.
const SEARCH_FINE: i32 = 6;
/// A block matches clearly above this correlation.
const MIN_SCORE: f64 = 0.6;
/// A match away from the registered position must beat the best one near it by this
/// much correlation to count.
const AMBIGUITY: f64 = 0.1;

/// Settings of the self-check.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct SelfCheckConfig {
    /// Run it at all.
    pub enabled: bool,
    /// A frame whose median displacement from the reference photo exceeds this is
    /// inconsistent, mm.
    pub max_shift_mm: f64,
    /// Refuse the capture when more than this share of the checked frames is
    /// inconsistent (below it, the inconsistent frames are dropped).
    pub max_inconsistent_share: f64,
}

impl Default for SelfCheckConfig {
    fn default() -> Self {
        Self {
            enabled: true,
            max_shift_mm: 1.0,
            max_inconsistent_share: 0.2,
        }
    }
}

/// The check of one frame.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FrameCheck {
    /// Index of the frame in the registration (kept-frame order).
    pub kept_index: usize,
    /// Frame number in its video.
    pub frame: u64,
    /// Camera stream.
    pub stream: u32,
    /// Blocks compared (enough of them seen in both images).
    pub blocks: usize,
    /// Blocks that matched clearly.
    pub matched: usize,
    /// Matched blocks that agree on the frame's displacement (see `shift_mm`).
    #[serde(default)]
    pub agreeing: usize,
    /// Displacement from the reference photo that the largest group of agreeing
    /// matched blocks shows (within 0.5 mm or a quarter of it; the median of theirs),
    /// mm (`None`: no block matched clearly, or no group holds a third of them: the
    /// frame is unverified).
    pub shift_mm: Option<f64>,
    /// Largest displacement of a matched block, mm.
    pub max_shift_mm: Option<f64>,
    /// Median correlation of the matched blocks.
    pub score: Option<f64>,
    /// Displacement from the reference photo where the frame's blocks agree on one
    /// affine field rather than one shift (a frame registered warped: parts of it off
    /// by different amounts), mm: the 75th percentile of the field's length over the
    /// blocks that agree with it (`None`: no such field holds clearly more blocks than
    /// the shift does; see [`warp`]).
    #[serde(default)]
    pub warp_mm: Option<f64>,
    /// Matched blocks that agree with that affine field.
    #[serde(default)]
    pub warp_agreeing: usize,
    /// Every matched block: its centre on the plane (world cm) and where the reference
    /// photo shows its texture relative to it (world axes, mm), as
    /// `[x_cm, y_cm, dx_mm, dy_mm]`.
    #[serde(default)]
    pub block_shifts: Vec<[f64; 4]>,
}

impl FrameCheck {
    /// Whether this frame disagrees with the reference photo beyond `limit_mm`.
    pub fn inconsistent(&self, limit_mm: f64) -> bool {
        self.offset_mm().is_some_and(|s| s > limit_mm)
    }

    /// How far the frame lies from the reference photo, mm: its shift, or where its
    /// blocks agree on a warp, the larger of the two.
    pub fn offset_mm(&self) -> Option<f64> {
        match (self.shift_mm, self.warp_mm) {
            (Some(s), Some(w)) => Some(s.max(w)),
            (s, w) => s.or(w),
        }
    }
}

/// One frame to check: its thumbnail, full-resolution size and sub-frame mapping.
pub struct CheckedFrame<'a> {
    /// Frame number in its video.
    pub frame: u64,
    /// Camera stream.
    pub stream: u32,
    /// Colour thumbnail.
    pub thumb: &'a ImageU8,
    /// Full-resolution width, pixels (the mapping's coordinates).
    pub width: u32,
    /// The frame's mapping (full-resolution pixels <-> plane cm).
    pub mapping: PreparedMapping,
}

/// Compare every frame with the reference photo over `region`.
pub fn check(
    reference: &ImageU8,
    reference_plane_from_pixel: &Homography,
    region: Region,
    frames: &[CheckedFrame],
) -> Vec<FrameCheck> {
    let Ok(grid) = PlaneGrid::new(region, FINE_PX_PER_CM) else {
        return Vec::new();
    };
    let Some(ref_pixel) = reference_plane_from_pixel.inverse() else {
        return Vec::new();
    };
    let ref_fine = rectify(&grid, reference, &|q| ref_pixel.apply(q));
    let ref_coarse = ref_fine.reduce(COARSE);
    frames
        .par_iter()
        .enumerate()
        .map(|(k, f)| {
            let s = f.thumb.width as f64 / f64::from(f.width);
            let fine = rectify(&grid, f.thumb, &|q| {
                f.mapping
                    .plane_to_pixel(q)
                    .map(|p| Vec2::new((p.x + 0.5) * s - 0.5, (p.y + 0.5) * s - 0.5))
            });
            let mut c = check_frame(k, f, &fine, &ref_fine, &ref_coarse);
            // Grid cells (rows downwards from the region's top edge) to world axes; the
            // warp's affine field is the same field in either.
            for b in &mut c.block_shifts {
                *b = [
                    grid.region.x_min + b[0],
                    grid.region.y_max - b[1],
                    b[2],
                    -b[3],
                ];
            }
            c
        })
        .collect()
}

fn check_frame(
    k: usize,
    f: &CheckedFrame,
    fine: &PlaneImage,
    ref_fine: &PlaneImage,
    ref_coarse: &PlaneImage,
) -> FrameCheck {
    let coarse = fine.reduce(COARSE);
    let n = BLOCK_COARSE;
    let mut shifts = Vec::new();
    let mut centres = Vec::new();
    let mut scores = Vec::new();
    let mut blocks = 0;
    // Blocks on a half-overlapping lattice of coarse cells.
    let step = (n / 2).max(1);
    let mut by = 0;
    while by + n <= coarse.h {
        let mut bx = 0;
        while bx + n <= coarse.w {
            let seen = (0..n * n)
                .filter(|i| {
                    coarse
                        .get((bx + i % n) as i64, (by + i / n) as i64)
                        .is_some()
                })
                .count();
            if (seen as f64) >= MIN_VALID * (n * n) as f64 {
                blocks += 1;
                let (fx, fy) = ((bx * COARSE) as i64, (by * COARSE) as i64);
                // Near the registered position, and anywhere in the search range.
                let local = best_shift(fine, ref_fine, fx, fy, n * COARSE, (0, 0), SEARCH_FINE);
                let global = best_shift(
                    &coarse,
                    ref_coarse,
                    bx as i64,
                    by as i64,
                    n,
                    (0, 0),
                    SEARCH_COARSE,
                )
                .and_then(|(c, _, _)| {
                    let centre = (c.0 * COARSE as i64, c.1 * COARSE as i64);
                    best_shift(fine, ref_fine, fx, fy, n * COARSE, centre, SEARCH_FINE)
                });
                // A far match counts only when it is clearly better than the best near
                // the registered position: on a repetitive texture several positions
                // match about equally, and the registration's own is then believed.
                let chosen = match (local, global) {
                    (Some(l), Some(g)) if l.1 >= g.1 - AMBIGUITY => Some(l),
                    (_, Some(g)) => Some(g),
                    (l, None) => l,
                };
                if let Some((s, v, nb)) = chosen.filter(|c| c.1 >= MIN_SCORE) {
                    let dx = s.0 as f64 + parabola(nb[0], v, nb[1]);
                    let dy = s.1 as f64 + parabola(nb[2], v, nb[3]);
                    shifts.push((10.0 * dx / FINE_PX_PER_CM, 10.0 * dy / FINE_PX_PER_CM));
                    let centre = |b: usize| (b * COARSE) as f64 + 0.5 * (n * COARSE) as f64;
                    centres.push((centre(bx) / FINE_PX_PER_CM, centre(by) / FINE_PX_PER_CM));
                    scores.push(v);
                }
            }
            bx += step;
        }
        by += step;
    }
    let median = |v: &mut Vec<f64>| {
        v.sort_by(f64::total_cmp);
        (!v.is_empty()).then(|| v[v.len() / 2])
    };
    let blocks_mm: Vec<[f64; 4]> = centres
        .iter()
        .zip(&shifts)
        .map(|(c, s)| [c.0, c.1, s.0, s.1])
        .collect();
    let mut c = summarise(k, f.frame, f.stream, blocks, blocks_mm);
    c.score = median(&mut scores);
    c
}

/// The check of a frame (`kept_index`, video `frame`, `stream`) from the blocks
/// compared (`blocks`) and those that matched clearly (`[x, y, dx_mm, dy_mm]`): the
/// displacement they agree on, as a shift or as an affine field (no score).
pub(crate) fn summarise(
    kept_index: usize,
    frame: u64,
    stream: u32,
    blocks: usize,
    matched: Vec<[f64; 4]>,
) -> FrameCheck {
    let shifts: Vec<(f64, f64)> = matched.iter().map(|b| (b[2], b[3])).collect();
    let max = shifts
        .iter()
        .map(|s| s.0.hypot(s.1))
        .fold(None, |m: Option<f64>, v| Some(m.map_or(v, |m| m.max(v))));
    let (shift, agreeing) = consensus(&shifts);
    let (warp_mm, warp_agreeing) = warp(&matched, agreeing);
    FrameCheck {
        kept_index,
        frame,
        stream,
        blocks,
        matched: shifts.len(),
        agreeing,
        shift_mm: shift,
        max_shift_mm: max,
        score: None,
        warp_mm,
        warp_agreeing,
        block_shifts: matched,
    }
}
/// How many frames the check verified (their offset is known), and the largest offset
/// among them, mm (0 when none).
pub fn verified(checks: &[FrameCheck]) -> (usize, f64) {
    checks
        .iter()
        .filter_map(FrameCheck::offset_mm)
        .fold((0, 0.0), |(n, m), s| (n + 1, f64::max(m, s)))
}

/// The frames more than `limit_mm` off, said in one clause ("frames 31-68 (5 of 40
/// checked) lie 2.9-3.1 mm (median 3.0 mm) from where the reference photo shows the
/// same texture"), or `None` when no frame is.
pub fn disagreement(checks: &[FrameCheck], limit_mm: f64) -> Option<String> {
    let bad: Vec<&FrameCheck> = checks.iter().filter(|c| c.inconsistent(limit_mm)).collect();
    let mut sorted: Vec<f64> = bad.iter().filter_map(|c| c.offset_mm()).collect();
    if sorted.is_empty() {
        return None;
    }
    sorted.sort_by(f64::total_cmp);
    let frames: Vec<u64> = bad.iter().map(|c| c.frame).collect();
    let bent: Vec<u64> = bad
        .iter()
        .filter(|c| c.warp_mm.is_some_and(|w| w > limit_mm))
        .map(|c| c.frame)
        .collect();
    let bent = if bent.is_empty() {
        String::new()
    } else {
        format!(
            " (frames {} bent: parts of each off by different amounts)",
            ranges(&bent)
        )
    };
    Some(format!(
        "frames {} ({} of {} checked) lie {:.1}-{:.1} mm (median {:.1} mm) from where the reference photo shows the same texture{bent}",
        ranges(&frames),
        bad.len(),
        verified(checks).0,
        sorted[0],
        sorted[sorted.len() - 1],
        sorted[sorted.len() / 2]
    ))
}

/// Output pixels a matched block may lie from the reference photo before its frame is
/// reported as off in parts ([`edge_disagreement`]): issue 18's bound on a frame's p95.
pub const EDGE_PX: f64 = 2.0;
/// ... but never less than this, mm: below it the blocks' own spread has not been
/// measured (4K captures put 2 output pixels at 0.15-0.2 mm).
pub const EDGE_FLOOR_MM: f64 = 0.3;

/// Blocks matched farther than this from where the frame puts them are left out of
/// [`edge_disagreement`], mm: on the captures measured (session 39: 615 verified
/// frames of 18 runs, Mitsuba tiles, hard-small and `paper`) such blocks were pattern
/// repeats, and leaving them out took the right frames named from 77 to 26 while the
/// 6 frames over 2 output px named stayed named.
pub const EDGE_MAX_MM: f64 = 10.0;

/// [`EDGE_PX`] output pixels at `px_per_cm`, at least [`EDGE_FLOOR_MM`], in mm
/// (`None` without a scale).
pub fn edge_mm(px_per_cm: f64) -> Option<f64> {
    (px_per_cm > 0.0).then(|| (10.0 * EDGE_PX / px_per_cm).max(EDGE_FLOOR_MM))
}

/// Frames the self-check verified (their agreeing blocks' median is within the limit)
/// but one of whose matched blocks lies more than [`EDGE_PX`] output pixels (at
/// `px_per_cm`; at least [`EDGE_FLOOR_MM`]) from where the reference photo shows the
/// same texture: a frame right in the middle and off at an edge, which the median
/// does not see. Measured on captures rendered by Mitsuba 3 (session 32: 184 frames of
/// six captures), this flagged 13 of the 31 frames whose true p95 error is over 2
/// output pixels and none of the 153 under it. It is a warning, not a drop: on the
/// simulator's hard-small patchwork seed 2 it names 7 right frames, whose blocks
/// matched a repeated patch 24-54 mm away or lie 0.7-1.1 mm off alone (session 33);
/// blocks over [`EDGE_MAX_MM`] off are not counted since session 39.
/// One line for people, or `None`.
pub fn edge_disagreement(checks: &[FrameCheck], limit_mm: f64, px_per_cm: f64) -> Option<String> {
    let edge_mm = edge_mm(px_per_cm)?;
    let off: Vec<(u64, f64)> = checks
        .iter()
        .filter(|c| c.offset_mm().is_some() && !c.inconsistent(limit_mm))
        .filter_map(|c| {
            // A block matched farther than EDGE_MAX_MM away is a pattern repeat; without
            // blocks (an older record) the largest displacement stands.
            let far = if c.block_shifts.is_empty() {
                c.max_shift_mm
            } else {
                c.block_shifts
                    .iter()
                    .map(|b| b[2].hypot(b[3]))
                    .filter(|m| *m <= EDGE_MAX_MM)
                    .reduce(f64::max)
            };
            far.filter(|m| *m > edge_mm).map(|m| (c.frame, m))
        })
        .collect();
    if off.is_empty() {
        return None;
    }
    let frames: Vec<u64> = off.iter().map(|o| o.0).collect();
    let largest = off.iter().map(|o| o.1).fold(0.0, f64::max);
    Some(format!(
        "frames {} ({} of {} verified): parts of each lie up to {:.2} mm ({:.1} output px) from where the reference photo shows the same texture, though most of the frame agrees; the maps may be off by that much there (repetitive texture with few matches at the frames' edges does this)",
        ranges(&frames),
        off.len(),
        verified(checks).0,
        largest,
        largest * px_per_cm / 10.0
    ))
}

/// Runs of consecutive kept frames, as "a-b" frame-number ranges, for messages.
pub fn ranges(frames: &[u64]) -> String {
    let mut out: Vec<String> = Vec::new();
    let mut i = 0;
    while i < frames.len() {
        let mut j = i;
        while j + 1 < frames.len() && frames[j + 1] > frames[j] && frames[j + 1] - frames[j] <= 10 {
            j += 1;
        }
        out.push(if i == j {
            frames[i].to_string()
        } else {
            format!("{}-{}", frames[i], frames[j])
        });
        i = j + 1;
    }
    out.join(", ")
}

#[cfg(test)]
mod tests {
    use super::*;

    fn verified_frame(frame: u64, shift_mm: f64, max_shift_mm: f64) -> FrameCheck {
        FrameCheck {
            kept_index: frame as usize,
            frame,
            stream: 0,
            blocks: 10,
            matched: 10,
            agreeing: 10,
            shift_mm: Some(shift_mm),
            max_shift_mm: Some(max_shift_mm),
            score: Some(0.95),
            warp_mm: None,
            warp_agreeing: 0,
            block_shifts: Vec::new(),
        }
    }

    #[test]
    fn a_frame_off_at_an_edge_is_named_and_one_off_everywhere_is_left_to_the_median_check() {
        let checks = [
            verified_frame(0, 0.05, 0.3),
            verified_frame(5, 0.1, 0.9),
            verified_frame(10, 0.2, 0.6),
            verified_frame(15, 1.5, 2.0),
        ];
        // 30 px/cm: 2 output px are 0.67 mm; frame 15 is beyond the 1 mm median limit
        // (dropped elsewhere), so only frame 5 is named here.
        let w = edge_disagreement(&checks, 1.0, 30.0).expect("frame 5 is off at an edge");
        assert!(w.starts_with("frames 5 (1 of 4 verified)"), "{w}");
        assert!(w.contains("0.90 mm (2.7 output px)"), "{w}");
        // At 4K sampling (125 px/cm) 2 px are 0.16 mm, but the floor of 0.3 mm holds.
        let fine = [verified_frame(0, 0.05, 0.25), verified_frame(5, 0.05, 0.35)];
        let w = edge_disagreement(&fine, 1.0, 125.0).expect("frame 5 is over the floor");
        assert!(w.starts_with("frames 5 (1 of 2"), "{w}");
        assert!(edge_disagreement(&fine[..1], 1.0, 125.0).is_none());
        assert!(edge_disagreement(&checks, 1.0, 0.0).is_none());
        // With its blocks known, a block matched a pattern repeat 30 mm away does not
        // name a frame; one 2 mm off does.
        let mut repeat = verified_frame(20, 0.05, 30.0);
        repeat.block_shifts = vec![[0.0, 0.0, 0.05, 0.0], [2.0, 0.0, 30.0, 0.0]];
        assert!(edge_disagreement(&[repeat.clone()], 1.0, 30.0).is_none());
        repeat.block_shifts.push([4.0, 0.0, 0.0, 2.0]);
        let w = edge_disagreement(&[repeat], 1.0, 30.0).expect("a block 2 mm off");
        assert!(w.contains("up to 2.00 mm"), "{w}");
    }

    /// A tile-like texture: 4 mm cells of hashed colours with a smooth shading.
    fn plane_colour(x: f64, y: f64) -> [u8; 3] {
        let (i, j) = ((x / 0.4).floor() as i64, (y / 0.4).floor() as i64);
        let h = |k: i64| {
            let v = (i.wrapping_mul(73_856_093)
                ^ j.wrapping_mul(19_349_663)
                ^ k.wrapping_mul(83_492_791))
            .rem_euclid(200);
            (30 + v) as f64
        };
        let shade = 0.8 + 0.2 * (0.3 * x).sin();
        [h(1), h(2), h(3)].map(|v| (v * shade) as u8)
    }

    /// An image of `w` x `h` pixels seeing the plane through `plane_from_pixel`.
    fn render(w: usize, h: usize, plane_from_pixel: &Homography) -> ImageU8 {
        let mut img = ImageU8::new(w, h, 3);
        for r in 0..h {
            for c in 0..w {
                let q = plane_from_pixel
                    .apply(Vec2::new(c as f64, r as f64))
                    .unwrap();
                img.pixel_mut(c, r).copy_from_slice(&plane_colour(q.x, q.y));
            }
        }
        img
    }

    /// Pixel (u, v) -> plane (x0 + u / s, y0 - v / s).
    fn affine(x0: f64, y0: f64, s: f64) -> Homography {
        Homography(svbrdf_core::geometry::Mat3::new(
            1.0 / s,
            0.0,
            x0,
            0.0,
            -1.0 / s,
            y0,
            0.0,
            0.0,
            1.0,
        ))
    }

    fn mapping(h: &Homography, w: u32) -> PreparedMapping {
        let frame = svbrdf_core::capture::Frame {
            id: 0,
            source: 0,
            frame_index: Some(0),
            image: None,
            time_s: None,
            width: w,
            height: w,
            mapping: svbrdf_core::capture::FrameMapping::Homographies {
                subframes: vec![svbrdf_core::capture::SubFrame {
                    rect: [-0.5, -0.5, w as f64 - 0.5, w as f64 - 0.5],
                    plane_from_pixel: svbrdf_core::geometry::mat3_to_rows(&h.0),
                }],
            },
            camera_position: [0.0, 0.0, 10.0],
            light_position: [0.0, 0.0, 10.0],
            exposure_gain: None,
        };
        PreparedMapping::new(&frame).unwrap()
    }

    #[test]
    fn frames_registered_off_the_reference_are_flagged_and_only_those() {
        // Reference: 20 px/cm over [-8, 8] cm.
        let ref_h = affine(-8.0, 8.0, 20.0);
        let reference = render(320, 320, &ref_h);
        // Ten frames at 16 px/cm, each 10 cm wide, moving across; frames 4-6 are
        // rendered where they are but registered 5 mm off (a misregistered stretch).
        let side = 160u32;
        let mut thumbs = Vec::new();
        let mut maps = Vec::new();
        for k in 0..10 {
            let x0 = -8.0 + 0.6 * k as f64;
            let truth = affine(x0, 5.0 - 0.3 * k as f64, 16.0);
            thumbs.push(render(side as usize, side as usize, &truth));
            let off = if (4..=6).contains(&k) { 0.5 } else { 0.0 };
            maps.push(affine(x0 + off, 5.0 - 0.3 * k as f64, 16.0));
        }
        let frames: Vec<CheckedFrame> = (0..10)
            .map(|k| CheckedFrame {
                frame: 5 * k as u64,
                stream: 0,
                thumb: &thumbs[k],
                width: side,
                mapping: mapping(&maps[k], side),
            })
            .collect();
        let region = Region::centred(16.0, 16.0);
        let checks = check(&reference, &ref_h, region, &frames);
        assert_eq!(checks.len(), 10);
        for c in &checks {
            let s = c
                .shift_mm
                .unwrap_or_else(|| panic!("frame {} unverified: {c:?}", c.frame));
            if (20..=30).contains(&c.frame) {
                assert!((s - 5.0).abs() < 0.3, "frame {}: {s} mm", c.frame);
                assert!(c.inconsistent(1.0));
            } else {
                assert!(s < 0.3, "frame {}: {s} mm", c.frame);
                assert!(!c.inconsistent(1.0));
            }
        }
    }

    #[test]
    fn ranges_group_consecutive_frames() {
        assert_eq!(ranges(&[5, 10, 15, 40, 45, 90]), "5-15, 40-45, 90");
        assert_eq!(ranges(&[]), "");
    }
}
