//! How a frame's matched blocks vote: one displacement most of them agree on, or one
//! affine field where the frame is bent; blocks matched by a highlight or one repeat
//! off point every which way and gather in neither.

use super::FrameCheck;

/// Blocks whose displacements differ by less than this (or a quarter of their size) agree, mm.
const CONSENSUS_MM: f64 = 0.5;
/// A warp needs at least this many blocks agreeing on one affine displacement field
/// (three fit any field exactly).
const WARP_MIN_BLOCKS: usize = 6;

/// The displacement (mm) most of a frame's blocks agree on, and how many agree: a
/// misregistered frame moves its blocks together, while blocks that matched far away
/// on their own (a highlight where the reference photo has none, a repeating
/// pattern) point every which way. The largest group of agreeing blocks wins; `None`
/// when it has fewer than a third of the matched blocks (or fewer than 2): the frame
/// is then unverified, not inconsistent.
pub(super) fn consensus(shifts: &[(f64, f64)]) -> (Option<f64>, usize) {
    let (best, members) = consensus_group(shifts);
    let agreeing = members.len();
    match best {
        Some(b) if agreeing >= 2.max(shifts.len().div_ceil(3)) => (Some(b.0.hypot(b.1)), agreeing),
        _ => (None, agreeing),
    }
}

/// The largest group of agreeing displacements: its median displacement (mm; `None`
/// without displacements) and its members' indices.
fn consensus_group(shifts: &[(f64, f64)]) -> (Option<(f64, f64)>, Vec<usize>) {
    let Some(best) = shifts
        .iter()
        .map(|&a| {
            let support = shifts.iter().filter(|&&b| agree(a, b)).count();
            (support, a)
        })
        .max_by(|x, y| {
            x.0.cmp(&y.0)
                .then_with(|| y.1 .0.hypot(y.1 .1).total_cmp(&x.1 .0.hypot(x.1 .1)))
        })
        .map(|(_, a)| a)
    else {
        return (None, Vec::new());
    };
    let members: Vec<usize> = (0..shifts.len())
        .filter(|&k| agree(best, shifts[k]))
        .collect();
    let mut xs: Vec<f64> = members.iter().map(|&k| shifts[k].0).collect();
    let mut ys: Vec<f64> = members.iter().map(|&k| shifts[k].1).collect();
    xs.sort_by(f64::total_cmp);
    ys.sort_by(f64::total_cmp);
    (Some((xs[xs.len() / 2], ys[ys.len() / 2])), members)
}

/// The matched blocks of a checked frame that agree with its displacement from the
/// reference photo (`[x_cm, y_cm, dx_mm, dy_mm]`, as `block_shifts`): those of the
/// affine field where the frame is bent ([`warp`]), else those of the largest group
/// agreeing on one shift where that group verifies the frame; none for an unverified
/// frame. Blocks matched by a highlight or one repeat off point elsewhere and are not
/// among them.
pub fn agreeing_blocks(c: &FrameCheck) -> Vec<[f64; 4]> {
    let shifts: Vec<(f64, f64)> = c.block_shifts.iter().map(|b| (b[2], b[3])).collect();
    let (shift, members) = consensus_group(&shifts);
    if c.warp_mm.is_some() {
        if let Ok((_, group)) = warp_field(&c.block_shifts, members.len()) {
            return group.into_iter().map(|k| c.block_shifts[k]).collect();
        }
    }
    match shift {
        Some(_) if members.len() >= 2.max(shifts.len().div_ceil(3)) => {
            members.into_iter().map(|k| c.block_shifts[k]).collect()
        }
        _ => Vec::new(),
    }
}

/// Whether two displacements agree (mm): within 0.5 mm or a quarter of the first.
fn agree(a: (f64, f64), b: (f64, f64)) -> bool {
    let tol = (0.25 * a.0.hypot(a.1)).max(CONSENSUS_MM);
    (a.0 - b.0).hypot(a.1 - b.1) <= tol
}

/// An affine displacement field `d = M [x, y, 1]` (rows: dx, dy).
type Affine = [[f64; 3]; 2];

fn apply(m: &Affine, x: f64, y: f64) -> (f64, f64) {
    (
        m[0][0] * x + m[0][1] * y + m[0][2],
        m[1][0] * x + m[1][1] * y + m[1][2],
    )
}

/// Least-squares affine field through blocks `[x, y, dx, dy]` (`None` when their
/// positions are collinear).
fn fit_affine(blocks: &[&[f64; 4]]) -> Option<Affine> {
    use svbrdf_core::geometry::{Mat3, Vec3};
    let mut ata = Mat3::zeros();
    let (mut bx, mut by) = (Vec3::zeros(), Vec3::zeros());
    for b in blocks {
        let a = Vec3::new(b[0], b[1], 1.0);
        ata += a * a.transpose();
        bx += a * b[2];
        by += a * b[3];
    }
    // Relative to the positions' spread: collinear blocks fix no affine field.
    let scale = ata[(0, 0)].max(ata[(1, 1)]).max(1.0);
    if ata.determinant().abs() < 1e-9 * scale * scale * ata[(2, 2)] {
        return None;
    }
    let inv = ata.try_inverse()?;
    let (mx, my) = (inv * bx, inv * by);
    let m = [[mx.x, mx.y, mx.z], [my.x, my.y, my.z]];
    m.iter().flatten().all(|v| v.is_finite()).then_some(m)
}

/// A frame registered warped: its blocks' displacements from the reference photo
/// (`[x_cm, y_cm, dx_mm, dy_mm]`) disagree on one shift but agree on one affine field
/// (parts of the frame off by different amounts: a stretch of the panorama bent
/// between anchors). Every triple of blocks proposes a field; the one most blocks
/// agree with (as in [`consensus`]) is refitted to them. It counts only with at least
/// [`WARP_MIN_BLOCKS`] blocks, half of the matched ones, and a quarter of them (at
/// least 2) more than the shift's group (`shift_agreeing`): blocks matched by a
/// highlight or a repeat point every which way, and no field gathers them. Returns
/// the 75th percentile of the field's length over its blocks (mm) and their count.
pub(super) fn warp(blocks: &[[f64; 4]], shift_agreeing: usize) -> (Option<f64>, usize) {
    match warp_field(blocks, shift_agreeing) {
        Ok((f, group)) => {
            let mut len: Vec<f64> = group
                .iter()
                .map(|&k| {
                    let d = apply(&f, blocks[k][0], blocks[k][1]);
                    d.0.hypot(d.1)
                })
                .collect();
            len.sort_by(f64::total_cmp);
            (Some(len[(3 * len.len()) / 4]), group.len())
        }
        Err(count) => (None, count),
    }
}

/// The affine field of [`warp`] and the indices of the blocks agreeing with it, or
/// (`Err`) how many agreed with the best field where it does not count.
fn warp_field(blocks: &[[f64; 4]], shift_agreeing: usize) -> Result<(Affine, Vec<usize>), usize> {
    let n = blocks.len();
    if n < WARP_MIN_BLOCKS {
        return Err(0);
    }
    // At most 40 blocks propose fields (about 10,000 triples), all of them vote.
    let m = n.min(40);
    let fits = |f: &Affine, b: &[f64; 4]| agree((b[2], b[3]), apply(f, b[0], b[1]));
    let inliers = |f: &Affine| -> Vec<usize> { (0..n).filter(|&k| fits(f, &blocks[k])).collect() };
    let mut best: Option<(usize, Affine)> = None;
    for i in 0..m {
        for j in i + 1..m {
            for k in j + 1..m {
                let Some(f) = fit_affine(&[&blocks[i], &blocks[j], &blocks[k]]) else {
                    continue;
                };
                let c = blocks.iter().filter(|b| fits(&f, b)).count();
                if best.is_none_or(|(b, _)| c > b) {
                    best = Some((c, f));
                }
            }
        }
    }
    let Some((_, f)) = best else {
        return Err(0);
    };
    let group: Vec<&[f64; 4]> = inliers(&f).into_iter().map(|k| &blocks[k]).collect();
    let Some(f) = fit_affine(&group) else {
        return Err(0);
    };
    let group = inliers(&f);
    let count = group.len();
    let margin = n.div_ceil(4).max(2);
    if count < WARP_MIN_BLOCKS || 2 * count < n || count < shift_agreeing + margin {
        return Err(count);
    }
    Ok((f, group))
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::selfcheck::disagreement;

    #[test]
    fn blocks_must_agree_to_move_a_frame() {
        // Five blocks where registered, six far off in different directions (a
        // highlight's blocks matching anywhere): the frame is where it was registered.
        let mut v = vec![
            (0.01, 0.0),
            (-0.01, 0.02),
            (0.0, 0.01),
            (0.05, 0.0),
            (0.02, -0.01),
        ];
        v.extend([
            (-3.4, 27.0),
            (-4.6, 28.9),
            (9.6, 1.4),
            (6.5, 5.7),
            (6.5, -1.1),
            (-12.0, 2.0),
        ]);
        let (shift, agreeing) = consensus(&v);
        assert!(shift.is_some_and(|s| s < 0.05), "{shift:?}");
        assert_eq!(agreeing, 5);
        // A frame moved 3 mm moves its blocks together, even with a few strays.
        let mut w = vec![
            (3.0, 0.1),
            (2.9, 0.0),
            (3.1, -0.1),
            (3.0, 0.05),
            (2.95, 0.1),
        ];
        w.extend([(0.0, 0.0), (-8.0, 4.0)]);
        let (shift, agreeing) = consensus(&w);
        assert!(shift.is_some_and(|s| (s - 3.0).abs() < 0.1), "{shift:?}");
        assert_eq!(agreeing, 5);
        // Every block somewhere else: unverified, not inconsistent.
        let u = [
            (5.0, 0.0),
            (0.0, 5.0),
            (-5.0, 0.0),
            (0.0, -5.0),
            (9.0, 9.0),
            (-9.0, 9.0),
            (9.0, -9.0),
        ];
        assert_eq!(consensus(&u).0, None);
        assert_eq!(consensus(&[]), (None, 0));
    }

    /// Blocks on a 2 cm lattice of a 10 x 18 cm frame, displaced by `d(x, y)` mm.
    /// Blocks `[x_cm, y_cm, dx_mm, dy_mm]` on a 4 x 8 lattice, displaced by `d`.
    pub(crate) fn lattice(d: impl Fn(f64, f64) -> (f64, f64)) -> Vec<[f64; 4]> {
        let mut v = Vec::new();
        for j in 0..8 {
            for i in 0..4 {
                let (x, y) = (2.0 + 2.0 * f64::from(i), 2.0 + 2.0 * f64::from(j));
                let (dx, dy) = d(x, y);
                v.push([x, y, dx, dy]);
            }
        }
        v
    }

    #[test]
    fn a_bent_frame_is_found_where_no_shift_explains_it() {
        // Off by 0 mm at one end and 4 mm at the other (a stretch bent between
        // anchors): no shift holds most blocks, one affine field holds them all.
        let bent = lattice(|_, y| (0.25 * y, 0.0));
        let shifts: Vec<(f64, f64)> = bent.iter().map(|b| (b[2], b[3])).collect();
        let (shift, agreeing) = consensus(&shifts);
        let (w, n) = warp(&bent, agreeing);
        assert_eq!(n, bent.len());
        // Its blocks lie 0.5-4.5 mm off; the 75th percentile of the field is 3.5 mm.
        assert!(w.is_some_and(|w| (w - 3.5).abs() < 0.3), "{w:?} {shift:?}");
        let c = FrameCheck {
            kept_index: 0,
            frame: 7,
            stream: 0,
            blocks: n,
            matched: n,
            agreeing,
            shift_mm: shift,
            max_shift_mm: None,
            score: None,
            warp_mm: w,
            warp_agreeing: n,
            block_shifts: bent,
        };
        assert!(c.inconsistent(1.0));
        let line = disagreement(&[c], 1.0).unwrap_or_default();
        assert!(line.contains("frames 7 bent"), "{line}");

        // A frame registered right, or moved rigidly: the shift explains it, no warp.
        let right = lattice(|x, y| (0.02 * (x - y).sin(), 0.02 * (x + y).cos()));
        let moved = lattice(|_, _| (3.0, 0.0));
        for blocks in [right, moved] {
            let shifts: Vec<(f64, f64)> = blocks.iter().map(|b| (b[2], b[3])).collect();
            let (_, agreeing) = consensus(&shifts);
            assert_eq!(warp(&blocks, agreeing).0, None);
        }
    }

    #[test]
    fn strays_of_a_highlight_make_no_warp() {
        // Half the blocks in place, the others matched every which way (the highlight
        // of 4K patchwork seed 2, frame 151): no field gathers them.
        let mut blocks = lattice(|_, _| (0.0, 0.0));
        let strays = [
            (-3.4, 27.0),
            (-4.6, 28.9),
            (9.6, 1.4),
            (6.5, 5.7),
            (6.5, -1.1),
            (-12.0, 2.0),
            (20.0, -7.0),
            (-2.0, -15.0),
        ];
        for (k, d) in strays.iter().enumerate() {
            let b = &mut blocks[3 * k + 1];
            b[2] = d.0;
            b[3] = d.1;
        }
        let shifts: Vec<(f64, f64)> = blocks.iter().map(|b| (b[2], b[3])).collect();
        let (shift, agreeing) = consensus(&shifts);
        assert!(shift.is_some_and(|s| s < 0.05));
        assert_eq!(warp(&blocks, agreeing).0, None);
        // Too few blocks to tell a field from noise.
        let few: Vec<[f64; 4]> = lattice(|_, y| (0.5 * y, 0.0)).into_iter().take(5).collect();
        assert_eq!(warp(&few, 1), (None, 0));
    }
}
