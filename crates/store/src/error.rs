//! The store's error: always names the file, then what is wrong with it, and
//! where something would put it right, which [`Remedy`] (a fact, not a command:
//! the program that uses the store words the advice).

use std::path::{Path, PathBuf};

#[derive(Debug, Clone, thiserror::Error)]
#[error("{}: {message}", crate::text::sanitize(&.path.display().to_string()))]
pub struct StoreError {
    pub path: PathBuf,
    pub message: String,
    /// What would put it right, where the store knows (boxed: errors travel
    /// in every `Result`, and most have none).
    pub remedy: Option<Box<Remedy>>,
    /// For a request to object storage that failed: its URL and what happened
    /// (the command line says what to do from it). Shown through `message`.
    #[cfg(feature = "remote")]
    pub remote: Option<Box<crate::remote::RemoteError>>,
}

/// What would put a [`StoreError`] right.
#[derive(Debug, Clone, PartialEq, Eq)]
#[non_exhaustive]
pub enum Remedy {
    /// The dataset's index is missing, unreadable or out of date with its parts:
    /// rebuild it from the parts in `dataset` (a folder, or a URL's local copy).
    Reindex { dataset: PathBuf },
    /// `input` is a point cloud, not a dataset: convert it (to `output`, say).
    Convert { input: PathBuf, output: PathBuf },
    /// A part in object storage was replaced behind the index that pins it:
    /// write the dataset again, its index with it.
    Rewrite,
    /// The file was written by a newer version of the format.
    Upgrade,
    /// The work needs about `needed` bytes of memory, more than its budget.
    MoreMemory { needed: u64 },
}

impl StoreError {
    pub fn new(path: &Path, message: impl Into<String>) -> Self {
        StoreError {
            path: path.to_path_buf(),
            message: message.into(),
            remedy: None,
            #[cfg(feature = "remote")]
            remote: None,
        }
    }

    /// The error with what would put it right.
    pub fn with_remedy(mut self, remedy: Remedy) -> Self {
        self.remedy = Some(Box::new(remedy));
        self
    }

    /// Whether the same read may succeed later: a request to object storage
    /// that got no answer (refused, timed out, cut), a short answer, or a
    /// server failing or throttling (HTTP 5xx, 429, 408): what a viewer
    /// retries in the background. Not a missing or
    /// denied object, one replaced behind the index, nor bytes that do not
    /// decode: reading them again gives the same answer.
    pub fn transient(&self) -> bool {
        #[cfg(feature = "remote")]
        if let Some(r) = &self.remote {
            // What a request's own retries try again, and also a refused
            // connection or an unknown host: a server that is down now may be
            // back later (the request fails at once; this read waits).
            return crate::remote::transient(&r.problem)
                || matches!(&r.problem, crate::remote::Problem::Network { .. });
        }
        false
    }

    /// A failed request: the path is its URL, the message what happened.
    #[cfg(feature = "remote")]
    pub fn remote(e: crate::remote::RemoteError) -> Self {
        let remedy = matches!(e.problem, crate::remote::Problem::Replaced { .. })
            .then(|| Box::new(Remedy::Rewrite));
        StoreError {
            path: PathBuf::from(&e.url),
            message: format!(
                "{}{}",
                e.problem,
                e.gave_up.map(|g| g.to_string()).unwrap_or_default()
            ),
            remedy,
            remote: Some(Box::new(e)),
        }
    }
}

pub type Result<T> = std::result::Result<T, StoreError>;
