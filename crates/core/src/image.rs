//! A minimal interleaved image type, our own so that no stage depends on OpenCV's.

/// Interleaved image: `data[(row * width + col) * channels + c]`.
#[derive(Debug, Clone, PartialEq)]
pub struct Image<T> {
    /// Columns.
    pub width: usize,
    /// Rows.
    pub height: usize,
    /// Channels per pixel.
    pub channels: usize,
    /// Samples, row-major, interleaved.
    pub data: Vec<T>,
}

/// Floating-point image (linear unless stated otherwise).
pub type ImageF32 = Image<f32>;
/// 8-bit image (sRGB-encoded unless stated otherwise).
pub type ImageU8 = Image<u8>;

impl<T: Copy + Default> Image<T> {
    /// A zero-filled image.
    pub fn new(width: usize, height: usize, channels: usize) -> Self {
        Self {
            width,
            height,
            channels,
            data: vec![T::default(); width * height * channels],
        }
    }

    /// Wrap existing samples; `None` if the length does not match.
    pub fn from_vec(width: usize, height: usize, channels: usize, data: Vec<T>) -> Option<Self> {
        (data.len() == width * height * channels).then_some(Self {
            width,
            height,
            channels,
            data,
        })
    }

    /// The samples of one pixel.
    #[inline]
    pub fn pixel(&self, col: usize, row: usize) -> &[T] {
        let i = (row * self.width + col) * self.channels;
        &self.data[i..i + self.channels]
    }

    /// The samples of one pixel, mutable.
    #[inline]
    pub fn pixel_mut(&mut self, col: usize, row: usize) -> &mut [T] {
        let i = (row * self.width + col) * self.channels;
        &mut self.data[i..i + self.channels]
    }

    /// One row of samples.
    pub fn row(&self, row: usize) -> &[T] {
        let n = self.width * self.channels;
        &self.data[row * n..(row + 1) * n]
    }
}

/// The four taps of a bilinear sample at continuous pixel coordinates (centres at
/// integers), clamped at the border: `(x0, y0, x1, y1, fx, fy)`. Non-finite
/// coordinates read pixel 0.
fn bilinear_taps(
    width: usize,
    height: usize,
    x: f64,
    y: f64,
) -> (usize, usize, usize, usize, f32, f32) {
    let xm = (width as f64 - 1.0).max(0.0);
    let ym = (height as f64 - 1.0).max(0.0);
    let x = if x.is_finite() { x.clamp(0.0, xm) } else { 0.0 };
    let y = if y.is_finite() { y.clamp(0.0, ym) } else { 0.0 };
    let x0 = x.floor() as usize;
    let y0 = y.floor() as usize;
    let x1 = (x0 + 1).min(width.saturating_sub(1));
    let y1 = (y0 + 1).min(height.saturating_sub(1));
    (
        x0,
        y0,
        x1,
        y1,
        (x - x0 as f64) as f32,
        (y - y0 as f64) as f32,
    )
}

/// Weighted sum of the 4 x 4 taps `read(col, row)` into `out` (clamped at 0); returns
/// the largest tap value.
#[inline(always)]
fn cubic_taps(
    cols: &[usize; 4],
    rows: &[usize; 4],
    wx: [f32; 4],
    wy: [f32; 4],
    out: &mut [f32; 3],
    read: impl Fn(usize, usize) -> [f32; 3],
) -> f32 {
    let mut acc = [0f32; 3];
    let mut peak = 0f32;
    for (r, wr) in rows.iter().zip(wy) {
        let mut line = [0f32; 3];
        for (c, wc) in cols.iter().zip(wx) {
            let v = read(*c, *r);
            for k in 0..3 {
                peak = peak.max(v[k]);
                line[k] += wc * v[k];
            }
        }
        for k in 0..3 {
            acc[k] += wr * line[k];
        }
    }
    for k in 0..3 {
        out[k] = acc[k].max(0.0);
    }
    peak
}

/// [`cubic_taps`] for an RGB 8-bit image whose 4x4 window at (`x0`-1, `y0`-1) lies inside
/// it (None otherwise): one bounds check per row of taps instead of one per sample, for
/// the observation pass's tens of millions of samples per frame sweep. Sums in the same
/// order as [`cubic_taps`], so the results are identical.
#[inline]
fn srgb8_cubic_interior(
    i: &ImageU8,
    x0: usize,
    y0: usize,
    wx: [f32; 4],
    wy: [f32; 4],
    lut: &[f32; 256],
    out: &mut [f32; 3],
) -> Option<f32> {
    if i.channels != 3 || x0 == 0 || y0 == 0 || x0 + 2 >= i.width || y0 + 2 >= i.height {
        return None;
    }
    let stride = i.width * 3;
    let base = (y0 - 1) * stride + (x0 - 1) * 3;
    let mut acc = [0f32; 3];
    let mut peak = 0f32;
    for (j, wr) in wy.iter().enumerate() {
        let at = base + j * stride;
        let taps: &[u8; 12] = i.data.get(at..at + 12)?.try_into().ok()?;
        let mut line = [0f32; 3];
        for (c, wc) in wx.iter().enumerate() {
            for k in 0..3 {
                let v = lut[usize::from(taps[3 * c + k])];
                peak = peak.max(v);
                line[k] += wc * v;
            }
        }
        for k in 0..3 {
            acc[k] += wr * line[k];
        }
    }
    for k in 0..3 {
        out[k] = acc[k].max(0.0);
    }
    Some(peak)
}

/// Catmull-Rom weights of the taps at -1, 0, 1, 2 for a fraction `t` in [0, 1).
#[inline]
fn catmull_rom_weights(t: f32) -> [f32; 4] {
    let (t2, t3) = (t * t, t * t * t);
    [
        0.5 * (-t3 + 2.0 * t2 - t),
        0.5 * (3.0 * t3 - 5.0 * t2 + 2.0),
        0.5 * (-3.0 * t3 + 4.0 * t2 + t),
        0.5 * (t3 - t2),
    ]
}

impl ImageF32 {
    /// Bilinear sample at continuous pixel coordinates (centres at integers), clamped at
    /// the border. Writes `channels` values into `out`.
    pub fn sample_bilinear(&self, x: f64, y: f64, out: &mut [f32]) {
        let (x0, y0, x1, y1, fx, fy) = bilinear_taps(self.width, self.height, x, y);
        let (a, b, c, d) = (
            self.pixel(x0, y0),
            self.pixel(x1, y0),
            self.pixel(x0, y1),
            self.pixel(x1, y1),
        );
        for (k, o) in out.iter_mut().enumerate().take(self.channels) {
            let top = a[k] + (b[k] - a[k]) * fx;
            let bot = c[k] + (d[k] - c[k]) * fx;
            *o = top + (bot - top) * fy;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn srgb8_frames_interpolate_after_linearising() {
        let lut = crate::color::srgb8_to_linear_table();
        let u8img = ImageU8::from_vec(2, 1, 3, vec![0, 0, 0, 255, 128, 10]).unwrap();
        let lin = ImageF32::from_vec(
            2,
            1,
            3,
            u8img.data.iter().map(|&v| lut[usize::from(v)]).collect(),
        )
        .unwrap();
        let (a, b) = (FrameImage::Srgb8(u8img), FrameImage::Linear(lin));
        for x in [-1.0, 0.0, 0.25, 0.5, 1.0, 7.0] {
            let (mut p, mut q) = ([0f32; 3], [0f32; 3]);
            a.sample_linear(x, 0.3, &lut, &mut p);
            b.sample_linear(x, 0.3, &lut, &mut q);
            assert_eq!(p, q);
        }
        // Halfway between black and white is linear 0.5, not sRGB code 128.
        let mut p = [0f32; 3];
        a.sample_linear(0.5, 0.0, &lut, &mut p);
        assert!((p[0] - 0.5).abs() < 1e-6);
        assert_eq!(a.shape(), (2, 1, 3));
    }

    #[test]
    fn bicubic_srgb8_interior_path_matches_the_general_one() {
        let lut = crate::color::srgb8_to_linear_table();
        let (w, h) = (9, 7);
        let codes: Vec<u8> = (0..w * h * 3)
            .map(|i| ((i * 97 + 13) % 256) as u8)
            .collect();
        let linear = codes.iter().map(|&c| lut[usize::from(c)]).collect();
        let a = FrameImage::Srgb8(ImageU8::from_vec(w, h, 3, codes).unwrap());
        let b = FrameImage::Linear(ImageF32::from_vec(w, h, 3, linear).unwrap());
        let (mut p, mut q) = ([0f32; 3], [0f32; 3]);
        for i in 0..=100 {
            for j in 0..=80 {
                let (x, y) = (i as f64 * 0.0901 - 0.2, j as f64 * 0.0851 - 0.2);
                let (pa, pb) = (
                    a.sample_linear_cubic(x, y, &lut, &mut p),
                    b.sample_linear_cubic(x, y, &lut, &mut q),
                );
                assert_eq!((p, pa), (q, pb), "at ({x}, {y})");
            }
        }
    }

    #[test]
    fn bicubic_interpolates_pixels_and_reproduces_ramps() {
        let lut = crate::color::srgb8_to_linear_table();
        // A horizontal linear ramp in linear units, 6 x 4.
        let (w, h) = (6, 4);
        let data: Vec<f32> = (0..h)
            .flat_map(|_| (0..w).flat_map(|c| [0.1 * c as f32, 0.05, 0.5 - 0.05 * c as f32]))
            .collect();
        let img = FrameImage::Linear(ImageF32::from_vec(w, h, 3, data).unwrap());
        let mut o = [0f32; 3];
        // Pixel centres return the pixel; between them, away from the clamped border,
        // the ramp comes back exactly.
        let peak = img.sample_linear_cubic(2.0, 1.0, &lut, &mut o);
        assert!(
            (o[0] - 0.2).abs() < 1e-6 && (o[2] - 0.4).abs() < 1e-6,
            "{o:?}"
        );
        // The taps are columns 1-4: the largest value is channel 2 of column 1.
        assert!((peak - 0.45).abs() < 1e-6, "{peak}");
        img.sample_linear_cubic(2.3, 1.7, &lut, &mut o);
        assert!(
            (o[0] - 0.23).abs() < 1e-5 && (o[1] - 0.05).abs() < 1e-6,
            "{o:?}"
        );
        // sRGB frames are linearised before interpolation, as in the bilinear sampler.
        let u8img = ImageU8::from_vec(4, 1, 3, vec![0, 0, 0, 255, 128, 10, 40, 40, 40, 200, 0, 90])
            .unwrap();
        let lin = ImageF32::from_vec(
            4,
            1,
            3,
            u8img.data.iter().map(|&v| lut[usize::from(v)]).collect(),
        )
        .unwrap();
        let (a, b) = (FrameImage::Srgb8(u8img), FrameImage::Linear(lin));
        for x in [-2.0, 0.0, 0.4, 1.5, 2.9, 9.0] {
            let (mut p, mut q) = ([0f32; 3], [0f32; 3]);
            assert_eq!(
                a.sample_linear_cubic(x, 0.0, &lut, &mut p),
                b.sample_linear_cubic(x, 0.0, &lut, &mut q)
            );
            assert_eq!(p, q);
            assert!(p.iter().all(|v| *v >= 0.0 && v.is_finite()));
        }
        // A bright pixel's ringing next to black is clamped at 0, never negative.
        let mut row = vec![0.0f32; 15];
        row[3..6].copy_from_slice(&[1.0; 3]);
        let spike = FrameImage::Linear(ImageF32::from_vec(5, 1, 3, row).unwrap());
        spike.sample_linear_cubic(2.5, 0.0, &lut, &mut o);
        assert_eq!(o, [0.0; 3]);
        spike.sample_linear_cubic(1.5, 0.0, &lut, &mut o);
        assert!(o[0] > 0.5, "{o:?}");
        spike.sample_linear_cubic(f64::NAN, 0.0, &lut, &mut o);
        assert!(o.iter().all(|v| v.is_finite()));
    }

    #[test]
    fn bilinear_hits_pixel_centres_and_midpoints() {
        let img = ImageF32::from_vec(2, 2, 1, vec![0.0, 1.0, 2.0, 3.0]).unwrap();
        let mut o = [0f32];
        img.sample_bilinear(0.0, 0.0, &mut o);
        assert_eq!(o[0], 0.0);
        img.sample_bilinear(0.5, 0.5, &mut o);
        assert!((o[0] - 1.5).abs() < 1e-6);
        img.sample_bilinear(10.0, -3.0, &mut o);
        assert_eq!(o[0], 1.0);
        img.sample_bilinear(f64::NAN, 0.0, &mut o);
        assert!(o[0].is_finite());
    }
}

/// A decoded frame as the appearance stage receives it: 8-bit sRGB straight from a
/// video decoder (linearised per sample, so a 4K frame never exists as 100 MB of
/// floats), or already-linear floats (EXR, 16-bit PNG).
#[derive(Debug, Clone)]
pub enum FrameImage {
    /// 8-bit values with the sRGB transfer curve, RGB.
    Srgb8(ImageU8),
    /// Linear floats, RGB.
    Linear(ImageF32),
}

impl FrameImage {
    /// Bicubic (Catmull-Rom, Keys a = -1/2) sample of linear RGB at continuous pixel
    /// coordinates (centres at integers), clamped at the border; interpolation happens
    /// after linearisation. Sharper than [`sample_linear`](Self::sample_linear), whose
    /// one-pixel tent blurs pixel-scale texture a second time when video pixels are
    /// about the size of output pixels. Overshoot below 0 is clamped. Returns the
    /// largest linear value among the 16 taps, so that a caller can tell samples next to
    /// clipped pixels, where the cubic's negative lobes ring.
    pub fn sample_linear_cubic(&self, x: f64, y: f64, lut: &[f32; 256], out: &mut [f32; 3]) -> f32 {
        let (w, h, _) = self.shape();
        let xm = (w as f64 - 1.0).max(0.0);
        let ym = (h as f64 - 1.0).max(0.0);
        let x = if x.is_finite() { x.clamp(0.0, xm) } else { 0.0 };
        let y = if y.is_finite() { y.clamp(0.0, ym) } else { 0.0 };
        // Both are clamped to >= 0, so truncation is the floor (without a libm call).
        let (x0, y0) = ((x as usize) as f64, (y as usize) as f64);
        let (wx, wy) = (
            catmull_rom_weights((x - x0) as f32),
            catmull_rom_weights((y - y0) as f32),
        );
        if let Self::Srgb8(i) = self {
            if let Some(peak) = srgb8_cubic_interior(i, x0 as usize, y0 as usize, wx, wy, lut, out)
            {
                return peak;
            }
        }
        let tap = |v: f64, m: usize| (v.max(0.0) as usize).min(m.saturating_sub(1));
        let cols = [-1.0, 0.0, 1.0, 2.0].map(|d| tap(x0 + d, w));
        let rows = [-1.0, 0.0, 1.0, 2.0].map(|d| tap(y0 + d, h));
        // One loop per pixel type, so that the 16 taps do not branch on it.
        match self {
            Self::Srgb8(i) => cubic_taps(&cols, &rows, wx, wy, out, |c, r| {
                let p = i.pixel(c, r);
                [0, 1, 2].map(|k| lut[usize::from(p[k])])
            }),
            Self::Linear(i) => cubic_taps(&cols, &rows, wx, wy, out, |c, r| {
                let p = i.pixel(c, r);
                [p[0], p[1], p[2]]
            }),
        }
    }

    /// (width, height, channels).
    pub fn shape(&self) -> (usize, usize, usize) {
        match self {
            Self::Srgb8(i) => (i.width, i.height, i.channels),
            Self::Linear(i) => (i.width, i.height, i.channels),
        }
    }

    /// Bilinear sample of linear RGB at continuous pixel coordinates (centres at
    /// integers), clamped at the border. `lut` maps 8-bit sRGB codes to linear values
    /// (see [`crate::color::srgb8_to_linear_table`]); interpolation happens after
    /// linearisation, as the physics requires.
    pub fn sample_linear(&self, x: f64, y: f64, lut: &[f32; 256], out: &mut [f32; 3]) {
        match self {
            Self::Linear(i) => i.sample_bilinear(x, y, out),
            Self::Srgb8(i) => {
                let (x0, y0, x1, y1, fx, fy) = bilinear_taps(i.width, i.height, x, y);
                let (a, b, c, d) = (
                    i.pixel(x0, y0),
                    i.pixel(x1, y0),
                    i.pixel(x0, y1),
                    i.pixel(x1, y1),
                );
                for k in 0..3 {
                    let (a, b) = (lut[usize::from(a[k])], lut[usize::from(b[k])]);
                    let (c, d) = (lut[usize::from(c[k])], lut[usize::from(d[k])]);
                    let top = a + (b - a) * fx;
                    let bot = c + (d - c) * fx;
                    out[k] = top + (bot - top) * fy;
                }
            }
        }
    }
}
