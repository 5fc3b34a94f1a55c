//! Mitsuba 3 export: `scene.xml`, meshes, textures and `render.py` in one folder.
//!
//! The material uses stock plugins only: `normalmap` (our tangent-space normal map, raw)
//! over a `blendbsdf` with weight 0.5 of a `diffuse` BSDF with reflectance `2 rho_d`
//! and a `roughconductor` with `material = none` (Fresnel = 1), anisotropic roughness
//! `alpha_u`/`alpha_v` textures and specular reflectance `2 rho_s`. The 0.5 blend of
//! doubled albedos is exactly the sum `rho_d / pi + specular lobe` that was fitted.
//! Approximation: a Ward fit becomes a Beckmann microfacet lobe with the same alphas
//! (Ward's lobe is Beckmann's with a simpler normalisation and no shadowing term); a
//! GGX fit becomes a GGX lobe with the same alphas but without the Schlick rise of
//! Fresnel towards grazing angles. `principled` was not used because its anisotropy
//! cannot point along +y per pixel and its specular is not coloured. Neither plugin
//! turns the anisotropy per texel: a lobe whose tangent the fit turned
//! (`tangent_rotation`) is written along the nearer of the plane's axes, so grooves at
//! 30 degrees to the markers render at 0 and grooves at 60 at 90 (the glTF export
//! keeps the angle).
//!
//! Scene units are the plane's centimetres, +z up, the quad at its measured place and a
//! sphere beside it, a point light and a dim constant environment.
use std::fmt::Write as _;
use std::io::Write;
use std::path::{Path, PathBuf};

use svbrdf_core::brdf::ModelKind;
use svbrdf_core::fsutil::{write_atomic, StagingDir};
use svbrdf_core::image::ImageF32;
use svbrdf_core::maps::{write_exr, write_png, Encoding, PngDepth};
use svbrdf_core::CoreError;

use crate::gltf::sphere_placement;
use crate::mesh::{quad, sphere, Mesh};
use crate::{ExportConfig, ExportError, MaterialMaps};

/// Whether a lobe turned by `rotation` radians lies nearer the plane's y axis than its
/// x axis (its alphas are then written swapped).
fn axis_swapped(rotation: f64) -> bool {
    let r = rotation.rem_euclid(std::f64::consts::PI);
    (std::f64::consts::FRAC_PI_4..3.0 * std::f64::consts::FRAC_PI_4).contains(&r)
}

/// File name of the scene inside the export folder.
pub const SCENE_FILE: &str = "scene.xml";

/// A mesh as Wavefront OBJ in plane centimetres (glTF metres, Y up -> plane cm, z up).
/// OBJ's `v` grows upwards in the image; Mitsuba flips it back on loading.
fn obj(m: &Mesh, offset: [f64; 2]) -> String {
    let mut s = String::from("# svbrdf preview mesh: plane centimetres, +z out of the surface\n");
    for p in &m.positions {
        let (x, y, z) = (
            f64::from(p[0]) * 100.0 + offset[0],
            -f64::from(p[2]) * 100.0 + offset[1],
            f64::from(p[1]) * 100.0,
        );
        let _ = writeln!(s, "v {x:.6} {y:.6} {z:.6}");
    }
    for t in &m.uvs {
        let _ = writeln!(s, "vt {:.6} {:.6}", t[0], 1.0 - t[1]);
    }
    for n in &m.normals {
        let _ = writeln!(s, "vn {:.6} {:.6} {:.6}", n[0], -n[2], n[1]);
    }
    for t in m.indices.chunks_exact(3) {
        let _ = writeln!(
            s,
            "f {a}/{a}/{a} {b}/{b}/{b} {c}/{c}/{c}",
            a = t[0] + 1,
            b = t[1] + 1,
            c = t[2] + 1
        );
    }
    s
}

fn bitmap(name: &str, file: &str) -> String {
    format!(
        r#"<texture type="bitmap" name="{name}"><string name="filename" value="{file}"/><boolean name="raw" value="true"/><string name="filter_type" value="bilinear"/></texture>"#
    )
}

/// Write the Mitsuba export into the folder `out` and return the scene path.
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
    let (w, h) = (maps.grid.width, maps.grid.height);
    let mut diffuse = ImageF32::new(w, h, 3);
    let mut specular = ImageF32::new(w, h, 3);
    let mut alpha_u = ImageF32::new(w, h, 1);
    let mut alpha_v = ImageF32::new(w, h, 1);
    let mut normal = ImageF32::new(w, h, 3);
    for (i, p) in maps.params.iter().enumerate() {
        for c in 0..3 {
            diffuse.data[3 * i + c] = (2.0 * p.rho_d[c].clamp(0.0, 1.0)) as f32;
            specular.data[3 * i + c] = (2.0 * p.rho_s[c].clamp(0.0, 1.0)) as f32;
        }
        // roughconductor's alphas lie along the mesh's u and v: a lobe turned by more
        // than 45 degrees is closer to the same lobe along the other axis.
        let (ax, ay) = if axis_swapped(p.tangent_rotation) {
            (p.alpha_y, p.alpha_x)
        } else {
            (p.alpha_x, p.alpha_y)
        };
        alpha_u.data[i] = ax.clamp(1e-3, 1.0) as f32;
        alpha_v.data[i] = ay.clamp(1e-3, 1.0) as f32;
        let n = p.normal();
        normal.data[3 * i..3 * i + 3].copy_from_slice(&[
            (0.5 * n.x + 0.5) as f32,
            (0.5 * n.y + 0.5) as f32,
            (0.5 * n.z + 0.5) as f32,
        ]);
    }
    let meta = |what: &str| {
        vec![
            ("map", what.to_string()),
            ("encoding", "linear".to_string()),
        ]
    };
    write_exr(
        &dir.join("diffuse_x2.exr"),
        &diffuse,
        &["R", "G", "B"],
        &meta("2 x diffuse albedo"),
    )?;
    write_exr(
        &dir.join("specular_x2.exr"),
        &specular,
        &["R", "G", "B"],
        &meta("2 x specular albedo"),
    )?;
    write_exr(
        &dir.join("alpha_u.exr"),
        &alpha_u,
        &["Y"],
        &meta("roughness along plane +x"),
    )?;
    write_exr(
        &dir.join("alpha_v.exr"),
        &alpha_v,
        &["Y"],
        &meta("roughness along plane +y"),
    )?;
    write_png(
        &dir.join("normal.png"),
        &normal,
        Encoding::Linear,
        PngDepth::Sixteen,
        &meta("tangent-space normal, 0.5 n + 0.5, +y up"),
    )?;
    // What was measured: the same coverage map as the glTF export's.
    let coverage = maps.coverage_shares();
    maps.write_coverage(dir)?;
    maps.write_confidence(dir)?;

    let region = maps.grid.region;
    let centre = [
        0.5 * (region.x_min + region.x_max),
        0.5 * (region.y_min + region.y_max),
    ];
    let mut shapes = vec![("quad.obj", obj(&quad(&region), centre))];
    let (radius, sc) = sphere_placement(maps);
    if cfg.sphere {
        let s = sphere(&region, radius, sc, cfg.sphere_segments, cfg.sphere_rings);
        shapes.push(("sphere.obj", obj(&s, centre)));
    }
    for (name, text) in &shapes {
        let p = dir.join(name);
        write_atomic(&p, |f| {
            f.write_all(text.as_bytes())
                .map_err(|e| CoreError::io(&p, e))
        })?;
    }

    // Camera and light: oblique view of the quad and the sphere from the -y side.
    let extent = region.width().max(region.height());
    let target = [
        centre[0]
            + if cfg.sphere {
                50.0 * (sc[0] + radius) - 0.25 * region.width()
            } else {
                0.0
            },
        centre[1],
        0.0,
    ];
    let dist = 2.2
        * (extent
            + if cfg.sphere {
                100.0 * 2.0 * radius
            } else {
                0.0
            });
    let origin = [target[0], target[1] - 0.75 * dist, 0.65 * dist];
    let light = [
        target[0] - 0.3 * extent,
        target[1] - 0.4 * extent,
        1.2 * extent,
    ];
    let light_r2 = light[2] * light[2];
    // A white diffuse surface under the light reads about 0.7.
    let intensity = 0.7 * std::f64::consts::PI * light_r2;
    let distribution = match maps.model {
        ModelKind::Ward => "beckmann",
        ModelKind::Ggx => "ggx",
    };
    let height = (cfg.mitsuba_width * 2).div_ceil(3);
    let mut xml = String::new();
    let _ = writeln!(xml, r#"<?xml version="1.0" encoding="utf-8"?>"#);
    let _ = writeln!(
        xml,
        "<!-- svbrdf {}: {} fit, scene units cm, +z out of the material. Textures: *.exr linear; normal.png linear (raw). See docs/CONVENTIONS.md. Render: python3 render.py -->",
        env!("CARGO_PKG_VERSION"),
        maps.model.model().name()
    );
    if let Some(c) = coverage {
        let _ = writeln!(
            xml,
            "<!-- coverage.png: {:.1}% of the material measured (seen by at least {} frames), {:.1}% seen by fewer, {:.1}% never seen (its BRDF is copied from the nearest measured cluster, not measured) -->",
            100.0 * c.measured,
            crate::MEASURED_VIEWS,
            100.0 * c.thin,
            100.0 * c.unobserved
        );
    }
    if let Some(c) = &maps.confidence {
        let _ = writeln!(
            xml,
            "<!-- {}: {} -->",
            svbrdf_core::confidence::CONFIDENCE_FILE,
            c.summary.sentence().replace("--", "-")
        );
    }
    let _ = writeln!(xml, r#"<scene version="3.0.0">"#);
    let _ = writeln!(
        xml,
        r#"  <default name="spp" value="{}"/>"#,
        cfg.mitsuba_spp
    );
    let _ = writeln!(
        xml,
        r#"  <default name="width" value="{}"/>"#,
        cfg.mitsuba_width
    );
    let _ = writeln!(xml, r#"  <default name="height" value="{height}"/>"#);
    let _ = writeln!(
        xml,
        r#"  <integrator type="path"><integer name="max_depth" value="4"/></integrator>"#
    );
    let _ = writeln!(xml, r#"  <sensor type="perspective">"#);
    let _ = writeln!(
        xml,
        r#"    <float name="fov" value="40"/><string name="fov_axis" value="x"/>"#
    );
    let _ = writeln!(
        xml,
        r#"    <transform name="to_world"><lookat origin="{:.4}, {:.4}, {:.4}" target="{:.4}, {:.4}, {:.4}" up="0, 0, 1"/></transform>"#,
        origin[0], origin[1], origin[2], target[0], target[1], target[2]
    );
    let _ = writeln!(
        xml,
        r#"    <sampler type="independent"><integer name="sample_count" value="$spp"/></sampler>"#
    );
    let _ = writeln!(
        xml,
        r#"    <film type="hdrfilm"><integer name="width" value="$width"/><integer name="height" value="$height"/><string name="pixel_format" value="rgb"/></film>"#
    );
    let _ = writeln!(xml, "  </sensor>");
    let _ = writeln!(xml, r#"  <bsdf type="normalmap" id="{}">"#, cfg.name);
    let _ = writeln!(xml, "    {}", bitmap("normalmap", "normal.png"));
    let _ = writeln!(xml, r#"    <bsdf type="blendbsdf">"#);
    let _ = writeln!(xml, r#"      <float name="weight" value="0.5"/>"#);
    let _ = writeln!(
        xml,
        r#"      <bsdf type="diffuse">{}</bsdf>"#,
        bitmap("reflectance", "diffuse_x2.exr")
    );
    let _ = writeln!(xml, r#"      <bsdf type="roughconductor">"#);
    let _ = writeln!(
        xml,
        r#"        <string name="material" value="none"/><string name="distribution" value="{distribution}"/>"#
    );
    let _ = writeln!(xml, "        {}", bitmap("alpha_u", "alpha_u.exr"));
    let _ = writeln!(xml, "        {}", bitmap("alpha_v", "alpha_v.exr"));
    let _ = writeln!(
        xml,
        "        {}",
        bitmap("specular_reflectance", "specular_x2.exr")
    );
    let _ = writeln!(xml, "      </bsdf>\n    </bsdf>\n  </bsdf>");
    for (name, _) in &shapes {
        let _ = writeln!(
            xml,
            r#"  <shape type="obj"><string name="filename" value="{name}"/><boolean name="face_normals" value="false"/><ref id="{}"/></shape>"#,
            cfg.name
        );
    }
    let _ = writeln!(
        xml,
        r#"  <emitter type="point"><point name="position" x="{:.4}" y="{:.4}" z="{:.4}"/><rgb name="intensity" value="{intensity:.3}"/></emitter>"#,
        light[0], light[1], light[2]
    );
    let _ = writeln!(
        xml,
        r#"  <emitter type="constant"><rgb name="radiance" value="0.08"/></emitter>"#
    );
    let _ = writeln!(xml, "</scene>");
    let scene = dir.join(SCENE_FILE);
    write_atomic(&scene, |f| {
        f.write_all(xml.as_bytes())
            .map_err(|e| CoreError::io(&scene, e))
    })?;
    let script = dir.join("render.py");
    write_atomic(&script, |f| {
        f.write_all(RENDER_PY.as_bytes())
            .map_err(|e| CoreError::io(&script, e))
    })?;
    let target = staging.commit()?;
    Ok(target.join(SCENE_FILE))
}

/// Renders the scene with the stock `mitsuba` package (`pip install mitsuba`).
const RENDER_PY: &str = r#"#!/usr/bin/env python3
"""Render scene.xml with Mitsuba 3 (pip install mitsuba).

Usage: python3 render.py [--spp N] [--width W] [--out render.exr]
Writes a linear EXR and an sRGB PNG beside it. Uses the scalar_rgb variant, which
runs on any CPU; pass --variant llvm_ad_rgb for a faster, vectorised render.
"""
import argparse
import os

import mitsuba as mi

ap = argparse.ArgumentParser()
ap.add_argument("--spp", type=int, default=None)
ap.add_argument("--width", type=int, default=None)
ap.add_argument("--variant", default="scalar_rgb")
ap.add_argument("--out", default="render.exr")
a = ap.parse_args()
mi.set_variant(a.variant)
here = os.path.dirname(os.path.abspath(__file__))
params = {}
if a.spp:
    params["spp"] = a.spp
if a.width:
    params["width"] = a.width
    params["height"] = (2 * a.width + 2) // 3
scene = mi.load_file(os.path.join(here, "scene.xml"), **params)
img = mi.render(scene)
mi.util.write_bitmap(a.out, img)
mi.util.write_bitmap(os.path.splitext(a.out)[0] + ".png", img)
print(a.out)
"#;

#[cfg(test)]
mod tests {
    use super::*;
    use crate::gltf::tests::checker;

    #[test]
    fn turned_lobes_are_written_along_the_nearer_axis() {
        let deg = |d: f64| d.to_radians();
        for (turn, swapped) in [(0.0, false), (30.0, false), (50.0, true), (120.0, true)] {
            assert_eq!(axis_swapped(deg(turn)), swapped, "{turn}");
        }
        assert!(!axis_swapped(deg(170.0)) && !axis_swapped(deg(-10.0)));
    }

    #[test]
    fn scene_references_files_that_exist() {
        let tmp = tempfile::tempdir().expect("tmp");
        let maps = checker(ModelKind::Ggx);
        let scene = write(
            &maps,
            &ExportConfig::default(),
            &tmp.path().join("m"),
            false,
        )
        .expect("export");
        let xml = std::fs::read_to_string(&scene).expect("read");
        for part in xml.split("value=\"").skip(1) {
            let v = part.split('"').next().unwrap_or("");
            if v.ends_with(".exr") || v.ends_with(".png") || v.ends_with(".obj") {
                assert!(tmp.path().join("m").join(v).exists(), "{v}");
            }
        }
        assert!(xml.contains(r#"value="ggx""#));
        let quad = std::fs::read_to_string(tmp.path().join("m/quad.obj")).expect("obj");
        assert_eq!(quad.lines().filter(|l| l.starts_with("f ")).count(), 2);
    }
}
