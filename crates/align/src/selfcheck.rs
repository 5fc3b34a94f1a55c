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

/// Fine cells per cm of the comparison grid.
const FINE_PX_PER_CM: f64 = 10.0;
/// Blocks whose displacements differ by less than this (or a quarter of their size) agree, mm.
const CONSENSUS_MM: f64 = 0.5;
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
/// A block needs this share of its cells seen (and unclipped) in both images.
const MIN_VALID: f64 = 0.6;
/// A warp needs at least this many blocks agreeing on one affine displacement field
/// (three fit any field exactly).
const WARP_MIN_BLOCKS: usize = 6;

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

/// A colour image on the plane grid; `None` where unseen or clipped.
struct PlaneImage {
    w: usize,
    h: usize,
    px: Vec<Option<[f32; 3]>>,
}

impl PlaneImage {
    fn get(&self, x: i64, y: i64) -> Option<[f32; 3]> {
        if x < 0 || y < 0 || x >= self.w as i64 || y >= self.h as i64 {
            return None;
        }
        self.px[y as usize * self.w + x as usize]
    }

    /// Box-average by `k` (cells with any missing sample stay missing).
    fn reduce(&self, k: usize) -> Self {
        let (w, h) = (self.w / k, self.h / k);
        let mut px = vec![None; w * h];
        for r in 0..h {
            for c in 0..w {
                let mut acc = [0.0f32; 3];
                let mut ok = true;
                'cell: for dy in 0..k {
                    for dx in 0..k {
                        match self.px[(r * k + dy) * self.w + c * k + dx] {
                            Some(v) => (0..3).for_each(|i| acc[i] += v[i]),
                            None => {
                                ok = false;
                                break 'cell;
                            }
                        }
                    }
                }
                if ok {
                    let n = (k * k) as f32;
                    px[r * w + c] = Some(acc.map(|v| v / n));
                }
            }
        }
        Self { w, h, px }
    }
}

fn bilinear(img: &ImageU8, x: f64, y: f64) -> Option<[f32; 3]> {
    if x < 0.0 || y < 0.0 || x > (img.width - 1) as f64 || y > (img.height - 1) as f64 {
        return None;
    }
    let (x0, y0) = (x.floor() as usize, y.floor() as usize);
    let (x1, y1) = ((x0 + 1).min(img.width - 1), (y0 + 1).min(img.height - 1));
    let (fx, fy) = ((x - x0 as f64) as f32, (y - y0 as f64) as f32);
    let mut out = [0.0f32; 3];
    let mut clipped = false;
    for (xx, yy, wgt) in [
        (x0, y0, (1.0 - fx) * (1.0 - fy)),
        (x1, y0, fx * (1.0 - fy)),
        (x0, y1, (1.0 - fx) * fy),
        (x1, y1, fx * fy),
    ] {
        let p = img.pixel(xx, yy);
        for i in 0..3 {
            clipped |= p[i] >= 250;
            out[i] += wgt * f32::from(p[i]);
        }
    }
    (!clipped).then_some(out)
}

/// Rectify an image onto `grid` through `pixel_of` (plane cm -> image pixel), with
/// 2 x 2 samples per cell.
fn rectify(
    grid: &PlaneGrid,
    img: &ImageU8,
    pixel_of: &(dyn Fn(Vec2) -> Option<Vec2> + Sync),
) -> PlaneImage {
    let px: Vec<Option<[f32; 3]>> = (0..grid.len())
        .into_par_iter()
        .map(|i| {
            let (c, r) = ((i % grid.width) as f64, (i / grid.width) as f64);
            let mut acc = [0.0f32; 3];
            for (dx, dy) in [(-0.25, -0.25), (0.25, -0.25), (-0.25, 0.25), (0.25, 0.25)] {
                let q = grid.to_plane(Vec2::new(c + dx, r + dy));
                let p = pixel_of(q)?;
                let v = bilinear(img, p.x, p.y)?;
                (0..3).for_each(|k| acc[k] += 0.25 * v[k]);
            }
            Some(acc)
        })
        .collect();
    PlaneImage {
        w: grid.width,
        h: grid.height,
        px,
    }
}

/// Correlation of the block of `a` at (bx, by) (side `n`) with `b` shifted by (sx, sy):
/// the mean over colour channels of the normalised cross-correlation over the cells
/// valid in both. `None` below `MIN_VALID` valid cells.
fn ncc(
    a: &PlaneImage,
    b: &PlaneImage,
    bx: i64,
    by: i64,
    n: usize,
    sx: i64,
    sy: i64,
) -> Option<f64> {
    let mut s = [[0.0f64; 5]; 3]; // per channel: sum a, sum b, sum aa, sum bb, sum ab
    let mut count = 0usize;
    for y in 0..n as i64 {
        for x in 0..n as i64 {
            let (Some(va), Some(vb)) = (a.get(bx + x, by + y), b.get(bx + x + sx, by + y + sy))
            else {
                continue;
            };
            count += 1;
            for ch in 0..3 {
                let (p, q) = (f64::from(va[ch]), f64::from(vb[ch]));
                let t = &mut s[ch];
                t[0] += p;
                t[1] += q;
                t[2] += p * p;
                t[3] += q * q;
                t[4] += p * q;
            }
        }
    }
    if (count as f64) < MIN_VALID * (n * n) as f64 {
        return None;
    }
    let m = count as f64;
    let mut total = 0.0;
    let mut channels = 0.0;
    for t in &s {
        let va = t[2] - t[0] * t[0] / m;
        let vb = t[3] - t[1] * t[1] / m;
        let cov = t[4] - t[0] * t[1] / m;
        // A flat channel (e.g. grey grout in one colour) says nothing; skip it.
        if va > 1e-6 * m && vb > 1e-6 * m {
            total += cov / (va * vb).sqrt();
            channels += 1.0;
        }
    }
    (channels > 0.0).then(|| total / channels)
}

/// The best integer shift, its correlation, and the correlations one cell left,
/// right, up and down of it (for the sub-cell parabola).
type Peak = ((i64, i64), f64, [Option<f64>; 4]);

/// Best shift of block (bx, by) of `a` against `b` within `radius` around `centre`.
fn best_shift(
    a: &PlaneImage,
    b: &PlaneImage,
    bx: i64,
    by: i64,
    n: usize,
    centre: (i64, i64),
    radius: i32,
) -> Option<Peak> {
    let mut best: Option<((i64, i64), f64)> = None;
    for sy in -radius..=radius {
        for sx in -radius..=radius {
            let s = (centre.0 + i64::from(sx), centre.1 + i64::from(sy));
            if let Some(v) = ncc(a, b, bx, by, n, s.0, s.1) {
                if best.is_none_or(|b| v > b.1) {
                    best = Some((s, v));
                }
            }
        }
    }
    let (s, v) = best?;
    let nb =
        [(-1, 0), (1, 0), (0, -1), (0, 1)].map(|(dx, dy)| ncc(a, b, bx, by, n, s.0 + dx, s.1 + dy));
    Some((s, v, nb))
}

/// Sub-cell offset of a parabola through (-1, l), (0, c), (1, r).
fn parabola(l: Option<f64>, c: f64, r: Option<f64>) -> f64 {
    match (l, r) {
        (Some(l), Some(r)) => {
            let d = l - 2.0 * c + r;
            if d < -1e-9 {
                (0.5 * (l - r) / d).clamp(-0.5, 0.5)
            } else {
                0.0
            }
        }
        _ => 0.0,
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

/// The displacement (mm) most of a frame's blocks agree on, and how many agree: a
/// misregistered frame moves its blocks together, while blocks that matched far away
/// on their own (a highlight where the reference photo has none, a repeating
/// pattern) point every which way. The largest group of agreeing blocks wins; `None`
/// when it has fewer than a third of the matched blocks (or fewer than 2): the frame
/// is then unverified, not inconsistent.
fn consensus(shifts: &[(f64, f64)]) -> (Option<f64>, usize) {
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
fn warp(blocks: &[[f64; 4]], shift_agreeing: usize) -> (Option<f64>, usize) {
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
pub(crate) mod tests {
    use super::*;

    fn plane(w: usize, h: usize, f: impl Fn(usize, usize) -> [f32; 3]) -> PlaneImage {
        PlaneImage {
            w,
            h,
            px: (0..w * h).map(|i| Some(f(i % w, i / w))).collect(),
        }
    }

    fn texture(x: usize, y: usize) -> [f32; 3] {
        let v = |k: usize| {
            let h = (x.wrapping_mul(73_856_093)
                ^ y.wrapping_mul(19_349_663)
                ^ k.wrapping_mul(83_492_791))
                % 1000;
            h as f32 / 4.0
        };
        [v(1), v(2), v(3)]
    }

    #[test]
    fn a_shifted_block_is_found_at_its_shift_despite_a_change_of_gain() {
        let b = plane(80, 80, texture);
        // `a` sees b shifted by (7, -3) under a dimmer, tinted light.
        let a = plane(80, 80, |x, y| {
            let t = texture(x + 7, (y as i64 - 3).rem_euclid(1000) as usize);
            [0.5 * t[0] + 10.0, 0.7 * t[1], 0.6 * t[2] + 3.0]
        });
        let (s, v, _) = best_shift(&a, &b, 20, 20, 30, (0, 0), 10).unwrap();
        assert_eq!(s, (7, -3));
        assert!(v > 0.99, "{v}");
    }

    #[test]
    fn parabola_finds_the_peak_between_cells() {
        // Samples of -(x - 0.3)^2 at -1, 0, 1.
        let f = |x: f64| -(x - 0.3) * (x - 0.3);
        assert!((parabola(Some(f(-1.0)), f(0.0), Some(f(1.0))) - 0.3).abs() < 1e-9);
        assert_eq!(parabola(None, 1.0, Some(0.0)), 0.0);
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

    #[test]
    fn ranges_group_consecutive_frames() {
        assert_eq!(ranges(&[5, 10, 15, 40, 45, 90]), "5-15, 40-45, 90");
        assert_eq!(ranges(&[]), "");
    }
}
