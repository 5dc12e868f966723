//! The store's error: always names the file, then what is wrong with it.

use std::path::{Path, PathBuf};

#[derive(Debug, thiserror::Error)]
#[error("{}: {message}", crate::text::sanitize(&.path.display().to_string()))]
pub struct StoreError {
    pub path: PathBuf,
    pub message: String,
    /// For a request to object storage that failed: its URL and what happened
    /// (the command line says what to do from it). Shown through `message`.
    #[cfg(feature = "remote")]
    pub remote: Option<crate::remote::RemoteError>,
}

impl StoreError {
    pub fn new(path: &Path, message: impl Into<String>) -> Self {
        StoreError {
            path: path.to_path_buf(),
            message: message.into(),
            #[cfg(feature = "remote")]
            remote: None,
        }
    }

    /// A failed request: the path is its URL, the message what happened.
    #[cfg(feature = "remote")]
    pub fn remote(e: crate::remote::RemoteError) -> Self {
        StoreError {
            path: PathBuf::from(&e.url),
            message: e.problem.to_string(),
            remote: Some(e),
        }
    }
}

pub type Result<T> = std::result::Result<T, StoreError>;
