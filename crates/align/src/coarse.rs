//! Coarse alignment (paper 3.1.2): similarities between frames from coarse SIFT
//! features, and the connectivity map that decides which frames are kept.

use std::collections::{BTreeSet, HashMap, VecDeque};

use rayon::prelude::*;
use svbrdf_core::geometry::{Mat3, Vec2};
use svbrdf_core::homography::Homography;
use svbrdf_cv::features::{estimate_similarity, match_indexed, Features, MatchIndex, Robust};

use crate::config::AlignConfig;
use crate::frames::FrameData;
use crate::{AlignError, Progress};

/// A verified similarity between two frames (2x3, row-major) and its inlier matches
/// (coarse feature indices in a and b).
pub(crate) type SimilarityMatch = ([[f64; 3]; 2], Vec<(u32, u32)>);

/// The connectivity map (paper 3.1.3): inlier counts between kept frames.
#[derive(Debug, Clone, Default)]
pub struct Connectivity {
    /// Frames (indices into the decoded list) that the map covers.
    pub frames: usize,
    /// Raw inlier counts of tested pairs.
    pub counts: HashMap<(usize, usize), usize>,
    /// The inlier matches (coarse feature indices) of verified pairs, reused by fine
    /// matching.
    pub matches: HashMap<(usize, usize), Vec<(u32, u32)>>,
    /// Pairs kept after thresholding and median filtering.
    pub kept: BTreeSet<(usize, usize)>,
}

pub(crate) fn pts(f: &Features, idx: impl Iterator<Item = u32>) -> Vec<[f64; 2]> {
    idx.map(|i| {
        let p = f.points[i as usize];
        [f64::from(p[0]), f64::from(p[1])]
    })
    .collect()
}

/// Similarity between two frames' coarse features: (2x3 matrix a -> b, inliers).
pub(crate) fn coarse_pair(
    (a, ia): (&FrameData, &MatchIndex),
    (b, ib): (&FrameData, &MatchIndex),
    cfg: &AlignConfig,
) -> Result<Option<SimilarityMatch>, AlignError> {
    let long = f64::from(a.width.max(a.height));
    let cs = (f64::from(cfg.coarse_long_side) / long).min(1.0);
    let area = f64::from(a.width) * f64::from(a.height) * cs * cs;
    let min = AlignConfig::scaled_min(cfg.coarse_min_inliers, 960.0 * 540.0, area);
    let m = match_indexed(ia, ib, 0.8)?;
    if m.len() < min {
        return Ok(None);
    }
    let thr = cfg.coarse_inlier_px * long / 960.0;
    let src = pts(&a.coarse, m.iter().map(|x| x.0));
    let dst = pts(&b.coarse, m.iter().map(|x| x.1));
    Ok(estimate_similarity(&src, &dst, thr)?.and_then(
        |Robust {
             model: t,
             inliers: inl,
         }| {
            let kept: Vec<(u32, u32)> = m
                .iter()
                .zip(&inl)
                .filter(|(_, ok)| **ok)
                .map(|(x, _)| *x)
                .collect();
            (kept.len() >= min).then_some((t, kept))
        },
    ))
}

/// [`coarse_pair`] for many pairs in parallel.
pub(crate) fn coarse_pairs(
    frames: &[FrameData],
    index: &[MatchIndex],
    pairs: &[(usize, usize)],
    cfg: &AlignConfig,
    progress: &dyn Progress,
) -> Result<Vec<(usize, usize, Option<SimilarityMatch>)>, AlignError> {
    pairs
        .par_iter()
        .map(|&(i, j)| {
            let r = coarse_pair((&frames[i], &index[i]), (&frames[j], &index[j]), cfg);
            progress.advance(1);
            r.map(|r| (i, j, r))
        })
        .collect()
}

pub(crate) fn sim_to_mat(t: &[[f64; 3]; 2]) -> Mat3 {
    Mat3::new(
        t[0][0], t[0][1], t[0][2], t[1][0], t[1][1], t[1][2], 0.0, 0.0, 1.0,
    )
}

/// Coarse alignment: consecutive pairs, then pairs whose predicted footprints overlap.
pub(crate) fn coarse(
    frames: &[FrameData],
    cfg: &AlignConfig,
    progress: &dyn Progress,
) -> Result<(Connectivity, usize), AlignError> {
    let n = frames.len();
    let mut counts = HashMap::new();
    let mut matches = HashMap::new();
    let mut tested = 0usize;
    let chain: Vec<(usize, usize)> = if cfg.all_pairs {
        (0..n)
            .flat_map(|i| (i + 1..n).map(move |j| (i, j)))
            .collect()
    } else {
        (0..n.saturating_sub(1)).map(|i| (i, i + 1)).collect()
    };
    progress.stage("coarse alignment", chain.len() as u64);
    // Each frame meets a dozen others: its search index is built once.
    let index: Vec<MatchIndex> = frames
        .par_iter()
        .map(|f| MatchIndex::new(&f.coarse))
        .collect::<Result<_, _>>()?;
    let results = coarse_pairs(frames, &index, &chain, cfg, progress)?;
    tested += chain.len();
    let mut sims: HashMap<(usize, usize), Mat3> = HashMap::new();
    for (i, j, r) in results {
        if let Some((t, m)) = r {
            counts.insert((i, j), m.len());
            matches.insert((i, j), m);
            sims.insert((i, j), sim_to_mat(&t));
        }
    }
    if !cfg.all_pairs {
        // Predict each frame's position by chaining similarities within segments of
        // the time chain (frame i -> first frame of its segment), then test pairs of
        // the same segment whose predicted centres are closer than 0.8 frame
        // diagonals. Where the chain breaks (blur, a fast jerk), every pair across the
        // two segments is tested, so a break cannot split the capture by itself.
        let mut to_seg: Vec<Mat3> = vec![Mat3::identity(); n];
        let mut seg = vec![0usize; n];
        for i in 1..n {
            match sims.get(&(i - 1, i)).and_then(|s| s.try_inverse()) {
                Some(inv) => {
                    to_seg[i] = to_seg[i - 1] * inv;
                    seg[i] = seg[i - 1];
                }
                None => {
                    to_seg[i] = Mat3::identity();
                    seg[i] = seg[i - 1] + 1;
                }
            }
        }
        let centre = |f: &FrameData| Vec2::new(0.5 * f64::from(f.width), 0.5 * f64::from(f.height));
        let diag = frames
            .first()
            .map(|f| f64::from(f.width).hypot(f64::from(f.height)))
            .unwrap_or(1.0);
        // Within a segment: each frame's nearest predicted neighbours (at most
        // `LOOP_CANDIDATES`) closer than 0.8 frame diagonals. Across a chain break: the
        // frames just before and after it, which is where the hand's path continues.
        const LOOP_CANDIDATES: usize = 10;
        let mut extra = BTreeSet::new();
        for i in 0..n {
            let pa = Homography(to_seg[i]).apply(centre(&frames[i]));
            let mut near: Vec<(f64, usize)> = (0..n)
                .filter(|&j| j + 1 < i || j > i + 1)
                .filter(|&j| seg[j] == seg[i])
                .filter_map(|j| {
                    let pb = Homography(to_seg[j]).apply(centre(&frames[j]))?;
                    let d = (pa? - pb).norm();
                    (d < 0.8 * diag).then_some((d, j))
                })
                .collect();
            near.sort_by(|a, b| a.0.total_cmp(&b.0));
            for &(_, j) in near.iter().take(LOOP_CANDIDATES) {
                extra.insert((i.min(j), i.max(j)));
            }
        }
        for b in 1..n {
            if seg[b] != seg[b - 1] {
                for i in b.saturating_sub(4)..b {
                    for j in b..(b + 4).min(n) {
                        if j > i + 1 {
                            extra.insert((i, j));
                        }
                    }
                }
            }
        }
        let extra: Vec<(usize, usize)> = extra.into_iter().collect();
        progress.stage("loop closure", extra.len() as u64);
        let results = coarse_pairs(frames, &index, &extra, cfg, progress)?;
        tested += extra.len();
        for (i, j, r) in results {
            if let Some((_, m)) = r {
                counts.insert((i, j), m.len());
                matches.insert((i, j), m);
            }
        }
    }
    progress.finish();
    let kept = filter_connectivity(n, &counts);
    Ok((
        Connectivity {
            frames: n,
            counts,
            matches,
            kept,
        },
        tested,
    ))
}

/// Threshold at the 50th percentile of overlapping pairs, then a 5x5 median filter of
/// the binary map (paper 3.1.3). Consecutive frames that matched are always kept: the
/// percentile is meant to remove weak loop closures, not the time chain.
pub fn filter_connectivity(
    n: usize,
    counts: &HashMap<(usize, usize), usize>,
) -> BTreeSet<(usize, usize)> {
    let mut values: Vec<usize> = counts.values().copied().collect();
    values.sort_unstable();
    let thr = values.get(values.len() / 2).copied().unwrap_or(0);
    let on = |i: usize, j: usize| -> bool {
        let (a, b) = if i < j { (i, j) } else { (j, i) };
        counts.get(&(a, b)).is_some_and(|c| *c >= thr)
    };
    let mut kept = BTreeSet::new();
    for (&(i, j), _) in counts.iter() {
        // Median of the 5x5 neighbourhood of (i, j) in the symmetric binary map.
        let mut ones = 0;
        let mut total = 0;
        for di in -2i64..=2 {
            for dj in -2i64..=2 {
                let (a, b) = (i as i64 + di, j as i64 + dj);
                if a < 0 || b < 0 || a >= n as i64 || b >= n as i64 || a == b {
                    continue;
                }
                total += 1;
                ones += usize::from(on(a as usize, b as usize));
            }
        }
        if 2 * ones >= total || j == i + 1 {
            kept.insert((i, j));
        }
    }
    // Beyond the paper: the filter can cut a short capture in two where the hand
    // jerked. Every raw pair was verified by RANSAC, so add back the strongest raw
    // pairs that join separate components (a maximum spanning forest over the rest).
    let mut parent: Vec<usize> = (0..n).collect();
    fn root(p: &mut [usize], mut i: usize) -> usize {
        while p[i] != i {
            p[i] = p[p[i]];
            i = p[i];
        }
        i
    }
    for &(i, j) in &kept {
        let (a, b) = (root(&mut parent, i), root(&mut parent, j));
        parent[a] = b;
    }
    let mut raw: Vec<(&(usize, usize), &usize)> = counts.iter().collect();
    raw.sort_by(|a, b| b.1.cmp(a.1).then(a.0.cmp(b.0)));
    for (&(i, j), _) in raw {
        let (a, b) = (root(&mut parent, i), root(&mut parent, j));
        if a != b {
            parent[a] = b;
            kept.insert((i, j));
        }
    }
    kept
}

/// Connected components of the kept pairs, largest first (ties: earliest frame
/// first), each sorted.
pub(crate) fn components(n: usize, pairs: &BTreeSet<(usize, usize)>) -> Vec<Vec<usize>> {
    let mut adj = vec![Vec::new(); n];
    for &(i, j) in pairs {
        adj[i].push(j);
        adj[j].push(i);
    }
    let mut seen = vec![false; n];
    let mut out = Vec::new();
    for s in 0..n {
        if seen[s] {
            continue;
        }
        let mut comp = Vec::new();
        let mut q = VecDeque::from([s]);
        seen[s] = true;
        while let Some(v) = q.pop_front() {
            comp.push(v);
            for &w in &adj[v] {
                if !seen[w] {
                    seen[w] = true;
                    q.push_back(w);
                }
            }
        }
        comp.sort_unstable();
        out.push(comp);
    }
    out.sort_by_key(|c| (std::cmp::Reverse(c.len()), c[0]));
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn components_of_a_hand_made_graph() {
        // 0-1-2 and 3-4, 5 alone.
        let pairs: BTreeSet<(usize, usize)> = [(0, 1), (1, 2), (3, 4)].into_iter().collect();
        assert_eq!(components(2, &BTreeSet::new()), vec![vec![0], vec![1]]);
        assert_eq!(
            components(6, &pairs),
            vec![vec![0, 1, 2], vec![3, 4], vec![5]]
        );
    }

    #[test]
    fn connectivity_filter_keeps_the_chain_and_rejoins_a_cut() {
        // A chain of 8 frames; frames 3-4 matched weakly (a hand jerk), everything
        // else strongly with its next two frames.
        let mut counts = HashMap::new();
        for i in 0..8usize {
            for d in 1..=2 {
                if i + d < 8 {
                    counts.insert((i, i + d), if (i, i + d) == (3, 4) { 1 } else { 100 });
                }
            }
        }
        counts.remove(&(2, 4));
        counts.remove(&(3, 5));
        let kept = filter_connectivity(8, &counts);
        // Time-chain neighbours are always kept, so the capture stays in one piece.
        assert!(kept.contains(&(3, 4)));
        assert_eq!(components(8, &kept)[0].len(), 8);
    }
}
