//! Several input files read as one stream of points (`pcimg convert tiles/*.laz`):
//! surveys come as hundreds of tiles, and a dataset should not be split where the
//! tiling happened to cut.
//!
//! * Every file is opened once up front (headers only, no points decoded) so that a
//!   mismatch is reported before hours of work: the files must carry the same
//!   attributes in the same order, and no two may declare different coordinate
//!   reference systems (compared without the whitespace outside quoted names). Each error names both files.
//!   Empty (zero-byte) files are left out.
//! * Then the files are read one after the other, one reader open at a time; each
//!   reader's own errors name its file (and line or byte offset).
//! * Each file keeps its own colour scale and GPS-time offset; the converter brings
//!   chunks to the first chunk's offsets (`convert::normalize`).
//! * Sampling ([`PointReader::sample_rest`]) applies to the current file and every
//!   later one; it is refused when any of them cannot sample (PLY).

use std::collections::HashSet;
use std::path::{Path, PathBuf};

use super::{IngestError, InputKind, PointReader, ReadOptions, SourceInfo, detect, open};
use crate::points::{ChunkExtent, PointColumns};

/// Whether `path` is an empty (zero-byte) file: one [`MultiReader`] leaves out.
pub fn is_empty_file(path: &Path) -> bool {
    std::fs::metadata(path).is_ok_and(|m| m.is_file() && m.len() == 0)
}

/// Reads `paths` in order as one input.
pub struct MultiReader {
    paths: Vec<PathBuf>,
    kinds: Vec<InputKind>,
    sizes: Vec<u64>,
    opts: ReadOptions,
    info: SourceInfo,
    /// Index of the file `current` reads.
    at: usize,
    current: Option<Box<dyn PointReader>>,
    /// Bytes of the files already finished.
    bytes_before: u64,
    skipped_before: u64,
    clamped_before: u64,
    left_out_before: u64,
    /// Sampling rate asked for, applied to every file opened from now on.
    every: Option<u64>,
}

/// Opens `paths` as one input: the file itself when there is one, else a
/// [`MultiReader`] over them (see the module documentation for the checks).
pub fn open_all(
    paths: &[PathBuf],
    opts: &ReadOptions,
) -> Result<Box<dyn PointReader>, IngestError> {
    match paths {
        [] => Err(IngestError::format(Path::new("-"), "no input files")),
        [one] => open(one, opts),
        _ => Ok(Box::new(MultiReader::open(paths, opts)?)),
    }
}

impl MultiReader {
    pub fn open(paths: &[PathBuf], opts: &ReadOptions) -> Result<MultiReader, IngestError> {
        // Empty files (a tile with nothing in it) hold no points: left out, unless
        // every file is empty (then the first one's error says so).
        let sized: Vec<PathBuf> = paths
            .iter()
            .filter(|p| !is_empty_file(p))
            .cloned()
            .collect();
        let paths = if sized.is_empty() {
            &paths[..1]
        } else {
            &sized[..]
        };
        let mut seen = HashSet::new();
        let mut infos: Vec<SourceInfo> = Vec::with_capacity(paths.len());
        let mut kinds = Vec::with_capacity(paths.len());
        for p in paths {
            let key = p.canonicalize().unwrap_or_else(|_| p.clone());
            if !seen.insert(key) {
                return Err(IngestError::format(p, "given twice as an input"));
            }
            kinds.push(detect(p)?);
            // A reader opened for its header decodes nothing (text: the first
            // lines, for the column layout).
            infos.push(open(p, opts)?.info().clone());
        }
        let info = merge(&infos)?;
        Ok(MultiReader {
            paths: paths.to_vec(),
            kinds,
            sizes: infos.iter().map(|i| i.file_bytes).collect(),
            opts: opts.clone(),
            info,
            at: 0,
            current: None,
            bytes_before: 0,
            skipped_before: 0,
            clamped_before: 0,
            left_out_before: 0,
            every: None,
        })
    }

    /// Opens file `at` (applying the sampling rate asked for so far).
    fn open_current(&mut self) -> Result<(), IngestError> {
        let mut r = open(&self.paths[self.at], &self.opts)?;
        let names = &r.info().attribute_names;
        if *names != self.info.attribute_names {
            // The file changed since it was checked.
            return Err(differ(
                &self.paths[self.at],
                names,
                &self.paths[0],
                &self.info.attribute_names,
            ));
        }
        if let Some(every) = self.every {
            r.sample_rest(every);
        }
        self.current = Some(r);
        Ok(())
    }

    /// The next item `next` takes from the files, one after the other (`None`
    /// once every file is done).
    fn next_of<T>(
        &mut self,
        mut next: impl FnMut(&mut Box<dyn PointReader>) -> Result<Option<T>, IngestError>,
    ) -> Result<Option<T>, IngestError> {
        while self.at < self.paths.len() {
            if self.current.is_none() {
                self.open_current()?;
            }
            if let Some(r) = self.current.as_mut()
                && let Some(c) = next(r)?
            {
                return Ok(Some(c));
            }
            self.finish_current();
        }
        Ok(None)
    }

    /// Closes the current file, adding its counts to those before.
    fn finish_current(&mut self) {
        if let Some(r) = self.current.take() {
            self.skipped_before += r.skipped();
            self.clamped_before += r.clamped_colours();
            self.left_out_before += r.left_out();
        }
        self.bytes_before += self.sizes[self.at];
        self.at += 1;
    }
}

/// The files' infos as one: checks that they agree.
fn merge(infos: &[SourceInfo]) -> Result<SourceInfo, IngestError> {
    let first = &infos[0];
    let mut crs: Option<(&Path, &String)> = None;
    for i in infos {
        if i.attribute_names != first.attribute_names {
            return Err(differ(
                &i.path,
                &i.attribute_names,
                &first.path,
                &first.attribute_names,
            ));
        }
        if let Some(c) = &i.crs_wkt {
            match crs {
                Some((p, known)) if crs_key(known) != crs_key(c) => {
                    return Err(IngestError::format(
                        &i.path,
                        format!(
                            "its coordinate reference system differs from that of {} \
                             (a dataset has one; convert them separately, or reproject first)",
                            super::error::show_path(p)
                        ),
                    ));
                }
                Some(_) => {}
                None => crs = Some((&i.path, c)),
            }
        }
    }
    let formats: Vec<&str> = {
        let mut f: Vec<&str> = Vec::new();
        for i in infos {
            if !f.contains(&i.format.as_str()) {
                f.push(&i.format);
            }
        }
        f
    };
    let all = |f: &dyn Fn(&SourceInfo) -> bool| infos.iter().all(f);
    Ok(SourceInfo {
        path: first.path.clone(),
        format: formats.join(", "),
        declared_points: all(&|i| i.declared_points.is_some())
            .then(|| infos.iter().filter_map(|i| i.declared_points).sum()),
        // (A file that declares no points declares no bounds either, whatever
        // its header holds.)
        declared_bounds: all(&|i| i.declared_bounds.is_some() || i.declared_points == Some(0))
            .then(|| {
                infos
                    .iter()
                    .filter(|i| i.declared_points != Some(0))
                    .filter_map(|i| i.declared_bounds)
                    .fold(crate::points::Bounds::EMPTY, |a, b| a.union(&b))
            })
            .filter(|b| !b.is_empty()),
        crs_wkt: crs.map(|(_, c)| c.clone()),
        attribute_names: first.attribute_names.clone(),
        file_bytes: infos.iter().map(|i| i.file_bytes).sum(),
        notes: infos
            .iter()
            .flat_map(|i| {
                i.notes
                    .iter()
                    .map(|n| format!("{}: {n}", super::error::show_path(&i.path)))
            })
            .collect(),
        // One file's description of itself (a viewpoint, its scans) would
        // mislead about the others: kept only when every file has the same.
        metadata: if infos.iter().all(|i| i.metadata == first.metadata) {
            first.metadata.clone()
        } else {
            Vec::new()
        },
        coordinate_lattice: common_lattice(infos),
        // Every file on a lattice: the finest step on each axis.
        coordinate_step: infos
            .iter()
            .map(|i| i.coordinate_step)
            .collect::<Option<Vec<[f64; 3]>>>()
            .map(|s| {
                s.iter().fold([f64::INFINITY; 3], |a, b| {
                    [0, 1, 2].map(|k| a[k].min(b[k].abs()))
                })
            }),
    })
}

/// A CRS as compared: `EPSG:<code>` when it is one, or WKT naming its EPSG code
/// at the top level (LAS 1.4 tiles carry WKT where LAS 1.2 tiles of the same
/// survey carry the code in GeoTIFF keys); else the WKT without the whitespace
/// outside its quoted names (pretty printed and compact WKT are the same CRS).
fn crs_key(s: &str) -> String {
    if let Some(code) = epsg_code(s) {
        return format!("EPSG:{code}");
    }
    let mut quoted = false;
    s.chars()
        .filter(|&c| {
            quoted ^= c == '"';
            quoted || !c.is_whitespace()
        })
        .collect()
}

/// The EPSG code of `EPSG:<n>`, or the one a WKT (1 or 2) gives its CRS as a
/// whole: the last `AUTHORITY["EPSG","n"]` or `ID["EPSG",n]` directly inside the
/// outermost node (the codes of nested nodes, a datum's say, are not the CRS's).
fn epsg_code(s: &str) -> Option<u64> {
    let t = s.trim();
    if let Some(n) = t
        .get(..5)
        .filter(|p| p.eq_ignore_ascii_case("EPSG:"))
        .and_then(|_| t[5..].trim().parse().ok())
    {
        return Some(n);
    }
    let b = t.as_bytes();
    let (mut depth, mut quoted, mut found) = (0usize, false, None);
    let mut word_start = 0;
    for (i, &c) in b.iter().enumerate() {
        if quoted {
            quoted = c != b'"';
            continue;
        }
        match c {
            b'"' => quoted = true,
            b'[' | b'(' => {
                depth += 1;
                let word = t[word_start..i].trim();
                if depth == 2
                    && (word.eq_ignore_ascii_case("AUTHORITY") || word.eq_ignore_ascii_case("ID"))
                {
                    found = authority_code(&t[i + 1..]).or(found);
                }
            }
            b']' | b')' => depth = depth.saturating_sub(1),
            _ => {}
        }
        if matches!(c, b'[' | b'(' | b']' | b')' | b',') {
            word_start = i + 1;
        }
    }
    found
}

/// The code of an authority node's body `"EPSG","2992"]` (or `"EPSG",2992]`).
fn authority_code(body: &str) -> Option<u64> {
    let end = body.find([']', ')'])?;
    let mut parts = body[..end]
        .split(',')
        .map(|p| p.trim().trim_matches('"').trim());
    let name = parts.next()?;
    let code = parts.next()?;
    name.eq_ignore_ascii_case("EPSG")
        .then(|| code.parse().ok())
        .flatten()
}

fn differ(path: &Path, names: &[String], other: &Path, other_names: &[String]) -> IngestError {
    let list = |n: &[String]| {
        if n.is_empty() {
            "none".to_string()
        } else {
            pcimg_core::text::sanitize(&n.join(", "))
        }
    };
    IngestError::format(
        path,
        format!(
            "its attributes ({}) differ from those of {} ({}): the files of one dataset \
             must carry the same attributes; convert them separately",
            list(names),
            super::error::show_path(other),
            list(other_names)
        ),
    )
}

impl PointReader for MultiReader {
    fn info(&self) -> &SourceInfo {
        &self.info
    }

    fn next_chunk(&mut self) -> Result<Option<PointColumns>, IngestError> {
        self.next_of(|r| r.next_chunk())
    }

    fn gives_extents(&mut self) -> Result<bool, IngestError> {
        // One file's rows only (see `row_source`).
        if self.paths.len() != 1 || self.at >= self.paths.len() {
            return Ok(false);
        }
        if self.current.is_none() {
            self.open_current()?;
        }
        self.current
            .as_mut()
            .map_or(Ok(false), |r| r.gives_extents())
    }

    fn next_extent(&mut self) -> Result<Option<ChunkExtent>, IngestError> {
        if self.paths.len() != 1 {
            return Ok(self.next_chunk()?.map(|c| ChunkExtent::of(&c)));
        }
        self.next_of(|r| r.next_extent())
    }

    fn bytes_done(&self) -> u64 {
        self.bytes_before + self.current.as_ref().map_or(0, |r| r.bytes_done())
    }

    fn skipped(&self) -> u64 {
        self.skipped_before + self.current.as_ref().map_or(0, |r| r.skipped())
    }

    fn clamped_colours(&self) -> u64 {
        self.clamped_before + self.current.as_ref().map_or(0, |r| r.clamped_colours())
    }

    fn left_out(&self) -> u64 {
        self.left_out_before + self.current.as_ref().map_or(0, |r| r.left_out())
    }

    fn row_source(&self) -> Option<std::sync::Arc<dyn crate::points::RowSource>> {
        // One file's rows only: point indices run over every file.
        if self.paths.len() != 1 {
            return None;
        }
        self.current.as_ref().and_then(|r| r.row_source())
    }

    fn sample_rest(&mut self, every: u64) -> bool {
        // PLY readers deliver every point: then none samples, so that every point
        // stands for the same number of points.
        if every < 2 || self.kinds[self.at.min(self.kinds.len() - 1)..].contains(&InputKind::Ply) {
            return false;
        }
        if let Some(r) = self.current.as_mut() {
            r.sample_rest(every);
        }
        self.every = Some(every);
        true
    }
}

/// The lattice every file's points lie on, when they all have one and one
/// holds them all ([`Lattice::common`](crate::points::Lattice::common)).
pub(crate) fn common_lattice(infos: &[SourceInfo]) -> Option<crate::points::Lattice> {
    let all: Vec<crate::points::Lattice> = infos
        .iter()
        .map(|i| i.coordinate_lattice)
        .collect::<Option<_>>()?;
    crate::points::Lattice::common(&all)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn info(path: &str, names: &[&str], crs: Option<&str>) -> SourceInfo {
        SourceInfo {
            path: PathBuf::from(path),
            format: "las 1.4".into(),
            declared_points: Some(10),
            declared_bounds: None,
            crs_wkt: crs.map(String::from),
            attribute_names: names.iter().map(|s| s.to_string()).collect(),
            file_bytes: 100,
            notes: Vec::new(),
            metadata: Vec::new(),
            coordinate_step: None,
            coordinate_lattice: None,
        }
    }

    #[test]
    fn files_share_a_lattice_when_their_steps_and_points_agree() {
        let with = |step: [f64; 3], origin: [f64; 3]| SourceInfo {
            coordinate_lattice: Some(crate::points::Lattice { step, origin }),
            ..info("t.las", &[], None)
        };
        // LAS tiles: one scale, offsets whole steps apart.
        let a = with([0.01; 3], [636_000.0, 848_000.0, 0.0]);
        let b = with([0.01; 3], [637_000.0, 849_000.0, 400.0]);
        let got = common_lattice(&[a.clone(), b.clone()]).unwrap();
        assert_eq!(got.step, [0.01; 3]);
        assert_eq!(got.origin, [636_000.0, 848_000.0, 0.0]);
        // An offset half a step off: no lattice holds both.
        let half = with([0.01; 3], [637_000.005, 849_000.0, 400.0]);
        assert_eq!(common_lattice(&[a.clone(), half]), None);
        // 2 and 3 decimals: the finer, on each axis.
        let fine = with([0.001, 0.01, 0.001], [0.0; 3]);
        let got = common_lattice(&[a.clone(), fine.clone()]).unwrap();
        assert_eq!(got.step, [0.001, 0.01, 0.001]);
        assert_eq!(got.origin, [0.0, 848_000.0, 0.0]);
        // Steps that do not divide each other, or a file with none.
        let odd = with([0.003; 3], [0.0; 3]);
        assert_eq!(common_lattice(&[a.clone(), odd]), None);
        assert_eq!(common_lattice(&[a, info("f.ply", &[], None)]), None);
    }

    #[test]
    fn infos_merge_when_they_agree() {
        let m = merge(&[
            info("a.las", &["intensity"], None),
            info("b.las", &["intensity"], Some("EPSG:2992")),
            info("c.las", &["intensity"], Some("EPSG:2992")),
        ])
        .unwrap();
        assert_eq!(m.crs_wkt.as_deref(), Some("EPSG:2992"));
        // Pretty-printed and compact WKT are one CRS; a name that differs is not.
        let wkt = |s: &str| info("w.las", &["intensity"], Some(s));
        assert!(
            merge(&[
                wkt(r#"GEOGCS["WGS 84",DATUM["x"]]"#),
                wkt("GEOGCS[\"WGS 84\",\n  DATUM[ \"x\" ] ]")
            ])
            .is_ok()
        );
        assert!(merge(&[wkt(r#"GEOGCS["WGS 84"]"#), wkt(r#"GEOGCS["WGS  84"]"#)]).is_err());
        assert_eq!((m.declared_points, m.file_bytes), (Some(30), 300));
        assert_eq!(m.format, "las 1.4");
    }

    /// A WKT naming its EPSG code at the top level is that code's CRS; a code of a
    /// nested node (the base geographic CRS) is not.
    #[test]
    fn wkt_and_epsg_codes_compare_by_the_top_level_code() {
        let oregon = r#"PROJCS["NAD83 / Oregon GIC Lambert (ft)",
            GEOGCS["NAD83",DATUM["North_American_Datum_1983",AUTHORITY["EPSG","6269"]],
                AUTHORITY["EPSG","4269"]],
            UNIT["foot",0.3048,AUTHORITY["EPSG","9002"]],
            AUTHORITY["EPSG","2992"]]"#;
        assert_eq!(epsg_code(oregon), Some(2992));
        assert_eq!(epsg_code("epsg: 2992"), Some(2992));
        let wkt2 = r#"PROJCRS["WGS 84 / UTM zone 10N",BASEGEOGCRS["WGS 84",ID["EPSG",4326]],
            ID["EPSG",32610]]"#;
        assert_eq!(epsg_code(wkt2), Some(32610));
        let no_top = r#"PROJCS["local",GEOGCS["NAD83",AUTHORITY["EPSG","4269"]]]"#;
        assert_eq!(epsg_code(no_top), None);
        // A quoted name holding brackets does not confuse the depth.
        let tricky =
            r#"PROJCS["a [b] (c)",GEOGCS["x",AUTHORITY["EPSG","4269"]],AUTHORITY["EPSG","26910"]]"#;
        assert_eq!(epsg_code(tricky), Some(26910));
        let ok = merge(&[
            info("a.las", &["intensity"], Some("EPSG:2992")),
            info("b.las", &["intensity"], Some(oregon)),
        ]);
        assert!(ok.is_ok());
        for other in ["EPSG:4269", no_top] {
            assert!(
                merge(&[
                    info("a.las", &["intensity"], Some(other)),
                    info("b.las", &["intensity"], Some(oregon)),
                ])
                .is_err(),
                "{other}"
            );
        }
    }

    #[test]
    fn differing_crs_or_attributes_name_both_files() {
        let e = merge(&[
            info("a.las", &["intensity"], Some("EPSG:2992")),
            info("b.las", &["intensity"], None),
            info("c.las", &["intensity"], Some("EPSG:32610")),
        ])
        .unwrap_err()
        .to_string();
        assert!(
            e.starts_with("c.las:") && e.contains("a.las") && e.contains("reference system"),
            "{e}"
        );
        let e = merge(&[
            info("a.las", &["intensity"], None),
            info("b.las", &[], None),
        ])
        .unwrap_err()
        .to_string();
        assert!(e.contains("(none)") && e.contains("(intensity)"), "{e}");
    }
}
