//! The `pcimg` command line: argument parsing and dispatch only.

use clap::Parser;

fn main() -> std::process::ExitCode {
    let cli = pcimg::cli::Cli::parse();
    match pcimg::cli::run(cli) {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!(
                "pcimg: {}",
                pcimg::text::sanitize_multiline(&format!("{e:#}"))
            );
            std::process::ExitCode::FAILURE
        }
    }
}
