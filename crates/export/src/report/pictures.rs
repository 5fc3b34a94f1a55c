//! The pictures the report draws from the maps: renders of the material, where it was
//! measured and where its gloss is a guess, in sRGB PNGs beside the page.

use std::path::{Path, PathBuf};

use svbrdf_core::confidence::SpecularSeen;
use svbrdf_core::geometry::Vec3;
use svbrdf_core::image::ImageF32;
use svbrdf_core::maps::{write_png, Encoding, PngDepth};

use svbrdf_core::CoreError;

use crate::{ExportError, MaterialMaps};

/// The preview renders of [`crate::render`], written as sRGB PNGs into `dir`.
pub fn write_renders(
    maps: &MaterialMaps,
    dir: &Path,
) -> Result<Vec<(PathBuf, String)>, ExportError> {
    std::fs::create_dir_all(dir).map_err(|e| CoreError::io(dir, e))?;
    let mut out = Vec::new();
    let views: [(&str, Vec3, &str); 3] = [
        (
            "sphere_left.png",
            Vec3::new(-1.0, 0.6, 0.8),
            "light from the upper left",
        ),
        (
            "sphere_front.png",
            Vec3::new(0.1, 0.2, 1.0),
            "light from the camera (as in the capture)",
        ),
        (
            "sphere_grazing.png",
            Vec3::new(1.0, 0.1, 0.15),
            "grazing light from the right",
        ),
    ];
    for (name, light, what) in views {
        let img = crate::render::sphere(maps, 384, light);
        let p = dir.join(name);
        save(&p, &img, &format!("fitted material on a sphere, {what}"))?;
        out.push((p, format!("sphere, {what}")));
    }
    let img = crate::render::plane(maps, 768);
    let p = dir.join("plane.png");
    save(
        &p,
        &img,
        "fitted material on its plane, oblique view, point light",
    )?;
    out.push((
        p,
        "the material's own plane, oblique view, point light from the upper left".into(),
    ));
    Ok(out)
}

/// The diffuse albedo with the pixels no frame saw hatched in magenta (densely) and
/// those only one or two frames saw (sparsely): what was measured and what was filled.
/// `None` where the coverage is unknown.
pub fn measured_picture(maps: &MaterialMaps) -> Option<ImageF32> {
    let c = maps.coverage.as_ref()?;
    Some(hatched(
        maps,
        [1.0, 0.0, 1.0],
        |i| match c[i] {
            0 => Hatch::Dense,
            v if v < crate::MEASURED_VIEWS => Hatch::Sparse,
            _ => Hatch::None,
        },
        |i| c[i] == 0,
    ))
}

/// The diffuse albedo with the pixels whose highlight was never seen hatched in cyan
/// (densely) and those where only its flank or a clipped peak was seen (sparsely):
/// where the gloss was measured and where it is a guess. `None` where the confidence
/// is unknown.
pub fn gloss_picture(maps: &MaterialMaps) -> Option<ImageF32> {
    let c = maps.confidence.as_ref()?;
    Some(hatched(
        maps,
        [0.0, 1.0, 1.0],
        |i| match SpecularSeen::of(c.per_pixel[i][1]) {
            SpecularSeen::Never => Hatch::Dense,
            SpecularSeen::Flank => Hatch::Sparse,
            SpecularSeen::Peak => Hatch::None,
        },
        |_| false,
    ))
}

/// How densely a pixel is hatched.
#[derive(Clone, Copy, PartialEq)]
enum Hatch {
    None,
    Sparse,
    Dense,
}

/// The diffuse albedo (linear) with diagonal stripes of `colour` where `hatch` says,
/// darkened where `dark` says.
fn hatched(
    maps: &MaterialMaps,
    colour: [f32; 3],
    hatch: impl Fn(usize) -> Hatch,
    dark: impl Fn(usize) -> bool,
) -> ImageF32 {
    let (w, h) = (maps.grid.width, maps.grid.height);
    // Stripes about 1/80 of the map's long side apart, at least 4 pixels.
    let period = (w.max(h) / 80).max(4);
    let mut img = ImageF32::new(w, h, 3);
    for (i, p) in maps.params.iter().enumerate() {
        let (x, y) = (i % w, i / w);
        let stripe = (x + y) % period < period.div_ceil(3);
        let on = match hatch(i) {
            Hatch::Dense => stripe,
            Hatch::Sparse => stripe && ((x + y) / period) % 3 == 0,
            Hatch::None => false,
        };
        let px = if on {
            colour
        } else if dark(i) {
            p.rho_d.map(|v| (0.35 * v) as f32)
        } else {
            p.rho_d.map(|v| v as f32)
        };
        img.data[3 * i..3 * i + 3].copy_from_slice(&px);
    }
    img
}

/// One sentence on what the capture measured, for people.
pub fn coverage_sentence(maps: &MaterialMaps) -> Option<String> {
    let s = maps.coverage_shares()?;
    Some(if s.unobserved + s.thin < 1e-4 {
        format!(
            "Every part of the material was seen by at least {} frames: all of it is measured.",
            crate::MEASURED_VIEWS
        )
    } else {
        format!(
            "{:.1}% of the material was seen by at least {} frames (measured); {:.1}% by only one or two (sparse magenta stripes: less certain); {:.1}% by none (dense magenta stripes, darkened): no frame saw these parts, so their material is a copy of the nearest measured region, not a measurement. The exports carry the same coverage map (coverage.png); `svbrdf export --mask-unobserved` cuts those parts out of the glTF.",
            100.0 * s.measured,
            crate::MEASURED_VIEWS,
            100.0 * s.thin,
            100.0 * s.unobserved
        )
    })
}

pub(super) fn save(path: &Path, img: &ImageF32, meaning: &str) -> Result<(), ExportError> {
    write_png(
        path,
        img,
        Encoding::Srgb,
        PngDepth::Eight,
        &[("meaning", meaning.into()), ("map", "render".into())],
    )?;
    Ok(())
}
