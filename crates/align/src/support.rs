//! Sub-frame support (beyond the paper): how firmly each sub-frame's map is fixed by the
//! correspondences it takes part in.
//!
//! The global solve gives every sub-frame a homography, also those that saw no feature
//! match, no marker and no reference-photo match: their maps come from the smoothness
//! of the overlaps and the starting point, i.e. they are extrapolated. With texture
//! that matches everywhere this never matters; on brushed metal, where a frame's few
//! matches sit in one corner, such sub-frames were measured 1-7 cm off while the
//! solve's residual said 0.004 cm. The measure here is the linearised uncertainty of
//! the sub-frame's map at its corners: for each frame, the normal matrix of every
//! constraint touching its sub-frames (matches with other frames count with the other
//! frame held fixed; the seams between its own sub-frames count as they are weighted in
//! the solve), inverted; the standard deviation of a corner's plane position in units
//! of one constraint's noise is the sub-frame's **noise gain**. About 0.1-0.5 where a
//! sub-frame holds its own spread matches, several where it leans on a neighbour, and
//! hundreds or more where nothing fixes it.

// Index loops over 8x8 blocks read more clearly than iterator chains here.
#![allow(clippy::needless_range_loop)]

use std::ops::Range;

use nalgebra::DMatrix;
use rayon::prelude::*;
use svbrdf_core::geometry::{Mat3, Vec2};

use std::collections::HashMap;

use crate::matching::{EdgeCut, Registration};
use crate::solve::{project, to_params, Constraint};

/// Least share of a frame's sub-frames that must be supported for the frame to be
/// kept: below it the frame's pose would rest on a corner of the image.
pub const MIN_SUPPORTED_SHARE: f64 = 0.3;

/// What the support check did (`align.json` `summary.support`).
#[derive(Debug, Clone, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct SupportSummary {
    /// Largest noise gain a kept sub-frame may have (`AlignConfig::max_noise_gain`).
    pub max_noise_gain: f64,
    /// Sub-frames of the registered frames.
    pub subframes: usize,
    /// Of those, removed as extrapolated (including every sub-frame of dropped frames).
    pub removed: usize,
    /// Frames dropped because fewer than [`MIN_SUPPORTED_SHARE`] of their sub-frames
    /// were supported (video frame numbers).
    pub frames_dropped: Vec<u64>,
    /// Kept frames that lost sub-frames: (video frame, sub-frames kept, sub-frames).
    pub partial_frames: Vec<(u64, usize, usize)>,
    /// Kept frames that the self-check showed bent at an edge and that lost the
    /// sub-frames there (`checks::trim_bent_parts`): (video frame, sub-frames left
    /// out, sub-frames it had).
    #[serde(default)]
    pub bent_trimmed: Vec<(u64, usize, usize)>,
    /// Largest noise gain at which a sub-frame on a frame's edge is used out to that
    /// edge (`AlignConfig::edge_noise_gain`; 0: off).
    #[serde(default)]
    pub edge_noise_gain: f64,
    /// Sub-frames of kept frames used short of the frame's edge ([`apply_edge_cuts`]).
    #[serde(default)]
    pub edge_cut: usize,
    /// Share of the kept sub-frames' area (pixels) that those cuts left out.
    #[serde(default)]
    pub edge_cut_area: f64,
    /// Sub-frames that would have been cut but were used out to the frame's edge,
    /// because the cuts alone took the coverage below the minimum (a warning says so).
    #[serde(default)]
    pub edge_cut_waived: usize,
}

impl SupportSummary {
    /// One line for people; `None` when nothing was removed or cut.
    pub fn describe(&self) -> Option<String> {
        let removed = (self.removed > 0).then(|| {
            let dropped = if self.frames_dropped.is_empty() {
                String::new()
            } else {
                format!(
                    "; {} frames dropped as mostly extrapolated ({})",
                    self.frames_dropped.len(),
                    list(&self.frames_dropped)
                )
            };
            format!(
                "{} of {} sub-frames left out: no correspondences of their own fixed their maps (noise gain above {}){dropped}; {} kept frames are partial",
                self.removed,
                self.subframes,
                self.max_noise_gain,
                self.partial_frames.len()
            )
        });
        let parts: Vec<String> = [removed, self.edges(), self.bent()]
            .into_iter()
            .flatten()
            .collect();
        (!parts.is_empty()).then(|| parts.join("; "))
    }

    /// The cuts along the frames' edges, in words; `None` when there were none.
    pub fn edges(&self) -> Option<String> {
        (self.edge_cut > 0).then(|| {
            format!(
                "{} sub-frames along frames' edges used short of the edge ({:.1}% of the sub-frames' area), where their maps were extrapolated past their correspondences (noise gain above {})",
                self.edge_cut,
                100.0 * self.edge_cut_area,
                self.edge_noise_gain
            )
        })
    }

    /// The sub-frames the self-check left out as bent at an edge, in words; `None`
    /// when it left out none.
    pub fn bent(&self) -> Option<String> {
        (!self.bent_trimmed.is_empty()).then(|| {
            let n: usize = self.bent_trimmed.iter().map(|b| b.1).sum();
            let frames: Vec<u64> = self.bent_trimmed.iter().map(|b| b.0).collect();
            format!(
                "{n} sub-frames of frame(s) {} left out: the self-check showed them bent at an edge",
                list(&frames)
            )
        })
    }
}

/// Cut back the sub-frames along the frames' edges to where their maps are fixed
/// (`Registration::edge_cuts`, worked out by the global solve); called once the checks
/// have judged the frames whole, so that a frame's admission never depends on the cut.
/// Records how many sub-frames and how much of their area in `support`.
pub(crate) fn apply_edge_cuts(reg: &mut Registration) {
    let keys: Vec<(u32, u64)> = reg.frames.iter().map(|f| (f.stream, f.index)).collect();
    let (n, share) = cut_mappings(&keys, &mut reg.mappings, &reg.edge_cuts);
    reg.edge_cuts.clear();
    reg.support.edge_cut = n;
    reg.support.edge_cut_area = share;
}

/// Replace every rectangle of `mappings` (one per frame, keyed by `keys`) that `cuts`
/// lists for its frame by its cut; the number replaced and the share of the
/// rectangles' area they lost.
fn cut_mappings(
    keys: &[(u32, u64)],
    mappings: &mut [Vec<([f64; 4], Mat3)>],
    cuts: &HashMap<(u32, u64), Vec<EdgeCut>>,
) -> (usize, f64) {
    let (mut n, mut cut_area, mut area) = (0, 0.0, 0.0);
    let rect_area = |r: &[f64; 4]| (r[2] - r[0]).max(0.0) * (r[3] - r[1]).max(0.0);
    for (key, m) in keys.iter().zip(mappings) {
        let mine = cuts.get(key);
        for (rect, _) in m.iter_mut() {
            let a = rect_area(rect);
            area += a;
            if let Some(&(_, cut)) = mine.and_then(|c| c.iter().find(|(full, _)| full == rect)) {
                cut_area += a - rect_area(&cut);
                *rect = cut;
                n += 1;
            }
        }
    }
    (n, if area > 0.0 { cut_area / area } else { 0.0 })
}

/// Frame numbers, the first eight and a count.
fn list(v: &[u64]) -> String {
    let head: Vec<String> = v.iter().take(8).map(u64::to_string).collect();
    if v.len() > 8 {
        format!("{} and {} more", head.join(", "), v.len() - 8)
    } else {
        head.join(", ")
    }
}

/// The noise gain at each of `probes(block)` (in that order) for every block of a
/// frame in `frames`; `None` for blocks of no listed frame, every probe infinite where
/// the frame's normal matrix is singular.
pub(crate) fn noise_gains_at(
    solved: &[Mat3],
    cons: &[Constraint],
    frames: &[Range<usize>],
    probes: impl Fn(usize) -> Vec<Vec2> + Sync,
) -> Vec<Option<Vec<f64>>> {
    let params: Vec<[f64; 8]> = solved.iter().map(to_params).collect();
    let mut frame_of = vec![usize::MAX; solved.len()];
    for (f, r) in frames.iter().enumerate() {
        for b in r.clone() {
            if let Some(slot) = frame_of.get_mut(b) {
                *slot = f;
            }
        }
    }
    // The constraints each frame takes part in.
    let mut touching: Vec<Vec<usize>> = vec![Vec::new(); frames.len()];
    for (k, c) in cons.iter().enumerate() {
        let (a, b) = match *c {
            Constraint::Pair { a, b, .. } => (a, Some(b)),
            Constraint::Anchor { a, .. } => (a, None),
        };
        let fa = frame_of.get(a).copied().unwrap_or(usize::MAX);
        if fa != usize::MAX {
            touching[fa].push(k);
        }
        if let Some(fb) = b.and_then(|b| frame_of.get(b).copied()) {
            if fb != usize::MAX && fb != fa {
                touching[fb].push(k);
            }
        }
    }
    let per_frame: Vec<Vec<(usize, Vec<f64>)>> = frames
        .par_iter()
        .zip(&touching)
        .map(|(range, mine)| frame_gains(&params, cons, range.clone(), mine, &probes))
        .collect();
    let mut out = vec![None; solved.len()];
    for (b, g) in per_frame.into_iter().flatten() {
        out[b] = Some(g);
    }
    out
}

/// Noise gains of one frame's blocks.
fn frame_gains(
    params: &[[f64; 8]],
    cons: &[Constraint],
    range: Range<usize>,
    mine: &[usize],
    probes: &(impl Fn(usize) -> Vec<Vec2> + Sync),
) -> Vec<(usize, Vec<f64>)> {
    let m = range.len();
    let n = 8 * m;
    let mut normal = DMatrix::<f64>::zeros(n, n);
    let local = |b: usize| range.contains(&b).then(|| b - range.start);
    let mut add = |blocks: &[(usize, [[f64; 8]; 2])], w: f64| {
        for (a, ja) in blocks {
            for (b, jb) in blocks {
                for k in 0..8 {
                    for l in 0..8 {
                        normal[(a * 8 + k, b * 8 + l)] +=
                            w * (ja[0][k] * jb[0][l] + ja[1][k] * jb[1][l]);
                    }
                }
            }
        }
    };
    for &k in mine {
        match cons[k] {
            Constraint::Pair { a, p, b, q, w } => {
                let mut blocks = Vec::with_capacity(2);
                if let Some(la) = local(a) {
                    blocks.push((la, project(&params[a], p).1));
                }
                if let Some(lb) = local(b) {
                    let mut j = project(&params[b], q).1;
                    for row in &mut j {
                        for v in row.iter_mut() {
                            *v = -*v;
                        }
                    }
                    blocks.push((lb, j));
                }
                add(&blocks, w);
            }
            Constraint::Anchor { a, p, w, .. } => {
                if let Some(la) = local(a) {
                    add(&[(la, project(&params[a], p).1)], w);
                }
            }
        }
    }
    // A whisper of damping keeps directions nothing constrains finite (and huge).
    let scale = (0..n)
        .map(|i| normal[(i, i)])
        .fold(0.0, f64::max)
        .max(1e-12);
    for i in 0..n {
        normal[(i, i)] += 1e-10 * scale;
    }
    let Some(cov) = normal.cholesky().map(|c| c.inverse()) else {
        return range
            .map(|b| (b, vec![f64::INFINITY; probes(b).len()]))
            .collect();
    };
    range
        .clone()
        .enumerate()
        .map(|(lb, b)| {
            let gains = probes(b)
                .into_iter()
                .map(|p| {
                    let j = project(&params[b], p).1;
                    let mut var = 0.0;
                    for r in 0..2 {
                        for k in 0..8 {
                            for l in 0..8 {
                                var += j[r][k] * cov[(lb * 8 + k, lb * 8 + l)] * j[r][l];
                            }
                        }
                    }
                    var.max(0.0).sqrt()
                })
                .collect();
            (b, gains)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Noise gain of every sub-frame (indexed like the solve's blocks; sub-frames of no
    /// frame in `frames` get `f64::INFINITY`). `frames` lists each frame's block range;
    /// `probes(block)` the normalised points where the block's map is used (its corners).
    fn noise_gains(
        solved: &[Mat3],
        cons: &[Constraint],
        frames: &[Range<usize>],
        probes: impl Fn(usize) -> Vec<Vec2> + Sync,
    ) -> Vec<f64> {
        noise_gains_at(solved, cons, frames, probes)
            .into_iter()
            .map(|g| match g {
                Some(g) => g.into_iter().fold(0.0, f64::max),
                None => f64::INFINITY,
            })
            .collect()
    }

    /// One frame of 2 x 1 sub-frames over normalised x in [-1, 1] (split at 0), both
    /// starting as the same map (plane cm = 5 x normalised), joined by seams at x = 0.
    fn two_cells(anchors: &[Vec2]) -> (Vec<Mat3>, Vec<Constraint>) {
        let h = Mat3::new(5.0, 0.0, 0.0, 0.0, 5.0, 0.0, 0.0, 0.0, 1.0);
        let mut cons = Vec::new();
        for &p in anchors {
            cons.push(Constraint::Anchor {
                a: usize::from(p.x >= 0.0),
                p,
                x: p * 5.0,
                w: 1.0,
            });
        }
        for y in [-0.5, 0.0, 0.5] {
            for dx in [-0.05, 0.0, 0.05] {
                let s = Vec2::new(dx, y);
                cons.push(Constraint::Pair {
                    a: 0,
                    p: s,
                    b: 1,
                    q: s,
                    w: 4.0,
                });
            }
        }
        (vec![h, h], cons)
    }

    /// One frame holding blocks `a..b`.
    fn frame(a: usize, b: usize) -> Vec<Range<usize>> {
        let r = a..b;
        vec![r]
    }

    fn corners(b: usize) -> Vec<Vec2> {
        let (x0, x1) = if b == 0 { (-1.0, 0.0) } else { (0.0, 1.0) };
        [(x0, -1.0), (x1, -1.0), (x0, 1.0), (x1, 1.0)]
            .into_iter()
            .map(|(x, y)| Vec2::new(x, y))
            .collect()
    }

    fn grid(x0: f64, x1: f64) -> Vec<Vec2> {
        let mut v = Vec::new();
        for i in 0..5 {
            for j in 0..5 {
                v.push(Vec2::new(
                    x0 + (x1 - x0) * (0.1 + 0.2 * f64::from(i)),
                    -0.9 + 0.45 * f64::from(j),
                ));
            }
        }
        v
    }

    #[test]
    fn sub_frames_with_spread_matches_are_supported() {
        let pts: Vec<Vec2> = grid(-1.0, 0.0).into_iter().chain(grid(0.0, 1.0)).collect();
        let (h, cons) = two_cells(&pts);
        let g = noise_gains(&h, &cons, &frame(0, 2), corners);
        assert!(g.iter().all(|g| *g < 1.5), "{g:?}");
    }

    #[test]
    fn a_sub_frame_without_matches_of_its_own_is_not() {
        // Matches only in the left cell: the right one hangs on the seam and its far
        // corners are free.
        let (h, cons) = two_cells(&grid(-1.0, 0.0));
        let g = noise_gains(&h, &cons, &frame(0, 2), corners);
        assert!(g[0] < 1.5, "{g:?}");
        assert!(g[1] > 10.0 * g[0], "{g:?}");
        // A few matches in the right cell's corner fix its near part only.
        let pts: Vec<Vec2> = grid(-1.0, 0.0)
            .into_iter()
            .chain([Vec2::new(0.1, -0.9), Vec2::new(0.2, -0.8)])
            .collect();
        let (h, cons) = two_cells(&pts);
        let g2 = noise_gains(&h, &cons, &frame(0, 2), corners);
        assert!(g2[1] > 4.0 && g2[1] < g[1], "{g2:?}");
    }

    #[test]
    fn blocks_of_no_listed_frame_are_infinitely_uncertain() {
        let (h, cons) = two_cells(&grid(-1.0, 1.0));
        let g = noise_gains(&h, &cons, &frame(0, 1), corners);
        assert!(g[0].is_finite() && g[1].is_infinite(), "{g:?}");
    }

    #[test]
    fn edge_cuts_replace_their_frames_rectangles_only() {
        let full = [-0.5, -0.5, 100.0, 100.0];
        let cut = [20.0, -0.5, 100.0, 100.0];
        let inside = [90.0, 90.0, 200.0, 200.0];
        let h = Mat3::identity();
        let mut mappings = vec![vec![(full, h), (inside, h)], vec![(full, h)]];
        let cuts = HashMap::from([((0, 7), vec![(full, cut)])]);
        let (n, share) = cut_mappings(&[(0, 7), (1, 7)], &mut mappings, &cuts);
        assert_eq!(n, 1);
        assert_eq!(mappings[0][0].0, cut);
        assert_eq!(mappings[0][1].0, inside);
        // The same rectangle of another stream's frame 7 is not cut.
        assert_eq!(mappings[1][0].0, full);
        let area = 100.5 * 100.5;
        let lost = 20.5 * 100.5;
        assert!(
            (share - lost / (2.0 * area + 110.0 * 110.0)).abs() < 1e-12,
            "{share}"
        );
    }

    #[test]
    fn describe_names_dropped_frames() {
        let s = SupportSummary {
            max_noise_gain: 4.0,
            subframes: 100,
            removed: 30,
            frames_dropped: (1..=10).collect(),
            partial_frames: vec![(20, 10, 15)],
            bent_trimmed: vec![(24, 4, 15), (30, 2, 15)],
            edge_noise_gain: 1.5,
            edge_cut: 12,
            edge_cut_area: 0.034,
            edge_cut_waived: 0,
        };
        let line = s.describe().unwrap_or_default();
        assert!(line.contains("; 12 sub-frames along frames' edges used short of the edge (3.4% of the sub-frames' area)"), "{line}");
        assert!(line.contains("(noise gain above 1.5)"), "{line}");
        assert!(line.contains("30 of 100"), "{line}");
        assert!(line.ends_with("6 sub-frames of frame(s) 24, 30 left out: the self-check showed them bent at an edge"), "{line}");
        assert!(line.contains("1, 2, 3, 4, 5, 6, 7, 8 and 2 more"), "{line}");
        assert!(SupportSummary::default().describe().is_none());
        let only_bent = SupportSummary {
            bent_trimmed: vec![(24, 4, 15)],
            ..Default::default()
        };
        assert_eq!(only_bent.describe(), only_bent.bent());
        let only_cut = SupportSummary {
            edge_cut: 3,
            ..Default::default()
        };
        assert_eq!(only_cut.describe(), only_cut.edges());
    }
}
