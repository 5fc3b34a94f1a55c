//! NVIDIA's FLIP image-difference metric (pip `flip-evaluator`) as `svbrdf eval`'s
//! perceptual figure. The evaluator runs as its own command-line tool: each held-out
//! photo and our rendering are written as 8-bit sRGB PNGs (pixels outside the compared
//! area copied from the photo into both, so they add no difference), `flip` writes its
//! grey error map, and the mean is taken over the compared pixels only.

use std::path::{Path, PathBuf};
use std::process::Command;

use anyhow::{Context, Result};
use svbrdf_core::image::ImageF32;
use svbrdf_core::maps::{read_image_linear, write_png, Encoding, PngDepth};
use svbrdf_fit::holdout::ImageMetric;
use svbrdf_fit::FitError;

/// Environment variable naming the `flip` executable.
pub const FLIP_ENV: &str = "SVBRDF_FLIP";

/// How to install the evaluator, for messages.
pub const FLIP_INSTALL: &str = "pip install flip-evaluator (or scripts/test-tools.sh, which puts it in .venv-tools/bin/flip), then pass --flip PATH or set SVBRDF_FLIP";

/// The `flip` command of NVIDIA's FLIP evaluator.
pub struct FlipTool {
    exe: PathBuf,
    version: String,
}

impl FlipTool {
    /// The tool at `explicit`, else at `$SVBRDF_FLIP`, else `flip` on the `PATH`;
    /// `Ok(None)` when none was asked for and none is found. A tool that was asked for
    /// but does not run is an error.
    pub fn locate(explicit: Option<&Path>) -> Result<Option<Self>> {
        let asked = explicit
            .map(Path::to_path_buf)
            .or_else(|| std::env::var_os(FLIP_ENV).map(PathBuf::from));
        match asked {
            Some(exe) => Self::probe(&exe).map(Some).with_context(|| {
                format!(
                    "the FLIP evaluator {} does not run (expected NVIDIA's `flip` command: {FLIP_INSTALL})",
                    exe.display()
                )
            }),
            None => Ok(Self::probe(Path::new("flip")).ok()),
        }
    }

    fn probe(exe: &Path) -> Result<Self> {
        let out = Command::new(exe).arg("-h").output()?;
        let text = String::from_utf8_lossy(&out.stdout);
        let first = text.lines().next().unwrap_or_default();
        let version = first
            .strip_prefix("FLIP v")
            .map(|v| v.trim_end_matches('.').to_string())
            .with_context(|| format!("`{} -h` printed {first:?}", exe.display()))?;
        Ok(Self {
            exe: exe.to_path_buf(),
            version,
        })
    }
}

impl ImageMetric for FlipTool {
    fn describe(&self) -> String {
        format!(
            "NVIDIA FLIP v{} (flip-evaluator, LDR-FLIP on 8-bit sRGB, its default 67 pixels per degree), mean over the compared pixels",
            self.version
        )
    }

    fn mean_error(
        &self,
        reference: &ImageF32,
        test: &ImageF32,
        mask: &[bool],
    ) -> Result<f64, FitError> {
        let fail =
            |what: String| FitError::Source(format!("FLIP ({}): {what}", self.exe.display()));
        let dir = tempfile::tempdir().map_err(|e| fail(format!("a temporary folder: {e}")))?;
        let mut test = test.clone();
        for (i, &m) in mask.iter().enumerate() {
            if !m {
                let c = test.channels;
                test.data[i * c..i * c + c].copy_from_slice(&reference.data[i * c..i * c + c]);
            }
        }
        let (r, t) = (
            dir.path().join("reference.png"),
            dir.path().join("test.png"),
        );
        // The values are sRGB-encoded already: stored as they are.
        write_png(&r, reference, Encoding::Linear, PngDepth::Eight, &[])?;
        write_png(&t, &test, Encoding::Linear, PngDepth::Eight, &[])?;
        let out = Command::new(&self.exe)
            .args(["-nm", "-v", "0", "-b", "error", "-r"])
            .arg(&r)
            .arg("-t")
            .arg(&t)
            .arg("-d")
            .arg(dir.path())
            .output()
            .map_err(|e| fail(e.to_string()))?;
        if !out.status.success() {
            return Err(fail(format!(
                "exit {}: {}",
                out.status,
                String::from_utf8_lossy(&out.stderr).trim()
            )));
        }
        let map = read_image_linear(&dir.path().join("error.png"), Encoding::Linear)?;
        if map.width != reference.width || map.height != reference.height {
            return Err(fail(format!(
                "an error map of {}x{} for {}x{} images",
                map.width, map.height, reference.width, reference.height
            )));
        }
        let (mut sum, mut n) = (0.0, 0usize);
        for (i, &m) in mask.iter().enumerate() {
            if m {
                sum += f64::from(map.data[i * map.channels]);
                n += 1;
            }
        }
        Ok(if n > 0 { sum / n as f64 } else { 0.0 })
    }
}
