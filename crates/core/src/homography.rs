//! Plane-to-plane homographies.

use nalgebra::{DMatrix, SymmetricEigen};

use crate::geometry::{centroid_scatter, Mat3, Vec2};
use crate::CoreError;

/// A homography acting on 2-D points in homogeneous coordinates.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Homography(pub Mat3);

impl Homography {
    /// The identity map.
    pub fn identity() -> Self {
        Self(Mat3::identity())
    }

    /// Map a point; `None` when it goes to infinity.
    pub fn apply(&self, p: Vec2) -> Option<Vec2> {
        let m = &self.0;
        let w = m[(2, 0)] * p.x + m[(2, 1)] * p.y + m[(2, 2)];
        if w.abs() < 1e-15 {
            return None;
        }
        Some(Vec2::new(
            (m[(0, 0)] * p.x + m[(0, 1)] * p.y + m[(0, 2)]) / w,
            (m[(1, 0)] * p.x + m[(1, 1)] * p.y + m[(1, 2)]) / w,
        ))
    }

    /// The inverse map.
    pub fn inverse(&self) -> Option<Self> {
        self.0.try_inverse().map(|m| Self(m).normalized())
    }

    /// `self` after `other`: x -> self(other(x)).
    pub fn compose(&self, other: &Self) -> Self {
        Self(self.0 * other.0).normalized()
    }

    /// Scale so that the bottom-right entry is 1 (the paper's eq. 4), when it is not ~0.
    pub fn normalized(self) -> Self {
        let s = self.0[(2, 2)];
        if s.abs() > 1e-12 {
            Self(self.0 / s)
        } else {
            Self(self.0 / self.0.norm())
        }
    }

    /// Direct linear transform from four or more correspondences, with Hartley
    /// normalisation of both point sets so the answer does not depend on units.
    pub fn from_correspondences(src: &[Vec2], dst: &[Vec2]) -> Result<Self, CoreError> {
        if src.len() != dst.len() || src.len() < 4 {
            return Err(CoreError::Degenerate(format!(
                "homography needs at least 4 matched points, got {} and {}",
                src.len(),
                dst.len()
            )));
        }
        let ts = normalizing_transform(src)?;
        let td = normalizing_transform(dst)?;
        let n = src.len();
        let mut a = DMatrix::<f64>::zeros(2 * n, 9);
        for (i, (s, d)) in src.iter().zip(dst).enumerate() {
            let s = ts
                .apply(*s)
                .ok_or_else(|| CoreError::Degenerate("point at infinity".into()))?;
            let d = td
                .apply(*d)
                .ok_or_else(|| CoreError::Degenerate("point at infinity".into()))?;
            let r = 2 * i;
            a.row_mut(r).copy_from_slice(&[
                -s.x,
                -s.y,
                -1.0,
                0.0,
                0.0,
                0.0,
                d.x * s.x,
                d.x * s.y,
                d.x,
            ]);
            a.row_mut(r + 1).copy_from_slice(&[
                0.0,
                0.0,
                0.0,
                -s.x,
                -s.y,
                -1.0,
                d.y * s.x,
                d.y * s.y,
                d.y,
            ]);
        }
        let ata = a.transpose() * &a;
        let eig = SymmetricEigen::new(ata);
        let (imin, _) = eig
            .eigenvalues
            .iter()
            .enumerate()
            .min_by(|x, y| x.1.total_cmp(y.1))
            .ok_or_else(|| CoreError::Degenerate("empty system".into()))?;
        let h = eig.eigenvectors.column(imin);
        let hn = Mat3::new(h[0], h[1], h[2], h[3], h[4], h[5], h[6], h[7], h[8]);
        let td_inv =
            td.0.try_inverse()
                .ok_or_else(|| CoreError::Degenerate("points are collinear".into()))?;
        let out = Self(td_inv * hn * ts.0).normalized();
        if !out.0.iter().all(|v| v.is_finite()) || out.0.determinant().abs() < 1e-15 {
            return Err(CoreError::Degenerate(
                "homography is singular (collinear points?)".into(),
            ));
        }
        Ok(out)
    }
}

/// Similarity that moves the centroid to the origin and the mean distance to sqrt(2).
fn normalizing_transform(pts: &[Vec2]) -> Result<Homography, CoreError> {
    let n = pts.len() as f64;
    let (c, [sxx, sxy, syy]) =
        centroid_scatter(pts).ok_or_else(|| CoreError::Degenerate("no points".into()))?;
    let d = pts.iter().map(|p| (p - c).norm()).sum::<f64>() / n;
    if d < 1e-12 {
        return Err(CoreError::Degenerate("all points coincide".into()));
    }
    // Collinear points fix no homography: reject them by the spread's smaller axis.
    let tr = sxx + syy;
    let det = sxx * syy - sxy * sxy;
    let small = 0.5 * (tr - (tr * tr - 4.0 * det).max(0.0).sqrt());
    if small < 1e-10 * tr {
        return Err(CoreError::Degenerate("points are collinear".into()));
    }
    let s = std::f64::consts::SQRT_2 / d;
    Ok(Homography(Mat3::new(
        s,
        0.0,
        -s * c.x,
        0.0,
        s,
        -s * c.y,
        0.0,
        0.0,
        1.0,
    )))
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn random_h(a: f64, b: f64, c: f64, d: f64, e: f64, f: f64) -> Homography {
        Homography(Mat3::new(
            1.0 + a,
            b,
            30.0 * c,
            d,
            1.0 + e,
            -20.0 * f,
            1e-4 * b,
            -1e-4 * a,
            1.0,
        ))
    }

    proptest! {
        #[test]
        fn dlt_recovers_known_homography(a in -0.3f64..0.3, b in -0.3f64..0.3, c in -1.0f64..1.0,
                                         d in -0.3f64..0.3, e in -0.3f64..0.3, f in -1.0f64..1.0) {
            let h = random_h(a, b, c, d, e, f);
            let src: Vec<Vec2> = [(0.0, 0.0), (400.0, 10.0), (390.0, 300.0), (5.0, 310.0), (200.0, 150.0)]
                .iter().map(|&(x, y)| Vec2::new(x, y)).collect();
            let dst: Vec<Vec2> = src.iter().map(|p| h.apply(*p).unwrap()).collect();
            let est = Homography::from_correspondences(&src, &dst).unwrap();
            for p in &src {
                let q = est.apply(*p).unwrap();
                prop_assert!((q - h.apply(*p).unwrap()).norm() < 1e-6);
            }
        }

        #[test]
        fn inverse_round_trip(a in -0.3f64..0.3, b in -0.3f64..0.3, c in -1.0f64..1.0,
                              x in -100.0f64..100.0, y in -100.0f64..100.0) {
            let h = random_h(a, b, c, 0.1, -0.1, 0.5);
            let p = Vec2::new(x, y);
            let q = h.apply(p).unwrap();
            let back = h.inverse().unwrap().apply(q).unwrap();
            prop_assert!((back - p).norm() < 1e-8);
        }
    }

    #[test]
    fn collinear_points_are_rejected() {
        let src: Vec<Vec2> = (0..5)
            .map(|i| Vec2::new(f64::from(i), 2.0 * f64::from(i)))
            .collect();
        assert!(Homography::from_correspondences(&src, &src).is_err());
    }
}
