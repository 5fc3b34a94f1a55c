//! The fit's output folder:
//!
//! ```text
//! OUT/fit.json            manifest: model, units, light intensity, maps, summary
//! OUT/maps/diffuse.exr    diffuse albedo rho_d, linear RGB        (+ .png, sRGB 8-bit)
//! OUT/maps/specular.exr   specular albedo rho_s, linear RGB       (+ .png, sRGB 8-bit)
//! OUT/maps/roughness.exr  R = alpha_x, G = alpha_y, B = tangent rotation / 360 degrees, linear (+ .png, linear 16-bit)
//! OUT/maps/normal.exr     tangent-space unit normal x, y, z       (+ .png, linear 8-bit, (n + 1) / 2)
//! OUT/maps/average.exr    mean observed colour, linear RGB        (+ .png, sRGB 8-bit)
//! OUT/maps/clusters.png   final clusters in random colours (sRGB); clusters.exr holds ids
//! OUT/maps/initial_clusters.png  the initial k-means clusters in random colours (sRGB)
//! OUT/maps/residual.exr   RMS re-rendering error per pixel, linear (+ .png, linear 16-bit, x10)
//! OUT/maps/coverage.exr   observations per pixel (0: filled)      (+ .png, 8-bit, 0 black)
//! OUT/maps/confidence.exr R = diffuse, G = specular, B = normal confidence in [0, 1], linear (+ .png, linear 8-bit)
//! OUT/rerender.png        observed frames (top) over their re-rendering (bottom), sRGB
//! OUT/clusters.json       every final cluster: id, pixels, depth, BRDF, RMS error
//! ```

use std::path::Path;

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use svbrdf_core::image::ImageF32;
use svbrdf_core::maps::{write_exr, write_png, Encoding, PngDepth};
use svbrdf_core::plane::Region;

use crate::{FitError, FitSummary, FittedMaps};

/// Value of the manifest's `format` field.
pub const FIT_FORMAT: &str = "svbrdf-fit";
/// Manifest file name.
pub const FIT_FILE: &str = "fit.json";

/// One map file.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct MapFile {
    /// Path relative to the output folder.
    pub file: String,
    /// `linear` or `srgb`.
    pub encoding: Encoding,
    /// What the values are.
    pub meaning: String,
}

/// `fit.json`.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct FitManifest {
    /// Always [`FIT_FORMAT`].
    pub format: String,
    /// Format version (1).
    pub version: u32,
    /// Model: `ward` (paper eq. 10) or `ggx`.
    pub model: String,
    /// Plane region covered by the maps, cm; row 0 is the `y_max` edge.
    pub region: Region,
    /// Pixels per cm.
    pub px_per_cm: f64,
    /// Map width, pixels.
    pub width: usize,
    /// Map height, pixels.
    pub height: usize,
    /// Normal-map convention.
    pub normal_convention: String,
    /// Units of the albedos.
    pub albedo_units: String,
    /// Every map file.
    pub maps: Vec<MapFile>,
    /// The re-rendering strip.
    pub rerender: String,
    /// Figures of the fit.
    pub summary: FitSummary,
}

fn plane(maps: &FittedMaps, f: impl Fn(usize) -> [f32; 3]) -> ImageF32 {
    let g = &maps.grid;
    let mut img = ImageF32::new(g.width, g.height, 3);
    for (p, px) in img.data.chunks_exact_mut(3).enumerate() {
        px.copy_from_slice(&f(p));
    }
    img
}

/// How one map is written.
struct MapSpec<'a> {
    name: &'a str,
    model: &'a str,
    /// Encoding of the PNG (the EXR is always linear).
    enc: Encoding,
    depth: PngDepth,
    meaning: &'a str,
    /// The PNG holds the values times this (for maps whose range is not [0, 1]).
    png_scale: f32,
}

/// Write `maps/NAME.exr` (linear) and `maps/NAME.png`, both with metadata, and list them.
/// The normal map's PNG holds `(n + 1) / 2`.
fn write_map(dir: &Path, m: &MapSpec, img: &ImageF32) -> Result<[MapFile; 2], FitError> {
    let meta = |enc: Encoding| {
        vec![
            ("map", m.name.to_string()),
            ("meaning", m.meaning.to_string()),
            ("model", m.model.to_string()),
            ("encoding", enc.as_str().to_string()),
        ]
    };
    let exr = format!("maps/{}.exr", m.name);
    write_exr(
        &dir.join(&exr),
        img,
        &["R", "G", "B"],
        &meta(Encoding::Linear),
    )?;
    let mut png_img = img.clone();
    let shift = if m.name == "normal" { 1.0 } else { 0.0 };
    let scale = if m.name == "normal" { 0.5 } else { m.png_scale };
    png_img
        .data
        .iter_mut()
        .for_each(|v| *v = (*v + shift) * scale);
    let png = format!("maps/{}.png", m.name);
    write_png(&dir.join(&png), &png_img, m.enc, m.depth, &meta(m.enc))?;
    let scaled = if m.png_scale == 1.0 {
        m.meaning.to_string()
    } else {
        format!("{}, multiplied by {}", m.meaning, m.png_scale)
    };
    Ok([
        MapFile {
            file: exr,
            encoding: Encoding::Linear,
            meaning: m.meaning.to_string(),
        },
        MapFile {
            file: png,
            encoding: m.enc,
            meaning: if m.name == "normal" {
                format!("{}; stored as (n + 1) / 2", m.meaning)
            } else {
                scaled
            },
        },
    ])
}

/// Write the maps, the strip and the manifest into `dir` (which must exist).
pub fn write_outputs(
    dir: &Path,
    maps: &FittedMaps,
    summary: &FitSummary,
    strip: &ImageF32,
) -> Result<FitManifest, FitError> {
    let mdir = dir.join("maps");
    std::fs::create_dir_all(&mdir).map_err(|e| svbrdf_core::CoreError::io(&mdir, e))?;
    let normal_convention = "tangent space = plane frame: +X along plane +x (image right), \
        +Y along plane +y (image up, OpenGL convention), +Z out of the surface; PNG stores \
        (n + 1) / 2 linearly";
    let p = &maps.params;
    let model = summary.model.as_str();
    // The maps are built first and written in parallel: PNG compression of a
    // 4-megapixel map takes about a second, and the writes are independent.
    let mut jobs: Vec<(MapSpec, ImageF32)> = Vec::new();
    let mut put = |name: &'static str,
                   img: ImageF32,
                   enc: Encoding,
                   depth: PngDepth,
                   meaning: &'static str,
                   scale: f32| {
        jobs.push((
            MapSpec {
                name,
                model,
                enc,
                depth,
                meaning,
                png_scale: scale,
            },
            img,
        ))
    };
    put(
        "diffuse",
        plane(maps, |i| p[i].rho_d.map(|v| v as f32)),
        Encoding::Srgb,
        PngDepth::Eight,
        "diffuse albedo rho_d",
        1.0,
    );
    put(
        "specular",
        plane(maps, |i| p[i].rho_s.map(|v| v as f32)),
        Encoding::Srgb,
        PngDepth::Eight,
        "specular albedo rho_s",
        1.0,
    );
    put(
        "roughness",
        plane(maps, |i| {
            [
                p[i].alpha_x as f32,
                p[i].alpha_y as f32,
                rotation_to_turns(p[i].tangent_rotation),
            ]
        }),
        Encoding::Linear,
        PngDepth::Sixteen,
        "roughness: R = alpha_x (along the tangent), G = alpha_y (along the bitangent), B = tangent rotation from plane +x towards +y in turns (0.125 = 45 degrees; 0: alpha_x along plane x)",
        1.0,
    );
    let normal = plane(maps, |i| {
        let n = p[i].normal();
        [n.x as f32, n.y as f32, n.z as f32]
    });
    put(
        "normal",
        normal,
        Encoding::Linear,
        PngDepth::Eight,
        normal_convention,
        1.0,
    );
    put(
        "average",
        plane(maps, |i| maps.average[i].map(|v| v as f32)),
        Encoding::Srgb,
        PngDepth::Eight,
        "mean observed colour (linear radiance)",
        1.0,
    );
    put(
        "residual",
        plane(maps, |i| [maps.residual[i]; 3]),
        Encoding::Linear,
        PngDepth::Sixteen,
        "RMS re-rendering error per pixel (linear radiance)",
        10.0,
    );
    let max_cov = maps.coverage.iter().copied().max().unwrap_or(1).max(1) as f32;
    put(
        "coverage",
        plane(maps, |i| [maps.coverage[i] as f32; 3]),
        Encoding::Linear,
        PngDepth::Eight,
        "observations per pixel (0: BRDF filled from the nearest observed cluster)",
        1.0 / max_cov,
    );
    put(
        "confidence",
        plane(maps, |i| maps.confidence[i]),
        Encoding::Linear,
        PngDepth::Eight,
        svbrdf_core::confidence::CONFIDENCE_MEANING,
        1.0,
    );
    // Clusters: ids in the EXR, random but fixed colours in the PNG.
    let n = maps.cluster.iter().copied().max().unwrap_or(0) as usize + 1;
    let mut rng = ChaCha8Rng::seed_from_u64(0x5eed);
    let colours: Vec<[f32; 3]> = (0..n)
        .map(|_| [0; 3].map(|_| rng.random_range(0.05f32..0.9)))
        .collect();
    // Initial (k-means) clusters, the starting point of the recursive splits.
    let k0 = maps.clusters.iter().map(|c| c.initial).max().unwrap_or(0) as usize + 1;
    let initial_colours: Vec<[f32; 3]> = (0..k0)
        .map(|_| [0; 3].map(|_| rng.random_range(0.05f32..0.9)))
        .collect();
    let initial_of = |i: usize| {
        maps.clusters
            .get(maps.cluster[i] as usize)
            .map_or(0, |c| c.initial as usize)
    };
    let write_clusters = || -> Result<Vec<MapFile>, FitError> {
        write_exr(
            &mdir.join("clusters.exr"),
            &plane(maps, |i| [maps.cluster[i] as f32; 3]),
            &["R", "G", "B"],
            &[
                ("map", "clusters".into()),
                ("meaning", "final cluster id".into()),
            ],
        )?;
        write_png(
            &mdir.join("clusters.png"),
            &plane(maps, |i| colours[maps.cluster[i] as usize]),
            Encoding::Srgb,
            PngDepth::Eight,
            &[
                ("map", "clusters".into()),
                ("meaning", "final clusters, random colours".into()),
            ],
        )?;
        write_png(
            &mdir.join("initial_clusters.png"),
            &plane(maps, |i| initial_colours[initial_of(i)]),
            Encoding::Srgb,
            PngDepth::Eight,
            &[
                ("map", "initial_clusters".into()),
                ("meaning", "initial k-means clusters, random colours".into()),
            ],
        )?;
        write_png(
            &dir.join("rerender.png"),
            strip,
            Encoding::Srgb,
            PngDepth::Eight,
            &[(
                "meaning",
                "top: observed frames rectified onto the plane; bottom: re-rendered from the maps"
                    .into(),
            )],
        )?;
        Ok(vec![
            MapFile {
                file: "maps/initial_clusters.png".into(),
                encoding: Encoding::Srgb,
                meaning:
                    "initial k-means clusters in random colours (ids: clusters.json, field initial)"
                        .into(),
            },
            MapFile {
                file: "maps/clusters.exr".into(),
                encoding: Encoding::Linear,
                meaning: "final cluster id (exact integers)".into(),
            },
            MapFile {
                file: "maps/clusters.png".into(),
                encoding: Encoding::Srgb,
                meaning: "final clusters in random colours".into(),
            },
        ])
    };
    let (written, extra) = rayon::join(
        || {
            jobs.par_iter()
                .map(|(m, img)| write_map(dir, m, img))
                .collect::<Result<Vec<_>, FitError>>()
        },
        write_clusters,
    );
    let mut files: Vec<MapFile> = written?.into_iter().flatten().collect();
    files.extend(extra?);
    let manifest = FitManifest {
        format: FIT_FORMAT.into(),
        version: 1,
        model: summary.model.clone(),
        region: maps.grid.region,
        px_per_cm: maps.grid.px_per_cm,
        width: maps.grid.width,
        height: maps.grid.height,
        normal_convention: normal_convention.to_string(),
        albedo_units: match summary.light_intensity_source {
            crate::IntensitySource::Normalised => {
                "relative: the light intensity was unknown and normalised (see light_intensity)"
                    .into()
            }
            _ => "absolute reflectance (the light intensity was known)".into(),
        },
        maps: files,
        rerender: "rerender.png".into(),
        summary: summary.clone(),
    };
    svbrdf_core::fsutil::write_json(&dir.join("clusters.json"), &maps.clusters)?;
    svbrdf_core::fsutil::write_json(&dir.join(FIT_FILE), &manifest)?;
    Ok(manifest)
}

/// Maps read back from an output folder: the grid and the BRDF per pixel, plus the
/// light intensity the fit used.
#[derive(Debug, Clone)]
pub struct LoadedMaps {
    /// The manifest.
    pub manifest: FitManifest,
    /// The grid.
    pub grid: svbrdf_core::plane::PlaneGrid,
    /// BRDF per pixel, row-major (normal angles recovered from the normal map).
    pub params: Vec<svbrdf_core::brdf::BrdfParams>,
    /// Observations per pixel (`maps/coverage.exr`), where the folder has it.
    pub coverage: Option<Vec<u32>>,
    /// Confidence per pixel (`maps/confidence.exr`: diffuse, specular, normal) and
    /// its summary from `fit.json`, where the folder has them.
    pub confidence: Option<svbrdf_core::confidence::ConfidenceMap>,
}

/// The tangent rotation (radians) as the roughness map's third channel stores it: a
/// fraction of a full turn, counter-clockwise seen from above (plane +x towards +y),
/// as Blender's "Anisotropic Rotation" input takes it. Lobes are symmetric under a
/// half turn, so fitted maps hold values in [0, 0.25).
pub fn rotation_to_turns(radians: f64) -> f32 {
    (radians / std::f64::consts::TAU) as f32
}

/// Inverse of [`rotation_to_turns`].
pub fn rotation_from_turns(turns: f32) -> f64 {
    f64::from(turns) * std::f64::consts::TAU
}

/// The parameters of pixel `i` from the four maps as `fit` writes them: diffuse and
/// specular albedo, roughness (alpha_x and alpha_y in the first two channels, the
/// tangent rotation in the third where there is one) and the unit normal
/// (renormalised; the normal-offset angles are derived from it).
pub fn params_from_maps(maps: [&ImageF32; 4], i: usize) -> svbrdf_core::brdf::BrdfParams {
    use svbrdf_core::brdf::BrdfParams;
    use svbrdf_core::geometry::Vec3;
    let px = |img: &ImageF32| -> [f64; 3] {
        let c = img.channels;
        std::array::from_fn(|k| f64::from(img.data[c * i + k.min(c - 1)]))
    };
    let [d, s, r, n] = maps;
    let nv = px(n);
    let normal = Vec3::new(nv[0], nv[1], nv[2])
        .try_normalize(1e-9)
        .unwrap_or_else(Vec3::z);
    let (tx, ty) = BrdfParams::angles_from_normal(normal);
    let rv = px(r);
    BrdfParams {
        rho_d: px(d),
        rho_s: px(s),
        alpha_x: rv[0],
        alpha_y: rv[1],
        normal_theta_x: tx,
        normal_theta_y: ty,
        tangent_rotation: if r.channels >= 3 {
            rotation_from_turns(r.data[r.channels * i + 2])
        } else {
            0.0
        },
    }
}

/// Read `fit.json` and the linear EXR maps of an output folder.
pub fn read_maps(dir: &Path) -> Result<LoadedMaps, FitError> {
    use svbrdf_core::maps::read_image_linear;
    let file = dir.join(FIT_FILE);
    let manifest: FitManifest = svbrdf_core::fsutil::read_json(&file)?;
    if manifest.format != FIT_FORMAT || manifest.version != 1 {
        return Err(svbrdf_core::CoreError::format(
            &file,
            format!(
                "format {:?} version {} (expected {FIT_FORMAT:?} version 1)",
                manifest.format, manifest.version
            ),
        )
        .into());
    }
    let grid = svbrdf_core::plane::PlaneGrid::new(manifest.region, manifest.px_per_cm)?;
    let read = |name: &str| -> Result<ImageF32, FitError> {
        let p = dir.join("maps").join(format!("{name}.exr"));
        let img = read_image_linear(&p, Encoding::Linear)?;
        if img.width != grid.width || img.height != grid.height {
            return Err(svbrdf_core::CoreError::format(
                &p,
                format!(
                    "{}x{} pixels, but fit.json says {}x{}",
                    img.width, img.height, grid.width, grid.height
                ),
            )
            .into());
        }
        Ok(img)
    };
    let (d, s, r, n) = (
        read("diffuse")?,
        read("specular")?,
        read("roughness")?,
        read("normal")?,
    );
    let params = (0..grid.len())
        .map(|i| params_from_maps([&d, &s, &r, &n], i))
        .collect();
    // Older fit folders and hand-made maps may lack the coverage map.
    let coverage = if dir.join("maps/coverage.exr").exists() {
        let c = read("coverage")?;
        Some(
            c.data
                .chunks(c.channels.max(1))
                .map(|p| p[0].max(0.0).round() as u32)
                .collect(),
        )
    } else {
        None
    };
    let confidence = match (
        dir.join("maps/confidence.exr").exists(),
        manifest.summary.confidence,
    ) {
        (true, Some(summary)) => {
            let c = read("confidence")?;
            if c.channels < 3 {
                return Err(svbrdf_core::CoreError::format(
                    dir.join("maps/confidence.exr"),
                    format!(
                        "{} channels (expected 3: diffuse, specular, normal)",
                        c.channels
                    ),
                )
                .into());
            }
            Some(svbrdf_core::confidence::ConfidenceMap {
                per_pixel: c
                    .data
                    .chunks(c.channels)
                    .map(|p| [p[0], p[1], p[2]])
                    .collect(),
                summary,
            })
        }
        _ => None,
    };
    Ok(LoadedMaps {
        manifest,
        grid,
        params,
        coverage,
        confidence,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_tangent_rotation_survives_the_roughness_map() {
        let img = |c: usize, v: [f32; 3]| {
            let mut i = ImageF32::new(1, 1, c);
            i.data.copy_from_slice(&v[..c]);
            i
        };
        let (d, s, n) = (img(3, [0.2; 3]), img(3, [0.3; 3]), img(3, [0.0, 0.0, 1.0]));
        let turn = 0.4;
        let r = img(3, [0.08, 0.25, rotation_to_turns(turn)]);
        let p = params_from_maps([&d, &s, &r, &n], 0);
        assert!((p.tangent_rotation - turn).abs() < 1e-6, "{p:?}");
        assert!((p.alpha_x - 0.08).abs() < 1e-6 && (p.alpha_y - 0.25).abs() < 1e-6);
        // A two-channel roughness map (alpha_x, alpha_y) has no rotation.
        let r2 = img(2, [0.08, 0.25, 0.0]);
        assert_eq!(params_from_maps([&d, &s, &r2, &n], 0).tangent_rotation, 0.0);
    }
}
