//! The global solve (paper 3.1.4) over every registered frame's sub-frames, from the
//! correspondences [`match_frames`](crate::matching::match_frames) found: sub-frame
//! support, camera poses and light positions.

use std::collections::HashMap;

use svbrdf_core::geometry::{Mat3, Vec2, Vec3};
use svbrdf_core::homography::Homography;

use crate::config::AlignConfig;
use crate::matching::{Matched, PlaneTies, Registration};
use crate::pose::pose_from_homography;
use crate::solve::{solve, Constraint};
use crate::subframes::*;
use crate::trace::{AlignTrace, Fate};
use crate::{AlignError, Progress};

impl Matched {
    /// [`solve`](Self::solve) again (with more anchors or corrected correspondences),
    /// carrying over what the steps after the first solve recorded in `previous`.
    pub(crate) fn solve_again(
        &self,
        ties: &PlaneTies,
        previous: &mut Registration,
        cfg: &AlignConfig,
        progress: &dyn Progress,
        lap: &mut dyn FnMut(&str),
        trace: &mut AlignTrace,
    ) -> Result<Registration, AlignError> {
        let none = std::collections::HashSet::new();
        self.solve_without(&none, ties, previous, cfg, progress, lap, trace)
    }

    /// [`solve_again`](Self::solve_again) without the frames `leave_out` names
    /// (stream, frame number): their correspondences no longer hold the others' maps,
    /// and the others' support is judged without them.
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn solve_without(
        &self,
        leave_out: &std::collections::HashSet<(u32, u64)>,
        ties: &PlaneTies,
        previous: &mut Registration,
        cfg: &AlignConfig,
        progress: &dyn Progress,
        lap: &mut dyn FnMut(&str),
        trace: &mut AlignTrace,
    ) -> Result<Registration, AlignError> {
        let registered: Vec<usize> = self
            .registered
            .iter()
            .copied()
            .filter(|&i| !leave_out.contains(&(self.frames[i].stream, self.frames[i].index)))
            .collect();
        let mut again = self.solve_frames(&registered, ties, cfg, progress, lap, trace)?;
        again.marker_hunt = previous.marker_hunt.take();
        again.marker_corners = previous.marker_corners.take();
        again.relief = previous.relief.take();
        Ok(again)
    }

    /// Solve for every registered frame's sub-frame maps, with `ties` as extra
    /// anchors, and keep the frames whose maps are supported and whose pose is
    /// plausible.
    pub fn solve(
        &self,
        ties: &PlaneTies,
        cfg: &AlignConfig,
        progress: &dyn Progress,
        lap: &mut dyn FnMut(&str),
        trace: &mut AlignTrace,
    ) -> Result<Registration, AlignError> {
        self.solve_frames(&self.registered, ties, cfg, progress, lap, trace)
    }

    /// [`solve`](Self::solve) over the frames `registered` (indices into `frames`).
    fn solve_frames(
        &self,
        registered: &[usize],
        ties: &PlaneTies,
        cfg: &AlignConfig,
        progress: &dyn Progress,
        lap: &mut dyn FnMut(&str),
        trace: &mut AlignTrace,
    ) -> Result<Registration, AlignError> {
        let Matched {
            frames,
            fine,
            anchors,
            marker_anchors,
            init,
            intrinsics,
            intrinsics2,
            cm_per_px,
            pose_region: region,
            ..
        } = self;
        let (intrinsics, intrinsics2, cm_per_px, region) =
            (*intrinsics, *intrinsics2, *cm_per_px, *region);
        let mut drops = self.drops.clone();
        let mut second_drops = self.second_drops.clone();
        let no_ties = Vec::new();
        let ties_of = |i: usize| {
            ties.get(&(frames[i].stream, frames[i].index))
                .unwrap_or(&no_ties)
        };
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
        for &i in registered {
            slot.insert(i, init_blocks.len());
            let h = init[i].unwrap_or_else(Mat3::identity)
                * nrms[i].try_inverse().unwrap_or_else(Mat3::identity);
            // A sub-frame with enough absolute anchors of its own starts from them: lens
            // distortion bends each sub-frame's map away from the frame's single
            // homography by up to tens of pixels, and a close start saves solver iterations.
            let mut own: Vec<(Vec<Vec2>, Vec<Vec2>)> =
                vec![(Vec::new(), Vec::new()); grids[i].len()];
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
        for (i, j, r) in fine {
            let (Some((a, b, _)), true, true) = (r, slot.contains_key(i), slot.contains_key(j))
            else {
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
        for &i in registered {
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
            for (p, x, w) in ties_of(i) {
                cons.push(Constraint::Anchor {
                    a: sub(i, *p),
                    p: norm(i, *p),
                    x: *x,
                    w: *w,
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
        // Noise gains at each sub-frame's `CORNERS` corners (its support), then along the
        // frame's edges it lies on (how far towards them its map is used).
        const CORNERS: usize = 4;
        let probed = crate::support::noise_gains_at(&solved, &cons, &ranges, |b| {
            let i = owner[b];
            let [x0, y0, x1, y1] = grids[i].rect(b - slot[&i]);
            [(x0, y0), (x1, y0), (x0, y1), (x1, y1)]
                .into_iter()
                .map(|(x, y)| Vec2::new(x, y))
                .chain(if cfg.edge_noise_gain > 0.0 {
                    grids[i].edge_probes(b - slot[&i])
                } else {
                    Vec::new()
                })
                .map(|p| norm(i, p))
                .collect()
        });
        let gains: Vec<f64> = probed
            .iter()
            .map(|g| {
                g.as_ref().map_or(f64::INFINITY, |g| {
                    g.iter().take(CORNERS).fold(0.0, |a, b| a.max(*b))
                })
            })
            .collect();
        progress.finish();
        lap("global solve");

        // Back to pixel coordinates, poses from the centre sub-frame, region check.
        let mut support = crate::support::SupportSummary {
            max_noise_gain: cfg.max_noise_gain,
            edge_noise_gain: cfg.edge_noise_gain,
            ..Default::default()
        };
        // Registered frames with a plausible pose: (frame, sub-frame maps, pose).
        let mut posed = Vec::new();
        for &i in registered {
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
            // Where each sub-frame's map is used in the end (`support::apply_edge_cuts`,
            // after the checks, which judge the whole frame).
            let cuts: Vec<[f64; 4]> = (0..grid.len())
                .map(|c| match &probed[slot[&i] + c] {
                    Some(g) if cfg.edge_noise_gain > 0.0 => {
                        grid.cut_rect(c, g.get(CORNERS..).unwrap_or(&[]), cfg.edge_noise_gain)
                    }
                    _ => grid.rect(c),
                })
                .collect();
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
            let cuts: Vec<crate::matching::EdgeCut> = blocks
                .iter()
                .zip(cuts)
                .zip(&supported)
                .filter(|(_, s)| **s)
                .map(|((b, cut), _)| (b.0, cut))
                .filter(|(full, cut)| full != cut)
                .collect();
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
            posed.push((i, blocks, cuts, pose));
        }
        // Light positions: the flash camera's own, and for the second stream the flash
        // camera's at the synchronised time, interpolated between the nearest kept flash
        // frames (frames outside their time span are dropped, not extrapolated).
        let offset = Vec3::from(cfg.camera.flash_offset_cm);
        let mut flash_track: Vec<(f64, Vec3)> = posed
            .iter()
            .filter(|(i, _, _, _)| frames[*i].stream == 0)
            .map(|(i, _, _, p)| (frames[*i].time_s, p.camera_to_world(offset)))
            .collect();
        flash_track.sort_by(|a, b| a.0.total_cmp(&b.0));
        let (mut out_frames, mut mappings, mut poses, mut lights) =
            (Vec::new(), Vec::new(), Vec::new(), Vec::new());
        let mut edge_cuts = HashMap::new();
        for (i, blocks, cuts, pose) in posed {
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
            if !cuts.is_empty() {
                edge_cuts.insert((frames[i].stream, frames[i].index), cuts);
            }
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
            cross_pairs: self.cross_pairs,
            connectivity: self.connectivity.clone(),
            verified_pairs: self.verified_pairs.clone(),
            coarse_tested: self.coarse_tested,
            fine_pairs: self.fine_pairs,
            fine_rechecked: self.fine_rechecked,
            fine_guided: self.fine_guided,
            reference_tied: self.reference_tied.clone(),
            with_markers: self.with_markers,
            pieces: self.pieces,
            per_frame_anchors: self.per_frame_anchors.clone(),
            solve: report,
            support,
            edge_cuts,
            marker_hunt: None,
            densified: None,
            plane_ties: None,
            marker_corners: None,
            relief: None,
            plane_tied: Default::default(),
        })
    }
}
