//! Coarse and fine alignment, the connectivity map, and the set-up of the global solve.

use std::collections::{BTreeSet, HashMap, VecDeque};

use rayon::prelude::*;
use svbrdf_core::geometry::{Intrinsics, Mat3, Pose, Vec2, Vec3};
use svbrdf_core::homography::Homography;
use svbrdf_core::image::ImageU8;
use svbrdf_cv::features::{
    downscaled, estimate_homography, estimate_similarity, match_indexed, match_into,
    match_one_to_one, sift, Features, MatchIndex, Robust,
};

use crate::blur::blurry_frames;
use crate::config::{AlignConfig, FineMethod};
use crate::frames::FrameData;
use crate::patch::{refine, Grey, PatchSettings};
use crate::pose::pose_from_homography;
use crate::reference::ReferenceFrame;
use crate::solve::{solve, Constraint, SolveReport};
use crate::{AlignError, DropCounts, Progress};

/// A verified similarity between two frames (2x3, row-major) and its inlier matches
/// (coarse feature indices in a and b).
type SimilarityMatch = ([[f64; 3]; 2], Vec<(u32, u32)>);
/// Verified correspondences (frame a px, frame b px) and the homography a -> b.
type FineMatch = (Vec<[f64; 2]>, Vec<[f64; 2]>, Mat3);

/// Features of the reference photo with their plane positions (cm).
pub struct ReferenceFeatures {
    features: Features,
    /// Full-resolution reference pixels of the features.
    pixels: Vec<Vec2>,
    plane: Vec<Vec2>,
    /// Full-resolution luminance, for `FineMethod::Patch`.
    grey: Option<Grey>,
    /// plane_from_pixel of the reference photo.
    plane_from_pixel: Homography,
    /// Search index of the features (`FineMethod::Patch`), built once for all frames.
    index: Option<MatchIndex>,
}

/// Reference-photo features for absolute anchoring of frames. With patch refinement
/// they are matched with the frames' coarse features, so they are detected at about
/// the same density per cm: the reference is taken from about twice the frames'
/// height, so at twice the coarse long side, with four times the features.
pub fn reference_features(
    img: &ImageU8,
    rf: &ReferenceFrame,
    cfg: &AlignConfig,
) -> Result<ReferenceFeatures, AlignError> {
    let long = img.width.max(img.height) as f64;
    let (side, count) = match cfg.fine_method {
        FineMethod::Sift => (f64::from(cfg.fine_long_side), cfg.fine_features * 2),
        FineMethod::Patch => (
            2.0 * f64::from(cfg.coarse_long_side),
            cfg.coarse_features * 4,
        ),
    };
    let s = (side / long).min(1.0);
    let small = downscaled(img, s)?;
    let f = sift(&small, count, cfg.sift_contrast, None)?;
    let mut plane = Vec::with_capacity(f.len());
    let mut pixels = Vec::with_capacity(f.len());
    for p in &f.points {
        let full = Vec2::new(
            (f64::from(p[0]) + 0.5) / s - 0.5,
            (f64::from(p[1]) + 0.5) / s - 0.5,
        );
        pixels.push(full);
        plane.push(rf.plane_from_pixel.apply(full).unwrap_or_else(Vec2::zeros));
    }
    let grey = (cfg.fine_method == FineMethod::Patch).then(|| Grey::from_image(img));
    let index = match cfg.fine_method {
        FineMethod::Patch => Some(MatchIndex::new(&f)?),
        FineMethod::Sift => None,
    };
    Ok(ReferenceFeatures {
        index,
        features: f,
        pixels,
        plane,
        grey,
        plane_from_pixel: rf.plane_from_pixel,
    })
}

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

/// The second stream's decoded frames (times already on the flash camera's clock,
/// `stream` = 1) and its camera.
pub struct SecondFrames {
    /// Frames at the second stream's frame step, after the flash onset.
    pub frames: Vec<FrameData>,
    /// The second camera's intrinsics.
    pub intrinsics: Intrinsics,
}

/// The decoded frames to register.
pub struct Streams {
    /// The flash video's frames (or the still photos).
    pub frames: Vec<FrameData>,
    /// `true` for video frames (time order, blur pre-filter); `false` for photos.
    pub ordered: bool,
    /// The second stream of a two-camera capture.
    pub second: Option<SecondFrames>,
}

/// Result of registration, ready to be written.
pub struct Registration {
    /// Frames kept, with their data: the flash stream's, then the second stream's.
    pub frames: Vec<FrameData>,
    /// Per kept frame: sub-frame rectangles and plane_from_pixel homographies.
    pub mappings: Vec<Vec<([f64; 4], Mat3)>>,
    /// Per kept frame: camera pose.
    pub poses: Vec<Pose>,
    /// Per kept frame: light (flash) position, cm. For second-stream frames it is the
    /// flash camera's at the synchronised time, interpolated between its frames.
    pub lights: Vec<Vec3>,
    /// Intrinsics of the video camera.
    pub intrinsics: Intrinsics,
    /// Frame accounting (flash stream).
    pub drops: DropCounts,
    /// Frame accounting of the second stream (`disconnected` is unused), if any.
    pub second_drops: Option<DropCounts>,
    /// Second-stream frames matched to a flash frame (joint constraints between the
    /// streams).
    pub cross_pairs: usize,
    /// Coarse connectivity (over frames after blur selection).
    pub connectivity: Connectivity,
    /// Coarse pairs verified by RANSAC, as (video frame, video frame, inliers).
    pub verified_pairs: Vec<(u64, u64, usize)>,
    /// Coarse pairs tested.
    pub coarse_tested: usize,
    /// Fine pairs used.
    pub fine_pairs: usize,
    /// Frames anchored by reference matches.
    pub reference_anchored: usize,
    /// Frames with markers.
    pub with_markers: usize,
    /// Solve statistics.
    pub solve: SolveReport,
}

fn pts(f: &Features, idx: impl Iterator<Item = u32>) -> Vec<[f64; 2]> {
    idx.map(|i| {
        let p = f.points[i as usize];
        [f64::from(p[0]), f64::from(p[1])]
    })
    .collect()
}

/// Similarity between two frames' coarse features: (2x3 matrix a -> b, inliers).
fn coarse_pair(
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
fn coarse_pairs(
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

fn sim_to_mat(t: &[[f64; 3]; 2]) -> Mat3 {
    Mat3::new(
        t[0][0], t[0][1], t[0][2], t[1][0], t[1][1], t[1][2], 0.0, 0.0, 1.0,
    )
}

/// Coarse alignment: consecutive pairs, then pairs whose predicted footprints overlap.
fn coarse(
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

/// Largest connected component of the kept pairs.
fn largest_component(n: usize, pairs: &BTreeSet<(usize, usize)>) -> Vec<usize> {
    let mut adj = vec![Vec::new(); n];
    for &(i, j) in pairs {
        adj[i].push(j);
        adj[j].push(i);
    }
    let mut seen = vec![false; n];
    let mut best = Vec::new();
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
        if comp.len() > best.len() {
            best = comp;
        }
    }
    best.sort_unstable();
    best
}

/// The fine minimum inlier count for this frame size.
fn fine_min(f: &FrameData, cfg: &AlignConfig) -> usize {
    let long = f64::from(f.width.max(f.height));
    let fs = (f64::from(cfg.fine_long_side) / long).min(1.0);
    AlignConfig::scaled_min(
        cfg.fine_min_inliers,
        3840.0 * 2160.0,
        f64::from(f.width) * f64::from(f.height) * fs * fs,
    )
}

/// Verified fine correspondences between frames a and b (full-resolution pixels).
fn fine_pair(
    a: &FrameData,
    b: &FrameData,
    coarse_matches: Option<&[(u32, u32)]>,
    cfg: &AlignConfig,
) -> Result<Option<FineMatch>, AlignError> {
    if cfg.fine_method == FineMethod::Patch {
        return fine_pair_patch(a, b, coarse_matches, cfg);
    }
    let m = match_one_to_one(&a.fine, &b.fine, 0.8)?;
    let min = fine_min(a, cfg);
    if m.len() < min {
        return Ok(None);
    }
    let long = f64::from(a.width.max(a.height));
    let thr = cfg.fine_inlier_px * long / 3840.0;
    let src = pts(&a.fine, m.iter().map(|x| x.0));
    let dst = pts(&b.fine, m.iter().map(|x| x.1));
    let Some(Robust {
        model: h,
        inliers: inl,
    }) = estimate_homography(&src, &dst, thr)?
    else {
        return Ok(None);
    };
    let keep: Vec<usize> = (0..inl.len()).filter(|&k| inl[k]).collect();
    if keep.len() < min {
        return Ok(None);
    }
    Ok(Some((
        keep.iter().map(|&k| src[k]).collect(),
        keep.iter().map(|&k| dst[k]).collect(),
        svbrdf_core::geometry::mat3_from_rows(&h),
    )))
}

/// Patch settings for a frame of `long` full-resolution pixels whose patch image is
/// `grey_long` pixels: the radius scales with the patch image, the search covers the
/// coarse features' localisation error (about one coarse pixel).
fn patch_settings(cfg: &AlignConfig, long: f64, grey_long: f64) -> PatchSettings {
    let coarse_px = grey_long / f64::from(cfg.coarse_long_side).min(long);
    PatchSettings {
        radius: (cfg.patch_radius_px * grey_long / 3840.0).round().max(5.0) as usize,
        search: (coarse_px.round() as i32).clamp(3, 8),
        ..PatchSettings::default()
    }
}

/// Full-resolution pixel to patch-image pixel (pixel centres at integers).
fn to_grey(p: Vec2, s: f64) -> Vec2 {
    Vec2::new((p.x + 0.5) * s - 0.5, (p.y + 0.5) * s - 0.5)
}

/// Refine coarse correspondences `(a px, b px)` (full resolution) by patches: `a`'s
/// point stays, `b`'s moves to where `a`'s patch, warped by the local linear part of
/// `h_ab`, matches best. Returns the kept pairs, full-resolution pixels.
fn refine_matches(
    (ga, width_a): (&Grey, u32),
    (gb, width_b): (&Grey, u32),
    matches: impl Iterator<Item = (Vec2, Vec2)>,
    h_ab: &Mat3,
    settings: &PatchSettings,
) -> Vec<([f64; 2], Vec2)> {
    let (sa, sb) = (
        ga.width as f64 / f64::from(width_a),
        gb.width as f64 / f64::from(width_b),
    );
    let Some(h_ba) = h_ab.try_inverse().map(Homography) else {
        return Vec::new();
    };
    matches
        .filter_map(|(p, q)| {
            // b -> a offsets, in patch-image pixels of each.
            let f0 = h_ba.apply(q)?;
            let fx = h_ba.apply(q + Vec2::new(1.0, 0.0))? - f0;
            let fy = h_ba.apply(q + Vec2::new(0.0, 1.0))? - f0;
            let k = sa / sb;
            let jac = [k * fx.x, k * fy.x, k * fx.y, k * fy.y];
            let (qr, _) = refine(ga, to_grey(p, sa), gb, to_grey(q, sb), jac, settings)?;
            let q_full = Vec2::new((qr.x + 0.5) / sb - 0.5, (qr.y + 0.5) / sb - 0.5);
            Some(([p.x, p.y], q_full))
        })
        .collect()
}

/// [`fine_pair`] by patch refinement of the coarse matches (those of the coarse stage
/// where given, else matched here).
fn fine_pair_patch(
    a: &FrameData,
    b: &FrameData,
    coarse_matches: Option<&[(u32, u32)]>,
    cfg: &AlignConfig,
) -> Result<Option<FineMatch>, AlignError> {
    let (Some(ga), Some(gb)) = (a.grey.as_deref(), b.grey.as_deref()) else {
        return Ok(None);
    };
    let m = match coarse_matches {
        Some(m) => m.to_vec(),
        None => match_one_to_one(&a.coarse, &b.coarse, 0.8)?,
    };
    let min = fine_min(a, cfg);
    if m.len() < min {
        return Ok(None);
    }
    let long = f64::from(a.width.max(a.height));
    let thr = cfg.fine_inlier_px * long / 3840.0;
    let src = pts(&a.coarse, m.iter().map(|x| x.0));
    let dst = pts(&b.coarse, m.iter().map(|x| x.1));
    let Some(Robust { model, inliers }) = estimate_homography(&src, &dst, thr)? else {
        return Ok(None);
    };
    let h = svbrdf_core::geometry::mat3_from_rows(&model);
    let settings = patch_settings(cfg, long, ga.width.max(ga.height) as f64);
    let refined = refine_matches(
        (ga, a.width),
        (gb, b.width),
        (0..src.len()).filter(|&k| inliers[k]).map(|k| {
            (
                Vec2::new(src[k][0], src[k][1]),
                Vec2::new(dst[k][0], dst[k][1]),
            )
        }),
        &h,
        &settings,
    );
    if refined.len() < min {
        return Ok(None);
    }
    Ok(Some((
        refined.iter().map(|r| r.0).collect(),
        refined.iter().map(|r| [r.1.x, r.1.y]).collect(),
        h,
    )))
}

/// Absolute anchors of one frame from the reference photo by patch refinement:
/// (frame px, plane cm).
fn reference_anchors_patch(
    f: &FrameData,
    rfe: &ReferenceFeatures,
    cfg: &AlignConfig,
    thr_cm: f64,
) -> Result<Vec<([f64; 2], Vec2)>, AlignError> {
    let (Some(ga), Some(gr), Some(index)) = (f.grey.as_deref(), rfe.grey.as_ref(), &rfe.index)
    else {
        return Ok(Vec::new());
    };
    let m = match_into(&f.coarse, index, 0.8)?;
    let min = fine_min(f, cfg);
    if m.len() < min {
        return Ok(Vec::new());
    }
    let src = pts(&f.coarse, m.iter().map(|x| x.0));
    let dst: Vec<[f64; 2]> = m
        .iter()
        .map(|x| [rfe.pixels[x.1 as usize].x, rfe.pixels[x.1 as usize].y])
        .collect();
    // The inlier distance on the plane in reference pixels.
    let c = Vec2::new(0.5 * gr.width as f64, 0.5 * gr.height as f64);
    let cm_per_ref_px = match (
        rfe.plane_from_pixel.apply(c),
        rfe.plane_from_pixel.apply(c + Vec2::new(1.0, 0.0)),
    ) {
        (Some(a), Some(b)) => (a - b).norm().max(1e-9),
        _ => return Ok(Vec::new()),
    };
    let Some(Robust { model, inliers }) = estimate_homography(&src, &dst, thr_cm / cm_per_ref_px)?
    else {
        return Ok(Vec::new());
    };
    let keep: Vec<usize> = (0..src.len()).filter(|&k| inliers[k]).collect();
    if keep.len() < min {
        return Ok(Vec::new());
    }
    let h_fr = Homography(svbrdf_core::geometry::mat3_from_rows(&model));
    let (fp, rp): (Vec<Vec2>, Vec<Vec2>) = keep
        .iter()
        .map(|&k| {
            (
                Vec2::new(src[k][0], src[k][1]),
                Vec2::new(dst[k][0], dst[k][1]),
            )
        })
        .unzip();
    let long = f64::from(f.width.max(f.height));
    let settings = patch_settings(cfg, long, ga.width.max(ga.height) as f64);
    let refined = refine_matches(
        (ga, f.width),
        (gr, gr.width as u32),
        fp.into_iter().zip(rp),
        &h_fr.0,
        &settings,
    );
    let out: Vec<([f64; 2], Vec2)> = refined
        .into_iter()
        .filter_map(|(p, r)| Some((p, rfe.plane_from_pixel.apply(r)?)))
        .collect();
    Ok(if out.len() >= min { out } else { Vec::new() })
}

/// Sub-frame layout of one frame: rectangles with overlap, and the core cells.
struct Grid {
    cols: usize,
    rows: usize,
    w: f64,
    h: f64,
    ox: f64,
    oy: f64,
}

impl Grid {
    fn new(width: u32, height: u32, cfg: &AlignConfig) -> Self {
        let (w, h) = (f64::from(width), f64::from(height));
        let (cols, rows) = match cfg.subframes {
            Some((c, r)) => (c as usize, r as usize),
            None => {
                // The paper's 5 x 11 at 2160 x 3840 (portrait), at least 3 x 5.
                let (short, long) = (w.min(h), w.max(h));
                let a = ((5.0 * short / 2160.0).round() as usize).max(3);
                let b = ((11.0 * long / 3840.0).round() as usize).max(5);
                if h >= w {
                    (a, b)
                } else {
                    (b, a)
                }
            }
        };
        // Paper: 25 and 22 px overlap at 2160 x 3840.
        let s = w.max(h) / 3840.0;
        Self {
            cols,
            rows,
            w,
            h,
            ox: (25.0 * s).max(4.0),
            oy: (22.0 * s).max(4.0),
        }
    }

    fn len(&self) -> usize {
        self.cols * self.rows
    }

    fn cell(&self, p: Vec2) -> usize {
        let c = (((p.x + 0.5) / self.w * self.cols as f64).floor() as isize)
            .clamp(0, self.cols as isize - 1) as usize;
        let r = (((p.y + 0.5) / self.h * self.rows as f64).floor() as isize)
            .clamp(0, self.rows as isize - 1) as usize;
        r * self.cols + c
    }

    /// Rectangle `[x0, y0, x1, y1]` of a sub-frame including its overlap.
    fn rect(&self, k: usize) -> [f64; 4] {
        let (c, r) = ((k % self.cols) as f64, (k / self.cols) as f64);
        let (cw, ch) = (self.w / self.cols as f64, self.h / self.rows as f64);
        [
            (c * cw - 0.5 - self.ox).max(-0.5),
            (r * ch - 0.5 - self.oy).max(-0.5),
            ((c + 1.0) * cw - 0.5 + self.ox).min(self.w - 0.5),
            ((r + 1.0) * ch - 0.5 + self.oy).min(self.h - 0.5),
        ]
    }

    /// Sample points on the shared borders of neighbouring cells: (cell a, cell b, point).
    fn seams(&self) -> Vec<(usize, usize, Vec2)> {
        let (cw, ch) = (self.w / self.cols as f64, self.h / self.rows as f64);
        let mut out = Vec::new();
        for r in 0..self.rows {
            for c in 0..self.cols {
                let k = r * self.cols + c;
                for t in [0.1, 0.5, 0.9] {
                    if c + 1 < self.cols {
                        let x = (c + 1) as f64 * cw - 0.5;
                        for dx in [-self.ox, 0.0, self.ox] {
                            out.push((k, k + 1, Vec2::new(x + dx, (r as f64 + t) * ch - 0.5)));
                        }
                    }
                    if r + 1 < self.rows {
                        let y = (r + 1) as f64 * ch - 0.5;
                        for dy in [-self.oy, 0.0, self.oy] {
                            out.push((
                                k,
                                k + self.cols,
                                Vec2::new((c as f64 + t) * cw - 0.5, y + dy),
                            ));
                        }
                    }
                }
            }
        }
        out
    }
}

/// Normalisation of frame pixels for conditioning: centred, long side = 2.
fn normaliser(w: u32, h: u32) -> Mat3 {
    let s = 2.0 / f64::from(w.max(h));
    Mat3::new(
        s,
        0.0,
        -s * 0.5 * (f64::from(w) - 1.0),
        0.0,
        s,
        -s * 0.5 * (f64::from(h) - 1.0),
        0.0,
        0.0,
        1.0,
    )
}

/// The frames the blur metric keeps (eq. 1, per stream) and how many it drops.
fn drop_blurry(frames: Vec<FrameData>, sigmas: f64) -> (Vec<FrameData>, Vec<u64>) {
    let metrics: Vec<f64> = frames.iter().map(|f| f.blur).collect();
    let blurry: BTreeSet<usize> = blurry_frames(&metrics, sigmas).into_iter().collect();
    let dropped = blurry.iter().map(|&i| frames[i].index).collect();
    let sharp = frames
        .into_iter()
        .enumerate()
        .filter(|(i, _)| !blurry.contains(i))
        .map(|(_, f)| f)
        .collect();
    (sharp, dropped)
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

/// Coarse to fine registration of the decoded frames.
pub fn register(
    streams: Streams,
    rf: &ReferenceFrame,
    ref_features: Option<&ReferenceFeatures>,
    cfg: &AlignConfig,
    progress: &dyn Progress,
    lap: &mut dyn FnMut(&str),
) -> Result<Registration, AlignError> {
    let Streams {
        frames: decoded,
        ordered,
        second,
    } = streams;
    let mut drops = DropCounts {
        decoded: decoded.len(),
        blur_metrics: decoded.iter().map(|f| (f.index, f.blur)).collect(),
        ..DropCounts::default()
    };
    // Blur selection (video frames only: a still photo was taken on purpose, and a
    // handful of them gives no statistics).
    let frames = if ordered {
        let (sharp, blurry) = drop_blurry(decoded, cfg.blur_sigmas);
        drops.blurry = blurry.len();
        drops.blurry_frames = blurry;
        sharp
    } else {
        decoded
    };
    if frames.len() < 2 {
        return Err(AlignError::Connect(format!(
            "only {} sharp frame(s) out of {}: need at least 2",
            frames.len(),
            drops.decoded
        )));
    }
    let (width, height) = (frames[0].width, frames[0].height);
    let intrinsics = Intrinsics::from_fov(width, height, cfg.camera.fov_deg)?;

    // Coarse alignment and the connectivity map. Photos have no time order: every
    // pair is tested.
    let all_pairs_cfg;
    let coarse_cfg = if ordered {
        cfg
    } else {
        all_pairs_cfg = AlignConfig {
            all_pairs: true,
            ..cfg.clone()
        };
        &all_pairs_cfg
    };
    let (connectivity, coarse_tested) = coarse(&frames, coarse_cfg, progress)?;
    let mut verified_pairs: Vec<(u64, u64, usize)> = connectivity
        .counts
        .iter()
        .map(|(&(i, j), &c)| (frames[i].index, frames[j].index, c))
        .collect();
    verified_pairs.sort_unstable();
    let comp = largest_component(frames.len(), &connectivity.kept);
    drops.disconnected = frames.len() - comp.len();
    lap("coarse alignment");
    if comp.len() < 2 {
        return Err(AlignError::Connect(format!(
            "frames do not connect: {} of {} sharp frames matched none of the others (repetitive or featureless texture?)",
            frames.len() - comp.len(),
            frames.len()
        )));
    }
    let in_comp: HashMap<usize, usize> = comp.iter().enumerate().map(|(k, &i)| (i, k)).collect();
    // The thresholded, filtered map decides which frames are kept (its largest
    // component, as in the paper); fine matching then uses every pair that coarse
    // RANSAC verified among them. Measured on the paper preset (4 s): 18 -> 54 fine
    // pairs, 95th percentile alignment error 0.53 -> 0.50 px.
    let all: Vec<(usize, usize)> = connectivity
        .counts
        .keys()
        .filter(|(i, j)| in_comp.contains_key(i) && in_comp.contains_key(j))
        .map(|&(i, j)| (in_comp[&i], in_comp[&j]))
        .collect();
    // Keep each frame's strongest connections (and the time chain).
    let mut pairs = BTreeSet::new();
    let strength = |i: usize, j: usize| {
        connectivity
            .counts
            .get(&(comp[i], comp[j]))
            .copied()
            .unwrap_or(0)
    };
    for f in 0..comp.len() {
        let mut mine: Vec<(usize, usize)> = all
            .iter()
            .copied()
            .filter(|&(i, j)| i == f || j == f)
            .collect();
        // Ties broken by the pair itself: `all` comes from a hash map, whose order
        // differs from process to process, and a tie at the cut made two runs of the
        // same video keep different pairs.
        mine.sort_by_key(|&(i, j)| (std::cmp::Reverse(strength(i, j)), i, j));
        for (k, p) in mine.into_iter().enumerate() {
            if k < cfg.max_pairs_per_frame || p.1 == p.0 + 1 {
                pairs.insert(p);
            }
        }
    }
    let mut pairs: Vec<(usize, usize)> = pairs.into_iter().collect();
    let mut frames: Vec<FrameData> = comp.iter().map(|&i| frames[i].clone()).collect();
    let n_flash = frames.len();

    // The second stream joins the same problem: its frames chain to their next two
    // neighbours, and each one is matched with the flash frames nearest in time,
    // which were lit by the same flash position (so highlights agree) and tie the two
    // streams together.
    let intrinsics2 = second.as_ref().map(|s| s.intrinsics);
    let mut second_drops = None;
    if let Some(sec) = second {
        let decoded2 = sec.frames.len();
        let (kept2, blurry2) = drop_blurry(sec.frames, cfg.blur_sigmas);
        second_drops = Some(DropCounts {
            decoded: decoded2,
            blurry: blurry2.len(),
            blurry_frames: blurry2,
            ..DropCounts::default()
        });
        let (base, m) = (frames.len(), kept2.len());
        for (k, f) in kept2.iter().enumerate() {
            for d in 1..=2 {
                if k + d < m {
                    pairs.push((base + k, base + k + d));
                }
            }
            let t = f.time_s;
            let mut near: Vec<(f64, usize)> = (0..n_flash)
                .map(|i| ((frames[i].time_s - t).abs(), i))
                .collect();
            near.sort_by(|a, b| a.0.total_cmp(&b.0));
            for &(_, i) in near.iter().take(cfg.cross_pairs_per_frame) {
                pairs.push((i, base + k));
            }
        }
        frames.extend(kept2);
    }
    let n = frames.len();

    // Fine matches between connected frames.
    progress.stage("fine matching", (pairs.len() + n) as u64);
    let fine: Vec<_> = pairs
        .par_iter()
        .map(|&(i, j)| {
            // Flash-stream pairs reuse their coarse inlier matches.
            let known = (j < n_flash)
                .then(|| connectivity.matches.get(&(comp[i], comp[j])))
                .flatten();
            let r = fine_pair(&frames[i], &frames[j], known.map(Vec::as_slice), cfg);
            progress.advance(1);
            r.map(|r| (i, j, r))
        })
        .collect::<Result<_, _>>()?;
    // Plane cm per frame pixel at a typical capture height (60% of the reference's).
    let cm_per_px = rf.height.clamp(5.0, 50.0) * 0.6 / intrinsics.fx;
    // Fine matches with the reference photo: absolute anchors (beyond the paper).
    let anchors: Vec<Vec<([f64; 2], Vec2)>> = frames
        .par_iter()
        .map(|f| {
            let out = match ref_features {
                None => Ok(Vec::new()),
                Some(rfe) if cfg.fine_method == FineMethod::Patch => {
                    let thr_px = cfg.fine_inlier_px * f64::from(f.width.max(f.height)) / 3840.0;
                    reference_anchors_patch(f, rfe, cfg, thr_px * cm_per_px)
                }
                Some(rfe) => match_one_to_one(&f.fine, &rfe.features, 0.8)
                    .and_then(|m| {
                        let min = fine_min(f, cfg);
                        if m.len() < min {
                            return Ok(Vec::new());
                        }
                        let src = pts(&f.fine, m.iter().map(|x| x.0));
                        let dst: Vec<[f64; 2]> = m
                            .iter()
                            .map(|x| [rfe.plane[x.1 as usize].x, rfe.plane[x.1 as usize].y])
                            .collect();
                        // Verify on the plane: a homography frame px -> plane cm, with the
                        // inlier distance converted through a rough frame scale.
                        let thr_px = cfg.fine_inlier_px * f64::from(f.width.max(f.height)) / 3840.0;
                        let thr_cm = thr_px * cm_per_px;
                        Ok(match estimate_homography(&src, &dst, thr_cm)? {
                            Some(Robust { inliers: inl, .. })
                                if inl.iter().filter(|v| **v).count() >= min =>
                            {
                                (0..src.len())
                                    .filter(|&k| inl[k])
                                    .map(|k| (src[k], Vec2::new(dst[k][0], dst[k][1])))
                                    .collect()
                            }
                            _ => Vec::new(),
                        })
                    })
                    .map_err(AlignError::from),
            };
            progress.advance(1);
            out
        })
        .collect::<Result<_, AlignError>>()?;
    progress.finish();
    lap("fine matching");
    // The patch images (1 GB for 120 4K frames) are not needed any more.
    for f in &mut frames {
        f.grey = None;
    }

    // Marker anchors (eqs. 5-6).
    let world_markers: HashMap<i32, [Vec2; 4]> =
        rf.markers.iter().map(|(id, c)| (*id, *c)).collect();
    let marker_anchors: Vec<Vec<(Vec2, Vec2)>> = frames
        .iter()
        .map(|f| {
            f.markers
                .iter()
                .filter_map(|m| {
                    world_markers
                        .get(&m.id)
                        .map(|w| (0..4).map(|k| (m.corners[k], w[k])).collect::<Vec<_>>())
                })
                .flatten()
                .collect()
        })
        .collect();
    let with_markers = marker_anchors.iter().filter(|a| !a.is_empty()).count();
    let reference_anchored = anchors.iter().filter(|a| !a.is_empty()).count();

    // Initial plane_from_pixel homography per frame: from its own absolute anchors,
    // else propagated from a neighbour through the pairwise homography.
    let mut init: Vec<Option<Mat3>> = (0..n)
        .map(|i| {
            let mut src: Vec<Vec2> = anchors[i]
                .iter()
                .map(|(p, _)| Vec2::new(p[0], p[1]))
                .collect();
            let mut dst: Vec<Vec2> = anchors[i].iter().map(|(_, x)| *x).collect();
            for (p, x) in &marker_anchors[i] {
                src.push(*p);
                dst.push(*x);
            }
            if src.len() >= 4 {
                Homography::from_correspondences(&src, &dst)
                    .ok()
                    .map(|h| h.0)
            } else {
                None
            }
        })
        .collect();
    let mut pair_h: HashMap<(usize, usize), Mat3> = HashMap::new();
    let mut fine_pairs = 0;
    let mut cross_pairs = 0;
    for (i, j, r) in &fine {
        if let Some((_, _, h)) = r {
            pair_h.insert((*i, *j), *h);
            fine_pairs += 1;
            cross_pairs += usize::from(frames[*i].stream != frames[*j].stream);
        }
    }
    let mut changed = true;
    while changed {
        changed = false;
        for (&(i, j), h) in &pair_h {
            // h maps i px -> j px.
            if init[i].is_none() {
                if let Some(hj) = init[j] {
                    init[i] = Some(hj * h);
                    changed = true;
                }
            }
            if init[j].is_none() {
                if let (Some(hi), Some(inv)) = (init[i], h.try_inverse()) {
                    init[j] = Some(hi * inv);
                    changed = true;
                }
            }
        }
    }
    let registered: Vec<usize> = (0..n).filter(|&i| init[i].is_some()).collect();
    drops.unregistered = (0..n_flash).filter(|&i| init[i].is_none()).count();
    if let Some(d) = &mut second_drops {
        d.unregistered = (n_flash..n).filter(|&i| init[i].is_none()).count();
    }
    if registered.is_empty() {
        let partial = frames.iter().filter(|f| !f.markers.is_empty()).count();
        return Err(AlignError::Connect(format!(
            "no frame could be tied to the plane: of the {n} connected sharp frames sampled (every {}th of {} decoded), {with_markers} showed a whole marker of the reference photo's ({partial} any marker of the dictionary) and {reference_anchored} matched the reference photo well enough ({} verified matches needed); expected at least one of either. Film passing slowly over each marker so that it is fully in view for a moment, or lower frame_step in the camera description to sample more frames",
            cfg.camera.frame_step,
            drops.decoded,
            cfg.fine_min_inliers
        )));
    }

    // Global solve over all sub-frames of registered frames (each stream has its
    // own frame size, so its own sub-frame grid and normalisation).
    let grids: Vec<Grid> = frames
        .iter()
        .map(|f| Grid::new(f.width, f.height, cfg))
        .collect();
    let nrms: Vec<Mat3> = frames
        .iter()
        .map(|f| normaliser(f.width, f.height))
        .collect();
    let mut slot: HashMap<usize, usize> = HashMap::new();
    let mut init_blocks = Vec::new();
    for &i in &registered {
        slot.insert(i, init_blocks.len());
        let h = init[i].unwrap_or_else(Mat3::identity)
            * nrms[i].try_inverse().unwrap_or_else(Mat3::identity);
        // A sub-frame with enough absolute anchors of its own starts from them: lens
        // distortion bends each sub-frame's map away from the frame's single
        // homography by up to tens of pixels, and a close start saves solver iterations.
        let mut own: Vec<(Vec<Vec2>, Vec<Vec2>)> = vec![(Vec::new(), Vec::new()); grids[i].len()];
        let nrm = Homography(nrms[i]);
        let absolute = anchors[i]
            .iter()
            .map(|(p, x)| (Vec2::new(p[0], p[1]), *x))
            .chain(marker_anchors[i].iter().copied());
        for (p, x) in absolute {
            let c = grids[i].cell(p);
            if let Some(q) = nrm.apply(p) {
                own[c].0.push(q);
                own[c].1.push(x);
            }
        }
        for (src, dst) in &own {
            let local = (src.len() >= 12)
                .then(|| Homography::from_correspondences(src, dst).ok())
                .flatten()
                .map(|g| g.0)
                .filter(|g| g.iter().all(|v| v.is_finite()));
            init_blocks.push(local.unwrap_or(h));
        }
    }
    let sub = |frame: usize, p: Vec2| slot[&frame] + grids[frame].cell(p);
    let norm = |frame: usize, p: Vec2| Homography(nrms[frame]).apply(p).unwrap_or(p);
    let mut cons = Vec::new();
    for (i, j, r) in &fine {
        let (Some((a, b, _)), true, true) = (r, slot.contains_key(i), slot.contains_key(j)) else {
            continue;
        };
        for (p, q) in a.iter().zip(b) {
            let (p, q) = (Vec2::new(p[0], p[1]), Vec2::new(q[0], q[1]));
            cons.push(Constraint::Pair {
                a: sub(*i, p),
                p: norm(*i, p),
                b: sub(*j, q),
                q: norm(*j, q),
                w: 1.0,
            });
        }
    }
    for &i in &registered {
        for (p, x) in &anchors[i] {
            let p = Vec2::new(p[0], p[1]);
            cons.push(Constraint::Anchor {
                a: sub(i, p),
                p: norm(i, p),
                x: *x,
                w: cfg.reference_weight,
            });
        }
        for (p, x) in &marker_anchors[i] {
            cons.push(Constraint::Anchor {
                a: sub(i, *p),
                p: norm(i, *p),
                x: *x,
                w: 4.0,
            });
        }
        for (a, b, p) in grids[i].seams() {
            let base = slot[&i];
            cons.push(Constraint::Pair {
                a: base + a,
                p: norm(i, p),
                b: base + b,
                q: norm(i, p),
                w: cfg.overlap_weight,
            });
        }
    }
    // Residual scale: about two frame pixels on the plane.
    let huber = 2.0 * cm_per_px;
    progress.stage("global solve", 1);
    let (solved, report) = solve(&init_blocks, &cons, huber, cfg.iterations)?;
    progress.finish();
    lap("global solve");

    // Back to pixel coordinates, poses from the centre sub-frame, region check.
    let region = rf.marker_region().expanded(cfg.camera.marker_size_cm);
    // Registered frames with a plausible pose: (frame, sub-frame maps, pose).
    let mut posed = Vec::new();
    for &i in &registered {
        let (grid, second) = (&grids[i], frames[i].stream != 0);
        let (width, height) = (frames[i].width, frames[i].height);
        let intrinsics = match (second, intrinsics2) {
            (true, Some(k)) => k,
            _ => intrinsics,
        };
        let centre_cell = grid.cell(Vec2::new(
            0.5 * (f64::from(width) - 1.0),
            0.5 * (f64::from(height) - 1.0),
        ));
        let blocks: Vec<([f64; 4], Mat3)> = (0..grid.len())
            .map(|c| {
                let h = solved[slot[&i] + c] * nrms[i];
                (grid.rect(c), h / h[(2, 2)])
            })
            .collect();
        // Paper: decompose the centre sub-frame's homography. A single sub-frame spans
        // a small patch, which makes rotation and translation hard to tell apart; we
        // fit one homography to the piecewise map over the central 60% of the frame
        // (where lens distortion is mild) and decompose that.
        let mut img_pts = Vec::new();
        let mut plane_pts = Vec::new();
        for gy in 0..9 {
            for gx in 0..9 {
                let p = Vec2::new(
                    (0.2 + 0.6 * f64::from(gx) / 8.0) * f64::from(width) - 0.5,
                    (0.2 + 0.6 * f64::from(gy) / 8.0) * f64::from(height) - 0.5,
                );
                if let Some(q) = Homography(blocks[grid.cell(p)].1).apply(p) {
                    img_pts.push(p);
                    plane_pts.push(q);
                }
            }
        }
        let centre_fit = Homography::from_correspondences(&plane_pts, &img_pts).ok();
        let Some(pose) = centre_fit
            .and_then(|h| pose_from_homography(&intrinsics, &h.0))
            .or_else(|| {
                blocks[centre_cell]
                    .1
                    .try_inverse()
                    .and_then(|inv| pose_from_homography(&intrinsics, &inv))
            })
        else {
            match (second, &mut second_drops) {
                (true, Some(d)) => d.unregistered += 1,
                _ => drops.unregistered += 1,
            }
            continue;
        };
        // The paper's check applies to the hand-held flash camera; the second camera
        // stands beside the material by design and only has to be above it.
        let plausible = if second {
            pose.centre.z > 0.0
        } else {
            region.contains(Vec2::new(pose.centre.x, pose.centre.y))
        };
        if !plausible || !blocks.iter().all(|b| b.1.iter().all(|v| v.is_finite())) {
            match (second, &mut second_drops) {
                (true, Some(d)) => d.outside += 1,
                _ => drops.outside += 1,
            }
            continue;
        }
        posed.push((i, blocks, pose));
    }
    // Light positions: the flash camera's own, and for the second stream the flash
    // camera's at the synchronised time, interpolated between the nearest kept flash
    // frames (frames outside their time span are dropped, not extrapolated).
    let offset = Vec3::from(cfg.camera.flash_offset_cm);
    let mut flash_track: Vec<(f64, Vec3)> = posed
        .iter()
        .filter(|(i, _, _)| frames[*i].stream == 0)
        .map(|(i, _, p)| (frames[*i].time_s, p.camera_to_world(offset)))
        .collect();
    flash_track.sort_by(|a, b| a.0.total_cmp(&b.0));
    let (mut out_frames, mut mappings, mut poses, mut lights) =
        (Vec::new(), Vec::new(), Vec::new(), Vec::new());
    for (i, blocks, pose) in posed {
        let light = if frames[i].stream == 0 {
            Some(pose.camera_to_world(offset))
        } else {
            interpolate_track(&flash_track, frames[i].time_s)
        };
        let Some(light) = light else {
            if let Some(d) = &mut second_drops {
                d.outside += 1;
            }
            continue;
        };
        out_frames.push(frames[i].clone());
        mappings.push(blocks);
        poses.push(pose);
        lights.push(light);
    }
    drops.kept = out_frames.iter().filter(|f| f.stream == 0).count();
    if let Some(d) = &mut second_drops {
        d.kept = out_frames.len() - drops.kept;
    }
    if drops.kept == 0 {
        return Err(AlignError::Connect(
            "every frame's camera pose fell outside the marker boundary".into(),
        ));
    }
    Ok(Registration {
        frames: out_frames,
        mappings,
        poses,
        lights,
        intrinsics,
        drops,
        second_drops,
        cross_pairs,
        connectivity,
        verified_pairs,
        coarse_tested,
        fine_pairs,
        reference_anchored,
        with_markers,
        solve: report,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

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
