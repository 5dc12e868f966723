//! `pcimg render`: one frame of a dataset to a PNG, headless; with `--pick`
//! the point under a pixel as JSON, with `--legend` a legend and scale bar on
//! the image, with `--turntable N` frames around the dataset.

use super::turntable;
use super::view::{self, Drawing, ViewArgs};
use std::path::PathBuf;
use std::sync::Arc;

#[derive(Debug, clap::Args)]
pub struct Args {
    #[command(flatten)]
    pub view: ViewArgs,
    /// Output PNG (the only format written; its name must end in .png). With
    /// --turntable: one animated PNG, or with `{}` in the name one PNG a frame
    /// (`{}` becomes the frame number, 000, 001, ...).
    #[arg(short, long)]
    pub output: PathBuf,
    /// Frame width in pixels (1 to 16384).
    #[arg(long, default_value_t = 1280, value_parser = clap::value_parser!(u32).range(1..=16384))]
    pub width: u32,
    /// Frame height in pixels (1 to 16384).
    #[arg(long, default_value_t = 720, value_parser = clap::value_parser!(u32).range(1..=16384))]
    pub height: u32,
    /// Print the point drawn at pixel X,Y (column, row from the top-left) as
    /// JSON on stdout, with every attribute in source units (`null`: none
    /// there). The nearest point within 3 pixels counts.
    #[arg(long)]
    pub pick: Option<String>,
    /// Draw the legend (classes with their counts, or the ramp with its values)
    /// and a scale bar onto the image.
    #[arg(long)]
    pub legend: bool,
    /// Render N frames around the dataset (yaw steps of 360°/N from the
    /// view's), 2 to 720, as an animated PNG (or one PNG a frame, see -o).
    #[arg(long, value_parser = clap::value_parser!(u32).range(2..=720))]
    pub turntable: Option<u32>,
}

/// Parses `--pick X,Y` within a `width`×`height` frame.
fn parse_pick(s: &str, width: u32, height: u32) -> anyhow::Result<(u32, u32)> {
    let bad =
        || anyhow::anyhow!("--pick '{s}': expected X,Y, a pixel of the {width}x{height} frame");
    let (x, y) = s.split_once(',').ok_or_else(bad)?;
    let (x, y): (u32, u32) = (
        x.trim().parse().map_err(|_| bad())?,
        y.trim().parse().map_err(|_| bad())?,
    );
    if x >= width || y >= height {
        return Err(bad());
    }
    Ok((x, y))
}

pub fn run(a: Args) -> anyhow::Result<()> {
    let png = a
        .output
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("png"));
    if !png {
        anyhow::bail!(
            "-o {}: frames are written as PNG only: name the file NAME.png",
            crate::text::sanitize(&a.output.display().to_string())
        );
    }
    let pick_at = a
        .pick
        .as_deref()
        .map(|s| parse_pick(s, a.width, a.height))
        .transpose()?;
    if pick_at.is_some() && a.turntable.is_some() {
        anyhow::bail!("--pick applies to one frame, not to --turntable");
    }
    // Ctrl-C, SIGTERM, SIGHUP: nothing half-written stays (a large frame takes
    // seconds to encode).
    let tmp = crate::render::png_temporary(&a.output);
    let _ = ctrlc::set_handler(move || {
        let _ = std::fs::remove_file(&tmp);
        std::process::exit(130);
    });
    a.view.cache.apply()?;
    let ds = Arc::new(super::remote::open_for_view(&a.view.path, &a.view.cache)?);
    if let Some(h) = crate::advice::dataset_note(&ds) {
        note!("{h}");
    }
    let cam = view::camera_for(&a.view, &ds)?;
    if a.view.print_camera {
        note!("{}", cam.to_json());
    }
    let mut drawing = Drawing::new(ds.clone(), &a.view, a.width, a.height)?;
    if let Some(n) = a.turntable {
        return turntable::run(&mut drawing, &cam, n, &a.output, a.legend);
    }
    let d = drawing.draw(&cam, pick_at, a.legend)?;
    if let Some((x, y)) = pick_at {
        let json = match d.pick.flatten() {
            None => "null".to_string(),
            Some(h) => {
                let rec = crate::lod::point::point_record(&ds, d.tile_of(&h), h.index)
                    .map_err(anyhow::Error::msg)?;
                pick_json((x, y), h.pixel, &rec)
            }
        };
        super::print_out(&format!("{json}\n"))?;
    }
    d.frame.save_png(&a.output)?;
    note!("{}", view::describe(&d.report));
    note!(
        "wrote {}",
        crate::text::sanitize(&a.output.display().to_string())
    );
    Ok(())
}

pub fn pick_json(asked: (u32, u32), at: (u32, u32), r: &crate::lod::point::PointRecord) -> String {
    // Stored values are f32: digits beyond a micro-unit are noise.
    let round = |v: f64| (v * 1e6).round() / 1e6;
    let mut attrs = serde_json::Map::new();
    for (n, v) in &r.attributes {
        attrs.insert(crate::text::sanitize(n), serde_json::json!(round(*v)));
    }
    let class = r
        .attributes
        .iter()
        .find(|a| a.0 == "classification")
        .and_then(|a| crate::render::classes::code_of(a.1 as f32))
        .map(crate::render::classes::name);
    serde_json::json!({
        "pixel": [asked.0, asked.1],
        "at": [at.0, at.1],
        "part": crate::text::sanitize(&r.part),
        "level": r.level,
        "tile": r.tile,
        "index": r.index,
        "x": round(r.position[0]),
        "y": round(r.position[1]),
        "z": round(r.position[2]),
        "attributes": attrs,
        "class_name": class,
    })
    .to_string()
}
