//! # svbrdf-cv
//!
//! The only crate of `svbrdf` that links OpenCV. Everything crossing its boundary is
//! one of our own types ([`svbrdf_core::image::ImageU8`], plain corner arrays), so the
//! rest of the code base never sees a `Mat`.
//!
//! Images exchanged here are 8-bit RGB (channel order R, G, B), sRGB-encoded as
//! cameras and video codecs store them.
#![deny(missing_docs)]

pub mod aruco;
pub mod capture;
pub mod encode;
pub mod features;
pub mod probe;
pub mod video;

use std::path::{Path, PathBuf};

use opencv::core::{Mat, Vec3b};
use opencv::prelude::*;
use svbrdf_core::image::ImageU8;

/// Errors of the OpenCV edge.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum CvError {
    /// OpenCV reported an error.
    #[error("{context}: OpenCV: {source}")]
    OpenCv {
        /// What we were doing.
        context: String,
        /// OpenCV's error.
        source: opencv::Error,
    },
    /// A file could not be opened or written.
    #[error("{path}: {message}")]
    File {
        /// The file.
        path: PathBuf,
        /// What went wrong.
        message: String,
    },
    /// A value outside its accepted range.
    #[error("invalid {what} {value} (expected {expected})")]
    Invalid {
        /// Which value.
        what: String,
        /// The value given.
        value: String,
        /// The accepted range.
        expected: String,
    },
}

pub(crate) trait Context<T> {
    fn ctx(self, what: impl FnOnce() -> String) -> Result<T, CvError>;
}

impl<T> Context<T> for opencv::Result<T> {
    fn ctx(self, what: impl FnOnce() -> String) -> Result<T, CvError> {
        self.map_err(|source| CvError::OpenCv {
            context: what(),
            source,
        })
    }
}

/// Use one OpenCV thread: we parallelise across frames with rayon instead, which scales
/// better for SIFT and detection on small images.
pub fn set_single_threaded() -> Result<(), CvError> {
    // OpenCV's and FFmpeg's own log lines would come before ours and say less: every
    // failure they report reaches the user as one of our errors instead.
    opencv::core::set_log_level(opencv::core::LogLevel::LOG_LEVEL_SILENT)
        .ctx(|| "setting OpenCV's log level".into())?;
    opencv::core::set_num_threads(1).ctx(|| "setting OpenCV threads".into())
}

/// Convert our RGB image to an OpenCV BGR `Mat`.
pub(crate) fn rgb_to_mat(img: &ImageU8) -> Result<Mat, CvError> {
    if img.channels != 3 {
        return Err(CvError::Invalid {
            what: "channel count".into(),
            value: img.channels.to_string(),
            expected: "3 (RGB)".into(),
        });
    }
    let rows = i32::try_from(img.height).map_err(|_| too_big(img))?;
    let cols = i32::try_from(img.width).map_err(|_| too_big(img))?;
    let mut mat = Mat::new_rows_cols_with_default(rows, cols, opencv::core::CV_8UC3, 0.into())
        .ctx(|| "allocating image".into())?;
    for r in 0..img.height {
        let src = img.row(r);
        let dst = mat
            .at_row_mut::<Vec3b>(r as i32)
            .ctx(|| "writing image row".into())?;
        for (d, s) in dst.iter_mut().zip(src.chunks_exact(3)) {
            *d = Vec3b::from([s[2], s[1], s[0]]);
        }
    }
    Ok(mat)
}

fn too_big(img: &ImageU8) -> CvError {
    CvError::Invalid {
        what: "image size".into(),
        value: format!("{}x{}", img.width, img.height),
        expected: "sides below 2^31".into(),
    }
}

/// Convert an OpenCV BGR (or grey) `Mat` to our RGB image.
pub(crate) fn mat_to_rgb(mat: &Mat) -> Result<ImageU8, CvError> {
    let mut bgr = Mat::default();
    let src = match mat.channels() {
        3 => mat,
        1 => {
            opencv::imgproc::cvt_color_def(mat, &mut bgr, opencv::imgproc::COLOR_GRAY2BGR)
                .ctx(|| "converting grey to colour".into())?;
            &bgr
        }
        4 => {
            opencv::imgproc::cvt_color_def(mat, &mut bgr, opencv::imgproc::COLOR_BGRA2BGR)
                .ctx(|| "dropping alpha".into())?;
            &bgr
        }
        n => {
            return Err(CvError::Invalid {
                what: "channel count".into(),
                value: n.to_string(),
                expected: "1, 3 or 4".into(),
            })
        }
    };
    if src.depth() != opencv::core::CV_8U {
        return Err(CvError::Invalid {
            what: "sample depth".into(),
            value: src.depth().to_string(),
            expected: "8-bit unsigned".into(),
        });
    }
    let (w, h) = (src.cols() as usize, src.rows() as usize);
    let mut out = ImageU8::new(w, h, 3);
    for r in 0..h {
        let row = src
            .at_row::<Vec3b>(r as i32)
            .ctx(|| "reading image row".into())?;
        for (c, p) in row.iter().enumerate() {
            out.pixel_mut(c, r).copy_from_slice(&[p[2], p[1], p[0]]);
        }
    }
    Ok(out)
}

/// A single-channel 8-bit image as a `CV_8UC1` `Mat` (a copy).
pub(crate) fn grey_to_mat(img: &ImageU8) -> Result<Mat, CvError> {
    if img.channels != 1 {
        return Err(CvError::Invalid {
            what: "channel count".into(),
            value: img.channels.to_string(),
            expected: "1 (grey)".into(),
        });
    }
    let rows = i32::try_from(img.height).map_err(|_| too_big(img))?;
    let cols = i32::try_from(img.width).map_err(|_| too_big(img))?;
    let mut mat = Mat::new_rows_cols_with_default(rows, cols, opencv::core::CV_8UC1, 0.into())
        .ctx(|| "allocating image".into())?;
    for r in 0..img.height {
        mat.at_row_mut::<u8>(r as i32)
            .ctx(|| "writing image row".into())?
            .copy_from_slice(img.row(r));
    }
    Ok(mat)
}

/// A `CV_8UC1` `Mat` as a single-channel image.
pub(crate) fn mat_to_grey(mat: &Mat) -> Result<ImageU8, CvError> {
    if mat.typ() != opencv::core::CV_8UC1 {
        return Err(CvError::Invalid {
            what: "image type".into(),
            value: mat.typ().to_string(),
            expected: "8-bit, one channel".into(),
        });
    }
    let (w, h) = (mat.cols() as usize, mat.rows() as usize);
    let mut out = ImageU8::new(w, h, 1);
    for r in 0..h {
        out.data[r * w..(r + 1) * w].copy_from_slice(
            mat.at_row::<u8>(r as i32)
                .ctx(|| "reading image row".into())?,
        );
    }
    Ok(out)
}

/// Read a photo (JPEG, PNG, ...) as 8-bit RGB, applying its EXIF orientation.
pub fn read_image(path: &Path) -> Result<ImageU8, CvError> {
    check_image(path)?;
    let name = path.to_string_lossy();
    let mat = opencv::imgcodecs::imread(path, opencv::imgcodecs::IMREAD_COLOR)
        .ctx(|| format!("reading {name}"))?;
    if mat.empty() {
        return Err(CvError::File {
            path: path.into(),
            message: "cannot read or decode this image".into(),
        });
    }
    mat_to_rgb(&mat)
}

/// Smallest accepted image side, pixels: markers need some pixels each.
pub const MIN_IMAGE_SIDE: u32 = 64;
/// Largest accepted image side, pixels (a 200-megapixel phone photo is 16320 wide).
pub const MAX_IMAGE_SIDE: u32 = 20000;

/// Check an image file before OpenCV decodes it: a readable header with a plausible
/// size, JPEG segments and scans that reach the end-of-image marker, PNG data that
/// decode to the end. OpenCV would print libjpeg's warnings and return a partly grey
/// image for a truncated file.
pub fn check_image(path: &Path) -> Result<(), CvError> {
    let bad = |m: String| CvError::File {
        path: path.into(),
        message: m,
    };
    let meta = std::fs::metadata(path).map_err(|e| bad(format!("cannot read the image ({e})")))?;
    if !meta.is_file() {
        return Err(bad("is not a file (expected a JPEG or PNG image)".into()));
    }
    if meta.len() == 0 {
        return Err(bad(
            "the image file is empty (expected a JPEG or PNG image)".into(),
        ));
    }
    let reader = image::ImageReader::open(path)
        .and_then(|r| r.with_guessed_format())
        .map_err(|e| bad(format!("cannot read the image ({e})")))?;
    let Some(format) = reader.format() else {
        return Err(bad(
            "is not an image format svbrdf reads (expected a JPEG or PNG image)".into(),
        ));
    };
    let (w, h) = reader.into_dimensions().map_err(|e| {
        bad(format!(
            "cannot decode the {format:?} header ({e}; expected a JPEG or PNG image)"
        ))
    })?;
    if w.min(h) < MIN_IMAGE_SIDE || w.max(h) > MAX_IMAGE_SIDE {
        return Err(bad(format!(
            "the image is {w}x{h} pixels (expected {MIN_IMAGE_SIDE} to {MAX_IMAGE_SIDE} pixels a side, as a phone photo)"
        )));
    }
    if format == image::ImageFormat::Jpeg {
        let bytes = std::fs::read(path).map_err(|e| bad(format!("cannot read the image ({e})")))?;
        if !jpeg_is_complete(&bytes) {
            return Err(bad(
                "the JPEG data end before the image does (the file is truncated or damaged: copy it from the phone again)".into(),
            ));
        }
    }
    // A JPEG's structure is checked above without decoding it twice; a PNG is checked
    // by decoding it (its chunks carry no such end marker before the data ends).
    if format == image::ImageFormat::Png {
        let mut limits = image::Limits::default();
        limits.max_alloc = Some(2 << 30);
        let mut r = image::ImageReader::open(path)
            .and_then(|r| r.with_guessed_format())
            .map_err(|e| bad(format!("cannot read the image ({e})")))?;
        r.limits(limits);
        r.decode().map_err(|e| {
            bad(format!(
                "the {format:?} data do not decode ({e}; the file is truncated or damaged: copy it from the phone again)"
            ))
        })?;
    }
    Ok(())
}

/// Whether a JPEG file's segments and scans run to its end-of-image marker (a
/// truncated file stops inside a segment or a scan).
pub fn jpeg_is_complete(b: &[u8]) -> bool {
    if b.len() < 4 || b[0] != 0xFF || b[1] != 0xD8 {
        return false;
    }
    let mut i = 2;
    loop {
        if i >= b.len() || b[i] != 0xFF {
            return false;
        }
        while i < b.len() && b[i] == 0xFF {
            i += 1;
        }
        let Some(&marker) = b.get(i) else {
            return false;
        };
        i += 1;
        match marker {
            0xD9 => return true,
            0xD0..=0xD7 | 0x01 => continue,
            _ => {
                let Some(len) = b
                    .get(i..i + 2)
                    .map(|l| usize::from(u16::from_be_bytes([l[0], l[1]])))
                else {
                    return false;
                };
                if len < 2 || i + len > b.len() {
                    return false;
                }
                i += len;
                if marker == 0xDA {
                    // Entropy-coded data: up to the next marker that is neither a
                    // stuffed 0xFF00 nor a restart marker.
                    loop {
                        if i + 1 >= b.len() {
                            return false;
                        }
                        if b[i] == 0xFF && b[i + 1] != 0 && !(0xD0..=0xD7).contains(&b[i + 1]) {
                            break;
                        }
                        i += 1;
                    }
                }
            }
        }
    }
}

/// Write an 8-bit RGB image as JPEG with the given quality (1-100).
pub fn write_jpeg(path: &Path, img: &ImageU8, quality: i32) -> Result<(), CvError> {
    let mat = rgb_to_mat(img)?;
    let name = path.to_string_lossy();
    let params = opencv::core::Vector::<i32>::from_slice(&[
        opencv::imgcodecs::IMWRITE_JPEG_QUALITY,
        quality.clamp(1, 100),
    ]);
    let ok = opencv::imgcodecs::imwrite(path, &mat, &params).ctx(|| format!("writing {name}"))?;
    if !ok {
        return Err(CvError::File {
            path: path.into(),
            message: "OpenCV could not write this JPEG".into(),
        });
    }
    Ok(())
}
