//! Importing registered image sets: the MaterialGAN / svbrdf-diff-renderer capture
//! layout, whose photos already lie on the material plane.
//!
//! The layout (one folder): `00.png`, `01.png`, ... (sRGB, all the same size, square),
//! `image_size.txt` (the physical width of every image, cm), `camera_pos.txt` and
//! `light_pos.txt` (one `x,y,z` line per image, cm; origin at the image centre, z along
//! the surface normal towards the camera) and optionally `light_power.txt` (`r,g,b`).
//!
//! Axes, worked out from the data (each photo's flash highlight sits near the point
//! under its camera): +x runs along image columns to the right and +y along rows
//! upwards (row 0 is the largest y), which is this project's convention, so positions
//! are taken as they are. The light power is MaterialGAN's renderer's
//! `power * f * cos / d^2` with `d` in cm, the form of eq. (9), so it is this project's
//! intensity `I`; the source calls its absolute scale uncalibrated, so it is recorded
//! only with [`ImportOptions::use_light_power`].

use std::path::{Path, PathBuf};

use crate::capture::{Frame, FrameMapping, RegisteredCapture, Source, SourceKind, SubFrame};
use crate::maps::Encoding;
use crate::plane::Region;
use crate::CoreError;

/// Options of [`import_materialgan`].
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ImportOptions {
    /// Record `light_power.txt` as the capture's light intensity (else unknown, and
    /// the fit normalises it).
    pub use_light_power: bool,
}

fn read_text(path: &Path) -> Result<String, CoreError> {
    std::fs::read_to_string(path).map_err(|e| CoreError::io(path, e))
}

/// Parse `x,y,z` lines (commas or spaces); blank lines are skipped.
fn parse_triples(path: &Path) -> Result<Vec<[f64; 3]>, CoreError> {
    let text = read_text(path)?;
    let mut out = Vec::new();
    for (n, line) in text.lines().enumerate() {
        let line = line.trim();
        if line.is_empty() {
            continue;
        }
        let v: Vec<f64> = line
            .split(|c: char| c == ',' || c.is_whitespace())
            .filter(|s| !s.is_empty())
            .map(|s| s.parse::<f64>())
            .collect::<Result<_, _>>()
            .map_err(|_| {
                CoreError::format(
                    path,
                    format!("line {}: {line:?} is not three numbers x,y,z", n + 1),
                )
            })?;
        match v.as_slice() {
            [x, y, z] if v.iter().all(|a| a.is_finite()) => out.push([*x, *y, *z]),
            _ => {
                return Err(CoreError::format(
                    path,
                    format!("line {}: {line:?} is not three numbers x,y,z", n + 1),
                ))
            }
        }
    }
    Ok(out)
}

/// The numbered images of a MaterialGAN folder, in order.
fn numbered_images(dir: &Path) -> Result<Vec<String>, CoreError> {
    let mut names: Vec<(u32, String)> = std::fs::read_dir(dir)
        .map_err(|e| CoreError::io(dir, e))?
        .filter_map(|e| e.ok())
        .filter_map(|e| {
            let name = e.file_name().to_string_lossy().into_owned();
            let (stem, ext) = name.rsplit_once('.')?;
            let ok_ext = matches!(ext.to_ascii_lowercase().as_str(), "png" | "jpg" | "jpeg");
            (ok_ext && !stem.is_empty() && stem.chars().all(|c| c.is_ascii_digit()))
                .then(|| stem.parse::<u32>().ok().map(|n| (n, name.clone())))
                .flatten()
        })
        .collect();
    names.sort();
    Ok(names.into_iter().map(|(_, n)| n).collect())
}

/// Build a registered capture from a MaterialGAN-layout folder. The capture refers to
/// the images where they are (by absolute path); nothing is copied.
pub fn import_materialgan(
    dir: &Path,
    opts: &ImportOptions,
) -> Result<RegisteredCapture, CoreError> {
    let images = numbered_images(dir)?;
    if images.is_empty() {
        return Err(CoreError::format(
            dir,
            "no numbered images (00.png, 01.png, ...) found",
        ));
    }
    let size_file = dir.join("image_size.txt");
    let size_text = read_text(&size_file)?;
    let size: f64 = size_text.trim().parse().map_err(|_| {
        CoreError::format(
            &size_file,
            format!(
                "{:?} is not a number (expected the image width in cm)",
                size_text.trim()
            ),
        )
    })?;
    if !(size > 0.0 && size.is_finite()) {
        return Err(CoreError::format(
            &size_file,
            format!("image width {size} cm (expected > 0)"),
        ));
    }
    let cams_file = dir.join("camera_pos.txt");
    let lights_file = dir.join("light_pos.txt");
    let cams = parse_triples(&cams_file)?;
    let lights = parse_triples(&lights_file)?;
    for (file, list) in [(&cams_file, &cams), (&lights_file, &lights)] {
        if list.len() != images.len() {
            return Err(CoreError::format(
                file,
                format!(
                    "{} positions for {} images (expected one line per image)",
                    list.len(),
                    images.len()
                ),
            ));
        }
        if let Some((k, p)) = list.iter().enumerate().find(|(_, p)| p[2] <= 0.0) {
            return Err(CoreError::format(
                file,
                format!(
                    "line {}: z = {} cm is not above the plane (expected z > 0, along the surface normal)",
                    k + 1,
                    p[2]
                ),
            ));
        }
    }
    let mut dims: Option<(u32, u32, &String)> = None;
    for name in &images {
        let path = dir.join(name);
        let (w, h) = image::image_dimensions(&path)
            .map_err(|e| CoreError::format(&path, format!("unreadable image: {e}")))?;
        match dims {
            None => dims = Some((w, h, name)),
            Some((w0, h0, first)) if (w, h) != (w0, h0) => {
                return Err(CoreError::format(
                    &path,
                    format!("{w}x{h} pixels, but {first} is {w0}x{h0} (expected one size)"),
                ))
            }
            _ => {}
        }
    }
    let (w, h, _) = dims.ok_or_else(|| CoreError::format(dir, "no images"))?;
    // The images are square in the source; a non-square set keeps square pixels with
    // `image_size` as its width.
    let px = size / f64::from(w);
    let (half_w, half_h) = (0.5 * size, 0.5 * px * f64::from(h));
    let region = Region {
        x_min: -half_w,
        x_max: half_w,
        y_min: -half_h,
        y_max: half_h,
    };
    let light_intensity = if opts.use_light_power {
        let p = dir.join("light_power.txt");
        let v = parse_triples(&p)?;
        match v.as_slice() {
            [rgb] if rgb.iter().all(|c| *c > 0.0) => Some(*rgb),
            _ => {
                return Err(CoreError::format(
                    &p,
                    "expected one line r,g,b of positive numbers",
                ))
            }
        }
    } else {
        None
    };
    let abs: PathBuf = std::path::absolute(dir).unwrap_or_else(|_| dir.to_path_buf());
    let mut cap = RegisteredCapture::new("svbrdf import (MaterialGAN layout)", region, 1.0 / px);
    cap.light_intensity = light_intensity;
    cap.sources.push(Source {
        video: None,
        kind: SourceKind::Images,
        path: abs.to_string_lossy().into_owned(),
        encoding: Encoding::Srgb,
        stream: 0,
    });
    // Pixel centres at integer coordinates: column c covers x in
    // [x_min + c px, x_min + (c + 1) px], row r covers y from y_max downwards.
    let plane_from_pixel = [
        [px, 0.0, region.x_min + 0.5 * px],
        [0.0, -px, region.y_max - 0.5 * px],
        [0.0, 0.0, 1.0],
    ];
    for (k, name) in images.iter().enumerate() {
        cap.frames.push(Frame {
            id: k as u32,
            source: 0,
            frame_index: None,
            image: Some(name.clone()),
            time_s: None,
            width: w,
            height: h,
            mapping: FrameMapping::Homographies {
                subframes: vec![SubFrame {
                    rect: [-0.5, -0.5, f64::from(w) - 0.5, f64::from(h) - 0.5],
                    plane_from_pixel,
                }],
            },
            camera_position: cams[k],
            light_position: lights[k],
            exposure_gain: None,
        });
    }
    cap.validate(&dir.join("camera_pos.txt"))?;
    Ok(cap)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::capture::PreparedMapping;
    use crate::geometry::Vec2;

    fn folder(n_images: usize, cams: &str, size: &str) -> tempfile::TempDir {
        let d = tempfile::tempdir().unwrap();
        for k in 0..n_images {
            let img = image::RgbImage::from_pixel(8, 8, image::Rgb([100, 120, 140]));
            img.save(d.path().join(format!("{k:02}.png"))).unwrap();
        }
        std::fs::write(d.path().join("camera_pos.txt"), cams).unwrap();
        std::fs::write(d.path().join("light_pos.txt"), cams).unwrap();
        std::fs::write(d.path().join("image_size.txt"), size).unwrap();
        std::fs::write(d.path().join("light_power.txt"), "1500,1500,1500\n").unwrap();
        d
    }

    #[test]
    fn pixels_map_to_the_centred_plane_with_y_up() {
        let d = folder(2, "1,2,15\n-1,0.5,16\n", "4.0\n");
        let cap = import_materialgan(d.path(), &ImportOptions::default()).unwrap();
        assert_eq!(cap.frames.len(), 2);
        assert_eq!(cap.light_intensity, None);
        assert!((cap.px_per_cm - 2.0).abs() < 1e-12);
        let m = PreparedMapping::new(&cap.frames[0]).unwrap();
        // Top-left pixel centre: half a pixel (0.25 cm) in from the corner (-2, 2).
        let p = m.pixel_to_plane(Vec2::new(0.0, 0.0)).unwrap();
        assert!((p - Vec2::new(-1.75, 1.75)).norm() < 1e-12, "{p}");
        let p = m.pixel_to_plane(Vec2::new(7.0, 7.0)).unwrap();
        assert!((p - Vec2::new(1.75, -1.75)).norm() < 1e-12, "{p}");
        let with = import_materialgan(
            d.path(),
            &ImportOptions {
                use_light_power: true,
            },
        )
        .unwrap();
        assert_eq!(with.light_intensity, Some([1500.0; 3]));
    }

    #[test]
    fn bad_folders_name_the_file_and_value() {
        let d = folder(3, "1,2,15\n-1,0.5,16\n", "4.0");
        let e = import_materialgan(d.path(), &ImportOptions::default())
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("camera_pos.txt") && e.contains("2 positions for 3 images"),
            "{e}"
        );
        let d = folder(2, "1,2,15\n-1,0.5,-3\n", "4.0");
        let e = import_materialgan(d.path(), &ImportOptions::default())
            .unwrap_err()
            .to_string();
        assert!(e.contains("line 2") && e.contains("z = -3"), "{e}");
        let d = folder(2, "1,2,15\n-1,0.5,16\n", "four");
        let e = import_materialgan(d.path(), &ImportOptions::default())
            .unwrap_err()
            .to_string();
        assert!(e.contains("image_size.txt") && e.contains("four"), "{e}");
        let d = folder(2, "1,2,15\n-1,0.5,16\n", "4.0");
        image::RgbImage::new(4, 8)
            .save(d.path().join("01.png"))
            .unwrap();
        let e = import_materialgan(d.path(), &ImportOptions::default())
            .unwrap_err()
            .to_string();
        assert!(e.contains("01.png") && e.contains("4x8"), "{e}");
        let d = folder(2, "1,2\n-1,0.5,16\n", "4.0");
        let e = import_materialgan(d.path(), &ImportOptions::default())
            .unwrap_err()
            .to_string();
        assert!(e.contains("line 1") && e.contains("x,y,z"), "{e}");
    }
}
