//! The checks after the global solve: the sweep (a still camera is refused), the
//! self-check of every registered frame against the reference photo (drop the frames
//! that disagree, refuse when too many do), and the coverage of the region.

use std::path::Path;

use crate::{frames, matching, reference, selfcheck, trace, AlignError};

/// Check every registered frame against the reference photo (see `selfcheck`).
pub(crate) fn self_check(
    reg: &matching::Registration,
    ref_img: &svbrdf_core::image::ImageU8,
    reference: &reference::ReferenceFrame,
    region: svbrdf_core::plane::Region,
) -> Result<Vec<selfcheck::FrameCheck>, AlignError> {
    let prepared = prepared_mappings(reg)?;
    let frames: Vec<selfcheck::CheckedFrame> = reg
        .frames
        .iter()
        .zip(prepared)
        .map(|(f, mapping)| selfcheck::CheckedFrame {
            frame: f.index,
            stream: f.stream,
            thumb: &f.thumb,
            width: f.width,
            mapping,
        })
        .collect();
    Ok(selfcheck::check(
        ref_img,
        &reference.plane_from_pixel,
        region,
        &frames,
    ))
}

/// Each registered frame's mapping, ready for evaluation.
pub(crate) fn prepared_mappings(
    reg: &matching::Registration,
) -> Result<Vec<svbrdf_core::capture::PreparedMapping>, AlignError> {
    let mut out = Vec::with_capacity(reg.frames.len());
    for ((f, m), pose) in reg.frames.iter().zip(&reg.mappings).zip(&reg.poses) {
        let frame = svbrdf_core::capture::Frame {
            id: 0,
            source: 0,
            frame_index: Some(f.index),
            image: None,
            time_s: None,
            width: f.width,
            height: f.height,
            mapping: svbrdf_core::capture::FrameMapping::Homographies {
                subframes: m
                    .iter()
                    .map(|(rect, h)| svbrdf_core::capture::SubFrame {
                        rect: *rect,
                        plane_from_pixel: svbrdf_core::geometry::mat3_to_rows(h),
                    })
                    .collect(),
            },
            camera_position: pose.centre.into(),
            light_position: pose.centre.into(),
            exposure_gain: None,
        };
        out.push(svbrdf_core::capture::PreparedMapping::new(&frame)?);
    }
    Ok(out)
}

/// Least share of the region that kept flash frames must see at least
/// [`COVERAGE_VIEWS`] times; below it the capture is refused.
pub const MIN_COVERAGE: f64 = 0.6;
/// Below this share a warning says which part of the region is thin.
pub const GOOD_COVERAGE: f64 = 0.97;
/// Views a plane point needs to count as covered.
pub const COVERAGE_VIEWS: u32 = 3;

/// Share of the region seen by at least [`COVERAGE_VIEWS`] kept flash frames, and a
/// description of where the rest lies (5 mm cells).
pub(crate) fn coverage(
    reg: &matching::Registration,
    region: svbrdf_core::plane::Region,
) -> Result<(f64, String), AlignError> {
    use rayon::prelude::*;
    let grid = svbrdf_core::plane::PlaneGrid::new(region, 2.0)?;
    let prepared = prepared_mappings(reg)?;
    let flash: Vec<(&svbrdf_core::capture::PreparedMapping, &frames::FrameData)> = prepared
        .iter()
        .zip(&reg.frames)
        .filter(|(_, f)| f.stream == 0)
        .collect();
    let views: Vec<u32> = (0..grid.len())
        .into_par_iter()
        .map(|i| {
            let q = grid.pixel_centre(i % grid.width, i / grid.width);
            flash
                .iter()
                .filter(|(m, f)| {
                    m.plane_to_pixel(q).is_some_and(|p| {
                        p.x >= -0.5
                            && p.y >= -0.5
                            && p.x <= f64::from(f.width) - 0.5
                            && p.y <= f64::from(f.height) - 0.5
                    })
                })
                .count() as u32
        })
        .collect();
    let thin = views.iter().filter(|v| **v < COVERAGE_VIEWS).count();
    let share = 1.0 - thin as f64 / views.len().max(1) as f64;
    if thin == 0 {
        return Ok((share, String::new()));
    }
    // Name the ninths of the region where most cells are thin.
    let mut thin_in = [[0usize; 3]; 3];
    let mut all_in = [[0usize; 3]; 3];
    for (i, v) in views.iter().enumerate() {
        let (c, r) = (i % grid.width, i / grid.width);
        let (sx, sy) = ((3 * c / grid.width).min(2), (3 * r / grid.height).min(2));
        all_in[sy][sx] += 1;
        if *v < COVERAGE_VIEWS {
            thin_in[sy][sx] += 1;
        }
    }
    let names = [
        ["top-left corner", "top edge", "top-right corner"],
        ["left edge", "middle", "right edge"],
        ["bottom-left corner", "bottom edge", "bottom-right corner"],
    ];
    let mut parts = Vec::new();
    for sy in 0..3 {
        for sx in 0..3 {
            if all_in[sy][sx] > 0 && thin_in[sy][sx] * 2 > all_in[sy][sx] {
                parts.push(names[sy][sx]);
            }
        }
    }
    let missed = if parts.is_empty() {
        "scattered patches across the region".to_string()
    } else {
        format!("the {}", parts.join(", "))
    };
    Ok((share, missed))
}

/// Drop the frames the self-check found inconsistent with the reference photo, or
/// refuse the capture when too many are; warn about frames off in parts (at the output
/// resolution).
pub(crate) fn apply_self_check(
    reg: &mut matching::Registration,
    checks: &[selfcheck::FrameCheck],
    align_cfg: &crate::AlignConfig,
    warnings: &mut Vec<String>,
    trace: &mut trace::AlignTrace,
) -> Result<(), AlignError> {
    let cfg = &align_cfg.self_check;
    let px_per_cm = crate::output::px_per_cm(reg, align_cfg);
    let checked: Vec<&selfcheck::FrameCheck> =
        checks.iter().filter(|c| c.offset_mm().is_some()).collect();
    let bad: Vec<&selfcheck::FrameCheck> = checked
        .iter()
        .copied()
        .filter(|c| c.inconsistent(cfg.max_shift_mm))
        .collect();
    let unverified = checks.len() - checked.len();
    if unverified * 2 > checks.len() {
        warnings.push(format!(
            "the self-check could verify only {} of {} registered frames against the reference photo (too little matching texture or too much highlight): their registration is unchecked",
            checked.len(),
            checks.len()
        ));
    }
    let (trimmed, rest, said) = trim_bent_parts(reg, checks, cfg.max_shift_mm, px_per_cm);
    warnings.extend(said);
    if let Some(w) = selfcheck::edge_disagreement(&rest, cfg.max_shift_mm, px_per_cm) {
        warnings.push(w);
    }
    let mut drop: std::collections::HashSet<usize> = trimmed.into_iter().collect();
    if let Some(what) = selfcheck::disagreement(checks, cfg.max_shift_mm) {
        for c in &bad {
            if let Some(t) = trace.frame_mut(c.stream, c.frame) {
                t.fate = trace::Fate::Inconsistent;
            }
        }
        if bad.len() as f64 > cfg.max_inconsistent_share * checked.len() as f64 {
            return Err(AlignError::Solve(format!(
                "the registration failed its self-check: {what}, although the solve's residual is small (frames that drifted together, or matches one pattern repeat off on a repetitive texture); expected at most {:.0}% of the frames off by more than {} mm. Film again passing over each marker several times and keeping the phone 10-15 cm from the surface, or lower the frame step in the camera description",
                100.0 * cfg.max_inconsistent_share,
                cfg.max_shift_mm
            )));
        }
        drop.extend(bad.iter().map(|c| c.kept_index));
        let frames: Vec<(u32, u64)> = reg.frames.iter().map(|f| (f.stream, f.index)).collect();
        let stranded = stranded_frames(&frames, &reg.verified_pairs, &drop);
        let also = if stranded.is_empty() {
            String::new()
        } else {
            format!(
                ", and with them frame(s) {} whose only links to other frames were to those (their maps were solved with them)",
                frame_names(reg, &stranded)
            )
        };
        warnings.push(format!(
            "{what}; these frames were dropped (self-check against the reference photo){also}"
        ));
        drop.extend(stranded);
    }
    if !drop.is_empty() {
        for &k in &drop {
            if let Some(f) = reg.frames.get(k) {
                if let Some(t) = trace.frame_mut(f.stream, f.index) {
                    t.fate = trace::Fate::Inconsistent;
                }
            }
        }
        let _ = remove_frames(reg, &drop, |d, n| d.inconsistent += n);
    }
    Ok(())
}

/// The video frame numbers of kept frames (kept indices), comma-separated.
fn frame_names(reg: &matching::Registration, kept: &[usize]) -> String {
    let names: Vec<String> = kept
        .iter()
        .filter_map(|&k| reg.frames.get(k).map(|f| f.index.to_string()))
        .collect();
    names.join(", ")
}

/// Leave out the sub-frames of the verified, consistent frames that the self-check
/// shows bent at an edge ([`selfcheck::bent_blocks`]: neighbouring blocks off together
/// by more than [`selfcheck::EDGE_PX`] output pixels at `px_per_cm`): each sub-frame
/// whose centre falls on such a block. A frame left with fewer than
/// [`crate::support::MIN_SUPPORTED_SHARE`] of its sub-frames is to be dropped.
/// Returns those frames (kept indices), the checks with the bent blocks taken out (for
/// [`selfcheck::edge_disagreement`], which then warns of what is left), and one line
/// for people, recording the trimmed frames in `reg.support.bent_trimmed`.
///
/// Measured on the Mitsuba tiles capture `xi2` at the default frame step
/// (session 38): frame 14, registered right in the middle, lay 10.7 output px off at
/// its 95th percentile where one edge held few matches; the self-check saw that
/// edge's blocks 0.7-2.8 mm off, growing towards the corner.
pub(crate) fn trim_bent_parts(
    reg: &mut matching::Registration,
    checks: &[selfcheck::FrameCheck],
    limit_mm: f64,
    px_per_cm: f64,
) -> (Vec<usize>, Vec<selfcheck::FrameCheck>, Option<String>) {
    let mut rest = checks.to_vec();
    let Some(edge_mm) = selfcheck::edge_mm(px_per_cm) else {
        return (Vec::new(), rest, None);
    };
    let (mut drop, mut named, mut left_out, mut far) = (Vec::new(), Vec::new(), 0, 0.0_f64);
    for c in &mut rest {
        if c.inconsistent(limit_mm) {
            continue;
        }
        let bent = selfcheck::bent_blocks(c, edge_mm);
        let Some(m) = reg
            .mappings
            .get_mut(c.kept_index)
            .filter(|_| !bent.is_empty())
        else {
            continue;
        };
        let before = m.len();
        let removed = selfcheck::leave_out_bent(m, &bent);
        if removed == 0 {
            continue;
        }
        far = bent.iter().map(|b| b[2].hypot(b[3])).fold(far, f64::max);
        c.block_shifts.retain(|b| !bent.contains(b));
        c.max_shift_mm = c
            .block_shifts
            .iter()
            .map(|b| b[2].hypot(b[3]))
            .reduce(f64::max);
        named.push(c.frame);
        left_out += removed;
        reg.support.bent_trimmed.push((c.frame, removed, before));
        if (m.len() as f64) < crate::support::MIN_SUPPORTED_SHARE * before as f64 {
            drop.push(c.kept_index);
        }
    }
    if named.is_empty() {
        return (drop, rest, None);
    }
    let dropped = if drop.is_empty() {
        String::new()
    } else {
        format!(
            "; frame(s) {}, left with too few, were dropped",
            frame_names(reg, &drop)
        )
    };
    let said = format!(
        "frames {} ({} of {} verified): an edge of each lay up to {far:.2} mm ({:.1} output px) from where the reference photo shows the same texture while the rest of the frame agrees (few matches of their own there: repetitive texture); the {left_out} sub-frames there were left out{dropped}",
        selfcheck::ranges(&named),
        named.len(),
        selfcheck::verified(checks).0,
        far * px_per_cm / 10.0
    );
    (drop, rest, Some(said))
}

/// Kept flash frames (kept indices into `frames`, as (stream, video frame number), not
/// in `drop`) all of whose verified links (`pairs`: video frame numbers of the flash
/// stream) to other kept frames lead to frames in `drop`: the global solve fitted
/// their maps to frames the self-check found off, so what they rest on is gone with
/// them. Frames without links keep what anchors them.
///
/// Measured: on a Mitsuba-rendered tiles capture (`xi3`, default frame step) the
/// self-check dropped two of a piece of three frames (1.1-1.5 mm off); the third,
/// left alone and tied by its own reference-photo matches too, was 3.0 output px
/// off at its 95th percentile (`docs/BENCHMARKS.md`, session 38).
pub(crate) fn stranded_frames(
    frames: &[(u32, u64)],
    pairs: &[(u64, u64, usize)],
    drop: &std::collections::HashSet<usize>,
) -> Vec<usize> {
    use std::collections::HashMap;
    let kept: HashMap<u64, usize> = frames
        .iter()
        .enumerate()
        .filter(|(_, f)| f.0 == 0)
        .map(|(k, f)| (f.1, k))
        .collect();
    let mut links: HashMap<usize, Vec<usize>> = HashMap::new();
    for &(a, b, _) in pairs {
        if let (Some(&ka), Some(&kb)) = (kept.get(&a), kept.get(&b)) {
            links.entry(ka).or_default().push(kb);
            links.entry(kb).or_default().push(ka);
        }
    }
    let mut out: Vec<usize> = links
        .iter()
        .filter(|(k, partners)| {
            !drop.contains(k) && !partners.is_empty() && partners.iter().all(|p| drop.contains(p))
        })
        .map(|(&k, _)| k)
        .collect();
    out.sort_unstable();
    out
}

/// Remove the kept frames whose kept index is in `drop` from `reg`, counting them in
/// its frame accounting with `count` (per stream) and taking them off `kept`. Returns
/// the new kept index of every old one (`None`: removed).
pub(crate) fn remove_frames(
    reg: &mut matching::Registration,
    drop: &std::collections::HashSet<usize>,
    count: impl Fn(&mut crate::DropCounts, usize),
) -> impl Fn(usize) -> Option<usize> {
    fn retain_kept<T>(v: &mut Vec<T>, drop: &std::collections::HashSet<usize>) {
        let mut i = 0;
        v.retain(|_| {
            i += 1;
            !drop.contains(&(i - 1))
        });
    }
    let flash_dropped = drop
        .iter()
        .filter(|&&k| reg.frames.get(k).is_some_and(|f| f.stream == 0))
        .count();
    let second_dropped = drop.iter().filter(|&&k| k < reg.frames.len()).count() - flash_dropped;
    let n = reg.frames.len();
    retain_kept(&mut reg.frames, drop);
    retain_kept(&mut reg.mappings, drop);
    retain_kept(&mut reg.poses, drop);
    retain_kept(&mut reg.lights, drop);
    count(&mut reg.drops, flash_dropped);
    reg.drops.kept -= flash_dropped.min(reg.drops.kept);
    if let Some(d) = &mut reg.second_drops {
        count(d, second_dropped);
        d.kept -= second_dropped.min(d.kept);
    }
    let mut map = vec![None; n];
    let mut next = 0;
    for (k, m) in map.iter_mut().enumerate() {
        if !drop.contains(&k) {
            *m = Some(next);
            next += 1;
        }
    }
    move |k| map.get(k).copied().flatten()
}

/// Refuse a registration most of whose flash frames nothing independent of the chains
/// of frames confirms: neither matches of their own with the reference photo (enough
/// to anchor them) nor the self-check, which found where the reference photo shows
/// their texture. Markers do not confirm a frame: they lie off the material, and the
/// rest of the frame hangs on matches with other frames, which on texture that
/// matches in streaks (brushed metal) or repeats slide along it. Measured with the
/// reference photo's matches left out (`--no-reference-matches`, markers only), such
/// registrations succeeded 6-53 mm off while every frame with a marker "anchored"
/// (docs/BENCHMARKS.md, session 20).
pub(crate) fn require_confirmation(
    reg: &matching::Registration,
    checks: &[selfcheck::FrameCheck],
) -> Result<(), AlignError> {
    let verified: std::collections::BTreeSet<(u32, u64)> = checks
        .iter()
        .filter(|c| c.offset_mm().is_some())
        .map(|c| (c.stream, c.frame))
        .collect();
    let flash: Vec<(u32, u64)> = reg
        .frames
        .iter()
        .filter(|f| f.stream == 0)
        .map(|f| (f.stream, f.index))
        .collect();
    // Matched with the reference photo: by features, or at full resolution from
    // where plane ties placed the frame.
    let is_tied = |f: &(u32, u64)| reg.reference_tied.contains(f) || reg.plane_tied.contains(f);
    let tied = flash.iter().filter(|f| is_tied(f)).count();
    let checked = flash
        .iter()
        .filter(|f| !is_tied(f) && verified.contains(f))
        .count();
    let unconfirmed: Vec<u64> = flash
        .iter()
        .filter(|f| !is_tied(f) && !verified.contains(f))
        .map(|f| f.1)
        .collect();
    if unconfirmed.len() * 2 <= flash.len() {
        return Ok(());
    }
    Err(AlignError::Solve(format!(
        "the registration cannot be checked: of its {} registered frames, {tied} matched the reference photo well enough to be tied to it and {checked} more were verified against it by the self-check; frames {} are placed only through other frames and the markers (expected at least half of the frames confirmed by the reference photo: texture that matches in streaks or repeats lets chains of frames bend by millimetres to centimetres unseen). Take the reference photo from 20-30 cm under even light, straight down, with the whole region sharp, or pass --no-self-check to accept the registration unchecked",
        flash.len(),
        selfcheck::ranges(&unconfirmed)
    )))
}

/// Smallest sweep of the flash camera accepted, cm: the extent of its positions over
/// the kept frames. A still or barely moving phone sees the surface under one light
/// direction, from which no BRDF can be fitted.
pub const MIN_SWEEP_CM: f64 = 1.0;

/// Refuse a capture whose flash camera barely moved.
pub(crate) fn check_baseline(
    reg: &matching::Registration,
    reference: &Path,
) -> Result<f64, AlignError> {
    let xy: Vec<(f64, f64)> = reg
        .poses
        .iter()
        .zip(&reg.frames)
        .filter(|(_, f)| f.stream == 0)
        .map(|(p, _)| (p.centre.x, p.centre.y))
        .collect();
    let extent = |v: &mut dyn Iterator<Item = f64>| {
        let (lo, hi) = v.fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), x| {
            (lo.min(x), hi.max(x))
        });
        hi - lo
    };
    let sweep = extent(&mut xy.iter().map(|p| p.0)).hypot(extent(&mut xy.iter().map(|p| p.1)));
    let d = &reg.drops;
    if xy.len() < 3 && d.decoded >= 3 {
        // Not a still camera: too few frames registered to tell.
        return Err(AlignError::Connect(format!(
            "only {} of {} sampled frames could be registered ({} blurry, {} in pieces not tied to the plane, {} without a usable map, {} mostly extrapolated, {} outside the markers): the frames matched neither each other nor the reference photo well enough (expected most of them; low-contrast or streaky texture under a broad highlight does this). Film more slowly, with the markers in view more often, or lower frame_step in the camera description",
            xy.len(),
            d.decoded,
            d.blurry,
            d.disconnected,
            d.unregistered,
            d.unsupported,
            d.outside
        )));
    }
    if !(sweep >= MIN_SWEEP_CM) {
        return Err(AlignError::Video(format!(
            "the camera barely moved: over its {} registered frames the flash camera's positions span {:.2} cm (expected a sweep of at least {MIN_SWEEP_CM} cm; film 15-30 s moving the phone across the whole surface, see docs/CAPTURE.md; reference photo {})",
            xy.len(),
            if sweep.is_finite() { sweep } else { 0.0 },
            reference.display()
        )));
    }
    Ok(sweep)
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::collections::HashSet;

    #[test]
    fn a_frame_linked_only_to_dropped_frames_is_stranded() {
        // Kept: flash frames 0, 4, 10, 56, 65, 69, 89 and a second-stream frame 65.
        let frames = [
            (0, 0),
            (0, 4),
            (0, 10),
            (0, 56),
            (0, 65),
            (0, 69),
            (0, 89),
            (1, 65),
        ];
        let pairs = [
            (0, 4, 40),
            (4, 10, 35),
            (56, 65, 30),
            (65, 69, 25),
            (10, 56, 22),
            // A link to a frame no longer kept does not hold a frame.
            (89, 95, 50),
        ];
        // 56 and 69 dropped: 65 rests on them alone; 10 keeps 4.
        let drop: HashSet<usize> = [3, 5].into_iter().collect();
        assert_eq!(stranded_frames(&frames, &pairs, &drop), vec![4]);
        // Nothing dropped, nothing stranded; 89 (no kept partner) never is.
        assert!(stranded_frames(&frames, &pairs, &HashSet::new()).is_empty());
        // 65 dropped alone: 69 was linked to it only, 56 to 10 as well.
        let drop: HashSet<usize> = [4].into_iter().collect();
        assert_eq!(stranded_frames(&frames, &pairs, &drop), vec![5]);
    }
}
