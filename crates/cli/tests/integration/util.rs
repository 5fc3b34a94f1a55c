use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::sync::OnceLock;

/// Run `svbrdf` with arguments.
pub fn svbrdf(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_svbrdf"))
        .args(args)
        .output()
        .expect("failed to start svbrdf")
}

/// Arguments of `fit` and `run` that skip the choice of settings on held-out frames:
/// for tests whose subject is not the fitted material's settings (that choice is four
/// fifths of a tiny fit's time).
pub const NO_SELECTION: [&str; 2] = ["--select-folds", "0"];

/// A fresh temporary folder that lives until the test process ends.
pub fn temp_dir() -> PathBuf {
    let d = tempfile::tempdir().expect("temp dir");
    let p = d.path().to_path_buf();
    std::mem::forget(d);
    p
}

/// One `synth --preset tiny` capture shared by all tests of this binary.
pub fn tiny_capture() -> &'static Path {
    static DIR: OnceLock<PathBuf> = OnceLock::new();
    DIR.get_or_init(|| {
        let out = temp_dir().join("tiny");
        let o = svbrdf(&[
            "synth",
            "--preset",
            "tiny",
            "--seed",
            "3",
            "--out",
            out.to_str().unwrap(),
        ]);
        assert!(
            o.status.success(),
            "synth failed: {}",
            String::from_utf8_lossy(&o.stderr)
        );
        out
    })
}

/// Standard output as JSON lines (the benchmark's format).
pub fn json_lines(o: &Output) -> Vec<serde_json::Value> {
    String::from_utf8_lossy(&o.stdout)
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect()
}

pub fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

/// The repository root (tools/ and scripts/ live there).
pub fn repo_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

/// True when `.ci/run` asked for every optional tool to be present: a test that would
/// skip for a missing tool fails instead.
pub fn tools_required() -> bool {
    std::env::var_os("SVBRDF_REQUIRE_TOOLS").is_some_and(|v| v == "1")
}

/// Skip (return true) with a reason, or fail under `SVBRDF_REQUIRE_TOOLS=1`.
pub fn skip_without(tool: &str, present: bool, install: &str) -> bool {
    if present {
        return false;
    }
    assert!(
        !tools_required(),
        "{tool} is missing but SVBRDF_REQUIRE_TOOLS=1 ({install})"
    );
    eprintln!("SKIPPED: {tool} is not installed ({install})");
    true
}

/// `svbrdf run` of the shared tiny capture into `out`, with extra arguments.
pub fn run_tiny(out: &Path, extra: &[&str]) -> Output {
    let cap = tiny_capture();
    let (video, reference, camera) = (
        cap.join("flash.mp4"),
        cap.join("reference.jpg"),
        cap.join("camera.json"),
    );
    let mut args = vec![
        "run",
        "--video",
        video.to_str().unwrap(),
        "--reference",
        reference.to_str().unwrap(),
        "--camera",
        camera.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ];
    args.extend_from_slice(extra);
    svbrdf(&args)
}

/// One `svbrdf run` of the shared tiny capture.
pub fn tiny_run() -> &'static Path {
    static DIR: OnceLock<PathBuf> = OnceLock::new();
    DIR.get_or_init(|| {
        let out = temp_dir().join("run");
        let o = run_tiny(&out, &[]);
        assert!(o.status.success(), "run failed: {}", stderr(&o));
        out
    })
}

/// Headless Chromium's DOM after loading `url` (scripts run for up to `budget_ms` of
/// virtual time), or None when Chromium is not installed.
///
/// Virtual time does not wait for work off the main thread (three.js decodes textures
/// with `createImageBitmap`), so on a loaded machine the budget can run out before the
/// page is done although nothing is wrong with it. The page is loaded again, up to three
/// times with a doubled budget each time, until `ready` accepts its DOM; the last DOM is
/// returned either way, so a page that never gets ready still fails the caller's checks.
pub fn chromium_dom(url: &str, budget_ms: u32, ready: impl Fn(&str) -> bool) -> Option<String> {
    let has = Command::new("chromium")
        .arg("--version")
        .output()
        .is_ok_and(|o| o.status.success());
    if skip_without(
        "chromium",
        has,
        "apt-get install chromium, or run scripts/test-tools.sh",
    ) {
        return None;
    }
    let mut dom = String::new();
    for attempt in 0..3u32 {
        let profile = temp_dir().join("chromium-profile");
        let o = Command::new("timeout")
            .args([
                "120",
                "chromium",
                "--headless",
                "--no-sandbox",
                "--disable-gpu",
            ])
            .args([
                "--disable-background-networking",
                "--no-first-run",
                "--enable-unsafe-swiftshader",
            ])
            .arg(format!("--user-data-dir={}", profile.display()))
            .arg(format!("--virtual-time-budget={}", budget_ms << attempt))
            .arg("--dump-dom")
            .arg(url)
            .output()
            .expect("failed to start chromium");
        assert!(o.status.success(), "chromium failed: {}", stderr(&o));
        dom = String::from_utf8_lossy(&o.stdout).into_owned();
        if ready(&dom) {
            break;
        }
        eprintln!("chromium: {url} not ready after attempt {}", attempt + 1);
    }
    Some(dom)
}

/// The value of attribute `name` on the page's `<body>` tag.
pub fn body_attribute(dom: &str, name: &str) -> Option<String> {
    let start = dom.find("<body")?;
    let tag = &dom[start..start + dom[start..].find('>')?];
    let key = format!("{name}=\"");
    let i = tag.find(&key)? + key.len();
    Some(tag[i..i + tag[i..].find('"')?].to_string())
}

/// Whether a report page says it loaded every image it holds (or hit a script error,
/// which no retry mends).
pub fn images_loaded(dom: &str) -> bool {
    if body_attribute(dom, "data-error").is_some() {
        return true;
    }
    match (
        body_attribute(dom, "data-images-expected"),
        body_attribute(dom, "data-images-loaded"),
    ) {
        (Some(n), Some(loaded)) => loaded == format!("{n}/{n}"),
        _ => false,
    }
}

/// Kills the server when the test ends, pass or fail.
pub struct Server(pub std::process::Child);

impl Drop for Server {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// `svbrdf align` of a `svbrdf synth` folder's flash video, reference photo and camera
/// description into `out`, with `extra` flags.
pub fn align_synth(cap: &Path, out: &Path, extra: &[&str]) -> Output {
    let mut args = vec![
        "align",
        "--video",
        cap.join("flash.mp4").to_str().unwrap(),
        "--reference",
        cap.join("reference.jpg").to_str().unwrap(),
        "--camera",
        cap.join("camera.json").to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]
    .into_iter()
    .map(String::from)
    .collect::<Vec<_>>();
    args.extend(extra.iter().map(|s| s.to_string()));
    let refs: Vec<&str> = args.iter().map(String::as_str).collect();
    svbrdf(&refs)
}

/// A `hard-small` capture of `material` at `seed`, synthesised into a new folder.
pub fn hard_small(material: &str, seed: &str) -> PathBuf {
    let cap = temp_dir().join(format!("{material}{seed}"));
    let o = svbrdf(&[
        "synth",
        "--preset",
        "hard-small",
        "--material",
        material,
        "--seed",
        seed,
        "--out",
        cap.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    cap
}

/// A JSON file.
pub fn read_json(p: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(p).unwrap()).unwrap()
}

/// `svbrdf bench --fit-maps MAPS --truth CAP`: the maps' accuracy object.
pub fn maps_accuracy(maps: &Path, cap: &Path) -> serde_json::Value {
    let o = svbrdf(&[
        "bench",
        "--no-brdf",
        "--fit-maps",
        maps.to_str().unwrap(),
        "--truth",
        cap.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    json_lines(&o)[0]["accuracy"].clone()
}

/// Whether `b` is `a` turned a quarter clockwise, and whether counter-clockwise
/// (every 7th column compared exactly).
pub fn quarter_turns(
    a: &svbrdf_core::image::ImageU8,
    b: &svbrdf_core::image::ImageU8,
) -> (bool, bool) {
    let (w, h) = (a.width, a.height);
    let turned = |to: &dyn Fn(usize, usize) -> (usize, usize)| {
        (0..h).all(|y| {
            (0..w).step_by(7).all(|x| {
                let (bx, by) = to(x, y);
                a.pixel(x, y) == b.pixel(bx, by)
            })
        })
    };
    (
        turned(&|x, y| (h - 1 - y, x)),
        turned(&|x, y| (y, w - 1 - x)),
    )
}
