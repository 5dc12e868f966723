//! `pcimg info`: a dataset's parts, bands, levels, bounds and metadata, for people
//! or (with `--json`) as stable JSON for scripts.

use crate::points::{Bounds, Lattice};
use crate::store::level_codec_name;
use crate::store::{Dataset, Part};
use crate::text::{bytes, count, sanitize};
use serde::Serialize;
use std::path::PathBuf;

#[derive(Debug, clap::Args)]
pub struct Args {
    /// A part (.tif) or a directory of parts; or a COPC file (.copc.laz), an
    /// EPT dataset (its ept.json) or a survey of COPC files (its directory or
    /// pcimg-survey.json, made by `pcimg index`), local or at a URL (s3://,
    /// https://, ...), described without converting it.
    pub path: PathBuf,
    /// Print JSON (stable field names) instead of text.
    #[arg(long)]
    pub json: bool,
    /// Also list every tile of every level with its points and bounds.
    #[arg(long)]
    pub tiles: bool,
    /// List every part even when the dataset's index is paged (a dataset of
    /// many parts: every page of the index is read). Without it such a
    /// dataset is summed up from the index's root alone.
    #[arg(long)]
    pub parts: bool,
    #[command(flatten)]
    pub cache: super::remote::CacheArgs,
}

#[derive(Debug, Serialize)]
pub struct DatasetReport {
    pub path: String,
    pub points: u64,
    pub bytes: u64,
    pub bounds: Bounds,
    /// Bytes of the index the dataset was opened from (`null`: opened without one).
    pub index_bytes: Option<u64>,
    /// The overview's layers above the parts, lowest first (empty without one).
    pub overview: Vec<LayerReport>,
    /// Parts in the dataset.
    pub part_count: usize,
    /// Pages of the index (1: every entry in its root; `null`: no index).
    pub index_pages: Option<usize>,
    /// The parts, every one; empty for a paged index unless `--parts`.
    pub parts: Vec<PartReport>,
}

/// One layer of overview nodes.
#[derive(Debug, Serialize)]
pub struct LayerReport {
    /// 1 just above the parts.
    pub layer: u32,
    pub nodes: usize,
    /// Points of the nodes' coarsest levels (what a view of the layer draws).
    pub points: u64,
    /// Points and bytes stored in the nodes, all levels.
    pub stored_points: u64,
    pub bytes: u64,
}

#[derive(Debug, Serialize)]
pub struct PartReport {
    pub path: String,
    pub points: u64,
    pub bytes: u64,
    pub bigtiff: bool,
    pub format_version: u32,
    pub origin: [f64; 3],
    pub bounds: Bounds,
    pub layout: String,
    pub source: Option<String>,
    pub crs: Option<String>,
    pub max_quantization_error: Option<f64>,
    /// The source's lattice, where the part keeps its coordinates on it exactly.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub lattice: Option<Lattice>,
    /// The coordinates were rounded onto `lattice` (`--precision`), not found on
    /// it: within `max_quantization_error` of the source.
    #[serde(skip_serializing_if = "std::ops::Not::not")]
    pub lattice_rounded: bool,
    /// Points per classification code, as recorded when the part was written.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub class_counts: Vec<(u8, u64)>,
    /// What the source says of itself: `VIEWPOINT` (PCD), `SCANS` (E57, JSON).
    #[serde(skip_serializing_if = "std::collections::BTreeMap::is_empty")]
    pub from_source: std::collections::BTreeMap<String, String>,
    pub bands: Vec<BandReport>,
    pub levels: Vec<LevelReport>,
}

#[derive(Debug, Serialize)]
pub struct BandReport {
    pub name: String,
    pub data_type: &'static str,
    pub offset: f64,
    /// Smallest and largest value in source units, when the part records them.
    pub range: Option<[f64; 2]>,
}

#[derive(Debug, Serialize)]
pub struct LevelReport {
    pub level: usize,
    pub width: u32,
    pub height: u32,
    pub tile_width: u32,
    pub tile_height: u32,
    pub tiles: u32,
    pub tiles_with_data: usize,
    pub points: Option<u64>,
    pub bytes: u64,
    pub compression: String,
    pub tile_index: bool,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub tile_list: Option<Vec<TileReport>>,
}

#[derive(Debug, Serialize)]
pub struct TileReport {
    pub index: u32,
    pub points: Option<u32>,
    pub bounds: Bounds,
}

fn part_report(p: &Part, tiles: bool) -> PartReport {
    PartReport {
        path: p.path.display().to_string(),
        points: p.meta.point_count,
        bytes: p.file_bytes,
        bigtiff: p.bigtiff,
        format_version: p.meta.format_version,
        origin: p.meta.origin,
        bounds: p.meta.bounds,
        layout: p.meta.layout.clone(),
        source: p.meta.source.clone(),
        crs: p.meta.crs.clone(),
        max_quantization_error: p.meta.max_quantization_error,
        lattice: p.meta.lattice,
        lattice_rounded: p.meta.lattice_rounded,
        class_counts: p.meta.class_counts.clone(),
        from_source: p.meta.from_source.iter().cloned().collect(),
        bands: p
            .bands
            .iter()
            .map(|b| BandReport {
                name: b.name.clone(),
                data_type: "Float32",
                offset: b.offset,
                range: b.range.map(|(lo, hi)| [lo, hi]),
            })
            .collect(),
        levels: p
            .levels
            .iter()
            .map(|l| LevelReport {
                level: l.index,
                width: l.width,
                height: l.height,
                tile_width: l.tile_width,
                tile_height: l.tile_height,
                tiles: l.tiles_across * l.tiles_down,
                tiles_with_data: l.tiles.len(),
                points: l.points,
                bytes: l.bytes,
                compression: level_codec_name(l.compression, l.lerc_extra),
                tile_index: l.indexed,
                tile_list: tiles.then(|| {
                    l.tiles
                        .iter()
                        .map(|t| TileReport {
                            index: t.index,
                            points: t.points,
                            bounds: t.bounds,
                        })
                        .collect()
                }),
            })
            .collect(),
    }
}

/// The report for a dataset.
/// Every part is listed when the index is one page; a paged one's are not.
pub fn report(ds: &Dataset, tiles: bool) -> DatasetReport {
    let listed = if ds.index_pages().0 <= 1 {
        ds.parts().unwrap_or_default()
    } else {
        Vec::new()
    };
    report_of(ds, tiles, &listed)
}

/// The report listing `parts`.
pub fn report_of(ds: &Dataset, tiles: bool, parts: &[&Part]) -> DatasetReport {
    DatasetReport {
        path: ds.path.display().to_string(),
        points: ds.points(),
        bytes: ds.bytes(),
        bounds: ds.bounds(),
        index_bytes: ds.index_bytes,
        overview: overview_report(ds),
        part_count: ds.part_count(),
        index_pages: ds.index_bytes.map(|_| ds.index_pages().0),
        parts: parts.iter().map(|p| part_report(p, tiles)).collect(),
    }
}

fn overview_report(ds: &Dataset) -> Vec<LayerReport> {
    (1..=ds.layer_count())
        .map(|layer| {
            let s = ds.layer_summary(layer);
            LayerReport {
                layer,
                nodes: s.nodes,
                points: s.points,
                stored_points: s.stored_points,
                bytes: s.bytes,
            }
        })
        .collect()
}

fn xyz(v: [f64; 3]) -> String {
    format!("({:.3}, {:.3}, {:.3})", v[0], v[1], v[2])
}

/// The report as text for a terminal (every string from the file sanitized).
pub fn render_text(r: &DatasetReport) -> String {
    use std::fmt::Write;
    let mut o = String::new();
    let _ = writeln!(
        o,
        "dataset  {}\n         {} part(s), {} points, {}",
        sanitize(&r.path),
        r.part_count,
        count(r.points),
        bytes(r.bytes)
    );
    let _ = writeln!(
        o,
        "bounds   min {}\n         max {}",
        xyz(r.bounds.min),
        xyz(r.bounds.max)
    );
    let _ = match r.index_bytes {
        Some(b) => match r.index_pages {
            Some(pages) if pages > 1 => writeln!(
                o,
                "index    {} ({}) and {} more pages, read as a view reaches them",
                crate::store::dataset::index::INDEX_FILE,
                bytes(b),
                pages - 1
            ),
            _ => writeln!(
                o,
                "index    {} ({}): opened without reading the parts' headers",
                crate::store::dataset::index::INDEX_FILE,
                bytes(b)
            ),
        },
        None if r.part_count > 1 => writeln!(o, "index    none (`pcimg index` makes one)"),
        None => Ok(()),
    };
    if !r.overview.is_empty() {
        let _ = writeln!(
            o,
            "overview {} layer(s) above the parts' levels\n    layer  nodes   points drawn   points stored  bytes",
            r.overview.len()
        );
        for l in r.overview.iter().rev() {
            let _ = writeln!(
                o,
                "    {:<5}  {:>5}  {:>13}  {:>14}  {}",
                l.layer,
                l.nodes,
                count(l.points),
                count(l.stored_points),
                bytes(l.bytes)
            );
        }
    }
    if r.parts.is_empty() && r.part_count > 0 {
        let _ = writeln!(
            o,
            "\n(the parts are not listed: `pcimg info --parts` lists all {}, reading every page of the index)",
            count(r.part_count as u64)
        );
    }
    for (i, p) in r.parts.iter().enumerate() {
        let _ = writeln!(
            o,
            "\npart {}/{}  {}",
            i + 1,
            r.part_count,
            sanitize(&p.path)
        );
        let _ = writeln!(
            o,
            "  points   {}   file {} ({})   format v{}   layout {}",
            count(p.points),
            bytes(p.bytes),
            if p.bigtiff { "BigTIFF" } else { "classic TIFF" },
            p.format_version,
            sanitize(&p.layout)
        );
        let _ = writeln!(o, "  origin   {}", xyz(p.origin));
        let _ = writeln!(
            o,
            "  bounds   min {}\n           max {}",
            xyz(p.bounds.min),
            xyz(p.bounds.max)
        );
        let steps = |l: &Lattice| {
            let unit = crate::store::crs::unit_symbol(p.crs.as_deref());
            l.step
                .iter()
                .map(|s| format!("{} {unit}", s.abs()).trim_end().to_string())
                .collect::<Vec<_>>()
                .join(", ")
        };
        let within = |e: f64| crate::store::crs::distance(e, p.crs.as_deref());
        if let (Some(l), true) = (&p.lattice, p.lattice_rounded) {
            let _ = writeln!(
                o,
                "  stored coordinates rounded onto a lattice (steps {}; convert --precision){}",
                steps(l),
                p.max_quantization_error
                    .map(|e| format!(", within {} of the source", within(e)))
                    .unwrap_or_default()
            );
        } else if let Some(l) = &p.lattice {
            let _ = writeln!(
                o,
                "  stored coordinates exactly on the source's lattice (steps {}){}",
                steps(l),
                p.max_quantization_error
                    .map(|e| format!(
                        "; read as 32-bit floats (drawing, picking) within {}",
                        within(e)
                    ))
                    .unwrap_or_default()
            );
        } else if let Some(e) = p.max_quantization_error {
            let _ = writeln!(
                o,
                "  stored coordinates within {} of the source",
                crate::store::crs::distance(e, p.crs.as_deref())
            );
        }
        let _ = writeln!(
            o,
            "  source   {}",
            p.source
                .as_deref()
                .map(sanitize)
                .unwrap_or_else(|| "-".into())
        );
        let crs = p.crs.as_deref().map(sanitize).unwrap_or_else(|| "-".into());
        let crs = if crs.chars().count() > 100 {
            format!("{}…", crs.chars().take(100).collect::<String>())
        } else {
            crs
        };
        let _ = writeln!(o, "  crs      {crs}");
        if !p.class_counts.is_empty() {
            let classes: Vec<String> = p
                .class_counts
                .iter()
                .map(|&(c, n)| format!("{c} {} {}", crate::render::classes::name(c), count(n)))
                .collect();
            let _ = writeln!(o, "  classes  {}", classes.join(" · "));
        }
        for (k, v) in &p.from_source {
            source_lines(&mut o, k, v);
        }
        let _ = writeln!(o, "  bands    {}", p.bands.len());
        for (b, band) in p.bands.iter().enumerate() {
            // A coordinate on a lattice at the step's decimals (636001.73, not
            // the f64 sum's 636001.7300000001).
            let places = p.lattice.filter(|_| b < 3).and_then(|l| l.decimals(b));
            let mut off = match (band.range, places) {
                (Some([lo, hi]), Some(d)) => format!("  range {lo:.d$} .. {hi:.d$}"),
                (Some([lo, hi]), None) => format!("  range {lo} .. {hi}"),
                (None, _) => String::new(),
            };
            if band.offset != 0.0 {
                off.push_str(&format!("  offset {}", band.offset));
            }
            if crate::time::is_exact_band(&band.name) {
                off.push_str("  (with gps_time: the time bit for bit)");
            }
            let _ = writeln!(
                o,
                "    {:>2}  {:<18} {}{}",
                b + 1,
                sanitize(&band.name),
                band.data_type,
                off
            );
        }
        let _ = writeln!(
            o,
            "  levels   {}\n    level  size          tiles        points        bytes        compression  tile index",
            p.levels.len()
        );
        for l in &p.levels {
            let _ = writeln!(
                o,
                "    {:<5}  {:<12}  {:<11}  {:>12}  {:>11}  {:<11}  {}",
                l.level,
                format!("{}×{}", l.width, l.height),
                format!("{}/{}", l.tiles_with_data, l.tiles),
                l.points.map(count).unwrap_or_else(|| "?".into()),
                bytes(l.bytes),
                l.compression,
                if l.tile_index { "yes" } else { "no" }
            );
            if let Some(tiles) = &l.tile_list {
                for t in tiles {
                    let _ = writeln!(
                        o,
                        "           tile {:<6} {:>8} points  min {} max {}",
                        t.index,
                        t.points
                            .map(|n| count(n as u64))
                            .unwrap_or_else(|| "?".into()),
                        xyz(t.bounds.min),
                        xyz(t.bounds.max)
                    );
                }
            }
        }
    }
    o
}

/// A `from_source` item as lines: E57 scans one a line, others as they are.
fn source_lines(o: &mut String, key: &str, value: &str) {
    use std::fmt::Write;
    let scans: Option<Vec<serde_json::Value>> = (key == crate::store::spec::key::SCANS)
        .then(|| serde_json::from_str(value).ok())
        .flatten();
    let Some(scans) = scans else {
        let _ = writeln!(
            o,
            "  {:<8} {}",
            sanitize(&key.to_ascii_lowercase()),
            sanitize(value)
        );
        return;
    };
    let _ = writeln!(o, "  scans    {}", scans.len());
    for s in &scans {
        let num = |k: &str| {
            s[k].as_array()
                .map(|a| a.iter().filter_map(|v| v.as_f64()).collect::<Vec<_>>())
                .unwrap_or_default()
        };
        let list = |v: Vec<f64>| {
            v.iter()
                .map(|c| format!("{c}"))
                .collect::<Vec<_>>()
                .join(", ")
        };
        let _ = writeln!(
            o,
            "    {:>3}  {:<24} {:>12} points  rotation (w x y z) ({})  translation ({})",
            s["scan"].as_u64().unwrap_or(0),
            sanitize(s["name"].as_str().unwrap_or("-")),
            count(s["points"].as_u64().unwrap_or(0)),
            list(num("rotation")),
            list(num("translation"))
        );
    }
}

/// What `info` says of a COPC file: its header and the octree's levels as
/// far as the hierarchy pages read (the root page: `--tiles` reads them all).
#[derive(Debug, Serialize)]
pub struct CopcReport {
    pub path: String,
    pub format: &'static str,
    pub points: u64,
    pub bytes: u64,
    pub bounds: Bounds,
    pub point_format: u8,
    pub record_bytes: u16,
    pub crs: Option<String>,
    pub attributes: Vec<String>,
    /// The octree's cube: centre and half its side; the root's point spacing.
    pub center: [f64; 3],
    pub halfsize: f64,
    pub spacing: f64,
    /// Nodes and points at each depth, in the pages read.
    pub levels: Vec<CopcLevel>,
    pub pages_read: usize,
    /// Hierarchy pages known but not read (their nodes are not counted).
    pub pages_unread: usize,
}

#[derive(Debug, Serialize)]
pub struct CopcLevel {
    pub depth: i32,
    pub nodes: usize,
    pub points: u64,
    pub bytes: u64,
}

fn copc_report(a: &Args) -> anyhow::Result<CopcReport> {
    let c = crate::ingest::copc::open_any(&a.path)?;
    let (crs, attributes) = crate::ingest::copc::describe(&c)?;
    // The nodes of the pages read (the root page), or of every page.
    let nodes = if a.tiles {
        c.all_nodes()?
    } else {
        c.known_nodes()
    };
    let mut levels: Vec<CopcLevel> = Vec::new();
    for e in &nodes {
        let d = e.key.d;
        while levels.len() <= d as usize {
            levels.push(CopcLevel {
                depth: levels.len() as i32,
                nodes: 0,
                points: 0,
                bytes: 0,
            });
        }
        let l = &mut levels[d as usize];
        l.nodes += 1;
        l.points += u64::from(e.points);
        l.bytes += u64::from(e.bytes);
    }
    let (pages_read, pages_unread) = c.pages();
    Ok(CopcReport {
        path: a.path.display().to_string(),
        format: "copc",
        points: c.header.points,
        bytes: c.len,
        bounds: Bounds {
            min: c.header.min,
            max: c.header.max,
        },
        point_format: c.header.format,
        record_bytes: c.header.record_len,
        crs,
        attributes,
        center: c.info.center,
        halfsize: c.info.halfsize,
        spacing: c.info.spacing,
        levels,
        pages_read,
        pages_unread,
    })
}

fn copc_text(r: &CopcReport) -> String {
    use std::fmt::Write;
    let mut s = String::new();
    let v = |p: [f64; 3]| format!("({:.3}, {:.3}, {:.3})", p[0], p[1], p[2]);
    let _ = writeln!(s, "copc     {}", sanitize(&r.path));
    let _ = writeln!(
        s,
        "         {} points, {}; LAS 1.4 point format {} ({}-byte records), LAZ chunks in an octree",
        count(r.points),
        bytes(r.bytes),
        r.point_format,
        r.record_bytes
    );
    let _ = writeln!(s, "bounds   min {}", v(r.bounds.min));
    let _ = writeln!(s, "         max {}", v(r.bounds.max));
    let _ = writeln!(
        s,
        "octree   cube centre {}, half side {:.3}; root spacing {:.3}",
        v(r.center),
        r.halfsize,
        r.spacing
    );
    octree_text(
        &mut s,
        &r.levels,
        (r.pages_read, r.pages_unread, "page"),
        &r.attributes,
        r.crs.as_deref(),
    );
    s
}

/// What `info` says of a survey of COPC files (`pcimg index` over them):
/// from its survey file alone, no COPC file opened.
#[derive(Debug, Serialize)]
pub struct SurveyReport {
    pub path: String,
    pub format: &'static str,
    pub files: usize,
    pub points: u64,
    /// Bytes of the COPC files, and of the overview nodes.
    pub bytes: u64,
    pub overview_bytes: u64,
    pub bounds: Bounds,
    pub crs: Option<String>,
    pub attributes: Vec<String>,
    /// The overview's layers above the files' root nodes, lowest first.
    pub overview: Vec<SurveyLayer>,
    /// Every file (`--tiles`), else none.
    pub file_list: Vec<crate::survey::SurveyFile>,
}

#[derive(Debug, Serialize)]
pub struct SurveyLayer {
    pub layer: u32,
    pub nodes: usize,
    pub points: u64,
    pub bytes: u64,
}

fn survey_report(a: &Args) -> anyhow::Result<SurveyReport> {
    let (at, s) = crate::survey::read(&a.path)?;
    let mut overview: Vec<SurveyLayer> = (1..=s.layers())
        .map(|layer| SurveyLayer {
            layer,
            nodes: 0,
            points: 0,
            bytes: 0,
        })
        .collect();
    for n in &s.nodes {
        let l = &mut overview[n.layer as usize - 1];
        l.nodes += 1;
        l.points += n.points;
        l.bytes += n.bytes;
    }
    Ok(SurveyReport {
        path: at.display().to_string(),
        format: "copc-survey",
        files: s.files.len(),
        points: s.points(),
        bytes: s.files.iter().map(|f| f.bytes).sum(),
        overview_bytes: s.nodes.iter().map(|n| n.bytes).sum(),
        bounds: s.bounds(),
        crs: s.crs.clone(),
        attributes: s.bands.clone(),
        overview,
        file_list: if a.tiles { s.files } else { Vec::new() },
    })
}

fn survey_text(r: &SurveyReport) -> String {
    use std::fmt::Write;
    let mut s = String::new();
    let v = |p: [f64; 3]| format!("({:.3}, {:.3}, {:.3})", p[0], p[1], p[2]);
    let _ = writeln!(s, "survey   {}", sanitize(&r.path));
    let _ = writeln!(
        s,
        "         {} COPC files, {} points, {}; overview {}",
        count(r.files as u64),
        count(r.points),
        bytes(r.bytes),
        bytes(r.overview_bytes)
    );
    let _ = writeln!(s, "bounds   min {}", v(r.bounds.min));
    let _ = writeln!(s, "         max {}", v(r.bounds.max));
    for l in r.overview.iter().rev() {
        let _ = writeln!(
            s,
            "layer {:>2}  {:>7} nodes  {:>13} points  {}",
            l.layer,
            count(l.nodes as u64),
            count(l.points),
            bytes(l.bytes)
        );
    }
    for f in &r.file_list {
        let _ = writeln!(
            s,
            "file     {}  {} points (root {}), {}",
            sanitize(&f.file),
            count(f.points),
            count(f.root_points),
            bytes(f.bytes)
        );
    }
    let _ = writeln!(s, "bands    x y z {}", r.attributes.join(" "));
    if let Some(c) = &r.crs {
        let short: String = c.chars().take(60).collect();
        let _ = writeln!(s, "crs      {}", sanitize(&short));
    }
    s
}

/// The octree's levels (bytes where known), what of its hierarchy was read
/// (`unit`: page or file), the bands and the CRS, as `info` prints them.
fn octree_text(
    s: &mut String,
    levels: &[CopcLevel],
    (read, unread, unit): (usize, usize, &str),
    attributes: &[String],
    crs: Option<&str>,
) {
    use std::fmt::Write;
    for l in levels {
        let size = if l.bytes > 0 {
            format!("  {:>10}", bytes(l.bytes))
        } else {
            String::new()
        };
        let _ = writeln!(
            s,
            "  depth {:>2}  {:>7} nodes  {:>13} points{size}",
            l.depth,
            count(l.nodes as u64),
            count(l.points),
        );
    }
    let _ = writeln!(
        s,
        "         hierarchy: {read} {unit}(s) read{}",
        if unread > 0 {
            format!(", {unread} not read (their nodes are not counted above; --tiles reads them)")
        } else {
            String::new()
        }
    );
    let _ = writeln!(s, "bands    x y z {}", attributes.join(" "));
    if let Some(c) = crs {
        let short: String = c.chars().take(120).collect();
        let _ = writeln!(s, "crs      {}", sanitize(&short));
    }
}

/// What `info` says of an EPT dataset: its `ept.json` and the octree's
/// levels in the hierarchy files read (the root's; `--tiles` reads them all).
#[derive(Debug, Serialize)]
pub struct EptReport {
    pub path: String,
    pub format: &'static str,
    pub points: u64,
    pub bounds: Bounds,
    /// The octree's cube.
    pub cube: Bounds,
    pub crs: Option<String>,
    pub attributes: Vec<String>,
    pub levels: Vec<CopcLevel>,
    pub hierarchy_files_read: usize,
    pub hierarchy_files_unread: usize,
}

fn ept_report(a: &Args) -> anyhow::Result<EptReport> {
    let e = crate::ingest::ept::Ept::open(&a.path)?;
    let (attributes, _) = e.probe()?;
    let nodes = if a.tiles {
        e.nodes_where(&|_| true)?
    } else {
        // The nodes of the files read (the root's), no other file read.
        let mut out = vec![e.root()];
        let mut i = 0;
        while i < out.len() {
            let k = out[i].key;
            i += 1;
            out.extend(e.known_children(&k));
        }
        out
    };
    let mut levels: Vec<CopcLevel> = Vec::new();
    for n in &nodes {
        let d = n.key.d.max(0) as usize;
        while levels.len() <= d {
            levels.push(CopcLevel {
                depth: levels.len() as i32,
                nodes: 0,
                points: 0,
                bytes: 0,
            });
        }
        levels[d].nodes += 1;
        levels[d].points += n.points;
    }
    let (read, unread) = e.hierarchy_files();
    Ok(EptReport {
        path: a.path.display().to_string(),
        format: "ept",
        points: e.points,
        bounds: e.bounds,
        cube: Bounds {
            min: e.cube.0,
            max: e.cube.1,
        },
        crs: e.srs.clone(),
        attributes,
        levels,
        hierarchy_files_read: read,
        hierarchy_files_unread: unread,
    })
}

fn ept_text(r: &EptReport) -> String {
    use std::fmt::Write;
    let mut s = String::new();
    let v = |p: [f64; 3]| format!("({:.3}, {:.3}, {:.3})", p[0], p[1], p[2]);
    let _ = writeln!(s, "ept      {}", sanitize(&r.path));
    let _ = writeln!(
        s,
        "         {} points, LAZ files in an octree",
        count(r.points)
    );
    let _ = writeln!(s, "bounds   min {}", v(r.bounds.min));
    let _ = writeln!(s, "         max {}", v(r.bounds.max));
    octree_text(
        &mut s,
        &r.levels,
        (r.hierarchy_files_read, r.hierarchy_files_unread, "file"),
        &r.attributes,
        r.crs.as_deref(),
    );
    s
}

pub fn run(a: Args) -> anyhow::Result<()> {
    a.cache.apply()?;
    if crate::ingest::ept::is_ept(&a.path) {
        super::remote::read_url_inputs(a.cache.timeout.remote_options());
        let r = ept_report(&a)?;
        if a.json {
            super::print_out(&format!("{}\n", serde_json::to_string_pretty(&r)?))?;
        } else {
            super::print_out(&ept_text(&r))?;
        }
        return Ok(());
    }
    if crate::survey::is_survey(&a.path) {
        super::remote::read_url_inputs(a.cache.timeout.remote_options());
        let r = survey_report(&a)?;
        if a.json {
            super::print_out(&format!("{}\n", serde_json::to_string_pretty(&r)?))?;
        } else {
            super::print_out(&survey_text(&r))?;
        }
        return Ok(());
    }
    if super::remote::is_copc(&a.path) {
        super::remote::read_url_inputs(a.cache.timeout.remote_options());
        let r = copc_report(&a)?;
        if a.json {
            super::print_out(&format!("{}\n", serde_json::to_string_pretty(&r)?))?;
        } else {
            super::print_out(&copc_text(&r))?;
        }
        return Ok(());
    }
    let ds = Dataset::open_with(&a.path, &a.cache.open_options())?;
    if let Some(h) = crate::advice::dataset_note(&ds) {
        note!("{h}");
    }
    let r = if a.parts {
        report_of(&ds, a.tiles, &ds.parts()?)
    } else {
        report(&ds, a.tiles)
    };
    if a.json {
        super::print_out(&format!("{}\n", serde_json::to_string_pretty(&r)?))?;
    } else {
        super::print_out(&render_text(&r))?;
    }
    Ok(())
}
