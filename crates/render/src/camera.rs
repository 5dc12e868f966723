//! The camera: placement in `f64` world coordinates (orbit and fly modes),
//! perspective projection, per-origin `f32` view-projection matrices, frustum
//! culling of `f64` bounds, projected-size helpers for level selection, and JSON /
//! `--view` parsing.
//!
//! Conventions: Z is up. `yaw` is the azimuth of the viewing direction, measured
//! counter-clockwise from +X; `pitch` is the angle of the viewing direction above
//! the horizontal (negative looks down). Angles are radians in the struct and in
//! JSON; [`ViewSpec`] (the `--view` flag) takes degrees. Projection depth maps to
//! 0..1 (wgpu / Vulkan convention), right-handed view space.

use glam::{DMat4, DVec3, DVec4, Mat4};
use serde::{Deserialize, Serialize};

use crate::points::Bounds;

/// A camera description that cannot be used (bad `--view` or `--camera`).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{0}")]
pub struct CameraError(pub String);

/// How the camera is placed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum CameraMode {
    /// Looks at `target` from `distance` away, along the direction given by yaw/pitch.
    #[default]
    Orbit,
    /// Stands at `position` and looks along yaw/pitch.
    Fly,
}

/// Largest |pitch|, just short of straight up/down so the view matrix stays defined.
pub(crate) const MAX_PITCH: f64 = 89.9 * std::f64::consts::PI / 180.0;

/// A perspective camera with `f64` placement.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct Camera {
    pub mode: CameraMode,
    /// Orbit centre (orbit mode).
    pub target: DVec3,
    /// Eye position (fly mode).
    pub position: DVec3,
    /// Radians, azimuth of the viewing direction from +X.
    pub yaw: f64,
    /// Radians, elevation of the viewing direction (negative looks down).
    pub pitch: f64,
    /// Eye-target distance (orbit mode).
    pub distance: f64,
    /// Vertical field of view, radians.
    pub fov_y: f64,
    /// Width / height. Renderers replace it with their frame's aspect.
    pub aspect: f64,
    pub near: f64,
    pub far: f64,
}

impl Default for Camera {
    fn default() -> Self {
        Camera {
            mode: CameraMode::Orbit,
            target: DVec3::ZERO,
            position: DVec3::new(0.0, -1.0, 0.0),
            yaw: std::f64::consts::FRAC_PI_2,
            pitch: 0.0,
            distance: 1.0,
            fov_y: 60f64.to_radians(),
            aspect: 16.0 / 9.0,
            near: 0.01,
            far: 100.0,
        }
    }
}

/// Result of a frustum test.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Containment {
    Outside,
    Inside,
    Intersecting,
}

/// The six planes of a view frustum in world (`f64`) coordinates; a point `p` is
/// inside when `n·p + d >= 0` for every plane `(n, d)`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Frustum {
    pub planes: [DVec4; 6],
}

/// `--view yaw,pitch[,dist]`: degrees, degrees, world units.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ViewSpec {
    pub yaw_deg: f64,
    pub pitch_deg: f64,
    pub distance: Option<f64>,
}

impl std::str::FromStr for ViewSpec {
    type Err = CameraError;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        parse_view(s)
    }
}

/// Parses `yaw,pitch[,dist]` (degrees, degrees, world units).
pub fn parse_view(s: &str) -> Result<ViewSpec, CameraError> {
    let bad = |why: &str| {
        CameraError(format!(
            "bad view '{s}': {why} (expected yaw,pitch[,distance] in degrees, degrees, units)"
        ))
    };
    let parts: Vec<&str> = s.split(',').map(str::trim).collect();
    if !(2..=3).contains(&parts.len()) {
        return Err(bad("need 2 or 3 numbers"));
    }
    let mut v = [0.0f64; 3];
    for (slot, p) in v.iter_mut().zip(&parts) {
        *slot = p.parse::<f64>().map_err(|_| bad("not a number"))?;
        if !slot.is_finite() {
            return Err(bad("not finite"));
        }
    }
    if v[1].abs() > 90.0 {
        return Err(bad(
            "pitch must be within -90 (looking straight down) and 90",
        ));
    }
    let distance = if parts.len() == 3 {
        if v[2] <= 0.0 {
            return Err(bad("distance must be positive"));
        }
        Some(v[2])
    } else {
        None
    };
    Ok(ViewSpec {
        yaw_deg: v[0],
        pitch_deg: v[1],
        distance,
    })
}

fn bounds_corners(b: &Bounds) -> [DVec3; 8] {
    let mut c = [DVec3::ZERO; 8];
    for (i, corner) in c.iter_mut().enumerate() {
        *corner = DVec3::new(
            if i & 1 == 0 { b.min[0] } else { b.max[0] },
            if i & 2 == 0 { b.min[1] } else { b.max[1] },
            if i & 4 == 0 { b.min[2] } else { b.max[2] },
        );
    }
    c
}

/// Right-handed view matrix at `eye` looking along `dir` (unit), `up` roughly up.
pub(crate) fn look_to_rh(eye: DVec3, dir: DVec3, up: DVec3) -> DMat4 {
    let f = dir.normalize_or(DVec3::Y);
    let s = f.cross(up).normalize_or(DVec3::X);
    let u = s.cross(f);
    DMat4::from_cols(
        DVec4::new(s.x, u.x, -f.x, 0.0),
        DVec4::new(s.y, u.y, -f.y, 0.0),
        DVec4::new(s.z, u.z, -f.z, 0.0),
        DVec4::new(-s.dot(eye), -u.dot(eye), f.dot(eye), 1.0),
    )
}

/// Right-handed perspective projection with depth 0 (near) ..= 1 (far).
pub(crate) fn perspective_rh(fov_y: f64, aspect: f64, near: f64, far: f64) -> DMat4 {
    let h = 1.0 / (0.5 * fov_y).tan();
    let w = h / aspect;
    let r = far / (near - far);
    DMat4::from_cols(
        DVec4::new(w, 0.0, 0.0, 0.0),
        DVec4::new(0.0, h, 0.0, 0.0),
        DVec4::new(0.0, 0.0, r, -1.0),
        DVec4::new(0.0, 0.0, r * near, 0.0),
    )
}

impl Camera {
    /// A camera that shows the whole of `bounds`: orbit mode around the centre,
    /// looking from the south-west and 35° above, far enough that the bounding
    /// sphere fits in the narrower field of view (16:9 aspect; see
    /// [`Camera::fit_to`] to keep another aspect), near/far from the bounds.
    pub fn fit(bounds: &Bounds) -> Camera {
        let mut c = Camera {
            yaw: 45f64.to_radians(),
            pitch: -35f64.to_radians(),
            ..Camera::default()
        };
        c.fit_to(bounds);
        c
    }

    /// Re-centres on `bounds` keeping orientation, field of view and aspect.
    pub fn fit_to(&mut self, bounds: &Bounds) {
        if bounds.is_empty() || bounds.min.iter().chain(&bounds.max).any(|v| !v.is_finite()) {
            return;
        }
        let center = DVec3::from(bounds.center());
        let ext = DVec3::from(bounds.extent());
        let radius = (0.5 * ext.length()).max(1e-6);
        let half_y = 0.5 * self.fov_y.clamp(1e-3, 3.1);
        let half_x = (half_y.tan() * self.aspect.max(1e-6)).atan();
        let half = half_y.min(half_x);
        let dist = radius / half.sin() * 1.02;
        self.mode = CameraMode::Orbit;
        self.target = center;
        self.distance = dist;
        self.position = self.eye();
        self.set_clip_from_bounds(bounds);
    }

    /// Unit viewing direction.
    pub fn forward(&self) -> DVec3 {
        let p = self.pitch.clamp(-MAX_PITCH, MAX_PITCH);
        DVec3::new(p.cos() * self.yaw.cos(), p.cos() * self.yaw.sin(), p.sin())
    }

    /// Eye position in world coordinates.
    pub fn eye(&self) -> DVec3 {
        match self.mode {
            CameraMode::Orbit => self.target - self.forward() * self.distance,
            CameraMode::Fly => self.position,
        }
    }

    /// Switches mode keeping the current eye and viewing direction.
    pub(crate) fn set_mode(&mut self, mode: CameraMode) {
        if mode == self.mode {
            return;
        }
        let eye = self.eye();
        match mode {
            CameraMode::Fly => self.position = eye,
            CameraMode::Orbit => self.target = eye + self.forward() * self.distance.max(1e-9),
        }
        self.mode = mode;
    }

    /// Unit right vector (horizontal, perpendicular to the viewing direction).
    pub fn right(&self) -> DVec3 {
        DVec3::new(self.yaw.sin(), -self.yaw.cos(), 0.0)
    }

    /// Camera up vector (perpendicular to forward and right).
    pub fn up(&self) -> DVec3 {
        self.right().cross(self.forward())
    }

    /// Turns the view: orbit mode circles the target, fly mode looks around.
    /// Radians; pitch is clamped short of straight up/down.
    pub fn rotate(&mut self, d_yaw: f64, d_pitch: f64) {
        if !(d_yaw.is_finite() && d_pitch.is_finite()) {
            return;
        }
        self.yaw = (self.yaw + d_yaw).rem_euclid(std::f64::consts::TAU);
        self.pitch = (self.pitch + d_pitch).clamp(-MAX_PITCH, MAX_PITCH);
    }

    /// Orbit mode: multiplies the distance by `factor` (< 1 moves closer).
    /// Fly mode: moves forward by `(1 - factor) * distance`.
    pub fn zoom(&mut self, factor: f64) {
        if !(factor.is_finite() && factor > 0.0) {
            return;
        }
        match self.mode {
            CameraMode::Orbit => self.distance = (self.distance * factor).max(1e-9),
            CameraMode::Fly => self.position += self.forward() * (1.0 - factor) * self.distance,
        }
    }

    /// Moves eye (and target) by `right`, `up`, `forward` world units along
    /// the camera axes.
    pub fn translate(&mut self, right: f64, up: f64, forward: f64) {
        let d = self.right() * right + self.up() * up + self.forward() * forward;
        if !d.is_finite() {
            return;
        }
        self.target += d;
        self.position += d;
    }

    /// Applies a `--view` spec (orbit mode; keeps the distance when none is given).
    pub fn apply_view(&mut self, v: &ViewSpec) {
        if self.mode != CameraMode::Orbit {
            self.set_mode(CameraMode::Orbit);
        }
        self.yaw = v.yaw_deg.to_radians();
        self.pitch = v.pitch_deg.to_radians().clamp(-MAX_PITCH, MAX_PITCH);
        if let Some(d) = v.distance {
            self.distance = d;
        }
    }

    /// Sets near/far so that `bounds` lies between them as seen from the eye.
    /// `near` is never below `far / 100000` to keep depth precision.
    pub fn set_clip_from_bounds(&mut self, bounds: &Bounds) {
        if bounds.is_empty() {
            return;
        }
        let eye = self.eye();
        let f = self.forward();
        let corners = bounds_corners(bounds);
        let mut max_d = 0.0f64;
        let mut min_d = f64::INFINITY;
        for c in &corners {
            let d = (*c - eye).dot(f);
            max_d = max_d.max(d);
            min_d = min_d.min(d);
        }
        let far = (max_d * 1.05).max(1e-3);
        let near = (min_d * 0.95).max(far / 1e5);
        if far.is_finite() && near.is_finite() {
            self.far = far;
            self.near = near.min(far * 0.5);
        }
    }

    /// Near and far planes as used by the projection (invalid values replaced).
    pub(crate) fn near_far(&self) -> (f64, f64) {
        let near = if self.near.is_finite() && self.near > 0.0 {
            self.near
        } else {
            1e-3
        };
        let far = if self.far.is_finite() && self.far > near {
            self.far
        } else {
            near * 1e5
        };
        (near, far)
    }

    /// View matrix for coordinates relative to `origin` (`f64`).
    pub(crate) fn view_f64(&self, origin: [f64; 3]) -> DMat4 {
        let o = DVec3::from(origin);
        let eye = self.eye() - o;
        look_to_rh(eye, self.forward(), DVec3::Z)
    }

    /// Projection matrix for `aspect` (`f64`, depth 0..1).
    pub(crate) fn proj_f64(&self, aspect: f64) -> DMat4 {
        let (near, far) = self.near_far();
        let aspect = if aspect.is_finite() && aspect > 0.0 {
            aspect
        } else {
            1.0
        };
        perspective_rh(self.fov_y.clamp(1e-3, 3.1), aspect, near, far)
    }

    /// `f32` view-projection for points stored relative to `origin`, with the
    /// camera's own aspect. Computed in `f64` with the origin subtracted before
    /// the cast, so large georeferenced coordinates keep their precision.
    pub fn view_proj(&self, origin: [f64; 3]) -> Mat4 {
        self.view_proj_aspect(origin, self.aspect)
    }

    /// [`Camera::view_proj`] with an explicit aspect (width / height).
    pub(crate) fn view_proj_aspect(&self, origin: [f64; 3], aspect: f64) -> Mat4 {
        (self.proj_f64(aspect) * self.view_f64(origin)).as_mat4()
    }

    /// The frustum in world coordinates for `aspect`.
    pub fn frustum(&self, aspect: f64) -> Frustum {
        Frustum::from_matrix(&(self.proj_f64(aspect) * self.view_f64([0.0; 3])))
    }

    /// Distance from the eye to a world point.
    pub fn distance_to(&self, p: [f64; 3]) -> f64 {
        (DVec3::from(p) - self.eye()).length()
    }

    /// Pixels covered by one world unit seen at `distance` on a viewport
    /// `viewport_height` pixels high (used to pick pyramid levels).
    pub fn pixels_per_unit(&self, distance: f64, viewport_height: u32) -> f64 {
        let d = distance.max(1e-12);
        viewport_height as f64 / (2.0 * (0.5 * self.fov_y).tan() * d)
    }

    /// Projected size in pixels of something `size` world units wide at `distance`.
    #[cfg(test)]
    pub(crate) fn projected_size(&self, size: f64, distance: f64, viewport_height: u32) -> f64 {
        size * self.pixels_per_unit(distance, viewport_height)
    }

    /// Projects a world point to pixel coordinates (x right, y down) on a
    /// `width`×`height` image; `None` when behind the camera or outside near/far.
    pub fn project(&self, p: [f64; 3], width: u32, height: u32) -> Option<[f64; 2]> {
        let m = self.proj_f64(width as f64 / height.max(1) as f64) * self.view_f64([0.0; 3]);
        let c = m * DVec4::new(p[0], p[1], p[2], 1.0);
        if c.w <= 0.0 || c.z < 0.0 || c.z > c.w {
            return None;
        }
        let nx = c.x / c.w;
        let ny = c.y / c.w;
        Some([
            (nx * 0.5 + 0.5) * width as f64,
            (0.5 - ny * 0.5) * height as f64,
        ])
    }

    pub fn to_json(&self) -> String {
        serde_json::to_string(self).unwrap_or_default()
    }

    /// Parses a camera from JSON; missing fields take their defaults.
    pub fn from_json(s: &str) -> Result<Camera, CameraError> {
        Camera::from_json_over(s, &Camera::default())
    }

    /// A camera from JSON whose fields override those of `base` (a partial
    /// camera such as `{"yaw": 1.2}` keeps the rest of `base`). Unknown fields
    /// and non-finite values are errors.
    pub fn from_json_over(s: &str, base: &Camera) -> Result<Camera, CameraError> {
        let bad = |e: &dyn std::fmt::Display| CameraError(format!("bad camera JSON: {e}"));
        let given: serde_json::Value = serde_json::from_str(s).map_err(|e| bad(&e))?;
        let serde_json::Value::Object(given) = given else {
            return Err(bad(&"expected an object such as {\"yaw\": 0.5}"));
        };
        let serde_json::Value::Object(mut merged) =
            serde_json::to_value(base).map_err(|e| bad(&e))?
        else {
            return Err(bad(&"the camera is not an object"));
        };
        for (k, v) in given {
            if !merged.contains_key(&k) {
                let known: Vec<&str> = merged.keys().map(String::as_str).collect();
                return Err(bad(&format!(
                    "unknown field '{}' (fields: {})",
                    crate::text::sanitize(&k),
                    known.join(", ")
                )));
            }
            merged.insert(k, v);
        }
        let c: Camera =
            serde_json::from_value(serde_json::Value::Object(merged)).map_err(|e| bad(&e))?;
        let finite = [c.yaw, c.pitch, c.distance, c.fov_y, c.aspect, c.near, c.far]
            .iter()
            .all(|v| v.is_finite())
            && c.target.is_finite()
            && c.position.is_finite();
        if !finite {
            return Err(CameraError("bad camera JSON: non-finite value".into()));
        }
        let check = |ok: bool, what: &str| if ok { Ok(()) } else { Err(bad(&what)) };
        check(c.distance > 0.0, "distance must be positive")?;
        check(
            c.fov_y > 0.0 && c.fov_y < std::f64::consts::PI,
            "fov_y must be between 0 and pi radians",
        )?;
        check(c.aspect > 0.0, "aspect must be positive")?;
        check(
            c.pitch.abs() <= std::f64::consts::FRAC_PI_2,
            "pitch must be within -pi/2 and pi/2 radians",
        )?;
        check(
            c.near > 0.0 && c.far > c.near,
            "near and far must satisfy 0 < near < far",
        )?;
        Ok(c)
    }
}

impl Frustum {
    /// Extracts the planes of a view-projection matrix (depth 0..1), normalized.
    pub(crate) fn from_matrix(m: &DMat4) -> Frustum {
        let r0 = m.row(0);
        let r1 = m.row(1);
        let r2 = m.row(2);
        let r3 = m.row(3);
        let raw = [r3 + r0, r3 - r0, r3 + r1, r3 - r1, r2, r3 - r2];
        let planes = raw.map(|p| {
            let l = p.truncate().length();
            if l > 0.0 { p / l } else { p }
        });
        Frustum { planes }
    }

    /// Classifies `b` against the frustum (conservative: a box reported
    /// `Intersecting` may still be outside near a frustum edge).
    pub fn contains_aabb(&self, b: &Bounds) -> Containment {
        if b.is_empty() {
            return Containment::Outside;
        }
        let mut all_inside = true;
        for p in &self.planes {
            let n = p.truncate();
            // The corner furthest along the normal (p-vertex) and the nearest (n-vertex).
            let mut pv = DVec3::ZERO;
            let mut nv = DVec3::ZERO;
            for a in 0..3 {
                if n[a] >= 0.0 {
                    pv[a] = b.max[a];
                    nv[a] = b.min[a];
                } else {
                    pv[a] = b.min[a];
                    nv[a] = b.max[a];
                }
            }
            if n.dot(pv) + p.w < 0.0 {
                return Containment::Outside;
            }
            if n.dot(nv) + p.w < 0.0 {
                all_inside = false;
            }
        }
        if all_inside {
            Containment::Inside
        } else {
            Containment::Intersecting
        }
    }

    /// Whether a world point is inside.
    #[cfg(test)]
    pub(crate) fn contains_point(&self, p: [f64; 3]) -> bool {
        let v = DVec3::from(p);
        self.planes
            .iter()
            .all(|pl| pl.truncate().dot(v) + pl.w >= 0.0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn bounds(min: [f64; 3], max: [f64; 3]) -> Bounds {
        Bounds { min, max }
    }

    #[test]
    fn fit_shows_all_corners() {
        let cases = [
            bounds([0.0; 3], [1.0; 3]),
            bounds(
                [637000.0, 5_100_000.0, 200.0],
                [638000.0, 5_101_500.0, 450.0],
            ),
            bounds([-5.0, -5.0, 0.0], [5.0, 5.0, 0.0]),
            bounds([0.0, 0.0, 0.0], [1000.0, 1.0, 1.0]),
        ];
        for b in &cases {
            for (w, h) in [(1280u32, 720u32), (320, 240), (100, 100)] {
                let mut cam = Camera::fit(b);
                cam.aspect = w as f64 / h as f64;
                cam.fit_to(b);
                let fr = cam.frustum(cam.aspect);
                assert_eq!(fr.contains_aabb(b), Containment::Inside, "{b:?}");
                for c in bounds_corners(b) {
                    let p = cam.project(c.into(), w, h).expect("corner projects");
                    assert!(p[0] >= 0.0 && p[0] <= w as f64, "{p:?}");
                    assert!(p[1] >= 0.0 && p[1] <= h as f64, "{p:?}");
                    // Via the f32 matrix relative to an origin too.
                    let o = b.min;
                    let m = cam.view_proj_aspect(o, w as f64 / h as f64);
                    let rel = (c - DVec3::from(o)).as_vec3();
                    let clip = m * rel.extend(1.0);
                    assert!(clip.w > 0.0 && clip.z >= -1e-4 * clip.w && clip.z <= clip.w * 1.0001);
                    assert!((clip.x / clip.w).abs() <= 1.0001);
                    assert!((clip.y / clip.w).abs() <= 1.0001);
                }
            }
        }
    }

    #[test]
    fn view_proj_keeps_precision_with_large_origin() {
        let origin = [637179.22, 5_100_123.456, 312.5];
        let b = bounds(
            [origin[0] - 2.0, origin[1] - 2.0, origin[2] - 1.0],
            [origin[0] + 2.0, origin[1] + 2.0, origin[2] + 1.0],
        );
        let cam = Camera::fit(&b);
        let (w, h) = (1920u32, 1080u32);
        let m = cam.view_proj_aspect(origin, w as f64 / h as f64);
        // Two points 0.5 mm apart must project apart, and match the f64 projection.
        for (dx, dy) in [(0.0, 0.0), (0.0005, 0.0), (0.3, -0.2), (1.0001, 1.5)] {
            let world = [origin[0] + dx, origin[1] + dy, origin[2]];
            let exact = cam.project(world, w, h).unwrap();
            let clip = m * glam::Vec4::new(dx as f32, dy as f32, 0.0, 1.0);
            let sx = (clip.x / clip.w * 0.5 + 0.5) * w as f32;
            let sy = (0.5 - clip.y / clip.w * 0.5) * h as f32;
            assert!((sx as f64 - exact[0]).abs() < 0.01, "{sx} vs {}", exact[0]);
            assert!((sy as f64 - exact[1]).abs() < 0.01, "{sy} vs {}", exact[1]);
        }
        // A naive f32 path (absolute coordinates) would be off by far more than
        // the sub-millimetre offset; check the relative path resolves 0.5 mm.
        let a = m * glam::Vec4::new(0.0, 0.0, 0.0, 1.0);
        let b2 = m * glam::Vec4::new(0.0005, 0.0, 0.0, 1.0);
        let pa = (a.x / a.w * 0.5 + 0.5) * w as f32;
        let pb = (b2.x / b2.w * 0.5 + 0.5) * w as f32;
        let exact_a = cam
            .project([origin[0], origin[1], origin[2]], w, h)
            .unwrap()[0];
        let exact_b = cam
            .project([origin[0] + 0.0005, origin[1], origin[2]], w, h)
            .unwrap()[0];
        let want = exact_b - exact_a;
        assert!(
            want.abs() > 0.05,
            "test setup: 0.5 mm should be visible ({want} px)"
        );
        assert!(((pb - pa) as f64 - want).abs() < 0.02 * want.abs().max(1.0));
    }

    #[test]
    fn frustum_classification() {
        let b = bounds([0.0; 3], [10.0; 3]);
        let cam = Camera::fit(&b);
        let fr = cam.frustum(16.0 / 9.0);
        assert_eq!(fr.contains_aabb(&b), Containment::Inside);
        let small = bounds([4.0; 3], [6.0; 3]);
        assert_eq!(fr.contains_aabb(&small), Containment::Inside);
        // Far behind the camera.
        let eye = cam.eye();
        let behind = eye - cam.forward() * 100.0;
        let bb = bounds((behind - DVec3::ONE).into(), (behind + DVec3::ONE).into());
        assert_eq!(fr.contains_aabb(&bb), Containment::Outside);
        // Far to the side.
        let side = bounds([1e6, 1e6, 0.0], [1e6 + 1.0, 1e6 + 1.0, 1.0]);
        assert_eq!(fr.contains_aabb(&side), Containment::Outside);
        // Huge box containing the camera straddles every plane.
        let huge = bounds([-1e5; 3], [1e5; 3]);
        assert_eq!(fr.contains_aabb(&huge), Containment::Intersecting);
        assert_eq!(fr.contains_aabb(&Bounds::EMPTY), Containment::Outside);
        assert!(fr.contains_point([5.0; 3]));
    }

    #[test]
    fn json_and_view_round_trip() {
        let cam = Camera::fit(&bounds([0.0; 3], [3.0, 4.0, 5.0]));
        let back = Camera::from_json(&cam.to_json()).unwrap();
        assert_eq!(cam, back);
        let partial = Camera::from_json(r#"{"yaw": 1.0, "mode": "fly"}"#).unwrap();
        assert_eq!(partial.mode, CameraMode::Fly);
        assert_eq!(partial.yaw, 1.0);
        assert!(Camera::from_json("{nope").is_err());
        // Fields left out keep the base camera's; unknown ones are refused.
        let over = Camera::from_json_over(r#"{"yaw": 0.25}"#, &cam).unwrap();
        assert_eq!(over.yaw, 0.25);
        assert_eq!((over.target, over.distance), (cam.target, cam.distance));
        let e = Camera::from_json_over(r#"{"yaww": 0.25}"#, &cam).unwrap_err();
        assert!(
            e.0.contains("unknown field 'yaww'") && e.0.contains("yaw"),
            "{e}"
        );
        assert!(Camera::from_json_over("[1, 2]", &cam).is_err());
        assert!(Camera::from_json_over(r#"{"yaw": "left"}"#, &cam).is_err());
        for (json, says) in [
            (r#"{"distance": -5}"#, "distance"),
            (r#"{"fov_y": 0}"#, "fov_y"),
            (r#"{"aspect": 0}"#, "aspect"),
            (r#"{"pitch": 2}"#, "pitch"),
            (r#"{"near": 10, "far": 1}"#, "near"),
        ] {
            let e = Camera::from_json_over(json, &cam).unwrap_err();
            assert!(e.0.contains(says), "{json}: {e}");
        }
        let v = parse_view("30, -45, 120").unwrap();
        assert_eq!(v.distance, Some(120.0));
        let v2: ViewSpec = "10,20".parse().unwrap();
        assert_eq!(v2.distance, None);
        assert!(parse_view("1").is_err());
        assert!(parse_view("a,b").is_err());
        assert!(parse_view("1,2,-3").is_err());
        assert!(parse_view("1,2,3,4").is_err());
        assert!(parse_view("45,180").unwrap_err().0.contains("pitch"));
        assert!(parse_view("45,-90").is_ok());
        let mut c = cam;
        c.apply_view(&v);
        assert!((c.yaw - 30f64.to_radians()).abs() < 1e-12);
        assert_eq!(c.distance, 120.0);
    }

    #[test]
    fn navigation_helpers() {
        let b = bounds([0.0; 3], [10.0; 3]);
        let mut cam = Camera::fit(&b);
        let t = cam.target;
        let d = cam.distance;
        cam.rotate(0.3, 0.2);
        assert_eq!(cam.target, t);
        assert!(((cam.eye() - t).length() - d).abs() < 1e-9);
        cam.rotate(0.0, 10.0);
        assert_eq!(cam.pitch, MAX_PITCH);
        assert!(cam.view_proj([0.0; 3]).is_finite());
        cam.zoom(0.5);
        assert!((cam.distance - d * 0.5).abs() < 1e-9);
        cam.zoom(f64::NAN);
        cam.zoom(-1.0);
        assert!((cam.distance - d * 0.5).abs() < 1e-9);
        let eye = cam.eye();
        cam.translate(1.0, 2.0, 3.0);
        let moved = cam.eye() - eye;
        assert!((moved.length() - 14f64.sqrt()).abs() < 1e-9);
        assert!(cam.right().dot(cam.forward()).abs() < 1e-12);
        assert!(cam.up().dot(cam.forward()).abs() < 1e-12);
        // Right is to the right on screen, up is up.
        let c = cam.target;
        let r = cam.project((c + cam.right()).into(), 100, 100).unwrap();
        let u = cam.project((c + cam.up()).into(), 100, 100).unwrap();
        assert!(r[0] > 50.0 && (r[1] - 50.0).abs() < 1e-6);
        assert!(u[1] < 50.0 && (u[0] - 50.0).abs() < 1e-6);
        cam.set_mode(CameraMode::Fly);
        let p = cam.position;
        cam.zoom(0.5);
        assert!(((cam.position - p).length() - 0.5 * cam.distance).abs() < 1e-9);
    }

    #[test]
    fn modes_and_projected_size() {
        let mut cam = Camera::fit(&bounds([0.0; 3], [10.0; 3]));
        let eye = cam.eye();
        let m0 = cam.view_proj([0.0; 3]);
        cam.set_mode(CameraMode::Fly);
        assert!((cam.eye() - eye).length() < 1e-9);
        let m1 = cam.view_proj([0.0; 3]);
        assert!(m0.abs_diff_eq(m1, 1e-5));
        cam.set_mode(CameraMode::Orbit);
        assert!((cam.eye() - eye).length() < 1e-6);
        let ppu = cam.pixels_per_unit(10.0, 720);
        assert!((cam.projected_size(2.0, 10.0, 720) - 2.0 * ppu).abs() < 1e-9);
        assert!(cam.pixels_per_unit(20.0, 720) < ppu);
        // Degenerate bounds leave the camera usable.
        let mut d = Camera::default();
        d.fit_to(&Bounds::EMPTY);
        assert_eq!(d, Camera::default());
        let p = Camera::fit(&bounds([1.0; 3], [1.0; 3]));
        assert!(p.view_proj([0.0; 3]).is_finite());
    }
}
