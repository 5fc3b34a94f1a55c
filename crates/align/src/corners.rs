//! Sub-pixel marker corners from edge lines.
//!
//! OpenCV refines ArUco corners with `cornerSubPix`, which is built for X-junctions and
//! is biased towards the dark side at an L-junction: measured on our simulator,
//! detected squares come out 0.2-0.4 px too small per corner. The marker size sets the
//! world scale, so that bias becomes a scale error of the whole capture. Here each
//! side of the marker is located where the linear-light intensity crosses halfway
//! between ink and paper (unbiased for any symmetric blur), a line is fitted per side,
//! and the corners are the intersections of adjacent lines.

use svbrdf_core::color::srgb8_to_linear_table;
use svbrdf_core::geometry::{centroid_scatter, Vec2};
use svbrdf_core::image::ImageU8;

/// Linear luminance of an 8-bit sRGB image, for edge localisation.
pub struct Luminance {
    w: usize,
    h: usize,
    data: Vec<f32>,
}

impl Luminance {
    /// Decode sRGB and weight channels by Rec. 709 luminance (a one-channel image is
    /// taken as sRGB-coded luminance already).
    pub fn new(img: &ImageU8) -> Self {
        let lut = srgb8_to_linear_table();
        let data = if img.channels < 3 {
            // Already luminance (sRGB-coded): only linearise.
            img.data
                .iter()
                .step_by(img.channels.max(1))
                .map(|&v| lut[v as usize])
                .collect()
        } else {
            img.data
                .chunks_exact(img.channels)
                .map(|p| {
                    0.2126 * lut[p[0] as usize]
                        + 0.7152 * lut[p[1] as usize]
                        + 0.0722 * lut[p[2] as usize]
                })
                .collect()
        };
        Self {
            w: img.width,
            h: img.height,
            data,
        }
    }

    /// From sRGB-coded luma samples (`width` x `height`, row-major).
    pub fn from_grey(width: usize, height: usize, data: &[u8]) -> Self {
        let lut = srgb8_to_linear_table();
        Self {
            w: width,
            h: height,
            data: data.iter().map(|&v| lut[v as usize]).collect(),
        }
    }

    fn at(&self, p: Vec2) -> Option<f64> {
        if !(p.x >= 0.0 && p.y >= 0.0 && p.x <= (self.w - 1) as f64 && p.y <= (self.h - 1) as f64) {
            return None;
        }
        let (x0, y0) = (p.x.floor() as usize, p.y.floor() as usize);
        let (x1, y1) = ((x0 + 1).min(self.w - 1), (y0 + 1).min(self.h - 1));
        let (fx, fy) = (p.x - x0 as f64, p.y - y0 as f64);
        let g = |x: usize, y: usize| f64::from(self.data[y * self.w + x]);
        let top = g(x0, y0) + (g(x1, y0) - g(x0, y0)) * fx;
        let bot = g(x0, y1) + (g(x1, y1) - g(x0, y1)) * fx;
        Some(top + (bot - top) * fy)
    }
}

/// A line `n . p = d` with unit normal `n`.
#[derive(Debug, Clone, Copy)]
struct Line {
    n: Vec2,
    d: f64,
}

fn fit_line(pts: &[Vec2]) -> Option<Line> {
    if pts.len() < 3 {
        return None;
    }
    let (c, [sxx, sxy, syy]) = centroid_scatter(pts)?;
    // Normal = eigenvector of the smaller eigenvalue of the scatter matrix.
    let theta = 0.5 * (2.0 * sxy).atan2(sxx - syy);
    let dir = Vec2::new(theta.cos(), theta.sin());
    let n = Vec2::new(-dir.y, dir.x);
    Some(Line { n, d: n.dot(&c) })
}

fn intersect(a: Line, b: Line) -> Option<Vec2> {
    let det = a.n.x * b.n.y - a.n.y * b.n.x;
    if det.abs() < 1e-9 {
        return None;
    }
    Some(Vec2::new(
        (a.d * b.n.y - b.d * a.n.y) / det,
        (a.n.x * b.d - b.n.x * a.d) / det,
    ))
}

/// Refine the four corners of a marker with `cells` cells per side (border included).
/// Returns the input unchanged where an edge cannot be measured.
pub fn refine_corners(lum: &Luminance, corners: &[Vec2; 4], cells: usize) -> [Vec2; 4] {
    let found = visible_corners(lum, corners, cells, 3, f64::INFINITY);
    std::array::from_fn(|k| found[k].unwrap_or(corners[k]))
}

/// How far across a predicted side the edge is searched, pixels: a third of a border
/// cell, far enough for a corner error of a pixel, close enough to stay on the ink
/// border.
pub fn search_reach(corners: &[Vec2; 4], cells: usize) -> f64 {
    let side = (0..4)
        .map(|k| (corners[(k + 1) % 4] - corners[k]).norm())
        .sum::<f64>()
        / 4.0;
    (side / cells.max(3) as f64 / 3.0).clamp(1.5, 6.0)
}

/// The corners of a marker predicted at `corners` that the image shows, each where
/// the two sides meeting there cross: a side is located on at least `min_points`
/// edge points (only the part of it in the image counts, so a marker cut by the
/// image's edge still gives the corners it shows) whose line fit leaves at most
/// `max_rms` pixels. `None` where a side cannot be measured or the crossing lies over
/// twice [`search_reach`] from the prediction.
pub fn visible_corners(
    lum: &Luminance,
    corners: &[Vec2; 4],
    cells: usize,
    min_points: usize,
    max_rms: f64,
) -> [Option<Vec2>; 4] {
    let centre = corners.iter().fold(Vec2::zeros(), |a, p| a + p) / 4.0;
    let side = (0..4)
        .map(|k| (corners[(k + 1) % 4] - corners[k]).norm())
        .sum::<f64>()
        / 4.0;
    let reach = search_reach(corners, cells);
    let mut lines = Vec::with_capacity(4);
    for k in 0..4 {
        let (a, b) = (corners[k], corners[(k + 1) % 4]);
        let dir = (b - a).normalize();
        let mut n = Vec2::new(-dir.y, dir.x);
        if n.dot(&(centre - a)) > 0.0 {
            n = -n; // point outwards, from ink to paper
        }
        let samples = ((side / 2.0) as usize).clamp(8, 64);
        let mut pts = Vec::with_capacity(samples);
        for i in 0..samples {
            // Stay away from the corners, where the other edge interferes.
            let t = 0.2 + 0.6 * (i as f64 + 0.5) / samples as f64;
            let base = a + (b - a) * t;
            let steps = (reach * 20.0) as i32;
            let profile: Option<Vec<(f64, f64)>> = (-steps..=steps)
                .map(|s| {
                    let o = f64::from(s) / 20.0;
                    lum.at(base + n * o).map(|v| (o, v))
                })
                .collect();
            let Some(profile) = profile else { continue };
            let lo = profile[..profile.len() / 4]
                .iter()
                .map(|p| p.1)
                .sum::<f64>()
                / (profile.len() / 4) as f64;
            let hi = profile[3 * profile.len() / 4..]
                .iter()
                .map(|p| p.1)
                .sum::<f64>()
                / (profile.len() - 3 * profile.len() / 4) as f64;
            if hi - lo < 0.05 {
                continue; // no clear ink-to-paper edge here
            }
            let mid = 0.5 * (lo + hi);
            // First crossing from ink to paper, interpolated.
            if let Some(w) = profile.windows(2).find(|w| w[0].1 < mid && w[1].1 >= mid) {
                let f = (mid - w[0].1) / (w[1].1 - w[0].1);
                pts.push(base + n * (w[0].0 + f * (w[1].0 - w[0].0)));
            }
        }
        let line = (pts.len() >= min_points)
            .then(|| fit_line(&pts))
            .flatten()
            .filter(|l| {
                let ss: f64 = pts.iter().map(|p| (l.n.dot(p) - l.d).powi(2)).sum();
                (ss / pts.len() as f64).sqrt() <= max_rms
            });
        lines.push(line);
    }
    std::array::from_fn(|k| {
        // Corner k joins side k-1 (from corner k-1 to k) and side k.
        let (l0, l1) = (lines[(k + 3) % 4]?, lines[k]?);
        intersect(l0, l1).filter(|p| (p - corners[k]).norm() < 2.0 * reach)
    })
}
