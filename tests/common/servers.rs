//! Test servers started the way users start them, on free ports of
//! 127.0.0.1, waited for until they answer (never a fixed sleep) and stopped
//! by a guard even when the test fails: `python3 -m http.server` serving a
//! folder, and SeaweedFS (`weed mini`) with one SigV4 identity and a bucket.
//! `None` (outside CI) when the program is missing; with CI=true a failure.

use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

/// `n` distinct free TCP ports of 127.0.0.1 (held together while chosen).
pub fn free_ports(n: usize) -> Vec<u16> {
    let held: Vec<std::net::TcpListener> = (0..n)
        .map(|_| std::net::TcpListener::bind("127.0.0.1:0").unwrap())
        .collect();
    held.iter()
        .map(|l| l.local_addr().unwrap().port())
        .collect()
}

/// `python3 -m http.server` serving a folder (one that can also be stopped and
/// started again on its port).
#[allow(unused_imports)]
pub use super::http::HttpServer;

pub const WEED_KEY: &str = "pcimgtestkey";
pub const WEED_SECRET: &str = "pcimgtestsecret";
pub const WEED_BUCKET: &str = "pcimg";

/// A SeaweedFS server (`weed mini`), killed and reaped on drop.
pub struct Weed {
    child: Child,
    pub port: u16,
    dir: tempfile::TempDir,
}

impl Drop for Weed {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

impl Weed {
    /// Starts `weed mini` with one identity and the bucket, and waits (at most
    /// 60 s) until the bucket lists. The free ports are chosen by binding and
    /// letting go, so another process can take one before weed binds it: weed
    /// then exits saying "address already in use", and is started again on
    /// other ports (up to 5 times).
    pub fn start() -> Option<Weed> {
        if !super::tool_available("weed", "version") {
            return None;
        }
        for _ in 0..5 {
            match Weed::try_start() {
                Ok(w) => return Some(w),
                Err(log) if log.contains("address already in use") => continue,
                Err(log) => {
                    panic!("SeaweedFS did not serve the bucket within 60 s; its log:\n{log}")
                }
            }
        }
        panic!("SeaweedFS found a port taken on each of 5 starts");
    }

    /// One start: the server, or its log when it exited or did not serve the
    /// bucket within 60 s.
    fn try_start() -> Result<Weed, String> {
        let dir = tempfile::tempdir().unwrap();
        let config = dir.path().join("s3.json");
        std::fs::write(
            &config,
            format!(
                r#"{{"identities":[{{"name":"pcimg","credentials":[{{"accessKey":"{WEED_KEY}","secretKey":"{WEED_SECRET}"}}],"actions":["Admin","Read","Write","List","Tagging"]}}]}}"#
            ),
        )
        .unwrap();
        let data = dir.path().join("data");
        std::fs::create_dir(&data).unwrap();
        let p = free_ports(10);
        let log = std::fs::File::create(dir.path().join("weed.log")).unwrap();
        let child = Command::new("weed")
            .arg("mini")
            .arg(format!("-dir={}", data.display()))
            .args(["-ip=127.0.0.1", "-ip.bind=127.0.0.1"])
            .arg(format!("-master.port={}", p[0]))
            .arg(format!("-master.port.grpc={}", p[1]))
            .arg(format!("-volume.port={}", p[2]))
            .arg(format!("-volume.port.grpc={}", p[3]))
            .arg(format!("-filer.port={}", p[4]))
            .arg(format!("-filer.port.grpc={}", p[5]))
            .arg(format!("-s3.port={}", p[6]))
            .arg(format!("-s3.port.grpc={}", p[7]))
            .arg(format!("-admin.port={}", p[8]))
            .arg(format!("-admin.port.grpc={}", p[9]))
            .args(["-admin.ui=false", "-webdav=false"])
            .args(["-s3.port.iceberg=0", "-s3.port.lance=0"])
            .arg(format!("-s3.config={}", config.display()))
            .arg(format!("-bucket={WEED_BUCKET}"))
            .stdin(Stdio::null())
            .stdout(log.try_clone().unwrap())
            .stderr(log)
            .spawn()
            .expect("cannot start weed");
        let mut w = Weed {
            child,
            port: p[6],
            dir,
        };
        let start = Instant::now();
        let log =
            |w: &Weed| std::fs::read_to_string(w.dir.path().join("weed.log")).unwrap_or_default();
        loop {
            if w.list("").is_ok() {
                return Ok(w);
            }
            if w.child.try_wait().ok().flatten().is_some()
                || start.elapsed() >= Duration::from_secs(60)
            {
                return Err(log(&w));
            }
            std::thread::sleep(Duration::from_millis(100));
        }
    }

    pub fn addr(&self) -> std::net::SocketAddr {
        std::net::SocketAddr::from(([127, 0, 0, 1], self.port))
    }

    pub fn endpoint(&self) -> String {
        format!("http://127.0.0.1:{}", self.port)
    }

    /// The server's bucket, reached by the test itself (straight, not through
    /// any proxy), and a runtime to wait on it.
    fn store(
        &self,
    ) -> object_store::Result<(object_store::aws::AmazonS3, tokio::runtime::Runtime)> {
        // reqwest is built without a TLS provider (as pcimg installs ring).
        let _ = rustls::crypto::ring::default_provider().install_default();
        let store = object_store::aws::AmazonS3Builder::new()
            .with_endpoint(self.endpoint())
            .with_allow_http(true)
            .with_bucket_name(WEED_BUCKET)
            .with_region("us-east-1")
            .with_access_key_id(WEED_KEY)
            .with_secret_access_key(WEED_SECRET)
            .with_retry(object_store::RetryConfig {
                max_retries: 0,
                ..Default::default()
            })
            .build()?;
        let rt = tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
            .unwrap();
        Ok((store, rt))
    }

    /// The objects under `prefix` and their sizes, listed by the test itself
    /// (straight from the server, not through any proxy).
    pub fn list(&self, prefix: &str) -> object_store::Result<Vec<(String, u64)>> {
        use futures_util::TryStreamExt;
        use object_store::ObjectStore;
        let (store, rt) = self.store()?;
        let prefix = (!prefix.is_empty()).then(|| object_store::path::Path::from(prefix));
        let got: Vec<object_store::ObjectMeta> =
            rt.block_on(store.list(prefix.as_ref()).try_collect())?;
        let mut v: Vec<(String, u64)> = got
            .into_iter()
            .map(|m| (m.location.to_string(), m.size))
            .collect();
        v.sort();
        Ok(v)
    }

    /// The object `name` of the bucket, read by the test itself.
    pub fn get(&self, name: &str) -> object_store::Result<Vec<u8>> {
        use object_store::ObjectStoreExt;
        let (store, rt) = self.store()?;
        let loc = object_store::path::Path::from(name);
        rt.block_on(async { Ok(store.get(&loc).await?.bytes().await?.to_vec()) })
    }

    /// Stores `data` as the object `name` of the bucket, by the test itself.
    pub fn put(&self, name: &str, data: Vec<u8>) -> object_store::Result<()> {
        use object_store::ObjectStoreExt;
        let (store, rt) = self.store()?;
        let loc = object_store::path::Path::from(name);
        rt.block_on(store.put(&loc, data.into()))?;
        Ok(())
    }

    /// The environment that points pcimg at this server.
    pub fn env(&self) -> Vec<(&'static str, String)> {
        vec![
            ("AWS_ENDPOINT", self.endpoint()),
            ("AWS_ALLOW_HTTP", "true".into()),
            ("AWS_REGION", "us-east-1".into()),
            ("AWS_ACCESS_KEY_ID", WEED_KEY.into()),
            ("AWS_SECRET_ACCESS_KEY", WEED_SECRET.into()),
            ("NODEVICE_SELECT", "1".into()),
        ]
    }

    /// `pcimg ARGS` with the keys of this server and `endpoint` (this server,
    /// or a proxy in front of it); no other `AWS_*` setting of the caller's.
    pub fn pcimg(&self, endpoint: &str, args: &[&str]) -> Command {
        let mut c = Command::new(env!("CARGO_BIN_EXE_pcimg"));
        for (k, _) in std::env::vars() {
            if k.starts_with("AWS_") {
                c.env_remove(k);
            }
        }
        c.args(args)
            .env("AWS_ENDPOINT", endpoint)
            .env("AWS_ALLOW_HTTP", "true")
            .env("AWS_REGION", "us-east-1")
            .env("AWS_ACCESS_KEY_ID", WEED_KEY)
            .env("AWS_SECRET_ACCESS_KEY", WEED_SECRET)
            .env("NODEVICE_SELECT", "1");
        c
    }
}
