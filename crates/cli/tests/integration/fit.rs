//! The appearance stage on the tiny preset: outputs complete and self-describing, and
//! accuracy against the simulator's truth within loose bounds (the paper-preset figures
//! live in the benchmark, see docs/BENCHMARKS.md).

use std::path::Path;

use crate::util::{json_lines, maps_accuracy, stderr, svbrdf, temp_dir, tiny_capture};

fn png_text(path: &Path) -> Vec<(String, String)> {
    let dec = png::Decoder::new(std::io::BufReader::new(std::fs::File::open(path).unwrap()));
    let reader = dec.read_info().unwrap();
    reader
        .info()
        .uncompressed_latin1_text
        .iter()
        .map(|t| (t.keyword.clone(), t.text.clone()))
        .collect()
}

#[test]
fn fit_writes_complete_self_describing_maps() {
    let cap = tiny_capture().join("registered");
    let out = temp_dir().join("fit");
    let o = svbrdf(&[
        "fit",
        "--capture",
        cap.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let text = String::from_utf8_lossy(&o.stdout);
    assert!(text.contains("re-rendering error"), "{text}");
    let m: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("fit.json")).unwrap()).unwrap();
    assert_eq!(m["format"], "svbrdf-fit");
    assert_eq!(m["model"], "ward");
    // The settings were chosen on held-out frames: every candidate scored, the
    // Lambertian one far worse on this glossy material, and the choice printed.
    let sel = &m["summary"]["selection"];
    let cands = sel["candidates"].as_array().unwrap();
    assert_eq!(cands.len(), 7, "{sel}");
    let err = |name: &str| {
        cands.iter().find(|c| c["name"] == name).unwrap()["held_out_srgb_rmse"]
            .as_f64()
            .unwrap()
    };
    for c in cands {
        let (h, t) = (
            c["held_out_srgb_rmse"].as_f64().unwrap(),
            c["training_srgb_rmse"].as_f64().unwrap(),
        );
        assert!(h.is_finite() && t.is_finite() && h > 0.0, "{c}");
    }
    assert!(err("diffuse-only") > 1.5 * err("default"), "{sel}");
    assert_ne!(sel["chosen"], "diffuse-only", "{sel}");
    // Far worse after the first fold, the Lambertian setting is not fitted on the
    // others: one fold's figures, and the record and the printout say so.
    let lambertian = cands.iter().find(|c| c["name"] == "diffuse-only").unwrap();
    assert_eq!(lambertian["dropped_after"], 1, "{sel}");
    assert_eq!(
        lambertian["held_out_srgb_rmse_per_fold"]
            .as_array()
            .unwrap()
            .len(),
        1,
        "{sel}"
    );
    let default = cands.iter().find(|c| c["name"] == "default").unwrap();
    assert!(default.get("dropped_after").is_none(), "{sel}");
    assert_eq!(
        default["held_out_srgb_rmse_per_fold"]
            .as_array()
            .unwrap()
            .len(),
        3,
        "{sel}"
    );
    assert!(text.contains("(left out after fold 1)"), "{text}");
    assert_eq!(sel["held_out_frames"].as_array().unwrap().len(), 3);
    assert!(text.contains("settings: "), "{text}");
    let files = m["maps"].as_array().unwrap();
    for name in [
        "diffuse",
        "specular",
        "roughness",
        "normal",
        "average",
        "residual",
        "coverage",
        "confidence",
        "clusters",
    ] {
        for ext in ["exr", "png"] {
            let f = format!("maps/{name}.{ext}");
            assert!(out.join(&f).is_file(), "{f} missing");
            assert!(files.iter().any(|e| e["file"] == f), "{f} not in fit.json");
        }
    }
    assert!(out.join("rerender.png").is_file());
    // Colour maps are sRGB in PNG, data maps linear; the files say so themselves.
    let enc = |f: &str| {
        png_text(&out.join("maps").join(f))
            .into_iter()
            .find(|(k, _)| k == "svbrdf:encoding")
            .map(|(_, v)| v)
    };
    assert_eq!(enc("diffuse.png").as_deref(), Some("srgb"));
    assert_eq!(enc("normal.png").as_deref(), Some("linear"));
    assert_eq!(enc("roughness.png").as_deref(), Some("linear"));
    // Every map value is finite and within its physical range.
    let s = &m["summary"];
    assert!(s["final_clusters"].as_u64().unwrap() >= s["initial_clusters"].as_u64().unwrap());
    let k = s["initial_clusters"].as_u64().unwrap();
    assert!((2..=20).contains(&k), "k = {k}");
    for (name, lo, hi) in [
        ("diffuse", 0.0, 1.0),
        ("specular", 0.0, 1.0),
        ("roughness", 0.0, 1.0),
        ("normal", -1.0, 1.0),
    ] {
        let img = image::open(out.join("maps").join(format!("{name}.exr")))
            .unwrap()
            .to_rgb32f();
        assert!(
            img.iter().all(|v| v.is_finite() && *v >= lo && *v <= hi),
            "{name} has values outside [{lo}, {hi}] or NaN"
        );
    }
    // Re-running into the same folder needs --overwrite.
    let o = svbrdf(&[
        "fit",
        "--capture",
        cap.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("--overwrite"), "{}", stderr(&o));
}

#[test]
fn fit_accuracy_on_tiny_within_loose_bounds_and_refinement_helps() {
    let synth = tiny_capture();
    let o = svbrdf(&[
        "bench",
        "--no-brdf",
        "--fit-capture",
        synth.join("registered").to_str().unwrap(),
        "--truth",
        synth.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let lines = json_lines(&o);
    assert_eq!(lines.len(), 2);
    let acc = |i: usize, k: &str| lines[i]["accuracy"][k].as_f64().unwrap();
    assert_eq!(lines[0]["refine"], false);
    assert_eq!(lines[1]["refine"], true);
    for i in 0..2 {
        eprintln!("{}", lines[i]);
        // Intensity withheld: the global scale absorbs it and should be near 1 here
        // because the normalisation targets the material's bright end.
        assert!(acc(i, "albedo_scale") > 0.2 && acc(i, "albedo_scale") < 5.0);
        assert!(acc(i, "diffuse_rmse") < 0.10, "{}", lines[i]);
        assert!(acc(i, "normal_mean_deg") < 6.0, "{}", lines[i]);
        assert!(acc(i, "relight_relative_rmse_mean") < 1.5, "{}", lines[i]);
    }
    assert!(
        acc(1, "diffuse_rmse") < acc(0, "diffuse_rmse"),
        "refinement did not lower the diffuse error"
    );
    assert!(
        lines[1]["rerender_rmse"].as_f64().unwrap() < lines[0]["rerender_rmse"].as_f64().unwrap()
    );
}

#[test]
fn truth_blur_scores_perfect_maps_and_grows_with_the_blur() {
    let synth = tiny_capture();
    let o = svbrdf(&[
        "bench",
        "--no-brdf",
        "--truth",
        synth.to_str().unwrap(),
        "--truth-blur",
        "0,0.5,1",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let lines = json_lines(&o);
    assert_eq!(lines.len(), 3);
    let acc = |i: usize, k: &str| lines[i]["accuracy"][k].as_f64().unwrap();
    assert_eq!(lines[0]["bench"], "resolution_floor");
    // Unblurred true maps reproduce the held-out images (same renderer, same grid).
    assert!(acc(0, "diffuse_rmse") < 1e-6, "{}", lines[0]);
    assert!(acc(0, "relight_relative_rmse_mean") < 1e-4, "{}", lines[0]);
    assert!((acc(0, "albedo_scale") - 1.0).abs() < 1e-6, "{}", lines[0]);
    for k in ["diffuse_rmse", "relight_relative_rmse_mean"] {
        assert!(
            acc(1, k) > acc(0, k) && acc(2, k) > acc(1, k),
            "{k}: {lines:?}"
        );
    }
    let o = svbrdf(&[
        "bench",
        "--no-brdf",
        "--truth",
        synth.to_str().unwrap(),
        "--truth-blur",
        "12",
    ]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("--truth-blur 12"), "{}", stderr(&o));
}

fn assert_fit_rejected(capture: &Path, needles: &[&str]) {
    let root = temp_dir();
    let out = root.join("out");
    let o = svbrdf(&[
        "fit",
        "--capture",
        capture.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(!o.status.success());
    let err = stderr(&o);
    assert_eq!(err.trim().lines().count(), 1, "expected one line:\n{err}");
    assert!(!err.contains("panicked"), "{err}");
    for n in needles {
        assert!(err.contains(n), "{n:?} not in {err:?}");
    }
    assert!(!out.exists(), "output left behind");
}

#[test]
fn fit_rejects_bad_captures_with_one_line() {
    let root = temp_dir();
    assert_fit_rejected(&root.join("nope"), &["nope"]);
    let src = std::fs::read_to_string(tiny_capture().join("registered/capture.json")).unwrap();
    let mut v: serde_json::Value = serde_json::from_str(&src).unwrap();
    // Another format version.
    let d = root.join("v2");
    std::fs::create_dir_all(&d).unwrap();
    let mut w = v.clone();
    w["version"] = 2.into();
    std::fs::write(d.join("capture.json"), w.to_string()).unwrap();
    assert_fit_rejected(&d, &["version 2"]);
    // A video that is not there.
    let d = root.join("novideo");
    std::fs::create_dir_all(&d).unwrap();
    let mut w = v.clone();
    w["sources"][0]["path"] = "missing.mp4".into();
    std::fs::write(d.join("capture.json"), w.to_string()).unwrap();
    assert_fit_rejected(&d, &["missing.mp4"]);
    // A pose under the plane.
    let d = root.join("under");
    std::fs::create_dir_all(&d).unwrap();
    v["frames"][0]["light_position"][2] = (-3.0).into();
    std::fs::write(d.join("capture.json"), v.to_string()).unwrap();
    assert_fit_rejected(&d, &["light z -3"]);
    // Unknown model.
    let o = svbrdf(&[
        "fit",
        "--capture",
        tiny_capture().join("registered").to_str().unwrap(),
        "--out",
        root.join("m").to_str().unwrap(),
        "--model",
        "phong",
    ]);
    assert!(!o.status.success());
    assert!(
        stderr(&o).contains("\"phong\" (expected ward or ggx)"),
        "{}",
        stderr(&o)
    );
}

#[test]
fn fit_with_ggx_writes_ggx_maps() {
    let cap = tiny_capture().join("registered");
    let out = temp_dir().join("ggx");
    let o = svbrdf(&[
        "fit",
        "--capture",
        cap.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--model",
        "ggx",
        "--no-refine",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let m: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("fit.json")).unwrap()).unwrap();
    assert_eq!(m["model"], "ggx");
    assert_eq!(m["summary"]["refined"], false);
    // The GGX fit explains the (Ward-rendered) video about as well as Ward does.
    let rmse = m["summary"]["rmse_final"].as_f64().unwrap();
    assert!(rmse.is_finite() && rmse < 0.1, "rmse {rmse}");
}

/// Issue 19: a sweep that never passes over the region's edges sees their highlight
/// only obliquely; the confidence map says their gloss is a guess there and measured
/// under the sweep, and the fit warns.
#[test]
fn a_sweep_that_never_passes_over_the_edges_leaves_their_gloss_unmeasured() {
    let dir = temp_dir();
    let cap = dir.join("narrow");
    let o = svbrdf(&[
        "synth",
        "--preset",
        "tiny",
        "--material",
        "tiles",
        // 0.2: at 0.25, on session 31's freshly set-up machine, only 22% of the surface
        // went unseen (under the fit's 25% warning; session 30's machine: over it).
        "--reach",
        "0.2",
        "--out",
        cap.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let out = dir.join("fit");
    let o = svbrdf(&[
        "fit",
        "--capture",
        cap.join("registered").to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(
        stderr(&o).contains("the highlight was never seen on"),
        "{}",
        stderr(&o)
    );
    let m: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("fit.json")).unwrap()).unwrap();
    let unseen = m["summary"]["confidence"]["specular_unseen"]
        .as_f64()
        .unwrap();
    assert!(unseen > 0.25, "{}", m["summary"]["confidence"]);
    // Per cluster: the shares of its pixels by specular confidence add up to 1.
    let clusters: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("clusters.json")).unwrap()).unwrap();
    let clusters = clusters.as_array().unwrap();
    let without_peak = clusters
        .iter()
        .filter(|c| c["specular_seen"][0].as_f64() == Some(0.0))
        .count();
    for c in clusters {
        let s: f64 = (0..3)
            .map(|k| c["specular_seen"][k].as_f64().unwrap())
            .sum();
        assert!((s - 1.0).abs() < 1e-9, "{c}");
    }
    assert_eq!(m["summary"]["clusters_without_peak"], without_peak);
    let img = svbrdf_core::maps::read_image_linear(
        &out.join("maps/confidence.exr"),
        svbrdf_core::maps::Encoding::Linear,
    )
    .unwrap();
    let (w, h) = (img.width, img.height);
    // Share of pixels whose highlight was never seen (specular confidence 0), in the
    // centre (under the sweep) and along the edges.
    let (mut centre, mut edge) = ((0, 0), (0, 0));
    for y in 0..h {
        for x in 0..w {
            let unseen = usize::from(img.data[(y * w + x) * img.channels + 1] <= 0.0);
            let (u, v) = (x as f64 / w as f64 - 0.5, y as f64 / h as f64 - 0.5);
            let r = u.abs().max(v.abs());
            if r < 0.15 {
                centre = (centre.0 + unseen, centre.1 + 1);
            } else if r > 0.4 {
                edge = (edge.0 + unseen, edge.1 + 1);
            }
        }
    }
    let share = |c: (usize, usize)| c.0 as f64 / c.1.max(1) as f64;
    let (centre, edge) = (share(centre), share(edge));
    // Session 29's reassignment threshold moved pixels between lobes and left the
    // edges at 0.50 (not above it; centre 0.05): the bound on the edges is 0.45, the contrast
    // with the centre (over 3x) is what the test is about. With the sweep at 0.2
    // (session 31): edges 0.56, centre 0.09, whole surface 0.36.
    assert!(
        centre < 0.25 && edge > 0.45 && edge > 3.0 * centre,
        "highlight never seen: centre {centre:.2}, edges {edge:.2}"
    );
}

/// Tiles, scene seed 1: with each split part fitted only from its parent, two of three
/// clustering seeds left a glossy motif in a poor local minimum (diffuse RMSE 0.086 and
/// 0.083 against 0.050: its highlight absorbed into a near-white diffuse albedo). With
/// restarts at the shallow splits (`split_restart_depth`) every seed stays below 0.055
/// (measured 0.042-0.049); turned off,
/// seed 1 is worse again (if it no longer is, the restarts have stopped earning their
/// cost and the default should be measured again).
#[test]
fn the_diffuse_error_on_tiles_does_not_hang_on_the_clustering_seed() {
    let dir = temp_dir();
    let cap = dir.join("tiles");
    let o = svbrdf(&[
        "synth",
        "--preset",
        "tiny",
        "--material",
        "tiles",
        "--seed",
        "1",
        "--out",
        cap.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let fit = |seed: &str, config: Option<&str>| {
        let out = dir.join(format!("fit-{seed}-{}", config.map_or(0, str::len)));
        let mut args = vec![
            "fit".to_string(),
            "--capture".into(),
            cap.join("registered").to_string_lossy().into_owned(),
            "--out".into(),
            out.to_string_lossy().into_owned(),
            "--seed".into(),
            seed.into(),
        ];
        if let Some(c) = config {
            let f = dir.join("config.json");
            std::fs::write(&f, c).unwrap();
            args.extend(["--config".into(), f.to_string_lossy().into_owned()]);
        }
        let args: Vec<&str> = args.iter().map(String::as_str).collect();
        let o = svbrdf(&args);
        assert!(o.status.success(), "{}", stderr(&o));
        maps_accuracy(&out, &cap)["diffuse_rmse"].as_f64().unwrap()
    };
    let errors: Vec<f64> = ["1", "3"].iter().map(|s| fit(s, None)).collect();
    assert!(
        errors.iter().all(|e| *e < 0.055),
        "diffuse RMSE per seed {errors:?}"
    );
    // The restarts alone, pixel reassignment off in both fits: since session 29 the
    // reassignment also moves most of the pixels a fit from the parent alone leaves in
    // the wrong part (from the parent only 0.0310, with restarts 0.0320, both with it).
    let no_moves = r#"{"reassign_pixels": false}"#;
    let restarts = fit("1", Some(no_moves));
    let paper = fit(
        "1",
        Some(r#"{"split_restart_depth": 0, "reassign_pixels": false}"#),
    );
    assert!(
        paper > 1.2 * restarts,
        "from the parent only: {paper}, with restarts {restarts}"
    );
}

/// Brushed metal laid at 45 degrees to the markers: the held-out validation turns the
/// lobes (`turned-grain`), the fit says so, the roughness map's third channel holds the
/// turn, and the maps are closer to the truth than with the lobes held along the
/// plane's axes (on `tiny` at 30-60 degrees: diffuse RMSE 0.025-0.041 -> 0.009-0.035,
/// normals 3.9-5.9 -> 1.0-1.6 degrees; docs/BENCHMARKS.md, session 23).
#[test]
fn grooves_laid_askew_are_fitted_turned() {
    let dir = temp_dir();
    let cap = dir.join("askew");
    let o = svbrdf(&[
        "synth",
        "--material",
        "brushed-metal",
        "--grain-angle",
        "45",
        "--out",
        cap.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let fit = |out: &Path, extra: &[&str]| {
        let reg = cap.join("registered");
        let mut args = vec![
            "fit",
            "--capture",
            reg.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
        ];
        args.extend_from_slice(extra);
        let o = svbrdf(&args);
        assert!(o.status.success(), "{}", stderr(&o));
        String::from_utf8_lossy(&o.stdout).to_string()
    };
    let turned = dir.join("turned");
    let text = fit(&turned, &[]);
    assert!(
        text.contains("anisotropy turned from the markers' axes"),
        "{text}"
    );
    let m: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(turned.join("fit.json")).unwrap()).unwrap();
    let s = &m["summary"];
    assert_eq!(
        s["selection"]["chosen"], "turned-grain",
        "{}",
        s["selection"]
    );
    let g = &s["turned_grain"];
    assert!(g["share"].as_f64().unwrap() > 0.5, "{g}");
    assert!(
        (g["median_deg"].as_f64().unwrap() - 45.0).abs() < 5.0,
        "{g}"
    );
    let axes = dir.join("axes");
    let config = dir.join("axes.json");
    std::fs::write(&config, r#"{"turned_grain": false}"#).unwrap();
    fit(&axes, &["--config", config.to_str().unwrap()]);
    let (a, t) = (maps_accuracy(&axes, &cap), maps_accuracy(&turned, &cap));
    let get = |v: &serde_json::Value, k: &str| v[k].as_f64().unwrap();
    assert!(
        get(&t, "normal_mean_deg") < 0.5 * get(&a, "normal_mean_deg"),
        "{t} {a}"
    );
    assert!(get(&t, "diffuse_rmse") < get(&a, "diffuse_rmse"), "{t} {a}");
}
