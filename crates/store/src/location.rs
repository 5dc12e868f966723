//! Where a dataset is: a local path, a `file://` URL (read as a local path), or an
//! object-store URL (read through the `remote` feature).

/// Whether `s` names an object-store URL rather than a local path.
pub fn is_url(s: &str) -> bool {
    const SCHEMES: [&str; 8] = [
        "s3://", "s3a://", "gs://", "az://", "abfs://", "abfss://", "http://", "https://",
    ];
    let lower = s.to_ascii_lowercase();
    SCHEMES.iter().any(|p| lower.starts_with(p))
}

/// A `file://` URL's local path (read as any local dataset: memory-mapped).
pub fn file_url_path(s: &str) -> Option<std::path::PathBuf> {
    let u = url::Url::parse(s).ok()?;
    (u.scheme() == "file")
        .then(|| u.to_file_path().ok())
        .flatten()
}
