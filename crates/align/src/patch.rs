//! Guided sub-pixel correspondences at full resolution: a feature matched at coarse
//! scale is refined by comparing image patches, with the pair's local affine warp,
//! normalised cross-correlation over a small search window, then Gauss-Newton with a
//! gain and an offset (the flash moves with the camera, so the same surface point is
//! brighter or darker from frame to frame).
//!
//! This replaces the paper's full-resolution SIFT (2-3 s per 4K frame) for the fine
//! alignment: a coarse match predicts the position to a few pixels, and the patch
//! locates it to a small fraction of a pixel.

// Index loops over the small normal equations read more clearly than iterator chains.
#![allow(clippy::needless_range_loop)]

use svbrdf_core::geometry::Vec2;
use svbrdf_core::image::ImageU8;

/// A single-channel 8-bit image for patch work (the luminance of a frame).
#[derive(Debug, Clone)]
pub struct Grey {
    /// Columns.
    pub width: usize,
    /// Rows.
    pub height: usize,
    /// Row-major samples.
    pub data: Vec<u8>,
}

impl Grey {
    /// Luminance (Rec. 601 weights) of an RGB or grey image.
    pub fn from_image(img: &ImageU8) -> Self {
        let data = if img.channels >= 3 {
            img.data
                .chunks_exact(img.channels)
                .map(|p| {
                    ((77 * u32::from(p[0]) + 150 * u32::from(p[1]) + 29 * u32::from(p[2]) + 128)
                        >> 8) as u8
                })
                .collect()
        } else {
            img.data
                .iter()
                .step_by(img.channels.max(1))
                .copied()
                .collect()
        };
        Self {
            width: img.width,
            height: img.height,
            data,
        }
    }

    #[inline]
    fn at(&self, x: usize, y: usize) -> f32 {
        f32::from(self.data[y * self.width + x])
    }

    /// Bilinear sample at continuous pixel coordinates (pixel centres at integers);
    /// `None` outside the image.
    #[inline]
    pub fn sample(&self, x: f64, y: f64) -> Option<f32> {
        if !(x >= 0.0 && y >= 0.0) {
            return None;
        }
        let (x0, y0) = (x as usize, y as usize);
        if x0 + 1 >= self.width || y0 + 1 >= self.height {
            return None;
        }
        let (fx, fy) = ((x - x0 as f64) as f32, (y - y0 as f64) as f32);
        let top = self.at(x0, y0) * (1.0 - fx) + self.at(x0 + 1, y0) * fx;
        let bottom = self.at(x0, y0 + 1) * (1.0 - fx) + self.at(x0 + 1, y0 + 1) * fx;
        Some(top * (1.0 - fy) + bottom * fy)
    }
}

/// Settings of the patch refinement.
#[derive(Debug, Clone, Copy)]
pub struct PatchSettings {
    /// Patch half-width, pixels of the second image (the patch is `2r+1` square).
    pub radius: usize,
    /// Search half-width around the prediction, whole pixels.
    pub search: i32,
    /// Lowest normalised cross-correlation accepted, in (-1, 1].
    pub min_ncc: f32,
}

impl Default for PatchSettings {
    fn default() -> Self {
        Self {
            radius: 12,
            search: 4,
            min_ncc: 0.8,
        }
    }
}

/// Where the point `pa` of image `a` lies in image `b`, starting from the prediction
/// `pb`. `jac` maps a small offset in `b` to the offset in `a` (the local linear part of
/// the pair's b-to-a mapping, row-major 2x2). Returns the refined position and its
/// normalised cross-correlation, or `None` where the patch is flat, leaves an image, or
/// matches nowhere well.
pub fn refine(
    a: &Grey,
    pa: Vec2,
    b: &Grey,
    pb: Vec2,
    jac: [f64; 4],
    s: &PatchSettings,
) -> Option<(Vec2, f32)> {
    let r = s.radius as i32;
    let n = (2 * r + 1) as usize;
    // Template: image a resampled onto b's pixel grid around the prediction.
    let mut t = Vec::with_capacity(n * n);
    for v in -r..=r {
        for u in -r..=r {
            let (u, v) = (f64::from(u), f64::from(v));
            t.push(a.sample(
                pa.x + jac[0] * u + jac[1] * v,
                pa.y + jac[2] * u + jac[3] * v,
            )?);
        }
    }
    normalise(&mut t)?;
    // Integer search by normalised cross-correlation.
    let (cx, cy) = (pb.x.round() as i64, pb.y.round() as i64);
    let mut best = (f32::NEG_INFINITY, 0i32, 0i32);
    // The integer search only has to find the right pixel (Gauss-Newton does the
    // rest), so it compares every second row and column: a quarter of the work.
    let sub: Vec<f32> = (0..n)
        .step_by(2)
        .flat_map(|k| (0..n).step_by(2).map(move |l| (k, l)))
        .map(|(k, l)| t[k * n + l])
        .collect();
    let sub_mean = sub.iter().sum::<f32>() / sub.len() as f32;
    let sub: Vec<f32> = sub.iter().map(|v| v - sub_mean).collect();
    let sub_norm = sub.iter().map(|v| v * v).sum::<f32>().sqrt();
    if sub_norm <= 0.0 {
        return None;
    }
    let ns = n.div_ceil(2);
    let nf = (ns * ns) as f32;
    for dy in -s.search..=s.search {
        for dx in -s.search..=s.search {
            let (x0, y0) = (
                cx + i64::from(dx) - i64::from(r),
                cy + i64::from(dy) - i64::from(r),
            );
            if x0 < 0 || y0 < 0 || x0 as usize + n >= b.width || y0 as usize + n >= b.height {
                continue;
            }
            // The template has zero mean, so the patch's mean drops out of the product:
            // one pass gives the product, the sum and the sum of squares.
            let (mut dot, mut s1, mut s2) = (0f32, 0f32, 0f32);
            for (k, row) in (y0 as usize..y0 as usize + n).step_by(2).enumerate() {
                let src = &b.data[row * b.width + x0 as usize..row * b.width + x0 as usize + n];
                for (&tv, &v) in sub[k * ns..(k + 1) * ns].iter().zip(src.iter().step_by(2)) {
                    let v = f32::from(v);
                    dot += tv * v;
                    s1 += v;
                    s2 += v * v;
                }
            }
            let var = s2 - s1 * s1 / nf;
            // Less than about one grey level of contrast: nothing to lock on to.
            if var < nf {
                continue;
            }
            let ncc = dot / (var.sqrt() * sub_norm);
            if ncc > best.0 {
                best = (ncc, dx, dy);
            }
        }
    }
    if best.0 < s.min_ncc {
        return None;
    }
    // A peak on the border of the search window is not a peak.
    if best.1.abs() == s.search || best.2.abs() == s.search {
        return None;
    }
    let start = Vec2::new(
        (cx + i64::from(best.1)) as f64,
        (cy + i64::from(best.2)) as f64,
    );
    let mut c = start;
    // Gauss-Newton on translation, gain and offset: b(c + u) ~ g * t(u) + o. All
    // samples of one iteration share the fractional offset of `c`, so the patch (with
    // a one-pixel border for the gradients) is interpolated with one set of weights.
    let m = n + 2;
    let mut bp = vec![0f32; m * m];
    for _ in 0..4 {
        let (x0, y0) = (c.x - f64::from(r) - 1.0, c.y - f64::from(r) - 1.0);
        if !(x0 >= 0.0 && y0 >= 0.0) {
            return None;
        }
        let (ix, iy) = (x0.floor() as usize, y0.floor() as usize);
        if ix + m + 1 >= b.width || iy + m + 1 >= b.height {
            return None;
        }
        let (fx, fy) = ((x0 - ix as f64) as f32, (y0 - iy as f64) as f32);
        let (w00, w10, w01, w11) = (
            (1.0 - fx) * (1.0 - fy),
            fx * (1.0 - fy),
            (1.0 - fx) * fy,
            fx * fy,
        );
        for k in 0..m {
            let r0 = &b.data[(iy + k) * b.width + ix..(iy + k) * b.width + ix + m + 1];
            let r1 = &b.data[(iy + k + 1) * b.width + ix..(iy + k + 1) * b.width + ix + m + 1];
            for l in 0..m {
                bp[k * m + l] = w00 * f32::from(r0[l])
                    + w10 * f32::from(r0[l + 1])
                    + w01 * f32::from(r1[l])
                    + w11 * f32::from(r1[l + 1]);
            }
        }
        let mut h = [[0f64; NP]; NP];
        let mut g = [0f64; NP];
        let (mut hh, mut gg) = ([0f32; NP * (NP + 1) / 2], [0f32; NP]);
        let inv_r = 1.0 / r as f32;
        for k in 0..n {
            for l in 0..n {
                let i = (k + 1) * m + l + 1;
                let bv = bp[i];
                let gx = 0.5 * (bp[i + 1] - bp[i - 1]);
                let gy = 0.5 * (bp[i + m] - bp[i - m]);
                let tv = t[k * n + l];
                // Residual b(c + d + u) - (gain * t + offset), linearised in d.
                // The flash moves with the camera, so the shading also tilts across the
                // patch: a linear ramp beside gain and offset.
                let (du, dv) = ((l as f32 - r as f32) * inv_r, (k as f32 - r as f32) * inv_r);
                let j: [f32; NP] = [gx, gy, -tv, -1.0, -du, -dv];
                let mut q = 0;
                for p in 0..NP {
                    gg[p] += j[p] * bv;
                    for o in p..NP {
                        hh[q] += j[p] * j[o];
                        q += 1;
                    }
                }
            }
        }
        let mut q = 0;
        for p in 0..NP {
            g[p] = f64::from(gg[p]);
            for o in p..NP {
                h[p][o] = f64::from(hh[q]);
                h[o][p] = h[p][o];
                q += 1;
            }
        }
        let d = solve_small(h, g)?;
        // d solves H d = g; the step is -d (gain and offset are re-solved in full each
        // time, so only the translation accumulates).
        let step = Vec2::new(-d[0], -d[1]);
        c += step;
        if (c - start).norm() > 1.5 {
            return None;
        }
        if step.norm() < 0.01 {
            break;
        }
    }
    Some((c, best.0))
}

/// Zero mean and unit norm in place; `None` for a flat patch.
fn normalise(p: &mut [f32]) -> Option<()> {
    let n = p.len() as f32;
    let mean = p.iter().sum::<f32>() / n;
    let mut ss = 0.0;
    for v in p.iter_mut() {
        *v -= mean;
        ss += *v * *v;
    }
    // Less than about one grey level of contrast: nothing to lock on to.
    if ss < n * 1.0 {
        return None;
    }
    let inv = 1.0 / ss.sqrt();
    for v in p.iter_mut() {
        *v *= inv;
    }
    Some(())
}

/// Unknowns of the photometric Gauss-Newton: translation, gain, offset, ramp.
const NP: usize = 6;

/// Solve the small symmetric system `h x = g` by Gaussian elimination with pivoting.
fn solve_small(mut h: [[f64; NP]; NP], mut g: [f64; NP]) -> Option<[f64; NP]> {
    for col in 0..NP {
        let piv = (col..NP).max_by(|&i, &j| h[i][col].abs().total_cmp(&h[j][col].abs()))?;
        if h[piv][col].abs() < 1e-12 {
            return None;
        }
        h.swap(col, piv);
        g.swap(col, piv);
        for row in col + 1..NP {
            let f = h[row][col] / h[col][col];
            for k in col..NP {
                h[row][k] -= f * h[col][k];
            }
            g[row] -= f * g[col];
        }
    }
    let mut x = [0f64; NP];
    for row in (0..NP).rev() {
        let mut s = g[row];
        for k in row + 1..NP {
            s -= h[row][k] * x[k];
        }
        x[row] = s / h[row][row];
    }
    Some(x)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A smooth random texture (sum of sinusoids), sampled at `(x - dx, y - dy)` with a
    /// gain and an offset: the content of `a` appears shifted by (dx, dy) in `b`.
    fn texture(w: usize, h: usize, dx: f64, dy: f64, gain: f64, offset: f64) -> Grey {
        let waves = [
            (0.31, 0.17, 0.0),
            (-0.12, 0.43, 1.3),
            (0.23, -0.29, 2.1),
            (0.07, 0.11, 0.4),
            (0.52, 0.05, 2.9),
        ];
        let mut data = Vec::with_capacity(w * h);
        for y in 0..h {
            for x in 0..w {
                let (u, v) = (x as f64 - dx, y as f64 - dy);
                let s: f64 = waves
                    .iter()
                    .map(|(a, b, p)| (a * u + b * v + p).sin())
                    .sum();
                data.push(
                    (offset + gain * (128.0 + 22.0 * s))
                        .round()
                        .clamp(0.0, 255.0) as u8,
                );
            }
        }
        Grey {
            width: w,
            height: h,
            data,
        }
    }

    #[test]
    fn recovers_subpixel_shift_under_gain_and_offset() {
        let a = texture(120, 120, 0.0, 0.0, 1.0, 0.0);
        for (dx, dy) in [(0.3, -0.45), (2.7, 1.2), (-3.4, 0.8)] {
            let b = texture(120, 120, dx, dy, 0.8, 20.0);
            let pa = Vec2::new(60.0, 58.0);
            // Predicted at the rounded shift's opposite corner: up to a few pixels off.
            let (got, ncc) = refine(
                &a,
                pa,
                &b,
                pa,
                [1.0, 0.0, 0.0, 1.0],
                &PatchSettings::default(),
            )
            .expect("a textured patch matches");
            let err = (got - (pa + Vec2::new(dx, dy))).norm();
            assert!(err < 0.05, "shift ({dx}, {dy}): error {err:.3} px");
            assert!(ncc > 0.95, "{ncc}");
        }
    }

    #[test]
    fn flat_patches_and_far_predictions_are_refused() {
        let flat = Grey {
            width: 80,
            height: 80,
            data: vec![100; 6400],
        };
        let p = Vec2::new(40.0, 40.0);
        let s = PatchSettings::default();
        assert!(refine(&flat, p, &flat, p, [1.0, 0.0, 0.0, 1.0], &s).is_none());
        let a = texture(120, 120, 0.0, 0.0, 1.0, 0.0);
        let b = texture(120, 120, 9.0, 0.0, 1.0, 0.0);
        // The true position is 9 px away, beyond the 4 px search: no answer rather than
        // a wrong one.
        let r = refine(
            &a,
            Vec2::new(60.0, 60.0),
            &b,
            Vec2::new(60.0, 60.0),
            [1.0, 0.0, 0.0, 1.0],
            &s,
        );
        assert!(
            r.is_none_or(|(q, _)| (q - Vec2::new(69.0, 60.0)).norm() < 0.1),
            "{r:?}"
        );
        // Near the border: the patch would leave the image.
        assert!(refine(
            &a,
            Vec2::new(3.0, 3.0),
            &a,
            Vec2::new(3.0, 3.0),
            [1.0, 0.0, 0.0, 1.0],
            &s
        )
        .is_none());
    }
}
