//! The inspector's clip box, moved and sized by keys: `o` shows one (the
//! `--clip` box, or the middle half of the data across, all of it in height) or
//! hides it; while no section is shown, `( )` size it and `{ }` move it along
//! one axis, `/` and `\` choose the axis. Tiles outside the box are not loaded
//! (the filter's clip culls them by their bounds).

use crate::points::Bounds;

/// Factor per `(` / `)` on the box's width along the chosen axis.
const SIZE_STEP: f64 = 1.25;

/// What `{` / `}` move the box by: this fraction of its width on the axis.
const MOVE_STEP: f64 = 0.25;

/// The narrowest a box gets on any axis (world units), so it never vanishes.
const MIN_WIDTH: f64 = 1e-3;

/// The axes' names, for the status line.
pub const AXES: [&str; 3] = ["x", "y", "z"];

/// A clip box being edited: the box and the axis the keys act on.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ClipBox {
    pub bounds: Bounds,
    pub axis: usize,
}

impl ClipBox {
    /// The box `o` shows first: `given` (from `--clip`), else the middle half
    /// of `data` in x and y and all of its height.
    pub fn start(data: &Bounds, given: Option<Bounds>) -> ClipBox {
        let bounds = given.unwrap_or_else(|| {
            let (c, e) = (data.center(), data.extent());
            let mut b = *data;
            for k in 0..2 {
                b.min[k] = c[k] - 0.25 * e[k];
                b.max[k] = c[k] + 0.25 * e[k];
            }
            b
        });
        ClipBox { bounds, axis: 0 }
    }

    /// Wider (`d > 0`) or narrower along the axis, about its centre.
    pub fn resize(&mut self, d: i8) {
        let k = self.axis;
        let c = 0.5 * (self.bounds.min[k] + self.bounds.max[k]);
        let w =
            ((self.bounds.max[k] - self.bounds.min[k]) * SIZE_STEP.powi(d as i32)).max(MIN_WIDTH);
        self.bounds.min[k] = c - 0.5 * w;
        self.bounds.max[k] = c + 0.5 * w;
    }

    /// Moves the box by `d` quarters of its width along the axis.
    pub fn shift(&mut self, d: i8) {
        let k = self.axis;
        let w = (self.bounds.max[k] - self.bounds.min[k]).max(MIN_WIDTH);
        let step = d as f64 * MOVE_STEP * w;
        self.bounds.min[k] += step;
        self.bounds.max[k] += step;
    }

    /// The next axis (`d > 0`) or the previous: x → y → z → x.
    pub fn next_axis(&mut self, d: i8) {
        self.axis = (self.axis as i64 + d as i64).rem_euclid(3) as usize;
    }

    /// The status line's account: each axis's range, the chosen one marked.
    pub fn describe(&self) -> String {
        let b = &self.bounds;
        let axes: Vec<String> = (0..3)
            .map(|k| {
                format!(
                    "{}{} {:.2}..{:.2}",
                    if k == self.axis { "*" } else { "" },
                    AXES[k],
                    b.min[k],
                    b.max[k]
                )
            })
            .collect();
        format!("clip {}", axes.join(" "))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn data() -> Bounds {
        Bounds {
            min: [0.0, 0.0, 0.0],
            max: [100.0, 200.0, 10.0],
        }
    }

    #[test]
    fn starts_in_the_middle_or_from_the_given_box() {
        let c = ClipBox::start(&data(), None);
        assert_eq!(c.bounds.min, [25.0, 50.0, 0.0]);
        assert_eq!(c.bounds.max, [75.0, 150.0, 10.0]);
        let given = Bounds {
            min: [1.0, 2.0, 3.0],
            max: [4.0, 5.0, 6.0],
        };
        assert_eq!(ClipBox::start(&data(), Some(given)).bounds, given);
    }

    #[test]
    fn keys_size_move_and_choose_the_axis() {
        let mut c = ClipBox::start(&data(), None);
        c.resize(1);
        assert!((c.bounds.max[0] - c.bounds.min[0] - 62.5).abs() < 1e-9);
        assert!(
            (c.bounds.min[0] + c.bounds.max[0] - 100.0).abs() < 1e-9,
            "about its centre"
        );
        assert_eq!(c.bounds.min[1], 50.0, "other axes untouched");
        c.shift(1);
        assert!((c.bounds.min[0] - (50.0 - 31.25 + 15.625)).abs() < 1e-9);
        c.next_axis(1);
        c.next_axis(1);
        assert_eq!(c.axis, 2);
        c.shift(-4);
        assert_eq!((c.bounds.min[2], c.bounds.max[2]), (-10.0, 0.0));
        c.next_axis(1);
        assert_eq!(c.axis, 0, "wraps around");
        c.next_axis(-1);
        assert_eq!(c.axis, 2);
        for _ in 0..200 {
            c.resize(-1);
        }
        assert!(c.bounds.max[2] - c.bounds.min[2] >= MIN_WIDTH * 0.999);
        assert!(c.describe().contains("*z -"), "{}", c.describe());
    }
}
