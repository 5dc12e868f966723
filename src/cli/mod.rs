//! The command line: one file per command; `main.rs` only parses and dispatches.

pub mod convert;
pub mod demo;
pub mod info;
pub mod inspect;
pub mod preview;
pub mod render;
pub mod synth;
pub mod view;

use clap::{Parser, Subcommand};

/// pcimg: massive point clouds as multi-band image pyramids, viewed from a terminal.
#[derive(Debug, Parser)]
#[command(
    name = "pcimg",
    version,
    about,
    long_about = None,
    args_conflicts_with_subcommands = true,
    arg_required_else_help = true
)]
pub struct Cli {
    #[command(subcommand)]
    pub command: Option<Command>,
    /// A dataset to open in the inspector (the same as `pcimg inspect PATH`).
    pub path: Option<std::path::PathBuf>,
}

#[derive(Debug, Subcommand)]
pub enum Command {
    /// List a dataset's parts, bands, pyramid levels, bounds and metadata.
    Info(info::Args),
    /// Convert a point cloud (text, PLY, LAS/LAZ) into an image dataset, out of core.
    Convert(convert::Args),
    /// Browse a dataset in the terminal: parts, bands, levels and a live view.
    Inspect(inspect::Args),
    /// Build a synthetic dataset in a temporary directory and open the inspector on it.
    Demo(demo::Args),
    /// Render one frame of a dataset to a PNG, headless.
    Render(render::Args),
    /// Print one frame inline in the terminal (kitty, sixel, iTerm2, half-blocks).
    Preview(preview::Args),
    /// Write a deterministic synthetic scan as text, LAS or LAZ.
    Synth(synth::Args),
}

/// Runs the parsed command.
pub fn run(cli: Cli) -> anyhow::Result<()> {
    let Some(command) = cli.command else {
        let path = cli
            .path
            .ok_or_else(|| anyhow::anyhow!("give a command or a dataset path (see --help)"))?;
        return inspect::run(inspect::defaults(&path));
    };
    match command {
        Command::Inspect(a) => inspect::run(a),
        Command::Info(a) => info::run(a),
        Command::Convert(a) => convert::run(a),
        Command::Demo(a) => demo::run(a),
        Command::Render(a) => render::run(a),
        Command::Preview(a) => preview::run(a),
        Command::Synth(a) => synth::run(a),
    }
}
