//! E57 point clouds (ASTM E2807): every scan of the file, one after the other,
//! each in the file's frame (its pose applied). The `e57` crate reads the
//! header and the XML section; the points are decoded here (`records.rs`).
//!
//! * Coordinates: cartesian, or spherical converted to cartesian; scaled
//!   integers, floats and doubles alike. Scaled integers in one frame (no scan
//!   turned by its pose) are the input's lattice ([`scan::lattice`]), which
//!   the store keeps exactly. Points whose `cartesianInvalidState` /
//!   `sphericalInvalidState` is not 0 are left out and counted
//!   ([`PointReader::left_out`]).
//! * Bands: `intensity` (normalised to 0–1 by the scan's `intensityLimits`, or
//!   its type's range), `red green blue` (0–255, by `colorLimits`), `row`,
//!   `column`, `return_number` (E57's return index + 1), `number_of_returns`,
//!   `time`, each where any scan has it (0 in scans without it), and `scan` (the
//!   scan's index) when there are several.
//! * The scans' names, point counts and poses go into the part's metadata
//!   (`SCANS`); embedded images are skipped, and the summary says so.
//! * Out of core: a thread of its own decodes scan by scan, packet by packet,
//!   into chunks of [`ReadOptions::chunk_points`] and hands them over one at a
//!   time; the file is read through its memory map, the pages behind the reader
//!   released. Page checksums use the `crc32c` crate (SSE 4.2).
//! * Errors (a bad page checksum, a truncated file, a malformed XML section) name
//!   the file and the byte offset of the last read.

mod map;
mod records;
mod scan;

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::mpsc::{Receiver, SyncSender, sync_channel};

use self::map::MapCursor;
use self::scan::{Layout, Point, Scan};
use super::error::IngestError;
use super::{PointReader, ReadOptions, SourceInfo};
use crate::points::{Attribute, PointColumns};
use e57::{E57Reader, PointCloud};

/// What the decoding thread and the reader share.
struct Shared {
    path: PathBuf,
    last_read: Arc<AtomicU64>,
    records_done: AtomicU64,
    left_out: AtomicU64,
}

impl Shared {
    /// The `e57` crate panicked (contained): the data is corrupt.
    fn corrupt(&self) -> IngestError {
        IngestError::binary(
            &self.path,
            self.last_read.load(Ordering::Relaxed),
            "E57: the decoder failed on corrupt data",
        )
    }

    fn error(&self, e: e57::Error) -> IngestError {
        IngestError::binary(
            &self.path,
            self.last_read.load(Ordering::Relaxed),
            format!("E57: {}", pcimg_core::text::sanitize(&e.to_string())),
        )
    }
}

type Chunk = Result<PointColumns, IngestError>;

enum State {
    /// Opened, no point read yet (a reader opened for its header starts no thread).
    Ready(Arc<memmap2::Mmap>),
    Running {
        rx: Receiver<Chunk>,
        thread: Option<std::thread::JoinHandle<()>>,
    },
    Done,
}

/// The reader of one E57 file.
pub(crate) struct E57Input {
    info: SourceInfo,
    scans: Vec<PointCloud>,
    layout: Layout,
    records: u64,
    chunk_points: usize,
    shared: Arc<Shared>,
    state: State,
}

/// Opens an E57 file: its header and XML section (no points yet).
pub fn open(path: &Path, opts: &ReadOptions) -> Result<Box<dyn PointReader>, IngestError> {
    let map = Arc::new(super::map_file(path)?);
    let cursor = MapCursor::new(map.clone());
    let shared = Arc::new(Shared {
        path: path.to_path_buf(),
        last_read: cursor.last_read.clone(),
        records_done: AtomicU64::new(0),
        left_out: AtomicU64::new(0),
    });
    // (The crate may panic on corrupt data: that is an error like any other.)
    let reader = super::contain::contain(|| E57Reader::new(cursor))
        .ok_or_else(|| shared.corrupt())?
        .map_err(|e| shared.error(e))?;
    let scans = reader.pointclouds();
    for (i, pc) in scans.iter().enumerate() {
        if !Scan::new(pc, i).has_coordinates() {
            return Err(IngestError::format(
                path,
                format!("E57 scan {i} has neither cartesian nor spherical coordinates"),
            ));
        }
    }
    let layout = Layout::of(&scans);
    // Scaled-integer coordinates in one frame: the lattice they lie on.
    let lattice = scan::lattice(&scans);
    let records = scans.iter().map(|s| s.records).sum();
    let mut notes = Vec::new();
    let images = reader.images().len();
    if images > 0 {
        notes.push(format!(
            "{images} embedded image(s) skipped (pcimg stores the points only)"
        ));
    }
    let info = SourceInfo {
        path: path.to_path_buf(),
        format: format!(
            "e57 ({} scan{})",
            scans.len(),
            if scans.len() == 1 { "" } else { "s" }
        ),
        declared_points: Some(records),
        declared_bounds: None,
        crs_wkt: reader
            .coordinate_metadata()
            .map(|c| c.trim().to_string())
            .filter(|c| !c.is_empty()),
        attribute_names: layout.names.clone(),
        file_bytes: map.len() as u64,
        notes,
        metadata: vec![(crate::points::key::SCANS.to_string(), scans_json(&scans))],
        coordinate_step: lattice.map(|l| l.step),
        coordinate_lattice: lattice,
    };
    Ok(Box::new(E57Input {
        info,
        scans,
        layout,
        records,
        chunk_points: opts.chunk_points.max(1),
        shared,
        state: State::Ready(map),
    }))
}

/// The scans for the part's metadata (`SCANS`).
fn scans_json(scans: &[PointCloud]) -> String {
    let list: Vec<serde_json::Value> = scans
        .iter()
        .enumerate()
        .map(|(i, pc)| {
            let (rotation, translation) = match &pc.transform {
                Some(t) => (
                    [t.rotation.w, t.rotation.x, t.rotation.y, t.rotation.z],
                    [t.translation.x, t.translation.y, t.translation.z],
                ),
                None => ([1.0, 0.0, 0.0, 0.0], [0.0; 3]),
            };
            serde_json::json!({
                "scan": i,
                "name": pc.name,
                "guid": pc.guid,
                "points": pc.records,
                "rotation": rotation,
                "translation": translation,
            })
        })
        .collect();
    serde_json::Value::Array(list).to_string()
}

/// Empty columns for up to `n` points.
fn empty(layout: &Layout, n: usize) -> PointColumns {
    PointColumns {
        x: Vec::with_capacity(n),
        y: Vec::with_capacity(n),
        z: Vec::with_capacity(n),
        attributes: layout
            .names
            .iter()
            .map(|name| Attribute::new(name.clone(), Vec::with_capacity(n)))
            .collect(),
    }
}

/// The decoding thread: every scan, chunk by chunk, into `tx`.
fn decode(
    map: Arc<memmap2::Mmap>,
    scans: Vec<PointCloud>,
    layout: Layout,
    chunk: usize,
    shared: Arc<Shared>,
    tx: SyncSender<Chunk>,
) {
    let mut cols = empty(&layout, chunk);
    let mut attrs = vec![0.0; layout.names.len()];
    let mut released = 0;
    let run = || -> Result<bool, IngestError> {
        let fault = |f: records::Fault| {
            IngestError::binary(&shared.path, f.offset, format!("E57: {}", f.message))
        };
        for (i, pc) in scans.iter().enumerate() {
            let scan = Scan::new(pc, i);
            let mut values = vec![0.0; pc.prototype.len()];
            let mut rec = records::Records::new(&map, pc).map_err(fault)?;
            let before = shared.records_done.load(Ordering::Relaxed);
            let mut done = 0;
            loop {
                let ready = rec.fill().map_err(fault)?;
                if ready == 0 {
                    break;
                }
                let mut left_out = 0;
                for k in 0..ready {
                    rec.values(k, &mut values);
                    match scan.point(&values, &layout, &mut attrs) {
                        Point::Valid(p) => {
                            cols.x.push(p[0]);
                            cols.y.push(p[1]);
                            cols.z.push(p[2]);
                            for (a, v) in cols.attributes.iter_mut().zip(&attrs) {
                                a.values.push(*v as f32);
                            }
                        }
                        Point::Invalid => left_out += 1,
                    }
                    if cols.len() >= chunk {
                        let full = std::mem::replace(&mut cols, empty(&layout, chunk));
                        if tx.send(Ok(full)).is_err() {
                            return Ok(false);
                        }
                    }
                }
                rec.take();
                done += ready as u64;
                shared.records_done.store(before + done, Ordering::Relaxed);
                shared.left_out.fetch_add(left_out, Ordering::Relaxed);
                let at = rec.offset();
                shared.last_read.store(at, Ordering::Relaxed);
                let upto = (at as usize).saturating_sub(map::KEEP);
                super::release_consumed(&map, &mut released, upto);
            }
        }
        Ok(true)
    };
    match super::contain::contain(run).unwrap_or_else(|| Err(shared.corrupt())) {
        Ok(true) => {
            if !cols.is_empty() {
                let _ = tx.send(Ok(cols));
            }
        }
        Ok(false) => {}
        Err(e) => {
            let _ = tx.send(Err(e));
        }
    }
}

impl E57Input {
    fn start(&mut self) -> Result<(), IngestError> {
        if !matches!(self.state, State::Ready(_)) {
            return Ok(());
        }
        let State::Ready(map) = std::mem::replace(&mut self.state, State::Done) else {
            return Ok(());
        };
        let (tx, rx) = sync_channel(1);
        let (scans, layout, chunk, shared) = (
            self.scans.clone(),
            self.layout.clone(),
            self.chunk_points,
            self.shared.clone(),
        );
        let thread = std::thread::Builder::new()
            .name("e57".into())
            .spawn(move || decode(map, scans, layout, chunk, shared, tx))
            .map_err(|e| IngestError::io(&self.info.path, "cannot start the E57 decoder", e))?;
        self.state = State::Running {
            rx,
            thread: Some(thread),
        };
        Ok(())
    }
}

impl PointReader for E57Input {
    fn info(&self) -> &SourceInfo {
        &self.info
    }

    fn next_chunk(&mut self) -> Result<Option<PointColumns>, IngestError> {
        self.start()?;
        let State::Running { rx, .. } = &self.state else {
            return Ok(None);
        };
        match rx.recv() {
            Ok(Ok(c)) => Ok(Some(c)),
            Ok(Err(e)) => {
                self.state = State::Done;
                Err(e)
            }
            Err(_) => {
                // The thread hung up: at the end, or because it panicked.
                let state = std::mem::replace(&mut self.state, State::Done);
                if let State::Running {
                    thread: Some(t), ..
                } = state
                    && t.join().is_err()
                {
                    return Err(self.shared.corrupt());
                }
                Ok(None)
            }
        }
    }

    fn bytes_done(&self) -> u64 {
        let done = self.shared.records_done.load(Ordering::Relaxed);
        if matches!(self.state, State::Done) || done >= self.records {
            return self.info.file_bytes;
        }
        (self.info.file_bytes as f64 * done as f64 / self.records.max(1) as f64) as u64
    }

    fn skipped(&self) -> u64 {
        0
    }

    fn left_out(&self) -> u64 {
        self.shared.left_out.load(Ordering::Relaxed)
    }
}

impl Drop for E57Input {
    fn drop(&mut self) {
        if let State::Running { rx, thread } = std::mem::replace(&mut self.state, State::Done) {
            // The thread stops at its next send.
            drop(rx);
            if let Some(t) = thread {
                let _ = t.join();
            }
        }
    }
}
