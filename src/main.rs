//! The `pcimg` command line: argument parsing and dispatch only.

use clap::Parser;

fn main() -> std::process::ExitCode {
    // A closed pipe (`pcimg info X | head`) ends the process quietly, as it ends
    // other command-line tools, instead of a panic in `println!`.
    #[cfg(unix)]
    // SAFETY: restoring a signal's default action, before any thread exists.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
    let args: Vec<std::ffi::OsString> = std::env::args_os().collect();
    if let Some(msg) = pcimg::cli::misspelt_command(&args) {
        eprintln!("pcimg: {msg}");
        return std::process::ExitCode::from(2);
    }
    let cli = pcimg::cli::Cli::parse_from(args);
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
