//! Camera and plane geometry.
//!
//! Conventions (see `docs/CONVENTIONS.md`): world units are centimetres; the material
//! lies in the plane z = 0 with +z pointing out of the surface towards the camera.
//! Camera frames follow OpenCV: +x right, +y down, +z along the optical axis. Pixel
//! centres sit at integer coordinates, so an image of width W spans [-0.5, W - 0.5].

use nalgebra::{Matrix3, Vector2, Vector3};
use serde::{Deserialize, Serialize};

use crate::CoreError;

/// A 3-vector in world or camera coordinates (cm).
pub type Vec3 = Vector3<f64>;
/// A 2-vector: pixel coordinates or plane coordinates (cm).
pub type Vec2 = Vector2<f64>;
/// A 3x3 matrix (rotations, homographies).
pub type Mat3 = Matrix3<f64>;

/// Pinhole intrinsics in pixels.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Intrinsics {
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
    /// Focal length along x, pixels.
    pub fx: f64,
    /// Focal length along y, pixels.
    pub fy: f64,
    /// Principal point x, pixels (pixel centres at integers).
    pub cx: f64,
    /// Principal point y, pixels.
    pub cy: f64,
}

impl Intrinsics {
    /// Square-pixel intrinsics with the principal point at the image centre, from a
    /// field of view in degrees measured across the image's *longer* side (a phone's
    /// quoted field of view is the sensor's long side, whichever way the phone is held).
    pub fn from_fov(width: u32, height: u32, fov_deg: f64) -> Result<Self, CoreError> {
        if !(fov_deg > 0.0 && fov_deg < 180.0) {
            return Err(CoreError::invalid(
                "field of view",
                fov_deg,
                "degrees, in the open range (0, 180)",
            ));
        }
        if width == 0 || height == 0 {
            return Err(CoreError::invalid(
                "image size",
                format!("{width}x{height}"),
                "both sides at least 1 pixel",
            ));
        }
        let long = f64::from(width.max(height));
        let f = 0.5 * long / (0.5 * fov_deg.to_radians()).tan();
        Ok(Self {
            width,
            height,
            fx: f,
            fy: f,
            cx: 0.5 * (f64::from(width) - 1.0),
            cy: 0.5 * (f64::from(height) - 1.0),
        })
    }

    /// Pixel to normalised image coordinates (before distortion is removed).
    pub fn pixel_to_normalized(&self, p: Vec2) -> Vec2 {
        Vec2::new((p.x - self.cx) / self.fx, (p.y - self.cy) / self.fy)
    }

    /// Normalised image coordinates to pixel.
    pub fn normalized_to_pixel(&self, q: Vec2) -> Vec2 {
        Vec2::new(q.x * self.fx + self.cx, q.y * self.fy + self.cy)
    }

    /// The same camera with every length in pixels multiplied by `s` (image resized by `s`).
    pub fn scaled(&self, s: f64) -> Self {
        let w = (f64::from(self.width) * s).round().max(1.0) as u32;
        let h = (f64::from(self.height) * s).round().max(1.0) as u32;
        Self {
            width: w,
            height: h,
            fx: self.fx * s,
            fy: self.fy * s,
            cx: (self.cx + 0.5) * s - 0.5,
            cy: (self.cy + 0.5) * s - 0.5,
        }
    }

    /// Whether a pixel position lies inside the image area.
    pub fn contains(&self, p: Vec2) -> bool {
        p.x >= -0.5
            && p.y >= -0.5
            && p.x < f64::from(self.width) - 0.5
            && p.y < f64::from(self.height) - 0.5
    }
}

/// Radial lens distortion of the Brown-Conrady / OpenCV form, in normalised coordinates:
/// `x_d = x_u * (1 + k1 r^2 + k2 r^4)` with `r^2 = x_u^2 + y_u^2`.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct RadialDistortion {
    /// Second-order coefficient (negative: barrel).
    pub k1: f64,
    /// Fourth-order coefficient.
    pub k2: f64,
}

impl RadialDistortion {
    /// Apply distortion to undistorted normalised coordinates.
    pub fn distort(&self, q: Vec2) -> Vec2 {
        let r2 = q.norm_squared();
        q * (1.0 + self.k1 * r2 + self.k2 * r2 * r2)
    }

    /// Remove distortion by Newton iteration on the radius. Converges for the moderate
    /// distortions of phone lenses (|k1| < 0.5 within the image); returns the best
    /// estimate after a fixed number of steps otherwise.
    pub fn undistort(&self, d: Vec2) -> Vec2 {
        let rd = d.norm();
        if rd < 1e-15 || (self.k1 == 0.0 && self.k2 == 0.0) {
            return d;
        }
        let mut r = rd;
        for _ in 0..20 {
            let r2 = r * r;
            let f = r * (1.0 + self.k1 * r2 + self.k2 * r2 * r2) - rd;
            let df = 1.0 + 3.0 * self.k1 * r2 + 5.0 * self.k2 * r2 * r2;
            if df.abs() < 1e-12 {
                break;
            }
            let step = f / df;
            r -= step;
            if step.abs() < 1e-14 {
                break;
            }
        }
        d * (r / rd)
    }
}

/// Undistortion by table lookup on the distorted radius: built once per distortion
/// (per frame), then each pixel costs one interpolation instead of Newton steps.
#[derive(Debug, Clone)]
pub struct UndistortTable {
    step: f64,
    ratio: Vec<f64>,
}

impl UndistortTable {
    /// Table of `undistorted / distorted` radius for distorted radii in [0, r_max].
    pub fn new(d: &RadialDistortion, r_max: f64, entries: usize) -> Self {
        let n = entries.max(2);
        let step = r_max.max(1e-9) / (n - 1) as f64;
        let ratio = (0..n)
            .map(|i| {
                let r = i as f64 * step;
                if r == 0.0 {
                    1.0
                } else {
                    d.undistort(Vec2::new(r, 0.0)).x / r
                }
            })
            .collect();
        Self { step, ratio }
    }

    /// A table covering every pixel of `intr` (normalised radius of the farthest corner).
    pub fn for_image(d: &RadialDistortion, intr: &Intrinsics) -> Self {
        let corners = [
            (-0.5, -0.5),
            (f64::from(intr.width) - 0.5, f64::from(intr.height) - 0.5),
        ];
        let r = corners
            .iter()
            .flat_map(|&(x, _)| corners.iter().map(move |&(_, y)| Vec2::new(x, y)))
            .map(|p| intr.pixel_to_normalized(p).norm())
            .fold(0.0, f64::max);
        Self::new(d, r * 1.05, 4096)
    }

    /// Undistort normalised coordinates.
    #[inline]
    pub fn undistort(&self, q: Vec2) -> Vec2 {
        let r = q.norm();
        let f = r / self.step;
        let i = (f as usize).min(self.ratio.len() - 2);
        let t = (f - i as f64).min(1.0);
        q * (self.ratio[i] + (self.ratio[i + 1] - self.ratio[i]) * t)
    }
}

/// A rigid camera pose: `rotation` maps camera axes to world axes (world_from_camera),
/// `centre` is the camera centre in world coordinates (cm).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Pose {
    /// world_from_camera rotation.
    pub rotation: Mat3,
    /// Camera centre in world coordinates (cm).
    pub centre: Vec3,
}

impl Pose {
    /// A camera at `centre` looking at `target`; `up` is the world direction that should
    /// appear towards the top of the image (camera -y).
    pub fn look_at(centre: Vec3, target: Vec3, up: Vec3) -> Result<Self, CoreError> {
        let z = (target - centre)
            .try_normalize(1e-12)
            .ok_or_else(|| CoreError::Degenerate("look_at: target equals centre".into()))?;
        let x = z
            .cross(&up)
            .try_normalize(1e-12)
            .ok_or_else(|| CoreError::Degenerate("look_at: up is parallel to the view".into()))?;
        let y = z.cross(&x);
        Ok(Self {
            rotation: Mat3::from_columns(&[x, y, z]),
            centre,
        })
    }

    /// Camera coordinates of a world point.
    pub fn world_to_camera(&self, p: Vec3) -> Vec3 {
        self.rotation.transpose() * (p - self.centre)
    }

    /// World direction of a camera-frame direction.
    pub fn camera_dir_to_world(&self, d: Vec3) -> Vec3 {
        self.rotation * d
    }

    /// World position of a point given in camera coordinates (e.g. the flash offset).
    pub fn camera_to_world(&self, p: Vec3) -> Vec3 {
        self.rotation * p + self.centre
    }
}

/// A distorted pinhole camera at a pose.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Camera {
    /// Intrinsics.
    pub intrinsics: Intrinsics,
    /// Radial distortion.
    pub distortion: RadialDistortion,
    /// Pose.
    pub pose: Pose,
}

impl Camera {
    /// Project a world point to pixel coordinates; `None` if it lies behind the camera.
    pub fn project(&self, p: Vec3) -> Option<Vec2> {
        let c = self.pose.world_to_camera(p);
        if c.z <= 1e-9 {
            return None;
        }
        let q = Vec2::new(c.x / c.z, c.y / c.z);
        Some(
            self.intrinsics
                .normalized_to_pixel(self.distortion.distort(q)),
        )
    }

    /// World-space direction (not normalised) of the ray through a pixel.
    pub fn pixel_ray(&self, pixel: Vec2) -> Vec3 {
        let q = self
            .distortion
            .undistort(self.intrinsics.pixel_to_normalized(pixel));
        self.pose.camera_dir_to_world(Vec3::new(q.x, q.y, 1.0))
    }

    /// Where the ray through a pixel meets the plane z = 0; `None` if it points away.
    pub fn pixel_to_plane(&self, pixel: Vec2) -> Option<Vec2> {
        ray_plane(self.pose.centre, self.pixel_ray(pixel))
    }
}

/// Intersection of a ray `origin + t * dir`, t > 0, with the plane z = 0.
pub fn ray_plane(origin: Vec3, dir: Vec3) -> Option<Vec2> {
    if dir.z.abs() < 1e-12 {
        return None;
    }
    let t = -origin.z / dir.z;
    if t <= 0.0 {
        return None;
    }
    Some(Vec2::new(origin.x + t * dir.x, origin.y + t * dir.y))
}

/// Rotation about the x axis by `a` radians.
pub fn rot_x(a: f64) -> Mat3 {
    let (s, c) = a.sin_cos();
    Mat3::new(1.0, 0.0, 0.0, 0.0, c, -s, 0.0, s, c)
}

/// Rotation about the y axis by `a` radians.
pub fn rot_y(a: f64) -> Mat3 {
    let (s, c) = a.sin_cos();
    Mat3::new(c, 0.0, s, 0.0, 1.0, 0.0, -s, 0.0, c)
}

/// Rotation about the z axis by `a` radians.
pub fn rot_z(a: f64) -> Mat3 {
    let (s, c) = a.sin_cos();
    Mat3::new(c, -s, 0.0, s, c, 0.0, 0.0, 0.0, 1.0)
}

/// Centroid of 2-D points and their scatter about it, `(centroid, [sxx, sxy, syy])`
/// (sums of products of the centred coordinates). `None` for no points.
pub fn centroid_scatter(pts: &[Vec2]) -> Option<(Vec2, [f64; 3])> {
    if pts.is_empty() {
        return None;
    }
    let c = pts.iter().fold(Vec2::zeros(), |a, p| a + p) / pts.len() as f64;
    let mut s = [0.0; 3];
    for p in pts {
        let q = p - c;
        s[0] += q.x * q.x;
        s[1] += q.x * q.y;
        s[2] += q.y * q.y;
    }
    Some((c, s))
}

/// Row-major array form of a 3x3 matrix, as written in our JSON files.
pub fn mat3_to_rows(m: &Mat3) -> [[f64; 3]; 3] {
    [
        [m[(0, 0)], m[(0, 1)], m[(0, 2)]],
        [m[(1, 0)], m[(1, 1)], m[(1, 2)]],
        [m[(2, 0)], m[(2, 1)], m[(2, 2)]],
    ]
}

/// Inverse of [`mat3_to_rows`].
pub fn mat3_from_rows(r: &[[f64; 3]; 3]) -> Mat3 {
    Mat3::new(
        r[0][0], r[0][1], r[0][2], r[1][0], r[1][1], r[1][2], r[2][0], r[2][1], r[2][2],
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn camera(k1: f64, k2: f64, cx: f64, cy: f64, h: f64, tilt: f64) -> Camera {
        let intr = Intrinsics::from_fov(640, 480, 70.0).unwrap();
        let pose = Pose::look_at(
            Vec3::new(cx, cy, h),
            Vec3::new(cx + tilt, cy - tilt, 0.0),
            Vec3::new(0.0, 1.0, 0.0),
        )
        .unwrap();
        Camera {
            intrinsics: intr,
            distortion: RadialDistortion { k1, k2 },
            pose,
        }
    }

    #[test]
    fn undistort_table_matches_newton() {
        let d = RadialDistortion {
            k1: -0.08,
            k2: 0.02,
        };
        let intr = Intrinsics::from_fov(270, 480, 70.0).unwrap();
        let t = UndistortTable::for_image(&d, &intr);
        for &(u, v) in &[(0.0, 0.0), (269.0, 479.0), (135.0, 10.0), (3.0, 300.0)] {
            let q = intr.pixel_to_normalized(Vec2::new(u, v));
            assert!((t.undistort(q) - d.undistort(q)).norm() < 1e-7);
        }
    }

    #[test]
    fn fov_uses_long_side() {
        let a = Intrinsics::from_fov(2160, 3840, 70.0).unwrap();
        let b = Intrinsics::from_fov(3840, 2160, 70.0).unwrap();
        assert!((a.fx - b.fx).abs() < 1e-9);
        assert!((a.fx - 1920.0 / 35f64.to_radians().tan()).abs() < 1e-9);
        assert!(Intrinsics::from_fov(10, 10, 180.0).is_err());
        assert!(Intrinsics::from_fov(10, 10, 0.0).is_err());
    }

    #[test]
    fn look_down_keeps_world_y_at_image_top() {
        let cam = camera(0.0, 0.0, 0.0, 0.0, 20.0, 0.0);
        let top = cam.project(Vec3::new(0.0, 1.0, 0.0)).unwrap();
        let right = cam.project(Vec3::new(1.0, 0.0, 0.0)).unwrap();
        assert!(top.y < cam.intrinsics.cy);
        assert!(right.x > cam.intrinsics.cx);
    }

    proptest! {
        #[test]
        fn distortion_round_trip(k1 in -0.3f64..0.1, k2 in -0.05f64..0.05, x in -0.7f64..0.7, y in -0.5f64..0.5) {
            let d = RadialDistortion { k1, k2 };
            let q = Vec2::new(x, y);
            let back = d.undistort(d.distort(q));
            prop_assert!((back - q).norm() < 1e-9);
        }

        #[test]
        fn project_unproject_round_trip(
            k1 in -0.2f64..0.05, cx in -5.0f64..5.0, cy in -5.0f64..5.0,
            h in 8.0f64..30.0, tilt in -3.0f64..3.0, u in 0.0f64..639.0, v in 0.0f64..479.0,
        ) {
            let cam = camera(k1, 0.01, cx, cy, h, tilt);
            let p = Vec2::new(u, v);
            let on_plane = cam.pixel_to_plane(p).unwrap();
            let back = cam.project(Vec3::new(on_plane.x, on_plane.y, 0.0)).unwrap();
            prop_assert!((back - p).norm() < 1e-6, "{:?} -> {:?}", p, back);
        }
    }
}
