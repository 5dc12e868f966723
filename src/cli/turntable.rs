//! `render --turntable N`: N frames around the dataset, the camera's yaw
//! stepping 360°/N from the view's, written as one animated PNG (APNG, 10
//! frames a second, looping) or, with `{}` in the output name, one PNG a frame.

use super::view::Drawing;
use crate::camera::Camera;
use crate::render::Frame;
use std::path::{Path, PathBuf};

/// The yaw of frame `i` of `n` (radians), starting from `yaw0`.
pub fn frame_yaw(yaw0: f64, i: u32, n: u32) -> f64 {
    yaw0 + std::f64::consts::TAU * i as f64 / n as f64
}

/// The file of frame `i` when `pattern` holds `{}`.
pub fn frame_path(pattern: &Path, i: u32) -> Option<PathBuf> {
    let s = pattern.to_str()?;
    s.contains("{}")
        .then(|| PathBuf::from(s.replacen("{}", &format!("{i:03}"), 1)))
}

/// Draws the frames and writes them.
pub fn run(d: &mut Drawing, cam: &Camera, n: u32, out: &Path, legend: bool) -> anyhow::Result<()> {
    let mut frames = Vec::with_capacity(if frame_path(out, 0).is_some() {
        0
    } else {
        n as usize
    });
    let mut points = 0u64;
    let t = std::time::Instant::now();
    for i in 0..n {
        let mut c = *cam;
        c.yaw = frame_yaw(cam.yaw, i, n);
        let drawn = d.draw(&c, None, legend)?;
        points += drawn.report.selection.points;
        match frame_path(out, i) {
            Some(p) => drawn.frame.save_png(&p)?,
            None => frames.push(drawn.frame),
        }
    }
    if frame_path(out, 0).is_none() {
        save_apng(&frames, out)?;
    }
    note!(
        "{n} frames, {} points in all, in {:.1} s",
        crate::text::count(points),
        t.elapsed().as_secs_f64()
    );
    note!(
        "wrote {}",
        crate::text::sanitize(&out.display().to_string())
    );
    Ok(())
}

/// Writes `frames` (all one size) as a looping animated PNG, 10 frames a
/// second, under a temporary name renamed into place.
pub fn save_apng(frames: &[Frame], path: &Path) -> anyhow::Result<()> {
    let Some(first) = frames.first() else {
        anyhow::bail!("no frames to write");
    };
    let tmp = crate::render::png_temporary(path);
    let res = (|| -> anyhow::Result<()> {
        let file = std::io::BufWriter::new(std::fs::File::create(&tmp)?);
        let mut enc = png::Encoder::new(file, first.width, first.height);
        enc.set_color(png::ColorType::Rgba);
        enc.set_depth(png::BitDepth::Eight);
        enc.set_animated(frames.len() as u32, 0)?;
        enc.set_frame_delay(1, 10)?;
        let mut w = enc.write_header()?;
        for f in frames {
            w.write_image_data(&f.rgba)?;
        }
        w.finish()?;
        Ok(())
    })();
    if let Err(e) = res {
        let _ = std::fs::remove_file(&tmp);
        anyhow::bail!(
            "cannot save {}: {e}",
            crate::text::sanitize(&path.display().to_string())
        );
    }
    std::fs::rename(&tmp, path)?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn yaws_and_names() {
        let y: Vec<f64> = (0..4).map(|i| frame_yaw(1.0, i, 4)).collect();
        assert!((y[2] - (1.0 + std::f64::consts::PI)).abs() < 1e-12);
        assert_eq!(
            frame_path(Path::new("out/spin_{}.png"), 7).unwrap(),
            PathBuf::from("out/spin_007.png")
        );
        assert_eq!(frame_path(Path::new("spin.png"), 7), None);
    }
}
