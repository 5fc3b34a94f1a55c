//! `report.html`: one self-contained page about a run (every image embedded, no network,
//! opens from disk). It shows whatever the run folder holds, so it works for a full
//! `svbrdf run`, for a fit of an imported capture, and with or without ground truth:
//!
//! - `aligned/`: panorama, camera and flash trajectory, connectivity map, frames kept
//!   and dropped, alignment timings;
//! - `maps/`: every map, initial and final clusters, residual and coverage, the
//!   re-rendering strip (input frames over their re-rendering) and per-frame errors;
//! - `renders/` (written here): the fitted material on a sphere under three lights and
//!   on its plane under an oblique point light, by [`crate::render`];
//! - `truth/` (synthetic captures): `accuracy.json` and truth | fit | difference
//!   pictures;
//! - `run.json`: stage times; `export/`: links to the glTF and Mitsuba files.
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use svbrdf_core::fsutil::write_atomic;
use svbrdf_core::CoreError;

use crate::{ExportError, MaterialMaps};

mod page;
mod pictures;

use page::{escape, frame_chart, num, read_json, timings, Page};
use pictures::save;
pub use pictures::{coverage_sentence, gloss_picture, measured_picture, write_renders};

/// File name of the report inside a run folder.
pub const REPORT_FILE: &str = "report.html";
/// Longest side of an embedded image, pixels (larger ones are shrunk for the page;
/// the full-resolution files stay beside it).
pub const MAX_EMBED_SIDE: u32 = 1024;

/// Write `report.html` (and `renders/` when `maps` are given) into the run folder
/// `dir`. Returns the report's path.
pub fn write_report(dir: &Path, maps: Option<&MaterialMaps>) -> Result<PathBuf, ExportError> {
    let mut page = Page {
        html: String::new(),
        images: 0,
    };
    let align = read_json(&dir.join("aligned/align.json"));
    let fit = read_json(&dir.join("maps/fit.json"));
    let run = read_json(&dir.join("run.json"));
    let truth = read_json(&dir.join("truth/accuracy.json"));

    // Summary.
    page.section("summary", "Summary", "");
    let mut rows = Vec::new();
    if let Some(r) = &run {
        rows.push((
            "video".into(),
            r["inputs"]["video"]["path"]
                .as_str()
                .unwrap_or("?")
                .to_string(),
        ));
        let st: Vec<String> = ["align", "fit", "export"]
            .iter()
            .filter(|n| r["stages"][**n].is_object())
            .map(|n| format!("{n} {} s", num(&r["stages"][*n]["seconds"], 1)))
            .collect();
        rows.push(("stage times".into(), st.join(", ")));
        if let Some(w) = r["warnings"].as_array().filter(|w| !w.is_empty()) {
            let w: Vec<&str> = w.iter().filter_map(|s| s.as_str()).collect();
            rows.push(("warnings".into(), w.join(" | ")));
        }
    }
    if let Some(a) = &align {
        let f = &a["summary"]["frames"];
        rows.push((
            "frames".into(),
            format!(
                "{} decoded, {} kept; dropped: {} blurry, {} disconnected, {} unregistered, {} outside the markers",
                f["decoded"], f["kept"], f["blurry"], f["disconnected"], f["unregistered"], f["outside"]
            ),
        ));
        let t = &a["summary"]["second"];
        if t.is_object() {
            let g = &t["frames"];
            rows.push((
                "second camera".into(),
                format!(
                    "synchronised at {} s of the second video{}; {} frames used, {} kept ({} blurry, {} unregistered, {} implausible); {} before the flash onset and {} after the flash video's end left out",
                    num(&t["sync_offset_s"], 3),
                    if t["onset"].is_object() { " (flash onset)" } else { " (given by hand)" },
                    g["decoded"], g["kept"], g["blurry"], g["unregistered"], g["outside"],
                    t["before_onset"], t["after_end"]
                ),
            ));
        }
        let checks = a["summary"]["self_check"]
            .as_array()
            .cloned()
            .unwrap_or_default();
        let verified: Vec<f64> = checks
            .iter()
            .filter_map(|c| c["shift_mm"].as_f64())
            .collect();
        if !checks.is_empty() {
            rows.push((
                "self-check".into(),
                format!(
                    "{} of {} registered frames verified against the reference photo; largest median offset {:.2} mm; {} frames dropped as inconsistent",
                    verified.len(),
                    checks.len(),
                    verified.iter().copied().fold(0.0, f64::max),
                    a["summary"]["frames"]["inconsistent"].as_u64().unwrap_or(0)
                ),
            ));
        }
        if let Some(c) = a["summary"]["coverage"].as_f64() {
            rows.push((
                "coverage".into(),
                format!(
                    "{:.1}% of the region seen by at least {} registered frames",
                    100.0 * c,
                    crate::MEASURED_VIEWS
                ),
            ));
        }
        if let Some(line) = densified_row(a) {
            rows.push(("frame step".into(), line));
        }
        rows.push((
            "alignment".into(),
            format!(
                "global solve residual rms {} cm, median {} cm; {} frames anchored to the reference photo",
                num(&a["summary"]["solve_rms_cm"], 4),
                num(&a["summary"]["solve_median_cm"], 4),
                a["summary"]["reference_anchored"]
            ),
        ));
        let sup = &a["summary"]["support"];
        if sup["removed"].as_u64().unwrap_or(0) > 0 {
            rows.push((
                "support".into(),
                format!(
                    "{} of {} sub-frames left out because no match, marker or reference-photo match of their own fixed where they lie on the material (their maps would be guesses); {} frames dropped for it, {} kept in part",
                    sup["removed"],
                    sup["subframes"],
                    sup["frames_dropped"].as_array().map_or(0, Vec::len),
                    sup["partial_frames"].as_array().map_or(0, Vec::len)
                ),
            ));
        }
        let pieces = a["summary"]["pieces"].as_u64().unwrap_or(1);
        if pieces > 1 {
            rows.push((
                "pieces".into(),
                format!(
                    "the frames form {pieces} pieces that no frame pair connects; each is tied to the plane by the reference photo or markers (checked frame by frame by the self-check)"
                ),
            ));
        }
        let e = &a["summary"]["exposure"];
        if e.is_object() {
            let text = match (e["mode"].as_str(), e["range_ev"].as_array()) {
                (Some("estimated"), Some(r)) if r.len() == 2 => format!(
                    "one gain per frame estimated from overlapping frames: {:+.2} to {:+.2} EV around the mean (residual spread {:.1}%); each frame's observations are divided by its gain",
                    r[0].as_f64().unwrap_or(0.0),
                    r[1].as_f64().unwrap_or(0.0),
                    100.0 * e["residual_spread"].as_f64().unwrap_or(0.0)
                ),
                (Some("fixed"), _) => "assumed fixed (--fixed-exposure)".into(),
                (Some("steady"), _) => format!(
                    "steady: one gain per frame explains no more than fixed exposure (residual spread {:.1}% against {:.1}%), so frames are taken as equally exposed",
                    100.0 * e["residual_spread"].as_f64().unwrap_or(0.0),
                    100.0 * e["residual_spread_fixed"].as_f64().unwrap_or(0.0)
                ),
                _ => format!(
                    "not estimated ({}): frames taken as equally exposed",
                    e["note"].as_str().unwrap_or("no reason recorded")
                ),
            };
            rows.push(("exposure".into(), text));
        }
        let v = &a["summary"]["video_decoding"];
        if v.is_object() {
            rows.push((
                "video".into(),
                format!(
                    "{} {}, Y'CbCr matrix {}, range {}: decoded with {}, transfer {}{} ({})",
                    v["codec"].as_str().unwrap_or("?"),
                    v["pix_fmt"].as_str().unwrap_or("?"),
                    v["matrix_tag"].as_str().unwrap_or("untagged"),
                    v["range_tag"].as_str().unwrap_or("untagged"),
                    v["decoded_with"]
                        .as_str()
                        .unwrap_or("?")
                        .replace("bt", "BT."),
                    v["transfer"].as_str().unwrap_or("sdr").to_uppercase(),
                    if v["from_bt2020"].as_bool() == Some(true) {
                        ", BT.2020 primaries converted to BT.709"
                    } else {
                        ""
                    },
                    v["decoder"].as_str().unwrap_or("opencv")
                ),
            ));
        }
        rows.push((
            "alignment timings".into(),
            timings(&a["summary"]["timings"]),
        ));
    }
    if let Some(f) = &fit {
        let s = &f["summary"];
        rows.push((
            "maps".into(),
            format!(
                "{} x {} pixels at {} px/cm, model {}, albedo units {}",
                f["width"],
                f["height"],
                num(&f["px_per_cm"], 1),
                f["model"].as_str().unwrap_or("?"),
                f["albedo_units"].as_str().unwrap_or("?")
            ),
        ));
        rows.push((
            "clusters".into(),
            format!(
                "{} initial (k-means elbow), {} final after recursive splitting, deepest level {}",
                s["initial_clusters"], s["final_clusters"], s["max_depth"]
            ),
        ));
        rows.push((
            "observations".into(),
            format!(
                "{} ({} with a clipped channel); {} of {} pixels observed",
                s["observations"], s["clipped_observations"], s["covered_pixels"], s["pixels"]
            ),
        ));
        rows.push((
            "re-rendering error".into(),
            format!(
                "linear RMS {} with clusters only, {} final",
                num(&s["rmse_clusters"], 4),
                num(&s["rmse_final"], 4)
            ),
        ));
        if let Some(sel) = s["selection"].as_object() {
            rows.push((
                "settings".into(),
                format!(
                    "{} ({})",
                    sel["chosen"].as_str().unwrap_or("?"),
                    sel["reason"].as_str().unwrap_or("")
                ),
            ));
        }
        if let Some(g) = s["turned_grain"].as_object() {
            rows.push((
                "anisotropy".into(),
                format!(
                    "turned from the markers' axes on {:.0}% of the surface (median {:.0} degrees from +x towards +y; roughness map B). The glTF export keeps the angle; the Mitsuba export writes it along the nearer axis.",
                    100.0 * g["share"].as_f64().unwrap_or(0.0),
                    g["median_deg"].as_f64().unwrap_or(0.0)
                ),
            ));
        }
        rows.push(("fit timings".into(), timings(&s["timings"])));
    }
    page.table(&rows);
    page.end();

    // How the settings were chosen: error on held-out frames against training error.
    if let Some(c) = fit.as_ref().and_then(|f| {
        let c = f["summary"]["selection"]["candidates"].as_array()?;
        (!c.is_empty()).then_some(c)
    }) {
        let folds = fit.as_ref().map_or(0, |f| {
            f["summary"]["selection"]["folds"].as_u64().unwrap_or(0)
        });
        page.section(
            "selection",
            "How the settings were chosen",
            &escape(&format!(
                "Each setting was fitted {folds} times, each time without one stretch of the video, and asked to predict the frames it had not seen (RMS error of sRGB-encoded values; linear radiance in brackets). The training error always prefers more detail; the held-out error says which setting predicts new views. A setting far worse than the configured settings after a fold is not fitted on the rest (its row says so). The configured settings last."
            )),
        );
        let rows: Vec<(String, String)> = c
            .iter()
            .map(|c| {
                let dropped = c["dropped_after"].as_u64().map_or(String::new(), |n| {
                    format!(" (fitted on {n} of the {folds} folds only: its error there was far above the configured settings', so it could not be chosen)")
                });
                (
                    c["name"].as_str().unwrap_or("?").to_string(),
                    format!(
                        "held-out {} ({}), training {} ({}): {}{dropped}",
                        num(&c["held_out_srgb_rmse"], 4),
                        num(&c["held_out_rmse"], 4),
                        num(&c["training_srgb_rmse"], 4),
                        num(&c["training_rmse"], 4),
                        c["settings"].as_str().unwrap_or("")
                    ),
                )
            })
            .collect();
        page.table(&rows);
        page.end();
    }

    // Renders.
    if let Some(m) = maps {
        let renders = write_renders(m, &dir.join("renders"))?;
        page.section(
            "renders",
            "Renders",
            "The fitted model itself (before conversion for other renderers), rendered by svbrdf's CPU renderer; sRGB.",
        );
        page.figures(&renders, false)?;
        page.end();
    }

    // What was measured and what was filled in.
    if let Some((m, img)) = maps.and_then(|m| Some((m, measured_picture(m)?))) {
        let p = dir.join("renders/measured.png");
        save(
            &p,
            &img,
            "diffuse albedo; magenta stripes: seen by no frame (dense) or by 1-2 frames (sparse)",
        )?;
        page.section(
            "coverage",
            "What was measured",
            &coverage_sentence(m).unwrap_or_default(),
        );
        page.figures(
            &[(
                p,
                "diffuse albedo (sRGB); magenta stripes mark parts not measured".into(),
            )],
            false,
        )?;
        page.end();
    }

    // Where the gloss was measured and where it is a guess.
    if let Some((c, img)) = maps.and_then(|m| Some((m.confidence.as_ref()?, gloss_picture(m)?))) {
        let p = dir.join("renders/gloss_measured.png");
        save(
            &p,
            &img,
            "diffuse albedo; cyan stripes: highlight never seen (dense) or only its flank or clipped (sparse)",
        )?;
        page.section(
            "confidence",
            "Where the gloss was measured",
            &escape(&format!(
                "{} Dense cyan stripes: the highlight was never seen there; sparse: only its flank or a clipped peak. The exports carry the full confidence map ({}: {}).",
                c.summary.sentence(),
                svbrdf_core::confidence::CONFIDENCE_FILE,
                svbrdf_core::confidence::CONFIDENCE_MEANING
            )),
        );
        page.figures(
            &[(
                p,
                "diffuse albedo (sRGB); cyan stripes mark parts whose gloss is a guess".into(),
            )],
            false,
        )?;
        page.end();
    }

    // Maps.
    let md = dir.join("maps/maps");
    if md.exists() {
        page.section(
            "maps",
            "Maps",
            "Colour maps are shown sRGB-encoded (the EXR files beside them are linear); roughness, normal, residual and coverage are linear data. Top of each map = +y on the plane.",
        );
        let items: Vec<(PathBuf, String)> = [
            ("diffuse.png", "diffuse albedo rho_d (sRGB)"),
            ("specular.png", "specular albedo rho_s (sRGB)"),
            (
                "roughness.png",
                "roughness: R = alpha_x, G = alpha_y (linear)",
            ),
            (
                "normal.png",
                "normal, tangent space, +Y up (linear, 0.5 n + 0.5)",
            ),
            ("average.png", "average observed colour (sRGB)"),
            ("initial_clusters.png", "initial clusters (k-means)"),
            ("clusters.png", "final clusters (after splitting)"),
            (
                "residual.png",
                "per-pixel re-rendering RMS error (linear, x10)",
            ),
            (
                "coverage.png",
                "observations per pixel (black: none, filled)",
            ),
        ]
        .iter()
        .map(|(f, c)| (md.join(f), c.to_string()))
        .collect();
        page.figures(&items, false)?;
        page.end();
    }

    // Geometry.
    let ad = dir.join("aligned");
    if ad.exists() {
        page.section(
            "geometry",
            "Geometry",
            "From the alignment stage (paper section 3.1).",
        );
        let items: Vec<(PathBuf, String)> = [
            (
                "panorama.png",
                "average-colour panorama of the aligned frames",
            ),
            (
                "trajectory.png",
                "camera (and flash) trajectory over the plane",
            ),
            (
                "connectivity.png",
                "connectivity map: frame pairs that overlap",
            ),
            (
                "exposure.png",
                "exposure gain per flash frame over time (lines every stop, the brighter one at the mean; orange: interpolated; grey: not applied, the exposure was steady); the fit divides each frame by its gain",
            ),
        ]
        .iter()
        .map(|(f, c)| (ad.join(f), c.to_string()))
        .collect();
        page.figures(&items, false)?;
        page.end();
    }

    // Re-rendering.
    if let Some(f) = &fit {
        page.section(
            "rerender",
            "Input frames and their re-rendering",
            "Top: observed frames resampled onto the plane; bottom: the same views rendered from the fitted maps (the paper's supplemental comparison). Below: error per input frame, relative to its mean radiance.",
        );
        page.figures(
            &[(
                dir.join("maps/rerender.png"),
                "observed (top) vs re-rendered (bottom)".into(),
            )],
            true,
        )?;
        if let Some(frames) = f["summary"]["frames"].as_array() {
            page.html.push_str(&frame_chart(frames));
        }
        page.end();
    }

    // Ground truth.
    if let Some(t) = &truth {
        page.section(
            "truth",
            "Against the simulator's ground truth",
            "Diffuse albedo after one global scale factor (the flash intensity is unknown to the fit); relighting under held-out oblique lights as RMSE of linear radiance divided by the mean.",
        );
        let mut rows = vec![
            (
                "diffuse albedo RMSE".to_string(),
                num(&t["diffuse_rmse"], 4),
            ),
            (
                "global albedo scale".to_string(),
                num(&t["albedo_scale"], 4),
            ),
            (
                "normal error, mean / median (deg)".to_string(),
                format!(
                    "{} / {}",
                    num(&t["normal_mean_deg"], 2),
                    num(&t["normal_median_deg"], 2)
                ),
            ),
            (
                "relighting error, mean".to_string(),
                format!(
                    "{}%",
                    num(
                        &(t["relight_relative_rmse_mean"].as_f64().unwrap_or(f64::NAN) * 100.0)
                            .into(),
                        1
                    )
                ),
            ),
        ];
        if let Some(a) = t.get("align_error_px_median") {
            rows.push(("alignment error, median (output px)".into(), num(a, 3)));
        }
        page.table(&rows);
        let td = dir.join("truth");
        let mut pics: Vec<(PathBuf, String)> = std::fs::read_dir(&td)
            .map_err(|e| CoreError::io(&td, e))?
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| p.extension().is_some_and(|x| x == "png"))
            .map(|p| {
                let name = p
                    .file_stem()
                    .map(|s| s.to_string_lossy().into_owned())
                    .unwrap_or_default();
                (p, format!("{name}: truth | fit | 4 x |difference|"))
            })
            .collect();
        pics.sort();
        page.figures(&pics, true)?;
        page.end();
    }

    // Held-out evaluation (`svbrdf eval`).
    if let Some(e) = read_json(&dir.join("eval/eval.json")) {
        page.section(
            "eval",
            "Held-out photographs",
            "Fitted without these frames, then rendered from each one's own camera and light and compared with the photo on the plane: RMSE and SSIM of linear values and of sRGB values. Strips: photo | rendering | 4 x |difference|.",
        );
        let mut rows = Vec::new();
        for im in e["images"].as_array().into_iter().flatten() {
            rows.push((
                im["name"].as_str().unwrap_or("?").to_string(),
                format!(
                    "RMSE linear {} ({}% of the mean), sRGB {}; SSIM linear {}, sRGB {}",
                    num(&im["rmse_linear"], 4),
                    num(
                        &(im["relative_rmse_linear"].as_f64().unwrap_or(f64::NAN) * 100.0).into(),
                        1
                    ),
                    num(&im["rmse_srgb"], 4),
                    num(&im["ssim_linear"], 3),
                    num(&im["ssim_srgb"], 3)
                ) + &im["flip"]
                    .as_f64()
                    .map(|f| format!("; FLIP {f:.3}"))
                    .unwrap_or_default(),
            ));
        }
        if let Some(m) = e["flip_metric"].as_str() {
            rows.push((
                "FLIP".into(),
                format!("{m}; 0 = identical, lower is better"),
            ));
        }
        rows.push((
            "fitted".into(),
            format!(
                "{} frames, model {}{}",
                e["fitted_frames"],
                e["model"].as_str().unwrap_or("?"),
                if e["diffuse_only"].as_bool() == Some(true) {
                    ", diffuse only (rho_s = 0)"
                } else {
                    ""
                }
            ),
        ));
        page.table(&rows);
        let pics: Vec<(PathBuf, String)> = e["images"]
            .as_array()
            .into_iter()
            .flatten()
            .filter_map(|im| {
                let strip = dir.join("eval").join(im["strip"].as_str()?);
                Some((
                    strip,
                    format!(
                        "{}: photo | rendering | 4 x |difference|",
                        im["name"].as_str().unwrap_or("?")
                    ),
                ))
            })
            .collect();
        page.figures(&pics, true)?;
        page.end();
    }

    // Files.
    page.section("files", "Files", "");
    let mut rows = Vec::new();
    for (what, rel) in [
        ("glTF 2.0 (quad + sphere)", "export/gltf/material.gltf"),
        ("Mitsuba 3 scene", "export/mitsuba/scene.xml"),
        ("maps (EXR linear, PNG)", "maps/maps"),
        ("fit manifest", "maps/fit.json"),
        ("registered capture", "aligned/capture.json"),
    ] {
        if dir.join(rel).exists() {
            rows.push((what.to_string(), rel.to_string()));
        }
    }
    page.html.push_str("<ul>");
    for (what, rel) in rows {
        let _ = write!(
            page.html,
            "<li>{}: <a href=\"{r}\">{r}</a></li>",
            escape(&what),
            r = escape(&rel)
        );
    }
    page.html.push_str("</ul>");
    page.end();

    let html = format!(
        r##"<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>svbrdf report</title>
<meta name="viewport" content="width=device-width, initial-scale=1">
<style>
body {{ font: 15px/1.45 system-ui, sans-serif; margin: 0 auto; max-width: 1200px; padding: 1em 2em; color: #222; background: #fafafa; }}
h1 {{ margin-bottom: 0.2em; }} h2 {{ border-bottom: 1px solid #ccc; padding-bottom: 0.2em; margin-top: 1.6em; }}
table {{ border-collapse: collapse; }} th {{ text-align: left; padding: 0.2em 1em 0.2em 0; vertical-align: top; white-space: nowrap; }} td {{ padding: 0.2em 0; }}
.grid {{ display: grid; grid-template-columns: repeat(auto-fill, minmax(260px, 1fr)); gap: 1em; }}
.grid.wide {{ grid-template-columns: 1fr; }}
figure {{ margin: 0; }} img {{ width: 100%; image-rendering: auto; background: #fff; border: 1px solid #ddd; }}
figcaption {{ font-size: 13px; color: #555; }}
.chart rect {{ fill: #4a7ab8; }} .chart text {{ font-size: 11px; fill: #555; }}
nav a {{ margin-right: 1em; }}
</style></head>
<body data-images-expected="{n}">
<h1>svbrdf report</h1>
<nav><a href="#summary">summary</a><a href="#renders">renders</a><a href="#maps">maps</a><a href="#geometry">geometry</a><a href="#rerender">re-rendering</a><a href="#truth">ground truth</a><a href="#files">files</a></nav>
{body}
<footer><p>Written by svbrdf {version}. Colour conventions: docs/CONVENTIONS.md.</p></footer>
<script>
// Self-check used by the browser test: how many images decoded, and any script error.
window.addEventListener("error", (e) => document.body.setAttribute("data-error", String(e.message)));
window.addEventListener("load", () => {{
  const imgs = Array.from(document.images);
  const ok = imgs.filter((i) => i.complete && i.naturalWidth > 0).length;
  document.body.setAttribute("data-images-loaded", ok + "/" + imgs.length);
}});
</script>
</body></html>
"##,
        n = page.images,
        body = page.html,
        version = env!("CARGO_PKG_VERSION"),
    );
    let path = dir.join(REPORT_FILE);
    write_atomic(&path, |w| {
        use std::io::Write;
        w.write_all(html.as_bytes())
            .map_err(|e| CoreError::io(&path, e))
    })?;
    Ok(path)
}

/// The report's line for a capture aligned twice (`align.json` `summary.densified`):
/// what the pass at the camera's frame step gave, what the finer pass gave, and which
/// one the capture uses.
fn densified_row(a: &serde_json::Value) -> Option<String> {
    let d = &a["summary"]["densified"];
    let first = d["first"]["frame_step"].as_u64()?;
    let finer = d["finer"]["frame_step"].as_u64()?;
    let pass = |p: &serde_json::Value| {
        let what = match p["coverage"].as_f64() {
            Some(c) if p["refusal"].is_null() => {
                format!("{:.1}% of the region covered", 100.0 * c)
            }
            _ => "refused".to_string(),
        };
        format!("{} of {} kept, {what}", p["kept"], p["sampled"])
    };
    Some(format!(
        "one frame in {first} sampled: {}; aligned again from one frame in {finer}: {}; this capture uses the {} pass",
        pass(&d["first"]),
        pass(&d["finer"]),
        if d["kept_finer"].as_bool() == Some(true) {
            "finer"
        } else {
            "first"
        }
    ))
}

#[cfg(test)]
mod tests {
    use super::page::base64;
    use super::*;

    #[test]
    fn base64_matches_the_rfc_examples() {
        for (i, o) in [
            ("", ""),
            ("f", "Zg=="),
            ("fo", "Zm8="),
            ("foo", "Zm9v"),
            ("foob", "Zm9vYg=="),
            ("fooba", "Zm9vYmE="),
            ("foobar", "Zm9vYmFy"),
        ] {
            assert_eq!(base64(i.as_bytes()), o);
        }
    }

    #[test]
    fn a_capture_aligned_twice_says_which_pass_it_uses() {
        let a = serde_json::json!({"summary": {"densified": {
            "first": {"frame_step": 5, "sampled": 26, "kept": 16, "coverage": 0.55,
                      "refusal": "only 55.0% of the region is seen"},
            "finer": {"frame_step": 2, "sampled": 61, "kept": 46, "coverage": 0.972,
                      "refusal": null},
            "kept_finer": true}}});
        assert_eq!(
            densified_row(&a).expect("row"),
            "one frame in 5 sampled: 16 of 26 kept, refused; aligned again from one frame in 2: 46 of 61 kept, 97.2% of the region covered; this capture uses the finer pass"
        );
        assert!(densified_row(&serde_json::json!({"summary": {}})).is_none());
    }

    #[test]
    fn report_embeds_renders_and_escapes() {
        let tmp = tempfile::tempdir().expect("tmp");
        let maps = crate::gltf::tests::checker(svbrdf_core::brdf::ModelKind::Ward);
        let p = write_report(tmp.path(), Some(&maps)).expect("report");
        let html = std::fs::read_to_string(p).expect("read");
        assert_eq!(html.matches("data:image/png;base64,").count(), 4);
        assert!(html.contains("data-images-expected=\"4\""));
        assert_eq!(escape("<a & \"b\">"), "&lt;a &amp; &quot;b&quot;&gt;");
    }

    #[test]
    fn unmeasured_parts_are_hatched_and_said() {
        let tmp = tempfile::tempdir().expect("tmp");
        let mut maps = crate::gltf::tests::checker(svbrdf_core::brdf::ModelKind::Ward);
        let (w, n) = (maps.grid.width, maps.params.len());
        // The left half unseen, the right half measured.
        maps.coverage = Some((0..n).map(|i| if i % w < w / 2 { 0 } else { 7 }).collect());
        let img = measured_picture(&maps).expect("picture");
        let magenta = |i: usize| img.data[3 * i..3 * i + 3] == [1.0, 0.0, 1.0];
        let left = (0..n).filter(|&i| i % w < w / 2);
        let right = (0..n).filter(|&i| i % w >= w / 2);
        assert!(left.filter(|&i| magenta(i)).count() > 0);
        assert_eq!(right.filter(|&i| magenta(i)).count(), 0);
        let said = coverage_sentence(&maps).expect("sentence");
        assert!(said.contains("50.0% by none"), "{said}");
        let p = write_report(tmp.path(), Some(&maps)).expect("report");
        let html = std::fs::read_to_string(p).expect("read");
        assert!(html.contains("What was measured") && html.contains("not a measurement"));
        assert_eq!(html.matches("data:image/png;base64,").count(), 5);
        // Fully measured: no hatch, and the page says so.
        maps.coverage = Some(vec![3; n]);
        assert!(coverage_sentence(&maps)
            .expect("sentence")
            .contains("all of it is measured"));
    }

    #[test]
    fn parts_whose_highlight_was_never_seen_are_hatched_and_said() {
        let tmp = tempfile::tempdir().expect("tmp");
        let mut maps = crate::gltf::tests::checker(svbrdf_core::brdf::ModelKind::Ward);
        let (w, n) = (maps.grid.width, maps.params.len());
        assert!(gloss_picture(&maps).is_none());
        // The top rows' highlight never seen, the rest seen at its peak.
        maps.confidence = Some(svbrdf_core::confidence::ConfidenceMap {
            per_pixel: (0..n)
                .map(|i| [1.0, if i < 4 * w { 0.0 } else { 1.0 }, 1.0])
                .collect(),
            summary: svbrdf_core::confidence::ConfidenceSummary {
                observed_pixels: n,
                specular_peak: 0.7,
                specular_unseen: 0.3,
                ..Default::default()
            },
        });
        let img = gloss_picture(&maps).expect("picture");
        let cyan = |i: usize| img.data[3 * i..3 * i + 3] == [0.0, 1.0, 1.0];
        assert!((0..4 * w).any(cyan));
        assert!(!(4 * w..n).any(cyan));
        let p = write_report(tmp.path(), Some(&maps)).expect("report");
        let html = std::fs::read_to_string(p).expect("read");
        assert!(html.contains("Where the gloss was measured"), "no section");
        assert!(html.contains("their gloss is a guess from similar regions"));
    }
}
