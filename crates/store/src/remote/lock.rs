//! A lock on a prefix of object storage, for one writer at a time: the object
//! `.NAME.pcimg-lock` beside the prefix `…/NAME` (not under it, so a listing of
//! the dataset never shows it), created with a conditional write
//! (`If-None-Match: *`, object_store's `PutMode::Create`: Amazon S3 since
//! 2024, SeaweedFS, MinIO, GCS and Azure), so that of two writers exactly one
//! creates it. It records who holds it (process, host, start time, a random
//! token); a lock left by a process of this host that is gone is taken over.
//! A store that ignores the condition overwrites the object: the lock then
//! guards nothing, and the last writer wins, as without it.

use super::{InFlight, Problem, Remote, RemoteError, block_on};
use object_store::{ObjectStoreExt, PutMode, PutOptions, PutPayload};
use serde::{Deserialize, Serialize};
use std::sync::Arc;

/// Who holds (or held) a lock, as its object says.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize, Default)]
pub struct Holder {
    pub pid: Option<u32>,
    pub host: Option<String>,
    /// Seconds since the Unix epoch when it was taken.
    pub since: Option<u64>,
    #[serde(default)]
    token: String,
}

impl Holder {
    /// This process, now.
    fn me() -> Holder {
        let now = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .unwrap_or_default();
        Holder {
            pid: Some(std::process::id()),
            host: Some(host_name()),
            since: Some(now.as_secs()),
            token: format!("{:x}{:x}", now.as_nanos(), std::process::id()),
        }
    }

    /// A process of this host that no longer runs (a killed run's lock).
    pub fn is_gone(&self) -> bool {
        match (self.pid, &self.host) {
            (Some(pid), Some(host)) => *host == host_name() && !pcimg_core::disk::pid_alive(pid),
            _ => false,
        }
    }
}

/// This machine's name (`/proc/sys/kernel/hostname`; `unknown` elsewhere).
fn host_name() -> String {
    std::fs::read_to_string("/proc/sys/kernel/hostname")
        .map(|s| s.trim().to_string())
        .ok()
        .filter(|s| !s.is_empty())
        .unwrap_or_else(|| "unknown".into())
}

/// A lock held: its object is deleted when dropped.
#[derive(Debug)]
pub struct Lock {
    beside: Remote,
    name: String,
    /// A lock of a gone process that was removed to take this one.
    pub took_over: Option<Holder>,
}

/// The outcome of [`take`].
#[derive(Debug)]
pub enum Taken {
    Held(Lock),
    /// Another writer holds it; `url`: the lock object.
    Busy {
        holder: Holder,
        url: String,
    },
}

impl Lock {
    /// The lock object's URL.
    pub fn url(&self) -> String {
        self.beside.url_of(&self.name)
    }
}

impl Drop for Lock {
    fn drop(&mut self) {
        let loc = self.beside.location(&self.name);
        let store = self.beside.store.clone();
        let limit = self.beside.options.timeout;
        let _ = block_on(async move { tokio::time::timeout(limit, store.delete(&loc)).await });
    }
}

/// The lock object's store (the prefix's parent) and name.
fn beside(remote: &Remote) -> (Remote, String) {
    let mut parts: Vec<String> = remote
        .prefix
        .parts()
        .map(|p| p.as_ref().to_string())
        .collect();
    let last = parts.pop().unwrap_or_default();
    let mut b = remote.clone();
    b.prefix = parts.iter().map(String::as_str).collect();
    b.url = match remote.url.rsplit_once('/') {
        Some((parent, _)) if !last.is_empty() => parent.to_string(),
        _ => remote.url.clone(),
    };
    (b, format!(".{last}.pcimg-lock"))
}

/// Takes the lock of `remote`'s prefix, or says who holds it. A lock of a
/// process of this host that is gone is removed and taken.
pub fn take(remote: &Arc<Remote>) -> Result<Taken, RemoteError> {
    let (b, name) = beside(remote);
    let url = b.url_of(&name);
    let me = Holder::me();
    let body = serde_json::to_vec(&me).unwrap_or_default();
    let loc = b.location(&name);
    let mut took_over = None;
    for _ in 0..3 {
        let opts = PutOptions {
            mode: PutMode::Create,
            ..Default::default()
        };
        let payload = PutPayload::from(body.clone());
        // Ok(false): the object exists.
        let f = InFlight::start(&b);
        let r = block_on(b.retrying(|| {
            let (opts, payload) = (opts.clone(), payload.clone());
            let (loc, url, b) = (&loc, &url, &b);
            async move {
                match b.store.put_opts(loc, payload, opts).await {
                    Ok(_) => Ok(true),
                    Err(
                        object_store::Error::AlreadyExists { .. }
                        | object_store::Error::Precondition { .. },
                    ) => Ok(false),
                    Err(e) => Err(RemoteError::new(url, Problem::of(&e))),
                }
            }
        }));
        f.done(0, r.is_ok());
        if r? {
            return Ok(Taken::Held(Lock {
                beside: b,
                name,
                took_over,
            }));
        }
        // Who holds it: ours (a retried create whose first answer was lost),
        // a gone process's, or another writer's.
        let holder = match b.get(&name)? {
            Some((text, _, _)) => serde_json::from_slice::<Holder>(&text).unwrap_or_default(),
            // Released meanwhile: try again.
            None => continue,
        };
        if holder.token == me.token {
            return Ok(Taken::Held(Lock {
                beside: b,
                name,
                took_over,
            }));
        }
        if !holder.is_gone() {
            return Ok(Taken::Busy { holder, url });
        }
        let f = InFlight::start(&b);
        let d = block_on(b.store.delete(&loc));
        f.done(0, d.is_ok());
        d.map_err(|e| RemoteError::new(&url, Problem::of(&e)))?;
        took_over = Some(holder);
    }
    Err(RemoteError::new(
        &url,
        Problem::Other("the lock kept changing hands; try again".into()),
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn remote(url: &str, prefix: &str) -> Arc<Remote> {
        Arc::new(Remote::with_store(
            Arc::new(object_store::memory::InMemory::new()),
            prefix,
            url,
        ))
    }

    #[test]
    fn the_lock_sits_beside_the_prefix() {
        let r = remote("s3://b/data/city.pcimg", "data/city.pcimg");
        let (b, name) = beside(&r);
        assert_eq!(name, ".city.pcimg.pcimg-lock");
        assert_eq!(b.url_of(&name), "s3://b/data/.city.pcimg.pcimg-lock");
        assert_eq!(b.location(&name).as_ref(), "data/.city.pcimg.pcimg-lock");
    }

    #[test]
    fn one_writer_holds_it_until_dropped_and_a_gone_one_is_taken_over() {
        let r = remote("s3://b/city.pcimg", "city.pcimg");
        let Taken::Held(first) = take(&r).unwrap() else {
            panic!("not taken")
        };
        assert!(first.took_over.is_none());
        match take(&r).unwrap() {
            Taken::Busy { holder, url } => {
                assert_eq!(holder.pid, Some(std::process::id()));
                assert_eq!(url, "s3://b/.city.pcimg.pcimg-lock");
            }
            Taken::Held(_) => panic!("taken twice"),
        }
        drop(first);
        let Taken::Held(again) = take(&r).unwrap() else {
            panic!("not released")
        };
        // A lock of a process of this host that is gone.
        std::mem::forget(again);
        let (b, name) = beside(&r);
        let gone = Holder {
            pid: Some(u32::MAX / 2),
            host: Some(host_name()),
            since: Some(1),
            token: "x".into(),
        };
        block_on(b.store.put(
            &b.location(&name),
            PutPayload::from(serde_json::to_vec(&gone).unwrap()),
        ))
        .unwrap();
        let Taken::Held(taken) = take(&r).unwrap() else {
            panic!("a gone process's lock was not taken over")
        };
        assert_eq!(taken.took_over, Some(gone));
    }
}
