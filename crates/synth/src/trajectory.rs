//! Hand-held camera motion: a sinusoidal side-to-side and top-to-bottom sweep with
//! smooth hand jitter, as the paper's users film.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use svbrdf_core::geometry::{rot_x, rot_y, rot_z, Mat3, Pose, Vec3};

use crate::config::{SweepSpec, VideoSpec};

/// A smooth random signal: a sum of sinusoids with random frequencies and phases,
/// unit standard deviation.
#[derive(Debug, Clone)]
struct Wobble {
    terms: Vec<(f64, f64, f64)>,
}

impl Wobble {
    fn new(rng: &mut ChaCha8Rng, f_lo: f64, f_hi: f64) -> Self {
        let n = 3;
        let amp = (2.0 / n as f64).sqrt();
        let terms = (0..n)
            .map(|_| {
                (
                    amp,
                    rng.random_range(f_lo..f_hi),
                    rng.random_range(0.0..std::f64::consts::TAU),
                )
            })
            .collect();
        Self { terms }
    }

    fn at(&self, t: f64) -> f64 {
        self.terms
            .iter()
            .map(|(a, f, p)| a * (std::f64::consts::TAU * f * t + p).sin())
            .sum()
    }
}

/// The flash camera's path over time.
#[derive(Debug, Clone)]
pub struct Sweep {
    half_w: f64,
    half_h: f64,
    spec: SweepSpec,
    duration: f64,
    phase: f64,
    jitter: [Wobble; 6],
    breathing: Wobble,
    base_k1: f64,
    breath_amp: f64,
}

/// Per-frame camera state.
#[derive(Debug, Clone, Copy)]
pub struct CameraState {
    /// Pose.
    pub pose: Pose,
    /// Focal length multiplier (focus breathing).
    pub focal_scale: f64,
    /// Radial k1 at this moment.
    pub k1: f64,
}

impl Sweep {
    /// A sweep over a region of half-size (`half_w`, `half_h`) cm, deterministic in `seed`.
    pub fn new(spec: &SweepSpec, video: &VideoSpec, half_w: f64, half_h: f64, seed: u64) -> Self {
        let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x5EED_5EEB);
        let jitter = [
            Wobble::new(&mut rng, 0.3, 1.5),
            Wobble::new(&mut rng, 0.3, 1.5),
            Wobble::new(&mut rng, 0.2, 1.0),
            Wobble::new(&mut rng, 0.2, 1.0),
            Wobble::new(&mut rng, 0.1, 0.5),
            Wobble::new(&mut rng, 0.5, 2.0),
        ];
        Self {
            half_w: half_w * spec.reach,
            half_h: half_h * spec.reach,
            spec: spec.clone(),
            duration: video.duration_s,
            phase: rng.random_range(0.0..1.0),
            jitter,
            breathing: Wobble::new(&mut rng, 0.5, 3.0),
            base_k1: if video.k1_spread > 0.0 {
                video.k1 + video.k1_spread * (2.0 * rng.random_range(0.0..1.0) - 1.0)
            } else {
                video.k1
            },
            breath_amp: video.breathing,
        }
    }

    /// Camera state at time `t` seconds.
    pub fn at(&self, t: f64) -> CameraState {
        use std::f64::consts::{PI, TAU};
        let s = &self.spec;
        let u = t / self.duration;
        let x = self.half_w * (TAU * s.side_cycles * u + self.phase * TAU).sin()
            + 0.3 * self.jitter[0].at(t);
        let y = self.half_h * (PI * s.vertical_passes * u).cos() + 0.3 * self.jitter[1].at(t);
        let mid = 0.5 * (s.distance_min_cm + s.distance_max_cm);
        let amp = 0.5 * (s.distance_max_cm - s.distance_min_cm);
        let z =
            mid + amp * (0.7 * (TAU * 0.4 * t).sin() + 0.3 * self.jitter[2].at(t)).clamp(-1.0, 1.0);
        let j = s.tilt_jitter_deg.to_radians();
        // Looking straight down with the image top towards world +y, then hand tilt.
        let down = Mat3::new(1.0, 0.0, 0.0, 0.0, -1.0, 0.0, 0.0, 0.0, -1.0);
        let rot = rot_z(2.0 * j * self.jitter[4].at(t))
            * rot_x(j * self.jitter[2].at(t * 1.3))
            * rot_y(j * self.jitter[3].at(t))
            * down;
        let b = self.breathing.at(t);
        CameraState {
            pose: Pose {
                rotation: rot,
                centre: Vec3::new(x, y, z),
            },
            focal_scale: 1.0 + 0.5 * self.breath_amp * b,
            k1: self.base_k1 * (1.0 + 15.0 * self.breath_amp * b * 0.1),
        }
    }

    /// A sudden hand jerk direction for a motion-blurred frame, cm over the exposure.
    pub fn jerk(&self, t: f64) -> Vec3 {
        Vec3::new(self.jitter[5].at(t), self.jitter[5].at(t + 7.0), 0.0) * 0.12
    }
}
