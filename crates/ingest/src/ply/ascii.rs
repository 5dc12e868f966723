//! ASCII PLY vertices: the lines of the elements before the vertex element
//! skipped, then the vertex lines parsed by the parallel line engine the text
//! reader uses (`ingest::lines`), the lines of the elements after them counted
//! and checked whole.

use super::{Header, PropKind, VertexPlan};
use crate::color::ColorNormalizer;
use crate::error::IngestError;
use crate::lines::{LineEngine, LineReader};
use crate::{PointReader, ReadOptions, SourceInfo};
use memmap2::Mmap;
use std::path::Path;

/// The reader of an ASCII PLY file's vertices (`map`, its header and vertex plan
/// already parsed).
pub(super) fn open(
    path: &Path,
    opts: &ReadOptions,
    map: Mmap,
    header: &Header,
    plan: VertexPlan,
    info: SourceInfo,
) -> Result<Box<dyn PointReader>, IngestError> {
    let count = header.elements[plan.element].count;
    // Skip the lines of the elements before the vertex element.
    let mut pos = header.len;
    let mut line = header.lines + 1;
    for el in &header.elements[..plan.element] {
        for _ in 0..el.count {
            match memchr::memchr(b'\n', &map[pos.min(map.len())..]) {
                Some(k) => pos += k + 1,
                None => {
                    return Err(IngestError::line(
                        path,
                        line,
                        format!(
                            "the file ends inside element '{}'",
                            pcimg_core::text::sanitize(&el.name)
                        ),
                        b"",
                    ));
                }
            }
            line += 1;
        }
    }
    let mut layout = plan.layout.clone();
    layout.decide_offsets(&map[pos.min(map.len())..], count);
    let engine = LineEngine {
        path: path.to_path_buf(),
        layout,
        pos,
        end: map.len(),
        line,
        lines_left: Some(count),
        after: header.elements[plan.element + 1..]
            .iter()
            .map(|e| {
                let lists = e
                    .props
                    .iter()
                    .map(|p| matches!(p.kind, PropKind::List { .. }))
                    .collect();
                (e.name.clone(), e.count, lists)
            })
            .collect(),
        skip_invalid: opts.skip_invalid,
        allow_count_lines: false,
        chunk_points: opts.chunk_points,
        bytes_per_line: crate::lines::sample_bytes_per_line(&map, pos),
        skipped: 0,
        colors: ColorNormalizer::new(plan.float_color),
        pending: Default::default(),
        sample: None,
        declared: None,
        point_lines: 0,
    };
    Ok(Box::new(LineReader::new(info, map, engine)))
}
