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

/// A folder being built under a temporary name; [`commit`](Self::commit) renames it to
/// its final name. Dropped without commit, the temporary folder is removed.
#[derive(Debug)]
pub struct StagingDir {
    tmp: PathBuf,
    target: PathBuf,
    committed: bool,
}

impl StagingDir {
    /// Start building `target`. Fails if it exists, unless `overwrite`.
    pub fn new(target: &Path, overwrite: bool) -> Result<Self, CoreError> {
        if target.exists() && !overwrite {
            return Err(CoreError::invalid(
                "output folder",
                target.display(),
                "a path that does not exist yet (or pass --overwrite)",
            ));
        }
        let tmp = temp_sibling(target);
        if tmp.exists() {
            fs::remove_dir_all(&tmp).map_err(|e| CoreError::io(&tmp, e))?;
        }
        fs::create_dir_all(&tmp).map_err(|e| CoreError::io(&tmp, e))?;
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

    /// Move the finished folder into place, replacing an old one.
    pub fn commit(mut self) -> Result<PathBuf, CoreError> {
        if self.target.exists() {
            fs::remove_dir_all(&self.target).map_err(|e| CoreError::io(&self.target, e))?;
        }
        fs::rename(&self.tmp, &self.target).map_err(|e| CoreError::io(&self.target, e))?;
        self.committed = true;
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
            let s = StagingDir::new(&target, false).unwrap();
            fs::write(s.path().join("a"), b"x").unwrap();
        }
        assert!(!target.exists());
        assert_eq!(fs::read_dir(root.path()).unwrap().count(), 0);
        let s = StagingDir::new(&target, false).unwrap();
        fs::write(s.path().join("a"), b"x").unwrap();
        s.commit().unwrap();
        assert!(target.join("a").exists());
        assert!(StagingDir::new(&target, false).is_err());
        assert!(StagingDir::new(&target, true).is_ok());
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
