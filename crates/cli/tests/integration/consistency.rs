//! A run folder is consistent or visibly unfinished, identical runs give identical
//! bytes, and `view` serves nothing but the export's own files.

use std::collections::BTreeMap;
use std::io::{BufRead, Read, Write};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};

use crate::hostile::copy_tree;
use crate::util::{
    run_tiny, stderr, svbrdf, temp_dir, tiny_capture, tiny_run, Server, NO_SELECTION,
};

/// A number followed by a unit of time or memory, replaced by `#`: the run's own
/// measurements in report.html.
fn mask_measurements(text: &str) -> String {
    let mut out = String::with_capacity(text.len());
    let b: Vec<char> = text.chars().collect();
    let mut i = 0;
    while i < b.len() {
        if b[i].is_ascii_digit() {
            let start = i;
            while i < b.len() && (b[i].is_ascii_digit() || b[i] == '.') {
                i += 1;
            }
            let rest: String = b[i..b.len().min(i + 3)].iter().collect();
            if rest.starts_with(" s") || rest.starts_with(" MB") {
                out.push('#');
            } else {
                out.extend(&b[start..i]);
            }
        } else {
            out.push(b[i]);
            i += 1;
        }
    }
    out
}

/// JSON without the run's own measurements (timings, seconds, peak memory) and the
/// output paths, which differ between runs by nature.
fn strip_measurements(v: &mut serde_json::Value) {
    match v {
        serde_json::Value::Object(m) => {
            m.retain(|k, _| {
                !(k == "timings"
                    || k.ends_with("seconds")
                    || k.starts_with("peak_memory")
                    || k == "out")
            });
            m.values_mut().for_each(strip_measurements);
        }
        serde_json::Value::Array(a) => a.iter_mut().for_each(strip_measurements),
        _ => {}
    }
}

/// Every file of a folder, bytes, with measurements masked in JSON and HTML.
fn contents(dir: &Path) -> BTreeMap<PathBuf, Vec<u8>> {
    fn walk(root: &Path, d: &Path, out: &mut BTreeMap<PathBuf, Vec<u8>>) {
        for e in std::fs::read_dir(d).unwrap().flatten() {
            let p = e.path();
            if p.is_dir() {
                walk(root, &p, out);
                continue;
            }
            let mut bytes = std::fs::read(&p).unwrap();
            match p.extension().and_then(|e| e.to_str()) {
                Some("json") => {
                    let mut v: serde_json::Value = serde_json::from_slice(&bytes).unwrap();
                    strip_measurements(&mut v);
                    bytes = v.to_string().into_bytes();
                }
                Some("html") => {
                    bytes = mask_measurements(&String::from_utf8_lossy(&bytes)).into_bytes();
                }
                _ => {}
            }
            out.insert(p.strip_prefix(root).unwrap().to_path_buf(), bytes);
        }
    }
    let mut out = BTreeMap::new();
    walk(dir, dir, &mut out);
    out
}

fn assert_same_run(a: &Path, b: &Path) {
    let (ca, cb) = (contents(a), contents(b));
    let names = |c: &BTreeMap<PathBuf, Vec<u8>>| c.keys().cloned().collect::<Vec<_>>();
    assert_eq!(
        names(&ca),
        names(&cb),
        "{} and {} hold different files",
        a.display(),
        b.display()
    );
    for (k, v) in &ca {
        assert!(
            v == &cb[k],
            "{} differs between {} and {}",
            k.display(),
            a.display(),
            b.display()
        );
    }
}

#[test]
fn identical_runs_give_identical_bytes() {
    let first = tiny_run();
    for _ in 0..2 {
        let out = temp_dir().join("again");
        let o = run_tiny(&out, &[]);
        assert!(o.status.success(), "{}", stderr(&o));
        assert_same_run(first, &out);
    }
}

/// A complete run of another capture, to be overwritten (settings not chosen on
/// held-out frames: only its files matter).
fn other_run() -> PathBuf {
    let cap = temp_dir().join("other");
    let o = svbrdf(&[
        "synth",
        "--preset",
        "tiny",
        "--seed",
        "5",
        "--duration",
        "2",
        "--out",
        cap.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let out = temp_dir().join("otherrun");
    let o = svbrdf(&[
        "run",
        "--video",
        cap.join("flash.mp4").to_str().unwrap(),
        "--reference",
        cap.join("reference.jpg").to_str().unwrap(),
        "--camera",
        cap.join("camera.json").to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        NO_SELECTION[0],
        NO_SELECTION[1],
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    out
}

/// Start `run` of the shared tiny capture into `out` and kill it (SIGKILL) as soon as
/// it prints a line starting with `at`. Returns whether the kill came before the end.
fn run_killed_at(out: &Path, at: &str, overwrite: bool) -> bool {
    let cap = tiny_capture();
    let mut args = vec![
        "run".to_string(),
        "--video".into(),
        cap.join("flash.mp4").to_string_lossy().into_owned(),
        "--reference".into(),
        cap.join("reference.jpg").to_string_lossy().into_owned(),
        "--camera".into(),
        cap.join("camera.json").to_string_lossy().into_owned(),
        "--out".into(),
        out.to_string_lossy().into_owned(),
    ];
    args.extend(NO_SELECTION.map(String::from));
    if overwrite {
        args.push("--overwrite".into());
    }
    let mut child = Command::new(env!("CARGO_BIN_EXE_svbrdf"))
        .args(&args)
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let stdout = child.stdout.take().unwrap();
    let mut killed = false;
    for line in std::io::BufReader::new(stdout).lines() {
        let Ok(line) = line else { break };
        if line.starts_with(at) {
            child.kill().unwrap();
            killed = true;
            break;
        }
    }
    let status = child.wait().unwrap();
    killed && !status.success()
}

fn assert_refused_until_resumed(dir: &Path, fit_finished: bool) {
    let o = svbrdf(&["view", dir.to_str().unwrap(), "--port", "1"]);
    assert!(!o.status.success(), "view served an unfinished run");
    assert!(
        stderr(&o).contains("unfinished run folder"),
        "{}",
        stderr(&o)
    );
    assert_eq!(stderr(&o).trim().lines().count(), 1, "{}", stderr(&o));
    assert!(
        !dir.join("report.html").exists(),
        "the old report survived the restart"
    );
    if !fit_finished {
        let o = svbrdf(&[
            "export",
            "--maps",
            dir.join("maps").to_str().unwrap(),
            "--out",
            temp_dir().join("x").to_str().unwrap(),
        ]);
        assert!(!o.status.success(), "export read unfinished maps");
        assert!(stderr(&o).contains("unfinished maps"), "{}", stderr(&o));
    }
}

/// Its runs skip the choice of settings ([`NO_SELECTION`]): what is tested is the run
/// folder's state after a kill and the resume, which that choice does not touch.
#[test]
fn an_interrupted_run_is_refused_until_resumed_and_resumes_to_the_same_bytes() {
    let reference = temp_dir().join("reference");
    let o = run_tiny(&reference, &NO_SELECTION);
    assert!(o.status.success(), "{}", stderr(&o));
    let old = other_run();
    for (at, overwrite) in [
        ("== align", true),
        ("== fit", true),
        ("== export", true),
        ("== report", true),
        ("== fit", false),
        ("== report", false),
    ] {
        let dir = temp_dir().join("interrupted");
        if overwrite {
            copy_tree(&old, &dir);
        }
        assert!(
            run_killed_at(&dir, at, overwrite),
            "the run finished before {at}"
        );
        let record: serde_json::Value =
            serde_json::from_slice(&std::fs::read(dir.join("run.json")).unwrap()).unwrap();
        assert_eq!(
            record["complete"],
            serde_json::json!(false),
            "killed at {at}"
        );
        let fit_finished = !record["stages"]["fit"].is_null();
        assert_refused_until_resumed(&dir, fit_finished);
        // Resume: the same command, without --overwrite (the folder holds this run).
        let o = run_tiny(&dir, &NO_SELECTION);
        assert!(o.status.success(), "resume after {at}: {}", stderr(&o));
        assert_same_run(&reference, &dir);
        let names: Vec<String> = std::fs::read_dir(&dir)
            .unwrap()
            .flatten()
            .map(|e| e.file_name().to_string_lossy().into_owned())
            .collect();
        assert!(
            !names.iter().any(|n| n.starts_with('.')),
            "leftovers after {at}: {names:?}"
        );
    }
}

fn rss_kb(pid: u32) -> u64 {
    std::fs::read_to_string(format!("/proc/{pid}/status"))
        .unwrap_or_default()
        .lines()
        .find(|l| l.starts_with("VmRSS:"))
        .and_then(|l| l.split_whitespace().nth(1)?.parse().ok())
        .unwrap_or(0)
}

#[test]
fn view_serves_only_regular_files_inside_the_export_and_bounds_requests() {
    let run = temp_dir().join("viewrun");
    copy_tree(tiny_run(), &run);
    let gltf = run.join("export/gltf");
    std::os::unix::fs::symlink("/etc/passwd", gltf.join("passwd.png")).unwrap();
    std::os::unix::fs::symlink(run.join("run.json"), gltf.join("run.bin")).unwrap();
    std::fs::create_dir(gltf.join("sub.png")).unwrap();
    let mut child = Command::new(env!("CARGO_BIN_EXE_svbrdf"))
        .args(["view", run.to_str().unwrap()])
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let pid = child.id();
    let mut out = std::io::BufReader::new(child.stdout.take().unwrap());
    let _server = Server(child);
    let mut first = String::new();
    out.read_line(&mut first).unwrap();
    std::thread::spawn(move || std::io::copy(&mut out, &mut std::io::sink()));
    let port: u16 = first
        .split("http://127.0.0.1:")
        .nth(1)
        .and_then(|r| r.split('/').next())
        .and_then(|p| p.parse().ok())
        .unwrap_or_else(|| panic!("no port in {first:?}"));
    let request = |bytes: &[u8]| -> String {
        let mut s = std::net::TcpStream::connect(("127.0.0.1", port)).unwrap();
        s.set_read_timeout(Some(std::time::Duration::from_secs(30)))
            .unwrap();
        let _ = s.write_all(bytes);
        let mut r = Vec::new();
        let _ = s.read_to_end(&mut r);
        String::from_utf8_lossy(&r)
            .lines()
            .next()
            .unwrap_or("")
            .to_string()
    };
    for (path, status) in [
        ("/gltf/material.gltf", "200"),
        ("/gltf/passwd.png", "404"),
        ("/gltf/run.bin", "404"),
        ("/gltf/sub.png", "404"),
        ("/gltf/..%2Frun.json", "404"),
        ("/gltf/../../run.json", "404"),
        ("/etc/passwd", "404"),
    ] {
        let line = request(format!("GET {path} HTTP/1.1\r\nHost: x\r\n\r\n").as_bytes());
        assert!(line.contains(status), "GET {path}: {line:?}");
    }
    let before = rss_kb(pid);
    // 64 MB of request line with no newline, sent while the server stops reading.
    let huge = std::thread::spawn(move || {
        let mut s = std::net::TcpStream::connect(("127.0.0.1", port)).unwrap();
        s.set_write_timeout(Some(std::time::Duration::from_secs(20)))
            .unwrap();
        let _ = s.write_all(b"GET /");
        let chunk = vec![b'a'; 1 << 20];
        for _ in 0..64 {
            if s.write_all(&chunk).is_err() {
                break;
            }
        }
        let mut r = Vec::new();
        let _ = s.read_to_end(&mut r);
        String::from_utf8_lossy(&r)
            .lines()
            .next()
            .unwrap_or("")
            .to_string()
    });
    let line = huge.join().unwrap();
    assert!(line.is_empty() || line.contains("431"), "{line:?}");
    let after = rss_kb(pid);
    assert!(
        after < before + 20_000,
        "memory grew from {before} kB to {after} kB"
    );
    // Still serving.
    assert!(request(b"GET /gltf/material.gltf HTTP/1.1\r\n\r\n").contains("200"));
}
