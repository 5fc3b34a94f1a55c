//! Writing files and folders so that an interrupted run never leaves something that
//! looks complete: everything is written under a temporary name and renamed at the end.

use std::fs;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};

use crate::CoreError;

/// The temporary sibling name used while `path` is being written.
pub fn temp_sibling(path: &Path) -> PathBuf {
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| "out".into());
    path.with_file_name(format!(".{name}.tmp-{}", std::process::id()))
}

/// Write a file through `write` into a temporary sibling, then rename it into place.
pub fn write_atomic<F>(path: &Path, write: F) -> Result<(), CoreError>
where
    F: FnOnce(&mut BufWriter<fs::File>) -> Result<(), CoreError>,
{
    if let Some(dir) = path.parent() {
        if !dir.as_os_str().is_empty() {
            fs::create_dir_all(dir).map_err(|e| CoreError::io(dir, e))?;
        }
    }
    let tmp = temp_sibling(path);
    let result = (|| {
        let file = fs::File::create(&tmp).map_err(|e| CoreError::io(&tmp, e))?;
        let mut w = BufWriter::new(file);
        write(&mut w)?;
        w.flush().map_err(|e| CoreError::io(&tmp, e))?;
        fs::rename(&tmp, path).map_err(|e| CoreError::io(path, e))
    })();
    if result.is_err() {
        let _ = fs::remove_file(&tmp);
    }
    result
}

/// Write a JSON document atomically, pretty-printed.
pub fn write_json<T: serde::Serialize>(path: &Path, value: &T) -> Result<(), CoreError> {
    write_atomic(path, |w| {
        serde_json::to_writer_pretty(&mut *w, value)
            .map_err(|e| CoreError::format(path, e.to_string()))?;
        w.write_all(b"\n").map_err(|e| CoreError::io(path, e))
    })
}

/// Read and parse a JSON document.
pub fn read_json<T: serde::de::DeserializeOwned>(path: &Path) -> Result<T, CoreError> {
    let text = fs::read_to_string(path).map_err(|e| CoreError::io(path, e))?;
    serde_json::from_str(&text).map_err(|e| CoreError::format(path, e.to_string()))
}

/// Read a JSON settings document whose every key must be a field of `T` (a struct
/// with `#[serde(default)]`: missing keys take the defaults). An unknown key is an
/// error naming it and the closest known one: a typo must not fall back to a default
/// in silence.
pub fn read_json_settings<T>(path: &Path) -> Result<T, CoreError>
where
    T: serde::de::DeserializeOwned + serde::Serialize + Default,
{
    let text = fs::read_to_string(path).map_err(|e| CoreError::io(path, e))?;
    if text.trim().is_empty() {
        return Err(CoreError::format(
            path,
            "the file is empty (expected a JSON object, e.g. {})",
        ));
    }
    let value: serde_json::Value =
        serde_json::from_str(&text).map_err(|e| CoreError::format(path, e.to_string()))?;
    let Some(given) = value.as_object() else {
        return Err(CoreError::format(
            path,
            format!(
                "expected a JSON object of settings, found {}",
                json_kind(&value)
            ),
        ));
    };
    let known = serde_json::to_value(T::default())
        .ok()
        .and_then(|v| v.as_object().map(|o| o.keys().cloned().collect::<Vec<_>>()))
        .unwrap_or_default();
    for key in given.keys() {
        if !known.contains(key) {
            let closest = known
                .iter()
                .min_by_key(|k| edit_distance(k, key))
                .map(|k| format!("did you mean {k:?}? "))
                .unwrap_or_default();
            return Err(CoreError::format(
                path,
                format!(
                    "unknown key {key:?} ({closest}known keys: {})",
                    known.join(", ")
                ),
            ));
        }
    }
    serde_json::from_str(&text).map_err(|e| {
        // Name the key whose value is wrong: the first one that fails on its own.
        let culprit = given.iter().find(|(k, v)| {
            let mut one = serde_json::Map::new();
            one.insert((*k).clone(), (*v).clone());
            serde_json::from_value::<T>(serde_json::Value::Object(one)).is_err()
        });
        match culprit {
            Some((k, _)) => CoreError::format(path, format!("{k:?}: {e}")),
            None => CoreError::format(path, e.to_string()),
        }
    })
}

fn json_kind(v: &serde_json::Value) -> &'static str {
    match v {
        serde_json::Value::Null => "null",
        serde_json::Value::Bool(_) => "a boolean",
        serde_json::Value::Number(_) => "a number",
        serde_json::Value::String(_) => "a string",
        serde_json::Value::Array(_) => "an array",
        serde_json::Value::Object(_) => "an object",
    }
}

/// Levenshtein distance between two strings (for "did you mean" hints).
pub fn edit_distance(a: &str, b: &str) -> usize {
    let b: Vec<char> = b.chars().collect();
    let mut row: Vec<usize> = (0..=b.len()).collect();
    for (i, ca) in a.chars().enumerate() {
        let mut prev = row[0];
        row[0] = i + 1;
        for (j, cb) in b.iter().enumerate() {
            let cur = row[j + 1];
            row[j + 1] = (prev + usize::from(ca != *cb)).min(row[j] + 1).min(cur + 1);
            prev = cur;
        }
    }
    row[b.len()]
}

/// `path` made absolute with every symlink resolved, also when it does not exist yet
/// (its nearest existing ancestor is resolved and the rest appended).
pub fn resolve(path: &Path) -> PathBuf {
    let abs = std::path::absolute(path).unwrap_or_else(|_| path.to_path_buf());
    let mut tail = Vec::new();
    let mut cur = abs.as_path();
    loop {
        if let Ok(c) = fs::canonicalize(cur) {
            let mut out = c;
            for t in tail.iter().rev() {
                out.push(t);
            }
            return out;
        }
        match (cur.parent(), cur.file_name()) {
            (Some(parent), Some(name)) => {
                tail.push(name.to_os_string());
                cur = parent;
            }
            _ => return abs,
        }
    }
}

/// Refuse an output folder whose replacement would remove an input: it is an input,
/// or it contains one (after resolving links). An output inside an input folder is
/// fine as long as it holds no input itself.
pub fn check_output_spares_inputs(out: &Path, inputs: &[PathBuf]) -> Result<(), CoreError> {
    let target = resolve(out);
    for input in inputs {
        let i = resolve(input);
        if i == target || i.starts_with(&target) {
            return Err(CoreError::invalid(
                "output folder",
                format!(
                    "{} ({} the input {}, which replacing it would delete)",
                    out.display(),
                    if i == target { "it is" } else { "it contains" },
                    input.display()
                ),
                "a folder that neither is nor contains an input; choose another --out",
            ));
        }
    }
    Ok(())
}

/// Whether a process with this id is running (Linux `/proc`; elsewhere: assume so).
fn process_alive(pid: u32) -> bool {
    if !Path::new("/proc/self").exists() {
        return true;
    }
    Path::new("/proc").join(pid.to_string()).exists()
}

/// Remove `.NAME.tmp-PID` and `.NAME.old-PID` siblings of `target` left by a process
/// that was killed (its id no longer runs).
pub fn remove_stale_siblings(target: &Path) {
    let (Some(dir), Some(name)) = (target.parent(), target.file_name()) else {
        return;
    };
    let dir = if dir.as_os_str().is_empty() {
        Path::new(".")
    } else {
        dir
    };
    let name = name.to_string_lossy();
    let Ok(entries) = fs::read_dir(dir) else {
        return;
    };
    for e in entries.flatten() {
        let n = e.file_name().to_string_lossy().into_owned();
        for kind in [".tmp-", ".old-"] {
            let prefix = format!(".{name}{kind}");
            if let Some(pid) = n.strip_prefix(&prefix).and_then(|p| p.parse::<u32>().ok()) {
                if pid != std::process::id() && !process_alive(pid) {
                    let p = e.path();
                    let _ = if p.is_dir() {
                        fs::remove_dir_all(&p)
                    } else {
                        fs::remove_file(&p)
                    };
                }
            }
        }
    }
}

/// A folder being built under a temporary name; [`commit`](Self::commit) renames it to
/// its final name. Dropped without commit, the temporary folder is removed.
#[derive(Debug)]
pub struct StagingDir {
    tmp: PathBuf,
    target: PathBuf,
    committed: bool,
}

impl StagingDir {
    /// Start building `target`. Fails if it exists, unless `overwrite`, and always when
    /// replacing it would remove one of `inputs` (files or folders the command reads).
    pub fn new(target: &Path, overwrite: bool, inputs: &[PathBuf]) -> Result<Self, CoreError> {
        if target.exists() && !overwrite {
            return Err(CoreError::invalid(
                "output folder",
                target.display(),
                "a path that does not exist yet (or pass --overwrite)",
            ));
        }
        if target.exists() && !target.is_dir() {
            return Err(CoreError::invalid(
                "output folder",
                format!("{} (it is a file)", target.display()),
                "a folder, or a path that does not exist yet",
            ));
        }
        check_output_spares_inputs(target, inputs)?;
        remove_stale_siblings(target);
        let tmp = temp_sibling(target);
        if tmp.exists() {
            fs::remove_dir_all(&tmp).map_err(|e| CoreError::io(&tmp, e))?;
        }
        if let Some(parent) = target.parent() {
            if !parent.as_os_str().is_empty() && !parent.exists() {
                fs::create_dir_all(parent).map_err(|e| CoreError::io(parent, e))?;
            }
        }
        fs::create_dir(&tmp).map_err(|e| CoreError::io(target, e))?;
        Ok(Self {
            tmp,
            target: target.to_path_buf(),
            committed: false,
        })
    }

    /// Where to write while building.
    pub fn path(&self) -> &Path {
        &self.tmp
    }

    /// Move the finished folder into place. An old folder is first moved aside and
    /// deleted only once the new one is in place, so that an interruption at any
    /// point leaves the old folder or the new one (the other under a hidden name).
    pub fn commit(mut self) -> Result<PathBuf, CoreError> {
        let old = self.target.with_file_name(format!(
            ".{}.old-{}",
            self.target
                .file_name()
                .map(|n| n.to_string_lossy().into_owned())
                .unwrap_or_else(|| "out".into()),
            std::process::id()
        ));
        let had_old = self.target.exists();
        if had_old {
            fs::rename(&self.target, &old).map_err(|e| CoreError::io(&self.target, e))?;
        }
        if let Err(e) = fs::rename(&self.tmp, &self.target) {
            if had_old {
                let _ = fs::rename(&old, &self.target);
            }
            return Err(CoreError::io(&self.target, e));
        }
        self.committed = true;
        if had_old {
            fs::remove_dir_all(&old).map_err(|e| CoreError::io(&old, e))?;
        }
        Ok(self.target.clone())
    }
}

impl Drop for StagingDir {
    fn drop(&mut self) {
        if !self.committed {
            let _ = fs::remove_dir_all(&self.tmp);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn staging_dir_is_removed_unless_committed() {
        let root = tempfile::tempdir().unwrap();
        let target = root.path().join("out");
        {
            let s = StagingDir::new(&target, false, &[]).unwrap();
            fs::write(s.path().join("a"), b"x").unwrap();
        }
        assert!(!target.exists());
        assert_eq!(fs::read_dir(root.path()).unwrap().count(), 0);
        let s = StagingDir::new(&target, false, &[]).unwrap();
        fs::write(s.path().join("a"), b"x").unwrap();
        s.commit().unwrap();
        assert!(target.join("a").exists());
        assert!(StagingDir::new(&target, false, &[]).is_err());
        assert!(StagingDir::new(&target, true, &[]).is_ok());
    }

    #[test]
    fn an_output_that_is_or_holds_an_input_is_refused() {
        let root = tempfile::tempdir().unwrap();
        let inp = root.path().join("in");
        fs::create_dir(&inp).unwrap();
        fs::write(inp.join("video.mp4"), b"v").unwrap();
        let video = inp.join("video.mp4");
        // The folder holding the input, the input's folder itself, a parent of it, and
        // the same folder reached through a relative path with `..`.
        for out in [
            inp.clone(),
            root.path().to_path_buf(),
            inp.join("..").join("in"),
        ] {
            let e = StagingDir::new(&out, true, std::slice::from_ref(&video)).unwrap_err();
            assert!(e.to_string().contains("video.mp4"), "{e}");
        }
        let e = StagingDir::new(&video, true, std::slice::from_ref(&video)).unwrap_err();
        assert!(e.to_string().contains("it is a file"), "{e}");
        // Inside the input's folder is fine: the input survives the replacement.
        let s = StagingDir::new(&inp.join("out"), true, std::slice::from_ref(&video)).unwrap();
        s.commit().unwrap();
        assert_eq!(fs::read(&video).unwrap(), b"v");
    }

    #[test]
    fn commit_replaces_the_old_folder_and_leaves_no_siblings() {
        let root = tempfile::tempdir().unwrap();
        let target = root.path().join("out");
        fs::create_dir(&target).unwrap();
        fs::write(target.join("old"), b"o").unwrap();
        // A sibling left by a killed process (pid 0 never names a user process).
        fs::create_dir(root.path().join(".out.tmp-999999999")).unwrap();
        let s = StagingDir::new(&target, true, &[]).unwrap();
        fs::write(s.path().join("new"), b"n").unwrap();
        s.commit().unwrap();
        assert!(target.join("new").exists() && !target.join("old").exists());
        let names: Vec<_> = fs::read_dir(root.path())
            .unwrap()
            .flatten()
            .map(|e| e.file_name())
            .collect();
        assert_eq!(names, vec![std::ffi::OsString::from("out")]);
    }

    #[test]
    fn failed_write_leaves_nothing() {
        let root = tempfile::tempdir().unwrap();
        let p = root.path().join("f.json");
        let r = write_atomic(&p, |_| Err(CoreError::Degenerate("boom".into())));
        assert!(r.is_err());
        assert_eq!(fs::read_dir(root.path()).unwrap().count(), 0);
    }
}
