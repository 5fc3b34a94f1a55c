//! Registration, in the paper's order: blur selection (eq. 1), coarse alignment and the
//! connectivity map (`coarse.rs`), fine correspondences between frames and with the
//! reference photo (`fine.rs`), marker and reference anchors, initial homographies,
//! and the global solve over every frame's sub-frames (`subframes.rs`, `solve.rs`).

use std::collections::{BTreeMap, BTreeSet, HashMap};

use rayon::prelude::*;
use svbrdf_core::geometry::{Intrinsics, Mat3, Pose, Vec2, Vec3};
use svbrdf_core::homography::Homography;
use svbrdf_cv::features::{estimate_homography, match_one_to_one, Robust};

use crate::blur::blurry_frames;
use crate::coarse::*;
use crate::config::{AlignConfig, FineMethod};
use crate::fine::*;
use crate::frames::FrameData;
use crate::partial::{marker_crops, MarkerCrop};
use crate::reference::ReferenceFrame;
use crate::solve::SolveReport;
use crate::trace::{AlignTrace, Fate};
use crate::{AlignError, DropCounts, Progress};

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

/// A sub-frame's full rectangle and the one where its map is used in the end (frame
/// pixels, `[x0, y0, x1, y1]`).
pub type EdgeCut = ([f64; 4], [f64; 4]);

/// Result of registration, ready to be written.
pub struct Registration {
    /// Frames kept, with their data: the flash stream's, then the second stream's.
    pub frames: Vec<FrameData>,
    /// Per kept frame: sub-frame rectangles and plane_from_pixel homographies.
    pub mappings: Vec<Vec<([f64; 4], Mat3)>>,
    /// Per kept frame (stream, video frame or photo number): the sub-frames along its
    /// edges whose maps are to be used short of that edge (full rectangle, cut one),
    /// applied by [`support::apply_edge_cuts`](crate::support::apply_edge_cuts) once
    /// the checks have judged the frames whole.
    pub edge_cuts: HashMap<(u32, u64), Vec<EdgeCut>>,
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
    /// Refined matches dropped as off their pair's homography (`fine::recheck`).
    pub fine_rechecked: usize,
    /// Matches the guided fill added (`fine::guided_fill`), after the recheck.
    pub fine_guided: usize,
    /// Frames anchored by reference matches, as (stream, frame number).
    pub reference_tied: BTreeSet<(u32, u64)>,
    /// Frames with markers.
    pub with_markers: usize,
    /// Pieces of the connectivity map tied to the plane separately (1: one chain).
    pub pieces: usize,
    /// Per sampled sharp frame (video frame number): matches with the reference photo
    /// that its verification kept, and whole markers seen.
    pub per_frame_anchors: Vec<(u64, usize, usize)>,
    /// Solve statistics.
    pub solve: SolveReport,
    /// Sub-frames left out as extrapolated, frames dropped for it.
    pub support: crate::support::SupportSummary,
    /// The marker hunt, where it ran (set by the caller).
    pub marker_hunt: Option<crate::hunt::MarkerHunt>,
    /// The first pass and a second from more frames, where both ran (set by the
    /// caller).
    pub densified: Option<crate::densify::Densified>,
    /// Frames confirmed by plane ties (full-resolution matches with the reference
    /// photo after a first solve), as (stream, frame number); set by the caller.
    pub plane_tied: BTreeSet<(u32, u64)>,
    /// What the plane ties did, where they ran (set by the caller).
    pub plane_ties: Option<crate::ties::PlaneTieSummary>,
    /// What the marker corners did, where they ran (set by the caller).
    pub marker_corners: Option<crate::partial::MarkerCornerSummary>,
    /// What the relief step found, where it ran (set by the caller).
    pub relief: Option<crate::relief::ReliefSummary>,
}

/// Frames matched and anchored, ready for the global solve: what
/// [`match_frames`] found, held so that the solve can run again.
pub struct Matched {
    /// Frames kept by the connectivity map (flash stream first); only those without
    /// reference-photo feature matches keep their patch images (for plane ties).
    pub(crate) frames: Vec<FrameData>,
    /// Fine correspondences per frame pair (indices into `frames`).
    pub(crate) fine: Vec<(usize, usize, Option<FineMatch>)>,
    /// Per frame: matches with the reference photo, (frame px, plane cm).
    pub(crate) anchors: Vec<Vec<([f64; 2], Vec2)>>,
    /// Per frame: marker corners, (frame px, plane cm).
    pub(crate) marker_anchors: Vec<Vec<(Vec2, Vec2)>>,
    /// Per frame: its patch image around the markers its first map puts in view but
    /// detection missed (`partial`; emptied once their corners are found).
    pub(crate) marker_crops: Vec<Vec<MarkerCrop>>,
    /// Frames with a first map.
    pub(crate) registered: Vec<usize>,
    /// First plane_from_pixel map per frame.
    pub(crate) init: Vec<Option<Mat3>>,
    pub(crate) intrinsics: Intrinsics,
    pub(crate) intrinsics2: Option<Intrinsics>,
    /// Plane cm per frame pixel at a typical capture height.
    pub(crate) cm_per_px: f64,
    /// Where a flash camera's pose must lie.
    pub(crate) pose_region: svbrdf_core::plane::Region,
    pub(crate) drops: DropCounts,
    pub(crate) second_drops: Option<DropCounts>,
    pub(crate) cross_pairs: usize,
    pub(crate) connectivity: Connectivity,
    pub(crate) verified_pairs: Vec<(u64, u64, usize)>,
    pub(crate) coarse_tested: usize,
    pub(crate) fine_pairs: usize,
    pub(crate) fine_rechecked: usize,
    pub(crate) fine_guided: usize,
    pub(crate) reference_tied: BTreeSet<(u32, u64)>,
    pub(crate) with_markers: usize,
    pub(crate) pieces: usize,
    pub(crate) per_frame_anchors: Vec<(u64, usize, usize)>,
}

/// Anchors found on the plane after a first solve, per frame (stream, frame number):
/// (frame px, plane cm, weight); see `crate::ties`.
pub type PlaneTies = BTreeMap<(u32, u64), Vec<(Vec2, Vec2, f64)>>;

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

/// Coarse to fine registration of the decoded frames: [`match_frames`], then the
/// global solve ([`Matched::solve`]); the matched frames are returned too, so that the
/// solve can run again with more anchors (plane ties from the self-check).
pub fn register(
    streams: Streams,
    rf: &ReferenceFrame,
    ref_features: Option<&ReferenceFeatures>,
    cfg: &AlignConfig,
    progress: &dyn Progress,
    lap: &mut dyn FnMut(&str),
    trace: &mut AlignTrace,
) -> Result<(Registration, Matched), AlignError> {
    let matched = match_frames(streams, rf, ref_features, cfg, progress, lap, trace)?;
    let reg = matched.solve(&PlaneTies::new(), cfg, progress, lap, trace)?;
    Ok((reg, matched))
}

/// Everything before the global solve: frames kept, their correspondences, anchors and
/// first maps (see [`Matched`]).
pub fn match_frames(
    streams: Streams,
    rf: &ReferenceFrame,
    ref_features: Option<&ReferenceFeatures>,
    cfg: &AlignConfig,
    progress: &dyn Progress,
    lap: &mut dyn FnMut(&str),
    trace: &mut AlignTrace,
) -> Result<Matched, AlignError> {
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
        for &b in &blurry {
            if let Some(t) = trace.frame_mut(0, b) {
                t.fate = Fate::Blurry;
            }
        }
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
    // The paper keeps the connectivity map's largest component. Every component joins
    // here: the others are kept where the reference photo or a marker ties one of
    // their frames to the plane (decided after fine matching), so a break in the
    // chain of frames (a fast jerk over a repetitive texture) does not drop the
    // stretch after it; the self-check then verifies each frame against the reference.
    let parts = components(frames.len(), &connectivity.kept);
    let largest = parts.first().map_or(0, Vec::len);
    trace.coarse_pairs_tested = coarse_tested;
    trace.coarse_pairs_verified = verified_pairs.len();
    trace.pieces = parts
        .iter()
        .map(|c| c.iter().map(|&i| frames[i].index).collect())
        .collect();
    for (k, c) in parts.iter().enumerate() {
        for &i in c {
            if let Some(t) = trace.frame_mut(frames[i].stream, frames[i].index) {
                t.piece = Some(k);
            }
        }
    }
    lap("coarse alignment");
    if largest < 2 {
        return Err(AlignError::Connect(format!(
            "frames do not connect: {} of {} sharp frames matched none of the others (repetitive or featureless texture?)",
            frames.len() - largest,
            frames.len()
        )));
    }
    let mut part_of = vec![0usize; frames.len()];
    for (k, c) in parts.iter().enumerate() {
        for &i in c {
            part_of[i] = k;
        }
    }
    let mut comp: Vec<usize> = parts.iter().flatten().copied().collect();
    comp.sort_unstable();
    // Component of each kept frame (flash frames first, as `frames` below).
    let part: Vec<usize> = comp.iter().map(|&i| part_of[i]).collect();
    let in_comp: HashMap<usize, usize> = comp.iter().enumerate().map(|(k, &i)| (i, k)).collect();
    // The thresholded, filtered map decides which frames are kept (its components,
    // above); fine matching then uses every pair that coarse
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
        for &b in &blurry2 {
            if let Some(t) = trace.frame_mut(1, b) {
                t.fate = Fate::Blurry;
            }
        }
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
    let counts = FineCounts::default();
    // No guided matches with a second (no-flash) stream: on the two-camera preset they
    // left the flash video's alignment as it was but moved the fit's diffuse RMSE from
    // 0.021 to 0.051, also when kept off the pairs with the second stream
    // (docs/BENCHMARKS.md, session 38).
    // Nor on video over FILL_MAX_LONG_SIDE: measured helpful at 960 px (Mitsuba tiles)
    // and harmful at 3840 px (the `paper` preset: p95 0.425 -> 0.476 px, worst frame
    // 0.713 -> 0.948 px, also at `fine_fill` 4; session 39).
    let long_side = frames
        .iter()
        .take(n_flash)
        .map(|f| f.width.max(f.height))
        .max()
        .unwrap_or(0);
    let without_fill = AlignConfig {
        fine_fill: 0,
        ..cfg.clone()
    };
    let pair_cfg = if frames.len() > n_flash || long_side > crate::fine::FILL_MAX_LONG_SIDE {
        &without_fill
    } else {
        cfg
    };
    let fine: Vec<_> = pairs
        .par_iter()
        .map(|&(i, j)| {
            // Flash-stream pairs reuse their coarse inlier matches.
            let known = (j < n_flash)
                .then(|| connectivity.matches.get(&(comp[i], comp[j])))
                .flatten();
            let r = fine_pair(
                &frames[i],
                &frames[j],
                known.map(Vec::as_slice),
                pair_cfg,
                &counts,
            );
            progress.advance(1);
            r.map(|r| (i, j, r))
        })
        .collect::<Result<_, _>>()?;
    // Plane cm per frame pixel at a typical capture height (60% of the reference's).
    let cm_per_px = rf.height.clamp(5.0, 50.0) * 0.6 / intrinsics.fx;
    // Fine matches with the reference photo: absolute anchors (beyond the paper).
    // Each frame's anchors and how many matches with the reference photo it verified
    // (also where that was too few: failures say how close the frames came).
    let anchored: Vec<ReferenceAnchors> = frames
        .par_iter()
        .map(|f| {
            let out = match ref_features {
                None => Ok((Vec::new(), 0)),
                Some(rfe) if cfg.fine_method == FineMethod::Patch => {
                    let thr_px = cfg.fine_inlier_px * f64::from(f.width.max(f.height)) / 3840.0;
                    reference_anchors_patch(f, rfe, cfg, thr_px * cm_per_px)
                }
                Some(rfe) => match_one_to_one(&f.fine, &rfe.features, 0.8)
                    .and_then(|m| {
                        let min = fine_min(f, cfg);
                        if m.len() < 8 {
                            return Ok((Vec::new(), 0));
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
                            Some(Robust { inliers: inl, .. }) => {
                                let kept: Vec<([f64; 2], Vec2)> = (0..src.len())
                                    .filter(|&k| inl[k])
                                    .map(|k| (src[k], Vec2::new(dst[k][0], dst[k][1])))
                                    .collect();
                                let verified = kept.len();
                                (if verified >= min { kept } else { Vec::new() }, verified)
                            }
                            None => (Vec::new(), 0),
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
    let reference_matches: Vec<usize> = anchored.iter().map(|a| a.1).collect();
    trace.reference_matches_needed = frames.first().map(|f| fine_min(f, cfg));
    for (f, &m) in frames.iter().zip(&reference_matches) {
        if let Some(t) = trace.frame_mut(f.stream, f.index) {
            t.reference_matches = Some(m);
        }
    }
    let per_frame_anchors: Vec<(u64, usize, usize)> = frames
        .iter()
        .zip(&reference_matches)
        .map(|(f, &m)| (f.index, m, f.markers.len()))
        .collect();
    let anchors: Vec<Vec<([f64; 2], Vec2)>> = anchored.into_iter().map(|a| a.0).collect();

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
    let reference_tied: BTreeSet<(u32, u64)> = frames
        .iter()
        .zip(&anchors)
        .filter(|(_, a)| !a.is_empty())
        .map(|(f, _)| (f.stream, f.index))
        .collect();
    let reference_anchored = reference_tied.len();

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
    // Ordered: frames without anchors of their own get their first map through the
    // pairs in this order, and a hash map's order differs per process (two runs of the
    // same capture differed in the ninth digit of every pose).
    let mut pair_h: BTreeMap<(usize, usize), Mat3> = BTreeMap::new();
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
    // Around the markers a frame's first map puts in view but detection missed, the
    // patch image is kept for the marker corners (`partial`).
    let marker_crops: Vec<Vec<MarkerCrop>> = frames
        .par_iter()
        .zip(&init)
        .map(|(f, h)| match h {
            Some(h) if cfg.marker_corners => marker_crops(f, h, &rf.markers),
            _ => Vec::new(),
        })
        .collect();
    // The patch images (1 GB for 120 4K frames) are not needed any more, except by
    // frames that the reference photo's matches did not anchor: plane ties match
    // them with the reference photo again once the solve has placed them (`ties`).
    let keep_grey = cfg.plane_ties && cfg.self_check.enabled;
    for (f, a) in frames.iter_mut().zip(&anchors) {
        if !(keep_grey && a.is_empty()) {
            f.grey = None;
        }
    }
    // A flash frame left without a map is disconnected where no frame of its
    // component was tied to the plane, else unregistered.
    let tied: BTreeSet<usize> = (0..n_flash)
        .filter(|&i| init[i].is_some())
        .map(|i| part[i])
        .collect();
    drops.disconnected = (0..n_flash)
        .filter(|&i| init[i].is_none() && !tied.contains(&part[i]))
        .count();
    drops.unregistered = (0..n_flash)
        .filter(|&i| init[i].is_none() && tied.contains(&part[i]))
        .count();
    let pieces = tied.len();
    for i in (0..n).filter(|&i| init[i].is_none()) {
        let fate = if i < n_flash && !tied.contains(&part[i]) {
            Fate::Disconnected
        } else {
            Fate::Unregistered
        };
        trace.set_fate(&frames[i], fate);
    }
    if let Some(d) = &mut second_drops {
        d.unregistered = (n_flash..n).filter(|&i| init[i].is_none()).count();
    }
    if registered.is_empty() {
        let partial = frames.iter().filter(|f| !f.markers.is_empty()).count();
        let closest = match (0..n).max_by_key(|&i| (reference_matches[i], std::cmp::Reverse(i))) {
            Some(i) if reference_matches[i] > 0 => format!(
                " (closest: frame {} with {} verified matches of the {} needed)",
                frames[i].index,
                reference_matches[i],
                fine_min(&frames[i], cfg)
            ),
            _ => " (none verified a single match with it: is it a photo of this surface?)".into(),
        };
        return Err(AlignError::Connect(format!(
            "no frame could be tied to the plane: of the {n} sharp frames sampled (every {}th of {} decoded; the connectivity map had {} pieces), {with_markers} showed a whole marker of the reference photo's ({partial} any marker of the dictionary) and {reference_anchored} matched the reference photo well enough{closest}; expected at least one of either. Film passing slowly over each marker so that it is fully in view for a moment, or lower frame_step in the camera description to sample more frames",
            cfg.camera.frame_step,
            drops.decoded,
            parts.len()
        )));
    }

    Ok(Matched {
        frames,
        fine,
        anchors,
        marker_anchors,
        marker_crops,
        registered,
        init,
        intrinsics,
        intrinsics2,
        cm_per_px,
        pose_region: rf.marker_region().expanded(cfg.camera.marker_size_cm),
        drops,
        second_drops,
        cross_pairs,
        connectivity,
        verified_pairs,
        coarse_tested,
        fine_pairs,
        fine_rechecked: counts.rechecked.into_inner(),
        fine_guided: counts.guided.into_inner(),
        reference_tied,
        with_markers,
        pieces,
        per_frame_anchors,
    })
}
