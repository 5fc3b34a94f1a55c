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
use crate::pose::pose_from_homography;
use crate::reference::ReferenceFrame;
use crate::solve::{solve, Constraint, SolveReport};
use crate::subframes::*;
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

/// Coarse to fine registration of the decoded frames.
pub fn register(
    streams: Streams,
    rf: &ReferenceFrame,
    ref_features: Option<&ReferenceFeatures>,
    cfg: &AlignConfig,
    progress: &dyn Progress,
    lap: &mut dyn FnMut(&str),
    trace: &mut AlignTrace,
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
    let ranges: Vec<std::ops::Range<usize>> = registered
        .iter()
        .map(|&i| slot[&i]..slot[&i] + grids[i].len())
        .collect();
    let owner: Vec<usize> = registered
        .iter()
        .flat_map(|&i| std::iter::repeat_n(i, grids[i].len()))
        .collect();
    let gains = crate::support::noise_gains(&solved, &cons, &ranges, |b| {
        let i = owner[b];
        let [x0, y0, x1, y1] = grids[i].rect(b - slot[&i]);
        [(x0, y0), (x1, y0), (x0, y1), (x1, y1)]
            .into_iter()
            .map(|(x, y)| norm(i, Vec2::new(x, y)))
            .collect()
    });
    progress.finish();
    lap("global solve");

    // Back to pixel coordinates, poses from the centre sub-frame, region check.
    let mut support = crate::support::SupportSummary {
        max_noise_gain: cfg.max_noise_gain,
        ..Default::default()
    };
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
        // Sub-frames whose maps no correspondence of their own fixes are left out;
        // a frame left with too few is dropped (see `support`).
        let supported: Vec<bool> = (0..grid.len())
            .map(|c| gains[slot[&i] + c] <= cfg.max_noise_gain)
            .collect();
        let kept_cells = supported.iter().filter(|s| **s).count();
        support.subframes += grid.len();
        if (kept_cells as f64) < crate::support::MIN_SUPPORTED_SHARE * grid.len() as f64 {
            support.removed += grid.len();
            support.frames_dropped.push(frames[i].index);
            trace.set_fate(&frames[i], Fate::Unsupported);
            match (second, &mut second_drops) {
                (true, Some(d)) => d.unsupported += 1,
                _ => drops.unsupported += 1,
            }
            continue;
        }
        if kept_cells < grid.len() {
            support.removed += grid.len() - kept_cells;
            support
                .partial_frames
                .push((frames[i].index, kept_cells, grid.len()));
        }
        // Paper: decompose the centre sub-frame's homography. A single sub-frame spans
        // a small patch, which makes rotation and translation hard to tell apart; we
        // fit one homography to the piecewise map over the central 60% of the frame
        // (where lens distortion is mild) and decompose that, from the supported
        // sub-frames only (over the whole frame where the centre has too few).
        let mut img_pts = Vec::new();
        let mut plane_pts = Vec::new();
        for (lo, span) in [(0.2, 0.6), (0.05, 0.9)] {
            img_pts.clear();
            plane_pts.clear();
            for gy in 0..9 {
                for gx in 0..9 {
                    let p = Vec2::new(
                        (lo + span * f64::from(gx) / 8.0) * f64::from(width) - 0.5,
                        (lo + span * f64::from(gy) / 8.0) * f64::from(height) - 0.5,
                    );
                    let c = grid.cell(p);
                    if !supported[c] {
                        continue;
                    }
                    if let Some(q) = Homography(blocks[c].1).apply(p) {
                        img_pts.push(p);
                        plane_pts.push(q);
                    }
                }
            }
            if img_pts.len() >= 24 {
                break;
            }
        }
        let centre_fit = Homography::from_correspondences(&plane_pts, &img_pts).ok();
        let centre_block = supported[centre_cell].then_some(blocks[centre_cell].1);
        let blocks: Vec<([f64; 4], Mat3)> = blocks
            .into_iter()
            .zip(&supported)
            .filter(|(_, s)| **s)
            .map(|(b, _)| b)
            .collect();
        let Some(pose) = centre_fit
            .and_then(|h| pose_from_homography(&intrinsics, &h.0))
            .or_else(|| {
                centre_block
                    .and_then(|b| b.try_inverse())
                    .and_then(|inv| pose_from_homography(&intrinsics, &inv))
            })
        else {
            match (second, &mut second_drops) {
                (true, Some(d)) => d.unregistered += 1,
                _ => drops.unregistered += 1,
            }
            trace.set_fate(&frames[i], Fate::Unregistered);
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
            trace.set_fate(&frames[i], Fate::Outside);
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
            crate::sync::interpolate_track(&flash_track, frames[i].time_s)
        };
        let Some(light) = light else {
            if let Some(d) = &mut second_drops {
                d.outside += 1;
            }
            trace.set_fate(&frames[i], Fate::Outside);
            continue;
        };
        trace.set_fate(&frames[i], Fate::Kept);
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
        return Err(AlignError::Connect(format!(
            "no frame kept: of {} registered frames, {} were mostly extrapolated (fewer than {:.0}% of their sub-frames fixed by matches of their own) and {} had a camera pose outside the marker boundary; film with more texture or markers in view, or pass a larger --max-noise-gain",
            registered.len(),
            drops.unsupported,
            100.0 * crate::support::MIN_SUPPORTED_SHARE,
            drops.outside
        )));
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
        reference_tied,
        with_markers,
        pieces,
        per_frame_anchors,
        solve: report,
        support,
        marker_hunt: None,
    })
}
