//! Cameras that map world points (metres, Y up) to pixels: a 3/4 perspective and two orthographic views.

use glam::Vec3;

/// Axis-aligned box in world coordinates that a view must show for a whole animation.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Bounds {
    /// Smallest x, y, z seen.
    pub min: Vec3,
    /// Largest x, y, z seen.
    pub max: Vec3,
}

impl Bounds {
    /// An empty box; [`Bounds::include`] grows it.
    pub fn empty() -> Self {
        Self {
            min: Vec3::INFINITY,
            max: Vec3::NEG_INFINITY,
        }
    }

    /// Grows the box to hold `point`; non-finite points are ignored so one bad sample cannot blow up a view.
    pub fn include(&mut self, point: impl Into<Vec3>) {
        let point = point.into();
        if point.is_finite() {
            self.min = self.min.min(point);
            self.max = self.max.max(point);
        }
    }

    /// Grows the box by `margin` metres on every side.
    pub fn padded(self, margin: f32) -> Self {
        Self {
            min: self.min - margin,
            max: self.max + margin,
        }
    }

    fn center(&self) -> Vec3 {
        0.5 * (self.min + self.max)
    }

    fn corners(&self) -> [Vec3; 8] {
        std::array::from_fn(|k| {
            Vec3::select(
                glam::BVec3::new(k & 1 == 0, k & 2 == 0, k & 4 == 0),
                self.min,
                self.max,
            )
        })
    }
}

/// A pixel rectangle of the picture that one camera draws into.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Panel {
    /// Left edge in pixels.
    pub x: i32,
    /// Top edge in pixels.
    pub y: i32,
    /// Width in pixels.
    pub width: i32,
    /// Height in pixels.
    pub height: i32,
}

/// A camera looking at a [`Bounds`] box, fitted so that the whole box fills its [`Panel`].
#[derive(Clone, Debug)]
pub struct Camera {
    target: Vec3,
    right: Vec3,
    up: Vec3,
    forward: Vec3,
    /// Eye distance from the target for a perspective camera; `None` for an orthographic one.
    eye_distance: Option<f32>,
    pixels_per_metre: f32,
    origin_px: [f32; 2],
}

impl Camera {
    /// Orthographic camera looking along `forward` with `up` pointing up on screen.
    pub fn orthographic(
        bounds: &Bounds,
        forward: Vec3,
        up: Vec3,
        panel: Panel,
        margin_px: f32,
    ) -> Self {
        Self::fitted(bounds, forward, up, None, panel, margin_px)
    }

    /// Perspective camera on a sphere around the box centre: `azimuth_deg` turns from +Z towards +X,
    /// `elevation_deg` lifts the eye above the horizon; the eye stands `distance_factor` box diagonals away.
    pub fn perspective(
        bounds: &Bounds,
        azimuth_deg: f32,
        elevation_deg: f32,
        distance_factor: f32,
        panel: Panel,
        margin_px: f32,
    ) -> Self {
        let (az, el) = (azimuth_deg.to_radians(), elevation_deg.to_radians());
        let towards_eye = Vec3::new(az.sin() * el.cos(), el.sin(), az.cos() * el.cos());
        let diagonal = (bounds.max - bounds.min).length().max(1e-3);
        Self::fitted(
            bounds,
            -towards_eye,
            Vec3::Y,
            Some(distance_factor * diagonal),
            panel,
            margin_px,
        )
    }

    fn fitted(
        bounds: &Bounds,
        forward: Vec3,
        up_hint: Vec3,
        eye_distance: Option<f32>,
        panel: Panel,
        margin_px: f32,
    ) -> Self {
        let forward = forward.normalize_or_zero();
        let right = forward.cross(up_hint).normalize_or_zero();
        let up = right.cross(forward);
        let mut camera = Self {
            target: bounds.center(),
            right,
            up,
            forward,
            eye_distance,
            pixels_per_metre: 1.0,
            origin_px: [0.0, 0.0],
        };
        // Project the box corners at unit scale, then choose scale and offset so they fill the panel.
        let (mut lo, mut hi) = ([f32::INFINITY; 2], [f32::NEG_INFINITY; 2]);
        for corner in bounds.corners() {
            let (plane, _) = camera.to_image_plane(corner);
            for k in 0..2 {
                lo[k] = lo[k].min(plane[k]);
                hi[k] = hi[k].max(plane[k]);
            }
        }
        let usable = [
            (panel.width as f32 - 2.0 * margin_px).max(1.0),
            (panel.height as f32 - 2.0 * margin_px).max(1.0),
        ];
        let extent = [(hi[0] - lo[0]).max(1e-6), (hi[1] - lo[1]).max(1e-6)];
        let scale = (usable[0] / extent[0]).min(usable[1] / extent[1]);
        let mid = [0.5 * (lo[0] + hi[0]), 0.5 * (lo[1] + hi[1])];
        camera.pixels_per_metre = scale;
        camera.origin_px = [
            panel.x as f32 + 0.5 * panel.width as f32 - scale * mid[0],
            panel.y as f32 + 0.5 * panel.height as f32 + scale * mid[1],
        ];
        camera
    }

    /// Image-plane coordinates (metres at the target's depth, y up) and depth along the view direction.
    fn to_image_plane(&self, point: Vec3) -> ([f32; 2], f32) {
        let d = point - self.target;
        let (x, y, z) = (d.dot(self.right), d.dot(self.up), d.dot(self.forward));
        match self.eye_distance {
            Some(distance) => {
                let depth = (z + distance).max(1e-4);
                ([x * distance / depth, y * distance / depth], depth)
            }
            None => ([x, y], z),
        }
    }

    /// Pixel column, pixel row (down) and depth (larger is farther from the viewer) of a world point.
    pub fn project(&self, point: impl Into<Vec3>) -> (f32, f32, f32) {
        let ([x, y], depth) = self.to_image_plane(point.into());
        (
            self.origin_px[0] + self.pixels_per_metre * x,
            self.origin_px[1] - self.pixels_per_metre * y,
            depth,
        )
    }

    /// The same camera aimed at `target`: the new target lands where the old one did on screen.
    pub fn aimed_at(&self, target: Vec3) -> Self {
        Self {
            target,
            ..self.clone()
        }
    }

    /// Pixels per metre at the target's depth (exact everywhere for an orthographic camera).
    pub fn pixels_per_metre(&self) -> f32 {
        self.pixels_per_metre
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn unit_box() -> Bounds {
        let mut bounds = Bounds::empty();
        bounds.include([0.0, 0.0, 0.0]);
        bounds.include([1.0, 1.0, 1.0]);
        bounds
    }

    const PANEL: Panel = Panel {
        x: 100,
        y: 50,
        width: 400,
        height: 200,
    };

    #[test]
    fn bounds_ignore_non_finite_points_and_pad() {
        let mut bounds = unit_box();
        bounds.include([f32::NAN, 5.0, 5.0]);
        assert_eq!(bounds.max, Vec3::ONE);
        assert_eq!(bounds.padded(0.5).min, Vec3::splat(-0.5));
    }

    #[test]
    fn side_view_maps_x_right_y_up_and_ignores_z() {
        let camera = Camera::orthographic(&unit_box(), Vec3::NEG_Z, Vec3::Y, PANEL, 0.0);
        // The box is 1 x 1 in the side view, so it fills the panel height: 200 px per metre.
        assert!((camera.pixels_per_metre() - 200.0).abs() < 1e-3);
        let (cx, cy, _) = camera.project([0.5, 0.5, 0.3]);
        assert!((cx - 300.0).abs() < 1e-3 && (cy - 150.0).abs() < 1e-3);
        let (x0, y0, _) = camera.project([0.0, 0.0, 0.0]);
        assert!((x0 - 200.0).abs() < 1e-3 && (y0 - 250.0).abs() < 1e-3);
        let (x1, y1, _) = camera.project([0.0, 0.0, 1.0]);
        assert!((x1 - x0).abs() < 1e-4 && (y1 - y0).abs() < 1e-4);
        // Nearer the viewer (+Z) means smaller depth.
        assert!(camera.project([0.0, 0.0, 1.0]).2 < camera.project([0.0, 0.0, 0.0]).2);
    }

    #[test]
    fn side_view_along_x_puts_minus_z_to_the_right() {
        let camera = Camera::orthographic(&unit_box(), Vec3::NEG_X, Vec3::Y, PANEL, 0.0);
        let (xa, ya, _) = camera.project([0.5, 0.5, 0.0]);
        let (xb, yb, _) = camera.project([0.5, 0.5, 1.0]);
        assert!(xa > xb + 150.0 && (ya - yb).abs() < 1e-4);
        let (_, yc, _) = camera.project([0.5, 1.0, 0.0]);
        assert!(yc < ya);
    }

    #[test]
    fn top_view_puts_plus_z_towards_the_bottom() {
        let camera = Camera::orthographic(&unit_box(), Vec3::NEG_Y, Vec3::NEG_Z, PANEL, 0.0);
        let (xa, ya, _) = camera.project([0.2, 0.5, 0.0]);
        let (xb, yb, _) = camera.project([0.2, 0.5, 1.0]);
        assert!((xa - xb).abs() < 1e-4);
        assert!(yb > ya + 150.0);
        let (xc, _, _) = camera.project([0.8, 0.5, 0.0]);
        assert!(xc > xa);
    }

    #[test]
    fn perspective_shrinks_far_things_and_fits_the_panel() {
        let bounds = unit_box();
        let camera = Camera::perspective(&bounds, -35.0, 30.0, 2.0, PANEL, 10.0);
        for corner in bounds.corners() {
            let (x, y, _) = camera.project(corner);
            assert!((109.9..=490.1).contains(&x), "x {x}");
            assert!((59.9..=240.1).contains(&y), "y {y}");
        }
        // A unit segment parallel to the image plane looks shorter when it is farther away.
        let toward = -camera.forward;
        let length_at = |base: Vec3| {
            let a = camera.project(base);
            let b = camera.project(base + camera.right);
            ((a.0 - b.0).powi(2) + (a.1 - b.1).powi(2)).sqrt()
        };
        let centre = bounds.center();
        let near = centre + 0.5 * toward;
        let far = centre - 0.5 * toward;
        assert!(length_at(near) > 1.2 * length_at(far));
        assert!(camera.project(near).2 < camera.project(far).2);
        // Re-aiming moves the new target to the old target's pixel.
        let moved = camera.aimed_at(Vec3::splat(5.0));
        let (a, b) = (camera.project(centre), moved.project([5.0, 5.0, 5.0]));
        assert!((a.0 - b.0).abs() < 1e-3 && (a.1 - b.1).abs() < 1e-3);
    }
}
