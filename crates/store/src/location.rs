//! A folder of named files: a local directory or a folder in a bucket. Bakes write their
//! artifacts, frame tiles, shard progress and manifest through it, so a bake runs the same on one
//! machine (`--out DIR`) as over many sharing a bucket (`--out s3://bucket/prefix`).

use std::path::PathBuf;
use std::sync::Arc;

use super::bucket::{is_bucket_url, Bucket, RetryPolicy};
use super::{files, write_atomic, StoreError, TileStore};

/// Where a folder of files lives.
#[derive(Debug, Clone)]
pub enum Location {
    /// A local directory (created on first write).
    Dir(PathBuf),
    /// The bucket's prefix itself.
    Bucket(Arc<Bucket>),
}

impl Location {
    /// `s3://bucket/prefix` (opened with the AWS environment variables) or a directory path.
    pub fn parse(text: &str) -> Result<Self, StoreError> {
        if is_bucket_url(text) {
            Ok(Self::Bucket(Arc::new(Bucket::open(
                text,
                &[],
                RetryPolicy::default(),
            )?)))
        } else {
            Ok(Self::Dir(PathBuf::from(text)))
        }
    }

    /// The directory path or the bucket URL, for messages.
    pub fn describe(&self) -> String {
        match self {
            Self::Dir(dir) => dir.display().to_string(),
            Self::Bucket(bucket) => bucket.url().to_string(),
        }
    }

    /// Makes sure the folder can be written (creates a directory; a bucket needs nothing).
    pub fn create(&self) -> Result<(), StoreError> {
        match self {
            Self::Dir(dir) => files::create_dir_all(dir),
            Self::Bucket(_) => Ok(()),
        }
    }

    /// The file `name`, or `None`.
    pub fn get(&self, name: &str) -> Result<Option<Vec<u8>>, StoreError> {
        match self {
            Self::Dir(dir) => files::read_if_exists(&dir.join(name)),
            Self::Bucket(bucket) => bucket.get(name),
        }
    }

    /// Writes the file `name` atomically (a reader sees the old file or the whole new one).
    pub fn put(&self, name: &str, bytes: &[u8]) -> Result<(), StoreError> {
        match self {
            Self::Dir(dir) => write_atomic(&dir.join(name), bytes),
            Self::Bucket(bucket) => bucket.put(name, bytes),
        }
    }

    /// The names of the files directly in the folder (none when it does not exist).
    pub fn names(&self) -> Result<Vec<String>, StoreError> {
        match self {
            Self::Dir(dir) => files::file_names(dir),
            Self::Bucket(bucket) => Ok(bucket.list("")?.0.into_iter().map(|o| o.name).collect()),
        }
    }

    /// The frame tiles kept in the folder's `tiles/` until each frame is finished.
    pub fn tiles(&self) -> Result<TileStore, StoreError> {
        match self {
            Self::Dir(dir) => TileStore::open(&dir.join("tiles")),
            Self::Bucket(bucket) => Ok(TileStore::in_bucket(bucket.clone(), "tiles")),
        }
    }
}
