//! Writing and reading map images. Every file says what it holds: EXR files carry
//! `svbrdf:*` string attributes, PNG files carry `tEXt` chunks plus the standard `sRGB`
//! or `gAMA = 1.0` chunk, so the colour encoding is machine-readable as well as
//! documented.
//!
//! Encodings: colour maps (diffuse, specular, average colour, renders) are sRGB in PNG
//! and linear in EXR; every other map (roughness, normal, residual, cluster ids) is
//! linear in both.

use std::path::Path;

use exr::prelude as ex;
use serde::{Deserialize, Serialize};

use crate::color::{linear_to_srgb, srgb_to_linear};
use crate::fsutil::write_atomic;
use crate::image::{ImageF32, ImageU8};
use crate::CoreError;

/// Transfer curve of stored values.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Encoding {
    /// Values are proportional to the physical quantity.
    Linear,
    /// Values carry the sRGB transfer curve (IEC 61966-2-1).
    Srgb,
}

impl Encoding {
    /// Name as written in file metadata.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Linear => "linear",
            Self::Srgb => "srgb",
        }
    }
}

/// Bit depth of a PNG.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PngDepth {
    /// 8 bits per sample.
    Eight,
    /// 16 bits per sample.
    Sixteen,
}

/// Write a float image as an uncompressed-precision (f32, ZIP-compressed) OpenEXR file.
/// `names` are the channel names (e.g. `["R","G","B"]`); `meta` become string attributes.
pub fn write_exr(
    path: &Path,
    img: &ImageF32,
    names: &[&str],
    meta: &[(&str, String)],
) -> Result<(), CoreError> {
    if names.len() != img.channels {
        return Err(CoreError::format(
            path,
            format!(
                "{} channel names for {} channels",
                names.len(),
                img.channels
            ),
        ));
    }
    let mut channels = ex::SmallVec::<[ex::AnyChannel<ex::FlatSamples>; 4]>::new();
    for (c, name) in names.iter().enumerate() {
        let samples: Vec<f32> = img
            .data
            .iter()
            .skip(c)
            .step_by(img.channels)
            .map(|v| if v.is_finite() { *v } else { 0.0 })
            .collect();
        channels.push(ex::AnyChannel::new(*name, ex::FlatSamples::F32(samples)));
    }
    let mut attrs = ex::LayerAttributes::default();
    for (k, v) in meta {
        attrs.other.insert(
            ex::Text::from(format!("svbrdf:{k}").as_str()),
            ex::AttributeValue::Text(ex::Text::from(v.as_str())),
        );
    }
    let layer = ex::Layer::new(
        (img.width, img.height),
        attrs,
        ex::Encoding::FAST_LOSSLESS,
        ex::AnyChannels::sort(channels),
    );
    let image = ex::Image::from_layer(layer);
    let mut bytes = std::io::Cursor::new(Vec::new());
    {
        use ex::WritableImage;
        image
            .write()
            // Parallel compression stores chunks in completion order; a fixed order
            // keeps output byte-identical for a given input.
            .non_parallel()
            .to_buffered(&mut bytes)
            .map_err(|e| CoreError::format(path, format!("EXR write failed: {e}")))?;
    }
    let mut bytes = bytes.into_inner();
    // The exr crate keeps custom attributes in a hash map, whose order differs per
    // process: sort the header's attributes so that the bytes do not.
    sort_exr_header(&mut bytes)
        .ok_or_else(|| CoreError::format(path, "EXR write produced an unreadable header"))?;
    write_atomic(path, |w| {
        use std::io::Write as _;
        w.write_all(&bytes).map_err(|e| CoreError::io(path, e))
    })
}

/// Sort the attributes of a single-part OpenEXR header by name, in place. The header's
/// length does not change, so the offset table after it stays valid. `None` if the
/// bytes are not a single-part EXR header.
fn sort_exr_header(bytes: &mut [u8]) -> Option<()> {
    const MAGIC: [u8; 4] = [0x76, 0x2f, 0x31, 0x01];
    const MULTIPART: u8 = 0x10; // bit 12 of the version field, in its second byte
    if bytes.get(..4)? != MAGIC || bytes.get(5)? & MULTIPART != 0 {
        return None;
    }
    let cstr_end = |from: usize| -> Option<usize> {
        bytes
            .get(from..)?
            .iter()
            .position(|b| *b == 0)
            .map(|p| from + p)
    };
    let mut attrs: Vec<(usize, usize, usize)> = Vec::new(); // (start, name end, end)
    let mut pos = 8;
    while *bytes.get(pos)? != 0 {
        let name_end = cstr_end(pos)?;
        let type_end = cstr_end(name_end + 1)?;
        let size_at = type_end + 1;
        let size = i32::from_le_bytes(bytes.get(size_at..size_at + 4)?.try_into().ok()?);
        let end = size_at + 4 + usize::try_from(size).ok()?;
        if end > bytes.len() {
            return None;
        }
        attrs.push((pos, name_end, end));
        pos = end;
    }
    let mut sorted = attrs.clone();
    sorted.sort_by(|a, b| bytes[a.0..a.1].cmp(&bytes[b.0..b.1]));
    let header: Vec<u8> = sorted
        .iter()
        .flat_map(|(s, _, e)| bytes[*s..*e].iter().copied())
        .collect();
    bytes[8..pos].copy_from_slice(&header);
    Some(())
}

/// Write a float image (values in [0, 1], linear) as PNG. With `Encoding::Srgb` the
/// values are sRGB-encoded and the file gets an `sRGB` chunk; with `Linear` they are
/// stored as they are and the file gets `gAMA = 1.0`. `meta` become `tEXt` chunks.
pub fn write_png(
    path: &Path,
    img: &ImageF32,
    encoding: Encoding,
    depth: PngDepth,
    meta: &[(&str, String)],
) -> Result<(), CoreError> {
    let color = match img.channels {
        1 => png::ColorType::Grayscale,
        3 => png::ColorType::Rgb,
        4 => png::ColorType::Rgba,
        n => {
            return Err(CoreError::format(
                path,
                format!("cannot store {n} channels in PNG"),
            ))
        }
    };
    let quant = |v: f32| -> f64 {
        let v = if v.is_finite() {
            f64::from(v).clamp(0.0, 1.0)
        } else {
            0.0
        };
        match encoding {
            Encoding::Srgb => linear_to_srgb(v),
            Encoding::Linear => v,
        }
    };
    let bytes: Vec<u8> = match depth {
        PngDepth::Eight => img
            .data
            .iter()
            .map(|v| (quant(*v) * 255.0).round() as u8)
            .collect(),
        PngDepth::Sixteen => img
            .data
            .iter()
            .flat_map(|v| ((quant(*v) * 65535.0).round() as u16).to_be_bytes())
            .collect(),
    };
    write_png_bytes(
        path, img.width, img.height, color, depth, encoding, &bytes, meta,
    )
}

/// Write an 8-bit image (already encoded as `encoding` says) as PNG.
pub fn write_png_u8(
    path: &Path,
    img: &ImageU8,
    encoding: Encoding,
    meta: &[(&str, String)],
) -> Result<(), CoreError> {
    let color = match img.channels {
        1 => png::ColorType::Grayscale,
        3 => png::ColorType::Rgb,
        4 => png::ColorType::Rgba,
        n => {
            return Err(CoreError::format(
                path,
                format!("cannot store {n} channels in PNG"),
            ))
        }
    };
    write_png_bytes(
        path,
        img.width,
        img.height,
        color,
        PngDepth::Eight,
        encoding,
        &img.data,
        meta,
    )
}

#[allow(clippy::too_many_arguments)]
fn write_png_bytes(
    path: &Path,
    width: usize,
    height: usize,
    color: png::ColorType,
    depth: PngDepth,
    encoding: Encoding,
    bytes: &[u8],
    meta: &[(&str, String)],
) -> Result<(), CoreError> {
    let (w, h) = (
        u32::try_from(width).map_err(|_| CoreError::format(path, "image too wide"))?,
        u32::try_from(height).map_err(|_| CoreError::format(path, "image too tall"))?,
    );
    let fmt = |e: png::EncodingError| CoreError::format(path, format!("PNG write failed: {e}"));
    write_atomic(path, |wr| {
        let mut enc = png::Encoder::new(&mut *wr, w, h);
        enc.set_color(color);
        enc.set_compression(png::Compression::Fast);
        enc.set_depth(match depth {
            PngDepth::Eight => png::BitDepth::Eight,
            PngDepth::Sixteen => png::BitDepth::Sixteen,
        });
        match encoding {
            Encoding::Srgb => enc.set_source_srgb(png::SrgbRenderingIntent::Perceptual),
            Encoding::Linear => enc.set_source_gamma(png::ScaledFloat::new(1.0)),
        }
        enc.add_text_chunk("svbrdf:encoding".into(), encoding.as_str().into())
            .map_err(fmt)?;
        // `svbrdf:encoding` is written above from `encoding`; a second copy from `meta`
        // would make readers that store text chunks as unique keys (Mitsuba) fail.
        for (k, v) in meta.iter().filter(|(k, _)| *k != "encoding") {
            enc.add_text_chunk(format!("svbrdf:{k}"), v.clone())
                .map_err(fmt)?;
        }
        let mut writer = enc.write_header().map_err(fmt)?;
        writer.write_image_data(bytes).map_err(fmt)?;
        writer.finish().map_err(fmt)
    })
}

/// Read an image file (PNG, JPEG, EXR) as linear floats with 3 channels. Integer files
/// are decoded with the given `encoding` (sRGB for colour maps and photos, linear for
/// data maps); float files (EXR) are taken as linear whatever `encoding` says.
pub fn read_image_linear(path: &Path, encoding: Encoding) -> Result<ImageF32, CoreError> {
    let dynimg = image::ImageReader::open(path)
        .map_err(|e| CoreError::io(path, e))?
        .with_guessed_format()
        .map_err(|e| CoreError::io(path, e))?
        .decode()
        .map_err(|e| CoreError::format(path, format!("cannot decode image: {e}")))?;
    let is_float = matches!(
        dynimg.color(),
        image::ColorType::Rgb32F | image::ColorType::Rgba32F
    );
    let rgb = dynimg.to_rgb32f();
    let (w, h) = (rgb.width() as usize, rgb.height() as usize);
    let mut data = rgb.into_raw();
    if !is_float && encoding == Encoding::Srgb {
        for v in &mut data {
            *v = srgb_to_linear(f64::from(*v)) as f32;
        }
    }
    ImageF32::from_vec(w, h, 3, data)
        .ok_or_else(|| CoreError::format(path, "unexpected sample count"))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn exr_bytes_do_not_depend_on_the_attribute_order() {
        let dir = tempfile::tempdir().unwrap();
        let img = ImageF32::new(3, 2, 3);
        let meta: Vec<(&str, String)> = (0..12).map(|i| ("k", format!("{i}"))).collect();
        let meta: Vec<(String, String)> = meta
            .iter()
            .enumerate()
            .map(|(i, (k, v))| (format!("{k}{i}"), v.clone()))
            .collect();
        let meta: Vec<(&str, String)> = meta.iter().map(|(k, v)| (k.as_str(), v.clone())).collect();
        let mut rev = meta.clone();
        rev.reverse();
        let (a, b) = (dir.path().join("a.exr"), dir.path().join("b.exr"));
        write_exr(&a, &img, &["R", "G", "B"], &meta).unwrap();
        write_exr(&b, &img, &["R", "G", "B"], &rev).unwrap();
        assert_eq!(std::fs::read(&a).unwrap(), std::fs::read(&b).unwrap());
        // Still a valid EXR with every attribute.
        let back = read_image_linear(&a, Encoding::Linear).unwrap();
        assert_eq!((back.width, back.height), (3, 2));
        let bytes = std::fs::read(&a).unwrap();
        let needle = b"svbrdf:k11";
        assert!(bytes.windows(needle.len()).any(|w| w == needle));
    }

    #[test]
    fn png_and_exr_round_trip_with_metadata() {
        let dir = tempfile::tempdir().unwrap();
        let mut img = ImageF32::new(4, 3, 3);
        for (i, v) in img.data.iter_mut().enumerate() {
            *v = (i as f32) / 36.0;
        }
        let meta = [("map", "diffuse_albedo".to_string())];
        let p = dir.path().join("a.png");
        write_png(&p, &img, Encoding::Srgb, PngDepth::Sixteen, &meta).unwrap();
        let back = read_image_linear(&p, Encoding::Srgb).unwrap();
        for (a, b) in img.data.iter().zip(&back.data) {
            assert!((a - b).abs() < 1e-3);
        }
        let text = std::fs::read(&p).unwrap();
        let needle = b"svbrdf:encoding";
        assert!(text.windows(needle.len()).any(|w| w == needle));

        let e = dir.path().join("a.exr");
        write_exr(&e, &img, &["R", "G", "B"], &meta).unwrap();
        let back = read_image_linear(&e, Encoding::Srgb).unwrap();
        for (a, b) in img.data.iter().zip(&back.data) {
            assert!((a - b).abs() < 1e-7);
        }
        let bytes = std::fs::read(&e).unwrap();
        let needle = b"svbrdf:map";
        assert!(bytes.windows(needle.len()).any(|w| w == needle));
    }

    #[test]
    fn unreadable_image_is_a_clear_error() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("bad.png");
        std::fs::write(&p, b"not a png").unwrap();
        let err = read_image_linear(&p, Encoding::Srgb)
            .unwrap_err()
            .to_string();
        assert!(err.contains("bad.png"), "{err}");
    }
}
