//! A COPC file in object storage or on an HTTP server as `pcimg-copc`'s byte
//! source: the header in one request (which also tells the object's size),
//! then ranges through [`RemoteFile`] (nearby ones merged, the rest fetched
//! concurrently, kept in the memory and disk caches, every request after the
//! first conditional on the ETag first seen).

use super::{Options, Remote, RemoteError, RemoteFile};
use std::ops::Range;
use std::sync::Arc;

/// A remote file read by ranges.
#[derive(Debug)]
pub struct RemoteBytes {
    file: RemoteFile,
    url: String,
}

impl RemoteBytes {
    /// The object at `url` (`s3://bucket/a/x.copc.laz`, `https://host/x.copc.laz`).
    pub fn open(url: &str, options: &Options) -> Result<RemoteBytes, RemoteError> {
        let url = url.trim_end_matches('/');
        let (dir, name) = match url.rfind('/') {
            Some(i) if i > url.find("://").map_or(0, |s| s + 2) => (&url[..i], &url[i + 1..]),
            _ => {
                return Err(RemoteError::new(
                    url,
                    super::Problem::BadUrl("name a file, not only a server or bucket".into()),
                ));
            }
        };
        let remote = client(dir, options)?;
        Ok(RemoteBytes {
            file: remote.file(name),
            url: url.to_string(),
        })
    }
}

/// The client of directory `dir`, one per directory and options in a
/// process: an EPT dataset's node files, a survey's COPC files, share its
/// connections (and what it learnt of the server: that it ignores ranges).
fn client(dir: &str, options: &Options) -> Result<Arc<Remote>, RemoteError> {
    type Clients = std::sync::Mutex<std::collections::HashMap<(String, u128), Arc<Remote>>>;
    static CLIENTS: std::sync::OnceLock<Clients> = std::sync::OnceLock::new();
    let key = (dir.to_string(), options.timeout.as_nanos());
    let clients = CLIENTS.get_or_init(Default::default);
    if let Some(r) = clients.lock().unwrap_or_else(|p| p.into_inner()).get(&key) {
        return Ok(r.clone());
    }
    let r = Arc::new(Remote::open_with(dir, options)?);
    clients
        .lock()
        .unwrap_or_else(|p| p.into_inner())
        .insert(key, r.clone());
    Ok(r)
}

fn io(e: RemoteError) -> std::io::Error {
    std::io::Error::other(e.to_string())
}

impl pcimg_copc::ByteSource for RemoteBytes {
    fn name(&self) -> String {
        self.url.clone()
    }
    fn read_prefix(&self, max: u64) -> std::io::Result<Vec<u8>> {
        self.file.read_prefix(max).map(|b| b.to_vec()).map_err(io)
    }
    fn read_all(&self) -> std::io::Result<Vec<u8>> {
        self.file.read_whole().map(|b| b.to_vec()).map_err(io)
    }
    fn size(&self) -> std::io::Result<u64> {
        self.file.object_size().map_err(io)
    }
    fn read_ranges(&self, ranges: &[Range<u64>]) -> std::io::Result<Vec<Vec<u8>>> {
        Ok(self
            .file
            .ranges(ranges)
            .map_err(io)?
            .into_iter()
            .map(|b| b.to_vec())
            .collect())
    }
}
