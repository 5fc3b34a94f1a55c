//! Parts of a frame the self-check shows off (issue 18, item 4: "drop or flag frames and
//! sub-frames that disagree"). A frame registered right in the middle can be bent at
//! an edge where its sub-frames held few correspondences of their own (flat tiles,
//! whose grout crossings all look alike): there neighbouring blocks lie off together,
//! by amounts that grow towards the edge and in one direction. Blocks matched by a
//! highlight or one repeat of a pattern away lie off alone, or centimetres off, or in
//! directions that differ from their neighbours'; those are not taken for a bend.

use svbrdf_core::geometry::{Mat3, Vec2};
use svbrdf_core::homography::Homography;

use super::FrameCheck;

/// Largest displacement taken for a bent part rather than a match one repeat of a
/// pattern away, mm: the bends measured on Mitsuba tiles were under 3 mm, while the
/// `paper` preset's patchwork at 4K shows neighbouring blocks matched 4-6.5 mm away on
/// right frames, and hard-small patchwork repeats 24-54 mm away (sessions 33, 39).
pub const MAX_BEND_MM: f64 = 3.5;
/// Least displacement taken for a bent part, mm, whatever the output resolution: the
/// blocks' own scatter at 4K reaches 0.3-0.45 mm on right frames (session 39), where
/// 2 output px are 0.22 mm.
pub const MIN_BEND_MM: f64 = 0.5;
/// Neighbouring blocks of a bend differ in size by at most this factor (a bend grows
/// smoothly towards the edge; a block matched one repeat away beside one off by
/// scatter does not).
const MAX_RATIO: f64 = 3.0;
/// Two off blocks are neighbours when their centres are at most this far apart, cm:
/// the blocks lie on a 2 cm lattice, so this takes the 8 around each.
const NEIGHBOUR_CM: f64 = 2.9;
/// ... and they point the same way when the cosine of the angle between their
/// displacements is at least this (45 degrees).
const SAME_WAY: f64 = std::f64::consts::FRAC_1_SQRT_2;
/// Half the side of a compared block, cm (blocks are 4 cm squares).
pub const BLOCK_HALF_CM: f64 = 2.0;

/// The matched blocks of a verified, consistent frame that lie more than `edge_mm`
/// (and [`MIN_BEND_MM`]) and at most [`MAX_BEND_MM`] off and have a neighbour that
/// does too, pointing the same way and at most [`MAX_RATIO`] times as far or near:
/// the bent part, as `[x_cm, y_cm, dx_mm, dy_mm]`. Empty for an unverified
/// frame (its blocks agree on nothing, so no part of it stands out).
pub fn bent_blocks(c: &FrameCheck, edge_mm: f64) -> Vec<[f64; 4]> {
    if c.offset_mm().is_none() {
        return Vec::new();
    }
    let off: Vec<[f64; 4]> = c
        .block_shifts
        .iter()
        .copied()
        .filter(|b| {
            let m = b[2].hypot(b[3]);
            m > edge_mm.max(MIN_BEND_MM) && m <= MAX_BEND_MM
        })
        .collect();
    off.iter()
        .copied()
        .filter(|a| {
            off.iter().any(|b| {
                let apart = (a[0] - b[0]).hypot(a[1] - b[1]);
                let dot = a[2] * b[2] + a[3] * b[3];
                let (ma, mb) = (a[2].hypot(a[3]), b[2].hypot(b[3]));
                apart > 1e-9
                    && apart <= NEIGHBOUR_CM
                    && dot >= SAME_WAY * ma * mb
                    && ma.max(mb) <= MAX_RATIO * ma.min(mb)
            })
        })
        .collect()
}

/// Whether a plane point (world cm) lies on one of `blocks`.
pub fn on_blocks(blocks: &[[f64; 4]], x_cm: f64, y_cm: f64) -> bool {
    blocks
        .iter()
        .any(|b| (x_cm - b[0]).abs() <= BLOCK_HALF_CM && (y_cm - b[1]).abs() <= BLOCK_HALF_CM)
}

/// Leave out the sub-frames of a frame's mapping (pixel rectangles and
/// plane_from_pixel maps, world cm) whose centre falls on one of the `bent` blocks;
/// how many were left out.
pub fn leave_out_bent(mapping: &mut Vec<([f64; 4], Mat3)>, bent: &[[f64; 4]]) -> usize {
    let before = mapping.len();
    mapping.retain(|(r, h)| {
        let centre = Vec2::new(0.5 * (r[0] + r[2]), 0.5 * (r[1] + r[3]));
        Homography(*h)
            .apply(centre)
            .is_none_or(|q| !on_blocks(bent, q.x, q.y))
    });
    before - mapping.len()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_sub_frames_on_bent_blocks_are_left_out() {
        // A 3 x 5 grid of 100 px sub-frames at 0.04 cm per pixel, the frame's top-left
        // pixel at (-10, 10) cm and its rows going down the plane's y.
        let h = Mat3::new(0.04, 0.0, -10.0, 0.0, -0.04, 10.0, 0.0, 0.0, 1.0);
        let mut mapping: Vec<([f64; 4], Mat3)> = (0..15)
            .map(|k| {
                let (x, y) = (100.0 * (k % 3) as f64, 100.0 * (k / 3) as f64);
                ([x, y, x + 99.0, y + 99.0], h)
            })
            .collect();
        // Sub-frame centres lie at x = -8, -4, 0 and y = 8, 4, 0, -4, -8 cm. Blocks
        // centred at (-1, 1) and (-1, -3) cover those at (0, 0) and (0, -4) only.
        let bent = [[-1.0, 1.0, 0.0, -2.0], [-1.0, -3.0, 0.0, -2.5]];
        assert_eq!(leave_out_bent(&mut mapping, &bent), 2);
        assert_eq!(mapping.len(), 13);
        assert!(mapping
            .iter()
            .all(|(r, _)| !(r[0] == 200.0 && (r[1] == 200.0 || r[1] == 300.0))));
        assert_eq!(leave_out_bent(&mut mapping, &[]), 0);
    }

    fn frame(blocks: Vec<[f64; 4]>) -> FrameCheck {
        super::super::summarise(0, 14, 0, blocks.len(), blocks)
    }

    /// A 4 x 5 lattice of blocks agreeing within 0.2 mm, with `bent` replacing some.
    fn lattice_with(bent: &[[f64; 4]]) -> Vec<[f64; 4]> {
        let mut v = Vec::new();
        for i in 0..4 {
            for j in 0..5 {
                let (x, y) = (-8.0 + 2.0 * i as f64, 2.0 * j as f64);
                let b = bent
                    .iter()
                    .find(|b| b[0] == x && b[1] == y)
                    .copied()
                    .unwrap_or([x, y, 0.05 * (i as f64 - 1.5), -0.03 * (j as f64 - 2.0)]);
                v.push(b);
            }
        }
        v
    }

    #[test]
    fn an_edge_off_together_is_bent_and_lone_or_far_blocks_are_not() {
        // Frame 14 of the Mitsuba capture xi2 (session 38): the right column off
        // 1.1-2.8 mm downwards, growing towards the corner, the next column 0.7-1.3 mm.
        let edge = [
            [-2.0, 6.0, 0.02, -1.14],
            [-2.0, 4.0, 0.07, -2.11],
            [-2.0, 2.0, 0.11, -2.77],
            [-4.0, 2.0, -0.06, -0.72],
            [-4.0, 0.0, 0.08, -1.33],
        ];
        let c = frame(lattice_with(&edge));
        assert!(c.offset_mm().is_some_and(|s| s < 0.3), "{c:?}");
        let bent = bent_blocks(&c, 0.69);
        assert_eq!(bent.len(), 5, "{bent:?}");
        assert!(on_blocks(&bent, -1.0, 3.0));
        assert!(!on_blocks(&bent, -7.0, 7.0));

        // A block alone 1 mm off, one matched a repeat 3 cm away beside a block off
        // the same way, two neighbours pointing opposite ways, and a block off 0.6 mm
        // beside one 2.5 mm off the same way (the `paper` preset's right frames show
        // such pairs, a repeat beside scatter): nothing is bent.
        let lone = [
            [-8.0, 0.0, 1.0, 0.0],
            [-2.0, 8.0, 30.0, 0.0],
            [-2.0, 6.0, 1.2, 0.0],
            [-6.0, 4.0, 0.0, 1.5],
            [-6.0, 2.0, 0.0, -1.5],
            [-8.0, 8.0, 0.0, 0.6],
            [-6.0, 8.0, 0.3, 2.5],
        ];
        let c = frame(lattice_with(&lone));
        assert!(c.offset_mm().is_some());
        assert!(
            bent_blocks(&c, 0.69).is_empty(),
            "{:?}",
            bent_blocks(&c, 0.69)
        );
        // The same edge under a higher limit (a coarser output's 2 px) is bent only
        // where it exceeds it; under a lower one (4K) no more than at 0.5 mm.
        let c = frame(lattice_with(&edge));
        assert_eq!(bent_blocks(&c, 2.0).len(), 2);
        assert!(bent_blocks(&c, 3.0).is_empty());
        assert_eq!(bent_blocks(&c, 0.22).len(), 5);
        // Two neighbours just over 0.3 mm, the same way: scatter at 4K, not a bend.
        let c = frame(lattice_with(&[
            [-8.0, 4.0, -0.32, -0.2],
            [-6.0, 4.0, -0.15, -0.3],
        ]));
        assert!(bent_blocks(&c, 0.22).is_empty());
    }

    #[test]
    fn an_unverified_frame_has_no_bent_part() {
        let blocks = vec![
            [0.0, 0.0, 3.0, 0.0],
            [2.0, 0.0, 3.1, 0.0],
            [4.0, 0.0, -6.0, 5.0],
            [6.0, 0.0, 0.0, -7.0],
            [8.0, 0.0, 9.0, 9.0],
            [0.0, 2.0, -2.0, -8.0],
            [2.0, 2.0, 8.0, -3.0],
            [4.0, 2.0, -9.0, -1.0],
            [6.0, 2.0, 0.5, 9.5],
        ];
        let c = frame(blocks);
        assert!(c.offset_mm().is_none(), "{c:?}");
        assert!(bent_blocks(&c, 0.5).is_empty());
    }
}
