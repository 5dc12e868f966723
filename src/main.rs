//! The `pcimg` command line: argument parsing and dispatch only.

use clap::Parser;
use std::io::Write;

fn main() -> std::process::ExitCode {
    let args: Vec<std::ffi::OsString> = std::env::args_os().collect();
    if let Some(msg) = pcimg::cli::misspelt_command(&args) {
        let _ = writeln!(std::io::stderr(), "pcimg: {msg}");
        return std::process::ExitCode::from(2);
    }
    let cli = pcimg::cli::Cli::parse_from(args);
    match pcimg::cli::run(cli) {
        Ok(()) => std::process::ExitCode::SUCCESS,
        // A reader that closed stdout (`pcimg info X | head`): nothing to say.
        Err(e) if e.is::<pcimg::cli::ClosedPipe>() => std::process::ExitCode::from(141),
        Err(e) => {
            let _ = writeln!(
                std::io::stderr(),
                "pcimg: {}",
                pcimg::text::sanitize_multiline(&format!("{e:#}"))
            );
            std::process::ExitCode::FAILURE
        }
    }
}
