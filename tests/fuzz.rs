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

/// A short run of the fast mode (`tests/common/fuzz_fast.rs`; `bash
/// bench/fuzz.sh` runs a million cases of each) for every untrusted input:
/// each reader or parser alone, and the remote reader against a server whose
/// answers are cut or corrupted. No case may panic (even where the code caught
/// it), break a reader's contract, leave a file or refuse without naming its
/// file or URL; the mutations reach both outcomes.
#[test]
fn every_input_kind_survives_its_fast_mutations() {
    use fuzz::fast::{Fuzzer, Kind, Tally};
    let cases: u64 = std::env::var("PCIMG_FUZZ_CASES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(200);
    let mut failures = Vec::new();
    for kind in Kind::ALL {
        let dir = tempfile::tempdir().unwrap();
        let mut fuzzer = Fuzzer::new(kind, dir.path()).unwrap();
        let mut rng = Rng::new(23);
        let mut tally = Tally::default();
        for it in 0..cases {
            let case = fuzzer.case(&mut rng);
            let verdict = fuzzer.run(&case);
            tally.record(&verdict);
            if verdict.is_failure() {
                failures.push(format!("{} case {it}: {verdict:?}", kind.name()));
            }
        }
        // Every kind both accepts and refuses some of its cases.
        assert!(
            tally.accepted >= 2 && tally.refused >= cases / 10,
            "{}: {tally:?}",
            kind.name()
        );
    }
    assert!(failures.is_empty(), "{failures:#?}");
}

/// The E57 cases' checksum repair computes what the writer wrote: an
/// undamaged file comes back unchanged, and a damaged page gets a new sum.
#[test]
fn e57_checksums_are_set_as_the_writer_sets_them() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("seed.e57");
    pcimg::synth_formats::write_e57(&path, 500, 4, false, 1).unwrap();
    let seed = std::fs::read(&path).unwrap();
    assert!(seed.len() >= 2 * 1024, "{} bytes", seed.len());
    let mut same = seed.clone();
    fuzz::fast::fix_e57_checksums(&mut same);
    assert!(same == seed, "an undamaged file's checksums were changed");
    let mut hurt = seed.clone();
    hurt[100] ^= 0x40;
    fuzz::fast::fix_e57_checksums(&mut hurt);
    assert_ne!(hurt[1020..1024], seed[1020..1024]);
    // The other pages are left as they were.
    assert_eq!(hurt[1024..], seed[1024..]);
}
