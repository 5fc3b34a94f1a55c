//! The plane images the self-check compares: a frame or the reference photo rectified
//! onto a grid of the plane, and the block correlation that finds how far one is
//! displaced from the other.

use rayon::prelude::*;
use svbrdf_core::geometry::Vec2;
use svbrdf_core::image::ImageU8;
use svbrdf_core::plane::PlaneGrid;

/// A block needs this share of its cells seen (and unclipped) in both images.
pub(super) const MIN_VALID: f64 = 0.6;

/// A colour image on the plane grid; `None` where unseen or clipped.
pub(super) struct PlaneImage {
    pub(super) w: usize,
    pub(super) h: usize,
    px: Vec<Option<[f32; 3]>>,
}

impl PlaneImage {
    pub(super) fn get(&self, x: i64, y: i64) -> Option<[f32; 3]> {
        if x < 0 || y < 0 || x >= self.w as i64 || y >= self.h as i64 {
            return None;
        }
        self.px[y as usize * self.w + x as usize]
    }

    /// Box-average by `k` (cells with any missing sample stay missing).
    pub(super) fn reduce(&self, k: usize) -> Self {
        let (w, h) = (self.w / k, self.h / k);
        let mut px = vec![None; w * h];
        for r in 0..h {
            for c in 0..w {
                let mut acc = [0.0f32; 3];
                let mut ok = true;
                'cell: for dy in 0..k {
                    for dx in 0..k {
                        match self.px[(r * k + dy) * self.w + c * k + dx] {
                            Some(v) => (0..3).for_each(|i| acc[i] += v[i]),
                            None => {
                                ok = false;
                                break 'cell;
                            }
                        }
                    }
                }
                if ok {
                    let n = (k * k) as f32;
                    px[r * w + c] = Some(acc.map(|v| v / n));
                }
            }
        }
        Self { w, h, px }
    }
}

fn bilinear(img: &ImageU8, x: f64, y: f64) -> Option<[f32; 3]> {
    if x < 0.0 || y < 0.0 || x > (img.width - 1) as f64 || y > (img.height - 1) as f64 {
        return None;
    }
    let (x0, y0) = (x.floor() as usize, y.floor() as usize);
    let (x1, y1) = ((x0 + 1).min(img.width - 1), (y0 + 1).min(img.height - 1));
    let (fx, fy) = ((x - x0 as f64) as f32, (y - y0 as f64) as f32);
    let mut out = [0.0f32; 3];
    let mut clipped = false;
    for (xx, yy, wgt) in [
        (x0, y0, (1.0 - fx) * (1.0 - fy)),
        (x1, y0, fx * (1.0 - fy)),
        (x0, y1, (1.0 - fx) * fy),
        (x1, y1, fx * fy),
    ] {
        let p = img.pixel(xx, yy);
        for i in 0..3 {
            clipped |= p[i] >= 250;
            out[i] += wgt * f32::from(p[i]);
        }
    }
    (!clipped).then_some(out)
}

/// Rectify an image onto `grid` through `pixel_of` (plane cm -> image pixel), with
/// 2 x 2 samples per cell.
pub(super) fn rectify(
    grid: &PlaneGrid,
    img: &ImageU8,
    pixel_of: &(dyn Fn(Vec2) -> Option<Vec2> + Sync),
) -> PlaneImage {
    let px: Vec<Option<[f32; 3]>> = (0..grid.len())
        .into_par_iter()
        .map(|i| {
            let (c, r) = ((i % grid.width) as f64, (i / grid.width) as f64);
            let mut acc = [0.0f32; 3];
            for (dx, dy) in [(-0.25, -0.25), (0.25, -0.25), (-0.25, 0.25), (0.25, 0.25)] {
                let q = grid.to_plane(Vec2::new(c + dx, r + dy));
                let p = pixel_of(q)?;
                let v = bilinear(img, p.x, p.y)?;
                (0..3).for_each(|k| acc[k] += 0.25 * v[k]);
            }
            Some(acc)
        })
        .collect();
    PlaneImage {
        w: grid.width,
        h: grid.height,
        px,
    }
}

/// Correlation of the block of `a` at (bx, by) (side `n`) with `b` shifted by (sx, sy):
/// the mean over colour channels of the normalised cross-correlation over the cells
/// valid in both. `None` below `MIN_VALID` valid cells.
fn ncc(
    a: &PlaneImage,
    b: &PlaneImage,
    bx: i64,
    by: i64,
    n: usize,
    sx: i64,
    sy: i64,
) -> Option<f64> {
    let mut s = [[0.0f64; 5]; 3]; // per channel: sum a, sum b, sum aa, sum bb, sum ab
    let mut count = 0usize;
    for y in 0..n as i64 {
        for x in 0..n as i64 {
            let (Some(va), Some(vb)) = (a.get(bx + x, by + y), b.get(bx + x + sx, by + y + sy))
            else {
                continue;
            };
            count += 1;
            for ch in 0..3 {
                let (p, q) = (f64::from(va[ch]), f64::from(vb[ch]));
                let t = &mut s[ch];
                t[0] += p;
                t[1] += q;
                t[2] += p * p;
                t[3] += q * q;
                t[4] += p * q;
            }
        }
    }
    if (count as f64) < MIN_VALID * (n * n) as f64 {
        return None;
    }
    let m = count as f64;
    let mut total = 0.0;
    let mut channels = 0.0;
    for t in &s {
        let va = t[2] - t[0] * t[0] / m;
        let vb = t[3] - t[1] * t[1] / m;
        let cov = t[4] - t[0] * t[1] / m;
        // A flat channel (e.g. grey grout in one colour) says nothing; skip it.
        if va > 1e-6 * m && vb > 1e-6 * m {
            total += cov / (va * vb).sqrt();
            channels += 1.0;
        }
    }
    (channels > 0.0).then(|| total / channels)
}

/// The best integer shift, its correlation, and the correlations one cell left,
/// right, up and down of it (for the sub-cell parabola).
type Peak = ((i64, i64), f64, [Option<f64>; 4]);

/// Best shift of block (bx, by) of `a` against `b` within `radius` around `centre`.
pub(super) fn best_shift(
    a: &PlaneImage,
    b: &PlaneImage,
    bx: i64,
    by: i64,
    n: usize,
    centre: (i64, i64),
    radius: i32,
) -> Option<Peak> {
    let mut best: Option<((i64, i64), f64)> = None;
    for sy in -radius..=radius {
        for sx in -radius..=radius {
            let s = (centre.0 + i64::from(sx), centre.1 + i64::from(sy));
            if let Some(v) = ncc(a, b, bx, by, n, s.0, s.1) {
                if best.is_none_or(|b| v > b.1) {
                    best = Some((s, v));
                }
            }
        }
    }
    let (s, v) = best?;
    let nb =
        [(-1, 0), (1, 0), (0, -1), (0, 1)].map(|(dx, dy)| ncc(a, b, bx, by, n, s.0 + dx, s.1 + dy));
    Some((s, v, nb))
}

/// Sub-cell offset of a parabola through (-1, l), (0, c), (1, r).
pub(super) fn parabola(l: Option<f64>, c: f64, r: Option<f64>) -> f64 {
    match (l, r) {
        (Some(l), Some(r)) => {
            let d = l - 2.0 * c + r;
            if d < -1e-9 {
                (0.5 * (l - r) / d).clamp(-0.5, 0.5)
            } else {
                0.0
            }
        }
        _ => 0.0,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn plane(w: usize, h: usize, f: impl Fn(usize, usize) -> [f32; 3]) -> PlaneImage {
        PlaneImage {
            w,
            h,
            px: (0..w * h).map(|i| Some(f(i % w, i / w))).collect(),
        }
    }

    fn texture(x: usize, y: usize) -> [f32; 3] {
        let v = |k: usize| {
            let h = (x.wrapping_mul(73_856_093)
                ^ y.wrapping_mul(19_349_663)
                ^ k.wrapping_mul(83_492_791))
                % 1000;
            h as f32 / 4.0
        };
        [v(1), v(2), v(3)]
    }

    #[test]
    fn a_shifted_block_is_found_at_its_shift_despite_a_change_of_gain() {
        let b = plane(80, 80, texture);
        // `a` sees b shifted by (7, -3) under a dimmer, tinted light.
        let a = plane(80, 80, |x, y| {
            let t = texture(x + 7, (y as i64 - 3).rem_euclid(1000) as usize);
            [0.5 * t[0] + 10.0, 0.7 * t[1], 0.6 * t[2] + 3.0]
        });
        let (s, v, _) = best_shift(&a, &b, 20, 20, 30, (0, 0), 10).unwrap();
        assert_eq!(s, (7, -3));
        assert!(v > 0.99, "{v}");
    }

    #[test]
    fn parabola_finds_the_peak_between_cells() {
        // Samples of -(x - 0.3)^2 at -1, 0, 1.
        let f = |x: f64| -(x - 0.3) * (x - 0.3);
        assert!((parabola(Some(f(-1.0)), f(0.0), Some(f(1.0))) - 0.3).abs() < 1e-9);
        assert_eq!(parabola(None, 1.0, Some(0.0)), 0.0);
    }
}
