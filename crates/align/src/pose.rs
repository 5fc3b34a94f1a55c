//! Camera pose from a plane-to-image homography (section 3.1.6): with known
//! intrinsics, `K^-1 H = lambda [r1 r2 t]`; the nearest rotation to `[r1 r2 r1 x r2]`
//! and the translation give the camera centre in world coordinates.

use svbrdf_core::geometry::{Intrinsics, Mat3, Pose, Vec3};

/// Decompose a homography from plane coordinates to pixels: `K^-1 H = lambda [r1 r2 t]`.
/// Returns the camera_from_plane rotation (the nearest rotation to `[r1 r2 r1 x r2]`)
/// and the plane origin in camera coordinates, with the plane in front of the camera.
pub fn decompose(k: &Intrinsics, pixel_from_plane: &Mat3) -> Option<(Mat3, Vec3)> {
    let kinv = Mat3::new(
        1.0 / k.fx,
        0.0,
        -k.cx / k.fx,
        0.0,
        1.0 / k.fy,
        -k.cy / k.fy,
        0.0,
        0.0,
        1.0,
    );
    let m = kinv * pixel_from_plane;
    let (c1, c2, c3) = (
        m.column(0).into_owned(),
        m.column(1).into_owned(),
        m.column(2).into_owned(),
    );
    let mut lambda = 2.0 / (c1.norm() + c2.norm());
    if !lambda.is_finite() {
        return None;
    }
    if c3.z * lambda < 0.0 {
        lambda = -lambda;
    }
    let (r1, r2, t) = (c1 * lambda, c2 * lambda, c3 * lambda);
    let approx = Mat3::from_columns(&[r1, r2, r1.cross(&r2)]);
    let svd = approx.svd(true, true);
    let mut r = svd.u? * svd.v_t?;
    if r.determinant() < 0.0 {
        r = -r;
    }
    Some((r, t))
}

/// Pose of a camera whose `pixel_from_plane` homography maps plane cm to pixels.
pub fn pose_from_homography(k: &Intrinsics, pixel_from_plane: &Mat3) -> Option<Pose> {
    let (r, t) = decompose(k, pixel_from_plane)?;
    // r is camera_from_world; the centre is -R^T t.
    let centre: Vec3 = -(r.transpose() * t);
    if !(centre.z > 0.0) {
        return None;
    }
    Some(Pose {
        rotation: r.transpose(),
        centre,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use svbrdf_core::geometry::{Camera, RadialDistortion, Vec2};
    use svbrdf_core::homography::Homography;

    #[test]
    fn recovers_pose() {
        let k = Intrinsics::from_fov(640, 480, 70.0).unwrap();
        let pose = Pose::look_at(
            Vec3::new(2.0, -1.0, 14.0),
            Vec3::new(2.5, -0.5, 0.0),
            Vec3::y(),
        )
        .unwrap();
        let cam = Camera {
            intrinsics: k,
            distortion: RadialDistortion::default(),
            pose,
        };
        let plane: Vec<Vec2> = [
            (-3.0, -3.0),
            (6.0, -2.0),
            (5.0, 4.0),
            (-2.0, 5.0),
            (1.0, 1.0),
        ]
        .iter()
        .map(|&(x, y)| Vec2::new(x, y))
        .collect();
        let px: Vec<Vec2> = plane
            .iter()
            .map(|p| cam.project(Vec3::new(p.x, p.y, 0.0)).unwrap())
            .collect();
        let h = Homography::from_correspondences(&plane, &px).unwrap();
        let est = pose_from_homography(&k, &h.0).unwrap();
        assert!((est.centre - pose.centre).norm() < 1e-6, "{:?}", est.centre);
        assert!((est.rotation - pose.rotation).norm() < 1e-6);
    }
}
