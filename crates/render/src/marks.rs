//! Marks drawn over a frame: the inspector's crosshair and its picked points.

use super::{Camera, Frame};

fn put(f: &mut Frame, x: i64, y: i64, c: [u8; 3]) {
    if x >= 0 && y >= 0 && x < f.width as i64 && y < f.height as i64 {
        let i = (y as usize * f.width as usize + x as usize) * 4;
        f.rgba[i..i + 3].copy_from_slice(&c);
    }
}

/// A crosshair centred on pixel `(x, y)`, arms `arm` pixels long with a gap in
/// the middle so the point under it stays visible; white with a dark outline.
pub fn crosshair(f: &mut Frame, x: u32, y: u32, arm: u32) {
    let (x, y, arm) = (x as i64, y as i64, arm.max(4) as i64);
    for pass in 0..2 {
        let (c, w) = if pass == 0 {
            ([0, 0, 0], 1)
        } else {
            ([255, 255, 255], 0)
        };
        for d in 3..=arm {
            for o in -w..=w {
                put(f, x + d, y + o, c);
                put(f, x - d, y + o, c);
                put(f, x + o, y + d, c);
                put(f, x + o, y - d, c);
            }
        }
    }
}

/// A small square ring around where world point `p` lands, in `color`.
pub fn mark(f: &mut Frame, camera: &Camera, p: [f64; 3], color: [u8; 3]) {
    let Some([sx, sy]) = camera.project(p, f.width, f.height) else {
        return;
    };
    let (x, y) = (sx.floor() as i64, sy.floor() as i64);
    for d in -3..=3i64 {
        for (dx, dy) in [(d, -3), (d, 3), (-3, d), (3, d)] {
            put(f, x + dx, y + dy, color);
        }
    }
}

/// A line between the pixels where `a` and `b` land (a measurement).
pub(crate) fn segment(f: &mut Frame, camera: &Camera, a: [f64; 3], b: [f64; 3], color: [u8; 3]) {
    let (Some(p), Some(q)) = (
        camera.project(a, f.width, f.height),
        camera.project(b, f.width, f.height),
    ) else {
        return;
    };
    let n = ((q[0] - p[0]).abs().max((q[1] - p[1]).abs()).ceil() as i64).clamp(1, 20_000);
    for k in 0..=n {
        let t = k as f64 / n as f64;
        let (x, y) = (p[0] + (q[0] - p[0]) * t, p[1] + (q[1] - p[1]) * t);
        put(f, x.floor() as i64, y.floor() as i64, color);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn marks_stay_inside() {
        let mut f = Frame::background(20, 10, [0, 0, 0]);
        crosshair(&mut f, 10, 5, 6);
        assert_eq!(f.pixel(14, 5).unwrap()[0], 255);
        assert_eq!(f.pixel(10, 5).unwrap()[0], 0, "the centre stays clear");
        crosshair(&mut f, 0, 0, 50);
        crosshair(&mut f, 19, 9, 50);
    }
}
