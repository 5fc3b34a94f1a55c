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

impl YcbcrMatrix {
    /// ITU-R BT.2020 non-constant luminance (HDR and wide-gamut video).
    pub const BT2020: Self = Self {
        kr: 0.2627,
        kb: 0.0593,
    };
}

/// Transfer characteristic of a video stream: how its R'G'B' code values relate to
/// linear light.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Transfer {
    /// SDR (BT.709, BT.601 or sRGB tags, or untagged): decoded with the sRGB curve,
    /// linear 1 = the format's white.
    Sdr,
    /// Hybrid log-gamma (ARIB STD-B67, BT.2100): scene light, linear 1 = the format's
    /// peak; its reference white (75% signal) is [`HLG_REFERENCE_WHITE`].
    Hlg,
    /// Perceptual quantiser (SMPTE ST 2084, BT.2100): display light, linear 1 =
    /// [`PQ_UNIT_NITS`] cd/m^2; brighter values are clipped.
    Pq,
}

/// Linear level of HLG's reference white (75% signal), with the peak at 1.
pub const HLG_REFERENCE_WHITE: f64 = 0.264_962_5;
/// PQ luminance that decodes to linear 1, cd/m^2 (a phone's HDR10 mastering peak).
pub const PQ_UNIT_NITS: f64 = 1000.0;
/// PQ luminance of reference (graphics) white, cd/m^2 (ITU-R BT.2408).
pub const PQ_REFERENCE_WHITE_NITS: f64 = 203.0;

const HLG_A: f64 = 0.178_832_77;
const HLG_B: f64 = 0.284_668_92;
const HLG_C: f64 = 0.559_910_73;
const PQ_M1: f64 = 0.159_301_757_812_5;
const PQ_M2: f64 = 78.843_75;
const PQ_C1: f64 = 0.835_937_5;
const PQ_C2: f64 = 18.851_562_5;
const PQ_C3: f64 = 18.6875;

impl Transfer {
    /// Linear value of a non-linear code value `v` in [0, 1].
    pub fn to_linear(self, v: f64) -> f64 {
        let v = v.clamp(0.0, 1.0);
        match self {
            Self::Sdr => srgb_to_linear(v),
            Self::Hlg => {
                if v <= 0.5 {
                    v * v / 3.0
                } else {
                    (((v - HLG_C) / HLG_A).exp() + HLG_B) / 12.0
                }
            }
            Self::Pq => {
                let p = v.powf(1.0 / PQ_M2);
                let nits =
                    10_000.0 * ((p - PQ_C1).max(0.0) / (PQ_C2 - PQ_C3 * p)).powf(1.0 / PQ_M1);
                (nits / PQ_UNIT_NITS).min(1.0)
            }
        }
    }

    /// Non-linear code value in [0, 1] of a linear value (the inverse of
    /// [`to_linear`](Self::to_linear); values above the range clip).
    pub fn from_linear(self, l: f64) -> f64 {
        let l = l.clamp(0.0, 1.0);
        match self {
            Self::Sdr => linear_to_srgb(l),
            Self::Hlg => {
                if l <= 1.0 / 12.0 {
                    (3.0 * l).sqrt()
                } else {
                    HLG_A * (12.0 * l - HLG_B).ln() + HLG_C
                }
            }
            Self::Pq => {
                let y = (l * PQ_UNIT_NITS / 10_000.0).powf(PQ_M1);
                ((PQ_C1 + PQ_C2 * y) / (1.0 + PQ_C3 * y)).powf(PQ_M2)
            }
        }
    }

    /// Linear level of the format's reference (diffuse) white: 1 for SDR.
    pub fn reference_white(self) -> f64 {
        match self {
            Self::Sdr => 1.0,
            Self::Hlg => HLG_REFERENCE_WHITE,
            Self::Pq => PQ_REFERENCE_WHITE_NITS / PQ_UNIT_NITS,
        }
    }

    /// Name for people.
    pub fn label(self) -> &'static str {
        match self {
            Self::Sdr => "SDR (sRGB curve)",
            Self::Hlg => "HLG",
            Self::Pq => "PQ",
        }
    }
}

/// Linear BT.2020 RGB to linear BT.709/sRGB RGB (same D65 white; ITU-R BT.2087).
pub const BT2020_TO_BT709: [[f64; 3]; 3] = [
    [1.660_491, -0.587_641, -0.072_850],
    [-0.124_550, 1.132_900, -0.008_349],
    [-0.018_151, -0.100_579, 1.118_730],
];

/// Linear BT.709/sRGB RGB to linear BT.2020 RGB (the inverse of [`BT2020_TO_BT709`]).
pub const BT709_TO_BT2020: [[f64; 3]; 3] = [
    [0.627_404, 0.329_283, 0.043_313],
    [0.069_097, 0.919_541, 0.011_362],
    [0.016_391, 0.088_013, 0.895_595],
];

/// `m * v` for a row-major 3x3.
pub fn mul3(m: &[[f64; 3]; 3], v: [f64; 3]) -> [f64; 3] {
    [0, 1, 2].map(|r| m[r][0] * v[0] + m[r][1] * v[1] + m[r][2] * v[2])
}

#[cfg(test)]
mod hdr_tests {
    use super::*;

    #[test]
    fn transfer_curves_invert_and_hit_their_reference_points() {
        for t in [Transfer::Sdr, Transfer::Hlg, Transfer::Pq] {
            for k in 0..=100 {
                let v = k as f64 / 100.0;
                let back = t.from_linear(t.to_linear(v));
                assert!(
                    (back - v).abs() < 1e-6 || t.to_linear(v) >= 1.0,
                    "{t:?} {v} {back}"
                );
            }
        }
        // HLG: 50% signal is 1/12 of the peak, 75% is reference white, 100% the peak.
        assert!((Transfer::Hlg.to_linear(0.5) - 1.0 / 12.0).abs() < 1e-12);
        assert!((Transfer::Hlg.to_linear(0.75) - HLG_REFERENCE_WHITE).abs() < 1e-6);
        assert!((Transfer::Hlg.to_linear(1.0) - 1.0).abs() < 1e-6);
        // PQ: 203 cd/m^2 at 58% signal (BT.2408), 1000 cd/m^2 at 75.2%.
        assert!((Transfer::Pq.from_linear(0.203) - 0.5807).abs() < 1e-3);
        assert!((Transfer::Pq.from_linear(1.0) - 0.7518).abs() < 1e-3);
    }

    #[test]
    fn the_primaries_matrices_invert_and_keep_white() {
        let w = mul3(&BT2020_TO_BT709, [1.0, 1.0, 1.0]);
        assert!(w.iter().all(|v| (v - 1.0).abs() < 1e-5), "{w:?}");
        let rgb = [0.3, 0.6, 0.2];
        let back = mul3(&BT2020_TO_BT709, mul3(&BT709_TO_BT2020, rgb));
        for k in 0..3 {
            assert!((back[k] - rgb[k]).abs() < 1e-5, "{back:?}");
        }
    }
}
