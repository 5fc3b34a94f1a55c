//! Importing registered image sets and held-out evaluation, on the real cards-blue
//! photographs in `../shared/data/real/` (absent in a user's clone: the tests then
//! skip and say why; CI has the data and `SVBRDF_REQUIRE_TOOLS=1` makes them required).

use std::path::{Path, PathBuf};

use crate::util::{repo_root, skip_without, stderr, svbrdf, temp_dir};

fn cards_blue() -> Option<PathBuf> {
    let p = repo_root().join("../shared/data/real/materialgan-cards-blue");
    let present = p.join("camera_pos.txt").is_file();
    if skip_without(
        "../shared/data/real/materialgan-cards-blue (real photos for evaluation)",
        present,
        "the project's shared data folder, present in CI; never copied into the project",
    ) {
        return None;
    }
    Some(p)
}

/// `svbrdf import` of a MaterialGAN-layout folder into a fresh folder.
fn import(data: &Path) -> PathBuf {
    import_as(data, "cards")
}

/// [`import`] into the temporary folder `name`.
fn import_as(data: &Path, name: &str) -> PathBuf {
    let cap = temp_dir().join(name);
    let o = svbrdf(&[
        "import",
        "--materialgan",
        data.to_str().unwrap(),
        "--out",
        cap.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    cap
}

fn json(path: PathBuf) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(&path).unwrap_or_else(|e| {
        panic!("{}: {e}", path.display());
    }))
    .unwrap()
}

/// The test: eval on cards-blue at reduced resolution, holding out two photos,
/// reports relighting errors, writes strips and a report, and the specular fit beats
/// the diffuse-only baseline on the held-out photos.
#[test]
fn eval_on_real_photos_beats_the_diffuse_only_baseline() {
    let Some(data) = cards_blue() else { return };
    let cap = import(&data);
    let c = json(cap.join("capture.json"));
    assert_eq!(c["frames"].as_array().map(Vec::len), Some(9));
    assert!(c["light_intensity"].is_null());

    // NVIDIA's FLIP evaluator, where installed (scripts/test-tools.sh).
    let flip = repo_root().join(".venv-tools/bin/flip");
    let has_flip = !skip_without(
        "flip-evaluator",
        flip.is_file(),
        "scripts/test-tools.sh installs it into .venv-tools",
    );
    let out = temp_dir().join("eval");
    let mut args = vec![
        "eval".to_string(),
        "--capture".into(),
        cap.to_str().unwrap().into(),
        "--holdout".into(),
        "7,8".into(),
        "--px-per-cm".into(),
        "25".into(),
        "--baseline".into(),
        "--out".into(),
        out.to_str().unwrap().into(),
    ];
    if has_flip {
        args.extend(["--flip".into(), flip.to_str().unwrap().into()]);
    }
    let o = svbrdf(&args.iter().map(String::as_str).collect::<Vec<_>>());
    assert!(o.status.success(), "{}", stderr(&o));
    let full = json(out.join("eval/eval.json"));
    let diffuse = json(out.join("diffuse-only/eval/eval.json"));
    assert_eq!(full["fitted_frames"], 7);
    assert_eq!(diffuse["diffuse_only"], true);
    for r in [&full, &diffuse] {
        let images = r["images"].as_array().unwrap();
        assert_eq!(images.len(), 2);
        for im in images {
            for k in ["rmse_linear", "rmse_srgb", "ssim_linear", "ssim_srgb"] {
                let v = im[k].as_f64().unwrap();
                assert!(v.is_finite() && v > -1.0 && v < 2.0, "{k} = {v}");
            }
            assert!(im["pixels"].as_u64().unwrap() > 10_000);
        }
    }
    for id in ["007", "008"] {
        assert!(out.join(format!("eval/strip_{id}.png")).is_file());
    }
    let (f, d) = (&full["mean"], &diffuse["mean"]);
    let summary = json(out.join("eval-summary.json"));
    let wins = &summary["pairwise"]["full_wins"];
    if has_flip {
        // Perceptual difference in [0, 1]; the full fit looks closer to the photos.
        for r in [&full, &diffuse] {
            for im in r["images"].as_array().unwrap() {
                let v = im["flip"].as_f64().unwrap();
                assert!(v > 0.0 && v < 1.0, "flip {v}");
            }
            assert!(r["flip_metric"].as_str().unwrap().contains("FLIP"));
        }
        assert!(
            f["flip"].as_f64() < d["flip"].as_f64(),
            "specular fit {f} vs diffuse only {d}"
        );
        assert_eq!(wins["flip"], 1, "{summary}");
    } else {
        assert!(full["images"][0]["flip"].is_null());
    }
    assert_eq!(summary["pairwise"]["sets"], 1, "{summary}");
    assert_eq!(wins["rmse_srgb"], 1, "{summary}");
    assert!(
        f["rmse_srgb"].as_f64() < d["rmse_srgb"].as_f64(),
        "specular fit {f} vs diffuse only {d}"
    );
    assert!(
        f["ssim_srgb"].as_f64() > d["ssim_srgb"].as_f64(),
        "specular fit {f} vs diffuse only {d}"
    );
    let report = std::fs::read_to_string(out.join("report.html")).unwrap();
    assert!(report.contains("Held-out photographs") && report.contains("07.png"));
    assert_eq!(report.contains("FLIP 0."), has_flip);
    // The strips show in a real browser, with every other image of the report.
    let url = format!("file://{}", out.join("report.html").display());
    if let Some(dom) = crate::util::chromium_dom(&url, 5000, crate::util::images_loaded) {
        use crate::util::body_attribute;
        assert_eq!(body_attribute(&dom, "data-error"), None, "script error");
        let n = body_attribute(&dom, "data-images-expected").unwrap();
        assert_eq!(
            body_attribute(&dom, "data-images-loaded"),
            Some(format!("{n}/{n}"))
        );
        assert!(dom.contains("<section id=\"eval\""));
    }

    // `run --capture` takes the imported capture through fit, export and report.
    let run = temp_dir().join("run");
    let o = svbrdf(&[
        "run",
        "--capture",
        cap.to_str().unwrap(),
        "--px-per-cm",
        "15",
        "--out",
        run.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(run.join("export/gltf/material.gltf").is_file());
    assert!(run.join("report.html").is_file());
}

/// A simulated set in the same layout (`synth --materialgan`): the photos import with
/// the axes and extent the writer used (a flipped axis would put every predicted
/// highlight in the wrong place), and on glossy tiles the full fit predicts the
/// held-out photos far better than the diffuse-only baseline.
#[test]
fn simulated_materialgan_set_imports_and_the_full_fit_beats_diffuse_only() {
    let set = temp_dir().join("mg-set");
    let o = svbrdf(&[
        "synth",
        "--material",
        "tiles",
        "--seed",
        "2",
        "--materialgan",
        "7",
        "--materialgan-px",
        "128",
        "--out",
        set.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    for f in ["00.png", "06.png", "ground_truth/maps/diffuse.exr"] {
        assert!(set.join(f).is_file(), "{f}");
    }
    let cams = std::fs::read_to_string(set.join("camera_pos.txt")).unwrap();
    assert_eq!(cams.lines().count(), 7);
    let truth = json(set.join("ground_truth/materialgan.json"));
    assert_eq!(truth["format"], "svbrdf-synth-materialgan");
    let cap = import_as(&set, "mg-cap");
    let out = temp_dir().join("mg-eval");
    let o = svbrdf(&[
        "eval",
        "--capture",
        cap.to_str().unwrap(),
        "--holdout",
        "5,6",
        "--baseline",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let (f, d) = (
        json(out.join("eval/eval.json"))["mean"].clone(),
        json(out.join("diffuse-only/eval/eval.json"))["mean"].clone(),
    );
    let get = |v: &serde_json::Value, k: &str| v[k].as_f64().unwrap_or(f64::NAN);
    assert!(
        get(&f, "rmse_srgb") < 0.5 * get(&d, "rmse_srgb"),
        "full {f} vs diffuse only {d}"
    );
    assert!(
        get(&f, "ssim_srgb") > get(&d, "ssim_srgb"),
        "full {f} vs {d}"
    );
    assert!(get(&f, "relative_rmse_linear") < 0.6, "full {f}");
}

#[test]
fn eval_and_import_name_bad_input() {
    let Some(data) = cards_blue() else { return };
    let cap = import(&data);
    let o = svbrdf(&[
        "eval",
        "--capture",
        cap.to_str().unwrap(),
        "--holdout",
        "3,12",
        "--out",
        temp_dir().join("e").to_str().unwrap(),
    ]);
    assert!(!o.status.success());
    let e = stderr(&o);
    assert!(
        e.contains("held-out frame 12") && e.contains("0, 1, 2, 3, 4, 5, 6, 7, 8"),
        "{e}"
    );
    assert_eq!(e.trim().lines().count(), 1, "{e}");
    let o = svbrdf(&[
        "import",
        "--materialgan",
        temp_dir().to_str().unwrap(),
        "--out",
        temp_dir().join("x").to_str().unwrap(),
    ]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("no numbered images"), "{}", stderr(&o));
}
