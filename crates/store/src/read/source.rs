//! Where a read's tile bytes come from: the part's memory map (a local file), or
//! the byte ranges of exactly the chunks the read needs, fetched from object
//! storage before it (`crate::remote`, merged and concurrent).

use crate::error::StoreError;
use crate::read::part::{Level, Part};

/// Why a read's chunks could not be had: the failed request (a local file's
/// map is always there, so without object storage there is no such error).
#[cfg(feature = "remote")]
pub(crate) type FetchError = crate::remote::RemoteError;
#[cfg(not(feature = "remote"))]
pub(crate) type FetchError = std::convert::Infallible;

/// The stored bytes of the chunks of one read.
pub(crate) enum Chunks<'a> {
    /// The whole file, mapped.
    Map(&'a crate::read::part::Bytes),
    /// Ranges fetched for this read, by file offset, sorted.
    #[cfg_attr(not(feature = "remote"), allow(dead_code))]
    Fetched(Vec<(u64, bytes::Bytes)>),
}

impl Chunks<'_> {
    /// Bytes `off..off + len` of the file.
    pub(crate) fn get(&self, off: u64, len: u64) -> std::result::Result<&[u8], String> {
        if len == 0 {
            return Ok(&[]);
        }
        match self {
            Chunks::Map(m) => m
                .get(off as usize..(off + len) as usize)
                .ok_or_else(|| format!("bytes {off}..{} lie past the end", off + len)),
            Chunks::Fetched(v) => {
                let i = v.partition_point(|(o, _)| *o <= off);
                i.checked_sub(1)
                    .map(|i| &v[i])
                    .filter(|(o, b)| off + len <= o + b.len() as u64)
                    .map(|(o, b)| &b[(off - o) as usize..(off - o + len) as usize])
                    .ok_or_else(|| format!("bytes {off}..{} were not fetched", off + len))
            }
        }
    }

    /// Asks the kernel for a mapped range ahead of its use (nothing remotely:
    /// the bytes are here).
    pub(crate) fn will_need(&self, off: u64, len: u64) {
        if let Chunks::Map(m) = self {
            m.will_need(off, len);
        }
    }
}

impl Part {
    /// The chunk indices (planes, or whole pixel-interleaved tiles) of `bands`
    /// of tile `t`.
    #[cfg(feature = "remote")]
    fn chunk_ids(&self, l: &Level, t: u32, bands: &[usize], out: &mut Vec<usize>) {
        let per_band = (l.tiles_across * l.tiles_down) as usize;
        if l.planar_separate {
            out.extend(bands.iter().map(|&b| b * per_band + t as usize));
        } else {
            out.push(t as usize);
        }
    }

    /// The bytes a read of `tiles` of level `l` for `bands` needs: the map, or
    /// for a remote part those chunks fetched now (x too where `with_x`).
    pub(crate) fn chunks(
        &self,
        l: &Level,
        tiles: &[u32],
        bands: &[usize],
        with_x: bool,
    ) -> std::result::Result<Chunks<'_>, FetchError> {
        let Some(remote) = &self.remote else {
            return Ok(Chunks::Map(&self.map));
        };
        self.fetch(remote, l, tiles, bands, with_x)
    }

    /// Those chunks of a remote part, fetched now.
    #[cfg(feature = "remote")]
    fn fetch(
        &self,
        remote: &crate::remote::RemoteFile,
        l: &Level,
        tiles: &[u32],
        bands: &[usize],
        with_x: bool,
    ) -> std::result::Result<Chunks<'_>, FetchError> {
        let mut want: Vec<usize> = bands.to_vec();
        if with_x && !want.contains(&0) {
            want.push(0);
        }
        let mut ids = Vec::new();
        for &t in tiles {
            self.chunk_ids(l, t, &want, &mut ids);
        }
        ids.sort_unstable();
        ids.dedup();
        let ranges: Vec<std::ops::Range<u64>> = ids
            .iter()
            .filter_map(|&c| Some((*l.offsets.get(c)?, *l.counts.get(c)?)))
            .filter(|&(_, n)| n > 0)
            .map(|(o, n)| o..o + n)
            .collect();
        let got = remote.read_ranges(&ranges)?;
        let mut v: Vec<(u64, bytes::Bytes)> = ranges.iter().map(|r| r.start).zip(got).collect();
        v.sort_by_key(|e| e.0);
        Ok(Chunks::Fetched(v))
    }

    #[cfg(not(feature = "remote"))]
    fn fetch(
        &self,
        remote: &crate::remote::RemoteFile,
        _: &Level,
        _: &[u32],
        _: &[usize],
        _: bool,
    ) -> std::result::Result<Chunks<'_>, FetchError> {
        match *remote {}
    }

    /// The error of a read of `level` whose chunks could not be fetched: it
    /// keeps the failed request (its URL and what happened), so that callers
    /// can tell a network failure, worth trying again, from bad bytes.
    pub(crate) fn fetch_failed(&self, level: usize, e: FetchError) -> StoreError {
        let message = format!("level {level}: {e}");
        StoreError {
            #[cfg(feature = "remote")]
            remote: Some(Box::new(e)),
            ..StoreError::new(&self.path, message)
        }
    }
}
