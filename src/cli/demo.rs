//! `pcimg demo`: builds a synthetic dataset in a temporary directory and opens the
//! inspector on it (or, without a terminal, prints its report).

use crate::store::{self, WriteOptions};
use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

#[derive(Debug, clap::Args)]
pub struct Args {
    /// Points in the synthetic scan, 1 to 50,000,000 (the demo builds them in
    /// memory; for more, `pcimg synth` a file and `pcimg convert` it).
    #[arg(short = 'n', long, default_value_t = 2_000_000,
          value_parser = clap::value_parser!(u64).range(1..=50_000_000))]
    pub points: u64,
    /// Keep the dataset in this directory (as DIR/demo.tif) instead of a
    /// temporary one; a demo.tif already there is replaced only if an earlier
    /// demo wrote it.
    #[arg(long)]
    pub keep: Option<PathBuf>,
    /// Image protocol of the inspector: auto, kitty, sixel, iterm or text.
    #[arg(long, default_value = "auto")]
    pub protocol: crate::term::Protocol,
    /// Symbols of the text protocol: half, quadrants, sextants, octants or
    /// braille (default: by terminal).
    #[arg(long)]
    pub symbols: Option<crate::term::symbols::SymbolSet>,
}

pub fn run(a: Args) -> anyhow::Result<()> {
    super::inspect::no_device_select();
    let interactive = super::inspect::have_terminal();
    // The temporary directory (unless --keep) has an unpredictable name and is
    // removed when `tmp` drops: on return, on error and on a panic.
    let mut tmp: Option<TempDir> = None;
    let dir = match &a.keep {
        Some(d) => {
            if d.exists() && !d.is_dir() {
                anyhow::bail!("--keep {}: not a directory", d.display());
            }
            std::fs::create_dir_all(d)
                .map_err(|e| anyhow::anyhow!("--keep {}: {e}", d.display()))?;
            d.clone()
        }
        None => {
            let t = TempDir::create()?;
            let d = t.path().to_path_buf();
            tmp = Some(t);
            d
        }
    };
    let path = dir.join("demo.tif");
    if a.keep.is_some() && std::fs::symlink_metadata(&path).is_ok() && !earlier_demo(&path) {
        anyhow::bail!(
            "{} exists and is not a dataset an earlier demo wrote: keep the demo in another directory",
            path.display()
        );
    }
    let cancel = on_interrupt(tmp.as_ref().map(|t| t.path().to_path_buf()));
    note!(
        "pcimg demo: generating {} synthetic points…",
        crate::text::count(a.points)
    );
    let t = std::time::Instant::now();
    let pts = crate::synth::scene(a.points, 1);
    let opts = WriteOptions {
        source: Some(DEMO_SOURCE.into()),
        cancel: Some(cancel),
        ..Default::default()
    };
    let s = store::write_part(&path, &pts, &opts)?;
    drop(pts);
    note!(
        "pcimg demo: wrote {} ({}) in {:.2} s",
        path.display(),
        crate::text::bytes(s.bytes),
        t.elapsed().as_secs_f64()
    );
    let ds = store::Dataset::open(&path)?;
    if interactive {
        let mut args = super::inspect::defaults(&path);
        args.protocol = a.protocol;
        args.symbols = a.symbols;
        let temporary = tmp.as_ref().map(|t| t.path());
        return super::inspect::open(std::sync::Arc::new(ds), &args, temporary);
    }
    let mut report = super::info::render_text(&super::info::report(&ds, false));
    report.push_str(&match &a.keep {
        Some(_) => format!(
            "(stdout is not a terminal, so the inspector did not open: look at the dataset with \
             `pcimg render {0} -o frame.png` or `pcimg preview {0}`)\n",
            path.display()
        ),
        None => "(stdout is not a terminal, so the inspector did not open. Keep the dataset with \
                 `pcimg demo --keep DIR`, then look at it with `pcimg render DIR/demo.tif -o frame.png` \
                 or `pcimg preview DIR/demo.tif`.)\n"
            .to_string(),
    });
    // Removed before printing: a reader that closes the pipe early ends the command.
    drop(ds);
    drop(tmp);
    super::print_out(&report)
}

/// Ctrl-C, SIGTERM, SIGHUP: passed on to the inspector while it runs; before
/// that, the returned flag stops the write (which removes its file), and should
/// the command not end within 5 s (still generating points) the temporary
/// directory is removed and the process ends.
fn on_interrupt(temporary: Option<std::path::PathBuf>) -> Arc<AtomicBool> {
    let cancel = Arc::new(AtomicBool::new(false));
    let flag = cancel.clone();
    let _ = ctrlc::set_handler(move || {
        if crate::tui::running() {
            crate::tui::on_signal();
            return;
        }
        flag.store(true, Ordering::SeqCst);
        std::thread::sleep(std::time::Duration::from_secs(5));
        if let Some(t) = &temporary {
            let _ = std::fs::remove_dir_all(t);
        }
        note!("pcimg: interrupted: nothing was kept");
        std::process::exit(130);
    });
    cancel
}

/// The demo's temporary directory, removed when dropped.
struct TempDir(PathBuf);

impl TempDir {
    /// A new directory `pcimg-demo-PID-NANOS` in the system's temporary
    /// directory (created with `create_dir`: never an existing one, never its
    /// missing parents).
    fn create() -> anyhow::Result<TempDir> {
        let nanos = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| d.subsec_nanos());
        let path =
            std::env::temp_dir().join(format!("pcimg-demo-{}-{nanos:08x}", std::process::id()));
        std::fs::create_dir(&path).map_err(|e| {
            anyhow::anyhow!(
                "cannot create the temporary directory {}: {e}",
                path.display()
            )
        })?;
        Ok(TempDir(path))
    }

    fn path(&self) -> &std::path::Path {
        &self.0
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

/// Whether `path` is a part an earlier `pcimg demo` wrote (its source is the
/// synthetic scene).
fn earlier_demo(path: &std::path::Path) -> bool {
    crate::store::Part::open(path)
        .is_ok_and(|p| matches!(p.meta.source.as_deref(), Some(DEMO_SOURCE | "pcimg synth")))
}

/// The source the demo's dataset records.
const DEMO_SOURCE: &str = "pcimg demo";
