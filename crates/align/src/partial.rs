//! Marker corners where the detector finds no marker (issue 18, item 2): a marker cut
//! by the frame's edge, or in view but missed (blur, the flash's glare).
//!
//! ArUco detection needs a whole marker with its code readable, and markers lie at the
//! region's corners, where a sweep often shows only part of one. Once a frame has a
//! map, the reference photo says where each marker's corners lie on the plane, so the
//! frame's map predicts them in the frame. Each corner the frame shows is then found
//! as in [`crate::corners`]: the two sides of the marker's ink border that meet there
//! are located where the luminance crosses halfway between ink and paper, a line is
//! fitted to each, and they cross at the corner. A corner counts only where both
//! sides are measured over enough of their length, the lines fit their edge points
//! tightly, and the corner lies within a third of a border cell of the prediction
//! (so an edge inside the marker's pattern, a whole cell away, is never taken). The
//! corners found become marker anchors of their frame, and the solve runs again.
//! Only frames without reference-photo feature matches are searched: those with them
//! are held by hundreds of anchors, which a few corners do not move.
//!
//! The fine-scale luminance of a frame is kept only around the markers its first map
//! puts in view ([`marker_crops`]), so this costs no memory on frames far from them.

use std::collections::HashMap;

use serde::{Deserialize, Serialize};
use svbrdf_core::geometry::{Mat3, Vec2};
use svbrdf_core::homography::Homography;

use crate::corners::{search_reach, visible_corners, Luminance};
use crate::fine::to_grey;
use crate::frames::FrameData;
use crate::matching::Registration;
use crate::patch::Grey;

/// A side must be located on at least this many edge points (of 8-64 sampled).
const MIN_SIDE_POINTS: usize = 8;
/// A side's edge points must lie this close to their line, RMS, fine-scale pixels.
const MAX_SIDE_RMS: f64 = 0.35;
/// A corner must lie this far inside the frame, fine-scale pixels.
const INSIDE_PX: f64 = 3.0;

/// A piece of a frame's fine-scale luminance around a reference marker that the
/// frame's first map puts at least partly in view but that detection did not find.
#[derive(Debug, Clone)]
pub struct MarkerCrop {
    /// Marker id.
    pub id: i32,
    /// Top-left of the crop in the fine-scale image, pixels.
    pub origin: (usize, usize),
    /// Fine-scale pixels per full-resolution pixel.
    pub scale: f64,
    /// The luminance.
    pub grey: Grey,
}

/// What the marker corners did, as `align.json` records it.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct MarkerCornerSummary {
    /// Kept frames without reference-photo feature matches of their own that showed
    /// part (or all) of a marker that detection did not find.
    pub frames_tried: usize,
    /// Frames that got corners.
    pub frames: usize,
    /// Corners found (each one anchor, weighted as a detected marker's corner).
    pub corners: usize,
    /// Of those, corners of markers the frame showed only in part.
    pub partial_corners: usize,
    /// After the solve with them, how far the solved maps put the corners from where
    /// they were found: median and largest, frame pixels (a corner found wrong would
    /// stand out against the frame's other anchors).
    #[serde(default)]
    pub residual_px: Option<[f64; 2]>,
}

impl MarkerCornerSummary {
    /// One line for the summary.
    pub fn describe(&self) -> String {
        format!(
            "marker corners: {} corners found in {} of {} kept frames without reference-photo feature matches that showed a marker detection missed ({} of markers cut by the frame's edge){}",
            self.corners,
            self.frames,
            self.frames_tried,
            self.partial_corners,
            match self.residual_px {
                Some([m, x]) => format!(
                    "; solved again with them, which then lie {m:.2} px (median), at most {x:.2} px from where the maps put them"
                ),
                None => String::new(),
            }
        )
    }
}

/// Crops of `f`'s fine-scale luminance around every marker of `world` (id, corners
/// on the plane, cm) that `plane_from_pixel` (full-resolution pixels -> cm) puts at
/// least partly in the frame and that was not detected in it. Empty without a
/// fine-scale image.
pub(crate) fn marker_crops(
    f: &FrameData,
    plane_from_pixel: &Mat3,
    world: &[(i32, [Vec2; 4])],
) -> Vec<MarkerCrop> {
    let (Some(grey), Some(pixel_from_plane)) = (&f.grey, Homography(*plane_from_pixel).inverse())
    else {
        return Vec::new();
    };
    let s = grey.width as f64 / f64::from(f.width.max(1));
    let mut out = Vec::new();
    for (id, corners) in world {
        if f.markers.iter().any(|m| m.id == *id) {
            continue;
        }
        let Some(px) = corners
            .iter()
            .map(|c| pixel_from_plane.apply(*c).map(|p| to_grey(p, s)))
            .collect::<Option<Vec<Vec2>>>()
        else {
            continue;
        };
        let side = (0..4)
            .map(|k| (px[(k + 1) % 4] - px[k]).norm())
            .sum::<f64>()
            / 4.0;
        // Room for a first map a few pixels off, and for the paper around the ink.
        let margin = 0.5 * side + 24.0;
        let lo = |k: usize| px.iter().map(|p| p[k]).fold(f64::INFINITY, f64::min) - margin;
        let hi = |k: usize| px.iter().map(|p| p[k]).fold(f64::NEG_INFINITY, f64::max) + margin;
        let (x0, y0) = (lo(0).max(0.0), lo(1).max(0.0));
        let (x1, y1) = (hi(0).min(grey.width as f64), hi(1).min(grey.height as f64));
        // Not in view at all, or absurdly large (a map far off).
        if !(x1 > x0 + 8.0 && y1 > y0 + 8.0) || side > grey.width.max(grey.height) as f64 {
            continue;
        }
        let (x0, y0, x1, y1) = (x0 as usize, y0 as usize, x1 as usize, y1 as usize);
        let mut data = Vec::with_capacity((x1 - x0) * (y1 - y0));
        for r in y0..y1 {
            data.extend_from_slice(&grey.data[r * grey.width + x0..r * grey.width + x1]);
        }
        out.push(MarkerCrop {
            id: *id,
            origin: (x0, y0),
            scale: s,
            grey: Grey {
                width: x1 - x0,
                height: y1 - y0,
                data,
            },
        });
    }
    out
}

/// The corners of `crop`'s marker (`world`: its corners on the plane, cm) that the
/// crop shows, as (full-resolution frame pixel, plane cm), with whether the frame
/// showed the marker only in part. `plane_to_pixel` is the frame's solved map.
pub(crate) fn crop_corners(
    crop: &MarkerCrop,
    world: &[Vec2; 4],
    cells: usize,
    frame_size: (u32, u32),
    plane_to_pixel: &dyn Fn(Vec2) -> Option<Vec2>,
) -> (Vec<(Vec2, Vec2)>, bool) {
    // The map holds only inside the frame: predict the corners through a homography
    // fitted to points of the marker and its paper that the frame sees.
    let (mut src, mut dst) = (Vec::new(), Vec::new());
    for j in 0..9 {
        for i in 0..9 {
            let (u, v) = (
                f64::from(i) / 8.0 * 2.0 - 0.5,
                f64::from(j) / 8.0 * 2.0 - 0.5,
            );
            let q = world[0] + (world[1] - world[0]) * u + (world[3] - world[0]) * v;
            if let Some(p) = plane_to_pixel(q) {
                src.push(q);
                dst.push(p);
            }
        }
    }
    if src.len() < 8 {
        return (Vec::new(), false);
    }
    let Ok(h) = Homography::from_correspondences(&src, &dst) else {
        return (Vec::new(), false);
    };
    let (o, s) = (
        Vec2::new(crop.origin.0 as f64, crop.origin.1 as f64),
        crop.scale,
    );
    let Some(predicted) = world
        .iter()
        .map(|c| h.apply(*c).map(|p| to_grey(p, s) - o))
        .collect::<Option<Vec<Vec2>>>()
    else {
        return (Vec::new(), false);
    };
    let predicted = [predicted[0], predicted[1], predicted[2], predicted[3]];
    let (fw, fh) = (f64::from(frame_size.0) * s, f64::from(frame_size.1) * s);
    let inside = |p: Vec2, m: f64| {
        let g = p + o;
        g.x >= m && g.y >= m && g.x <= fw - 1.0 - m && g.y <= fh - 1.0 - m
    };
    let partial = predicted.iter().any(|p| !inside(*p, 0.0));
    let lum = Luminance::from_grey(crop.grey.width, crop.grey.height, &crop.grey.data);
    let reach = search_reach(&predicted, cells);
    let found = visible_corners(&lum, &predicted, cells, MIN_SIDE_POINTS, MAX_SIDE_RMS);
    let corners = (0..4)
        .filter_map(|k| {
            let c = found[k]?;
            // Within a third of a border cell of the prediction, and inside the frame.
            ((c - predicted[k]).norm() <= reach && inside(c, INSIDE_PX)).then(|| {
                let g = c + o;
                (
                    Vec2::new((g.x + 0.5) / s - 0.5, (g.y + 0.5) / s - 0.5),
                    world[k],
                )
            })
        })
        .collect();
    (corners, partial)
}

/// Marker anchors found in one frame: its index among the matched frames, and
/// (frame pixel, plane cm) per corner.
pub(crate) type FrameCorners = (usize, Vec<(Vec2, Vec2)>);

/// Corners of the markers that detection missed in the kept frames of `reg` without
/// reference-photo feature matches of their own, from
/// their crops (`crops`, per frame of `frames`, the matched frames): per matched
/// frame index, the anchors (frame pixel, plane cm), with what was done.
pub(crate) fn marker_corners(
    frames: &[FrameData],
    crops: &[Vec<MarkerCrop>],
    reg: &Registration,
    world: &[(i32, [Vec2; 4])],
    cells: usize,
) -> Result<(Vec<FrameCorners>, MarkerCornerSummary), crate::AlignError> {
    let index: HashMap<(u32, u64), usize> = frames
        .iter()
        .enumerate()
        .map(|(i, f)| ((f.stream, f.index), i))
        .collect();
    let world: HashMap<i32, [Vec2; 4]> = world.iter().copied().collect();
    let mappings = crate::checks::prepared_mappings(reg)?;
    let mut summary = MarkerCornerSummary::default();
    let mut out = Vec::new();
    for (f, m) in reg.frames.iter().zip(&mappings) {
        // Frames with reference-photo feature matches are anchored by hundreds of
        // them; a few corners moved nothing there (4K tiles: 31 corners in 14 frames,
        // the same error to four digits) and cost a solve.
        if reg.reference_tied.contains(&(f.stream, f.index)) {
            continue;
        }
        let Some(&i) = index.get(&(f.stream, f.index)) else {
            continue;
        };
        let Some(frame_crops) = crops.get(i).filter(|c| !c.is_empty()) else {
            continue;
        };
        let mut anchors = Vec::new();
        let mut tried = false;
        for crop in frame_crops {
            let Some(w) = world.get(&crop.id) else {
                continue;
            };
            // Only markers the solved map puts in view.
            if !w.iter().any(|c| m.plane_to_pixel(*c).is_some()) {
                continue;
            }
            tried = true;
            let (found, partial) = crop_corners(crop, w, cells, (f.width, f.height), &|q| {
                m.plane_to_pixel(q)
            });
            if partial {
                summary.partial_corners += found.len();
            }
            anchors.extend(found);
        }
        summary.frames_tried += usize::from(tried);
        if !anchors.is_empty() {
            summary.frames += 1;
            summary.corners += anchors.len();
            out.push((i, anchors));
        }
    }
    Ok((out, summary))
}

/// How far the maps of `reg` put each found corner (`found`, per matched frame index
/// into `frames`) from where it was found, frame pixels: median and largest (`None`
/// without corners in kept frames).
pub(crate) fn residuals(
    frames: &[FrameData],
    found: &[FrameCorners],
    reg: &Registration,
) -> Result<Option<[f64; 2]>, crate::AlignError> {
    let kept: HashMap<(u32, u64), usize> = reg
        .frames
        .iter()
        .enumerate()
        .map(|(k, f)| ((f.stream, f.index), k))
        .collect();
    let mappings = crate::checks::prepared_mappings(reg)?;
    let mut r: Vec<f64> = Vec::new();
    for (i, anchors) in found {
        let Some(m) = frames
            .get(*i)
            .and_then(|f| kept.get(&(f.stream, f.index)))
            .and_then(|&k| mappings.get(k))
        else {
            continue;
        };
        r.extend(
            anchors
                .iter()
                .filter_map(|(p, x)| m.plane_to_pixel(*x).map(|q| (q - p).norm())),
        );
    }
    if r.is_empty() {
        return Ok(None);
    }
    r.sort_by(f64::total_cmp);
    Ok(Some([r[r.len() / 2], r[r.len() - 1]]))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A frame of `w` x `h` pixels at `s` px per cm seeing the plane from (x0, y0) at
    /// its top-left: white paper with a black marker (6 cells of 0.2 cm, a 1-cell
    /// border and a checker inside) whose top-left corner is at (mx, my) cm.
    fn render(w: usize, h: usize, s: f64, x0: f64, y0: f64, mx: f64, my: f64) -> Grey {
        let mut data = vec![0u8; w * h];
        for r in 0..h {
            for c in 0..w {
                // 4 x 4 supersamples per pixel.
                let mut acc = 0.0;
                for k in 0..16 {
                    let (u, v) = (
                        c as f64 + (f64::from(k % 4) + 0.5) / 4.0 - 0.5,
                        r as f64 + (f64::from(k / 4) + 0.5) / 4.0 - 0.5,
                    );
                    let (x, y) = (x0 + u / s, y0 - v / s);
                    let (cx, cy) = ((x - mx) / 0.2, (my - y) / 0.2);
                    let ink = if (0.0..6.0).contains(&cx) && (0.0..6.0).contains(&cy) {
                        let (i, j) = (cx as i32, cy as i32);
                        i == 0 || j == 0 || i == 5 || j == 5 || (i + j) % 2 == 0
                    } else {
                        false
                    };
                    acc += if ink { 0.03 } else { 0.8 };
                }
                let lin: f64 = acc / 16.0;
                let srgb = if lin <= 0.003_130_8 {
                    12.92 * lin
                } else {
                    1.055 * lin.powf(1.0 / 2.4) - 0.055
                };
                data[r * w + c] = (255.0 * srgb).round() as u8;
            }
        }
        Grey {
            width: w,
            height: h,
            data,
        }
    }

    fn frame(grey: Grey) -> FrameData {
        FrameData::for_test(grey, Default::default())
    }

    /// The corners of the test marker (1.2 cm) with its top-left at (mx, my), cm.
    fn square(mx: f64, my: f64) -> [Vec2; 4] {
        [
            Vec2::new(mx, my),
            Vec2::new(mx + 1.2, my),
            Vec2::new(mx + 1.2, my - 1.2),
            Vec2::new(mx, my - 1.2),
        ]
    }

    /// Plane from pixel of a frame at `s` px/cm, its top-left pixel at (x0, 3) cm.
    fn map(s: f64, x0: f64) -> Mat3 {
        Mat3::new(1.0 / s, 0.0, x0, 0.0, -1.0 / s, 3.0, 0.0, 0.0, 1.0)
    }

    #[test]
    fn corners_of_a_marker_cut_by_the_frame_edge_are_found_and_only_those_shown() {
        // 50 px/cm; the frame sees x in [0, 4] cm, y in [3, 0] cm; the marker (1.2 cm)
        // starts at x = -0.5 cm: its left corners lie outside the frame.
        let s = 50.0;
        let (mx, my) = (-0.5, 2.0);
        let grey = render(200, 150, s, 0.0, 3.0, mx, my);
        let f = frame(grey);
        let world = square(mx, my);
        // The first map is 1.5 px off (x); the solved map is 0.6 px off.
        let first = map(s, 0.03);
        let crops = marker_crops(&f, &first, &[(7, world)]);
        assert_eq!(crops.len(), 1);
        let solved = Homography(map(s, 0.012));
        let inv = solved.inverse().unwrap();
        let to_px = |q: Vec2| {
            inv.apply(q)
                .filter(|p| p.x >= -0.5 && p.y >= -0.5 && p.x <= 199.5 && p.y <= 149.5)
        };
        let (found, partial) = crop_corners(&crops[0], &world, 6, (200, 150), &to_px);
        assert!(partial);
        assert_eq!(found.len(), 2, "{found:?}");
        for (p, x) in &found {
            // The true pixel of plane point x.
            let truth = Vec2::new((x.x - 0.0) * s, (3.0 - x.y) * s);
            assert!((p - truth).norm() < 0.15, "{p:?} vs {truth:?}");
            assert!(x.x > 0.0, "only the right corners are in view: {x:?}");
        }
        // A marker detection found is not searched again.
        let mut g = frame(render(200, 150, s, 0.0, 3.0, mx, my));
        g.markers.push(crate::reference::MarkerObservation {
            id: 7,
            corners: [Vec2::zeros(); 4],
        });
        assert!(marker_crops(&g, &first, &[(7, world)]).is_empty());
    }

    #[test]
    fn a_prediction_a_cell_off_finds_no_corner() {
        // The map puts the marker a whole border cell (0.2 cm = 10 px) off: the sides
        // searched there are the pattern's inner edges or nothing, never a corner.
        let s = 50.0;
        let (mx, my) = (1.0, 2.0);
        let f = frame(render(200, 150, s, 0.0, 3.0, mx, my));
        let world = square(mx, my);
        let first = map(s, 0.0);
        let crops = marker_crops(&f, &first, &[(7, world)]);
        let off = Homography(map(s, -0.2));
        let inv = off.inverse().unwrap();
        let (found, partial) = crop_corners(&crops[0], &world, 6, (200, 150), &|q| inv.apply(q));
        assert!(!partial);
        assert!(found.is_empty(), "{found:?}");
        // Where the map is right, all four are found.
        let right = Homography(first).inverse().unwrap();
        let (found, _) = crop_corners(&crops[0], &world, 6, (200, 150), &|q| right.apply(q));
        assert_eq!(found.len(), 4);
    }
}
