//! Unit tests of the relief shift.

use super::*;

#[test]
fn the_basis_interpolates_and_holds_beyond_the_last_knot() {
    assert_eq!(basis(0.0), [0.0; K]);
    let b = basis(0.05);
    assert!((b[0] - 0.5).abs() < 1e-12 && b[1..].iter().all(|v| *v == 0.0));
    let b = basis(0.25);
    assert!((b[1] - 0.5).abs() < 1e-12 && (b[2] - 0.5).abs() < 1e-12);
    assert_eq!(basis(2.0)[K - 1], 1.0);
    for t in [0.03, 0.17, 0.44, 0.79] {
        assert!((basis(t).iter().sum::<f64>() - if t < 0.1 { t / 0.1 } else { 1.0 }).abs() < 1e-12);
    }
}

/// A camera looking straight down from `c` (cm), turned by `yaw` about the
/// vertical and tilted by `tilt` about its x axis: world point to pixel in focal
/// lengths, distorted by `k1`.
struct Cam {
    c: Vec3,
    r: nalgebra::Matrix3<f64>,
    k1: f64,
}

impl Cam {
    fn new(c: Vec3, yaw: f64, tilt: f64, k1: f64) -> Self {
        let down = nalgebra::Matrix3::new(1.0, 0.0, 0.0, 0.0, -1.0, 0.0, 0.0, 0.0, -1.0);
        let r = nalgebra::Rotation3::from_axis_angle(&Vec3::x_axis(), tilt).into_inner()
            * down
            * nalgebra::Rotation3::from_axis_angle(&Vec3::z_axis(), yaw).into_inner();
        Self { c, r, k1 }
    }

    fn pixel(&self, x: Vec2) -> Option<Vec2> {
        let p = self.r * (Vec3::new(x.x, x.y, 0.0) - self.c);
        let q = Vec2::new(p.x / p.z, p.y / p.z);
        (p.z > 0.0 && q.norm() < 0.65).then(|| q * (1.0 + self.k1 * q.norm_squared()))
    }

    fn light(&self) -> Vec3 {
        self.c + self.r.transpose() * Vec3::new(1.4, -0.3, 0.0)
    }
}

/// Apparent shift at each knot (cm): 30-120 um.
const TRUTH: [f64; K] = [0.006, 0.010, 0.012, 0.010, 0.007, 0.005, 0.004, 0.003];
const K1: f64 = -0.04;

/// The rigid model fitted to 12 frames of 400 plane points whose texture is shifted
/// by [`TRUTH`] towards the foot of the centre `truth_w` between lens and flash, and
/// to 4 flat markers.
fn fit_sweep(truth_w: f64) -> (ReliefSummary, [f64; K]) {
    let truth = TRUTH;
    let k1 = K1;
    let cams: Vec<Cam> = (0..12)
        .map(|i| {
            let a = f64::from(i) * 0.55;
            Cam::new(
                Vec3::new(2.5 * a.cos(), 2.5 * a.sin(), 10.0 + 0.45 * f64::from(i)),
                0.3 * f64::from(i),
                0.04 * (a * 1.3).sin(),
                k1,
            )
        })
        .collect();
    // A low-discrepancy spread of plane points over 12 x 12 cm.
    let points: Vec<Vec2> = (0..400)
        .map(|i| {
            let i = f64::from(i);
            Vec2::new(
                12.0 * ((i * 0.618_034) % 1.0) - 6.0,
                12.0 * ((i * 0.754_878) % 1.0) - 6.0,
            )
        })
        .collect();
    // Where frame `f` shows plane point `x` (its texture moved by the curve, or not
    // for flat print), as a side of a constraint.
    let side = |f: usize, x: Vec2, texture: bool| -> Option<(Side, Vec2)> {
        let light = cams[f].light();
        let shown = if texture {
            x + shift_at(&truth, centre(light, cams[f].c, truth_w), x)
        } else {
            x
        };
        let xn = cams[f].pixel(shown)?;
        Some((Side::new(f, xn, x, light, cams[f].c, texture), shown))
    };
    let mut obs = Vec::new();
    let mut own: Vec<(Vec<Vec2>, Vec<Vec2>)> = vec![(Vec::new(), Vec::new()); cams.len()];
    for x in &points {
        let seen: Vec<(Side, Vec2)> = (0..cams.len()).filter_map(|f| side(f, *x, true)).collect();
        for (s, y) in &seen {
            own[s.slot].0.push(s.xn);
            own[s.slot].1.push(*y);
        }
        for w in seen.windows(2) {
            obs.push(Obs::Pair(w[0].0, w[1].0));
        }
        if let Some((s, _)) = seen.first() {
            obs.push(Obs::Anchor(*s, *x, 1.0));
        }
    }
    // Four markers' corners, flat, seen by the frames that see them.
    let mut corners = 0;
    for m in [
        Vec2::new(-6.5, -6.5),
        Vec2::new(6.5, -6.5),
        Vec2::new(-6.5, 6.5),
        Vec2::new(6.5, 6.5),
    ] {
        for d in [
            Vec2::new(0.0, 0.0),
            Vec2::new(0.8, 0.0),
            Vec2::new(0.0, 0.8),
            Vec2::new(0.8, 0.8),
        ] {
            for f in 0..cams.len() {
                if let Some((s, _)) = side(f, m + d, false) {
                    obs.push(Obs::Anchor(s, m + d, 4.0));
                    corners += 1;
                }
            }
        }
    }
    assert!(corners >= 8, "{corners} marker corners in view");
    // Start: each frame's own points fitted by one homography (distortion and
    // shift left in).
    let frames: Vec<[f64; 8]> = own
        .iter()
        .map(|(src, dst)| to_params(&Homography::from_correspondences(src, dst).unwrap().0))
        .collect();
    let mut summary = ReliefSummary::default();
    let curve = solve_model(frames, &obs, 0.01, &mut summary).unwrap();
    (summary, curve)
}

fn assert_found(summary: &ReliefSummary, curve: &[f64; K], truth_w: f64) {
    assert_eq!(summary.centre_weight, truth_w, "{summary:?}");
    assert!((summary.lens[0] + K1).abs() < 0.004, "{:?}", summary.lens);
    for k in 0..6 {
        assert!(
            (curve[k] - TRUTH[k]).abs() < 0.0012,
            "knot {k}: {} um against {} um ({:?})",
            1e4 * curve[k],
            1e4 * TRUTH[k],
            summary.shift_um
        );
    }
    assert!(summary.gain > 0.5 && summary.applied, "{summary:?}");
}

#[test]
fn the_rigid_model_finds_the_shift_and_the_lens_together() {
    let (summary, curve) = fit_sweep(1.0);
    assert_found(&summary, &curve, 1.0);
}

#[test]
fn the_rigid_model_finds_a_shift_pointing_between_lens_and_flash() {
    // Half way (glossy bumps) and at the lens itself.
    for w in [0.5, 0.0] {
        let (summary, curve) = fit_sweep(w);
        assert_found(&summary, &curve, w);
    }
}

#[test]
fn a_shift_too_few_markers_can_correct_is_a_doubt_and_only_then() {
    let seen = ReliefSummary {
        gain: 0.027,
        marker_corners: 4,
        note: Some("4 marker corners".into()),
        ..Default::default()
    };
    assert!(seen.doubt().is_some_and(|d| d.contains("4 marker corners")));
    // Too small a share, or corrected: no doubt.
    let small = ReliefSummary {
        gain: 0.005,
        ..seen.clone()
    };
    assert!(small.doubt().is_none());
    let corrected = ReliefSummary {
        applied: true,
        note: None,
        marker_corners: 24,
        ..seen
    };
    assert!(corrected.doubt().is_none());
}

#[test]
fn the_shift_points_at_the_lights_foot() {
    let mut c = [0.0; K];
    c[2] = 0.005;
    // Light 10 cm above (0, 0); point 3 cm away: tangent 0.3, shift 50 um towards it.
    let s = shift_at(&c, Vec3::new(0.0, 0.0, 10.0), Vec2::new(3.0, 0.0));
    assert!((s.x + 0.005).abs() < 1e-12 && s.y.abs() < 1e-12);
}
