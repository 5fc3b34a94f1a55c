//! What lies on the plane: the material, four printed markers on white paper at the
//! region's corners, and the table around the material.

use svbrdf_core::brdf::BrdfParams;
use svbrdf_core::geometry::{Vec2, Vec3};
use svbrdf_core::plane::Region;

use crate::material::MaterialMaps;
use crate::noise::fbm;

/// A printed marker on the plane.
#[derive(Debug, Clone)]
pub struct PlacedMarker {
    /// Marker id.
    pub id: i32,
    /// Corners in world cm, OpenCV order (marker's top-left, top-right, bottom-right,
    /// bottom-left); the marker's top faces world +y.
    pub corners: [[f64; 3]; 4],
    /// Cells per side including the border, and their colours (`true` = white).
    pub cells: usize,
    /// Cell colours, row-major from the marker's top-left.
    pub white: Vec<bool>,
    x_min: f64,
    y_max: f64,
    size: f64,
}

/// The whole scene on the plane.
#[derive(Debug, Clone)]
pub struct Scene {
    /// Material maps (cover the region plus a margin).
    pub material: MaterialMaps,
    /// The four markers.
    pub markers: Vec<PlacedMarker>,
    /// The material region (markers' inner corners touch its corners).
    pub region: Region,
    paper_margin: f64,
    seed: u64,
}

const PAPER: BrdfParams = BrdfParams {
    rho_d: [0.80, 0.80, 0.78],
    rho_s: [0.03; 3],
    alpha_x: 0.35,
    alpha_y: 0.35,
    normal_theta_x: 0.0,
    normal_theta_y: 0.0,
    tangent_rotation: 0.0,
};

const INK: BrdfParams = BrdfParams {
    rho_d: [0.035, 0.035, 0.04],
    rho_s: [0.04; 3],
    alpha_x: 0.25,
    alpha_y: 0.25,
    normal_theta_x: 0.0,
    normal_theta_y: 0.0,
    tangent_rotation: 0.0,
};

impl Scene {
    /// Place markers of side `size` cm outside the region's corners, ids in the order
    /// top-left, top-right, bottom-right, bottom-left.
    pub fn new(
        material: MaterialMaps,
        region: Region,
        patterns: Vec<(i32, usize, Vec<bool>)>,
        size: f64,
        paper_margin: f64,
        seed: u64,
    ) -> Self {
        // Top-left corner (x_min, y_max) of each marker square.
        let origins = [
            (region.x_min - size, region.y_max + size),
            (region.x_max, region.y_max + size),
            (region.x_max, region.y_min),
            (region.x_min - size, region.y_min),
        ];
        let markers = patterns
            .into_iter()
            .zip(origins)
            .map(|((id, cells, white), (x0, y1))| PlacedMarker {
                id,
                corners: [
                    [x0, y1, 0.0],
                    [x0 + size, y1, 0.0],
                    [x0 + size, y1 - size, 0.0],
                    [x0, y1 - size, 0.0],
                ],
                cells,
                white,
                x_min: x0,
                y_max: y1,
                size,
            })
            .collect();
        Self {
            material,
            markers,
            region,
            paper_margin,
            seed,
        }
    }

    /// Surface parameters and unit normal at a plane point.
    #[inline]
    pub fn surface(&self, p: Vec2) -> (BrdfParams, Vec3) {
        for m in &self.markers {
            let (u, v) = ((p.x - m.x_min) / m.size, (m.y_max - p.y) / m.size);
            let mu = self.paper_margin / m.size;
            if u >= -mu && u < 1.0 + mu && v >= -mu && v < 1.0 + mu {
                if (0.0..1.0).contains(&u) && (0.0..1.0).contains(&v) {
                    let c = (u * m.cells as f64) as usize;
                    let r = (v * m.cells as f64) as usize;
                    let white = m.white[r.min(m.cells - 1) * m.cells + c.min(m.cells - 1)];
                    return (if white { PAPER } else { INK }, Vec3::z());
                }
                return (PAPER, Vec3::z());
            }
        }
        if self.material.covers(p) {
            return self.material.sample(p);
        }
        // The table the sample lies on: dark, low-contrast wood-like grain.
        let g = fbm(self.seed ^ 0x7AB1E, p.x / 0.6, p.y / 6.0, 3);
        let k = 0.6 + 0.8 * g;
        (
            BrdfParams {
                rho_d: [0.16 * k, 0.11 * k, 0.07 * k],
                rho_s: [0.04; 3],
                alpha_x: 0.3,
                alpha_y: 0.3,
                normal_theta_x: 0.0,
                normal_theta_y: 0.0,
                tangent_rotation: 0.0,
            },
            Vec3::z(),
        )
    }

    /// Whether a plane point lies within `r` cm of a marker's paper square.
    pub fn near_marker(&self, p: Vec2, r: f64) -> bool {
        let e = self.paper_margin + r;
        self.markers.iter().any(|m| {
            p.x >= m.x_min - e
                && p.x <= m.x_min + m.size + e
                && p.y <= m.y_max + e
                && p.y >= m.y_max - m.size - e
        })
    }

    /// Whether a plane point shows material (not paper) — ground-truth coverage mask.
    pub fn is_material(&self, p: Vec2) -> bool {
        if !self.region.contains(p) {
            return false;
        }
        !self.markers.iter().any(|m| {
            let e = self.paper_margin;
            p.x >= m.x_min - e
                && p.x < m.x_min + m.size + e
                && p.y <= m.y_max + e
                && p.y > m.y_max - m.size - e
        })
    }
}
