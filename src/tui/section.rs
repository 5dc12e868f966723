//! The inspector's section: a slab (a thickness around a vertical plane
//! through the last picked point, across the axis the view looks along) drawn
//! alone and seen from the side, as a profile. It is a clip box, so tiles
//! outside it are not loaded.

use crate::camera::Camera;
use crate::points::Bounds;
use crate::render::filter::Filter;

/// Factor per `(` / `)` on the slab's thickness.
const WIDTH_STEP: f64 = 1.5;

/// A slab across axis `axis` (0: x, 1: y), `center ± half` along it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Section {
    pub axis: usize,
    pub center: f64,
    pub half: f64,
    /// Where it passes through (the pick, or the centre of the data).
    pub through: [f64; 3],
    /// What the section replaced, restored when it closes.
    pub saved_clip: Option<Bounds>,
    pub saved_camera: Camera,
}

impl Section {
    /// A slab through `at` (else the centre of `bounds`) across the horizontal
    /// axis nearest the view direction, 1% of the data's extent along it thick
    /// (at least a millimetre).
    pub fn through(
        bounds: &Bounds,
        camera: &Camera,
        at: Option<[f64; 3]>,
        filter: &Filter,
    ) -> Section {
        let f = camera.forward();
        let axis = if f.x.abs() >= f.y.abs() { 0 } else { 1 };
        let p = at.unwrap_or(bounds.center());
        let half = (bounds.extent()[axis] * 0.005).max(0.001);
        Section {
            axis,
            center: p[axis],
            half,
            through: p,
            saved_clip: filter.clip,
            saved_camera: *camera,
        }
    }

    /// The clip box: `bounds` cut down to the slab.
    pub fn clip(&self, bounds: &Bounds) -> Bounds {
        let mut b = *bounds;
        b.min[self.axis] = self.center - self.half;
        b.max[self.axis] = self.center + self.half;
        b
    }

    /// Thicker (`d > 0`) or thinner.
    pub fn resize(&mut self, d: i8) {
        self.half = (self.half * WIDTH_STEP.powi(d as i32)).max(0.0005);
    }

    /// Moves the slab by `d` thicknesses along its axis.
    pub fn shift(&mut self, d: i8) {
        self.center += d as f64 * 2.0 * self.half;
    }

    /// A level camera looking across the slab at the point it passes through,
    /// from the side the current view looks from, far enough to see the whole
    /// profile.
    pub fn profile_camera(&self, bounds: &Bounds, current: &Camera) -> Camera {
        let mut c = *current;
        let f = current.forward();
        let along = if self.axis == 0 { f.x } else { f.y };
        c.mode = crate::camera::CameraMode::Orbit;
        c.yaw = match (self.axis, along >= 0.0) {
            (0, true) => 0.0,
            (0, false) => std::f64::consts::PI,
            (_, true) => std::f64::consts::FRAC_PI_2,
            (_, false) => -std::f64::consts::FRAC_PI_2,
        };
        c.pitch = 0.0;
        let mut t = bounds.center();
        t[self.axis] = self.center;
        t[2] = self.through[2].clamp(bounds.min[2], bounds.max[2]);
        c.target = glam::DVec3::from(t);
        let e = bounds.extent();
        let span = e[1 - self.axis].max(e[2]);
        c.distance = (span * 0.6 / (0.5 * c.fov_y).tan()).max(1e-3);
        c.set_clip_from_bounds(bounds);
        c
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn slab_follows_the_view_and_the_pick() {
        let b = Bounds {
            min: [0.0, 0.0, 0.0],
            max: [100.0, 200.0, 10.0],
        };
        let mut cam = Camera::fit(&b);
        cam.yaw = 0.1; // looking along +x
        let s = Section::through(&b, &cam, Some([30.0, 40.0, 5.0]), &Filter::default());
        assert_eq!(s.axis, 0);
        let c = s.clip(&b);
        assert!((c.min[0] - 29.5).abs() < 1e-9 && (c.max[0] - 30.5).abs() < 1e-9);
        assert_eq!((c.min[1], c.max[1]), (0.0, 200.0));
        let p = s.profile_camera(&b, &cam);
        assert_eq!((p.yaw, p.pitch), (0.0, 0.0));
        let mut s2 = s;
        s2.resize(1);
        assert!(s2.half > s.half);
        s2.shift(1);
        assert!(s2.center > s.center);
        cam.yaw = std::f64::consts::FRAC_PI_2; // along +y
        assert_eq!(Section::through(&b, &cam, None, &Filter::default()).axis, 1);
    }
}
