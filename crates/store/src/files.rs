//! Plain file access for the job store and offline bakes (so that only `store` touches the disk):
//! read a whole file, create or remove a directory, list the subdirectories of a directory. Writes go
//! through [`super::write_atomic`].

use super::StoreError;
use std::path::{Path, PathBuf};

/// Reads the whole file at `path`.
pub fn read(path: &Path) -> Result<Vec<u8>, StoreError> {
    std::fs::read(path).map_err(|e| StoreError::io(path, e))
}

/// Reads the file at `path`, or `None` when there is none.
pub fn read_if_exists(path: &Path) -> Result<Option<Vec<u8>>, StoreError> {
    match std::fs::read(path) {
        Ok(bytes) => Ok(Some(bytes)),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(None),
        Err(e) => Err(StoreError::io(path, e)),
    }
}

/// Removes `dir` and everything in it; a directory already gone is not an error.
pub fn remove_dir_all(dir: &Path) -> Result<(), StoreError> {
    match std::fs::remove_dir_all(dir) {
        Err(e) if e.kind() != std::io::ErrorKind::NotFound => Err(StoreError::io(dir, e)),
        _ => Ok(()),
    }
}

/// Creates `dir` and its parents.
pub fn create_dir_all(dir: &Path) -> Result<(), StoreError> {
    std::fs::create_dir_all(dir).map_err(|e| StoreError::io(dir, e))
}

/// The subdirectories of `dir` as (name, path), in no particular order; entries whose names are
/// not UTF-8 are skipped.
pub fn subdirectories(dir: &Path) -> Result<Vec<(String, PathBuf)>, StoreError> {
    let entries = std::fs::read_dir(dir).map_err(|e| StoreError::io(dir, e))?;
    Ok(entries
        .flatten()
        .filter(|e| e.file_type().is_ok_and(|t| t.is_dir()))
        .filter_map(|e| Some((e.file_name().into_string().ok()?, e.path())))
        .collect())
}
/// The names of the regular files directly in `dir` (none when it does not exist); names that
/// are not UTF-8 are skipped.
pub fn file_names(dir: &Path) -> Result<Vec<String>, StoreError> {
    let entries = match std::fs::read_dir(dir) {
        Ok(entries) => entries,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(Vec::new()),
        Err(e) => return Err(StoreError::io(dir, e)),
    };
    Ok(entries
        .flatten()
        .filter(|e| e.file_type().is_ok_and(|t| t.is_file()))
        .filter_map(|e| e.file_name().into_string().ok())
        .collect())
}

/// Reads at most `limit` bytes of `path`, refusing larger files (errors name `field`).
pub fn read_limited(path: &Path, field: &str, limit: usize) -> crate::Result<Vec<u8>> {
    use std::io::Read;
    let cannot = |e: std::io::Error| {
        crate::Error::invalid(field, format!("cannot read {}: {e}", path.display()))
    };
    let too_large = |len: u64| {
        crate::Error::too_large(
            field,
            format!("{} is {len} bytes", path.display()),
            format!("{limit} bytes"),
        )
    };
    let file = std::fs::File::open(path).map_err(cannot)?;
    let len = file.metadata().map_err(cannot)?.len();
    if len > limit as u64 {
        return Err(too_large(len));
    }
    let mut bytes = Vec::with_capacity(len as usize);
    file.take(limit as u64 + 1)
        .read_to_end(&mut bytes)
        .map_err(cannot)?;
    if bytes.len() > limit {
        return Err(too_large(bytes.len() as u64));
    }
    Ok(bytes)
}
