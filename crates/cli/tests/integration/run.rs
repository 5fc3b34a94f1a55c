//! The whole product: `svbrdf run` with stage reuse, and the exports checked by the
//! tools users open them with (Khronos glTF validator, Mitsuba 3).
use std::process::Command;

use crate::util::{
    repo_root, skip_without, stderr, svbrdf, temp_dir, tiny_capture, tiny_run, Server,
};

fn stdout(o: &std::process::Output) -> String {
    String::from_utf8_lossy(&o.stdout).into_owned()
}

#[test]
fn run_writes_everything_and_reuses_finished_stages() {
    let out = tiny_run();
    for f in [
        "run.json",
        "aligned/capture.json",
        "maps/fit.json",
        "maps/maps/diffuse.exr",
        "export/gltf/material.gltf",
        "export/gltf/base_color.png",
        "export/mitsuba/scene.xml",
        "export/mitsuba/render.py",
    ] {
        assert!(out.join(f).exists(), "{f} missing");
    }
    // A copy of the finished run: rerunning reuses every stage.
    let copy = temp_dir().join("copy");
    let status = Command::new("cp")
        .args(["-r", out.to_str().unwrap(), copy.to_str().unwrap()])
        .status()
        .unwrap();
    assert!(status.success());
    let run = |extra: &[&str]| crate::util::run_tiny(&copy, extra);
    let o = run(&[]);
    assert!(o.status.success(), "{}", stderr(&o));
    let s = stdout(&o);
    for stage in ["align", "fit", "export"] {
        assert!(
            s.contains(&format!("== {stage}: reusing")),
            "{stage} not reused:\n{s}"
        );
    }
    // A changed fit setting reruns the fit and what follows, not the alignment.
    let o = run(&["--model", "ggx"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let s = stdout(&o);
    assert!(s.contains("== align: reusing"), "{s}");
    assert!(s.contains("== fit\n") && s.contains("== export\n"), "{s}");
    let fit: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(copy.join("maps/fit.json")).unwrap())
            .unwrap();
    assert_eq!(fit["model"], "ggx");
    // A half-finished stage (its record says done but its folder is gone) is redone.
    std::fs::remove_dir_all(copy.join("export")).unwrap();
    let o = run(&["--model", "ggx"]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(stdout(&o).contains("== export\n"));
    assert!(copy.join("export/gltf/material.gltf").exists());
}

#[test]
fn run_refuses_a_folder_holding_another_capture() {
    let other = temp_dir().join("other");
    std::fs::create_dir_all(&other).unwrap();
    std::fs::write(other.join("notes.txt"), "mine").unwrap();
    let cap = tiny_capture();
    let o = svbrdf(&[
        "run",
        "--video",
        cap.join("flash.mp4").to_str().unwrap(),
        "--reference",
        cap.join("reference.jpg").to_str().unwrap(),
        "--out",
        other.to_str().unwrap(),
    ]);
    assert!(!o.status.success());
    let e = stderr(&o);
    assert_eq!(e.lines().count(), 1, "{e}");
    assert!(
        e.contains("--overwrite") && e.contains(other.to_str().unwrap()),
        "{e}"
    );
    assert_eq!(
        std::fs::read_to_string(other.join("notes.txt")).unwrap(),
        "mine"
    );

    let o = svbrdf(&[
        "run",
        "--video",
        "/nonexistent/flash.mp4",
        "--reference",
        cap.join("reference.jpg").to_str().unwrap(),
        "--out",
        temp_dir().join("x").to_str().unwrap(),
    ]);
    assert!(!o.status.success());
    assert!(
        stderr(&o).contains("/nonexistent/flash.mp4"),
        "{}",
        stderr(&o)
    );
}

#[test]
fn gltf_export_passes_the_khronos_validator() {
    let root = repo_root();
    let validator = root.join("tools/node_modules/gltf-validator");
    let node = Command::new("node").arg("--version").output().is_ok();
    if skip_without(
        "node + gltf-validator",
        node && validator.exists(),
        "run scripts/test-tools.sh",
    ) {
        return;
    }
    let validate = |gltf: &std::path::Path| -> serde_json::Value {
        let o = Command::new("node")
            .arg(root.join("scripts/validate-gltf.mjs"))
            .arg(gltf)
            .output()
            .unwrap();
        let report: serde_json::Value = serde_json::from_slice(&o.stdout)
            .unwrap_or_else(|e| panic!("validator output: {e}: {}", stderr(&o)));
        let issues = &report["issues"];
        assert_eq!(issues["numErrors"], 0, "{issues:#}");
        assert_eq!(issues["numWarnings"], 0, "{issues:#}");
        assert!(o.status.success());
        report
    };
    // With the parts no frame saw cut out (alpha mask), as valid.
    let masked = temp_dir().join("masked");
    let o = svbrdf(&[
        "export",
        "--maps",
        tiny_run().join("maps").to_str().unwrap(),
        "--out",
        masked.to_str().unwrap(),
        "--mask-unobserved",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let doc: serde_json::Value =
        serde_json::from_slice(&std::fs::read(masked.join("gltf/material.gltf")).unwrap()).unwrap();
    assert_eq!(doc["materials"][0]["alphaMode"], "MASK");
    assert!(doc["asset"]["extras"]["svbrdf"]["coverage"]["measured_share"].is_f64());
    assert!(masked.join("gltf/coverage.png").exists());
    validate(&masked.join("gltf/material.gltf"));
    let report = validate(&tiny_run().join("export/gltf/material.gltf"));
    let used = report["info"]["extensionsUsed"].to_string();
    assert!(used.contains("KHR_materials_specular") && used.contains("KHR_materials_anisotropy"));
    // The validator reads the PNGs' own colour chunks: colours sRGB, data linear.
    for r in report["info"]["resources"].as_array().unwrap() {
        let uri = r["uri"].as_str().unwrap_or("");
        let want = if uri.contains("color") {
            "srgb"
        } else {
            "linear"
        };
        if uri.ends_with(".png") {
            assert_eq!(r["image"]["transfer"], want, "{uri}");
        }
    }
}

#[test]
fn mitsuba_scene_renders_with_the_stock_package() {
    let python = std::env::var_os("SVBRDF_PYTHON")
        .map(std::path::PathBuf::from)
        .unwrap_or_else(|| repo_root().join(".venv-tools/bin/python"));
    let has = python.exists()
        && Command::new(&python)
            .args(["-c", "import mitsuba"])
            .status()
            .is_ok_and(|s| s.success());
    if skip_without(
        "the mitsuba Python package",
        has,
        "run scripts/test-tools.sh",
    ) {
        return;
    }
    let scene_dir = tiny_run().join("export/mitsuba");
    let img = temp_dir().join("mitsuba.exr");
    let o = Command::new(&python)
        .arg(scene_dir.join("render.py"))
        .args(["--spp", "4", "--width", "120", "--out"])
        .arg(&img)
        .output()
        .unwrap();
    assert!(o.status.success(), "mitsuba: {}", stderr(&o));
    let png = image::open(img.with_extension("png")).unwrap().to_rgb8();
    assert_eq!(png.width(), 120);
    // The material (reddish leather-like texture on a grey background) is visible: the
    // render is neither black nor one flat colour.
    let px: Vec<[u8; 3]> = png.pixels().map(|p| p.0).collect();
    let mean = px.iter().map(|p| f64::from(p[0])).sum::<f64>() / px.len() as f64;
    let distinct: std::collections::BTreeSet<[u8; 3]> = px.iter().copied().collect();
    assert!(
        mean > 10.0 && distinct.len() > 50,
        "mean {mean}, {} colours",
        distinct.len()
    );
}

#[test]
fn report_loads_in_chromium_with_every_image() {
    let report = tiny_run().join("report.html");
    let html = std::fs::read_to_string(&report).unwrap();
    // Self-contained: no external scripts, styles or images.
    assert!(!html.contains("src=\"http") && !html.contains("href=\"http"));
    // How the fit's settings were chosen, with every candidate's held-out error.
    assert!(
        html.contains("<section id=\"selection\""),
        "no selection section"
    );
    for name in [
        "diffuse-only",
        "fewer-clusters",
        "cluster-maps",
        "strong-prior",
        "cluster-lobes",
        "default",
    ] {
        assert!(html.contains(&format!("<th>{name}</th>")), "{name} missing");
    }
    let Some(dom) = crate::util::chromium_dom(
        &format!("file://{}", report.display()),
        5000,
        crate::util::images_loaded,
    ) else {
        return;
    };
    use crate::util::body_attribute;
    assert_eq!(body_attribute(&dom, "data-error"), None, "script error");
    let expected = body_attribute(&dom, "data-images-expected").unwrap();
    let n: usize = expected.parse().unwrap();
    // Renders (4), maps (9), geometry (3), re-rendering strip (1).
    assert!(n >= 17, "{n} images");
    assert_eq!(
        body_attribute(&dom, "data-images-loaded").as_deref(),
        Some(format!("{n}/{n}").as_str()),
        "not every image decoded"
    );
    for section in [
        "summary", "renders", "maps", "geometry", "rerender", "files",
    ] {
        assert!(
            dom.contains(&format!("<section id=\"{section}\"")),
            "{section}"
        );
    }
}

#[test]
fn viewer_serves_the_gltf_and_the_light_follows_the_pointer() {
    use std::io::BufRead;
    let run = tiny_run();
    // A busy port: the viewer must pick another one and say so.
    let busy = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let busy_port = busy.local_addr().unwrap().port();
    let child = Command::new(env!("CARGO_BIN_EXE_svbrdf"))
        .args([
            "view",
            run.to_str().unwrap(),
            "--port",
            &busy_port.to_string(),
        ])
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let mut server = Server(child);
    // Keep reading the server's stdout for as long as it runs: a closed pipe would end
    // the server at its next message (broken pipe), resetting the connections.
    let mut out = std::io::BufReader::new(server.0.stdout.take().unwrap());
    let mut first = String::new();
    out.read_line(&mut first).unwrap();
    std::thread::spawn(move || std::io::copy(&mut out, &mut std::io::sink()));
    let url = first
        .split_whitespace()
        .find(|w| w.starts_with("http://127.0.0.1:"))
        .unwrap_or_else(|| panic!("no URL in {first:?}"))
        .to_string();
    assert!(
        !url.contains(&format!(":{busy_port}/")),
        "{url} uses the busy port"
    );
    // Only files of the export folder are served.
    let port: u16 = url
        .trim_end_matches('/')
        .rsplit(':')
        .next()
        .unwrap()
        .parse()
        .unwrap();
    let get = |path: &str| {
        use std::io::{Read, Write};
        let mut s = std::net::TcpStream::connect(("127.0.0.1", port)).unwrap();
        s.set_read_timeout(Some(std::time::Duration::from_secs(30)))
            .unwrap();
        s.write_all(format!("GET {path} HTTP/1.1\r\nHost: x\r\n\r\n").as_bytes())
            .unwrap();
        let mut r = Vec::new();
        s.read_to_end(&mut r)
            .unwrap_or_else(|e| panic!("GET {path}: {e}"));
        String::from_utf8_lossy(&r)
            .lines()
            .next()
            .unwrap_or("")
            .to_string()
    };
    for (path, status) in [
        ("/gltf/material.gltf", "200"),
        ("/gltf/../run.json", "404"),
        ("/three/three.module.min.js", "200"),
    ] {
        let line = get(path);
        assert!(line.contains(status), "GET {path}: {line:?}");
    }

    let Some(dom) = crate::util::chromium_dom(&format!("{url}?selftest=1"), 15000, |dom| {
        // Loaded and self-tested, or failed for good.
        crate::util::body_attribute(dom, "data-pixel-change").is_some()
            || crate::util::body_attribute(dom, "data-error").is_some()
    }) else {
        return;
    };
    use crate::util::body_attribute;
    assert_eq!(body_attribute(&dom, "data-error"), None, "page error");
    assert_eq!(
        body_attribute(&dom, "data-loaded").as_deref(),
        Some("1"),
        "{dom}"
    );
    assert_eq!(
        body_attribute(&dom, "data-material").as_deref(),
        Some("MeshPhysicalMaterial")
    );
    let maps = body_attribute(&dom, "data-maps").unwrap();
    for m in ["base", "normal", "roughness", "specularColor", "anisotropy"] {
        assert!(
            maps.contains(m),
            "three.js did not load the {m} map: {maps}"
        );
    }
    let mean: f64 = body_attribute(&dom, "data-mean-before")
        .unwrap()
        .parse()
        .unwrap();
    assert!(mean > 5.0, "the page rendered black ({mean})");
    let change: f64 = body_attribute(&dom, "data-pixel-change")
        .unwrap()
        .parse()
        .unwrap();
    assert!(
        change > 0.5,
        "moving the light changed the image by only {change}"
    );
}

#[test]
fn marker_sheet_is_detected_by_opencv_at_its_physical_size() {
    let out = temp_dir().join("markers");
    let o = svbrdf(&["markers", "--out", out.to_str().unwrap(), "--size-cm", "2"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let svg = std::fs::read_to_string(out.join("markers.svg")).unwrap();
    assert!(svg.contains("DICT_6X6_250, 2.0 cm") && svg.contains("50 mm"));
    let img = image::open(out.join("markers.png")).unwrap().to_rgb8();
    assert_eq!((img.width(), img.height()), (2480, 3508), "A4 at 300 dpi");
    let ours = svbrdf_core::image::ImageU8::from_vec(
        img.width() as usize,
        img.height() as usize,
        3,
        img.into_raw(),
    )
    .unwrap();
    let dict = svbrdf_cv::aruco::Dictionary::from_name("DICT_6X6_250").unwrap();
    let mut found = svbrdf_cv::aruco::detect_markers(&ours, dict).unwrap();
    found.sort_by_key(|m| m.id);
    assert_eq!(
        found.iter().map(|m| m.id).collect::<Vec<_>>(),
        vec![0, 1, 2, 3]
    );
    for m in &found {
        // 2 cm at 300 dpi = 236.2 px per side.
        let c = m.corners;
        let side = ((c[1][0] - c[0][0]).powi(2) + (c[1][1] - c[0][1]).powi(2)).sqrt();
        assert!(
            (side - 2.0 / 2.54 * 300.0).abs() < 2.0,
            "id {}: side {side} px",
            m.id
        );
        // Upright: the marker's own top-left corner is its upper-left one on the page.
        assert!(
            c[0][1] < c[3][1] && c[0][0] < c[1][0],
            "id {} is rotated",
            m.id
        );
    }
    // Another dictionary, and a bad size.
    let o = svbrdf(&[
        "markers",
        "--out",
        temp_dir().join("april").to_str().unwrap(),
        "--dictionary",
        "DICT_APRILTAG_36h11",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let o = svbrdf(&[
        "markers",
        "--out",
        temp_dir().join("bad").to_str().unwrap(),
        "--size-cm",
        "30",
    ]);
    assert!(!o.status.success());
    assert!(
        stderr(&o).contains("30") && stderr(&o).lines().count() == 1,
        "{}",
        stderr(&o)
    );
}

#[test]
fn bench_preset_reports_every_stage_against_the_truth() {
    let dir = temp_dir().join("bench");
    std::fs::create_dir_all(&dir).unwrap();
    // Reuse the shared tiny capture instead of synthesizing another.
    std::os::unix::fs::symlink(tiny_capture(), dir.join("capture")).unwrap();
    let o = svbrdf(&[
        "bench",
        "--preset",
        "tiny",
        "--dir",
        dir.to_str().unwrap(),
        "--no-brdf",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let out = stdout(&o);
    assert_eq!(
        out.lines().count(),
        1,
        "stdout must hold the JSON line only:\n{out}"
    );
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    assert_eq!(v["bench"], "pipeline");
    assert!(v["synth_seconds"].is_null(), "the capture was not reused");
    for stage in ["align", "fit", "export"] {
        let s = &v["stages"][stage];
        assert!(s["seconds"].as_f64().unwrap() > 0.0, "{stage}");
        assert!(s["peak_memory_mb"].as_f64().unwrap() > 1.0, "{stage}");
    }
    let med = v["alignment"]["align_error_px_median"].as_f64().unwrap();
    assert!(med < 0.5, "alignment error {med}");
    let normal = v["maps"]["normal_mean_deg"].as_f64().unwrap();
    assert!(normal < 6.0, "normal error {normal}");
    assert!(v["maps"]["relight_relative_rmse_mean"]
        .as_f64()
        .unwrap()
        .is_finite());
    // The report of a synthetic run shows the ground truth.
    let html = std::fs::read_to_string(dir.join("run/report.html")).unwrap();
    assert!(html.contains("<section id=\"truth\""));
    assert!(dir.join("run/truth/accuracy.json").exists());
}
