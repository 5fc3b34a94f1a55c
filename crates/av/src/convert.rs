//! Y'CbCr planes to linear RGB: range, matrix, chroma upsampling, transfer curve,
//! primaries; and rotation. Pure arithmetic on the decoded planes.

use ffmpeg_next as ff;
use rayon::prelude::*;
use svbrdf_core::color::{Transfer, YcbcrMatrix, BT2020_TO_BT709};
use svbrdf_core::image::ImageF32;

/// A planar Y'CbCr layout.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct YuvFormat {
    /// Bits per sample (8 or 10, stored in 1 or 2 bytes little-endian).
    pub bits: u32,
    /// Horizontal chroma subsampling, log2 (1 for 4:2:0 and 4:2:2).
    pub shift_x: u32,
    /// Vertical chroma subsampling, log2 (1 for 4:2:0).
    pub shift_y: u32,
    /// A `yuvj` format: full range whatever the tag says.
    pub full_range_by_name: bool,
}

impl YuvFormat {
    /// The layout of an FFmpeg pixel format, if it is one we convert.
    pub fn of(p: ff::format::Pixel) -> Option<Self> {
        use ff::format::Pixel as P;
        let (bits, sx, sy, j) = match p {
            P::YUV420P => (8, 1, 1, false),
            P::YUVJ420P => (8, 1, 1, true),
            P::YUV422P => (8, 1, 0, false),
            P::YUVJ422P => (8, 1, 0, true),
            P::YUV444P => (8, 0, 0, false),
            P::YUVJ444P => (8, 0, 0, true),
            P::YUV420P10LE => (10, 1, 1, false),
            P::YUV422P10LE => (10, 1, 0, false),
            P::YUV444P10LE => (10, 0, 0, false),
            _ => return None,
        };
        Some(Self {
            bits,
            shift_x: sx,
            shift_y: sy,
            full_range_by_name: j,
        })
    }

    /// Name as FFmpeg spells it.
    pub fn name(&self) -> String {
        let sub = match (self.shift_x, self.shift_y) {
            (1, 1) => "420",
            (1, 0) => "422",
            _ => "444",
        };
        let j = if self.full_range_by_name { "j" } else { "" };
        if self.bits > 8 {
            format!("yuv{j}{sub}p{}le", self.bits)
        } else {
            format!("yuv{j}{sub}p")
        }
    }
}

/// A frame's planes as they lie in memory.
#[derive(Debug, Clone, Copy)]
pub struct Layout {
    /// Pixel layout.
    pub format: YuvFormat,
    /// Luma width, pixels.
    pub width: usize,
    /// Luma height, pixels.
    pub height: usize,
    /// Bytes per row of Y, Cb, Cr.
    pub strides: [usize; 3],
}

/// Entries of the transfer lookup table over [0, 1]: finer than 10-bit codes, so the
/// nearest entry is within 1/64 of a code of the exact value.
const LUT_SIZE: usize = 65536;

/// Linear value per non-linear code in [0, 1], sampled at `LUT_SIZE` points.
pub fn transfer_table(t: Transfer) -> Vec<f32> {
    (0..LUT_SIZE)
        .map(|k| t.to_linear(k as f64 / (LUT_SIZE - 1) as f64) as f32)
        .collect()
}

#[inline]
fn lookup(lut: &[f32], v: f32) -> f32 {
    lut[(v.clamp(0.0, 1.0) * (LUT_SIZE - 1) as f32 + 0.5) as usize]
}

/// Convert one frame. Chroma is upsampled bilinearly with MPEG-2/H.264 siting
/// (horizontally co-sited with the left luma sample, vertically between rows).
pub fn to_linear_rgb(
    l: &Layout,
    planes: [&[u8]; 3],
    matrix: YcbcrMatrix,
    full_range: bool,
    lut: &[f32],
    from_bt2020: bool,
) -> Result<ImageF32, String> {
    let f = l.format;
    let two = f.bits > 8;
    let bytes = if two { 2 } else { 1 };
    let (cw, ch) = (
        l.width.div_ceil(1 << f.shift_x),
        l.height.div_ceil(1 << f.shift_y),
    );
    let need = |p: usize, w: usize, h: usize| {
        h == 0 || (planes[p].len() >= (h - 1) * l.strides[p] + w * bytes)
    };
    if l.width == 0
        || l.height == 0
        || !need(0, l.width, l.height)
        || !need(1, cw, ch)
        || !need(2, cw, ch)
    {
        return Err(format!(
            "a frame's planes are smaller than its {}x{} {} size says (damaged file)",
            l.width,
            l.height,
            f.name()
        ));
    }
    let scale = f32::from(1u16 << (f.bits - 8));
    let max = ((1u32 << f.bits) - 1) as f32;
    let (y_off, y_span, c_off, c_span) = if full_range {
        (0.0, max, 128.0 * scale, max)
    } else {
        (16.0 * scale, 219.0 * scale, 128.0 * scale, 224.0 * scale)
    };
    let (kr, kb) = (matrix.kr as f32, matrix.kb as f32);
    let kg = 1.0 - kr - kb;
    let (rv, bu) = (2.0 * (1.0 - kr), 2.0 * (1.0 - kb));
    let (gu, gv) = (-bu * kb / kg, -rv * kr / kg);
    let m = BT2020_TO_BT709.map(|r| r.map(|v| v as f32));
    let mut out = ImageF32::new(l.width, l.height, 3);
    let read_row = |p: usize, y: usize, n: usize, dst: &mut Vec<f32>| {
        dst.clear();
        let row = &planes[p][y * l.strides[p]..];
        if two {
            dst.extend(
                row.chunks_exact(2)
                    .take(n)
                    .map(|b| f32::from(u16::from_le_bytes([b[0], b[1]]))),
            );
        } else {
            dst.extend(row[..n].iter().map(|v| f32::from(*v)));
        }
    };
    out.data
        .par_chunks_mut(l.width * 3)
        .enumerate()
        .for_each_init(
            || {
                (
                    Vec::new(),
                    Vec::new(),
                    Vec::new(),
                    Vec::new(),
                    Vec::new(),
                    vec![0f32; cw],
                    vec![0f32; cw],
                )
            },
            |(yrow, u0, u1, v0, v1, cu, cv), (row, line)| {
                // Chroma for this luma row, interpolated vertically (MPEG-2 siting:
                // between the two luma rows a chroma row covers).
                let cy = if f.shift_y == 1 {
                    ((row as f32 - 0.5) * 0.5).max(0.0)
                } else {
                    row as f32
                };
                let cy0 = (cy as usize).min(ch - 1);
                let cy1 = (cy0 + 1).min(ch - 1);
                let fy = cy - cy0 as f32;
                read_row(0, row, l.width, yrow);
                read_row(1, cy0, cw, u0);
                read_row(1, cy1, cw, u1);
                read_row(2, cy0, cw, v0);
                read_row(2, cy1, cw, v1);
                for k in 0..cw {
                    cu[k] = (u0[k] + (u1[k] - u0[k]) * fy - c_off) / c_span;
                    cv[k] = (v0[k] + (v1[k] - v0[k]) * fy - c_off) / c_span;
                }
                for (x, px) in line.chunks_exact_mut(3).enumerate() {
                    let yv = (yrow[x] - y_off) / y_span;
                    // Horizontally co-sited with even luma columns.
                    let (u, v) = if f.shift_x == 1 {
                        let k = x >> 1;
                        if x & 1 == 0 || k + 1 >= cw {
                            (cu[k.min(cw - 1)], cv[k.min(cw - 1)])
                        } else {
                            (0.5 * (cu[k] + cu[k + 1]), 0.5 * (cv[k] + cv[k + 1]))
                        }
                    } else {
                        (cu[x], cv[x])
                    };
                    let rgb =
                        [yv + rv * v, yv + gu * u + gv * v, yv + bu * u].map(|c| lookup(lut, c));
                    let rgb = if from_bt2020 {
                        [0, 1, 2].map(|r| {
                            (m[r][0] * rgb[0] + m[r][1] * rgb[1] + m[r][2] * rgb[2]).max(0.0)
                        })
                    } else {
                        rgb
                    };
                    px.copy_from_slice(&rgb);
                }
            },
        );
    Ok(out)
}

/// Turn an image clockwise by `deg` (0, 90, 180 or 270).
pub fn rotate(img: ImageF32, deg: u32) -> ImageF32 {
    let (w, h, c) = (img.width, img.height, img.channels);
    let (nw, nh) = if deg % 180 == 90 { (h, w) } else { (w, h) };
    if deg.is_multiple_of(360) {
        return img;
    }
    let mut out = ImageF32::new(nw, nh, c);
    for y in 0..nh {
        for x in 0..nw {
            // Source pixel of destination (x, y).
            let (sx, sy) = match deg % 360 {
                90 => (y, h - 1 - x),
                180 => (w - 1 - x, h - 1 - y),
                _ => (w - 1 - y, x),
            };
            let s = (sy * w + sx) * c;
            let d = (y * nw + x) * c;
            out.data[d..d + c].copy_from_slice(&img.data[s..s + c]);
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rotation_turns_clockwise() {
        // 2x1 image: left red, right green.
        let mut img = ImageF32::new(2, 1, 3);
        img.data.copy_from_slice(&[1.0, 0.0, 0.0, 0.0, 1.0, 0.0]);
        let r = rotate(img.clone(), 90);
        assert_eq!((r.width, r.height), (1, 2));
        // Clockwise: the left pixel goes to the top.
        assert_eq!(&r.data[0..3], &[1.0, 0.0, 0.0]);
        let r = rotate(img.clone(), 270);
        assert_eq!(&r.data[0..3], &[0.0, 1.0, 0.0]);
        let r = rotate(img, 180);
        assert_eq!(&r.data[0..3], &[0.0, 1.0, 0.0]);
    }

    #[test]
    fn limited_range_grey_and_white_convert_exactly() {
        let f = YuvFormat::of(ff::format::Pixel::YUV420P10LE).unwrap();
        let (w, h) = (4usize, 2usize);
        let plane =
            |v: u16, n: usize| -> Vec<u8> { (0..n).flat_map(|_| v.to_le_bytes()).collect() };
        // 10-bit limited range white: Y 940, Cb = Cr = 512.
        let y = plane(940, w * h);
        let c = plane(512, (w / 2) * (h / 2));
        let l = Layout {
            format: f,
            width: w,
            height: h,
            strides: [2 * w, w, w],
        };
        let lut = transfer_table(Transfer::Sdr);
        let img = to_linear_rgb(&l, [&y, &c, &c], YcbcrMatrix::BT2020, false, &lut, true).unwrap();
        assert!(
            img.data.iter().all(|v| (v - 1.0).abs() < 1e-3),
            "{:?}",
            img.data
        );
        let hlg = transfer_table(Transfer::Hlg);
        // 75% HLG signal (reference white): Y = 64 + 0.75 * 876 = 721.
        let y = plane(721, w * h);
        let img = to_linear_rgb(&l, [&y, &c, &c], YcbcrMatrix::BT2020, false, &hlg, true).unwrap();
        assert!(
            img.data.iter().all(|v| (v - 0.265).abs() < 2e-3),
            "{:?}",
            img.data
        );
        // Too small a plane is refused.
        assert!(to_linear_rgb(
            &l,
            [&y[..4], &c, &c],
            YcbcrMatrix::BT2020,
            false,
            &hlg,
            true
        )
        .is_err());
    }
}
