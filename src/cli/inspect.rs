//! `pcimg inspect PATH` (and `pcimg PATH`): opens the terminal inspector on a
//! dataset. Refuses clearly when there is no terminal to draw on.

use super::view::{self, ViewArgs};
use crate::render::RendererChoice;
use crate::store::Dataset;
use crate::term::Protocol;
use crate::tui::app::{LodChoice, Settings};
use crate::tui::{self, InspectOptions};
use clap::Parser;
use std::io::IsTerminal;
use std::path::Path;
use std::sync::Arc;

#[derive(Debug, clap::Args)]
pub struct Args {
    #[command(flatten)]
    pub view: ViewArgs,
    /// Image protocol: auto (asks the terminal, or inside tmux the tmux server;
    /// `pcimg doctor` shows what it finds), kitty, sixel, iterm or text
    /// (symbols in colour, for terminals and links without images).
    #[arg(long, default_value = "auto")]
    pub protocol: Protocol,
    /// Symbols of the text protocol: half (blocks), quadrants, sextants,
    /// octants or braille. Default: sextants where the terminal draws them
    /// itself (kitty, WezTerm, foot, Ghostty), else quadrants (every font).
    #[arg(long)]
    pub symbols: Option<crate::term::symbols::SymbolSet>,
    /// Threads loading tiles (1 to 64).
    #[arg(long, default_value_t = 2, value_parser = clap::value_parser!(u16).range(1..=64))]
    pub load_threads: u16,
}

/// The inspector's arguments with every default, for `path`.
pub fn defaults(path: &Path) -> Args {
    #[derive(Parser)]
    struct Wrapper {
        #[command(flatten)]
        args: Args,
    }
    Wrapper::parse_from([std::ffi::OsStr::new("pcimg"), path.as_os_str()]).args
}

/// Whether stdin and stdout are a terminal the inspector can take over.
pub fn have_terminal() -> bool {
    std::io::stdout().is_terminal() && std::io::stdin().is_terminal()
}

/// Sets `NODEVICE_SELECT=1` for the process unless it is set: Mesa's Vulkan
/// device-select layer must not run (it can hang headless machines). Call before
/// any thread or GPU adapter exists.
pub fn no_device_select() {
    if std::env::var_os("NODEVICE_SELECT").is_none() {
        // SAFETY: called at the start of a command, before our threads start.
        unsafe { std::env::set_var("NODEVICE_SELECT", "1") };
    }
}

pub fn run(a: Args) -> anyhow::Result<()> {
    no_device_select();
    // The dataset first: a wrong path is the error to report, terminal or not.
    a.view.cache.apply()?;
    let ds = Arc::new(super::remote::open_for_view(&a.view.path, &a.view.cache)?);
    if let Some(h) = crate::advice::dataset_note(&ds) {
        note!("{h}");
    }
    if !have_terminal() {
        anyhow::bail!(
            "the inspector needs a terminal (stdin and stdout are not one here): use `pcimg info {0}` for a report, `pcimg render {0} -o frame.png` for an image",
            a.view.path.display()
        );
    }
    open(ds, &a, None)
}

/// Opens the inspector on an already opened dataset (`temporary`: a directory
/// to remove should the process be ended by force). With `--print-camera`, the
/// camera the session ended with is printed on stderr, for `render --camera`.
pub fn open(ds: Arc<Dataset>, a: &Args, temporary: Option<&Path>) -> anyhow::Result<()> {
    no_device_select();
    let v = &a.view;
    let lod = match view::lod_for(&v.lod, v.budget, &ds)? {
        crate::lod::LodMode::View { .. } => LodChoice::View,
        crate::lod::LodMode::Distance => LodChoice::Distance,
        crate::lod::LodMode::Fixed(k) => LodChoice::Pinned(k),
    };
    let style = view::style_for(v, &ds)?;
    let filter = view::filter_for(v, &ds)?;
    let (edl, edl_params) = view::edl_for(v)?;
    let mut extra_bands = view::bands_for(&style, &filter);
    // The legend's class toggles, the `C` key and `v` (every band in turn)
    // need the bands at hand: tiles load all of them.
    for b in ds.totals().shown_bands() {
        if !["x", "y", "z"].contains(&b.as_str()) && !extra_bands.contains(b) {
            extra_bands.push(b.clone());
        }
    }
    let settings = Settings {
        lod,
        style,
        filter,
        point_size: v.point_size,
        edl,
        edl_params,
        budget: v.budget,
        memory: v.memory,
    };
    let renderer: RendererChoice = v.renderer.parse()?;
    let camera = view::camera_for(v, &ds)?;
    let last = tui::run(
        ds,
        InspectOptions {
            protocol: a.protocol,
            symbols: a.symbols,
            renderer,
            camera,
            settings,
            extra_bands,
            load_threads: a.load_threads as usize,
            temporary: temporary.map(Path::to_path_buf),
        },
    )?;
    if v.print_camera {
        note!("{}", last.to_json());
    }
    Ok(())
}
