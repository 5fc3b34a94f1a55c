//! glTF 2.0 export: `material.gltf` + `material.bin` + PNG textures in one folder.
//!
//! | file | glTF slot | encoding |
//! |---|---|---|
//! | `base_color.png` | `baseColorTexture` | sRGB 8-bit |
//! | `metallic_roughness.png` | `metallicRoughnessTexture` (G roughness, B metallic = 0) | linear 8-bit |
//! | `normal.png` | `normalTexture` (tangent space, +Y up) | linear 8-bit |
//! | `specular_color.png` | `KHR_materials_specular.specularColorTexture` | sRGB 8-bit |
//! | `anisotropy.png` | `KHR_materials_anisotropy.anisotropyTexture` (RG direction, B strength) | linear 8-bit |
//!
//! The conversions are in [`crate::convert`].
use std::io::Write;
use std::path::{Path, PathBuf};

use serde_json::{json, Value};
use svbrdf_core::fsutil::{write_atomic, StagingDir};
use svbrdf_core::image::ImageF32;
use svbrdf_core::maps::{write_png, Encoding, PngDepth};
use svbrdf_core::CoreError;

use crate::convert::{gltf_texel, GltfTexel, GLTF_DIELECTRIC_F0, WARD_TO_GGX_ALPHA};
use crate::mesh::{quad, sphere, Mesh};
use crate::{ExportConfig, ExportError, MaterialMaps, COVERAGE_FILE, COVERAGE_MEANING};

/// File name of the glTF document inside the export folder.
pub const GLTF_FILE: &str = "material.gltf";
const BIN_FILE: &str = "material.bin";

const FLOAT: u32 = 5126;
const UNSIGNED_INT: u32 = 5125;
const ARRAY_BUFFER: u32 = 34962;
const ELEMENT_ARRAY_BUFFER: u32 = 34963;

/// The texture images of the material, in glTF's encodings (values in [0, 1]).
struct Textures {
    base_color: ImageF32,
    metallic_roughness: ImageF32,
    normal: ImageF32,
    specular_color: ImageF32,
    anisotropy: ImageF32,
    /// `specularColorFactor` (same for R, G, B): the largest F0 over 0.04.
    specular_color_factor: f64,
}

fn textures(maps: &MaterialMaps) -> Textures {
    let (w, h) = (maps.grid.width, maps.grid.height);
    let texels: Vec<GltfTexel> = maps
        .params
        .iter()
        .map(|p| gltf_texel(maps.model, p))
        .collect();
    let f0_max = texels
        .iter()
        .flat_map(|t| t.f0)
        .fold(0.0, f64::max)
        .max(1e-3);
    let mut t = Textures {
        base_color: ImageF32::new(w, h, 3),
        metallic_roughness: ImageF32::new(w, h, 3),
        normal: ImageF32::new(w, h, 3),
        specular_color: ImageF32::new(w, h, 3),
        anisotropy: ImageF32::new(w, h, 3),
        specular_color_factor: f0_max / GLTF_DIELECTRIC_F0,
    };
    for (i, x) in texels.iter().enumerate() {
        let o = 3 * i;
        for c in 0..3 {
            t.base_color.data[o + c] = x.base_color[c] as f32;
            t.specular_color.data[o + c] = (x.f0[c] / f0_max) as f32;
        }
        t.metallic_roughness.data[o..o + 3].copy_from_slice(&[1.0, x.roughness as f32, 0.0]);
        let n = x.normal;
        t.normal.data[o..o + 3].copy_from_slice(&[
            (0.5 * n.x + 0.5) as f32,
            (0.5 * n.y + 0.5) as f32,
            (0.5 * n.z + 0.5) as f32,
        ]);
        let d = x.anisotropy_direction;
        t.anisotropy.data[o..o + 3].copy_from_slice(&[
            (0.5 * d[0] + 0.5) as f32,
            (0.5 * d[1] + 0.5) as f32,
            x.anisotropy_strength as f32,
        ]);
    }
    t
}

/// Binary buffer and its views and accessors.
#[derive(Default)]
struct Buffer {
    bytes: Vec<u8>,
    views: Vec<Value>,
    accessors: Vec<Value>,
}

impl Buffer {
    fn push(&mut self, data: &[u8], target: u32, accessor: Value) -> usize {
        while !self.bytes.len().is_multiple_of(4) {
            self.bytes.push(0);
        }
        self.views.push(json!({
            "buffer": 0,
            "byteOffset": self.bytes.len(),
            "byteLength": data.len(),
            "target": target,
        }));
        self.bytes.extend_from_slice(data);
        let mut a = accessor;
        a["bufferView"] = json!(self.views.len() - 1);
        self.accessors.push(a);
        self.accessors.len() - 1
    }

    fn floats<const N: usize>(&mut self, v: &[[f32; N]], kind: &str, bounds: bool) -> usize {
        let data: Vec<u8> = v.iter().flatten().flat_map(|x| x.to_le_bytes()).collect();
        let mut a = json!({"componentType": FLOAT, "count": v.len(), "type": kind});
        if bounds {
            let mut lo = [f32::INFINITY; N];
            let mut hi = [f32::NEG_INFINITY; N];
            for p in v {
                for k in 0..N {
                    lo[k] = lo[k].min(p[k]);
                    hi[k] = hi[k].max(p[k]);
                }
            }
            a["min"] = json!(lo.to_vec());
            a["max"] = json!(hi.to_vec());
        }
        self.push(&data, ARRAY_BUFFER, a)
    }

    fn mesh(&mut self, m: &Mesh) -> Value {
        let position = self.floats(&m.positions, "VEC3", true);
        let normal = self.floats(&m.normals, "VEC3", false);
        let tangent = self.floats(&m.tangents, "VEC4", false);
        let uv = self.floats(&m.uvs, "VEC2", false);
        let data: Vec<u8> = m.indices.iter().flat_map(|x| x.to_le_bytes()).collect();
        let indices = self.push(
            &data,
            ELEMENT_ARRAY_BUFFER,
            json!({"componentType": UNSIGNED_INT, "count": m.indices.len(), "type": "SCALAR"}),
        );
        json!({
            "attributes": {"POSITION": position, "NORMAL": normal, "TANGENT": tangent, "TEXCOORD_0": uv},
            "indices": indices,
            "material": 0,
        })
    }
}

/// Radius (m) and centre of the preview sphere: it rests on the ground beside the quad.
pub fn sphere_placement(maps: &MaterialMaps) -> (f64, [f64; 3]) {
    let (w, h) = (
        maps.grid.region.width() / 100.0,
        maps.grid.region.height() / 100.0,
    );
    let r = 0.35 * w.min(h);
    (r, [0.5 * w + 0.15 * w.min(h) + r, r, 0.0])
}

/// Write the glTF export into the folder `out` and return the `.gltf` path.
pub fn write(
    maps: &MaterialMaps,
    cfg: &ExportConfig,
    out: &Path,
    overwrite: bool,
) -> Result<PathBuf, ExportError> {
    maps.validate()?;
    cfg.validate()?;
    let staging = StagingDir::new(out, overwrite, &[])?;
    let dir = staging.path();
    let mut t = textures(maps);
    // Pixels no frame saw: cut out by the base colour's alpha when asked to.
    let masked = match (&maps.coverage, cfg.mask_unobserved) {
        (Some(c), true) => {
            let rgb = &t.base_color;
            let mut rgba = ImageF32::new(rgb.width, rgb.height, 4);
            for (i, &v) in c.iter().enumerate() {
                rgba.data[4 * i..4 * i + 3].copy_from_slice(&rgb.data[3 * i..3 * i + 3]);
                rgba.data[4 * i + 3] = if v == 0 { 0.0 } else { 1.0 };
            }
            t.base_color = rgba;
            true
        }
        _ => false,
    };
    maps.write_coverage(dir)?;
    maps.write_confidence(dir)?;
    let texture_files: [(&str, &ImageF32, Encoding, &str); 5] = [
        ("base_color.png", &t.base_color, Encoding::Srgb, "glTF baseColor = rho_d / (1 - max F0)"),
        (
            "metallic_roughness.png",
            &t.metallic_roughness,
            Encoding::Linear,
            "glTF metallicRoughness: G = roughness (sqrt of the smaller GGX alpha), B = metallic = 0",
        ),
        ("normal.png", &t.normal, Encoding::Linear, "tangent-space normal (0.5 n + 0.5), +Y up"),
        (
            "specular_color.png",
            &t.specular_color,
            Encoding::Srgb,
            "KHR_materials_specular colour: F0 / (0.04 specularColorFactor)",
        ),
        (
            "anisotropy.png",
            &t.anisotropy,
            Encoding::Linear,
            "KHR_materials_anisotropy: RG = direction (0.5 d + 0.5), B = strength",
        ),
    ];
    for (name, img, enc, meaning) in &texture_files {
        write_png(
            &dir.join(name),
            img,
            *enc,
            PngDepth::Eight,
            &[
                ("map", (*meaning).to_string()),
                ("encoding", enc.as_str().into()),
            ],
        )?;
    }

    let mut buf = Buffer::default();
    let mut meshes = vec![
        json!({"name": format!("{}_quad", cfg.name), "primitives": [buf.mesh(&quad(&maps.grid.region))]}),
    ];
    let mut nodes = vec![json!({"name": format!("{}_quad", cfg.name), "mesh": 0})];
    if cfg.sphere {
        let (r, c) = sphere_placement(maps);
        let s = sphere(
            &maps.grid.region,
            r,
            c,
            cfg.sphere_segments,
            cfg.sphere_rings,
        );
        meshes.push(json!({"name": format!("{}_sphere", cfg.name), "primitives": [buf.mesh(&s)]}));
        nodes.push(json!({"name": format!("{}_sphere", cfg.name), "mesh": 1}));
    }
    let bin_path = dir.join(BIN_FILE);
    let bytes = buf.bytes;
    write_atomic(&bin_path, |w| {
        w.write_all(&bytes).map_err(|e| CoreError::io(&bin_path, e))
    })?;

    let scale = t.specular_color_factor;
    let doc = json!({
        "asset": {
            "version": "2.0",
            "generator": concat!("svbrdf ", env!("CARGO_PKG_VERSION")),
            "extras": {
                "svbrdf": {
                    "fitted_model": maps.model,
                    "region_cm": maps.grid.region,
                    "px_per_cm": maps.grid.px_per_cm,
                    "units": "metres (1 glTF unit = 1 m; the quad has the material's measured size)",
                    "plane_to_gltf": "plane (x, y, z) cm -> glTF (x, z, -y) / 100",
                    "ward_to_ggx_alpha": if maps.model == svbrdf_core::brdf::ModelKind::Ward { WARD_TO_GGX_ALPHA } else { 1.0 },
                    "colour": "base_color.png and specular_color.png are sRGB; the other textures are linear",
                }
            }
        },
        "extensionsUsed": ["KHR_materials_specular", "KHR_materials_anisotropy"],
        "scene": 0,
        "scenes": [{"name": cfg.name, "nodes": (0..nodes.len()).collect::<Vec<_>>()}],
        "nodes": nodes,
        "meshes": meshes,
        "materials": [{
            "name": cfg.name,
            "pbrMetallicRoughness": {
                "baseColorTexture": {"index": 0},
                "metallicFactor": 1.0,
                "roughnessFactor": 1.0,
                "metallicRoughnessTexture": {"index": 1},
            },
            "normalTexture": {"index": 2},
            "extensions": {
                "KHR_materials_specular": {
                    "specularFactor": 1.0,
                    "specularColorFactor": [scale, scale, scale],
                    "specularColorTexture": {"index": 3},
                },
                "KHR_materials_anisotropy": {
                    "anisotropyStrength": 1.0,
                    "anisotropyRotation": 0.0,
                    "anisotropyTexture": {"index": 4},
                },
            },
        }],
        "samplers": [{"magFilter": 9729, "minFilter": 9987, "wrapS": 10497, "wrapT": 10497}],
        "textures": (0..texture_files.len()).map(|i| json!({"sampler": 0, "source": i})).collect::<Vec<_>>(),
        "images": texture_files.iter().map(|(name, ..)| json!({"uri": name, "mimeType": "image/png"})).collect::<Vec<_>>(),
        "buffers": [{"uri": BIN_FILE, "byteLength": bytes.len()}],
        "bufferViews": buf.views,
        "accessors": buf.accessors,
    });
    let mut doc = doc;
    if masked {
        doc["materials"][0]["alphaMode"] = json!("MASK");
    }
    if let Some(s) = maps.coverage_shares() {
        doc["asset"]["extras"]["svbrdf"]["coverage"] = json!({
            "file": COVERAGE_FILE,
            "meaning": COVERAGE_MEANING,
            "measured_share": s.measured,
            "thin_share": s.thin,
            "unobserved_share": s.unobserved,
            "unobserved_masked": masked,
        });
    }
    if let Some(c) = &maps.confidence {
        let s = &c.summary;
        doc["asset"]["extras"]["svbrdf"]["confidence"] = json!({
            "file": svbrdf_core::confidence::CONFIDENCE_FILE,
            "meaning": svbrdf_core::confidence::CONFIDENCE_MEANING,
            "specular_peak_share": s.specular_peak,
            "specular_flank_share": s.specular_flank,
            "specular_unseen_share": s.specular_unseen,
            "normal_low_share": s.normal_low,
            "diffuse_low_share": s.diffuse_low,
            "summary": s.sentence(),
        });
    }
    svbrdf_core::fsutil::write_json(&dir.join(GLTF_FILE), &doc)?;
    let target = staging.commit()?;
    Ok(target.join(GLTF_FILE))
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use svbrdf_core::brdf::{BrdfParams, ModelKind};
    use svbrdf_core::plane::{PlaneGrid, Region};

    pub(crate) fn checker(model: ModelKind) -> MaterialMaps {
        let grid = PlaneGrid::new(Region::centred(4.0, 3.0), 8.0).expect("grid");
        let params = (0..grid.len())
            .map(|i| {
                let (c, r) = (i % grid.width, i / grid.width);
                let odd = (c / 8 + r / 8) % 2 == 1;
                BrdfParams {
                    rho_d: if odd {
                        [0.6, 0.3, 0.1]
                    } else {
                        [0.1, 0.2, 0.5]
                    },
                    rho_s: if odd { [0.05; 3] } else { [0.3, 0.25, 0.2] },
                    alpha_x: if odd { 0.3 } else { 0.05 },
                    alpha_y: 0.1,
                    normal_theta_x: 0.1 * (c as f64 * 0.7).sin(),
                    normal_theta_y: 0.1 * (r as f64 * 0.5).cos(),
                    tangent_rotation: 0.0,
                }
            })
            .collect();
        MaterialMaps {
            model,
            grid,
            params,
            coverage: None,
            confidence: None,
        }
    }

    #[test]
    fn unobserved_pixels_are_recorded_and_masked_on_request() {
        let tmp = tempfile::tempdir().expect("tmp");
        let mut maps = checker(ModelKind::Ward);
        let n = maps.params.len();
        // A quarter of the pixels unseen, a quarter seen twice, the rest seen often.
        let coverage: Vec<u32> = (0..n as u32)
            .map(|i| [0, 2, 5, 9][(i % 4) as usize])
            .collect();
        maps.coverage = Some(coverage.clone());
        let read = |dir: &Path, cfg: &ExportConfig| -> (Value, ImageF32, ImageF32) {
            let path = write(&maps, cfg, dir, false).expect("export");
            let doc: Value =
                serde_json::from_str(&std::fs::read_to_string(&path).expect("read")).expect("json");
            let base =
                svbrdf_core::maps::read_image_linear(&dir.join("base_color.png"), Encoding::Linear)
                    .expect("base colour");
            let cov =
                svbrdf_core::maps::read_image_linear(&dir.join(COVERAGE_FILE), Encoding::Linear)
                    .expect("coverage");
            (doc, base, cov)
        };
        let (doc, base, cov) = read(&tmp.path().join("plain"), &ExportConfig::default());
        let c = &doc["asset"]["extras"]["svbrdf"]["coverage"];
        assert_eq!(c["unobserved_share"], json!(0.25), "{c}");
        assert_eq!(c["thin_share"], json!(0.25), "{c}");
        assert_eq!(c["unobserved_masked"], json!(false));
        assert!(doc["materials"][0].get("alphaMode").is_none());
        assert_eq!(base.channels, 3);
        for (k, &v) in coverage.iter().enumerate() {
            let want = match v {
                0 => 0.0,
                2 => 0.5,
                _ => 1.0,
            };
            assert!((cov.data[k * cov.channels] - want).abs() < 0.01, "{k}");
        }
        let cfg = ExportConfig {
            mask_unobserved: true,
            ..ExportConfig::default()
        };
        let (doc, base, _) = read(&tmp.path().join("masked"), &cfg);
        assert_eq!(doc["materials"][0]["alphaMode"], json!("MASK"));
        assert_eq!(base.channels, 3);
        // The alpha channel (read with the image crate: our reader keeps colour only).
        let rgba = image::open(tmp.path().join("masked/base_color.png"))
            .expect("png")
            .to_rgba8();
        for (k, &v) in coverage.iter().enumerate() {
            let alpha = rgba.as_raw()[4 * k + 3];
            assert_eq!(alpha, if v == 0 { 0 } else { 255 }, "pixel {k}");
        }
    }

    #[test]
    fn the_confidence_map_and_its_summary_travel_with_the_export() {
        let tmp = tempfile::tempdir().expect("tmp");
        let mut maps = checker(ModelKind::Ward);
        let n = maps.params.len();
        let per_pixel: Vec<[f32; 3]> = (0..n)
            .map(|i| [1.0, [0.0, 0.5, 1.0][i % 3], 0.25])
            .collect();
        let summary = svbrdf_core::confidence::ConfidenceSummary {
            observed_pixels: n,
            specular_unseen: 0.4,
            specular_flank: 0.3,
            specular_peak: 0.3,
            ..Default::default()
        };
        maps.confidence = Some(svbrdf_core::confidence::ConfidenceMap {
            per_pixel: per_pixel.clone(),
            summary,
        });
        let dir = tmp.path().join("out");
        let path = write(&maps, &ExportConfig::default(), &dir, false).expect("export");
        let doc: Value =
            serde_json::from_str(&std::fs::read_to_string(&path).expect("read")).expect("json");
        let c = &doc["asset"]["extras"]["svbrdf"]["confidence"];
        assert_eq!(c["specular_unseen_share"], json!(0.4), "{c}");
        assert!(
            c["summary"]
                .as_str()
                .expect("sentence")
                .contains("never seen"),
            "{c}"
        );
        let img = svbrdf_core::maps::read_image_linear(
            &dir.join(svbrdf_core::confidence::CONFIDENCE_FILE),
            Encoding::Linear,
        )
        .expect("confidence.png");
        for (k, v) in per_pixel.iter().enumerate() {
            for (got, want) in img.data[3 * k..3 * k + 3].iter().zip(v) {
                assert!((got - want).abs() < 0.01, "pixel {k}");
            }
        }
        // An out-of-range confidence is refused, not written.
        maps.confidence.as_mut().expect("set").per_pixel[0][1] = 1.5;
        assert!(write(
            &maps,
            &ExportConfig::default(),
            &tmp.path().join("bad"),
            false
        )
        .is_err());
    }

    /// The document for a fixed small material, compared with a checked-in golden
    /// file (regenerate with `SVBRDF_UPDATE_GOLDEN=1` after an intended change, and
    /// review the diff).
    #[test]
    fn document_matches_the_golden_file() {
        let tmp = tempfile::tempdir().expect("tmp");
        let maps = checker(ModelKind::Ward);
        let cfg = ExportConfig {
            sphere: false,
            ..ExportConfig::default()
        };
        let path = write(&maps, &cfg, &tmp.path().join("g"), false).expect("export");
        let mut doc: Value =
            serde_json::from_str(&std::fs::read_to_string(&path).expect("read")).expect("json");
        doc["asset"]["generator"] = json!("svbrdf");
        let text = serde_json::to_string_pretty(&doc).expect("json") + "\n";
        let golden =
            std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/golden/checker_quad.gltf");
        if std::env::var_os("SVBRDF_UPDATE_GOLDEN").is_some() {
            std::fs::create_dir_all(golden.parent().expect("parent")).expect("mkdir");
            std::fs::write(&golden, &text).expect("write golden");
        }
        let want = std::fs::read_to_string(&golden).expect("golden file");
        assert_eq!(
            text,
            want,
            "glTF document changed; see {}",
            golden.display()
        );
    }

    #[test]
    fn writes_a_complete_document_whose_buffers_match() {
        let tmp = tempfile::tempdir().expect("tmp");
        let maps = checker(ModelKind::Ward);
        let path = write(
            &maps,
            &ExportConfig::default(),
            &tmp.path().join("g"),
            false,
        )
        .expect("export");
        let doc: Value =
            serde_json::from_str(&std::fs::read_to_string(&path).expect("read")).expect("json");
        let bin = std::fs::metadata(tmp.path().join("g").join(BIN_FILE)).expect("bin");
        assert_eq!(doc["buffers"][0]["byteLength"].as_u64(), Some(bin.len()));
        for img in doc["images"].as_array().expect("images") {
            let f = tmp.path().join("g").join(img["uri"].as_str().expect("uri"));
            assert!(f.exists(), "{}", f.display());
        }
        assert_eq!(doc["meshes"].as_array().map(Vec::len), Some(2));
        // Refuses to replace without overwrite.
        assert!(write(
            &maps,
            &ExportConfig::default(),
            &tmp.path().join("g"),
            false
        )
        .is_err());
    }
}
