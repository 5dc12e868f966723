//! The store's error: always names the file, then what is wrong with it.

use std::path::{Path, PathBuf};

#[derive(Debug, thiserror::Error)]
#[error("{}: {message}", crate::text::sanitize(&.path.display().to_string()))]
pub struct StoreError {
    pub path: PathBuf,
    pub message: String,
}

impl StoreError {
    pub fn new(path: &Path, message: impl Into<String>) -> Self {
        StoreError {
            path: path.to_path_buf(),
            message: message.into(),
        }
    }
}

pub type Result<T> = std::result::Result<T, StoreError>;
