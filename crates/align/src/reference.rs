//! The world frame from the reference photo (paper 3.1.1 and 3.1.6).
//!
//! The world origin is the plane point on the reference camera's optical axis; +z is
//! the plane normal towards the camera; +x is the image's x axis projected onto the
//! plane. Beyond the paper, the plane's tilt relative to the sensor is estimated from
//! each marker's own pose (a homography from the known marker square, decomposed with
//! the intrinsics), so a photo that is not perfectly levelled still gives the right
//! frame; its height comes from the marker size and the field of view.

use svbrdf_core::geometry::{Intrinsics, Mat3, Pose, Vec2, Vec3};
use svbrdf_core::homography::Homography;
use svbrdf_core::plane::Region;

use crate::AlignError;

/// A marker seen in an image: id and four corners in pixels (OpenCV order: the
/// marker's top-left, top-right, bottom-right, bottom-left).
#[derive(Debug, Clone, PartialEq)]
pub struct MarkerObservation {
    /// Marker id.
    pub id: i32,
    /// Corner pixels.
    pub corners: [Vec2; 4],
}

/// What the reference photo fixes.
#[derive(Debug, Clone)]
pub struct ReferenceFrame {
    /// The reference camera in world coordinates.
    pub pose: Pose,
    /// Its intrinsics.
    pub intrinsics: Intrinsics,
    /// Reference image pixel -> plane (cm).
    pub plane_from_pixel: Homography,
    /// Marker corners on the plane (cm), per id, OpenCV order.
    pub markers: Vec<(i32, [Vec2; 4])>,
    /// Tilt of the reference camera away from looking straight down, radians.
    pub tilt: f64,
    /// Height of the reference camera above the plane, cm.
    pub height: f64,
    /// Where the world axes come from: `markers` (origin at the centre of the four
    /// markers' inner corners, +x from the pair of ids 0 and 3 towards ids 1 and 2) or
    /// `reference photo` (the paper's: origin under the photo's centre, its axes), used
    /// when the markers are not laid out as the capture kit says.
    pub axes: String,
}

impl ReferenceFrame {
    /// The rectangle bounded by the markers' inner corners (the corner of each marker
    /// closest to the centre of all four).
    pub fn marker_region(&self) -> Region {
        let all: Vec<Vec2> = self
            .markers
            .iter()
            .flat_map(|(_, c)| c.iter().copied())
            .collect();
        let centre = all.iter().fold(Vec2::zeros(), |a, p| a + p) / all.len().max(1) as f64;
        let inner: Vec<Vec2> = self
            .markers
            .iter()
            .filter_map(|(_, c)| {
                c.iter()
                    .copied()
                    .min_by(|a, b| (a - centre).norm().total_cmp(&(b - centre).norm()))
            })
            .collect();
        let fold = |f: fn(f64, f64) -> f64, init: f64, get: fn(&Vec2) -> f64| {
            inner.iter().map(get).fold(init, f)
        };
        Region {
            x_min: fold(f64::min, f64::MAX, |p| p.x),
            x_max: fold(f64::max, f64::MIN, |p| p.x),
            y_min: fold(f64::min, f64::MAX, |p| p.y),
            y_max: fold(f64::max, f64::MIN, |p| p.y),
        }
    }
}

/// Pose of a square marker of side `size` (cm) in camera coordinates: rotation with
/// columns (marker x, marker y, normal towards the camera) and the marker's
/// bottom-left corner position. `None` if degenerate.
pub fn marker_pose(k: &Intrinsics, corners: &[Vec2; 4], size: f64) -> Option<(Mat3, Vec3)> {
    // Marker-local coordinates, y up: TL, TR, BR, BL.
    let local = [
        Vec2::new(0.0, size),
        Vec2::new(size, size),
        Vec2::new(size, 0.0),
        Vec2::new(0.0, 0.0),
    ];
    let h = Homography::from_correspondences(&local, corners).ok()?;
    crate::pose::decompose(k, &h.0)
}

/// Joint plane from all markers: every marker, back-projected onto the plane `n.X + d
/// = 0`, must be a square of side `size`. Markers spread across the photo constrain
/// the tilt far better than any single marker's pose (whose normal is uncertain to
/// several tenths of a degree), so this refines the averaged single-marker estimate
/// by Gauss-Newton on the plane's two tilt angles and distance.
fn refine_plane(
    k: &Intrinsics,
    found: &[MarkerObservation],
    size: f64,
    n0: Vec3,
    d0: f64,
) -> (Vec3, f64) {
    let rays: Vec<[Vec3; 4]> = found
        .iter()
        .map(|m| {
            m.corners
                .map(|c| Vec3::new((c.x - k.cx) / k.fx, (c.y - k.cy) / k.fy, 1.0))
        })
        .collect();
    let normal = |p: &[f64; 3]| Vec3::new(p[0], p[1], -1.0).normalize();
    let residuals = |p: &[f64; 3]| -> Vec<f64> {
        let n = normal(p);
        let d = p[2];
        let mut r = Vec::with_capacity(rays.len() * 6);
        for ray in &rays {
            let pts = ray.map(|v| v * (-d / n.dot(&v)));
            for (a, b, len) in [
                (0, 1, size),
                (1, 2, size),
                (2, 3, size),
                (3, 0, size),
                (0, 2, size * std::f64::consts::SQRT_2),
                (1, 3, size * std::f64::consts::SQRT_2),
            ] {
                r.push((pts[a] - pts[b]).norm() - len);
            }
        }
        r
    };
    // Parameters: the normal's x and y slopes (n ~ (a, b, -1)) and the distance.
    let mut p = [n0.x / -n0.z, n0.y / -n0.z, d0];
    for _ in 0..15 {
        let r0 = residuals(&p);
        let mut jt = [
            vec![0.0; r0.len()],
            vec![0.0; r0.len()],
            vec![0.0; r0.len()],
        ];
        for (i, row) in jt.iter_mut().enumerate() {
            let h = if i < 2 {
                1e-7
            } else {
                1e-6 * p[2].abs().max(1.0)
            };
            let mut q = p;
            q[i] += h;
            for (j, v) in residuals(&q).iter().enumerate() {
                row[j] = (v - r0[j]) / h;
            }
        }
        let mut a = Mat3::zeros();
        let mut g = Vec3::zeros();
        for i in 0..3 {
            for j in 0..3 {
                a[(i, j)] = jt[i].iter().zip(&jt[j]).map(|(x, y)| x * y).sum();
            }
            g[i] = jt[i].iter().zip(&r0).map(|(x, y)| x * y).sum();
        }
        let Some(step) = a.try_inverse().map(|inv| inv * g) else {
            break;
        };
        p = [p[0] - step.x, p[1] - step.y, p[2] - step.z];
        if step.norm() < 1e-12 {
            break;
        }
    }
    if p.iter().all(|v| v.is_finite()) && p[2] > 0.0 {
        (normal(&p), p[2])
    } else {
        (n0, d0)
    }
}

/// Build the world frame from the markers found in the reference photo.
pub fn reference_frame(
    k: &Intrinsics,
    found: &[MarkerObservation],
    marker_size: f64,
    expected: usize,
) -> Result<ReferenceFrame, AlignError> {
    let mut ids: Vec<i32> = found.iter().map(|m| m.id).collect();
    ids.sort_unstable();
    ids.dedup();
    if ids.len() < expected || found.len() != ids.len() {
        return Err(AlignError::Markers(format!(
            "the reference photo must show {expected} distinct markers; found ids {:?}",
            found.iter().map(|m| m.id).collect::<Vec<_>>()
        )));
    }
    // Plane normal and distance in camera coordinates, averaged over markers weighted
    // by their size in the image (larger markers give steadier poses).
    let mut n_sum = Vec3::zeros();
    let mut d_sum = 0.0;
    let mut w_sum = 0.0;
    for m in found {
        let (r, t) = marker_pose(k, &m.corners, marker_size).ok_or_else(|| {
            AlignError::Markers(format!(
                "marker {} in the reference photo is degenerate",
                m.id
            ))
        })?;
        let n = r.column(2).into_owned();
        let w = (m.corners[0] - m.corners[2]).norm();
        n_sum += n * w;
        d_sum += -n.dot(&t) * w;
        w_sum += w;
    }
    let (n, d) = refine_plane(k, found, marker_size, n_sum.normalize(), d_sum / w_sum);
    if !(d > 0.0) || n.z >= -0.2 {
        return Err(AlignError::Markers(format!(
            "the markers in the reference photo give an implausible plane (distance {d:.2} cm, normal {:.2} {:.2} {:.2})",
            n.x, n.y, n.z
        )));
    }
    // Origin: the plane point on the optical axis.
    let s = -d / n.z;
    let origin = Vec3::new(0.0, 0.0, s);
    let x = Vec3::new(1.0, 0.0, 0.0);
    let ex = (x - n * n.dot(&x)).normalize();
    let ey = n.cross(&ex);
    // camera_from_world rotation has columns ex, ey, n.
    let c_from_w = Mat3::from_columns(&[ex, ey, n]);
    let w_from_c = c_from_w.transpose();
    let centre = w_from_c * (-origin);
    let kmat = Mat3::new(k.fx, 0.0, k.cx, 0.0, k.fy, k.cy, 0.0, 0.0, 1.0);
    let pixel_from_plane = Homography(kmat * Mat3::from_columns(&[ex, ey, origin])).normalized();
    let plane_from_pixel = pixel_from_plane
        .inverse()
        .ok_or_else(|| AlignError::Markers("reference plane homography is singular".into()))?;
    let mut markers = Vec::new();
    for m in found {
        let c = m
            .corners
            .map(|p| plane_from_pixel.apply(p).unwrap_or_else(Vec2::zeros));
        markers.push((m.id, c));
    }
    markers.sort_by_key(|m| m.0);
    // Move the world frame onto the markers, so that it does not depend on where the
    // reference photo was taken from or how it was rolled.
    let (to_markers, axes) = match marker_axes(&markers) {
        Some(t) => (t, "markers"),
        None => ((Vec2::zeros(), Vec2::new(1.0, 0.0)), "reference photo"),
    };
    let (o, ex2) = to_markers;
    let ey2 = Vec2::new(-ex2.y, ex2.x);
    // world' = Rz (world - o): rows of Rz are the new axes in the old frame.
    let rz = Mat3::new(ex2.x, ex2.y, 0.0, ey2.x, ey2.y, 0.0, 0.0, 0.0, 1.0);
    let a = Homography(Mat3::new(
        ex2.x,
        ex2.y,
        -ex2.dot(&o),
        ey2.x,
        ey2.y,
        -ey2.dot(&o),
        0.0,
        0.0,
        1.0,
    ));
    let plane_from_pixel = Homography(a.0 * plane_from_pixel.0).normalized();
    let to_new = |p: Vec2| {
        let d = p - o;
        Vec2::new(ex2.dot(&d), ey2.dot(&d))
    };
    for (_, c) in &mut markers {
        *c = c.map(to_new);
    }
    let centre = rz * (centre - Vec3::new(o.x, o.y, 0.0));
    Ok(ReferenceFrame {
        pose: Pose {
            rotation: rz * w_from_c,
            centre,
        },
        intrinsics: *k,
        plane_from_pixel,
        markers,
        tilt: (-n.z).clamp(-1.0, 1.0).acos(),
        height: centre.z,
        axes: axes.into(),
    })
}

/// The world origin and +x axis (in the photo's plane frame) defined by four markers
/// laid out as the capture kit says (ids in increasing order at the top-left,
/// top-right, bottom-right and bottom-left): origin at the centre of their inner
/// corners, +x from the left pair towards the right pair. `None` when there are not
/// four markers or the layout is not that one (the +y axis it implies, from the
/// bottom pair to the top pair, is more than 25 degrees off).
fn marker_axes(markers: &[(i32, [Vec2; 4])]) -> Option<(Vec2, Vec2)> {
    if markers.len() != 4 {
        return None;
    }
    let centre = |c: &[Vec2; 4]| c.iter().fold(Vec2::zeros(), |a, p| a + p) / 4.0;
    let m: Vec<Vec2> = markers.iter().map(|(_, c)| centre(c)).collect();
    let all = m.iter().fold(Vec2::zeros(), |a, p| a + p) / 4.0;
    let ex = ((m[1] + m[2]) - (m[0] + m[3])).try_normalize(1e-9)?;
    let up = ((m[0] + m[1]) - (m[3] + m[2])).try_normalize(1e-9)?;
    let ey = Vec2::new(-ex.y, ex.x);
    if ey.dot(&up) < 25f64.to_radians().cos() {
        return None;
    }
    // Each marker's inner corner: its corner nearest the centre of all four.
    let inner = markers.iter().map(|(_, c)| {
        *c.iter()
            .min_by(|a, b| (*a - all).norm().total_cmp(&(*b - all).norm()))
            .unwrap_or(&all)
    });
    let origin = inner.fold(Vec2::zeros(), |a, p| a + p) / 4.0;
    Some((origin, ex))
}

#[cfg(test)]
mod tests {
    use super::*;
    use svbrdf_core::geometry::{rot_x, Camera, RadialDistortion};

    fn observe(cam: &Camera, corners: &[[f64; 3]; 4], id: i32) -> MarkerObservation {
        MarkerObservation {
            id,
            corners: corners.map(|c| cam.project(Vec3::from(c)).unwrap()),
        }
    }

    fn square(x0: f64, y1: f64, s: f64) -> [[f64; 3]; 4] {
        [
            [x0, y1, 0.0],
            [x0 + s, y1, 0.0],
            [x0 + s, y1 - s, 0.0],
            [x0, y1 - s, 0.0],
        ]
    }

    #[test]
    fn recovers_world_frame_from_tilted_photo() {
        for tilt_deg in [0.0f64, 4.0, -7.0] {
            let k = Intrinsics::from_fov(720, 1280, 70.0).unwrap();
            let down = Mat3::new(1.0, 0.0, 0.0, 0.0, -1.0, 0.0, 0.0, 0.0, -1.0);
            // Tilted about x: the optical axis no longer hits the origin exactly, so
            // compare geometry that is frame-independent: distances between markers
            // and marker size, plus the plane position of the principal point.
            let cam = Camera {
                intrinsics: k,
                distortion: RadialDistortion::default(),
                pose: Pose {
                    rotation: rot_x(tilt_deg.to_radians()) * down,
                    centre: Vec3::new(0.0, 0.0, 20.0),
                },
            };
            let s = 1.6;
            let truth = [
                square(-5.6, 5.6, s),
                square(4.0, 5.6, s),
                square(4.0, -4.0, s),
                square(-5.6, -4.0, s),
            ];
            let found: Vec<_> = truth
                .iter()
                .enumerate()
                .map(|(i, c)| observe(&cam, c, i as i32))
                .collect();
            let rf = reference_frame(&k, &found, s, 4).unwrap();
            assert!(
                (rf.tilt.to_degrees() - tilt_deg.abs()).abs() < 0.05,
                "tilt {}",
                rf.tilt.to_degrees()
            );
            // Marker side lengths and the distance between marker 0 and 2 in cm.
            for (_, c) in &rf.markers {
                assert!(((c[0] - c[1]).norm() - s).abs() < 1e-3);
            }
            let d = (rf.markers[0].1[0] - rf.markers[2].1[2]).norm();
            let dt = (Vec2::new(-5.6, 5.6) - Vec2::new(5.6, -5.6)).norm();
            assert!((d - dt).abs() < 2e-3, "{d} vs {dt}");
            // The world frame is the markers', so the camera is where it was placed.
            assert!((rf.pose.centre - cam.pose.centre).norm() < 1e-2);
            if tilt_deg == 0.0 {
                // Untilted: world frame equals the simulator's.
                assert!((rf.markers[0].1[0] - Vec2::new(-5.6, 5.6)).norm() < 1e-3);
                let r = rf.marker_region();
                assert!((r.x_min + 4.0).abs() < 1e-3 && (r.y_max - 4.0).abs() < 1e-3);
            }
        }
    }

    #[test]
    fn world_frame_follows_the_markers_not_the_photo() {
        let k = Intrinsics::from_fov(720, 1280, 70.0).unwrap();
        let down = Mat3::new(1.0, 0.0, 0.0, 0.0, -1.0, 0.0, 0.0, 0.0, -1.0);
        let s = 1.6;
        let truth = [
            square(-5.6, 5.6, s),
            square(4.0, 5.6, s),
            square(4.0, -4.0, s),
            square(-5.6, -4.0, s),
        ];
        // Off-centre, rolled 10 degrees and tilted 4: the world frame is still the
        // markers' (the simulator's).
        let cam = Camera {
            intrinsics: k,
            distortion: RadialDistortion::default(),
            pose: Pose {
                rotation: svbrdf_core::geometry::rot_z(10f64.to_radians())
                    * rot_x(4f64.to_radians())
                    * down,
                centre: Vec3::new(1.5, -0.8, 22.0),
            },
        };
        let found: Vec<_> = truth
            .iter()
            .enumerate()
            .map(|(i, c)| observe(&cam, c, i as i32))
            .collect();
        let rf = reference_frame(&k, &found, s, 4).unwrap();
        assert_eq!(rf.axes, "markers");
        for (id, c) in &rf.markers {
            for (p, t) in c.iter().zip(&truth[*id as usize]) {
                assert!(
                    (p - Vec2::new(t[0], t[1])).norm() < 2e-3,
                    "{id}: {p} vs {t:?}"
                );
            }
        }
        assert!(
            (rf.pose.centre - cam.pose.centre).norm() < 0.02,
            "{}",
            rf.pose.centre
        );
        assert!((rf.pose.rotation - cam.pose.rotation).norm() < 1e-3);
        // Markers not in the kit's layout (ids 1 and 3 swapped): the photo's axes.
        let mut swapped = found.clone();
        swapped[1].id = 3;
        swapped[3].id = 1;
        let rf = reference_frame(&k, &swapped, s, 4).unwrap();
        assert_eq!(rf.axes, "reference photo");
    }

    #[test]
    fn too_few_markers_names_ids() {
        let k = Intrinsics::from_fov(720, 1280, 70.0).unwrap();
        let m = MarkerObservation {
            id: 7,
            corners: [
                Vec2::new(0.0, 0.0),
                Vec2::new(10.0, 0.0),
                Vec2::new(10.0, 10.0),
                Vec2::new(0.0, 10.0),
            ],
        };
        let e = reference_frame(&k, &[m], 1.6, 4).unwrap_err().to_string();
        assert!(e.contains("[7]"), "{e}");
    }
}
