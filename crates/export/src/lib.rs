//! # svbrdf-export
//!
//! Turns fitted svBRDF maps into files that renderers open as they are:
//!
//! - [`gltf`]: a glTF 2.0 scene (a quad with the material at its measured size and a
//!   sphere beside it) whose metallic-roughness material carries the specular colour in
//!   `KHR_materials_specular` and the anisotropy in `KHR_materials_anisotropy`.
//! - [`mitsuba`]: a Mitsuba 3 scene of the same quad and sphere with the maps wired to
//!   stock plugins (`normalmap` over `blendbsdf` of `diffuse` and `roughconductor`).
//!
//! The model conversions live in [`convert`] and are documented there and in
//! `docs/CONVENTIONS.md`. Nothing here links OpenCV.
#![deny(missing_docs)]
#![allow(clippy::neg_cmp_op_on_partial_ord)]

pub mod convert;
pub mod gltf;
pub mod markers;
pub mod mesh;
pub mod mitsuba;
pub mod render;
pub mod report;

use std::path::{Path, PathBuf};

use svbrdf_core::brdf::{BrdfParams, ModelKind};
use svbrdf_core::plane::PlaneGrid;
use svbrdf_core::CoreError;

/// Errors of the exporters.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ExportError {
    /// From the core (I/O, bad settings).
    #[error(transparent)]
    Core(#[from] CoreError),
}

/// Fitted maps, one BRDF per plane pixel (row-major, top row = largest y).
#[derive(Debug, Clone)]
pub struct MaterialMaps {
    /// The model the parameters belong to.
    pub model: ModelKind,
    /// The plane grid of the maps.
    pub grid: PlaneGrid,
    /// Parameters per pixel.
    pub params: Vec<BrdfParams>,
    /// Observations per pixel (frames that saw it; 0: not seen, its BRDF was filled
    /// from the nearest measured cluster), where known.
    pub coverage: Option<Vec<u32>>,
    /// How well each pixel's diffuse albedo, specular lobe and normal were measured,
    /// where known.
    pub confidence: Option<svbrdf_core::confidence::ConfidenceMap>,
}

/// Observations a map pixel needs to count as measured (as the alignment's coverage).
pub const MEASURED_VIEWS: u32 = 3;

/// File name of the coverage map beside each export's files (not a material texture).
pub const COVERAGE_FILE: &str = "coverage.png";
/// What the coverage map's values mean.
pub const COVERAGE_MEANING: &str = "coverage (linear): 1 = seen by at least 3 frames (measured), 0.5 = by 1-2 frames, 0 = by none (BRDF filled from the nearest measured cluster, not measured)";

/// Shares of the map's pixels by how well they were observed.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct CoverageShares {
    /// Seen by at least [`MEASURED_VIEWS`] frames.
    pub measured: f64,
    /// Seen by 1 or 2 frames.
    pub thin: f64,
    /// Not seen: the BRDF there was filled from the nearest measured cluster.
    pub unobserved: f64,
}

impl MaterialMaps {
    /// How much of the map was measured, where the coverage is known.
    pub fn coverage_shares(&self) -> Option<CoverageShares> {
        let c = self.coverage.as_ref()?;
        let n = c.len().max(1) as f64;
        let count = |f: &dyn Fn(u32) -> bool| c.iter().filter(|&&v| f(v)).count() as f64 / n;
        Some(CoverageShares {
            measured: count(&|v| v >= MEASURED_VIEWS),
            thin: count(&|v| v > 0 && v < MEASURED_VIEWS),
            unobserved: count(&|v| v == 0),
        })
    }

    /// Write [`COVERAGE_FILE`] into `dir` where the coverage is known (both exports
    /// carry it).
    pub(crate) fn write_coverage(&self, dir: &Path) -> Result<(), ExportError> {
        if let Some(img) = self.coverage_image() {
            svbrdf_core::maps::write_png(
                &dir.join(COVERAGE_FILE),
                &img,
                svbrdf_core::maps::Encoding::Linear,
                svbrdf_core::maps::PngDepth::Eight,
                &[
                    ("map", COVERAGE_MEANING.to_string()),
                    ("encoding", "linear".into()),
                ],
            )?;
        }
        Ok(())
    }

    /// Write the confidence map ([`svbrdf_core::confidence::CONFIDENCE_FILE`]) into
    /// `dir` where it is known (both exports carry it).
    pub(crate) fn write_confidence(&self, dir: &Path) -> Result<(), ExportError> {
        if let Some(c) = &self.confidence {
            c.write_png(dir, self.grid.width, self.grid.height)?;
        }
        Ok(())
    }

    /// The coverage as a linear grey image: 1 measured, 0.5 thin (1-2 frames), 0 not
    /// seen (filled).
    pub fn coverage_image(&self) -> Option<svbrdf_core::image::ImageF32> {
        let c = self.coverage.as_ref()?;
        let mut img = svbrdf_core::image::ImageF32::new(self.grid.width, self.grid.height, 1);
        for (o, &v) in img.data.iter_mut().zip(c) {
            *o = match v {
                0 => 0.0,
                v if v < MEASURED_VIEWS => 0.5,
                _ => 1.0,
            };
        }
        Some(img)
    }

    /// Check that the parameters fill the grid and are finite.
    pub fn validate(&self) -> Result<(), ExportError> {
        if self.params.len() != self.grid.len() || self.params.is_empty() {
            return Err(CoreError::invalid(
                "map size",
                self.params.len(),
                format!(
                    "{} pixels ({}x{})",
                    self.grid.len(),
                    self.grid.width,
                    self.grid.height
                ),
            )
            .into());
        }
        if let Some(i) = self
            .params
            .iter()
            .position(|p| !p.to_array().iter().all(|v| v.is_finite()))
        {
            return Err(CoreError::invalid(
                "map value",
                format!("non-finite at pixel {i}"),
                "finite parameters",
            )
            .into());
        }
        if let Some(c) = &self.confidence {
            if c.per_pixel.len() != self.params.len()
                || c.per_pixel
                    .iter()
                    .flatten()
                    .any(|v| !(0.0..=1.0).contains(v))
            {
                return Err(CoreError::invalid(
                    "confidence map",
                    format!("{} pixels", c.per_pixel.len()),
                    format!("{} pixels, as the maps, each in [0, 1]", self.params.len()),
                )
                .into());
            }
        }
        if let Some(c) = &self.coverage {
            if c.len() != self.params.len() {
                return Err(CoreError::invalid(
                    "coverage map size",
                    c.len(),
                    format!("{} pixels, as the maps", self.params.len()),
                )
                .into());
            }
        }
        Ok(())
    }
}

/// Settings of the exports.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ExportConfig {
    /// Name of the material inside the files.
    pub name: String,
    /// Add a sphere beside the quad.
    pub sphere: bool,
    /// Sphere segments around its axis (>= 8).
    pub sphere_segments: u32,
    /// Sphere rings from pole to pole (>= 4).
    pub sphere_rings: u32,
    /// Mitsuba preview image size, pixels (width; height follows 3:2).
    pub mitsuba_width: u32,
    /// Mitsuba samples per pixel.
    pub mitsuba_spp: u32,
    /// Cut the pixels no frame saw out of the glTF material (alpha mask) instead of
    /// showing the BRDF filled in from the nearest measured cluster.
    pub mask_unobserved: bool,
}

impl Default for ExportConfig {
    fn default() -> Self {
        Self {
            name: "svbrdf_material".into(),
            sphere: true,
            sphere_segments: 96,
            sphere_rings: 48,
            mitsuba_width: 768,
            mitsuba_spp: 64,
            mask_unobserved: false,
        }
    }
}

impl ExportConfig {
    /// Check the numbers.
    pub fn validate(&self) -> Result<(), ExportError> {
        if self.name.is_empty()
            || !self
                .name
                .chars()
                .all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '-')
        {
            return Err(CoreError::invalid(
                "material name",
                format!("{:?}", self.name),
                "letters, digits, '_' or '-'",
            )
            .into());
        }
        if self.sphere_segments < 8 || self.sphere_segments > 1024 {
            return Err(
                CoreError::invalid("sphere_segments", self.sphere_segments, "8 to 1024").into(),
            );
        }
        if self.sphere_rings < 4 || self.sphere_rings > 512 {
            return Err(CoreError::invalid("sphere_rings", self.sphere_rings, "4 to 512").into());
        }
        if !(16..=8192).contains(&self.mitsuba_width) {
            return Err(CoreError::invalid(
                "mitsuba_width",
                self.mitsuba_width,
                "16 to 8192 pixels",
            )
            .into());
        }
        if !(1..=65536).contains(&self.mitsuba_spp) {
            return Err(CoreError::invalid("mitsuba_spp", self.mitsuba_spp, "1 to 65536").into());
        }
        Ok(())
    }
}

/// Where the exports went.
#[derive(Debug, Clone, serde::Serialize, serde::Deserialize)]
pub struct ExportSummary {
    /// The glTF file.
    pub gltf: PathBuf,
    /// The Mitsuba scene.
    pub mitsuba: PathBuf,
}

/// Write both exports into `out/gltf/` and `out/mitsuba/` (each folder built under a
/// temporary name and renamed when complete).
pub fn export_all(
    maps: &MaterialMaps,
    cfg: &ExportConfig,
    out: &Path,
    overwrite: bool,
) -> Result<ExportSummary, ExportError> {
    maps.validate()?;
    cfg.validate()?;
    let gltf = gltf::write(maps, cfg, &out.join("gltf"), overwrite)?;
    let mitsuba = mitsuba::write(maps, cfg, &out.join("mitsuba"), overwrite)?;
    Ok(ExportSummary { gltf, mitsuba })
}
