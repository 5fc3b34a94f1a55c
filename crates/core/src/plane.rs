//! The material plane and its pixel grid.
//!
//! Plane coordinates are world x, y in cm (z = 0). Maps are stored with +x to the right
//! and +y towards the *top* of the image, so a map looks like the reference photo. The
//! centre of map pixel (column i, row j) is at
//! `x = x_min + (i + 0.5) / px_per_cm`, `y = y_max - (j + 0.5) / px_per_cm`.

use serde::{Deserialize, Serialize};

use crate::geometry::Vec2;
use crate::CoreError;

/// An axis-aligned rectangle on the plane, in cm.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Region {
    /// Left edge (cm).
    pub x_min: f64,
    /// Right edge (cm).
    pub x_max: f64,
    /// Bottom edge (cm).
    pub y_min: f64,
    /// Top edge (cm).
    pub y_max: f64,
}

impl Region {
    /// A region centred on the origin.
    pub fn centred(width_cm: f64, height_cm: f64) -> Self {
        Self {
            x_min: -0.5 * width_cm,
            x_max: 0.5 * width_cm,
            y_min: -0.5 * height_cm,
            y_max: 0.5 * height_cm,
        }
    }

    /// Width in cm.
    pub fn width(&self) -> f64 {
        self.x_max - self.x_min
    }

    /// Height in cm.
    pub fn height(&self) -> f64 {
        self.y_max - self.y_min
    }

    /// The region grown by `m` cm on every side.
    pub fn expanded(&self, m: f64) -> Self {
        Self {
            x_min: self.x_min - m,
            x_max: self.x_max + m,
            y_min: self.y_min - m,
            y_max: self.y_max + m,
        }
    }

    /// Whether a plane point lies inside.
    pub fn contains(&self, p: Vec2) -> bool {
        p.x >= self.x_min && p.x <= self.x_max && p.y >= self.y_min && p.y <= self.y_max
    }

    /// Check that the region is finite and has positive area.
    pub fn validate(&self) -> Result<(), CoreError> {
        let ok = [self.x_min, self.x_max, self.y_min, self.y_max]
            .iter()
            .all(|v| v.is_finite());
        if !ok || self.width() <= 0.0 || self.height() <= 0.0 {
            return Err(CoreError::invalid(
                "region",
                format!(
                    "[{}, {}] x [{}, {}]",
                    self.x_min, self.x_max, self.y_min, self.y_max
                ),
                "finite bounds in cm with x_min < x_max and y_min < y_max",
            ));
        }
        Ok(())
    }
}

/// A pixel grid over a region of the plane.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct PlaneGrid {
    /// The covered region; its size is rounded to whole pixels from `x_min`, `y_max`.
    pub region: Region,
    /// Resolution in pixels per cm.
    pub px_per_cm: f64,
    /// Columns.
    pub width: usize,
    /// Rows.
    pub height: usize,
}

impl PlaneGrid {
    /// A grid of the given resolution covering `region` (rounded to whole pixels).
    pub fn new(region: Region, px_per_cm: f64) -> Result<Self, CoreError> {
        region.validate()?;
        if !(px_per_cm > 0.0 && px_per_cm.is_finite()) {
            return Err(CoreError::invalid(
                "resolution",
                px_per_cm,
                "pixels per cm, greater than 0",
            ));
        }
        let width = (region.width() * px_per_cm).round().max(1.0) as usize;
        let height = (region.height() * px_per_cm).round().max(1.0) as usize;
        Ok(Self {
            region,
            px_per_cm,
            width,
            height,
        })
    }

    /// Plane position (cm) of the centre of pixel (col, row).
    pub fn pixel_centre(&self, col: usize, row: usize) -> Vec2 {
        self.to_plane(Vec2::new(col as f64, row as f64))
    }

    /// Continuous pixel coordinates (centres at integers) to plane position.
    pub fn to_plane(&self, p: Vec2) -> Vec2 {
        Vec2::new(
            self.region.x_min + (p.x + 0.5) / self.px_per_cm,
            self.region.y_max - (p.y + 0.5) / self.px_per_cm,
        )
    }

    /// Plane position to continuous pixel coordinates (centres at integers).
    pub fn to_pixel(&self, q: Vec2) -> Vec2 {
        Vec2::new(
            (q.x - self.region.x_min) * self.px_per_cm - 0.5,
            (self.region.y_max - q.y) * self.px_per_cm - 0.5,
        )
    }

    /// Number of pixels.
    pub fn len(&self) -> usize {
        self.width * self.height
    }

    /// Whether the grid has no pixels (never, for a validated grid).
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    proptest! {
        #[test]
        fn grid_round_trip(x in -10.0f64..10.0, y in -10.0f64..10.0, s in 1.0f64..200.0) {
            let g = PlaneGrid::new(Region::centred(20.0, 20.0), s).unwrap();
            let q = Vec2::new(x, y);
            prop_assert!((g.to_plane(g.to_pixel(q)) - q).norm() < 1e-9);
        }
    }

    #[test]
    fn first_pixel_is_top_left() {
        let g = PlaneGrid::new(Region::centred(2.0, 2.0), 10.0).unwrap();
        assert_eq!((g.width, g.height), (20, 20));
        let c = g.pixel_centre(0, 0);
        assert!((c.x + 0.95).abs() < 1e-12 && (c.y - 0.95).abs() < 1e-12);
        assert!(PlaneGrid::new(Region::centred(2.0, 2.0), 0.0).is_err());
        assert!(Region::centred(-1.0, 2.0).validate().is_err());
    }
}
