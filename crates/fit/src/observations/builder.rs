//! Observations gathered one decoded frame at a time ([`ObservationBuilder`]): each
//! frame's plane pixels sampled from its image (bicubic, bilinear next to clipped pixels),
//! then every frame's lists transposed into per-pixel storage.

use rayon::prelude::*;
use svbrdf_core::capture::{PreparedMapping, RegisteredCapture};
use svbrdf_core::color::srgb8_to_linear_table;
use svbrdf_core::geometry::{Vec2, Vec3};
use svbrdf_core::image::FrameImage;
use svbrdf_core::plane::PlaneGrid;

use super::{bin_key_of_directions, FrameGeometry, Observations, CLIPPED, RGB_SCALE};
use crate::config::FitConfig;
use crate::FitError;

/// One frame's observations before transposition: (pixel, rgb, key).
pub(super) type FrameObs = Vec<(u32, [u16; 3], u32)>;

/// Collects observations one decoded frame at a time.
pub struct ObservationBuilder {
    grid: PlaneGrid,
    frames: Vec<FrameGeometry>,
    mappings: Vec<PreparedMapping>,
    sizes: Vec<(u32, u32)>,
    per_frame: Vec<FrameObs>,
    saturated: Vec<u64>,
    saturation: f32,
    censor: bool,
    lut: [f32; 256],
    border: f64,
    bicubic: bool,
    bin_deg: f64,
    bin_cm: f64,
}

impl ObservationBuilder {
    /// Prepare for the frames of `capture` on `grid`.
    pub fn new(
        capture: &RegisteredCapture,
        grid: PlaneGrid,
        cfg: &FitConfig,
    ) -> Result<Self, FitError> {
        if capture.frames.len() > usize::from(u16::MAX) {
            return Err(FitError::invalid(
                "frame count",
                capture.frames.len(),
                "at most 65535 frames",
            ));
        }
        let mut mappings = Vec::with_capacity(capture.frames.len());
        for f in &capture.frames {
            mappings.push(PreparedMapping::new(f)?);
        }
        Ok(Self {
            grid,
            frames: capture
                .frames
                .iter()
                .map(|f| FrameGeometry {
                    id: f.id,
                    camera: Vec3::from(f.camera_position),
                    light: Vec3::from(f.light_position),
                    gain: f.gain(),
                })
                .collect(),
            sizes: capture.frames.iter().map(|f| (f.width, f.height)).collect(),
            mappings,
            per_frame: vec![Vec::new(); capture.frames.len()],
            saturated: vec![0; capture.frames.len()],
            saturation: cfg.saturation as f32,
            censor: cfg.censor_clipped,
            lut: srgb8_to_linear_table(),
            border: cfg.border_px,
            bicubic: cfg.bicubic,
            bin_deg: cfg.bin_deg,
            bin_cm: cfg.bin_cm,
        })
    }

    /// Plane-grid rows and columns that can see frame `k`: from its sub-frames' plane
    /// bounding boxes (their rectangles need not reach the frame's border: alignment
    /// leaves out or cuts back sub-frames it could not fix), or a camera frame's border.
    fn footprint(&self, k: usize) -> Option<(usize, usize, usize, usize)> {
        let mut lo = Vec2::new(f64::INFINITY, f64::INFINITY);
        let mut hi = -lo;
        let mut add = |q: Vec2| {
            let g = self.grid.to_pixel(q);
            lo = lo.inf(&g);
            hi = hi.sup(&g);
        };
        match &self.mappings[k] {
            PreparedMapping::Homographies(subs) => {
                for b in subs.iter().map(|s| s.plane_bbox) {
                    add(Vec2::new(b[0], b[1]));
                    add(Vec2::new(b[2], b[3]));
                }
            }
            camera => {
                let (w, h) = self.sizes[k];
                let (w, h) = (f64::from(w) - 0.5, f64::from(h) - 0.5);
                let n = 32;
                for i in 0..=n {
                    let t = i as f64 / n as f64;
                    for p in [
                        Vec2::new(-0.5 + t * (w + 0.5), -0.5),
                        Vec2::new(-0.5 + t * (w + 0.5), h),
                        Vec2::new(-0.5, -0.5 + t * (h + 0.5)),
                        Vec2::new(w, -0.5 + t * (h + 0.5)),
                    ] {
                        if let Some(q) = camera.pixel_to_plane(p) {
                            add(q);
                        }
                    }
                }
            }
        }
        if !(lo.x.is_finite() && hi.x.is_finite()) {
            return None;
        }
        let c0 = (lo.x.floor() - 2.0).max(0.0) as usize;
        let r0 = (lo.y.floor() - 2.0).max(0.0) as usize;
        let c1 = ((hi.x.ceil() + 3.0).max(0.0) as usize).min(self.grid.width);
        let r1 = ((hi.y.ceil() + 3.0).max(0.0) as usize).min(self.grid.height);
        (c0 < c1 && r0 < r1).then_some((c0, c1, r0, r1))
    }

    /// Add frame `k` of the capture (index into `capture.frames`), decoded to linear RGB.
    pub fn add_frame(&mut self, k: usize, img: &FrameImage) -> Result<(), FitError> {
        let (w, h) = self.sizes[k];
        let (iw, ih, ic) = img.shape();
        if iw != w as usize || ih != h as usize || ic != 3 {
            return Err(FitError::invalid(
                format!("frame {} image size", self.frames[k].id),
                format!("{iw}x{ih}x{ic}"),
                format!("{w}x{h} RGB as the capture says"),
            ));
        }
        let Some((c0, c1, r0, r1)) = self.footprint(k) else {
            return Ok(());
        };
        let mapping = &self.mappings[k];
        let geom = self.frames[k];
        let grid = self.grid;
        let (xmax, ymax) = (
            f64::from(w) - 1.0 - self.border,
            f64::from(h) - 1.0 - self.border,
        );
        let (border, sat, bd, bc) = (self.border, self.saturation, self.bin_deg, self.bin_cm);
        let (censor, bicubic) = (self.censor, self.bicubic);
        let lut = &self.lut;
        let rows: Vec<(FrameObs, u64)> = (r0..r1)
            .into_par_iter()
            .map(|r| {
                let mut out = Vec::with_capacity(c1 - c0);
                let mut clipped = 0;
                let mut c = [0f32; 3];
                let row = mapping.row(grid.pixel_centre(c0, r).y);
                for col in c0..c1 {
                    let q = grid.pixel_centre(col, r);
                    let Some(p) = row.plane_to_pixel(q) else {
                        continue;
                    };
                    if !(p.x >= border && p.y >= border && p.x <= xmax && p.y <= ymax) {
                        continue;
                    }
                    // Next to clipped pixels the cubic's negative lobes ring: bilinear there.
                    if !bicubic || img.sample_linear_cubic(p.x, p.y, lut, &mut c) >= sat {
                        img.sample_linear(p.x, p.y, lut, &mut c);
                    }
                    if !c.iter().all(|v| v.is_finite()) {
                        continue;
                    }
                    if c.iter().any(|v| *v >= sat) {
                        clipped += 1;
                        if !censor {
                            continue;
                        }
                    }
                    let rgb = c.map(|v| {
                        if v >= sat {
                            CLIPPED
                        } else {
                            // Rounded by adding one half (f64::round is a libm call
                            // on the baseline x86-64 target).
                            (f64::from(v.max(0.0)) * RGB_SCALE + 0.5).min(f64::from(CLIPPED - 1))
                                as u16
                        }
                    });
                    let surface = Vec3::new(q.x, q.y, 0.0);
                    let (dl, dv) = (geom.light - surface, geom.camera - surface);
                    let key = bin_key_of_directions(dl, dv, dl.norm_squared(), bd, bc);
                    out.push(((r * grid.width + col) as u32, rgb, key));
                }
                (out, clipped)
            })
            .collect();
        let mut all = Vec::with_capacity(rows.iter().map(|r| r.0.len()).sum());
        for (v, n) in rows {
            all.extend(v);
            self.saturated[k] += n;
        }
        self.per_frame[k] = all;
        Ok(())
    }

    /// Transpose into per-pixel storage.
    pub fn finish(self) -> Observations {
        let (start, frame, rgb, key) = transpose(&self.per_frame, self.grid.len());
        Observations {
            grid: self.grid,
            frames: self.frames,
            start,
            frame,
            rgb,
            key,
            clipped: self.saturated.iter().sum(),
            saturation: f64::from(self.saturation),
            ambient: 0.0,
        }
    }
}

/// Per-pixel storage (CSR: `start`, then frame id, colour and bin key per observation,
/// a pixel's observations in frame order) from per-frame lists sorted by pixel.
#[allow(clippy::type_complexity)]
pub(super) fn transpose(
    per_frame: &[FrameObs],
    npx: usize,
) -> (Vec<usize>, Vec<u16>, Vec<[u16; 3]>, Vec<u32>) {
    debug_assert!(
        per_frame
            .iter()
            .all(|f| f.windows(2).all(|w| w[0].0 < w[1].0)),
        "each frame's observations must be sorted by pixel"
    );
    let mut start = vec![0usize; npx + 1];
    for f in per_frame {
        for (p, _, _) in f {
            start[*p as usize + 1] += 1;
        }
    }
    for i in 0..npx {
        start[i + 1] += start[i];
    }
    let total = start[npx];
    let mut frame = vec![0u16; total];
    let mut rgb = vec![[0u16; 3]; total];
    let mut key = vec![0u32; total];
    // The scatter is the pass's one serial step over every observation (seconds on
    // the paper preset): it runs over blocks of pixels in parallel, each block with
    // its own slices of the output. A frame's observations are sorted by pixel (they
    // are gathered row by row), so a block finds its part of each frame by bisection.
    let blocks = rayon::current_num_threads().max(1) * 8;
    let step = npx.div_ceil(blocks).max(1);
    let mut parts = Vec::with_capacity(blocks);
    let (mut f_rest, mut c_rest, mut k_rest) =
        (frame.as_mut_slice(), rgb.as_mut_slice(), key.as_mut_slice());
    for p0 in (0..npx).step_by(step) {
        let p1 = (p0 + step).min(npx);
        let n = start[p1] - start[p0];
        let (f, fr) = std::mem::take(&mut f_rest).split_at_mut(n);
        let (c, cr) = std::mem::take(&mut c_rest).split_at_mut(n);
        let (k, kr) = std::mem::take(&mut k_rest).split_at_mut(n);
        (f_rest, c_rest, k_rest) = (fr, cr, kr);
        parts.push((p0, p1, f, c, k));
    }
    let start_ref = &start;
    parts.into_par_iter().for_each(|(p0, p1, f, c, k)| {
        let base = start_ref[p0];
        let mut fill: Vec<usize> = start_ref[p0..p1].iter().map(|s| s - base).collect();
        for (fi, obs) in per_frame.iter().enumerate() {
            let lo = obs.partition_point(|o| (o.0 as usize) < p0);
            let hi = obs.partition_point(|o| (o.0 as usize) < p1);
            for &(p, cc, b) in &obs[lo..hi] {
                let slot = &mut fill[p as usize - p0];
                let o = *slot;
                *slot += 1;
                f[o] = fi as u16;
                c[o] = cc;
                k[o] = b;
            }
        }
    });
    (start, frame, rgb, key)
}

#[cfg(test)]
mod tests {
    use super::*;
    use svbrdf_core::capture::{
        Frame, FrameMapping, Source, SourceKind, SubFrame, CAPTURE_FORMAT, CAPTURE_VERSION,
    };
    use svbrdf_core::maps::Encoding;
    use svbrdf_core::plane::Region;

    /// A 200 x 100 frame looking straight down at 10 px per cm, whose one sub-frame
    /// is `rect`.
    fn frame_with(rect: [f64; 4]) -> RegisteredCapture {
        let region = Region {
            x_min: 0.0,
            x_max: 20.0,
            y_min: 0.0,
            y_max: 10.0,
        };
        RegisteredCapture {
            format: CAPTURE_FORMAT.into(),
            version: CAPTURE_VERSION,
            producer: "test".into(),
            units: "cm".into(),
            region,
            px_per_cm: 10.0,
            light_intensity: None,
            sources: vec![Source {
                kind: SourceKind::Video,
                path: "v.mp4".into(),
                encoding: Encoding::Srgb,
                stream: 0,
                video: None,
            }],
            frames: vec![Frame {
                id: 0,
                source: 0,
                frame_index: Some(0),
                image: None,
                time_s: None,
                width: 200,
                height: 100,
                mapping: FrameMapping::Homographies {
                    subframes: vec![SubFrame {
                        rect,
                        plane_from_pixel: [[0.1, 0.0, 0.05], [0.0, -0.1, 9.95], [0.0, 0.0, 1.0]],
                    }],
                },
                camera_position: [10.0, 5.0, 10.0],
                light_position: [10.0, 5.0, 10.0],
                exposure_gain: None,
            }],
        }
    }

    #[test]
    fn a_frame_whose_sub_frames_stop_short_of_its_border_is_still_observed() {
        let full = frame_with([-0.5, -0.5, 199.5, 99.5]);
        let grid = PlaneGrid::new(full.region, 10.0).unwrap();
        let cfg = FitConfig::default();
        let b = ObservationBuilder::new(&full, grid, &cfg).unwrap();
        assert_eq!(b.footprint(0), Some((0, 200, 0, 100)));
        // Alignment cut every edge back by 20 px: the frame still sees the middle.
        let cut = frame_with([20.0, 20.0, 179.0, 79.0]);
        let b = ObservationBuilder::new(&cut, grid, &cfg).unwrap();
        let (c0, c1, r0, r1) = b.footprint(0).unwrap();
        assert!(
            c0 <= 20 && c1 >= 180 && r0 <= 20 && r1 >= 80,
            "{c0} {c1} {r0} {r1}"
        );
        assert!(
            c0 >= 15 && r0 >= 15,
            "the cut border is not seen: {c0} {r0}"
        );
    }

    #[test]
    fn transpose_matches_a_serial_scatter() {
        // Frames seeing different, overlapping pixel ranges, some pixels unseen.
        let npx = 1000;
        let per_frame: Vec<FrameObs> = (0..7u32)
            .map(|f| {
                (f * 90..(f * 90 + 400).min(npx as u32))
                    .filter(|p| (p + f) % 3 != 0)
                    .map(|p| (p, [p as u16, f as u16, 7], p * 10 + f))
                    .collect()
            })
            .collect();
        let (start, frame, rgb, key) = transpose(&per_frame, npx);
        let mut expected: Vec<Vec<(u16, [u16; 3], u32)>> = vec![Vec::new(); npx];
        for (f, obs) in per_frame.iter().enumerate() {
            for &(p, c, k) in obs {
                expected[p as usize].push((f as u16, c, k));
            }
        }
        assert_eq!(start.len(), npx + 1);
        for (p, e) in expected.iter().enumerate() {
            let got: Vec<_> = (start[p]..start[p + 1])
                .map(|o| (frame[o], rgb[o], key[o]))
                .collect();
            assert_eq!(&got, e, "pixel {p}");
        }
    }
}
