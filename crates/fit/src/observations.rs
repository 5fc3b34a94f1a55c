//! Observations: for every output pixel, the linear colour it showed in every frame that
//! saw it. Built frame by frame (frames are never all in memory), then stored pixel by
//! pixel (compressed sparse rows) because every later step works per pixel or per
//! cluster of pixels.
//!
//! An observation is 12 bytes: frame number (u16), linear RGB (u16 each, value *
//! 65535) and the key of its redundant-observation bin (u32). Its geometry (light and
//! view directions, light distance) is not stored: it follows from the pixel centre
//! and the frame's camera and light positions in a few multiplications.

use rayon::prelude::*;
use svbrdf_core::brdf::LightView;
use svbrdf_core::geometry::Vec3;
use svbrdf_core::plane::PlaneGrid;

use crate::FitError;

mod builder;
pub use builder::ObservationBuilder;

/// Linear value 1.0 is stored as this.
pub const RGB_SCALE: f64 = 65535.0;
/// Stored value of a clipped channel: the true value is at least the saturation
/// threshold (unclipped values are stored below it, so this is unambiguous).
pub const CLIPPED: u16 = u16::MAX;

/// Residual of a prediction against an observed channel. A clipped channel only says
/// "at least this bright": predicting above it costs nothing (a censored observation),
/// so flash highlights that the 8-bit video clipped still pull the specular lobe up
/// instead of being thrown away or pulling it down.
#[inline]
pub fn residual(pred: f64, observed: f64, clipped: bool) -> f64 {
    let r = pred - observed;
    if clipped {
        r.min(0.0)
    } else {
        r
    }
}

/// Where a frame's camera and light were.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FrameGeometry {
    /// Frame id in the capture.
    pub id: u32,
    /// Camera centre, cm.
    pub camera: Vec3,
    /// Light position, cm.
    pub light: Vec3,
    /// Exposure gain of the frame (the capture's `exposure_gain`, 1 when fixed): stored
    /// colours are divided by it when read, and a clipped channel means "at least the
    /// saturation threshold / gain".
    pub gain: f64,
}

/// All observations of a capture on an output grid.
#[derive(Debug, Clone)]
pub struct Observations {
    /// The output grid.
    pub grid: PlaneGrid,
    /// Frames, indexed by the observation's frame number.
    pub frames: Vec<FrameGeometry>,
    /// Observations of pixel `p` are `start[p]..start[p + 1]`.
    pub start: Vec<usize>,
    /// Frame number per observation.
    pub frame: Vec<u16>,
    /// Linear RGB * [`RGB_SCALE`] per observation.
    pub rgb: Vec<[u16; 3]>,
    /// Redundant-observation bin per observation (see [`bin_key`]).
    pub key: Vec<u32>,
    /// Observations with at least one clipped channel (kept as censored values with
    /// [`FitConfig::censor_clipped`], dropped otherwise).
    pub clipped: u64,
    /// Linear value at and above which a channel counts as clipped.
    pub saturation: f64,
    /// Room light recorded with every observation ([`LightView::ambient`], cm^-2): 0
    /// until [`crate::room::estimate`] sets it; part of every [`Self::light_view`].
    pub ambient: f64,
}

impl Observations {
    /// Number of output pixels.
    pub fn pixels(&self) -> usize {
        self.start.len() - 1
    }

    /// Number of observations.
    pub fn len(&self) -> usize {
        self.frame.len()
    }

    /// Whether there are none.
    pub fn is_empty(&self) -> bool {
        self.frame.is_empty()
    }

    /// Observation range of a pixel.
    pub fn range(&self, px: usize) -> std::ops::Range<usize> {
        self.start[px]..self.start[px + 1]
    }

    /// Share of the observations within `near_deg` of the mirror direction (half
    /// vector against the plane's normal) that have a clipped channel.
    pub fn clipped_near_mirror(&self, near_deg: f64) -> Option<f64> {
        let obs = self;
        let cos_limit = near_deg.to_radians().cos();
        let (near, clipped) = (0..obs.pixels())
            .into_par_iter()
            .map(|p| {
                let (mut n, mut c) = (0u64, 0u64);
                for o in obs.range(p) {
                    let lv = obs.light_view(p, o);
                    let h = lv.light + lv.view;
                    if h.z / h.norm().max(1e-12) >= cos_limit {
                        n += 1;
                        c += u64::from(obs.clipped(o).iter().any(|x| *x));
                    }
                }
                (n, c)
            })
            .reduce(|| (0, 0), |a, b| (a.0 + b.0, a.1 + b.1));
        (near > 0).then(|| clipped as f64 / near as f64)
    }

    /// Observation count of a pixel.
    pub fn count(&self, px: usize) -> usize {
        self.start[px + 1] - self.start[px]
    }

    /// Linear colour of observation `o` at gain 1 (divided by its frame's exposure
    /// gain; a clipped channel reads as the saturation threshold over that gain).
    #[inline]
    pub fn color(&self, o: usize) -> [f64; 3] {
        let inv = 1.0 / self.frames[usize::from(self.frame[o])].gain;
        self.rgb[o].map(|v| {
            if v == CLIPPED {
                self.saturation * inv
            } else {
                f64::from(v) / RGB_SCALE * inv
            }
        })
    }

    /// Which channels of observation `o` are clipped.
    #[inline]
    pub fn clipped(&self, o: usize) -> [bool; 3] {
        self.rgb[o].map(|v| v == CLIPPED)
    }

    /// Plane point (cm, z = 0) of a pixel's centre.
    #[inline]
    pub fn surface(&self, px: usize) -> Vec3 {
        let q = self
            .grid
            .pixel_centre(px % self.grid.width, px / self.grid.width);
        Vec3::new(q.x, q.y, 0.0)
    }

    /// Geometry of observation `o` of pixel `px`.
    #[inline]
    pub fn light_view(&self, px: usize, o: usize) -> LightView {
        let f = &self.frames[usize::from(self.frame[o])];
        LightView::from_points(self.surface(px), f.light, f.camera).with_ambient(self.ambient)
    }

    /// The observations of the frames `keep` selects (indexed like [`Self::frames`]),
    /// on every `step`-th output pixel in each direction: pixel (c, r) of the coarser
    /// grid (the region at `px_per_cm / step`) takes the observations of the fine pixel
    /// nearest its centre's block middle. Frames stay indexed as before, so exposure
    /// gains and frame ids carry over. Clipped counts are those of the kept
    /// observations.
    pub fn subset(&self, keep: &[bool], step: usize) -> Result<Self, FitError> {
        let step = step.max(1);
        let grid = if step == 1 {
            self.grid
        } else {
            PlaneGrid::new(self.grid.region, self.grid.px_per_cm / step as f64)?
        };
        let (w, h) = (self.grid.width, self.grid.height);
        let mut out = Self {
            grid,
            frames: self.frames.clone(),
            start: Vec::with_capacity(grid.len() + 1),
            frame: Vec::new(),
            rgb: Vec::new(),
            key: Vec::new(),
            clipped: 0,
            saturation: self.saturation,
            ambient: self.ambient,
        };
        out.start.push(0);
        for r in 0..grid.height {
            for c in 0..grid.width {
                let (fc, fr) = if step == 1 {
                    (c, r)
                } else {
                    (
                        (c * step + step / 2).min(w - 1),
                        (r * step + step / 2).min(h - 1),
                    )
                };
                for o in self.range(fr * w + fc) {
                    if !keep
                        .get(usize::from(self.frame[o]))
                        .copied()
                        .unwrap_or(false)
                    {
                        continue;
                    }
                    out.frame.push(self.frame[o]);
                    out.rgb.push(self.rgb[o]);
                    out.key.push(self.key[o]);
                    if self.rgb[o].contains(&CLIPPED) {
                        out.clipped += 1;
                    }
                }
                out.start.push(out.frame.len());
            }
        }
        Ok(out)
    }
}

/// The bin of the paper's section 3.2.2: 5-degree steps of the light and view polar and
/// azimuth angles (about the flat normal) and 1 cm steps of the light distance, packed
/// as `theta_i (5 bits) | phi_i (7) | theta_r (5) | phi_r (7) | r (8)`. Angle bins of
/// at least 3 degrees fit (the configuration checks it); distances saturate at 255 bins.
///
/// Angles come from [`fast_atan2`]: bin edges move by at most 0.1 degrees, which only
/// shifts the arbitrary partition, and the key costs a third of the libm version
/// (it is computed once per observation, tens of millions of times).
pub fn bin_key(lv: &LightView, bin_deg: f64, bin_cm: f64) -> u32 {
    bin_key_of_directions(lv.light, lv.view, lv.light_dist2, bin_deg, bin_cm)
}

/// [`bin_key`] from the surface-to-light and surface-to-camera vectors as they are:
/// the angles do not depend on their lengths, so the sampler skips normalising them.
#[inline]
pub fn bin_key_of_directions(
    light: Vec3,
    view: Vec3,
    light_dist2: f64,
    bin_deg: f64,
    bin_cm: f64,
) -> u32 {
    let step = bin_deg.to_radians();
    // Every quotient below is >= 0, so truncation is the floor (and NaN gives bin 0).
    let polar = |d: Vec3| {
        let s = (d.x * d.x + d.y * d.y).sqrt();
        ((fast_atan2(s, d.z) / step) as u32).min(31)
    };
    let azimuth = |d: Vec3| {
        let a = fast_atan2(d.y, d.x) + std::f64::consts::PI;
        ((a / step) as u32).min(127)
    };
    let r = ((light_dist2.sqrt() / bin_cm) as u32).min(255);
    (polar(light) << 27) | (azimuth(light) << 20) | (polar(view) << 15) | (azimuth(view) << 8) | r
}

/// `atan2(y, x)` in `[-pi, pi]` to within 0.002 radians (a degree-5 odd polynomial for
/// atan on [0, 1] and octant folding); no libm call.
#[inline]
pub fn fast_atan2(y: f64, x: f64) -> f64 {
    use std::f64::consts::{FRAC_PI_2, PI};
    let (ax, ay) = (x.abs(), y.abs());
    let (lo, hi) = if ax > ay { (ay, ax) } else { (ax, ay) };
    if hi == 0.0 {
        return 0.0;
    }
    let t = lo / hi;
    let t2 = t * t;
    let mut a = t
        * (0.999_866
            + t2 * (-0.330_299_5 + t2 * (0.180_141 + t2 * (-0.085_133 + t2 * 0.020_835_1))));
    if ay > ax {
        a = FRAC_PI_2 - a;
    }
    if x < 0.0 {
        a = PI - a;
    }
    if y < 0.0 {
        -a
    } else {
        a
    }
}

/// `n` flash frames, frame `i`'s camera at `camera(i)` and its flash beside it as on
/// the phone description of the presets (tests).
#[cfg(test)]
pub(crate) fn flash_frames(n: u32, camera: impl Fn(u32) -> Vec3) -> Vec<FrameGeometry> {
    (0..n)
        .map(|i| {
            let camera = camera(i);
            FrameGeometry {
                id: i,
                camera,
                light: camera + Vec3::new(1.4, -0.3, 0.0),
                gain: 1.0,
            }
        })
        .collect()
}

/// Exact Ward observations for tests: every pixel of `grid` seen by every frame,
/// rendered with `params(pixel)` under `intensity`. Channels at or above 0.9 are stored
/// as clipped, or with `drop_clipped` the observation is left out.
#[cfg(test)]
pub(crate) fn rendered(
    grid: PlaneGrid,
    frames: Vec<FrameGeometry>,
    params: impl Fn(usize) -> svbrdf_core::brdf::BrdfParams,
    intensity: f64,
    drop_clipped: bool,
) -> Observations {
    rendered_in_room(grid, frames, params, intensity, drop_clipped, 0.0)
}

/// [`rendered`] with room light `ambient` ([`LightView::ambient`]) in every frame.
#[cfg(test)]
pub(crate) fn rendered_in_room(
    grid: PlaneGrid,
    frames: Vec<FrameGeometry>,
    params: impl Fn(usize) -> svbrdf_core::brdf::BrdfParams,
    intensity: f64,
    drop_clipped: bool,
    ambient: f64,
) -> Observations {
    use svbrdf_core::brdf::{BrdfModel, Prepared, Ward};
    let mut start = vec![0];
    let (mut frame, mut rgb, mut key, mut clipped) = (Vec::new(), Vec::new(), Vec::new(), 0);
    for px in 0..grid.len() {
        let q = grid.pixel_centre(px % grid.width, px / grid.width);
        let p = Prepared::new(params(px));
        for (k, f) in frames.iter().enumerate() {
            let lv = LightView::from_points(Vec3::new(q.x, q.y, 0.0), f.light, f.camera);
            let v = Ward.radiance(&p, &lv.with_ambient(ambient), intensity);
            let any = v.iter().any(|c| *c >= 0.9);
            if any && drop_clipped {
                continue;
            }
            clipped += u64::from(any);
            frame.push(k as u16);
            rgb.push(v.map(|c| {
                if c >= 0.9 {
                    CLIPPED
                } else {
                    (c * RGB_SCALE).round() as u16
                }
            }));
            key.push(bin_key(&lv, 5.0, 1.0));
        }
        start.push(frame.len());
    }
    Observations {
        grid,
        frames,
        start,
        frame,
        rgb,
        key,
        clipped,
        saturation: 0.9,
        ambient: 0.0,
    }
}

#[cfg(test)]
mod tests {
    use super::builder::{transpose, FrameObs};
    use super::*;

    fn grid_observations(w: usize, h: usize, frames: usize) -> Observations {
        let region = svbrdf_core::plane::Region {
            x_min: 0.0,
            x_max: w as f64,
            y_min: 0.0,
            y_max: h as f64,
        };
        let grid = PlaneGrid::new(region, 1.0).unwrap();
        let per_frame: Vec<FrameObs> = (0..frames as u32)
            .map(|f| {
                (0..(w * h) as u32)
                    .filter(|p| (p + f) % 4 != 0)
                    .map(|p| (p, [p as u16, f as u16, if f == 2 { CLIPPED } else { 7 }], p))
                    .collect()
            })
            .collect();
        let (start, frame, rgb, key) = transpose(&per_frame, w * h);
        Observations {
            grid,
            frames: (0..frames as u32)
                .map(|id| FrameGeometry {
                    id: 10 + id,
                    camera: Vec3::new(0.0, 0.0, 10.0),
                    light: Vec3::new(1.0, 0.0, 10.0),
                    gain: 1.0,
                })
                .collect(),
            start,
            frame,
            rgb,
            key,
            clipped: (w * h) as u64,
            saturation: 0.9,
            ambient: 0.0,
        }
    }

    #[test]
    fn subsets_of_frames_partition_the_observations() {
        let obs = grid_observations(8, 6, 5);
        let held = [false, true, true, false, false];
        let keep: Vec<bool> = held.iter().map(|h| !h).collect();
        let (a, b) = (obs.subset(&keep, 1).unwrap(), obs.subset(&held, 1).unwrap());
        assert_eq!(a.len() + b.len(), obs.len());
        assert_eq!(a.frames, obs.frames);
        for p in 0..obs.pixels() {
            let frames = |o: &Observations| o.range(p).map(|i| o.frame[i]).collect::<Vec<_>>();
            let all = frames(&obs);
            assert_eq!(
                frames(&a),
                all.iter()
                    .copied()
                    .filter(|f| keep[*f as usize])
                    .collect::<Vec<_>>()
            );
            assert_eq!(
                frames(&b),
                all.iter()
                    .copied()
                    .filter(|f| held[*f as usize])
                    .collect::<Vec<_>>()
            );
        }
        // Only frame 2's observations are clipped, and only the held-out set has them.
        assert_eq!(a.clipped, 0);
        assert_eq!(
            b.clipped,
            b.frame.iter().filter(|f| **f == 2).count() as u64
        );
    }

    #[test]
    fn a_decimated_subset_takes_each_blocks_middle_pixel() {
        let obs = grid_observations(8, 6, 3);
        let d = obs.subset(&[true; 3], 2).unwrap();
        assert_eq!((d.grid.width, d.grid.height), (4, 3));
        for r in 0..3 {
            for c in 0..4 {
                let fine = (2 * r + 1) * 8 + 2 * c + 1;
                let got: Vec<u32> = d.range(r * 4 + c).map(|o| d.key[o]).collect();
                let want: Vec<u32> = obs.range(fine).map(|o| obs.key[o]).collect();
                assert_eq!(got, want, "pixel ({c}, {r})");
                // The coarse pixel's centre lies within the fine pixel's block.
                let q = d.grid.pixel_centre(c, r);
                let f = obs.grid.pixel_centre(2 * c + 1, 2 * r + 1);
                assert!((q.x - f.x).abs() <= 0.5 && (q.y - f.y).abs() <= 0.5);
            }
        }
    }

    #[test]
    fn fast_atan2_is_within_two_milliradians() {
        let mut worst: f64 = 0.0;
        for i in 0..3600 {
            let a = (i as f64 / 3600.0 - 0.5) * std::f64::consts::TAU;
            for r in [0.01, 1.0, 37.0] {
                let (y, x) = (r * a.sin(), r * a.cos());
                let d = (fast_atan2(y, x) - y.atan2(x)).abs();
                // +pi and -pi are the same direction.
                worst = worst.max(d.min((d - std::f64::consts::TAU).abs()));
            }
        }
        assert!(worst < 2e-3, "worst {worst}");
        assert_eq!(fast_atan2(0.0, 0.0), 0.0);
    }

    #[test]
    fn bin_key_separates_angles_and_distance() {
        let lv = |l: Vec3, v: Vec3, r: f64| LightView {
            light: l.normalize(),
            view: v.normalize(),
            light_dist2: r * r,
            ambient: 0.0,
        };
        let a = bin_key(&lv(Vec3::new(0.1, 0.0, 1.0), Vec3::z(), 12.2), 5.0, 1.0);
        let b = bin_key(&lv(Vec3::new(0.1, 0.0, 1.0), Vec3::z(), 12.7), 5.0, 1.0);
        let c = bin_key(&lv(Vec3::new(0.1, 0.0, 1.0), Vec3::z(), 13.1), 5.0, 1.0);
        // Distances well beyond 15 cm keep their own bins.
        let far = bin_key(&lv(Vec3::new(0.1, 0.0, 1.0), Vec3::z(), 24.5), 5.0, 1.0);
        let farther = bin_key(&lv(Vec3::new(0.1, 0.0, 1.0), Vec3::z(), 31.5), 5.0, 1.0);
        assert_ne!(far, farther);
        // Opposite azimuths and the widest angle bin differ.
        let e = bin_key(&lv(Vec3::new(-0.1, 0.0, 1.0), Vec3::z(), 12.2), 3.0, 1.0);
        let g = bin_key(&lv(Vec3::new(0.1, 0.0, 1.0), Vec3::z(), 12.2), 3.0, 1.0);
        assert_ne!(e, g);
        let d = bin_key(&lv(Vec3::new(0.0, 0.1, 1.0), Vec3::z(), 12.2), 5.0, 1.0);
        assert_eq!(a, b);
        assert_ne!(a, c);
        assert_ne!(a, d);
    }
}
