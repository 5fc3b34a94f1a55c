//! Fine correspondences (paper 3.1.3): matches between connected frames and with the
//! reference photo, located to a fraction of a pixel at full resolution.

use svbrdf_core::geometry::{Mat3, Vec2};
use svbrdf_core::homography::Homography;
use svbrdf_core::image::ImageU8;
use svbrdf_cv::features::{
    downscaled, estimate_homography, match_into, match_one_to_one, sift, Features, MatchIndex,
    Robust,
};

use crate::coarse::*;
use crate::config::{AlignConfig, FineMethod};
use crate::frames::FrameData;
use crate::patch::{refine, Grey, PatchSettings};
use crate::reference::ReferenceFrame;
use crate::subframes::Grid;
use crate::ties::two_dimensional;
use crate::AlignError;
use std::sync::atomic::{AtomicUsize, Ordering};

/// What the fine matching of all pairs did beyond the paper, counted across threads.
#[derive(Debug, Default)]
pub(crate) struct FineCounts {
    /// Refined matches dropped by [`recheck`].
    pub rechecked: AtomicUsize,
    /// Guided matches kept ([`guided_fill`]), after the recheck.
    pub guided: AtomicUsize,
}

/// Verified correspondences (frame a px, frame b px) and the homography a -> b.
pub(crate) type FineMatch = (Vec<[f64; 2]>, Vec<[f64; 2]>, Mat3);

/// Features of the reference photo with their plane positions (cm).
pub struct ReferenceFeatures {
    pub(crate) features: Features,
    /// Full-resolution reference pixels of the features.
    pub(crate) pixels: Vec<Vec2>,
    pub(crate) plane: Vec<Vec2>,
    /// Full-resolution luminance, for `FineMethod::Patch`.
    pub(crate) grey: Option<Grey>,
    /// plane_from_pixel of the reference photo.
    pub(crate) plane_from_pixel: Homography,
    /// Search index of the features (`FineMethod::Patch`), built once for all frames.
    pub(crate) index: Option<MatchIndex>,
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

/// The fine minimum inlier count for this frame size.
pub(crate) fn fine_min(f: &FrameData, cfg: &AlignConfig) -> usize {
    let long = f64::from(f.width.max(f.height));
    let fs = (f64::from(cfg.fine_long_side) / long).min(1.0);
    AlignConfig::scaled_min(
        cfg.fine_min_inliers,
        3840.0 * 2160.0,
        f64::from(f.width) * f64::from(f.height) * fs * fs,
    )
}

/// Verified fine correspondences between frames a and b (full-resolution pixels).
/// `counts` adds what the patch method's recheck dropped and its guided fill added.
pub(crate) fn fine_pair(
    a: &FrameData,
    b: &FrameData,
    coarse_matches: Option<&[(u32, u32)]>,
    cfg: &AlignConfig,
    counts: &FineCounts,
) -> Result<Option<FineMatch>, AlignError> {
    if cfg.fine_method == FineMethod::Patch {
        return fine_pair_patch(a, b, coarse_matches, cfg, counts);
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
pub(crate) fn patch_settings(cfg: &AlignConfig, long: f64, grey_long: f64) -> PatchSettings {
    let coarse_px = grey_long / f64::from(cfg.coarse_long_side).min(long);
    PatchSettings {
        radius: (cfg.patch_radius_px * grey_long / 3840.0).round().max(5.0) as usize,
        search: (coarse_px.round() as i32).clamp(3, 8),
        ..PatchSettings::default()
    }
}

/// Full-resolution pixel to patch-image pixel (pixel centres at integers).
pub(crate) fn to_grey(p: Vec2, s: f64) -> Vec2 {
    Vec2::new((p.x + 0.5) * s - 0.5, (p.y + 0.5) * s - 0.5)
}

/// Refine coarse correspondences `(a px, b px)` (full resolution) by patches: `a`'s
/// point stays, `b`'s moves to where `a`'s patch, warped by the local linear part of
/// `h_ab`, matches best. Returns the kept pairs, full-resolution pixels.
pub(crate) fn refine_matches(
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

/// Keep the items whose refined correspondence `at(item) = (first, second)` one
/// homography from first to second, fitted to them robustly, explains within `thr`
/// (the second's pixels). Returns how many it dropped.
///
/// Why: on repetitive texture (a printed motif, mosaic, grout crossings) coarse matches
/// one period off pass the coarse homography, whose inlier distance must allow for
/// lens distortion across whole frames, and the patch search then refines the wrong
/// point to a sharp but wrong peak. On captures rendered by Mitsuba with flat-coloured
/// tiles 5% of the refined matches were 2-8 output px off, most of them by one motif
/// period along a row or column (`docs/BENCHMARKS.md`, session 33); refined, the right
/// ones agree with one homography to a pixel or two even with the lens distortion of
/// the hard presets. With fewer than 5 matches a homography fits exactly and nothing
/// is checked.
pub(crate) fn recheck<T>(
    items: &mut Vec<T>,
    at: impl Fn(&T) -> ([f64; 2], Vec2),
    thr: f64,
) -> Result<usize, AlignError> {
    if items.len() < 5 {
        return Ok(0);
    }
    let first: Vec<[f64; 2]> = items.iter().map(|p| at(p).0).collect();
    let second: Vec<[f64; 2]> = items
        .iter()
        .map(|p| {
            let q = at(p).1;
            [q.x, q.y]
        })
        .collect();
    let before = items.len();
    match estimate_homography(&first, &second, thr)? {
        Some(Robust { inliers, .. }) => {
            let mut keep = inliers.into_iter();
            items.retain(|_| keep.next().unwrap_or(false));
        }
        None => items.clear(),
    }
    Ok(before - items.len())
}

/// [`fine_pair`] by patch refinement of the coarse matches (those of the coarse stage
/// where given, else matched here).
pub(crate) fn fine_pair_patch(
    a: &FrameData,
    b: &FrameData,
    coarse_matches: Option<&[(u32, u32)]>,
    cfg: &AlignConfig,
    counts: &FineCounts,
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
    // Each match tagged with whether the guided fill found it.
    let mut refined: Vec<(([f64; 2], Vec2), bool)> =
        refined.into_iter().map(|r| (r, false)).collect();
    if cfg.fine_fill > 0 {
        let used: Vec<u32> = (0..m.len())
            .filter(|&k| inliers[k])
            .map(|k| m[k].0)
            .collect();
        let have: Vec<([f64; 2], Vec2)> = refined.iter().map(|r| r.0).collect();
        let candidates = guided_fill((a, ga), (b, gb), &used, &have, &h, cfg, &settings);
        // Held to a stricter correlation than matches that passed the ratio test.
        let strict = PatchSettings {
            min_ncc: GUIDED_MIN_NCC,
            ..settings
        };
        refined.extend(
            refine_matches(
                (ga, a.width),
                (gb, b.width),
                candidates.into_iter(),
                &h,
                &strict,
            )
            .into_iter()
            .map(|r| (r, true)),
        );
    }
    let dropped = recheck(&mut refined, |r| r.0, cfg.fine_recheck_px * long / 3840.0)?;
    let guided = refined.iter().filter(|r| r.1).count();
    counts.rechecked.fetch_add(dropped, Ordering::Relaxed);
    counts.guided.fetch_add(guided, Ordering::Relaxed);
    let refined: Vec<([f64; 2], Vec2)> = refined.into_iter().map(|r| r.0).collect();
    if refined.len() < min {
        return Ok(None);
    }
    Ok(Some((
        refined.iter().map(|r| r.0).collect(),
        refined.iter().map(|r| [r.1.x, r.1.y]).collect(),
        h,
    )))
}

/// Lowest normalised cross-correlation of a guided match ([`guided_fill`]); matches
/// that passed the ratio test need 0.8 (`PatchSettings::default`). At 0.8 the guided
/// matches made hard-small leather and bathroom tiles worse (median 0.099 -> 0.111 and
/// 0.175 -> 0.192 output px, a frame 0.54 -> 0.91 px): the sub-frames short of matches
/// lie about the flash highlight, whose shading moves with the phone and which a loose
/// correlation follows. At 0.95 those captures are as before (0.097, 0.180) and the
/// Mitsuba-rendered tiles keep the gain (`docs/BENCHMARKS.md`, session 38).
pub const GUIDED_MIN_NCC: f32 = 0.95;

/// Guided matches are sought only among frames (video or still photos) whose long
/// side is at most this, pixels (see `matching::match_frames`).
pub const FILL_MAX_LONG_SIDE: u32 = 1920;

/// Candidates for guided matches of the pair (a, b), as (a px, predicted b px): a's
/// coarse features that are not among the matches used (`used`, indices into
/// `a.coarse`), predicted in b through the pair's homography `h_ab`, lying in a
/// sub-frame of a or of b that holds fewer than `cfg.fine_fill` of the refined matches
/// `have`, with texture in two directions (on a grout line alone the patch would slide
/// along it). Each short sub-frame gets at most twice what it lacks (some candidates
/// fail to refine); features at a position already taken are skipped (SIFT repeats a
/// point for each of its orientations).
///
/// Why: the ratio test rejects a feature whose descriptor has a near twin elsewhere in
/// the frame, as every grout crossing and every copy of a printed motif has. Between
/// frames whose homography is known to a pixel or two, position tells the twins apart,
/// and the patch refinement and [`recheck`] verify each one as they do the rest.
pub(crate) fn guided_fill(
    (a, ga): (&FrameData, &Grey),
    (b, gb): (&FrameData, &Grey),
    used: &[u32],
    have: &[([f64; 2], Vec2)],
    h_ab: &Mat3,
    cfg: &AlignConfig,
    settings: &PatchSettings,
) -> Vec<(Vec2, Vec2)> {
    let fill = cfg.fine_fill;
    let (grid_a, grid_b) = (
        Grid::new(a.width, a.height, cfg),
        Grid::new(b.width, b.height, cfg),
    );
    let mut count_a = vec![0usize; grid_a.len()];
    let mut count_b = vec![0usize; grid_b.len()];
    let mut taken = std::collections::HashSet::new();
    let key = |p: Vec2| (p.x.round() as i64, p.y.round() as i64);
    for (p, q) in have {
        let p = Vec2::new(p[0], p[1]);
        count_a[grid_a.cell(p)] += 1;
        count_b[grid_b.cell(*q)] += 1;
        taken.insert(key(p));
    }
    let short = |count: &[usize]| count.iter().any(|&c| c < fill);
    if fill == 0 || !(short(&count_a) || short(&count_b)) {
        return Vec::new();
    }
    let mut is_used = vec![false; a.coarse.points.len()];
    for &k in used {
        if let Some(u) = is_used.get_mut(k as usize) {
            *u = true;
        }
    }
    let h = Homography(*h_ab);
    let s_a = ga.width as f64 / f64::from(a.width);
    let s_b = gb.width as f64 / f64::from(b.width);
    // Where the patch and its search window stay inside b, in b's pixels.
    let margin = (settings.radius + settings.search.unsigned_abs() as usize + 2) as f64 / s_b;
    let inside_b = |q: Vec2| {
        q.x >= margin
            && q.y >= margin
            && q.x < f64::from(b.width) - margin
            && q.y < f64::from(b.height) - margin
    };
    let mut tried_a = vec![0usize; grid_a.len()];
    let mut tried_b = vec![0usize; grid_b.len()];
    let wants = |count: usize, tried: usize| count < fill && tried < 2 * (fill - count);
    let mut out = Vec::new();
    for (k, pt) in pts(&a.coarse, 0..a.coarse.points.len() as u32)
        .into_iter()
        .enumerate()
    {
        if is_used[k] {
            continue;
        }
        let p = Vec2::new(pt[0], pt[1]);
        let Some(q) = h.apply(p) else {
            continue;
        };
        if !inside_b(q) || taken.contains(&key(p)) {
            continue;
        }
        let (ca, cb) = (grid_a.cell(p), grid_b.cell(q));
        if !(wants(count_a[ca], tried_a[ca]) || wants(count_b[cb], tried_b[cb])) {
            continue;
        }
        if !two_dimensional(ga, to_grey(p, s_a), settings.radius) {
            continue;
        }
        taken.insert(key(p));
        tried_a[ca] += 1;
        tried_b[cb] += 1;
        out.push((p, q));
    }
    out
}

/// A frame's anchors on the reference photo (frame pixel, plane cm) and how many
/// matches its verification kept (also when too few to anchor it).
pub(crate) type ReferenceAnchors = (Vec<([f64; 2], Vec2)>, usize);

/// Absolute anchors of one frame from the reference photo by patch refinement:
/// (frame px, plane cm).
pub(crate) fn reference_anchors_patch(
    f: &FrameData,
    rfe: &ReferenceFeatures,
    cfg: &AlignConfig,
    thr_cm: f64,
) -> Result<ReferenceAnchors, AlignError> {
    let (Some(ga), Some(gr), Some(index)) = (f.grey.as_deref(), rfe.grey.as_ref(), &rfe.index)
    else {
        return Ok((Vec::new(), 0));
    };
    let m = match_into(&f.coarse, index, 0.8)?;
    let min = fine_min(f, cfg);
    // Fewer candidates than needed are still verified, to say how close the frame came.
    if m.len() < 8 {
        return Ok((Vec::new(), 0));
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
        _ => return Ok((Vec::new(), 0)),
    };
    let Some(Robust { model, inliers }) = estimate_homography(&src, &dst, thr_cm / cm_per_ref_px)?
    else {
        return Ok((Vec::new(), 0));
    };
    let keep: Vec<usize> = (0..src.len()).filter(|&k| inliers[k]).collect();
    if keep.len() < min {
        return Ok((Vec::new(), keep.len()));
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
    // Not rechecked like frame pairs: against the reference photo a frame shows its
    // whole lens distortion, and the check dropped right anchors with the wrong ones
    // (one Mitsuba-rendered capture lost its registration at twice the distance).
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
    let verified = out.len();
    Ok((if verified >= min { out } else { Vec::new() }, verified))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A pair seen through a mild homography, a few matches a motif period off.
    fn pairs_with_period_errors() -> (Vec<([f64; 2], Vec2)>, Vec<usize>) {
        let h = Homography(Mat3::new(
            1.02, 0.03, 12.0, -0.02, 0.98, -7.0, 2e-5, -1e-5, 1.0,
        ));
        let mut pairs = Vec::new();
        let mut off = Vec::new();
        for k in 0..60 {
            let p = Vec2::new(
                20.0 + f64::from(k % 10) * 50.0,
                30.0 + f64::from(k / 10) * 150.0,
            );
            let mut q = h.apply(p).unwrap_or(p);
            // Small refinement noise on every match.
            q += Vec2::new(
                0.3 * (f64::from(k) * 1.7).sin(),
                0.3 * (f64::from(k) * 2.3).cos(),
            );
            if k % 9 == 4 {
                // One period (14 px) along a row or a column.
                q += if k % 2 == 0 {
                    Vec2::new(14.0, 0.0)
                } else {
                    Vec2::new(0.0, -14.0)
                };
                off.push(k as usize);
            }
            pairs.push(([p.x, p.y], q));
        }
        (pairs, off)
    }

    #[test]
    fn recheck_drops_exactly_the_matches_a_period_off() {
        let (mut pairs, off) = pairs_with_period_errors();
        let before = pairs.clone();
        let dropped = recheck(&mut pairs, |p| *p, 2.0).unwrap();
        assert_eq!(dropped, off.len());
        let kept: Vec<usize> = (0..before.len())
            .filter(|&k| pairs.iter().any(|p| p.0 == before[k].0))
            .collect();
        assert!(kept.iter().all(|k| !off.contains(k)), "{kept:?} {off:?}");
        assert_eq!(kept.len(), before.len() - off.len());
    }

    #[test]
    fn recheck_leaves_too_few_matches_alone() {
        let (pairs, _) = pairs_with_period_errors();
        let mut four: Vec<_> = pairs.into_iter().skip(2).take(4).collect();
        assert_eq!(recheck(&mut four, |p| *p, 0.1).unwrap(), 0);
        assert_eq!(four.len(), 4);
    }

    /// Grout crossings: the same cross every 40 px on smooth shading, as an image seen
    /// through a shift `t` (a point `p` of the first frame lies at `p + t`).
    fn crossings(width: usize, height: usize, t: Vec2) -> Grey {
        let node = |x: f64| (x - 20.0) - 40.0 * ((x - 20.0) / 40.0).round();
        let mut data = Vec::with_capacity(width * height);
        for y in 0..height {
            for x in 0..width {
                let (dx, dy) = (node(x as f64 - t.x), node(y as f64 - t.y));
                let arm = |u: f64, v: f64| (-(u / 1.5).powi(2) - (v / 6.0).powi(2)).exp();
                let v = 60.0 + 0.1 * x as f64 + 120.0 * (arm(dx, dy) + arm(dy, dx));
                data.push(v.round().clamp(0.0, 255.0) as u8);
            }
        }
        Grey {
            width,
            height,
            data,
        }
    }

    fn frame(grey: Grey, points: Vec<[f32; 2]>) -> FrameData {
        // Every crossing's descriptor alike: the ratio test would take none.
        let descriptors = vec![0.0; 128 * points.len()];
        FrameData::for_test(
            grey,
            Features {
                points,
                descriptors,
            },
        )
    }

    #[test]
    fn guided_fill_finds_look_alike_crossings_where_sub_frames_lack_matches() {
        let (w, h) = (320usize, 480usize);
        let t = Vec2::new(3.3, -2.1);
        let mut points = Vec::new();
        for y in (20..h - 20).step_by(40) {
            for x in (20..w - 20).step_by(40) {
                points.push([x as f32, y as f32]);
            }
        }
        // SIFT repeats a point for each of its orientations.
        points.push(points[points.len() - 3]);
        // Unmatched features in the top sub-frames, which hold enough matches already.
        let extra: Vec<[f32; 2]> = points
            .iter()
            .filter(|p| p[1] <= 180.0)
            .map(|p| [p[0] + 1.0, p[1]])
            .collect();
        let matched_half = |p: &[f32; 2]| p[1] < 240.0 && p[0] % 40.0 == 20.0;
        points.extend(extra);
        let a = frame(crossings(w, h, Vec2::new(0.0, 0.0)), points.clone());
        let b = frame(crossings(w, h, t), Vec::new());
        let (ga, gb) = (a.grey.as_deref().unwrap(), b.grey.as_deref().unwrap());
        // The top half matched already; the bottom half's crossings failed the ratio test.
        let used: Vec<u32> = (0..points.len() as u32)
            .filter(|&k| matched_half(&points[k as usize]))
            .collect();
        let have: Vec<([f64; 2], Vec2)> = used
            .iter()
            .map(|&k| {
                let p = points[k as usize];
                (
                    [f64::from(p[0]), f64::from(p[1])],
                    Vec2::new(f64::from(p[0]), f64::from(p[1])) + t,
                )
            })
            .collect();
        // The pair's homography, 1.4 px off the truth.
        let h_ab = Mat3::new(1.0, 0.0, t.x + 1.2, 0.0, 1.0, t.y - 0.8, 0.0, 0.0, 1.0);
        let cfg = AlignConfig {
            fine_fill: 4,
            ..AlignConfig::default()
        };
        let settings = patch_settings(&cfg, h as f64, h as f64);
        let candidates = guided_fill((&a, ga), (&b, gb), &used, &have, &h_ab, &cfg, &settings);
        let grid = Grid::new(w as u32, h as u32, &cfg);
        let mut per_cell = vec![0usize; grid.len()];
        for (p, _) in &candidates {
            assert!(p.y > 240.0, "a matched crossing tried again: {p:?}");
            per_cell[grid.cell(*p)] += 1;
        }
        // Sub-frames below the matched half each get crossings, at most twice the
        // fill; those above it (6 matches each, over the fill of 4) none.
        let row_h = h as f64 / grid.rows as f64;
        for (c, &n) in per_cell.iter().enumerate() {
            let (top, bottom) = (
                (c / grid.cols) as f64 * row_h,
                (c / grid.cols + 1) as f64 * row_h,
            );
            assert!(n <= 8, "cell {c}: {n}");
            if bottom <= 240.0 {
                assert_eq!(n, 0, "cell {c}");
            }
            if top >= 240.0 {
                assert!(n >= 1, "cell {c}");
            }
        }
        let mut positions: Vec<(i64, i64)> = candidates
            .iter()
            .map(|(p, _)| (p.x as i64, p.y as i64))
            .collect();
        positions.sort_unstable();
        positions.dedup();
        assert_eq!(
            positions.len(),
            candidates.len(),
            "a repeated point tried twice"
        );
        let refined = refine_matches(
            (ga, a.width),
            (gb, b.width),
            candidates.into_iter(),
            &h_ab,
            &settings,
        );
        assert!(refined.len() >= 8, "{}", refined.len());
        for (p, q) in &refined {
            let err = (*q - (Vec2::new(p[0], p[1]) + t)).norm();
            assert!(err < 0.1, "{p:?} refined to {q:?}, {err:.3} px off");
        }
        // Nothing to fill: no candidates.
        let off = AlignConfig {
            fine_fill: 0,
            ..cfg
        };
        assert!(guided_fill((&a, ga), (&b, gb), &used, &have, &h_ab, &off, &settings).is_empty());
    }
}
