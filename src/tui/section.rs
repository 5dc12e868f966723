//! The inspector's section: a slab (a thickness around a vertical plane) drawn
//! alone and seen from the side, as a profile. The plane passes through the
//! two last picked points (the profile line surveyors draw), else through the
//! last pick (or the centre of the data) across the view; keys turn it about
//! the vertical, move it and size it. Tiles the slab misses are not loaded.

use crate::camera::Camera;
use crate::points::Bounds;
use crate::render::filter::{Filter, Slab};

/// Factor per `(` / `)` on the slab's thickness.
const WIDTH_STEP: f64 = 1.5;

/// Turn per `/` / `\` of the plane about the vertical: 15°.
const TURN_STEP: f64 = std::f64::consts::PI / 12.0;

/// A section: its slab and what it replaced.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Section {
    pub slab: Slab,
    /// The filter's slab before (from `--slab`), restored when it closes.
    pub saved_slab: Option<Slab>,
    pub saved_camera: Camera,
}

impl Section {
    /// A vertical slab through `picks`' two points when there are two (and
    /// they are apart horizontally), else through the last one (or the centre
    /// of `bounds`) across the view's horizontal direction; 1% of the data's
    /// extent across it thick (at least a millimetre).
    pub fn through(
        bounds: &Bounds,
        camera: &Camera,
        picks: &[[f64; 3]],
        filter: &Filter,
    ) -> Section {
        let f = camera.forward();
        let mut normal = if f.x.abs() + f.y.abs() > 1e-9 {
            [f.x, f.y, 0.0]
        } else {
            [1.0, 0.0, 0.0]
        };
        let mut point = picks.last().copied().unwrap_or(bounds.center());
        if let [a, b] = picks {
            let (dx, dy) = (b[0] - a[0], b[1] - a[1]);
            if dx.hypot(dy) > 1e-9 {
                normal = [-dy, dx, 0.0];
                point = std::array::from_fn(|k| 0.5 * (a[k] + b[k]));
            }
        }
        let e = bounds.extent();
        let l = normal[0].hypot(normal[1]);
        let across = (e[0] * normal[0].abs() + e[1] * normal[1].abs()) / l;
        let thick = (across * 0.01).max(0.002);
        let slab = Slab::new(point, normal, thick).unwrap_or(Slab {
            point,
            normal: [1.0, 0.0, 0.0],
            half: thick * 0.5,
        });
        Section {
            slab,
            saved_slab: filter.slab,
            saved_camera: *camera,
        }
    }

    /// Thicker (`d > 0`) or thinner.
    pub fn resize(&mut self, d: i8) {
        self.slab.half = (self.slab.half * WIDTH_STEP.powi(d as i32)).max(0.0005);
    }

    /// Moves the slab by `d` thicknesses along its normal.
    pub fn shift(&mut self, d: i8) {
        let step = d as f64 * 2.0 * self.slab.half;
        for k in 0..3 {
            self.slab.point[k] += step * self.slab.normal[k];
        }
    }

    /// Turns the plane about the vertical through its point by `d` steps of 15°.
    pub fn turn(&mut self, d: i8) {
        self.slab.rotate(d as f64 * TURN_STEP);
    }

    /// A level camera looking across the slab at its point, from the side the
    /// current view looks from, far enough to see the whole profile.
    pub fn profile_camera(&self, bounds: &Bounds, current: &Camera) -> Camera {
        let mut slab = self.slab;
        slab.point[2] = slab.point[2].clamp(bounds.min[2], bounds.max[2]);
        slab.profile_camera(bounds, current)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn slab_follows_the_view_and_the_picks() {
        let b = Bounds {
            min: [0.0, 0.0, 0.0],
            max: [100.0, 200.0, 10.0],
        };
        let mut cam = Camera::fit(&b);
        cam.yaw = 0.0; // looking along +x
        let s = Section::through(&b, &cam, &[[30.0, 40.0, 5.0]], &Filter::default());
        assert_eq!(s.slab.normal, [1.0, 0.0, 0.0]);
        assert!((s.slab.half - 0.5).abs() < 1e-9);
        assert!(s.slab.contains([30.4, 190.0, 0.0]) && !s.slab.contains([30.6, 40.0, 5.0]));
        let p = s.profile_camera(&b, &cam);
        assert!(p.yaw.abs() < 1e-9 && p.pitch.abs() < 1e-9);
        let mut s2 = s;
        s2.resize(1);
        assert!(s2.slab.half > s.slab.half);
        s2.shift(1);
        assert!(s2.slab.point[0] > s.slab.point[0]);
        // A quarter turn in six steps: the plane now runs along x.
        for _ in 0..6 {
            s2.turn(1);
        }
        assert!(
            (s2.slab.normal[1] - 1.0).abs() < 1e-9,
            "{:?}",
            s2.slab.normal
        );
        // Two picks: the plane holds both, vertical; the camera looks across it.
        let picks = [[10.0, 10.0, 1.0], [50.0, 50.0, 3.0]];
        let s3 = Section::through(&b, &cam, &picks, &Filter::default());
        assert!(s3.slab.contains(picks[0]) && s3.slab.contains(picks[1]));
        assert!(s3.slab.contains([30.0, 30.0, 9.0]) && !s3.slab.contains([40.0, 20.0, 2.0]));
        let p = s3.profile_camera(&b, &cam);
        let f = p.forward();
        assert!((f.x + f.y).abs() < 1e-9 && f.z.abs() < 1e-9, "{f:?}");
    }
}
