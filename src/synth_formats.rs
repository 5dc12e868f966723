//! The synthetic scene ([`crate::synth`]) written as PCD and E57, for the
//! benchmarks and the fuzzer's seeds. Points are in the scene's local frame
//! (without [`crate::synth::SCENE_ORIGIN`]: PCD and E57 scans are local), with
//! `intensity` and a grey colour made from it.

use crate::ingest::pcd::lzf;
use crate::synth::{point, temp_path};
use rayon::prelude::*;
use std::io::Write;
use std::path::Path;

/// How a PCD file stores its points.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PcdData {
    Ascii,
    Binary,
    Compressed,
}

/// Points generated at a time.
const BLOCK: u64 = 1 << 20;

/// Points `from..to` of the scene: local x y z, intensity, packed grey `rgb`.
fn block(seed: u64, from: u64, to: u64) -> Vec<([f32; 3], f32, u32)> {
    (from..to)
        .into_par_iter()
        .map(|i| {
            let (p, inten) = point(seed, i);
            let g = inten.clamp(0.0, 255.0) as u32;
            (p.map(|c| c as f32), inten, (g << 16) | (g << 8) | g)
        })
        .collect()
}

/// Writes `n` points as PCD v0.7 (`x y z intensity rgb`, all `F 4`),
/// atomically; returns the bytes written.
pub fn write_pcd(path: &Path, n: u64, seed: u64, data: PcdData) -> std::io::Result<u64> {
    let tmp = temp_path(path);
    let res = (|| -> std::io::Result<u64> {
        let mut out = std::io::BufWriter::with_capacity(1 << 20, std::fs::File::create(&tmp)?);
        let kind = match data {
            PcdData::Ascii => "ascii",
            PcdData::Binary => "binary",
            PcdData::Compressed => "binary_compressed",
        };
        let header = format!(
            "# .PCD v0.7 - Point Cloud Data file format\nVERSION 0.7\nFIELDS x y z intensity rgb\n\
             SIZE 4 4 4 4 4\nTYPE F F F F F\nCOUNT 1 1 1 1 1\nWIDTH {n}\nHEIGHT 1\n\
             VIEWPOINT 0 0 0 1 0 0 0\nPOINTS {n}\nDATA {kind}\n"
        );
        out.write_all(header.as_bytes())?;
        let mut bytes = header.len() as u64;
        let mut columns: Vec<Vec<u8>> = vec![Vec::new(); 5];
        let mut from = 0;
        while from < n {
            let to = (from + BLOCK).min(n);
            for (p, inten, rgb) in block(seed, from, to) {
                let vals = [p[0], p[1], p[2], inten, f32::from_bits(rgb)];
                match data {
                    PcdData::Ascii => {
                        let line = format!(
                            "{} {} {} {} {}\n",
                            vals[0],
                            vals[1],
                            vals[2],
                            vals[3],
                            f32::from_bits(rgb)
                        );
                        bytes += line.len() as u64;
                        out.write_all(line.as_bytes())?;
                    }
                    PcdData::Binary => {
                        for v in vals {
                            out.write_all(&v.to_le_bytes())?;
                        }
                        bytes += 20;
                    }
                    PcdData::Compressed => {
                        for (c, v) in columns.iter_mut().zip(vals) {
                            c.extend_from_slice(&v.to_le_bytes());
                        }
                    }
                }
            }
            from = to;
        }
        if data == PcdData::Compressed {
            let raw = columns.concat();
            drop(columns);
            let z = lzf::compress(&raw);
            out.write_all(&(z.len() as u32).to_le_bytes())?;
            out.write_all(&(raw.len() as u32).to_le_bytes())?;
            out.write_all(&z)?;
            bytes += 8 + z.len() as u64;
        }
        out.flush()?;
        Ok(bytes)
    })();
    match res {
        Ok(b) => {
            std::fs::rename(&tmp, path)?;
            Ok(b)
        }
        Err(e) => {
            let _ = std::fs::remove_file(&tmp);
            Err(e)
        }
    }
}

/// The pose of scan `k` of [`write_e57`]: a quarter turn about z per scan and
/// 10 m along x per scan, as a quaternion `w x y z` and a translation.
pub fn e57_pose(k: usize) -> ([f64; 4], [f64; 3]) {
    let half = k as f64 * std::f64::consts::FRAC_PI_4;
    (
        [half.cos(), 0.0, 0.0, half.sin()],
        [10.0 * k as f64, 0.0, 0.0],
    )
}

/// Writes `n` points as E57 in `scans` scans (each with the pose of
/// [`e57_pose`], its points stored so that the pose brings them back to the
/// scene's frame): cartesian x y z as 32-bit floats or (`scaled`) as integers
/// scaled by 1 mm, intensity (0–255, with limits), grey colour (0–255).
pub fn write_e57(
    path: &Path,
    n: u64,
    seed: u64,
    scaled: bool,
    scans: usize,
) -> Result<(), e57::Error> {
    use e57::{Record, RecordDataType, RecordName, RecordValue};
    let tmp = temp_path(path);
    let coord = |name: RecordName| Record {
        name,
        data_type: if scaled {
            RecordDataType::ScaledInteger {
                min: -10_000_000,
                max: 10_000_000,
                scale: 0.001,
                offset: 0.0,
            }
        } else {
            RecordDataType::F32
        },
    };
    let int = |name: RecordName| Record {
        name,
        data_type: RecordDataType::Integer { min: 0, max: 255 },
    };
    let res = (|| {
        let mut w = e57::E57Writer::from_file(&tmp, "pcimg-synth")?;
        let scans = scans.max(1);
        for k in 0..scans {
            let proto = vec![
                coord(RecordName::CartesianX),
                coord(RecordName::CartesianY),
                coord(RecordName::CartesianZ),
                int(RecordName::Intensity),
                int(RecordName::ColorRed),
                int(RecordName::ColorGreen),
                int(RecordName::ColorBlue),
            ];
            let mut pc = w.add_pointcloud(&format!("pcimg-synth-scan-{k}"), proto)?;
            pc.set_name(Some(format!("scan {k}")));
            let (q, t) = e57_pose(k);
            pc.set_transform(Some(e57::Transform {
                rotation: e57::Quaternion {
                    w: q[0],
                    x: q[1],
                    y: q[2],
                    z: q[3],
                },
                translation: e57::Translation {
                    x: t[0],
                    y: t[1],
                    z: t[2],
                },
            }));
            pc.set_intensity_limits(Some(e57::IntensityLimits {
                intensity_min: Some(RecordValue::Integer(0)),
                intensity_max: Some(RecordValue::Integer(255)),
            }));
            // The inverse pose: a turn back about z, after taking t off.
            let angle = -2.0 * q[3].atan2(q[0]);
            let (s, c) = angle.sin_cos();
            let (from, to) = (
                n * k as u64 / scans as u64,
                n * (k as u64 + 1) / scans as u64,
            );
            let mut at = from;
            while at < to {
                let end = (at + BLOCK).min(to);
                for (p, inten, _) in block(seed, at, end) {
                    let d = [p[0] as f64 - t[0], p[1] as f64 - t[1], p[2] as f64 - t[2]];
                    let local = [c * d[0] - s * d[1], s * d[0] + c * d[1], d[2]];
                    let v = |x: f64| {
                        if scaled {
                            RecordValue::ScaledInteger((x * 1000.0).round() as i64)
                        } else {
                            RecordValue::Single(x as f32)
                        }
                    };
                    let g = RecordValue::Integer(inten.clamp(0.0, 255.0) as i64);
                    pc.add_point(vec![
                        v(local[0]),
                        v(local[1]),
                        v(local[2]),
                        g.clone(),
                        g.clone(),
                        g.clone(),
                        g,
                    ])?;
                }
                at = end;
            }
            pc.finalize()?;
        }
        w.finalize()
    })();
    match res {
        Ok(()) => std::fs::rename(&tmp, path).map_err(|e| e57::Error::Write {
            desc: format!("cannot rename {}", tmp.display()),
            source: Some(Box::new(e)),
        }),
        Err(e) => {
            let _ = std::fs::remove_file(&tmp);
            Err(e)
        }
    }
}
