//! Colour transfer functions. All fitting and rendering happens in linear RGB with the
//! sRGB / Rec.709 primaries; only 8-bit video frames, JPEG photos and colour PNG maps
//! carry the sRGB transfer curve.

/// sRGB-encoded value in [0, 1] to linear.
#[inline]
pub fn srgb_to_linear(v: f64) -> f64 {
    if v <= 0.04045 {
        v / 12.92
    } else {
        ((v + 0.055) / 1.055).powf(2.4)
    }
}

/// Linear value to sRGB encoding; input is clamped to [0, 1].
#[inline]
pub fn linear_to_srgb(v: f64) -> f64 {
    let v = if v.is_finite() {
        v.clamp(0.0, 1.0)
    } else {
        0.0
    };
    if v <= 0.003_130_8 {
        12.92 * v
    } else {
        1.055 * v.powf(1.0 / 2.4) - 0.055
    }
}

/// Linear value to an 8-bit sRGB code value (rounded, clamped).
#[inline]
pub fn linear_to_srgb8(v: f64) -> u8 {
    (linear_to_srgb(v) * 255.0).round() as u8
}

/// Fast linear-to-8-bit-sRGB encoder: a table over 2^16 linear steps, exact to the
/// code value except within 1/65536 of a rounding boundary. For per-pixel use.
pub struct Srgb8Encoder {
    table: Vec<u8>,
}

impl Srgb8Encoder {
    /// Build the table (64 KiB).
    pub fn new() -> Self {
        let table = (0..=65535u32)
            .map(|i| linear_to_srgb8(f64::from(i) / 65535.0))
            .collect();
        Self { table }
    }

    /// Encode a linear value (clamped to [0, 1]; NaN gives 0).
    #[inline]
    pub fn encode(&self, v: f64) -> u8 {
        let i = if v.is_finite() {
            (v.clamp(0.0, 1.0) * 65535.0 + 0.5) as usize
        } else {
            0
        };
        self.table[i.min(65535)]
    }
}

impl Default for Srgb8Encoder {
    fn default() -> Self {
        Self::new()
    }
}

/// Lookup table from 8-bit sRGB code values to linear values.
pub fn srgb8_to_linear_table() -> [f32; 256] {
    let mut t = [0f32; 256];
    for (i, v) in t.iter_mut().enumerate() {
        *v = srgb_to_linear(i as f64 / 255.0) as f32;
    }
    t
}

/// Linear sRGB to CIE 1976 L*a*b* (D65 white).
pub fn linear_rgb_to_lab(rgb: [f64; 3]) -> [f64; 3] {
    let [r, g, b] = rgb;
    let x = 0.412_456_4 * r + 0.357_576_1 * g + 0.180_437_5 * b;
    let y = 0.212_672_9 * r + 0.715_152_2 * g + 0.072_175_0 * b;
    let z = 0.019_333_9 * r + 0.119_192_0 * g + 0.950_304_1 * b;
    let f = |t: f64| {
        let d: f64 = 6.0 / 29.0;
        if t > d * d * d {
            t.cbrt()
        } else {
            t / (3.0 * d * d) + 4.0 / 29.0
        }
    };
    let (fx, fy, fz) = (f(x / 0.950_47), f(y), f(z / 1.088_83));
    [116.0 * fy - 16.0, 500.0 * (fx - fy), 200.0 * (fy - fz)]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn srgb_round_trip_and_known_values() {
        for i in 0..=255u32 {
            let v = f64::from(i) / 255.0;
            assert!((linear_to_srgb(srgb_to_linear(v)) - v).abs() < 1e-12);
        }
        assert!((srgb_to_linear(0.5) - 0.214_041).abs() < 1e-5);
        assert_eq!(linear_to_srgb8(1.0), 255);
        assert_eq!(linear_to_srgb8(f64::NAN), 0);
    }

    #[test]
    fn table_encoder_matches_exact_encoding() {
        let e = Srgb8Encoder::new();
        let mut off = 0;
        for i in 0..20000 {
            let v = f64::from(i) / 19999.0;
            let d = (i32::from(e.encode(v)) - i32::from(linear_to_srgb8(v))).abs();
            assert!(d <= 1);
            off += d;
        }
        assert!(off < 200, "{off} of 20000 differ by one code value");
        assert_eq!(e.encode(f64::NAN), 0);
        assert_eq!(e.encode(7.0), 255);
    }

    #[test]
    fn lab_of_white_and_black() {
        let w = linear_rgb_to_lab([1.0, 1.0, 1.0]);
        assert!((w[0] - 100.0).abs() < 0.01 && w[1].abs() < 0.01 && w[2].abs() < 0.01);
        let k = linear_rgb_to_lab([0.0, 0.0, 0.0]);
        assert!(k[0].abs() < 1e-9);
    }
}

/// Luma coefficients `(Kr, Kb)` of a Y'CbCr matrix.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct YcbcrMatrix {
    /// Red weight of luma.
    pub kr: f64,
    /// Blue weight of luma.
    pub kb: f64,
}

impl YcbcrMatrix {
    /// ITU-R BT.601 (SD video; what OpenCV's and FFmpeg's converters assume untagged).
    pub const BT601: Self = Self {
        kr: 0.299,
        kb: 0.114,
    };
    /// ITU-R BT.709 (HD video; what phones record in SDR).
    pub const BT709: Self = Self {
        kr: 0.2126,
        kb: 0.0722,
    };

    /// `(Y', Cb, Cr)` from `(R', G', B')`, unscaled (Y' in [0, 1], Cb and Cr in
    /// [-0.5, 0.5]); limited or full range scale all three alike afterwards.
    pub fn from_rgb(&self) -> crate::geometry::Mat3 {
        let (kr, kb) = (self.kr, self.kb);
        let kg = 1.0 - kr - kb;
        let (cb, cr) = (0.5 / (1.0 - kb), 0.5 / (1.0 - kr));
        crate::geometry::Mat3::new(
            kr,
            kg,
            kb,
            -kr * cb,
            -kg * cb,
            (1.0 - kb) * cb,
            (1.0 - kr) * cr,
            -kg * cr,
            -kb * cr,
        )
    }
}

/// The 3x3 map on gamma-encoded `(R', G', B')` that turns colours a decoder produced
/// with the wrong Y'CbCr matrix (`assumed`) into those of the stream's own
/// (`actual`): `from_rgb(actual)^-1 * from_rgb(assumed)`. Its inverse makes a
/// converter that applies `assumed` store what `actual` would.
pub fn ycbcr_matrix_fix(actual: YcbcrMatrix, assumed: YcbcrMatrix) -> crate::geometry::Mat3 {
    actual
        .from_rgb()
        .try_inverse()
        .map_or_else(crate::geometry::Mat3::identity, |inv| {
            inv * assumed.from_rgb()
        })
}

#[cfg(test)]
mod ycbcr_tests {
    use super::*;
    use crate::geometry::Vec3;

    #[test]
    fn grey_keeps_and_the_fix_inverts_a_wrong_decode() {
        let fix = ycbcr_matrix_fix(YcbcrMatrix::BT709, YcbcrMatrix::BT601);
        // Greys have Cb = Cr = 0 under every matrix: unchanged.
        let g = fix * Vec3::new(0.4, 0.4, 0.4);
        assert!((g - Vec3::new(0.4, 0.4, 0.4)).norm() < 1e-12);
        // Encode a colour with BT.709, decode it as BT.601, fix: the colour again.
        let rgb = Vec3::new(0.8, 0.2, 0.1);
        let ycc = YcbcrMatrix::BT709.from_rgb() * rgb;
        let wrong = YcbcrMatrix::BT601.from_rgb().try_inverse().unwrap() * ycc;
        assert!((wrong - rgb).norm() > 0.05, "{wrong:?}");
        assert!((fix * wrong - rgb).norm() < 1e-12);
    }
}
