//! A short, deterministic run of the mutation fuzzer (`tests/common/fuzz.rs`;
//! `benches/fuzz_inputs.rs` runs it for as long as asked): damaged inputs of
//! every format and damaged dataset parts must be refused with an error, never
//! panic or abort, and a refused conversion leaves no file behind.

mod common;
use common::fuzz::{self, Outcome};
use pcimg::synth::Rng;

/// Cases a run tries (`PCIMG_FUZZ_CASES` overrides, for a longer run).
const N_CASES: u64 = 300;

#[test]
fn mutated_inputs_are_refused_cleanly() {
    let n_cases = std::env::var("PCIMG_FUZZ_CASES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(N_CASES);
    let dir = tempfile::tempdir().unwrap();
    let seeds = fuzz::seeds(dir.path(), 1500).unwrap();
    let mut rng = Rng::new(17);
    let (mut accepted, mut refused) = (0, 0);
    let mut failures = Vec::new();
    for it in 0..n_cases {
        let (ext, data, work, o) = fuzz::case(&seeds, &mut rng, dir.path(), it);
        std::fs::create_dir(&work).unwrap();
        match fuzz::run(&work, &ext, &data, &o).unwrap() {
            Outcome::Accepted => accepted += 1,
            Outcome::Refused { msg, contained } => {
                refused += 1;
                // Every error names the file it is about.
                assert!(
                    msg.contains("in.") || msg.contains("out.pcimg"),
                    "case {it}: {msg}"
                );
                if contained {
                    failures.push(format!("case {it} (.{ext}): a decoder panicked: {msg}"));
                }
            }
            Outcome::Panicked(m) => failures.push(format!("case {it} (.{ext}): panic: {m}")),
            Outcome::LeftBehind(l) => failures.push(format!("case {it} (.{ext}): left {l:?}")),
        }
        std::fs::remove_dir_all(&work).unwrap();
    }
    assert!(failures.is_empty(), "{failures:#?}");
    // The mutations reach both outcomes (a run where every case fails to parse,
    // or none does, would test little).
    assert!(
        accepted >= 20 && refused >= 100,
        "{accepted} accepted, {refused} refused"
    );
}
