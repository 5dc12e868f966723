//! The `pcimg` command line: argument parsing and dispatch only.
fn main() {}
