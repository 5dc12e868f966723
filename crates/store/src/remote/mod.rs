//! Datasets in object storage (`s3://`, `gs://`, `az://`, `http(s)://`): the
//! `object_store` client built from a URL and the environment, one small tokio
//! runtime the blocking callers share, counters for the inspector's status line,
//! and errors that name the URL and what happened ([`RemoteError`]: the HTTP
//! status or the network condition; the command line adds what to do). Ranged,
//! cached reads of one object are `file.rs`.

pub mod copc;
pub mod disk;
pub mod file;
pub mod lock;
pub mod upload;

pub use file::RemoteFile;

use object_store::path::Path as ObjPath;
use object_store::{ObjectStore, ObjectStoreExt};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
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
struct InFlight(Arc<AtomicU64>);
impl InFlight {
    fn start(remote: &Remote) -> InFlight {
        remote.requests.fetch_add(1, Ordering::Relaxed);
        REQUESTS.fetch_add(1, Ordering::Relaxed);
        IN_FLIGHT.fetch_add(1, Ordering::Relaxed);
        InFlight(remote.received.clone())
    }
    fn done(self, bytes: u64, ok: bool) {
        BYTES.fetch_add(bytes, Ordering::Relaxed);
        self.0.fetch_add(bytes, Ordering::Relaxed);
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
#[derive(Clone)]
pub struct Remote {
    pub store: Arc<dyn ObjectStore>,
    /// The same store's multipart API where it has one (S3, GCS, Azure): large
    /// uploads then send each part, and retry it, themselves
    /// (`upload::put_parts`).
    pub multipart: Option<Arc<dyn object_store::multipart::MultipartStore>>,
    pub prefix: ObjPath,
    /// The URL as given, without a trailing `/` (messages).
    pub url: String,
    /// Requests sent through this dataset (tests, benchmarks).
    pub requests: Arc<AtomicU64>,
    /// Bytes received through this dataset (tests, benchmarks).
    pub received: Arc<AtomicU64>,
    /// Set once the server answered a ranged GET with the whole object (a
    /// static file server without Range support): objects are then fetched
    /// whole, once each, and ranges cut from them.
    pub ignores_range: Arc<AtomicBool>,
    /// Retries and timeouts.
    pub options: Options,
}

impl std::fmt::Debug for Remote {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Remote")
            .field("store", &self.store)
            .field("multipart", &self.multipart.is_some())
            .field("prefix", &self.prefix)
            .field("url", &self.url)
            .field("options", &self.options)
            .finish_non_exhaustive()
    }
}

/// How requests to object storage are retried and when one is given up: the
/// library's side of a command line's `--timeout`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Options {
    /// How long a request keeps being tried again (exponential backoff with
    /// jitter) while the server fails (HTTP 5xx, 429, 503 SlowDown), the
    /// connection is reset or the body cut short, or it stalls; then it fails
    /// ([`transient`] says which failures). A connection that sends nothing
    /// for [`Options::stall`] counts as stalled.
    pub timeout: Duration,
}

/// [`Options::timeout`]'s default.
pub const DEFAULT_TIMEOUT: Duration = Duration::from_secs(30);

impl Default for Options {
    fn default() -> Self {
        Options {
            timeout: DEFAULT_TIMEOUT,
        }
    }
}

impl Options {
    /// How long a connection may send nothing (or take to connect) before
    /// the request is taken as stalled and tried again: a quarter of the time
    /// limit, between 50 ms and 10 s (a stalled server is then reported
    /// within about the time limit, and retried a few times before).
    pub fn stall(&self) -> Duration {
        (self.timeout / 4).clamp(Duration::from_millis(50), Duration::from_secs(10))
    }

    /// The longest wait between two tries: an eighth of the time limit,
    /// between 50 ms and 4 s.
    fn max_backoff(&self) -> Duration {
        (self.timeout / 8).clamp(Duration::from_millis(50), Duration::from_secs(4))
    }

    /// object_store's own retries within one request: a few, quick
    /// (exponential backoff with decorrelated jitter from 50 ms; it retries
    /// 5xx, 429 and 408, refused and reset connections, timeouts of GET and
    /// HEAD, and a body cut short where the response has an ETag, from where
    /// it was cut), within the time limit. [`Remote::retrying`] then tries
    /// the request again, backing off further, until the time limit; a
    /// refused connection (nothing listens) is reported after these few.
    fn retry(&self) -> object_store::RetryConfig {
        object_store::RetryConfig {
            backoff: object_store::BackoffConfig {
                init_backoff: Duration::from_millis(50).min(self.max_backoff()),
                max_backoff: self.max_backoff(),
                base: 2.0,
            },
            max_retries: 3,
            retry_timeout: self.timeout,
        }
    }

    /// The client's timeouts as object_store configuration keys and values:
    /// connecting and each read within [`Options::stall`], a whole request
    /// (a large body on a slow link) within twice the time limit, at least a
    /// minute.
    fn client_keys(&self) -> [(object_store::ClientConfigKey, String); 3] {
        use object_store::ClientConfigKey as K;
        let ms = |d: Duration| format!("{}ms", d.as_millis().max(1));
        let stall = self.stall();
        [
            (K::ConnectTimeout, ms(stall.min(Duration::from_secs(5)))),
            (K::ReadTimeout, ms(stall)),
            (
                K::Timeout,
                ms((self.timeout * 2).max(Duration::from_secs(60))),
            ),
        ]
    }
}

/// `builder` with each of `config`'s keys set, or which key its store does
/// not know.
fn configure<B, K: std::str::FromStr>(
    builder: B,
    config: &[(&str, &str)],
    set: impl Fn(B, K, String) -> B,
) -> Result<B, String> {
    config.iter().try_fold(builder, |b, (k, v)| {
        let key = k
            .parse::<K>()
            .map_err(|_| format!("{k:?} is not a setting of this store"))?;
        Ok(set(b, key, v.to_string()))
    })
}

/// Waits between tries of one read: exponential, with full jitter (a random
/// wait between the first and twice the previous, at most the largest).
struct Backoff {
    next: Duration,
    first: Duration,
    max: Duration,
}

impl Backoff {
    fn new(o: &Options) -> Backoff {
        let max = o.max_backoff();
        let first = Duration::from_millis(50).min(max);
        Backoff {
            next: first,
            first,
            max,
        }
    }

    fn next(&mut self) -> Duration {
        let this = self.next;
        let hi = (this * 2).max(self.first);
        let span = (hi - self.first).as_nanos() as u64;
        let pick = if span == 0 { 0 } else { random() % span };
        self.next = (self.first + Duration::from_nanos(pick)).min(self.max);
        this
    }
}

/// A random number (the backoff's jitter): std's randomly keyed hasher.
fn random() -> u64 {
    use std::hash::{BuildHasher, Hasher};
    static N: AtomicU64 = AtomicU64::new(0);
    let mut h = std::collections::hash_map::RandomState::new().build_hasher();
    h.write_u64(N.fetch_add(1, Ordering::Relaxed));
    h.finish()
}

/// Whether a failed request is worth trying again: the server's trouble
/// (HTTP 5xx, 429 Too Many Requests, 408), the network's (a reset, cut or
/// stalled connection), or a body shorter than asked. Not a refused
/// connection (nothing listens there: object_store's few quick retries
/// suffice for a server restarting) nor an unknown host.
pub fn transient(p: &Problem) -> bool {
    match p {
        Problem::Status { status, .. } => *status >= 500 || matches!(*status, 408 | 429),
        Problem::Network { condition, .. } => !matches!(condition, Net::Refused | Net::UnknownHost),
        Problem::WrongRange { asked, bytes, .. } => *bytes < asked.end - asked.start,
        _ => false,
    }
}

impl Remote {
    /// The store a URL names, configured from the environment as each cloud's own
    /// tools are (`AWS_*` with `AWS_ENDPOINT`/`AWS_ENDPOINT_URL` and
    /// `AWS_ALLOW_HTTP` for S3-compatible servers, `GOOGLE_*`, `AZURE_*`).
    pub fn open(url: &str) -> Result<Remote, RemoteError> {
        Remote::open_with(url, &Options::default())
    }

    /// As [`Remote::open`], retrying and timing out as `options` say.
    pub fn open_with(url: &str, options: &Options) -> Result<Remote, RemoteError> {
        Remote::open_configured(url, options, &[])
    }

    /// As [`Remote::open_with`], with the store's settings given as well as
    /// read from the environment: `config` holds object_store's keys and
    /// values (`aws_endpoint`, `aws_access_key_id`, `google_service_account`,
    /// `azure_storage_account_name`, ...; see its `AmazonS3ConfigKey`,
    /// `GoogleConfigKey` and `AzureConfigKey`), which win over the
    /// environment's. For callers that hold credentials themselves (a
    /// program, a test) rather than in `AWS_*`.
    pub fn open_configured(
        url: &str,
        options: &Options,
        config: &[(&str, &str)],
    ) -> Result<Remote, RemoteError> {
        // The client is made here: TLS (ring) must be installed first.
        let _ = runtime();
        let trimmed = url.trim_end_matches('/');
        let bad = |m: String| RemoteError::new(trimmed, Problem::BadUrl(m));
        let u = url::Url::parse(trimmed).map_err(|e| bad(format!("not a URL: {e}")))?;
        let fail = |e: object_store::Error| RemoteError::new(trimmed, Problem::of(&e));
        let (scheme, path) = object_store::ObjectStoreScheme::parse(&u).map_err(|e| {
            bad(format!("not an object-store URL this pcimg reads ({e}); use s3://, gs://, az://, http(s):// or file://"))
        })?;
        use object_store::ObjectStoreScheme as S;
        let retry = options.retry();
        let keys = options.client_keys();
        /// A store, with its multipart API.
        type Both = (
            Arc<dyn ObjectStore>,
            Option<Arc<dyn object_store::multipart::MultipartStore>>,
        );
        fn both<S: ObjectStore + object_store::multipart::MultipartStore>(s: Arc<S>) -> Both {
            (s.clone(), Some(s))
        }
        let (store, multipart): Both = match scheme {
            S::AmazonS3 => both(Arc::new(
                keys.iter()
                    .fold(
                        configure(
                            object_store::aws::AmazonS3Builder::from_env().with_url(trimmed),
                            config,
                            object_store::aws::AmazonS3Builder::with_config,
                        )
                        .map_err(bad)?,
                        |b, (k, v)| {
                            b.with_config(object_store::aws::AmazonS3ConfigKey::Client(*k), v)
                        },
                    )
                    .with_retry(retry.clone())
                    .build()
                    .map_err(fail)?,
            )),
            S::GoogleCloudStorage => both(Arc::new(
                keys.iter()
                    .fold(
                        configure(
                            object_store::gcp::GoogleCloudStorageBuilder::from_env()
                                .with_url(trimmed),
                            config,
                            object_store::gcp::GoogleCloudStorageBuilder::with_config,
                        )
                        .map_err(bad)?,
                        |b, (k, v)| {
                            b.with_config(object_store::gcp::GoogleConfigKey::Client(*k), v)
                        },
                    )
                    .with_retry(retry.clone())
                    .build()
                    .map_err(fail)?,
            )),
            S::MicrosoftAzure => both(Arc::new(
                keys.iter()
                    .fold(
                        configure(
                            object_store::azure::MicrosoftAzureBuilder::from_env()
                                .with_url(trimmed),
                            config,
                            object_store::azure::MicrosoftAzureBuilder::with_config,
                        )
                        .map_err(bad)?,
                        |b, (k, v)| {
                            b.with_config(object_store::azure::AzureConfigKey::Client(*k), v)
                        },
                    )
                    .with_retry(retry.clone())
                    .build()
                    .map_err(fail)?,
            )),
            // The client refuses plain http:// unless told (`ClientOptions`
            // defaults to HTTPS only: reqwest's `https_only`, whose every
            // request then fails as a "builder error"). An http:// URL asks for
            // plain HTTP; an https:// one keeps refusing it (e.g. on a redirect).
            S::Http => (
                Arc::new(
                    object_store::http::HttpBuilder::new()
                        .with_url(&u[..url::Position::BeforePath])
                        .with_client_options(
                            keys.iter().fold(
                                object_store::ClientOptions::new()
                                    .with_allow_http(u.scheme() == "http"),
                                |o, (k, v)| o.with_config(*k, v),
                            ),
                        )
                        .with_retry(retry)
                        .build()
                        .map_err(fail)?,
                ) as Arc<dyn ObjectStore>,
                None,
            ),
            other => {
                return Err(bad(format!(
                    "{other:?} URLs are not read remotely; use s3://, gs://, az:// or http(s)://"
                )));
            }
        };
        let prefix = ObjPath::parse(path.as_ref()).map_err(|e| bad(e.to_string()))?;
        Ok(Remote {
            store,
            multipart,
            prefix,
            url: trimmed.to_string(),
            requests: Default::default(),
            received: Default::default(),
            ignores_range: Default::default(),
            options: *options,
        })
    }

    /// A dataset in a given store (tests: an in-memory store).
    pub fn with_store(store: Arc<dyn ObjectStore>, prefix: &str, url: &str) -> Remote {
        Remote {
            store,
            multipart: None,
            prefix: ObjPath::from(prefix),
            url: url.trim_end_matches('/').to_string(),
            requests: Default::default(),
            received: Default::default(),
            ignores_range: Default::default(),
            options: Options::default(),
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

    /// The whole object `name`, its size and ETag; `Ok(None)` when it is
    /// absent. Retried as [`Remote::retrying`] says (a body cut short too).
    pub fn get(
        &self,
        name: &str,
    ) -> Result<Option<(bytes::Bytes, u64, Option<String>)>, RemoteError> {
        let shown = self.url_of(name);
        block_on(self.retrying(|| self.get_once(name, &shown)))
    }

    async fn get_once(
        &self,
        name: &str,
        shown: &str,
    ) -> Result<Option<(bytes::Bytes, u64, Option<String>)>, RemoteError> {
        let loc = self.location(name);
        let f = InFlight::start(self);
        let r = async {
            let got = self.store.get_opts(&loc, Default::default()).await?;
            let (size, etag) = (got.meta.size, got.meta.e_tag.clone());
            Ok::<_, object_store::Error>((got.bytes().await?, size, etag))
        }
        .await;
        match r {
            Ok((b, size, etag)) => {
                f.done(b.len() as u64, true);
                if b.len() as u64 != size {
                    return Err(RemoteError::new(
                        shown,
                        Problem::WrongRange {
                            asked: 0..size,
                            got: 0..b.len() as u64,
                            bytes: b.len() as u64,
                        },
                    ));
                }
                Ok(Some((b, size, etag)))
            }
            Err(object_store::Error::NotFound { .. }) => {
                f.done(0, true);
                Ok(None)
            }
            Err(e) => {
                f.done(0, false);
                Err(RemoteError::new(shown, Problem::of(&e)))
            }
        }
    }

    /// Whether the object `name` exists (one HEAD request).
    pub fn exists(&self, name: &str) -> Result<bool, RemoteError> {
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
                Err(RemoteError::new(&self.url_of(name), Problem::of(&e)))
            }
        }
    }

    /// The name of some object under the prefix, if any (one listing request).
    pub fn first_object(&self) -> Result<Option<String>, RemoteError> {
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
                Err(RemoteError::new(&self.url, Problem::of(&e)))
            }
        }
    }

    /// `attempt` until it succeeds, fails for good (not [`transient`]), or
    /// the time limit ([`Options::timeout`], from the first try) would pass
    /// before the next try: object_store retries within one request, and
    /// this what it leaves (a body cut short where the response has no ETag,
    /// as from a static file server; a range shorter than asked; the rest of
    /// the time limit after object_store gave up early). The error then says
    /// how long it was tried ([`GaveUp`]).
    pub(crate) async fn retrying<T, Fut>(
        &self,
        mut attempt: impl FnMut() -> Fut,
    ) -> Result<T, RemoteError>
    where
        Fut: std::future::Future<Output = Result<T, RemoteError>>,
    {
        let start = std::time::Instant::now();
        let mut backoff = Backoff::new(&self.options);
        loop {
            match attempt().await {
                Ok(v) => return Ok(v),
                Err(mut e) if transient(&e.problem) => {
                    let wait = backoff.next();
                    let spent = start.elapsed();
                    if spent + wait > self.options.timeout {
                        e.gave_up = Some(GaveUp {
                            after: spent,
                            limit: self.options.timeout,
                        });
                        return Err(e);
                    }
                    tokio::time::sleep(wait).await;
                }
                Err(e) => return Err(e),
            }
        }
    }

    /// A ranged reader of the object `name`.
    pub fn file(self: &Arc<Self>, name: &str) -> RemoteFile {
        RemoteFile::new(self.clone(), name)
    }

    /// A ranged reader of the object `name` whose size and ETag are known (the
    /// dataset index records them): no request asks for them.
    pub(crate) fn file_pinned(self: &Arc<Self>, name: &str, size: u64, etag: String) -> RemoteFile {
        RemoteFile::pinned(self.clone(), name, size, etag)
    }
}

/// A request that failed: the URL it was for and what happened. Facts only:
/// what to do about it is the command line's to say (`src/advice.rs`).
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{}: {problem}{}", crate::text::sanitize(.url), .gave_up.map(|g| g.to_string()).unwrap_or_default())]
pub struct RemoteError {
    pub url: String,
    pub problem: Problem,
    /// Set where the request was tried again until the time limit
    /// ([`Options::timeout`]) and still failed.
    pub gave_up: Option<GaveUp>,
}

/// How long a failing request was tried before it was given up.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct GaveUp {
    /// From the first try to the last failure.
    pub after: Duration,
    /// The time limit.
    pub limit: Duration,
}

impl std::fmt::Display for GaveUp {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "; given up after {:.1} s of tries (the time limit is {:.1} s)",
            self.after.as_secs_f64(),
            self.limit.as_secs_f64()
        )
    }
}

impl RemoteError {
    pub fn new(url: &str, problem: Problem) -> RemoteError {
        RemoteError {
            url: url.to_string(),
            problem,
            gave_up: None,
        }
    }
}

/// The store's readers report errors as text (`URL: what happened`).
impl From<RemoteError> for String {
    fn from(e: RemoteError) -> String {
        e.to_string()
    }
}

/// What went wrong with a request.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Problem {
    /// Not a URL, or not one this build reads.
    BadUrl(String),
    /// HTTP 404 (or 405 from a static server; S3's `NoSuchBucket`).
    NotFound,
    /// HTTP 401 or 403; `detail`: the server's words.
    Denied { status: u16, detail: String },
    /// Any other HTTP status, after the retries; `detail`: the server's words.
    Status { status: u16, detail: String },
    /// No HTTP answer (after the retries).
    Network { condition: Net, detail: String },
    /// The server answered a ranged request with other bytes than asked for.
    WrongRange {
        asked: std::ops::Range<u64>,
        got: std::ops::Range<u64>,
        bytes: u64,
    },
    /// The object is not the one first seen (or recorded in the index); the
    /// text says what to do (these surface through the readers' text errors).
    Changed(String),
    /// A part pinned by the dataset index (its ETag) was replaced behind it;
    /// `etags`: the one found and the one the index records, where known.
    Replaced { etags: Option<(String, String)> },
    /// A plain http:// request from a client set to HTTPS only (S3 without
    /// `AWS_ALLOW_HTTP`).
    PlainHttp,
    /// Anything else: the store's own words.
    Other(String),
}

/// A network condition: what kept the request from an HTTP answer.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Net {
    /// Nothing listens at the address (the server is down, or the port wrong).
    Refused,
    /// The host name does not resolve.
    UnknownHost,
    /// No answer in time.
    TimedOut,
    /// The connection was reset or closed before the answer was complete.
    Cut,
    /// Anything else.
    Other,
}

impl std::fmt::Display for Problem {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let with = |f: &mut std::fmt::Formatter<'_>, detail: &str| {
            if detail.is_empty() {
                Ok(())
            } else {
                write!(f, " ({})", crate::text::sanitize(detail))
            }
        };
        match self {
            Problem::BadUrl(m) | Problem::Changed(m) | Problem::Other(m) => {
                f.write_str(&crate::text::sanitize(m))
            }
            Problem::NotFound => f.write_str("not found (HTTP 404)"),
            Problem::Replaced { etags: None } => f.write_str(
                "the part changed since the index was written (its ETag is not the one the \
                 dataset index records)",
            ),
            Problem::Replaced {
                etags: Some((now, then)),
            } => write!(
                f,
                "the part changed since the index was written (ETag {} now, {} in the index)",
                crate::text::sanitize(now),
                crate::text::sanitize(then)
            ),
            Problem::PlainHttp => {
                f.write_str("plain http:// refused: the client is set to HTTPS only")
            }
            Problem::Denied { status, detail } => {
                write!(f, "access denied (HTTP {status})")?;
                with(f, detail)
            }
            Problem::Status { status, detail } => {
                let reason = reqwest::StatusCode::from_u16(*status)
                    .ok()
                    .and_then(|c| c.canonical_reason())
                    .map(|r| format!(" {r}"))
                    .unwrap_or_default();
                write!(f, "the server answered HTTP {status}{reason}")?;
                with(f, detail)
            }
            Problem::Network { condition, detail } => {
                f.write_str(match condition {
                    Net::Refused => "connection refused",
                    Net::UnknownHost => "unknown host (the name does not resolve)",
                    Net::TimedOut => "no answer in time (timed out)",
                    Net::Cut => "the connection was cut before the answer was complete",
                    Net::Other => "network error",
                })?;
                with(f, detail)
            }
            Problem::WrongRange { asked, got, bytes } => write!(
                f,
                "asked for bytes {}..{}, got {}..{} ({bytes} bytes)",
                asked.start, asked.end, got.start, got.end
            ),
        }
    }
}

/// The server's words in an error, shortened (it may send a whole page).
fn short(text: &str) -> String {
    let t = crate::text::sanitize(text.trim());
    match t.char_indices().nth(200) {
        Some((i, _)) => format!("{}…", &t[..i]),
        None => t,
    }
}

impl Problem {
    /// The facts in an object_store error: its kind, the HTTP status, or the
    /// network condition found down its chain of sources.
    pub fn of(e: &object_store::Error) -> Problem {
        use object_store::Error as E;
        let text = e.to_string();
        let lower = text.to_ascii_lowercase();
        // The last words of the chain: the server's answer or the system's.
        let mut last: &dyn std::error::Error = e;
        while let Some(s) = last.source() {
            last = s;
        }
        let detail = short(&last.to_string());
        match e {
            E::NotFound { .. } => return Problem::NotFound,
            E::PermissionDenied { .. } => {
                return Problem::Denied {
                    status: 403,
                    detail,
                };
            }
            E::Unauthenticated { .. } => {
                return Problem::Denied {
                    status: 401,
                    detail,
                };
            }
            E::Precondition { .. } => {
                return Problem::Changed(
                    "changed while being read (its ETag no longer matches): open the dataset again"
                        .into(),
                );
            }
            _ => {}
        }
        if let Some(status) = status_in(&text) {
            let detail = body_in(&text);
            return match status {
                404 => Problem::NotFound,
                401 | 403 => Problem::Denied { status, detail },
                _ => Problem::Status { status, detail },
            };
        }
        if [
            "accessdenied",
            "signaturedoesnotmatch",
            "invalidaccesskeyid",
        ]
        .iter()
        .any(|w| lower.contains(w))
        {
            return Problem::Denied {
                status: 403,
                detail: short(&text),
            };
        }
        if lower.contains("nosuchbucket") {
            return Problem::NotFound;
        }
        // reqwest's `https_only` fails an http:// request as a "builder error".
        if lower.contains("builder error") {
            return Problem::PlainHttp;
        }
        if let Some(condition) = network_condition(e) {
            // The condition says it; the system's words only where it does not.
            let detail = if condition == Net::Other || condition == Net::UnknownHost {
                detail
            } else {
                String::new()
            };
            return Problem::Network { condition, detail };
        }
        Problem::Other(short(&text))
    }
}

/// The status in object_store's "Server returned non-2xx status code: 503 …".
fn status_in(text: &str) -> Option<u16> {
    let at = text.find("status code: ")? + "status code: ".len();
    let digits = text.get(at..at + 3)?;
    digits.parse().ok().filter(|s| (100..600).contains(s))
}

/// The body after "status code: 503 Service Unavailable: ".
fn body_in(text: &str) -> String {
    let at = text
        .find("status code: ")
        .map_or(0, |i| i + "status code: ".len());
    let rest = &text[at..];
    // "503 Service Unavailable: body"
    let body = rest
        .split_once(": ")
        .map(|(_, body)| body)
        .unwrap_or_default();
    // An S3 error document: its code and message ("SlowDown: Please reduce
    // your request rate.").
    let tag = |name: &str| {
        let open = format!("<{name}>");
        let at = body.find(&open)? + open.len();
        let len = body[at..].find("</")?;
        Some(body[at..at + len].trim())
    };
    match (tag("Code"), tag("Message")) {
        (Some(code), Some(message)) => short(&format!("{code}: {message}")),
        (Some(code), None) => short(code),
        _ => short(body),
    }
}

/// What kept a request from an HTTP answer, from the error's chain of sources.
fn network_condition(e: &object_store::Error) -> Option<Net> {
    use object_store::client::{HttpError, HttpErrorKind as K};
    let mut found = None;
    let mut at: Option<&(dyn std::error::Error + 'static)> = Some(e);
    while let Some(err) = at {
        if let Some(io) = err.downcast_ref::<std::io::Error>() {
            use std::io::ErrorKind as I;
            match io.kind() {
                I::ConnectionRefused => return Some(Net::Refused),
                I::TimedOut => return Some(Net::TimedOut),
                I::ConnectionReset | I::ConnectionAborted | I::BrokenPipe | I::UnexpectedEof => {
                    return Some(Net::Cut);
                }
                _ => {}
            }
        }
        let words = err.to_string().to_ascii_lowercase();
        if words.contains("connection refused") {
            return Some(Net::Refused);
        }
        if words.contains("dns error") || words.contains("failed to lookup address") {
            return Some(Net::UnknownHost);
        }
        if let Some(h) = err.downcast_ref::<HttpError>() {
            found = found.or(Some(match h.kind() {
                K::Timeout => Net::TimedOut,
                // (A connection closed before the whole answer came.)
                K::Interrupted | K::Request => Net::Cut,
                _ => Net::Other,
            }));
        }
        at = err.source();
    }
    found
}

/// What went wrong and what to do about it, from an object_store error.
pub(crate) fn explain(e: &object_store::Error) -> String {
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_backoff_grows_with_jitter_up_to_its_largest_wait() {
        let o = Options {
            timeout: Duration::from_secs(8),
        };
        assert_eq!(o.max_backoff(), Duration::from_secs(1));
        assert_eq!(o.stall(), Duration::from_secs(2));
        let mut b = Backoff::new(&o);
        let waits: Vec<Duration> = (0..40).map(|_| b.next()).collect();
        assert_eq!(waits[0], Duration::from_millis(50));
        assert!(waits.iter().all(|w| *w >= Duration::from_millis(50)));
        assert!(waits.iter().all(|w| *w <= Duration::from_secs(1)));
        // Each at most twice the one before (plus the first), and not all
        // alike (jitter).
        for p in waits.windows(2) {
            assert!(p[1] <= p[0] * 2 + Duration::from_millis(50), "{p:?}");
        }
        let distinct: std::collections::HashSet<_> = waits.iter().collect();
        assert!(distinct.len() > 10, "{waits:?}");
        // The limits of a small and a large time limit.
        let small = Options {
            timeout: Duration::from_millis(100),
        };
        assert_eq!(small.stall(), Duration::from_millis(50));
        assert_eq!(
            Options::default().stall(),
            Duration::from_millis(7500),
            "a quarter of 30 s"
        );
    }

    #[test]
    fn what_may_pass_is_tried_again() {
        let status = |status| Problem::Status {
            status,
            detail: String::new(),
        };
        let net = |condition| Problem::Network {
            condition,
            detail: String::new(),
        };
        assert!(transient(&status(500)) && transient(&status(503)) && transient(&status(429)));
        assert!(!transient(&status(400)) && !transient(&Problem::NotFound));
        assert!(transient(&net(Net::Cut)) && transient(&net(Net::TimedOut)));
        assert!(!transient(&net(Net::Refused)) && !transient(&net(Net::UnknownHost)));
        let range = |bytes| Problem::WrongRange {
            asked: 0..100,
            got: 0..100,
            bytes,
        };
        assert!(transient(&range(40)), "a body cut short");
        assert!(!transient(&range(100)));
    }

    #[test]
    fn statuses_are_read_from_object_store_words() {
        let text = "Generic HTTP error: Error performing GET http://h/x in 1s - Server returned \
                    non-2xx status code: 503 Service Unavailable: slow down";
        assert_eq!(status_in(text), Some(503));
        assert_eq!(body_in(text), "slow down");
        assert_eq!(status_in("no status here"), None);
        let s3 = "Generic S3 error: Error performing GET http://h/b/x in 1s - Server returned \
                  non-2xx status code: 503 Service Unavailable: <?xml version=\"1.0\"?>\n\
                  <Error><Code>SlowDown</Code><Message>Please reduce your request rate.\
                  </Message></Error>";
        assert_eq!(body_in(s3), "SlowDown: Please reduce your request rate.");
        let p = Problem::Status {
            status: 503,
            detail: body_in(text),
        };
        assert_eq!(
            p.to_string(),
            "the server answered HTTP 503 Service Unavailable (slow down)"
        );
        let e = RemoteError::new("http://h/d.pcimg/pcimg-index.json", Problem::NotFound);
        assert_eq!(
            e.to_string(),
            "http://h/d.pcimg/pcimg-index.json: not found (HTTP 404)"
        );
    }
}
