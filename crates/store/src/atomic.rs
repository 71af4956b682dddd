//! The one way skybake writes a file: to a temporary file in the same directory, fsync, rename over
//! the target, fsync the directory. A reader sees the old file or the complete new one, never a
//! partial write, and after return the new file survives a crash.

use std::fs::{self, File, OpenOptions};
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

use super::StoreError;

/// Marker in the names of temporary files; [`is_temp_file_name`] recognises them so that leftovers
/// of a crash can be cleaned up.
const TEMP_MARKER: &str = ".skybake-tmp.";

/// Distinguishes concurrent writers within this process.
static COUNTER: AtomicU64 = AtomicU64::new(0);

/// Writes `bytes` to `path` atomically and durably. Creates the parent directory if missing.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<(), StoreError> {
    let parent = parent_dir(path);
    let file_name = path.file_name().ok_or_else(|| {
        crate::Error::invalid("path", format!("{} has no file name", path.display()))
    })?;
    if !parent.is_dir() {
        fs::create_dir_all(&parent).map_err(|e| StoreError::io(&parent, e))?;
        // Make the new directory entry itself durable.
        sync_dir(&parent_dir(&parent))?;
    }

    let temp_path = parent.join(format!(
        ".{}{TEMP_MARKER}{}.{}",
        file_name.to_string_lossy(),
        std::process::id(),
        COUNTER.fetch_add(1, Ordering::Relaxed)
    ));
    let result = write_and_sync(&temp_path, bytes)
        .and_then(|()| fs::rename(&temp_path, path).map_err(|e| StoreError::io(path, e)));
    if result.is_err() {
        // Best effort: the temp file is garbage now; the original error is what matters.
        let _ = fs::remove_file(&temp_path);
    }
    result?;
    sync_dir(&parent)
}

/// True for names produced by [`write_atomic`] for its temporary files.
pub fn is_temp_file_name(name: &str) -> bool {
    name.starts_with('.') && name.contains(TEMP_MARKER)
}

fn write_and_sync(temp_path: &Path, bytes: &[u8]) -> Result<(), StoreError> {
    let mut file = OpenOptions::new()
        .write(true)
        .create_new(true)
        .open(temp_path)
        .map_err(|e| StoreError::io(temp_path, e))?;
    file.write_all(bytes)
        .and_then(|()| file.sync_all())
        .map_err(|e| StoreError::io(temp_path, e))
}

fn parent_dir(path: &Path) -> PathBuf {
    match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
        _ => PathBuf::from("."),
    }
}

/// Fsyncs a directory so that a rename or creation inside it is durable (POSIX). Other platforms
/// cannot open directories as files; there the rename's own guarantees have to do.
fn sync_dir(dir: &Path) -> Result<(), StoreError> {
    #[cfg(unix)]
    {
        File::open(dir)
            .and_then(|d| d.sync_all())
            .map_err(|e| StoreError::io(dir, e))
    }
    #[cfg(not(unix))]
    {
        let _ = dir;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scratch_dir(name: &str) -> PathBuf {
        let dir = std::env::temp_dir().join(format!(
            "skybake-atomic-{name}-{}-{}",
            std::process::id(),
            COUNTER.fetch_add(1, Ordering::Relaxed)
        ));
        let _ = fs::remove_dir_all(&dir);
        dir
    }

    #[test]
    fn writes_replaces_and_leaves_no_temp_files() {
        let dir = scratch_dir("replace");
        let path = dir.join("sub").join("file.bin");
        write_atomic(&path, b"first").unwrap();
        assert_eq!(fs::read(&path).unwrap(), b"first");
        write_atomic(&path, b"second, longer").unwrap();
        assert_eq!(fs::read(&path).unwrap(), b"second, longer");
        let names: Vec<String> = fs::read_dir(dir.join("sub"))
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        assert_eq!(names, vec!["file.bin".to_string()]);
        fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn failed_write_leaves_target_untouched() {
        let dir = scratch_dir("fail");
        let path = dir.join("target");
        write_atomic(&path, b"keep").unwrap();
        // Renaming a file over a non-empty directory fails; the old content must survive elsewhere.
        let blocked = dir.join("blocked");
        fs::create_dir_all(blocked.join("inner")).unwrap();
        assert!(matches!(
            write_atomic(&blocked, b"x"),
            Err(StoreError::Io { .. })
        ));
        assert_eq!(fs::read(&path).unwrap(), b"keep");
        let leftovers = fs::read_dir(&dir)
            .unwrap()
            .filter(|e| is_temp_file_name(&e.as_ref().unwrap().file_name().to_string_lossy()))
            .count();
        assert_eq!(leftovers, 0);
        fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn temp_names_are_recognised() {
        assert!(is_temp_file_name(".abc.exr.skybake-tmp.12.3"));
        assert!(!is_temp_file_name("abc.exr"));
    }
}
