//! Plane ties (issue 18, item 2): frames tied to the reference photo across the
//! change of light by what the self-check and the patch matcher find, not by features.
//!
//! Features of a flash frame and of the no-flash reference photo match poorly where the
//! light changes the texture's look, or at the 2-3x scale between them; then only the
//! markers, at the region's edge, tie frames to the plane, and stretches between
//! them bend unseen by the solve. The self-check compares every registered frame
//! with the reference photo on the plane, at the same scale, block by block (4 cm,
//! colour correlation robust to the change of light), and finds where the reference
//! photo shows each block's texture. Where a frame without feature matches of its
//! own has blocks that agree on one displacement (a shift, or an affine field where
//! the frame is bent), each such block becomes an anchor and the solve runs again.
//! Then every such frame the self-check placed is matched with the reference photo at
//! full resolution from where it lies ([`guided_matches`]), solved again with those
//! matches, and the frames they do not confirm are left out ([`tie_to_plane`]).

use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use svbrdf_core::geometry::{Mat3, Vec2};
use svbrdf_core::homography::Homography;
use svbrdf_cv::features::{estimate_homography, Robust};

use crate::checks::self_check;
use crate::coarse::pts;
use crate::config::AlignConfig;
use crate::fine::{fine_min, patch_settings, refine_matches, to_grey};
use crate::frames::FrameData;
use crate::matching::{Matched, PlaneTies, Registration};
use crate::patch::Grey;
use crate::selfcheck::{agreeing_blocks, FrameCheck};
use crate::{AlignError, Progress};

/// A frame needs this many agreeing blocks to be tied.
pub const MIN_TIE_BLOCKS: usize = 4;
/// Block ties are used only where a frame to be tied lies at least this far from the
/// reference photo, mm: closer, the full-resolution matcher finds the texture from
/// where the frame lies. Session 21 had 0.25 mm; with the marker corners, 4K patchwork
/// seed 2 (markers only) came in at 0.22 mm, skipped the block ties, and the
/// full-resolution matches then confirmed 41 of 61 frames, the worst kept one 1.38 px
/// off (0.963 px, 54 frames, at 0.1 mm).
pub const TIE_TRIGGER_MM: f64 = 0.1;
/// A frame placed by plane ties is confirmed where the patch matcher finds the
/// reference photo's texture at this share of its features at least.
pub const GUIDED_MIN_SHARE: f64 = 0.5;
/// A sub-frame of a frame the full-resolution matches confirm is left out where at
/// least this many of its features were tried ...
pub const GUIDED_SUB_MIN_TRIED: usize = 20;
/// ... and under this share of them matched: the frame is right where it matched and
/// bent there (hard-small patchwork seed 2, markers alone: the top sub-frames of frames
/// 2-12, 0-4 of 120-170 features matched each, lay 1.4-5 px off; the matched ones
/// 0.1-0.9 px).
pub const GUIDED_SUB_MIN_SHARE: f64 = 0.25;
/// Full-resolution matches kept per frame at most.
pub const MAX_GUIDED: usize = 300;
/// Weight of one block tie (a 4 cm block matched with the reference photo) against
/// one correspondence between frames (1) or one marker corner (4).
pub const BLOCK_TIE_WEIGHT: f64 = 16.0;

/// What the plane ties did, as `align.json` records it.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct PlaneTieSummary {
    /// Solves run again with plane ties.
    pub rounds: usize,
    /// Kept frames without reference-photo feature matches of their own.
    #[serde(default)]
    pub untied: usize,
    /// Frames tied (video frame numbers of the flash stream; second-stream frames are
    /// counted in `ties` only).
    pub frames: Vec<u64>,
    /// Frames that got block ties first (lying over [`TIE_TRIGGER_MM`] off).
    #[serde(default)]
    pub block_frames: usize,
    /// Block anchors.
    pub ties: usize,
    /// Frames matched with the reference photo at full resolution from where the
    /// block ties placed them (their block anchors then give way to these matches).
    #[serde(default)]
    pub guided_frames: usize,
    /// Those matches.
    #[serde(default)]
    pub guided_matches: usize,
    /// Frames left out: placed by plane ties but not confirmed by the reference photo
    /// (video frame numbers).
    #[serde(default)]
    pub unconfirmed: Vec<u64>,
    /// Confirmed frames that lost sub-frames the full-resolution matches did not
    /// confirm ([`GUIDED_SUB_MIN_SHARE`]): (video frame, sub-frames left out, sub-frames
    /// it had).
    #[serde(default)]
    pub unmatched_subframes: Vec<(u64, usize, usize)>,
    /// Largest offset from the reference photo among the frames to tie, before the
    /// first round, mm.
    pub offset_before_mm: f64,
    /// The same after the last round (the frames' new self-check), mm.
    pub offset_after_mm: f64,
}

impl PlaneTieSummary {
    /// One line for the summary.
    pub fn describe(&self) -> String {
        format!(
            "plane ties: {} frames without reference-photo feature matches of their own; {} of them first tied by {} blocks matched with the reference photo on the plane; {} confirmed by {} full-resolution matches with it, {} left out unconfirmed; {}solved again {} time(s); largest self-check offset of the tied frames {:.2} -> {:.2} mm",
            self.untied,
            self.block_frames,
            self.ties,
            self.guided_frames,
            self.guided_matches,
            self.unconfirmed.len(),
            if self.unmatched_subframes.is_empty() {
                String::new()
            } else {
                format!(
                    "{} sub-frames of {} confirmed frames left out where under a quarter of their features matched; ",
                    self.unmatched_subframes.iter().map(|u| u.1).sum::<usize>(),
                    self.unmatched_subframes.len()
                )
            },
            self.rounds,
            self.offset_before_mm,
            self.offset_after_mm
        )
    }
}

/// Plane ties for the frames of `reg` that have no reference-photo matches of their
/// own, from their self-check `checks` (one per kept frame, in kept order), and the
/// largest offset among the frames tied, mm. A frame pixel is found from the block's
/// centre through the frame's current map (`plane_to_pixel`).
pub(crate) fn ties_from_checks(
    reg: &Registration,
    checks: &[FrameCheck],
    plane_to_pixel: &dyn Fn(usize, Vec2) -> Option<Vec2>,
) -> (PlaneTies, f64) {
    let mut ties = PlaneTies::new();
    let mut largest = 0.0f64;
    for c in checks {
        let Some(f) = reg.frames.get(c.kept_index) else {
            continue;
        };
        if reg.reference_tied.contains(&(f.stream, f.index)) {
            continue;
        }
        let blocks = agreeing_blocks(c);
        if blocks.len() < MIN_TIE_BLOCKS {
            continue;
        }
        let anchors: Vec<(Vec2, Vec2, f64)> = blocks
            .iter()
            .filter_map(|b| {
                let at = Vec2::new(b[0], b[1]);
                let p = plane_to_pixel(c.kept_index, at)?;
                // The reference photo shows this texture `d` mm away.
                Some((p, at + Vec2::new(b[2], b[3]) / 10.0, BLOCK_TIE_WEIGHT))
            })
            .filter(|(p, x, _)| p.iter().chain(x.iter()).all(|v| v.is_finite()))
            .collect();
        if anchors.len() >= MIN_TIE_BLOCKS {
            largest = largest.max(c.offset_mm().unwrap_or(0.0));
            ties.insert((f.stream, f.index), anchors);
        }
    }
    (ties, largest)
}

/// Smallest ratio of the structure tensor's eigenvalues (weaker over stronger
/// gradient direction) over a patch for the full-resolution matcher to use it.
pub const MIN_TWO_DIMENSIONALITY: f64 = 0.2;

/// Whether the patch of radius `r` around `c` (patch-image pixels) has gradients in
/// two directions: the smaller eigenvalue of its structure tensor at least
/// [`MIN_TWO_DIMENSIONALITY`] of the larger one (and some gradient at all).
pub(crate) fn two_dimensional(g: &Grey, c: Vec2, r: usize) -> bool {
    let (cx, cy) = (c.x.round() as i64, c.y.round() as i64);
    let r = r as i64;
    if cx - r - 1 < 0
        || cy - r - 1 < 0
        || cx + r + 1 >= g.width as i64
        || cy + r + 1 >= g.height as i64
    {
        return false;
    }
    let at = |x: i64, y: i64| f64::from(g.data[y as usize * g.width + x as usize]);
    let (mut xx, mut xy, mut yy) = (0.0, 0.0, 0.0);
    for y in cy - r..=cy + r {
        for x in cx - r..=cx + r {
            let gx = at(x + 1, y) - at(x - 1, y);
            let gy = at(x, y + 1) - at(x, y - 1);
            xx += gx * gx;
            xy += gx * gy;
            yy += gy * gy;
        }
    }
    let half_trace = 0.5 * (xx + yy);
    let root = (0.25 * (xx - yy).powi(2) + xy * xy).sqrt();
    let (lo, hi) = (half_trace - root, half_trace + root);
    hi > 1e-9 && lo >= MIN_TWO_DIMENSIONALITY * hi
}

/// What [`guided_matches`] found for one frame.
#[derive(Debug, Clone, Default, PartialEq)]
pub(crate) struct Guided {
    /// Verified matches, (frame px, plane cm), at most [`MAX_GUIDED`] spread over
    /// those found.
    pub matches: Vec<(Vec2, Vec2)>,
    /// Matches verified (before thinning to [`MAX_GUIDED`]).
    pub verified: usize,
    /// Features tried (predicted inside the reference photo).
    pub tried: usize,
    /// Fewest matches that anchor a frame ([`fine_min`]).
    pub min: usize,
    /// Sub-frames (rectangles) where at least [`GUIDED_SUB_MIN_TRIED`] features were
    /// tried and under [`GUIDED_SUB_MIN_SHARE`] of them matched.
    pub unmatched: Vec<[f64; 4]>,
}

impl Guided {
    /// Whether these matches confirm the frame: enough of them, and over at least
    /// [`GUIDED_MIN_SHARE`] of the features tried (a frame partly bent matches only
    /// where it lies right).
    pub fn confirms(&self) -> bool {
        self.verified >= self.min.max(1)
            && self.verified as f64 >= GUIDED_MIN_SHARE * self.tried as f64
    }
}

/// Matches of frame `f` with the reference photo at full resolution, guided by the
/// frame's current map (`blocks`: sub-frame rectangles and plane_from_pixel maps):
/// each of the frame's coarse features is predicted in the reference photo through
/// the plane and refined by the patch matcher (NCC search, then Gauss-Newton with
/// gain, offset and a shading ramp), which the change of light does not fool as it
/// fools feature descriptors; the matches are verified by a homography as the
/// reference photo's feature matches are. No matches where fewer than [`fine_min`]
/// survive or the frame has no patch image.
pub(crate) fn guided_matches(
    f: &FrameData,
    blocks: &[([f64; 4], Mat3)],
    (reference, plane_from_ref): (&Grey, &Homography),
    cfg: &AlignConfig,
    thr_cm: f64,
) -> Result<Guided, AlignError> {
    let min = fine_min(f, cfg);
    let none = |tried| Guided {
        matches: Vec::new(),
        verified: 0,
        tried,
        min,
        unmatched: Vec::new(),
    };
    let Some(grey) = f.grey.as_deref() else {
        return Ok(none(0));
    };
    let Some(ref_from_plane) = plane_from_ref.inverse() else {
        return Ok(none(0));
    };
    let long = f64::from(f.width.max(f.height));
    let settings = patch_settings(cfg, long, grey.width.max(grey.height) as f64);
    let ref_width = reference.width as u32;
    let margin = (settings.radius + settings.search.unsigned_abs() as usize + 2) as f64;
    let inside = |q: Vec2| {
        q.x >= margin
            && q.y >= margin
            && q.x < reference.width as f64 - margin
            && q.y < reference.height as f64 - margin
    };
    let s_grey = grey.width as f64 / f64::from(f.width);
    let points = pts(&f.coarse, 0..f.coarse.points.len() as u32);
    // Group the features by the sub-frame that maps them: one map per group.
    let mut groups: Vec<Vec<(Vec2, Vec2)>> = vec![Vec::new(); blocks.len()];
    for p in points {
        let p = Vec2::new(p[0], p[1]);
        let Some(b) = blocks
            .iter()
            .position(|(r, _)| p.x >= r[0] && p.y >= r[1] && p.x < r[2] && p.y < r[3])
        else {
            continue;
        };
        let Some(q) = Homography(blocks[b].1)
            .apply(p)
            .and_then(|x| ref_from_plane.apply(x))
        else {
            continue;
        };
        // Only texture that fixes a position in both directions: on streaks (brushed
        // metal) the patch slides along them and "confirms" wherever the map put it.
        if inside(q) && two_dimensional(grey, to_grey(p, s_grey), settings.radius) {
            groups[b].push((p, q));
        }
    }
    let mut src: Vec<[f64; 2]> = Vec::new();
    let mut dst: Vec<[f64; 2]> = Vec::new();
    let mut src_block: Vec<usize> = Vec::new();
    let tried_in: Vec<usize> = groups.iter().map(Vec::len).collect();
    let tried: usize = tried_in.iter().sum();
    for (b, group) in groups.into_iter().enumerate() {
        if group.is_empty() {
            continue;
        }
        let h_fr = ref_from_plane.0 * blocks[b].1;
        for (p, q) in refine_matches(
            (grey, f.width),
            (reference, ref_width),
            group.into_iter(),
            &h_fr,
            &settings,
        ) {
            src.push(p);
            dst.push([q.x, q.y]);
            src_block.push(b);
        }
    }
    if src.len() < min {
        return Ok(none(tried));
    }
    // Verified in reference pixels (as the reference photo's feature matches are): the
    // inlier distance on the plane converted at the reference photo's centre.
    let c = Vec2::new(0.5 * reference.width as f64, 0.5 * reference.height as f64);
    let cm_per_ref_px = match (
        plane_from_ref.apply(c),
        plane_from_ref.apply(c + Vec2::new(1.0, 0.0)),
    ) {
        (Some(a), Some(b)) => (a - b).norm().max(1e-9),
        _ => return Ok(none(tried)),
    };
    let Some(Robust { inliers, .. }) = estimate_homography(&src, &dst, thr_cm / cm_per_ref_px)?
    else {
        return Ok(none(tried));
    };
    let mut matched_in = vec![0usize; blocks.len()];
    for (&b, _) in src_block.iter().zip(&inliers).filter(|(_, i)| **i) {
        matched_in[b] += 1;
    }
    let unmatched: Vec<[f64; 4]> = (0..blocks.len())
        .filter(|&b| {
            tried_in[b] >= GUIDED_SUB_MIN_TRIED
                && (matched_in[b] as f64) < GUIDED_SUB_MIN_SHARE * tried_in[b] as f64
        })
        .map(|b| blocks[b].0)
        .collect();
    let kept: Vec<(Vec2, Vec2)> = (0..src.len())
        .filter(|&k| inliers[k])
        .filter_map(|k| {
            let x = plane_from_ref.apply(Vec2::new(dst[k][0], dst[k][1]))?;
            Some((Vec2::new(src[k][0], src[k][1]), x))
        })
        .collect();
    Ok(if kept.len() >= min {
        // Thinned to about as many as a frame's feature matches with the reference
        // photo (74-424 per hard-small frame) keeps the solve small; measured on
        // hard-small leather and patchwork seed 1 (markers only), the accuracy is the
        // same with all of them (median 0.28 and 0.09 px either way).
        let verified = kept.len();
        let step = verified.div_ceil(MAX_GUIDED);
        Guided {
            matches: kept.into_iter().step_by(step.max(1)).collect(),
            verified,
            tried,
            min,
            unmatched,
        }
    } else {
        none(tried)
    })
}

/// Plane ties (`ties`), where kept frames have no reference-photo feature matches of
/// their own: those lying off the reference photo by blocks that agree are solved
/// again with the blocks as anchors; then every such frame is matched with the
/// reference photo at full resolution from where it lies, solved again with those
/// matches, and the frames they do not confirm are left out. Returns the
/// registration and its self-check (unchanged where every frame has feature matches).
#[allow(clippy::too_many_arguments)]
pub(crate) fn tie_to_plane(
    matched: &Matched,
    mut result: Registration,
    mut checks: Vec<FrameCheck>,
    (ref_img, reference, region): (
        &svbrdf_core::image::ImageU8,
        &crate::reference::ReferenceFrame,
        svbrdf_core::plane::Region,
    ),
    cfg: &AlignConfig,
    progress: &dyn Progress,
    lap: &mut dyn FnMut(&str),
    trace: &mut crate::trace::AlignTrace,
) -> Result<(Registration, Vec<FrameCheck>), AlignError> {
    let is_untied =
        |r: &Registration, f: &FrameData| !r.reference_tied.contains(&(f.stream, f.index));
    if !result.frames.iter().any(|f| is_untied(&result, f)) {
        return Ok((result, checks));
    }
    let mut all = PlaneTies::new();
    let mut summary = PlaneTieSummary::default();
    let mut confirmed = std::collections::BTreeSet::new();
    let mut unmatched = std::collections::HashMap::new();
    let mut solve_again = |all: &PlaneTies,
                           result: &mut Registration,
                           checks: &mut Vec<FrameCheck>,
                           lap: &mut dyn FnMut(&str)|
     -> Result<(), AlignError> {
        *result = matched.solve_again(all, result, cfg, progress, lap, trace)?;
        *checks = self_check(result, ref_img, reference, region)?;
        lap("self-check");
        Ok(())
    };
    // Frames far off first get block ties: the full-resolution matcher searches a few
    // pixels around where a frame's map puts the reference photo's texture.
    let mappings = crate::checks::prepared_mappings(&result)?;
    let (blocks, largest) = ties_from_checks(&result, &checks, &|k, x| {
        mappings.get(k).and_then(|m| m.plane_to_pixel(x))
    });
    summary.offset_before_mm = largest;
    summary.untied = result
        .frames
        .iter()
        .filter(|f| is_untied(&result, f))
        .count();
    if !blocks.is_empty() && largest >= TIE_TRIGGER_MM {
        summary.ties = blocks.values().map(Vec::len).sum();
        summary.block_frames = blocks.len();
        all = blocks;
        solve_again(&all, &mut result, &mut checks, lap)?;
        summary.rounds += 1;
    }
    // Every frame without feature matches of its own is matched with the reference
    // photo at full resolution from where it now lies; where that confirms it, those
    // matches replace its block ties.
    let grey = Grey::from_image(ref_img);
    let cm_per_px = matched.cm_per_px;
    // Only frames the self-check placed (their blocks agreed with the reference photo,
    // before or after block ties): the matcher searches a few pixels around where a
    // frame's map puts the texture, and a frame placed wrong on texture that matches
    // in streaks is "confirmed" there (tiny brushed metal, markers only: 12 frames
    // confirmed 4 mm off).
    let placed: std::collections::BTreeSet<(u32, u64)> = checks
        .iter()
        .filter(|c| c.offset_mm().is_some())
        .map(|c| (c.stream, c.frame))
        .collect();
    let guided: Vec<((u32, u64), Guided)> = result
        .frames
        .par_iter()
        .zip(&result.mappings)
        .filter(|(f, _)| is_untied(&result, f) && placed.contains(&(f.stream, f.index)))
        .map(|(f, blocks)| {
            let thr_px = cfg.fine_inlier_px * f64::from(f.width.max(f.height)) / 3840.0;
            let m = guided_matches(
                f,
                blocks,
                (&grey, &reference.plane_from_pixel),
                cfg,
                thr_px * cm_per_px,
            )?;
            Ok(((f.stream, f.index), m))
        })
        .collect::<Result<_, AlignError>>()?;
    lap("plane ties: matching");
    for (key, g) in guided {
        if !g.confirms() {
            continue;
        }
        summary.guided_frames += 1;
        summary.guided_matches += g.matches.len();
        confirmed.insert(key);
        if !g.unmatched.is_empty() {
            unmatched.insert(key, g.unmatched);
        }
        all.insert(
            key,
            g.matches
                .into_iter()
                .map(|(p, x)| (p, x, cfg.reference_weight))
                .collect(),
        );
    }
    if !confirmed.is_empty() {
        solve_again(&all, &mut result, &mut checks, lap)?;
        summary.rounds += 1;
    }
    // A registration that needed plane ties keeps only frames that the reference
    // photo confirms: by feature matches of their own, or by full-resolution matches
    // over at least half of the frame from where the ties placed it. Measured
    // (hard-small, markers alone): frames tied by blocks only, or whose full-resolution
    // matches held under half of their features, were 1-5 mm off at their 95th
    // percentile in places no block had matched.
    let leave_out: std::collections::HashSet<(u32, u64)> = result
        .frames
        .iter()
        .filter(|f| is_untied(&result, f) && !confirmed.contains(&(f.stream, f.index)))
        .map(|f| (f.stream, f.index))
        .collect();
    if !leave_out.is_empty() {
        // Solved again without them: their correspondences pulled the kept frames'
        // maps, and held sub-frames that nothing else fixes (hard-small leather seed
        // 2, markers alone: a kept frame next to 19 left out lay 3.6 px off at its
        // 95th percentile where they had held it).
        result = matched.solve_without(&leave_out, &all, &mut result, cfg, progress, lap, trace)?;
        checks = self_check(&result, ref_img, reference, region)?;
        lap("self-check");
        summary.rounds += 1;
        for f in matched.frames.iter() {
            if leave_out.contains(&(f.stream, f.index)) {
                trace.set_fate(f, crate::trace::Fate::Unconfirmed);
                if f.stream == 0 {
                    summary.unconfirmed.push(f.index);
                }
            }
        }
        summary.unconfirmed.sort_unstable();
        let second = leave_out.iter().filter(|k| k.0 != 0).count();
        result.drops.unconfirmed += leave_out.len() - second;
        if let Some(d) = &mut result.second_drops {
            d.unconfirmed += second;
        }
    }
    let kept: std::collections::HashMap<(u32, u64), usize> = result
        .frames
        .iter()
        .enumerate()
        .map(|(k, f)| ((f.stream, f.index), k))
        .collect();
    summary.frames = all.keys().filter(|k| k.0 == 0).map(|k| k.1).collect();
    summary.offset_after_mm = all
        .keys()
        .filter_map(|k| kept.get(k))
        .filter_map(|&k| checks.get(k).and_then(|c| c.offset_mm()))
        .fold(0.0, f64::max);
    // Sub-frames of confirmed frames where the full-resolution matches found under a
    // quarter of the features tried are left out; a frame left with too few goes.
    let mut drop = std::collections::HashSet::new();
    for (k, f) in result.frames.iter().enumerate() {
        let Some(rects) = unmatched.get(&(f.stream, f.index)) else {
            continue;
        };
        let m = &mut result.mappings[k];
        let before = m.len();
        m.retain(|(r, _)| !rects.contains(r));
        if m.len() == before {
            continue;
        }
        summary
            .unmatched_subframes
            .push((f.index, before - m.len(), before));
        if (m.len() as f64) < crate::support::MIN_SUPPORTED_SHARE * before as f64 {
            drop.insert(k);
            trace.set_fate(f, crate::trace::Fate::Unconfirmed);
            if f.stream == 0 {
                summary.unconfirmed.push(f.index);
            }
        }
    }
    if !drop.is_empty() {
        summary.unconfirmed.sort_unstable();
        let renumber = crate::checks::remove_frames(&mut result, &drop, |d, n| d.unconfirmed += n);
        checks = checks
            .into_iter()
            .filter_map(|mut c| {
                c.kept_index = renumber(c.kept_index)?;
                Some(c)
            })
            .collect();
    }
    result.plane_tied = confirmed;
    result.plane_ties = Some(summary);
    Ok((result, checks))
}

#[cfg(test)]
mod tests {
    use std::sync::Arc;

    use svbrdf_core::image::ImageU8;
    use svbrdf_cv::features::Features;

    use super::*;
    use crate::selfcheck::lattice;

    fn checked(blocks: Vec<[f64; 4]>) -> FrameCheck {
        // What the self-check writes for these blocks.
        crate::selfcheck::summarise(0, 7, 0, blocks.len(), blocks)
    }

    #[test]
    fn ties_come_from_the_blocks_that_agree_and_never_from_strays() {
        let strays = [
            [3.0, 5.0, -3.4, 27.0],
            [5.0, 9.0, 12.0, -4.0],
            [7.0, 3.0, 0.3, 9.9],
        ];
        // Bent (0 mm at one end, 4 mm at the other): the affine field's blocks.
        let mut bent = lattice(|_, y| (0.25 * y, 0.0));
        let n = bent.len();
        bent.extend(strays);
        let c = checked(bent.clone());
        assert!(c.warp_mm.is_some(), "{c:?}");
        assert_eq!(agreeing_blocks(&c), bent[..n].to_vec());
        // Moved rigidly by 3 mm: the shift's blocks.
        let mut moved = lattice(|_, _| (3.0, -1.0));
        moved.extend(strays);
        let c = checked(moved.clone());
        assert!(c.warp_mm.is_none() && c.shift_mm.is_some(), "{c:?}");
        assert_eq!(agreeing_blocks(&c), moved[..n].to_vec());
        // Blocks pointing every which way verify nothing and tie nothing.
        let scattered: Vec<[f64; 4]> = (0..12)
            .map(|k| {
                let a = f64::from(k) * 2.4;
                [
                    f64::from(k),
                    1.0,
                    9.0 * a.cos() * f64::from(k),
                    9.0 * a.sin(),
                ]
            })
            .collect();
        let c = checked(scattered);
        assert!(c.offset_mm().is_none(), "{c:?}");
        assert!(agreeing_blocks(&c).is_empty());
    }

    /// A smooth texture (values about 40-215).
    fn tex(u: f64, v: f64) -> f64 {
        let waves = [
            (0.31, 0.17, 0.0),
            (-0.12, 0.43, 1.3),
            (0.23, -0.29, 2.1),
            (0.07, 0.11, 0.4),
            (0.52, 0.05, 2.9),
        ];
        let s: f64 = waves
            .iter()
            .map(|(a, b, p)| (a * u + b * v + p).sin())
            .sum();
        128.0 + 17.0 * s
    }

    fn grey(w: usize, h: usize, f: impl Fn(f64, f64) -> f64) -> Grey {
        let mut data = Vec::with_capacity(w * h);
        for y in 0..h {
            for x in 0..w {
                data.push(f(x as f64, y as f64).round().clamp(0.0, 255.0) as u8);
            }
        }
        Grey {
            width: w,
            height: h,
            data,
        }
    }

    #[test]
    fn only_texture_that_varies_both_ways_fixes_a_position() {
        let c = Vec2::new(20.0, 20.0);
        // Streaks along x (brushed metal): no gradient along them.
        let streaks = grey(40, 40, |_, y| 128.0 + 60.0 * (0.9 * y).sin());
        assert!(!two_dimensional(&streaks, c, 5));
        // Flat: no gradient at all.
        assert!(!two_dimensional(&grey(40, 40, |_, _| 90.0), c, 5));
        // Blobs: gradients both ways.
        let blobs = grey(40, 40, |x, y| {
            128.0 + 40.0 * (0.7 * x).sin() * (0.6 * y).cos()
        });
        assert!(two_dimensional(&blobs, c, 5));
        // Too close to the border for the patch.
        assert!(!two_dimensional(&blobs, Vec2::new(3.0, 20.0), 5));
    }

    #[test]
    fn guided_matches_find_the_plane_across_light_and_scale() {
        // The reference photo: 10 px per cm. The frame sees its texture at half the
        // scale (frame px (x, y) shows reference px (0.5 x + 20.3, 0.5 y + 30.7)),
        // darker and with an offset (another light), and its current map is 0.4
        // reference px (0.04 cm) off.
        let reference = grey(300, 300, tex);
        let frame = grey(400, 400, |x, y| {
            0.6 * tex(0.5 * x + 20.3, 0.5 * y + 30.7) + 25.0
        });
        let truth = |p: Vec2| Vec2::new(0.05 * p.x + 2.03, 0.05 * p.y + 3.07);
        let plane_from_ref = Homography(Mat3::new(0.1, 0.0, 0.0, 0.0, 0.1, 0.0, 0.0, 0.0, 1.0));
        let off = Mat3::new(
            0.05,
            0.0,
            2.03 + 0.03,
            0.0,
            0.05,
            3.07 - 0.03,
            0.0,
            0.0,
            1.0,
        );
        let mut points = Vec::new();
        for j in 0..20 {
            for i in 0..20 {
                points.push([20.0 + 18.0 * i as f32, 20.0 + 18.0 * j as f32]);
            }
        }
        let f = FrameData {
            index: 3,
            stream: 0,
            file: None,
            time_s: 0.1,
            width: 400,
            height: 400,
            blur: 1.0,
            markers: Vec::new(),
            coarse: Features {
                points,
                descriptors: Vec::new(),
            },
            fine: Features::default(),
            grey: Some(Arc::new(frame)),
            thumb: ImageU8::new(1, 1, 3),
        };
        let cfg = AlignConfig {
            fine_min_inliers: 60,
            ..AlignConfig::default()
        };
        let m = guided_matches(
            &f,
            &[([0.0, 0.0, 400.0, 400.0], off)],
            (&reference, &plane_from_ref),
            &cfg,
            0.05,
        )
        .unwrap();
        assert!(m.confirms(), "{} of {}", m.verified, m.tried);
        // Of 400 features, those on two-dimensional texture.
        assert!(m.verified > 100, "{}", m.verified);
        let m = m.matches;
        assert!(m.len() <= MAX_GUIDED, "{}", m.len());
        let mut err: Vec<f64> = m.iter().map(|(p, x)| (truth(*p) - x).norm()).collect();
        err.sort_by(f64::total_cmp);
        // The map was off by 0.042 cm (0.42 reference px).
        let (median, worst) = (err[err.len() / 2], err[err.len() - 1]);
        assert!(median < 0.003 && worst < 0.0125, "{median} {worst}");

        // A frame bent at one side: its right half's map 1 cm off. That half matches
        // nothing and is named; the left half, placed as before, is not.
        let mut bent = off;
        bent[(0, 2)] += 1.0;
        let halves = [
            ([0.0, 0.0, 200.0, 400.0], off),
            ([200.0, 0.0, 400.0, 400.0], bent),
        ];
        let m = guided_matches(&f, &halves, (&reference, &plane_from_ref), &cfg, 0.05).unwrap();
        assert!(m.verified > 50, "{} of {}", m.verified, m.tried);
        assert_eq!(
            m.unmatched,
            vec![halves[1].0],
            "{} of {}",
            m.verified,
            m.tried
        );

        // Without the frame's patch image there is nothing to match.
        let bare = FrameData { grey: None, ..f };
        let none = guided_matches(
            &bare,
            &[([0.0, 0.0, 400.0, 400.0], off)],
            (&reference, &plane_from_ref),
            &cfg,
            0.05,
        )
        .unwrap();
        assert!(none.matches.is_empty() && !none.confirms());
    }
}
