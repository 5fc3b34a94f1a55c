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

pub fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}
