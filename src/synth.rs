//! A deterministic synthetic scan (terrain, buildings, vegetation-like clutter,
//! intensity) for demos, tests and benchmarks: the same `n` and `seed` always give
//! the same points.

use crate::points::{Attribute, PointColumns};
use rayon::prelude::*;

pub use pcimg_core::rng::Rng;

/// Where the scene sits: a georeferenced origin, so precision handling is exercised.
pub const SCENE_ORIGIN: [f64; 3] = [637_000.0, 6_010_900.0, 20.0];
/// Edge of the square scene in metres.
pub const SCENE_SIZE: f64 = 400.0;

fn terrain(x: f64, y: f64) -> f64 {
    3.0 * (x * 0.013).sin() * (y * 0.011).cos() + 1.5 * (x * 0.041 + y * 0.027).sin()
}

/// Buildings: (x0, y0, width, depth, height) on a regular block grid.
fn building(cell_x: i64, cell_y: i64) -> Option<(f64, f64, f64, f64, f64)> {
    let h = (cell_x.wrapping_mul(73_856_093) ^ cell_y.wrapping_mul(19_349_663)) as u64;
    let mut r = Rng::new(h);
    if r.f64() < 0.45 {
        return None;
    }
    let (bx, by) = (cell_x as f64 * 50.0 + 8.0, cell_y as f64 * 50.0 + 8.0);
    Some((
        bx,
        by,
        15.0 + 20.0 * r.f64(),
        15.0 + 20.0 * r.f64(),
        6.0 + 30.0 * r.f64(),
    ))
}

/// ASPRS classification codes of the scene's three kinds of point.
pub const CLASS_GROUND: u8 = 2;
pub const CLASS_VEGETATION: u8 = 5;
pub const CLASS_BUILDING: u8 = 6;

/// One point `i` of the scene generated with `seed`.
pub(crate) fn point(seed: u64, i: u64) -> ([f64; 3], f32) {
    let (p, intensity, _) = classified_point(seed, i);
    (p, intensity)
}

/// Point `i` of the scene with its ASPRS class: ground 2, vegetation 5, building 6.
pub fn classified_point(seed: u64, i: u64) -> ([f64; 3], f32, u8) {
    let mut r = Rng::new(seed ^ i.wrapping_mul(0xD6E8_FEB8_6659_FD93));
    let kind = r.f64();
    let x = r.f64() * SCENE_SIZE;
    let y = r.f64() * SCENE_SIZE;
    let ground = terrain(x, y);
    let cell = ((x / 50.0).floor() as i64, (y / 50.0).floor() as i64);
    if kind < 0.25
        && let Some((bx, by, w, d, h)) = building(cell.0, cell.1)
    {
        // A point on the building: roof or one of four walls.
        let face = r.f64();
        let (u, v) = (r.f64(), r.f64());
        let base = terrain(bx, by);
        let p = if face < 0.5 {
            [bx + u * w, by + v * d, base + h]
        } else if face < 0.625 {
            [bx, by + u * d, base + v * h]
        } else if face < 0.75 {
            [bx + w, by + u * d, base + v * h]
        } else if face < 0.875 {
            [bx + u * w, by, base + v * h]
        } else {
            [bx + u * w, by + d, base + v * h]
        };
        let intensity = if face < 0.5 { 180.0 } else { 120.0 } + 20.0 * r.f64();
        return (p, intensity as f32, CLASS_BUILDING);
    }
    if kind > 0.9 {
        // Vegetation-like clutter: blobs of points above the ground.
        let tx = (x / 7.0).floor() * 7.0 + 3.5;
        let ty = (y / 7.0).floor() * 7.0 + 3.5;
        let crown = 3.0 + 2.0 * r.f64();
        let (a, b, c) = (r.f64() - 0.5, r.f64() - 0.5, r.f64() - 0.5);
        let p = [
            tx + a * crown,
            ty + b * crown,
            terrain(tx, ty) + 5.0 + c * crown,
        ];
        return (p, (40.0 + 60.0 * r.f64()) as f32, CLASS_VEGETATION);
    }
    let noise = (r.f64() - 0.5) * 0.05;
    (
        [x, y, ground + noise],
        (70.0 + 40.0 * r.f64()) as f32,
        CLASS_GROUND,
    )
}

/// The order in which points are listed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Order {
    /// Generation order: every point anywhere in the scene (spatially random).
    #[default]
    Random,
    /// Like an airborne scan: flight strips 100 m wide flown back and forth along
    /// x, each a run of scan lines across the strip (zigzag), as a scanner lists
    /// them; consecutive points are neighbours, as in the paper's input file.
    Scan,
}

impl Order {
    pub fn parse(s: &str) -> Result<Order, String> {
        match s {
            "random" => Ok(Order::Random),
            "scan" => Ok(Order::Scan),
            _ => Err(format!("unknown point order '{s}' (random or scan)")),
        }
    }
}

/// Width of a flight strip in metres (the scene holds four).
const STRIP: f64 = 100.0;

/// Generation indices of `n` points in `order` (`None`: generation order).
/// [`permutation`] for the file writers: a scan order beyond `u32` indices is an
/// error, not a panic.
fn file_permutation(n: u64, seed: u64, order: Order) -> std::io::Result<Option<Vec<u32>>> {
    if n > u32::MAX as u64 && order != Order::Random {
        return Err(std::io::Error::other(
            "scan order holds at most 2^32 points",
        ));
    }
    Ok(permutation(n, seed, order))
}

fn permutation(n: u64, seed: u64, order: Order) -> Option<Vec<u32>> {
    if order == Order::Random || n == 0 {
        return None;
    }
    // Scan lines one mean point spacing apart; position across the strip in 13 bits.
    let lines = ((n as f64).sqrt().ceil() as u64).clamp(1, 1 << 16);
    let line_len = SCENE_SIZE / lines as f64;
    let mut keys: Vec<u64> = (0..n)
        .into_par_iter()
        .map(|i| {
            let (p, _) = point(seed, i);
            let (x, y) = (p[0].clamp(0.0, SCENE_SIZE), p[1].clamp(0.0, SCENE_SIZE));
            let strip = ((y / STRIP) as u64).min((SCENE_SIZE / STRIP) as u64 - 1);
            let mut line = ((x / line_len) as u64).min(lines - 1);
            if strip % 2 == 1 {
                line = lines - 1 - line;
            }
            let across = (y - strip as f64 * STRIP) / STRIP;
            let mut q = ((across * 8191.0) as u64).min(8191);
            if line % 2 == 1 {
                q = 8191 - q;
            }
            (((strip << 29) | (line << 13) | q) << 32) | i
        })
        .collect();
    keys.par_sort_unstable();
    Some(keys.into_par_iter().map(|k| k as u32).collect())
}

/// `n` points of the synthetic scene (the same as [`scene`]) with
/// `intensity` and `classification` attributes.
pub fn scene_classified(n: u64, seed: u64) -> PointColumns {
    let mut c = scene(n, seed);
    let class = (0..n)
        .into_par_iter()
        .map(|i| classified_point(seed, i).2 as f32)
        .collect();
    c.attributes.push(Attribute::new("classification", class));
    c
}

/// `n` points of the synthetic scene with an `intensity` attribute.
pub fn scene(n: u64, seed: u64) -> PointColumns {
    scene_in_order(n, seed, Order::Random)
}

/// `n` points of the synthetic scene (the same points as [`scene`]) listed in `order`.
pub fn scene_in_order(n: u64, seed: u64, order: Order) -> PointColumns {
    let perm = permutation(n, seed, order);
    let at = |i: u64| perm.as_ref().map_or(i, |p| p[i as usize] as u64);
    let pts: Vec<([f64; 3], f32)> = (0..n).into_par_iter().map(|i| point(seed, at(i))).collect();
    let mut c = PointColumns {
        x: Vec::with_capacity(n as usize),
        y: Vec::with_capacity(n as usize),
        z: Vec::with_capacity(n as usize),
        attributes: vec![Attribute::new("intensity", Vec::with_capacity(n as usize))],
    };
    for (p, i) in pts {
        c.x.push(SCENE_ORIGIN[0] + p[0]);
        c.y.push(SCENE_ORIGIN[1] + p[1]);
        c.z.push(SCENE_ORIGIN[2] + p[2]);
        c.attributes[0].values.push(i);
    }
    c
}

#[cfg(test)]
mod tests {
    #[test]
    fn deterministic_and_in_scene() {
        let a = super::scene(1000, 7);
        assert_eq!(a, super::scene(1000, 7));
        assert_ne!(a, super::scene(1000, 8));
        // Scan order: the same points, consecutive ones close together.
        let s = super::scene_in_order(1000, 7, super::Order::Scan);
        let key = |c: &crate::points::PointColumns, i: usize| {
            [c.x[i].to_bits(), c.y[i].to_bits(), c.z[i].to_bits()]
        };
        let mut ka: Vec<_> = (0..1000).map(|i| key(&a, i)).collect();
        let mut ks: Vec<_> = (0..1000).map(|i| key(&s, i)).collect();
        ka.sort();
        ks.sort();
        assert_eq!(ka, ks);
        let step = |c: &crate::points::PointColumns| {
            (1..1000)
                .map(|i| (c.x[i] - c.x[i - 1]).hypot(c.y[i] - c.y[i - 1]))
                .sum::<f64>()
                / 999.0
        };
        assert!(step(&s) * 5.0 < step(&a), "{} vs {}", step(&s), step(&a));
        let b = a.bounds();
        assert!(
            b.min[0] >= super::SCENE_ORIGIN[0] - 5.0 && b.max[0] <= super::SCENE_ORIGIN[0] + 405.0
        );
    }
}

/// Appends `v` with exactly three decimals (`-12.345`), fast.
fn push_fixed3(out: &mut Vec<u8>, v: f64) {
    let m = (v * 1000.0).round() as i64;
    if m < 0 {
        out.push(b'-');
    }
    let m = m.unsigned_abs();
    let (int, frac) = (m / 1000, m % 1000);
    let mut buf = [0u8; 20];
    let mut i = buf.len();
    let mut n = int;
    loop {
        i -= 1;
        buf[i] = b'0' + (n % 10) as u8;
        n /= 10;
        if n == 0 {
            break;
        }
    }
    out.extend_from_slice(&buf[i..]);
    out.push(b'.');
    out.push(b'0' + (frac / 100) as u8);
    out.push(b'0' + (frac / 10 % 10) as u8);
    out.push(b'0' + (frac % 10) as u8);
}

/// Points generated per block when writing files (bounds memory).
const WRITE_BLOCK: u64 = 1 << 20;

/// Writes `n` points of the scene as text, one `x y z intensity` line each (the
/// paper's input), atomically. Generation and formatting run in parallel.
pub fn write_text(path: &std::path::Path, n: u64, seed: u64) -> std::io::Result<u64> {
    write_text_in_order(path, n, seed, Order::Random)
}

/// The name a synthetic file is written under until complete: hidden, beside
/// it, and this process's own (`.NAME.PID.tmp`), so no user file is touched.
pub fn temp_path(path: &std::path::Path) -> std::path::PathBuf {
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| "synth".into());
    path.with_file_name(format!(".{name}.{}.tmp", std::process::id()))
}

/// [`write_text`] with the points listed in `order`.
pub fn write_text_in_order(
    path: &std::path::Path,
    n: u64,
    seed: u64,
    order: Order,
) -> std::io::Result<u64> {
    use std::io::Write;
    let perm = file_permutation(n, seed, order)?;
    let at = |i: u64| perm.as_ref().map_or(i, |p| p[i as usize] as u64);
    let tmp = temp_path(path);
    let mut out = std::io::BufWriter::with_capacity(1 << 20, std::fs::File::create(&tmp)?);
    let mut bytes = 0u64;
    let res = (|| {
        let mut start = 0;
        while start < n {
            let end = (start + WRITE_BLOCK).min(n);
            let pieces: Vec<Vec<u8>> = (start..end)
                .step_by(1 << 14)
                .collect::<Vec<u64>>()
                .into_par_iter()
                .map(|s| {
                    let e = (s + (1 << 14)).min(end);
                    let mut b = Vec::with_capacity((e - s) as usize * 48);
                    for i in s..e {
                        let (p, inten) = point(seed, at(i));
                        for (k, o) in SCENE_ORIGIN.iter().enumerate() {
                            push_fixed3(&mut b, o + p[k]);
                            b.push(b' ');
                        }
                        b.extend_from_slice((inten.round() as u32).to_string().as_bytes());
                        b.push(b'\n');
                    }
                    b
                })
                .collect();
            for p in pieces {
                bytes += p.len() as u64;
                out.write_all(&p)?;
            }
            start = end;
        }
        out.flush()
    })();
    if let Err(e) = res {
        let _ = std::fs::remove_file(&tmp);
        return Err(e);
    }
    drop(out);
    std::fs::rename(&tmp, path)?;
    Ok(bytes)
}

/// Writes `n` points of the scene as LAS 1.2 (point format 1: intensity, GPS time,
/// classification ground 2, vegetation 5, building 6),
/// scale 1 mm, atomically; compressed (LAZ) when `path` ends in `.laz`.
pub fn write_las(path: &std::path::Path, n: u64, seed: u64) -> std::io::Result<u64> {
    write_las_in_order(path, n, seed, Order::Random)
}

/// [`write_las`] with the points listed in `order`.
pub fn write_las_in_order(
    path: &std::path::Path,
    n: u64,
    seed: u64,
    order: Order,
) -> std::io::Result<u64> {
    let perm = file_permutation(n, seed, order)?;
    let at = |i: u64| perm.as_ref().map_or(i, |p| p[i as usize] as u64);
    let err = |e: las::Error| std::io::Error::other(e.to_string());
    let tmp = temp_path(path);
    let res = (|| -> std::io::Result<()> {
        let mut b = las::Builder::from((1, 2));
        b.point_format = las::point::Format::new(1).map_err(err)?;
        b.point_format.is_compressed = path
            .extension()
            .is_some_and(|e| e.eq_ignore_ascii_case("laz"));
        let t = |o| las::Transform {
            scale: 0.001,
            offset: o,
        };
        b.transforms = las::Vector {
            x: t(SCENE_ORIGIN[0]),
            y: t(SCENE_ORIGIN[1]),
            z: t(SCENE_ORIGIN[2]),
        };
        let header = b.into_header().map_err(err)?;
        // (`Writer::from_path` would pick compression from the temporary name.)
        let file = std::io::BufWriter::new(std::fs::File::create(&tmp)?);
        let mut w = las::Writer::new(file, header).map_err(err)?;
        let mut start = 0;
        while start < n {
            let end = (start + WRITE_BLOCK).min(n);
            let pts: Vec<([f64; 3], f32, u8)> = (start..end)
                .into_par_iter()
                .map(|i| classified_point(seed, at(i)))
                .collect();
            for (k, (p, inten, class)) in pts.into_iter().enumerate() {
                w.write_point(las::Point {
                    x: SCENE_ORIGIN[0] + p[0],
                    y: SCENE_ORIGIN[1] + p[1],
                    z: SCENE_ORIGIN[2] + p[2],
                    intensity: inten.round() as u16,
                    // One return a pulse (LAS numbers returns from 1).
                    return_number: 1,
                    number_of_returns: 1,
                    classification: las::point::Classification::new(class).map_err(err)?,
                    gps_time: Some(1.0e8 + (start + k as u64) as f64 * 1e-5),
                    ..Default::default()
                })
                .map_err(err)?;
            }
            start = end;
        }
        w.close().map_err(err)
    })();
    if let Err(e) = res {
        let _ = std::fs::remove_file(&tmp);
        return Err(e);
    }
    std::fs::rename(&tmp, path)?;
    Ok(std::fs::metadata(path)?.len())
}

#[cfg(test)]
mod file_tests {
    #[test]
    fn fixed_point_text() {
        let mut b = Vec::new();
        for v in [0.0, -0.0004, 1.5, -12.3456, 637179.2204] {
            super::push_fixed3(&mut b, v);
            b.push(b' ');
        }
        assert_eq!(
            String::from_utf8(b).unwrap(),
            "0.000 0.000 1.500 -12.346 637179.220 "
        );
    }

    #[test]
    fn las_points_are_single_returns_and_no_temporary_file_is_left() {
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join("s.las");
        // A user's file with the name the old temporary had is not touched.
        std::fs::write(d.path().join("s.partial"), "mine").unwrap();
        super::write_las(&p, 1000, 1).unwrap();
        let (_, cols, _) = crate::ingest::read_all(&p, &Default::default()).unwrap();
        for name in ["return_number", "number_of_returns"] {
            let a = cols.attributes.iter().find(|a| a.name == name).unwrap();
            assert!(a.values.iter().all(|&v| v == 1.0), "{name}");
        }
        let mut names: Vec<String> = std::fs::read_dir(d.path())
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        names.sort();
        assert_eq!(names, ["s.las", "s.partial"]);
        assert_eq!(std::fs::read(d.path().join("s.partial")).unwrap(), b"mine");
    }
}
