//! The command line: one file per command; `main.rs` only parses and dispatches.

/// `eprintln!` that never panics: a message to a closed stderr (`2>&1 | head`)
/// is dropped, and the command goes on (and cleans up) instead of panicking.
macro_rules! note {
    ($($arg:tt)*) => {{
        use std::io::Write as _;
        let _ = writeln!(std::io::stderr(), $($arg)*);
    }};
}

pub mod convert;
pub mod demo;
pub mod doctor;
pub mod export;
pub mod index;
pub mod info;
pub mod inspect;
pub mod preview;
pub mod remote;
pub mod render;
pub mod stats;
pub mod synth;
pub mod turntable;
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
    /// List a dataset's parts, bands, pyramid levels, bounds and metadata (or a
    /// COPC file's or EPT dataset's octree).
    Info(info::Args),
    /// Convert a point cloud (text, PLY, LAS/LAZ, PCD, E57, COPC, EPT) into an
    /// image dataset, out of core.
    Convert(convert::Args),
    /// Write a dataset's points (all, a level's even sample, a box, some classes)
    /// as LAS, LAZ, PLY, CSV or XYZ.
    Export(export::Args),
    /// Statistics of a dataset's bands (range, mean, percentiles, histogram), its
    /// classes and its point density (from an even sample, or --exact).
    Stats(stats::Args),
    /// Rebuild a dataset directory's index and overview (for parts made separately), or
    /// index COPC files (a directory or a list) as one survey, with no conversion.
    Index(index::Args),
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
    /// Ask the terminal what it draws and say which image protocol and cell size
    /// `preview` and `inspect` would use (for bug reports).
    Doctor(doctor::Args),
}

/// stdout was closed by its reader (`pcimg info X | head`): the command ends
/// quietly (exit status 141, as a shell reports a command that SIGPIPE ended).
#[derive(Debug, thiserror::Error)]
#[error("stdout was closed")]
pub struct ClosedPipe;

/// Writes `text` to stdout. A closed pipe is [`ClosedPipe`], not a panic: the
/// process keeps SIGPIPE ignored (Rust's default) so that a closed stderr or
/// stdout never kills a conversion before it cleans up.
pub fn print_out(text: &str) -> anyhow::Result<()> {
    use std::io::Write;
    let mut out = std::io::stdout().lock();
    match out.write_all(text.as_bytes()).and_then(|()| out.flush()) {
        Err(e) if e.kind() == std::io::ErrorKind::BrokenPipe => Err(ClosedPipe.into()),
        r => Ok(r?),
    }
}

/// The commands' names, for [`misspelt_command`]: those of clap's definition
/// of [`Cli`], with the `help` it adds.
fn commands() -> Vec<String> {
    let mut cli = <Cli as clap::CommandFactory>::command();
    cli.build();
    cli.get_subcommands()
        .map(|c| c.get_name().to_string())
        .collect()
}

/// When the first argument is neither a command nor an existing path but is
/// within two edits of a command's name (`pcimg conver x.xyz`), the message to
/// print instead of clap's, which would take it for a dataset path.
pub fn misspelt_command(args: &[std::ffi::OsString]) -> Option<String> {
    let first = args.get(1)?.to_str()?;
    if first.starts_with('-') {
        return None;
    }
    let commands = commands();
    if commands.iter().any(|c| c == first) || std::path::Path::new(first).exists() {
        return None;
    }
    let lower = first.to_ascii_lowercase();
    let best = commands
        .iter()
        .map(|c| (edit_distance(&lower, c), c.as_str()))
        .min()?;
    (best.0 <= 2).then(|| {
        format!(
            "no command '{}' (and no such file): did you mean `pcimg {}`? See `pcimg --help`.",
            crate::text::sanitize(first),
            best.1
        )
    })
}

/// Levenshtein distance between two short strings.
fn edit_distance(a: &str, b: &str) -> usize {
    let b: Vec<char> = b.chars().collect();
    let mut row: Vec<usize> = (0..=b.len()).collect();
    for (i, ca) in a.chars().enumerate() {
        let mut prev = row[0];
        row[0] = i + 1;
        for (j, cb) in b.iter().enumerate() {
            let here = row[j + 1];
            row[j + 1] = (prev + usize::from(ca != *cb))
                .min(row[j] + 1)
                .min(here + 1);
            prev = here;
        }
    }
    row[b.len()]
}

/// Runs the parsed command.
pub fn run(cli: Cli) -> anyhow::Result<()> {
    let Some(command) = cli.command else {
        let path = cli
            .path
            .ok_or_else(|| anyhow::anyhow!("give a command or a dataset path (see --help)"))?;
        return inspect::run(inspect::defaults(&path)).map_err(crate::advice::with_advice);
    };
    let net_stats = command.net_stats();
    let r = match command {
        Command::Inspect(a) => inspect::run(a),
        Command::Info(a) => info::run(a),
        Command::Convert(a) => convert::run(a),
        Command::Export(a) => export::run(a),
        Command::Stats(a) => stats::run(a),
        Command::Index(a) => index::run(a),
        Command::Demo(a) => demo::run(a),
        Command::Render(a) => render::run(a),
        Command::Preview(a) => preview::run(a),
        Command::Synth(a) => synth::run(a),
        Command::Doctor(a) => doctor::run(a),
    };
    remote::print_stats_if_asked(net_stats);
    r.map_err(crate::advice::with_advice)
}

impl Command {
    /// Whether `--net-stats` was given (the commands that read or write object
    /// storage take it).
    fn net_stats(&self) -> bool {
        match self {
            Command::Info(a) => a.cache.net_stats,
            Command::Convert(a) => a.net_stats,
            Command::Export(a) => a.cache.net_stats,
            Command::Stats(a) => a.cache.net_stats,
            Command::Inspect(a) => a.view.cache.net_stats,
            Command::Render(a) => a.view.cache.net_stats,
            Command::Preview(a) => a.view.cache.net_stats,
            Command::Index(_) | Command::Demo(_) | Command::Synth(_) | Command::Doctor(_) => false,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn misspelt_commands_are_named() {
        let args = |v: &[&str]| {
            v.iter()
                .map(Into::into)
                .collect::<Vec<std::ffi::OsString>>()
        };
        let m = misspelt_command(&args(&["pcimg", "conver", "x.xyz"])).unwrap();
        assert!(
            m.contains("'conver'") && m.contains("`pcimg convert`"),
            "{m}"
        );
        assert!(
            misspelt_command(&args(&["pcimg", "infoo"]))
                .unwrap()
                .contains("pcimg info")
        );
        assert_eq!(misspelt_command(&args(&["pcimg", "convert", "x"])), None);
        assert_eq!(misspelt_command(&args(&["pcimg", "--help"])), None);
        assert_eq!(misspelt_command(&args(&["pcimg", "city.pcimg"])), None);
        assert_eq!(misspelt_command(&args(&["pcimg", "."])), None);
        assert_eq!(edit_distance("kitten", "sitting"), 3);
        assert!(
            misspelt_command(&args(&["pcimg", "INFO"]))
                .unwrap()
                .contains("pcimg info")
        );
        assert!(
            misspelt_command(&args(&["pcimg", "hlep"]))
                .unwrap()
                .contains("pcimg help")
        );
        assert!(
            misspelt_command(&args(&["pcimg", "docter"]))
                .unwrap()
                .contains("`pcimg doctor`")
        );
    }

    #[test]
    fn every_command_is_known_for_misspellings() {
        let known = commands();
        // Every subcommand clap parses (each parsed on its own, so a new
        // variant of `Command` is covered without editing this list)...
        let cli = <Cli as clap::CommandFactory>::command();
        for sub in cli.get_subcommands() {
            assert!(
                known.iter().any(|k| k == sub.get_name()),
                "{}",
                sub.get_name()
            );
        }
        // ... and, by name, the ones there are today and clap's `help`.
        for name in [
            "info", "convert", "export", "stats", "index", "inspect", "demo", "render", "preview",
            "synth", "doctor", "help",
        ] {
            assert!(
                known.iter().any(|k| k == name),
                "{name} missing from {known:?}"
            );
        }
        // A command's own name is never taken for a misspelling.
        for name in &known {
            let args: Vec<std::ffi::OsString> = vec!["pcimg".into(), name.into()];
            assert_eq!(misspelt_command(&args), None, "{name}");
        }
    }
}
