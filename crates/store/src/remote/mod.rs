//! Datasets in object storage (`s3://`, `gs://`, `az://`, `http(s)://`): the
//! `object_store` client built from a URL and the environment, one small tokio
//! runtime the blocking callers share, counters for the inspector's status line,
//! and errors that name the URL and say what to fix. Ranged, cached reads of one
//! object are `file.rs`.

pub mod disk;
pub mod file;
pub mod upload;

pub use file::RemoteFile;

use object_store::path::Path as ObjPath;
use object_store::{ObjectStore, ObjectStoreExt};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, OnceLock};
use std::time::Duration;

pub use crate::location::{file_url_path, is_url};

fn runtime() -> &'static tokio::runtime::Runtime {
    static RT: OnceLock<tokio::runtime::Runtime> = OnceLock::new();
    RT.get_or_init(|| {
        // TLS through rustls with ring (reqwest is built without a provider).
        let _ = rustls::crypto::ring::default_provider().install_default();
        tokio::runtime::Builder::new_multi_thread()
            .worker_threads(2)
            .thread_name("pcimg-net")
            .enable_all()
            .build()
            .expect("cannot start the network runtime")
    })
}

/// Runs `f` on the network runtime and waits for it (never called from inside it).
pub fn block_on<F: std::future::Future>(f: F) -> F::Output {
    runtime().block_on(f)
}

/// What the network has done so far in this process (the inspector's status line).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Stats {
    /// Requests sent (retries included: object_store retries within one).
    pub requests: u64,
    pub in_flight: u64,
    /// Body bytes received.
    pub bytes: u64,
    /// Requests that failed after their retries.
    pub failed: u64,
}

static REQUESTS: AtomicU64 = AtomicU64::new(0);
static IN_FLIGHT: AtomicU64 = AtomicU64::new(0);
static BYTES: AtomicU64 = AtomicU64::new(0);
static FAILED: AtomicU64 = AtomicU64::new(0);

/// The process's network counters.
pub fn stats() -> Stats {
    Stats {
        requests: REQUESTS.load(Ordering::Relaxed),
        in_flight: IN_FLIGHT.load(Ordering::Relaxed),
        bytes: BYTES.load(Ordering::Relaxed),
        failed: FAILED.load(Ordering::Relaxed),
    }
}

/// Counts one request from start to end.
struct InFlight;
impl InFlight {
    fn start(remote: &Remote) -> InFlight {
        remote.requests.fetch_add(1, Ordering::Relaxed);
        REQUESTS.fetch_add(1, Ordering::Relaxed);
        IN_FLIGHT.fetch_add(1, Ordering::Relaxed);
        InFlight
    }
    fn done(self, bytes: u64, ok: bool) {
        BYTES.fetch_add(bytes, Ordering::Relaxed);
        if !ok {
            FAILED.fetch_add(1, Ordering::Relaxed);
        }
    }
}
impl Drop for InFlight {
    fn drop(&mut self) {
        IN_FLIGHT.fetch_sub(1, Ordering::Relaxed);
    }
}

/// A dataset's location in object storage: the store and the prefix under it.
#[derive(Debug, Clone)]
pub struct Remote {
    pub store: Arc<dyn ObjectStore>,
    pub prefix: ObjPath,
    /// The URL as given, without a trailing `/` (messages).
    pub url: String,
    /// Requests sent through this dataset (tests, benchmarks).
    pub requests: Arc<AtomicU64>,
}

/// Retries with exponential backoff (object_store's), bounded so that a dead
/// server is reported within seconds rather than minutes.
fn retry() -> object_store::RetryConfig {
    object_store::RetryConfig {
        backoff: object_store::BackoffConfig {
            init_backoff: Duration::from_millis(100),
            max_backoff: Duration::from_secs(2),
            base: 2.0,
        },
        max_retries: 4,
        retry_timeout: Duration::from_secs(20),
    }
}

impl Remote {
    /// The store a URL names, configured from the environment as each cloud's own
    /// tools are (`AWS_*` with `AWS_ENDPOINT`/`AWS_ENDPOINT_URL` and
    /// `AWS_ALLOW_HTTP` for S3-compatible servers, `GOOGLE_*`, `AZURE_*`).
    pub fn open(url: &str) -> Result<Remote, String> {
        // The client is made here: TLS (ring) must be installed first.
        let _ = runtime();
        let trimmed = url.trim_end_matches('/');
        let u = url::Url::parse(trimmed).map_err(|e| format!("{trimmed}: not a URL: {e}"))?;
        let fail = |e: object_store::Error| format!("{trimmed}: {}", explain(&e));
        let (scheme, path) = object_store::ObjectStoreScheme::parse(&u).map_err(|e| {
            format!("{trimmed}: not an object-store URL this pcimg reads ({e}); use s3://, gs://, az://, http(s):// or file://")
        })?;
        use object_store::ObjectStoreScheme as S;
        let store: Arc<dyn ObjectStore> = match scheme {
            S::AmazonS3 => Arc::new(
                object_store::aws::AmazonS3Builder::from_env()
                    .with_url(trimmed)
                    .with_retry(retry())
                    .build()
                    .map_err(fail)?,
            ),
            S::GoogleCloudStorage => Arc::new(
                object_store::gcp::GoogleCloudStorageBuilder::from_env()
                    .with_url(trimmed)
                    .with_retry(retry())
                    .build()
                    .map_err(fail)?,
            ),
            S::MicrosoftAzure => Arc::new(
                object_store::azure::MicrosoftAzureBuilder::from_env()
                    .with_url(trimmed)
                    .with_retry(retry())
                    .build()
                    .map_err(fail)?,
            ),
            S::Http => Arc::new(
                object_store::http::HttpBuilder::new()
                    .with_url(&u[..url::Position::BeforePath])
                    .with_retry(retry())
                    .build()
                    .map_err(fail)?,
            ),
            other => {
                return Err(format!(
                    "{trimmed}: {other:?} URLs are not read remotely; use s3://, gs://, az:// or http(s)://"
                ));
            }
        };
        let prefix = ObjPath::parse(path.as_ref()).map_err(|e| format!("{trimmed}: {e}"))?;
        Ok(Remote {
            store,
            prefix,
            url: trimmed.to_string(),
            requests: Default::default(),
        })
    }

    /// A dataset in a given store (tests: an in-memory store).
    pub fn with_store(store: Arc<dyn ObjectStore>, prefix: &str, url: &str) -> Remote {
        Remote {
            store,
            prefix: ObjPath::from(prefix),
            url: url.trim_end_matches('/').to_string(),
            requests: Default::default(),
        }
    }

    /// The object `name` (`/`-separated, relative to the prefix).
    pub fn location(&self, name: &str) -> ObjPath {
        let mut p = self.prefix.clone();
        for part in name.split('/').filter(|s| !s.is_empty()) {
            p = p.clone().join(part);
        }
        p
    }

    /// The URL of `name`, for messages.
    pub fn url_of(&self, name: &str) -> String {
        if name.is_empty() {
            self.url.clone()
        } else {
            format!("{}/{name}", self.url)
        }
    }

    /// The whole object `name`, its size and ETag; `Ok(None)` when it is absent.
    pub fn get(&self, name: &str) -> Result<Option<(bytes::Bytes, u64, Option<String>)>, String> {
        let store = self.store.clone();
        let loc = self.location(name);
        let shown = self.url_of(name);
        let this = self;
        block_on(async move {
            let f = InFlight::start(this);
            let r = async {
                let got = store.get_opts(&loc, Default::default()).await?;
                let (size, etag) = (got.meta.size, got.meta.e_tag.clone());
                Ok::<_, object_store::Error>((got.bytes().await?, size, etag))
            }
            .await;
            match r {
                Ok((b, size, etag)) => {
                    f.done(b.len() as u64, true);
                    Ok(Some((b, size, etag)))
                }
                Err(object_store::Error::NotFound { .. }) => {
                    f.done(0, true);
                    Ok(None)
                }
                Err(e) => {
                    f.done(0, false);
                    Err(format!("{shown}: {}", explain(&e)))
                }
            }
        })
    }

    /// Whether the object `name` exists (one HEAD request).
    pub fn exists(&self, name: &str) -> Result<bool, String> {
        let loc = self.location(name);
        let f = InFlight::start(self);
        match block_on(self.store.head(&loc)) {
            Ok(_) => {
                f.done(0, true);
                Ok(true)
            }
            Err(object_store::Error::NotFound { .. }) => {
                f.done(0, true);
                Ok(false)
            }
            Err(e) => {
                f.done(0, false);
                Err(format!("{}: {}", self.url_of(name), explain(&e)))
            }
        }
    }

    /// The name of some object under the prefix, if any (one listing request).
    pub fn first_object(&self) -> Result<Option<String>, String> {
        use futures_util::StreamExt;
        let f = InFlight::start(self);
        let mut list = self.store.list(Some(&self.prefix));
        match block_on(list.next()) {
            None => {
                f.done(0, true);
                Ok(None)
            }
            Some(Ok(meta)) => {
                f.done(0, true);
                Ok(Some(meta.location.to_string()))
            }
            Some(Err(e)) => {
                f.done(0, false);
                Err(format!("{}: {}", self.url, explain(&e)))
            }
        }
    }

    /// A ranged reader of the object `name`.
    pub fn file(self: &Arc<Self>, name: &str) -> RemoteFile {
        RemoteFile::new(self.clone(), name)
    }

    /// A ranged reader of the object `name` whose size and ETag are known (the
    /// dataset index records them): no request asks for them.
    pub fn file_pinned(self: &Arc<Self>, name: &str, size: u64, etag: String) -> RemoteFile {
        RemoteFile::pinned(self.clone(), name, size, etag)
    }
}

/// What went wrong and what to do about it, from an object_store error.
pub fn explain(e: &object_store::Error) -> String {
    use object_store::Error as E;
    let text = e.to_string();
    let lower = text.to_ascii_lowercase();
    match e {
        E::NotFound { .. } => "not found (404): check the bucket and the path".into(),
        E::PermissionDenied { .. } => {
            "access denied (403): check the credentials (AWS_ACCESS_KEY_ID and AWS_SECRET_ACCESS_KEY, GOOGLE_APPLICATION_CREDENTIALS, AZURE_STORAGE_ACCOUNT_KEY) and that they may read this bucket".into()
        }
        E::Unauthenticated { .. } => {
            "not authenticated (401): set the credentials (AWS_ACCESS_KEY_ID and AWS_SECRET_ACCESS_KEY, GOOGLE_APPLICATION_CREDENTIALS, AZURE_STORAGE_ACCOUNT_KEY)".into()
        }
        E::Precondition { .. } => {
            "changed while being read (its ETag no longer matches): open the dataset again".into()
        }
        _ if lower.contains("non-partial") => {
            "the server ignores range requests (it answered 200 with the whole object); pcimg reads tiles by range: serve the dataset from a server that supports HTTP Range".into()
        }
        _ if lower.contains("403") || lower.contains("accessdenied") || lower.contains("signaturedoesnotmatch") || lower.contains("invalidaccesskeyid") => format!(
            "access denied (403): check the credentials (AWS_ACCESS_KEY_ID, AWS_SECRET_ACCESS_KEY) ({})",
            crate::text::sanitize(&text)
        ),
        _ if lower.contains("nosuchbucket") || lower.contains("404") => format!(
            "not found (404): check the bucket and the path ({})",
            crate::text::sanitize(&text)
        ),
        _ if lower.contains("credential") || lower.contains("missing") && lower.contains("key") => format!(
            "no credentials: set AWS_ACCESS_KEY_ID and AWS_SECRET_ACCESS_KEY (or GOOGLE_*, AZURE_* for those clouds) ({})",
            crate::text::sanitize(&text)
        ),
        _ if lower.contains("connect") || lower.contains("dns") => format!(
            "cannot reach the server: check AWS_ENDPOINT (and AWS_ALLOW_HTTP=true for http://) ({})",
            crate::text::sanitize(&text)
        ),
        _ => crate::text::sanitize(&text),
    }
}
