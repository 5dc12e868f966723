//! Any bytes given to the part reader: opening and reading every level must return
//! `Ok` or `Err`, never panic, hang or allocate without bound.
#![no_main]

use libfuzzer_sys::fuzz_target;
use std::path::Path;

fuzz_target!(|data: &[u8]| {
    if let Ok(part) = pcimg::store::Part::from_bytes(Path::new("fuzz.tif"), data.to_vec()) {
        // A part that claims millions of points may legitimately need that much
        // memory to read; the harness only reads small ones.
        if part.meta.point_count > 1 << 20 {
            return;
        }
        let bands: Vec<usize> = (0..part.bands.len()).collect();
        for level in 0..part.levels.len() {
            let _ = part.read_level(level, &bands);
        }
    }
});
