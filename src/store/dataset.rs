//! A dataset: one part file, or a directory of part files.

use super::error::{Result, StoreError};
use super::reader::Part;
use crate::points::Bounds;
use std::path::{Path, PathBuf};

/// An opened dataset (headers only).
#[derive(Debug)]
pub struct Dataset {
    pub path: PathBuf,
    pub parts: Vec<Part>,
}

fn is_part_file(p: &Path) -> bool {
    let hidden = p
        .file_name()
        .and_then(|n| n.to_str())
        .is_some_and(|n| n.starts_with('.'));
    let ext = p
        .extension()
        .and_then(|e| e.to_str())
        .map(|e| e.to_ascii_lowercase());
    !hidden && matches!(ext.as_deref(), Some("tif" | "tiff"))
}

/// Extensions of the point clouds `pcimg convert` reads (named when one is
/// opened as a dataset).
const POINT_CLOUD_EXTENSIONS: [&str; 8] = ["las", "laz", "xyz", "txt", "csv", "asc", "pts", "ply"];

/// Whether the file begins as a TIFF does (a part renamed `.txt` is a part).
fn starts_like_tiff(path: &Path) -> bool {
    use std::io::Read;
    let mut head = [0u8; 4];
    std::fs::File::open(path)
        .and_then(|mut f| f.read_exact(&mut head))
        .is_ok_and(|()| matches!(&head, b"II*\0" | b"MM\0*" | b"II+\0" | b"MM\0+"))
}

/// `s` as one shell word (quoted when it holds anything but plain characters),
/// sanitized for the terminal.
fn shell_quoted(s: &str) -> String {
    let s = crate::text::sanitize(s);
    if s.chars()
        .all(|c| c.is_ascii_alphanumeric() || "-_./+,:@".contains(c))
    {
        s
    } else {
        format!("'{}'", s.replace('\'', "'\\''"))
    }
}

impl Dataset {
    /// Opens a `.tif` part or a directory of them (sorted by name).
    pub fn open(path: &Path) -> Result<Dataset> {
        let meta = std::fs::metadata(path)
            .map_err(|e| StoreError::new(path, format!("cannot open: {e}")))?;
        let parts = if meta.is_dir() {
            let mut files: Vec<PathBuf> = std::fs::read_dir(path)
                .map_err(|e| StoreError::new(path, format!("cannot list directory: {e}")))?
                .filter_map(|e| e.ok().map(|e| e.path()))
                .filter(|p| p.is_file() && is_part_file(p))
                .collect();
            files.sort();
            if files.is_empty() {
                return Err(StoreError::new(path, "directory holds no .tif parts"));
            }
            files
                .iter()
                .map(|f| Part::open(f))
                .collect::<Result<Vec<_>>>()?
        } else {
            let cloud = path
                .extension()
                .and_then(|e| e.to_str())
                .map(str::to_ascii_lowercase)
                .filter(|e| POINT_CLOUD_EXTENSIONS.contains(&e.as_str()));
            if let Some(ext) = cloud.filter(|_| !starts_like_tiff(path)) {
                let stem = path
                    .file_stem()
                    .map(|s| s.to_string_lossy().into_owned())
                    .unwrap_or_else(|| "cloud".into());
                return Err(StoreError::new(
                    path,
                    format!(
                        "a point cloud (.{ext}), not an image dataset: convert it first, e.g. \
                         `pcimg convert {} -o {}`",
                        shell_quoted(&path.display().to_string()),
                        shell_quoted(&format!("{stem}.pcimg"))
                    ),
                ));
            }
            vec![Part::open(path)?]
        };
        Ok(Dataset {
            path: path.to_path_buf(),
            parts,
        })
    }

    /// Union of the parts' bounds.
    pub fn bounds(&self) -> Bounds {
        self.parts
            .iter()
            .fold(Bounds::EMPTY, |b, p| b.union(&p.meta.bounds))
    }

    /// Total points over all parts.
    pub fn points(&self) -> u64 {
        self.parts.iter().map(|p| p.meta.point_count).sum()
    }

    /// Total bytes of all part files.
    pub fn bytes(&self) -> u64 {
        self.parts.iter().map(|p| p.file_bytes).sum()
    }
}
