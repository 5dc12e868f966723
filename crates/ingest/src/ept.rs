//! EPT (Entwine Point Tile) datasets: `ept.json`, an octree whose hierarchy
//! is JSON files (`ept-hierarchy/D-X-Y-Z.json`: each node's point count, -1
//! for a node whose subtree is in a file of its own, read when a walk reaches
//! it) and one LAZ file per node (`ept-data/D-X-Y-Z.laz`), local or at a URL.
//! Nodes are decoded into the columns of a LAS input of their format
//! (`las_records`). Only `laszip` data is read (`binary` and `zstandard`
//! datasets are refused with that said).

use crate::color::ColorNormalizer;
use crate::error::IngestError;
use crate::las_records::{Fields, decode_records};
use crate::points::{Bounds, PointColumns};
use crate::{PointReader, ReadOptions, SourceInfo};
use pcimg_copc::Key;
use rayon::prelude::*;
use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};

/// Whether `path` names an EPT dataset (its `ept.json`).
pub fn is_ept(path: &Path) -> bool {
    path.file_name().is_some_and(|n| n == "ept.json")
}

/// A node: its key and point count.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Node {
    pub key: Key,
    pub points: u64,
}

#[derive(Debug, Default)]
struct Hierarchy {
    /// Point counts of the nodes known.
    counts: HashMap<Key, u64>,
    /// Nodes whose subtree is in a hierarchy file not yet read.
    pending: HashMap<Key, ()>,
    files_read: usize,
}

/// An opened EPT dataset.
#[derive(Debug)]
pub struct Ept {
    /// `ept.json`'s path or URL.
    pub name: String,
    /// Its directory (local) or URL prefix.
    base: String,
    remote: bool,
    /// The octree's cube (min, max).
    pub cube: ([f64; 3], [f64; 3]),
    /// The points' bounds (`boundsConforming`).
    pub bounds: Bounds,
    pub points: u64,
    pub srs: Option<String>,
    hierarchy: Mutex<Hierarchy>,
}

fn key_name(k: &Key) -> String {
    format!("{}-{}-{}-{}", k.d, k.x, k.y, k.z)
}

fn parse_key(s: &str) -> Option<Key> {
    let v: Vec<i32> = s
        .split('-')
        .map(|t| t.parse().ok())
        .collect::<Option<_>>()?;
    (v.len() == 4 && (0..=31).contains(&v[0])).then(|| Key {
        d: v[0],
        x: v[1],
        y: v[2],
        z: v[3],
    })
}

impl Ept {
    fn at(&self, rel: &str) -> String {
        if self.remote {
            format!("{}/{rel}", self.base)
        } else {
            Path::new(&self.base).join(rel).display().to_string()
        }
    }

    /// The bytes of the dataset's file `rel`.
    fn get(&self, rel: &str) -> Result<Vec<u8>, IngestError> {
        get(&self.at(rel))
    }

    /// Opens the EPT dataset whose `ept.json` is at `path` (local or URL).
    pub fn open(path: &Path) -> Result<Ept, IngestError> {
        let name = path.to_string_lossy().into_owned();
        let remote = crate::is_url(path);
        let text = get(&name)?;
        let bad = |what: String| IngestError::format(path, what);
        let v: serde_json::Value = serde_json::from_slice(&text)
            .map_err(|e| IngestError::format(path, format!("not JSON: {e}")))?;
        let nums = |field: &str| -> Result<Vec<f64>, IngestError> {
            v[field]
                .as_array()
                .and_then(|a| a.iter().map(|x| x.as_f64()).collect::<Option<Vec<_>>>())
                .filter(|a| a.len() == 6 && a.iter().all(|x| x.is_finite()))
                .ok_or_else(|| bad(format!("\"{field}\" is not six numbers")))
        };
        let b = nums("bounds")?;
        let c = nums("boundsConforming").unwrap_or_else(|_| b.clone());
        match v["dataType"].as_str() {
            Some("laszip") => {}
            Some(t) => {
                return Err(bad(format!(
                    "EPT data type \"{t}\": only \"laszip\" EPT datasets are read"
                )));
            }
            None => return Err(bad("no \"dataType\": not an EPT dataset".into())),
        }
        if v["hierarchyType"].as_str().unwrap_or("json") != "json" {
            return Err(bad(
                "only a JSON hierarchy (\"hierarchyType\": \"json\") is read".into(),
            ));
        }
        let base = match name.rfind('/') {
            Some(i) => name[..i].to_string(),
            None => ".".to_string(),
        };
        let ept = Ept {
            name: name.clone(),
            base,
            remote,
            cube: ([b[0], b[1], b[2]], [b[3], b[4], b[5]]),
            bounds: Bounds {
                min: [c[0], c[1], c[2]],
                max: [c[3], c[4], c[5]],
            },
            points: v["points"].as_u64().unwrap_or(0),
            srs: v["srs"]["wkt"].as_str().map(str::to_string),
            hierarchy: Mutex::new(Hierarchy::default()),
        };
        ept.read_hierarchy(&Key::ROOT)?;
        if !ept.lock().counts.contains_key(&Key::ROOT) {
            return Err(IngestError::format(
                Path::new(&ept.at("ept-hierarchy/0-0-0-0.json")),
                "no entry for the root node 0-0-0-0",
            ));
        }
        Ok(ept)
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, Hierarchy> {
        self.hierarchy.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// Reads the hierarchy file of `key`'s subtree.
    fn read_hierarchy(&self, key: &Key) -> Result<(), IngestError> {
        let rel = format!("ept-hierarchy/{}.json", key_name(key));
        let file = self.at(&rel);
        let text = self.get(&rel)?;
        let v: serde_json::Value = serde_json::from_slice(&text)
            .map_err(|e| IngestError::format(Path::new(&file), format!("not JSON: {e}")))?;
        let Some(m) = v.as_object() else {
            return Err(IngestError::format(
                Path::new(&file),
                "not a JSON object of node counts",
            ));
        };
        let mut h = self.lock();
        h.files_read += 1;
        h.pending.remove(key);
        for (k, n) in m {
            let (Some(key), Some(n)) = (parse_key(k), n.as_i64()) else {
                return Err(IngestError::format(
                    Path::new(&file),
                    format!(
                        "entry \"{}\": not a node key and a count",
                        pcimg_core::text::sanitize(k)
                    ),
                ));
            };
            match n {
                -1 => {
                    h.pending.insert(key, ());
                }
                n if n >= 0 => {
                    h.counts.insert(key, n as u64);
                }
                n => {
                    return Err(IngestError::format(
                        Path::new(&file),
                        format!("node {k}: a count of {n}"),
                    ));
                }
            }
        }
        Ok(())
    }

    /// The root node.
    pub fn root(&self) -> Node {
        Node {
            key: Key::ROOT,
            points: self.lock().counts.get(&Key::ROOT).copied().unwrap_or(0),
        }
    }

    /// Node `key`'s cube.
    pub fn cube_of(&self, key: &Key) -> ([f64; 3], [f64; 3]) {
        let (lo, hi) = self.cube;
        let n = f64::from(1u32 << key.d.clamp(0, 31) as u32);
        let at = [key.x, key.y, key.z];
        let min: [f64; 3] = std::array::from_fn(|a| lo[a] + (hi[a] - lo[a]) / n * f64::from(at[a]));
        (min, std::array::from_fn(|a| min[a] + (hi[a] - lo[a]) / n))
    }

    /// The children of `key` that exist (reading their hierarchy files first
    /// where they have their own).
    pub fn children(&self, key: &Key) -> Result<Vec<Node>, IngestError> {
        let kids = key.children();
        let pending: Vec<Key> = {
            let h = self.lock();
            kids.iter()
                .filter(|k| h.pending.contains_key(k))
                .copied()
                .collect()
        };
        for k in pending {
            self.read_hierarchy(&k)?;
        }
        let h = self.lock();
        Ok(kids
            .iter()
            .filter_map(|k| h.counts.get(k).map(|&n| Node { key: *k, points: n }))
            .collect())
    }

    /// Node `key`, if a hierarchy file read so far counts it.
    pub fn known(&self, key: &Key) -> Option<Node> {
        self.lock().counts.get(key).map(|&n| Node {
            key: *key,
            points: n,
        })
    }

    /// The children of `key` in the hierarchy files read so far.
    pub fn known_children(&self, key: &Key) -> Vec<Node> {
        let h = self.lock();
        key.children()
            .iter()
            .filter_map(|k| h.counts.get(k).map(|&n| Node { key: *k, points: n }))
            .collect()
    }

    /// Every node whose cube `keep` accepts (and its ancestors' cubes).
    pub fn nodes_where(
        &self,
        keep: &dyn Fn(&pcimg_copc::Cube) -> bool,
    ) -> Result<Vec<Node>, IngestError> {
        let mut out = Vec::new();
        let mut todo = vec![self.root()];
        while let Some(n) = todo.pop() {
            if !keep(&self.cube_of(&n.key)) {
                continue;
            }
            out.push(n);
            todo.extend(self.children(&n.key)?);
        }
        out.sort_by_key(|n| (n.key.d, n.key.x, n.key.y, n.key.z));
        Ok(out)
    }

    /// Hierarchy files read, and known but not read.
    pub fn hierarchy_files(&self) -> (usize, usize) {
        let h = self.lock();
        (h.files_read, h.pending.len())
    }

    /// Node `n`'s LAZ file: its bytes, checked against the hierarchy's count.
    fn node_las(&self, n: &Node) -> Result<(las::Header, Vec<u8>, PathBuf), IngestError> {
        let rel = format!("ept-data/{}.laz", key_name(&n.key));
        let path = PathBuf::from(self.at(&rel));
        let bytes = self.get(&rel)?;
        let (header, records) = crate::contain::contain(|| -> Result<_, las::Error> {
            let mut r = las::Reader::new(std::io::Cursor::new(bytes))?;
            let pd = r.read_all()?;
            Ok((r.header().clone(), pd.raw_bytes().to_vec()))
        })
        .ok_or_else(|| IngestError::format(&path, "the LAZ decoder failed on corrupt data"))?
        .map_err(|e| IngestError::format(&path, format!("cannot read the LAZ file: {e}")))?;
        let held = header.number_of_points();
        if held != n.points {
            return Err(IngestError::format(
                &path,
                format!(
                    "holds {held} points, the hierarchy says {} for node {}",
                    n.points,
                    key_name(&n.key)
                ),
            ));
        }
        Ok((header, records, path))
    }

    /// Node `n`'s points as columns (GPS time relative to `gps_offset`).
    pub fn read(&self, n: &Node, gps_offset: f64) -> Result<PointColumns, IngestError> {
        if n.points == 0 {
            return Ok(PointColumns::default());
        }
        let (header, records, path) = self.node_las(n)?;
        let format = *header.point_format();
        let stride = usize::from(format.len());
        let fields = Fields::new(&path, &format, stride, &header)?;
        let names = super::las::attribute_names(&format);
        Ok(decode_records(&records, &fields, gps_offset, &names))
    }

    /// The attribute columns of its points (the root node's format) and the
    /// offset GPS time is kept relative to (the median of the root's first).
    pub fn probe(&self) -> Result<(Vec<String>, f64), IngestError> {
        let (names, offset, _) = self.probe_lattice()?;
        Ok((names, offset))
    }

    /// As [`Ept::probe`], with the LAS lattice of its nodes' coordinates.
    pub fn probe_lattice(&self) -> Result<(Vec<String>, f64, crate::points::Lattice), IngestError> {
        let (header, records, path) = self.node_las(&self.root())?;
        let format = *header.point_format();
        let fields = Fields::new(&path, &format, usize::from(format.len()), &header)?;
        let mut t: Vec<f64> = records
            .chunks_exact(fields.stride)
            .take(crate::OFFSET_SAMPLE)
            .filter_map(|r| crate::las_records::gps_of(r, &fields))
            .collect();
        let offset = if t.is_empty() {
            0.0
        } else {
            crate::attribute_offset(&mut t, true)
        };
        let t = header.transforms();
        let lattice = crate::points::Lattice {
            step: [t.x.scale, t.y.scale, t.z.scale],
            origin: [t.x.offset, t.y.offset, t.z.offset],
        };
        Ok((super::las::attribute_names(&format), offset, lattice))
    }
}

/// The bytes of the file or URL `at`.
fn get(at: &str) -> Result<Vec<u8>, IngestError> {
    crate::read_whole(Path::new(at))
}

/// An EPT dataset's points in a region (all without one).
pub struct EptReader {
    ept: Arc<Ept>,
    nodes: Vec<Node>,
    next: usize,
    names: Vec<String>,
    info: SourceInfo,
    colors: ColorNormalizer,
    region: Option<Bounds>,
    chunk: u64,
    done: u64,
    gps_offset: f64,
}

/// Opens the EPT dataset at `path` for reading the points in `opts.region`.
pub fn open(path: &Path, opts: &ReadOptions) -> Result<EptReader, IngestError> {
    let ept = Arc::new(Ept::open(path)?);
    let region = opts.region;
    let nodes: Vec<Node> = ept
        .nodes_where(&|c| region.is_none_or(|r| r.intersects(&Bounds { min: c.0, max: c.1 })))?
        .into_iter()
        .filter(|n| n.points > 0)
        .collect();
    let (names, gps_offset, lattice) = ept.probe_lattice()?;
    let total: u64 = nodes.iter().map(|n| n.points).sum();
    let info = SourceInfo {
        path: path.to_path_buf(),
        format: "ept".into(),
        declared_points: region.is_none().then_some(ept.points),
        declared_bounds: Some(ept.bounds),
        crs_wkt: ept.srs.clone(),
        attribute_names: names.clone(),
        file_bytes: total,
        notes: region
            .map(|_| {
                format!(
                    "EPT: read the {} octree nodes that reach the region",
                    nodes.len()
                )
            })
            .into_iter()
            .collect(),
        metadata: Vec::new(),
        coordinate_step: Some(lattice.step.map(f64::abs)),
        coordinate_lattice: Some(lattice),
    };
    Ok(EptReader {
        ept,
        nodes,
        next: 0,
        names,
        info,
        colors: ColorNormalizer::new(false),
        region,
        chunk: opts.chunk_points.max(1) as u64,
        done: 0,
        gps_offset,
    })
}

impl PointReader for EptReader {
    fn info(&self) -> &SourceInfo {
        &self.info
    }

    fn next_chunk(&mut self) -> Result<Option<PointColumns>, IngestError> {
        if self.next >= self.nodes.len() {
            return Ok(None);
        }
        let (end, points) = super::copc::batch(self.next, self.nodes.len(), self.chunk, |i| {
            self.nodes[i].points
        });
        let (ept, g) = (&self.ept, self.gps_offset);
        let parts: Vec<PointColumns> = self.nodes[self.next..end]
            .par_iter()
            .map(|n| ept.read(n, g))
            .collect::<Result<_, _>>()?;
        self.next = end;
        self.done += points;
        let mut cols = PointColumns::default();
        for p in parts {
            if p.attributes.len() != self.names.len() {
                return Err(IngestError::format(
                    &self.info.path,
                    "its nodes' LAZ files differ in point format",
                ));
            }
            if cols.x.is_empty() && cols.attributes.is_empty() {
                cols = p;
            } else {
                cols.append(&p)
                    .map_err(|e| IngestError::format(&self.info.path, e))?;
            }
        }
        if let Some(r) = &self.region {
            super::copc::keep_inside(&mut cols, r);
        }
        self.colors.apply(&mut cols);
        Ok(Some(cols))
    }

    fn bytes_done(&self) -> u64 {
        self.done
    }

    fn skipped(&self) -> u64 {
        0
    }
}
