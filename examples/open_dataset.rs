//! Opening a dataset with the `pcimg-store` crate alone: its parts, their levels
//! and tiles with bounds, and the points of a tile as columns.
//!
//! ```text
//! cargo run --release -- convert fixtures/autzen_trim.laz -o autzen.pcimg
//! cargo run --release --example open_dataset -- autzen.pcimg
//! ```
//!
//! A path (a part or a directory of parts), or with the `remote` feature an
//! `s3://`, `gs://`, `az://` or `http(s)://` URL.

use pcimg_store::Dataset;
use std::path::PathBuf;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let Some(path) = std::env::args_os().nth(1).map(PathBuf::from) else {
        eprintln!("usage: open_dataset DATASET");
        std::process::exit(2);
    };
    let ds = Dataset::open(&path)?;
    let b = ds.bounds();
    println!(
        "{} points in {} parts, x {:.2}..{:.2}, y {:.2}..{:.2}, z {:.2}..{:.2}",
        ds.points(),
        ds.part_count(),
        b.min[0],
        b.max[0],
        b.min[1],
        b.max[1],
        b.min[2],
        b.max[2]
    );
    // (A dataset of many parts has a paged index: listing every part reads
    // every page.)
    let parts = ds.parts()?;
    for part in &parts {
        let bands: Vec<&str> = part.bands.iter().map(|b| b.name.as_str()).collect();
        println!("{}: bands {}", part.path.display(), bands.join(" "));
        for level in &part.levels {
            println!(
                "  level {}: {} points in {} tiles",
                level.index,
                level.points.unwrap_or(0),
                level.tiles.len()
            );
        }
    }
    // The points of the first tile of the first part's coarsest level.
    if let Some(part) = parts.first() {
        let top = part.levels.len() - 1;
        let names: Vec<&str> = part.bands.iter().map(|b| b.name.as_str()).collect();
        let read = part.read_tiles(top, &[0], &part.band_indices(&names)?)?;
        println!("level {top}, tile 0: {} points", read.len());
        for (name, offset) in read.bands.iter().zip(&read.offsets) {
            let v = read.column(name).unwrap_or(&[]);
            if let Some(first) = v.first() {
                println!("  {name}: first {}", *first as f64 + offset);
            }
        }
    }
    Ok(())
}
