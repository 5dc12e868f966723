//! A part's header as the dataset index keeps it (`PartHeader`), and parts opened
//! from it: such a part answers every question about its levels and tiles from the
//! index and maps its file only on its first tile read, checking then that the file
//! is still the one indexed.

use crate::error::{Remedy, Result, StoreError};
use crate::read::part::{BandInfo, Bytes, Level, Part, PartMeta};
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex, OnceLock};

/// What the index records of one part's headers: enough to select its tiles
/// without opening it.
#[derive(Debug, Clone, serde::Serialize, serde::Deserialize)]
pub struct PartHeader {
    pub bigtiff: bool,
    pub little_endian: bool,
    pub meta: PartMeta,
    pub bands: Vec<BandInfo>,
    /// Without their tiles' file positions (`Level`'s skipped fields).
    pub levels: Vec<Level>,
}

/// The file behind a part opened from the index, mapped on first use.
pub(crate) struct Deferred {
    /// The dataset directory, named in the hint to re-index.
    dataset: PathBuf,
    /// Size and modification time when indexed.
    expect: (u64, (i64, u32)),
    /// For a part in object storage: the object and its head's length (0:
    /// unknown). Its size is checked instead of the modification time, and its
    /// ETag pinned by the first request.
    remote: Option<(Arc<crate::remote::RemoteFile>, u64)>,
    /// The part, or why it cannot be opened. A failure that may pass (the
    /// server did not answer: [`StoreError::transient`]) is not kept: the
    /// next tile read tries again.
    opened: OnceLock<Result<Part>>,
    /// Held while opening: concurrent first reads wait for one opening. It
    /// keeps the last failure that may pass and when it came: reads that
    /// waited for that opening share its outcome rather than each asking the
    /// server again.
    opening: Mutex<Option<(std::time::Instant, StoreError)>>,
}

impl Part {
    /// The header as the dataset index records it.
    pub fn header(&self) -> PartHeader {
        PartHeader {
            bigtiff: self.bigtiff,
            little_endian: self.little_endian,
            // (Without the raw metadata items: the index does not keep them,
            // and `pcimg index` holds every part's header while it builds.)
            meta: PartMeta {
                items: Default::default(),
                ..self.meta.clone()
            },
            bands: self.bands.clone(),
            levels: self
                .levels
                .iter()
                .map(|l| Level {
                    offsets: Vec::new(),
                    counts: Vec::new(),
                    z_lut: None,
                    row_order: false,
                    ..l.clone()
                })
                .collect(),
        }
    }

    /// A part of the dataset at `dataset` described by its index entry: nothing is
    /// read until a tile is.
    pub(crate) fn from_header(
        dataset: &Path,
        path: &Path,
        (file_bytes, mtime): (u64, (i64, u32)),
        h: PartHeader,
    ) -> Part {
        let samples = h.bands.len();
        Part {
            path: path.to_path_buf(),
            file_bytes,
            bigtiff: h.bigtiff,
            little_endian: h.little_endian,
            meta: h.meta,
            bands: h.bands,
            levels: h
                .levels
                .into_iter()
                .enumerate()
                .map(|(index, l)| Level { index, ..l })
                .collect(),
            samples,
            map: Arc::new(Bytes::Owned(Vec::new())),
            lazy: Some(Arc::new(Deferred {
                dataset: dataset.to_path_buf(),
                expect: (file_bytes, mtime),
                remote: None,
                opened: OnceLock::new(),
                opening: Mutex::new(None),
            })),
            remote: None,
        }
    }

    #[cfg(feature = "remote")]
    /// A part in object storage described by its index entry: nothing is
    /// fetched until a tile is read, then its head (`head` bytes, one request).
    pub(crate) fn from_header_remote(
        dataset: &Path,
        file: Arc<crate::remote::RemoteFile>,
        (file_bytes, head): (u64, u64),
        h: PartHeader,
    ) -> Part {
        let mut p = Part::from_header(dataset, Path::new(&file.url()), (file_bytes, (0, 0)), h);
        p.lazy = Some(Arc::new(Deferred {
            dataset: dataset.to_path_buf(),
            expect: (file_bytes, (0, 0)),
            remote: Some((file, head)),
            opened: OnceLock::new(),
            opening: Mutex::new(None),
        }));
        p
    }

    /// Whether the part's file has been read (always, but for parts opened from an
    /// index before their first tile read).
    pub fn is_open(&self) -> bool {
        self.lazy.as_ref().is_none_or(|d| d.opened.get().is_some())
    }

    /// Whether `p`, read from the file, is the part the index describes.
    fn same_shape(&self, p: &Part) -> bool {
        p.file_bytes == self.file_bytes
            && p.meta.point_count == self.meta.point_count
            && p.levels.len() == self.levels.len()
            && p.bands.len() == self.bands.len()
            && p.levels
                .iter()
                .zip(&self.levels)
                .all(|(a, b)| a.tiles.len() == b.tiles.len())
    }

    /// A remote part listed in the index, opened and checked against it.
    #[cfg(feature = "remote")]
    fn open_listed_remote(
        &self,
        file: &Arc<crate::remote::RemoteFile>,
        head: u64,
        bytes: u64,
    ) -> Result<Part> {
        let p = Part::open_remote(file.clone(), head, Some(bytes))?;
        if self.same_shape(&p) {
            Ok(p)
        } else {
            Err(
                StoreError::new(&self.path, "changed since the dataset was indexed")
                    .with_remedy(Remedy::Rewrite),
            )
        }
    }

    #[cfg(not(feature = "remote"))]
    fn open_listed_remote(
        &self,
        file: &Arc<crate::remote::RemoteFile>,
        _: u64,
        _: u64,
    ) -> Result<Part> {
        match **file {}
    }

    /// For a part opened from the index: the part read from its file (opened on
    /// the first call, and checked against the index); `None` for a part opened
    /// from its file.
    pub(crate) fn opened(&self) -> Result<Option<&Part>> {
        let Some(d) = &self.lazy else {
            return Ok(None);
        };
        fn kept(r: &Result<Part>) -> Result<Option<&Part>> {
            match r {
                Ok(p) => Ok(Some(p)),
                Err(e) => Err(e.clone()),
            }
        }
        if let Some(r) = d.opened.get() {
            return kept(r);
        }
        let asked = std::time::Instant::now();
        let mut one = d.opening.lock().unwrap_or_else(|p| p.into_inner());
        if let Some(r) = d.opened.get() {
            return kept(r);
        }
        if let Some((at, e)) = &*one
            && *at >= asked
        {
            return Err(e.clone());
        }
        let r = (|| {
            if let Some((file, head)) = &d.remote {
                return self.open_listed_remote(file, *head, d.expect.0);
            }
            let reindex = Remedy::Reindex {
                dataset: d.dataset.clone(),
            };
            let fail = |m: String| StoreError::new(&self.path, m).with_remedy(reindex.clone());
            let meta = std::fs::metadata(&self.path).map_err(|e| {
                fail(format!(
                    "is listed in the dataset's index but cannot be read ({e})"
                ))
            })?;
            let now = (meta.len(), crate::dataset::index::mtime_of(&meta));
            if now != d.expect {
                return Err(fail(format!(
                    "changed since the dataset was indexed ({} bytes now, {} then; modified {})",
                    now.0,
                    d.expect.0,
                    if now.1 == d.expect.1 { "then" } else { "since" }
                )));
            }
            let p = Part::open(&self.path).map_err(|e| e.with_remedy(reindex.clone()))?;
            if self.same_shape(&p) {
                Ok(p)
            } else {
                Err(fail("changed since the dataset was indexed".into()))
            }
        })();
        match r {
            Err(e) if e.transient() => {
                *one = Some((std::time::Instant::now(), e.clone()));
                Err(e)
            }
            r => kept(d.opened.get_or_init(|| r)),
        }
    }
}
