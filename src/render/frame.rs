//! What a picture shows ([`Frame`], [`Disc`]), what can go wrong drawing it ([`RenderError`]), and
//! the bundled font every picture is labelled with.

use std::path::PathBuf;
use std::sync::OnceLock;

use glam::Vec3;
use plotters::prelude::FontStyle;

/// DejaVu Sans 2.37 (Bitstream Vera licence, see `DejaVuSans-LICENSE.txt` beside it).
static FONT_BYTES: &[u8] = include_bytes!("DejaVuSans.ttf");

/// What can go wrong while drawing or writing a picture.
#[derive(Debug, thiserror::Error)]
pub enum RenderError {
    /// The bundled font could not be registered with plotters.
    #[error("the bundled font DejaVuSans.ttf could not be loaded")]
    Font,
    /// Drawing into the bitmap failed.
    #[error("drawing failed: {0}")]
    Draw(String),
    /// Writing or renaming an output file failed.
    #[error("cannot write {path}: {message}")]
    Write {
        /// The file that was being written.
        path: PathBuf,
        /// What the operating system or encoder said.
        message: String,
    },
}

/// The internal rigid disc: a flat cylinder whose axis is the body's y axis.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Disc {
    /// Centre of the disc in world coordinates (m).
    pub center: [f32; 3],
    /// Orientation as a unit quaternion (x, y, z, w).
    pub rotation: [f32; 4],
    /// Radius (m).
    pub radius: f32,
    /// Thickness along the body y axis (m).
    pub thickness: f32,
}

impl Disc {
    /// World-space triangles of a prism with `segments` sides approximating the disc.
    pub(crate) fn triangles(&self, segments: usize) -> Vec<[[f32; 3]; 3]> {
        let half = 0.5 * self.thickness;
        let ring = |y: f32| -> Vec<[f32; 3]> {
            (0..segments)
                .map(|k| {
                    let angle = std::f32::consts::TAU * k as f32 / segments as f32;
                    self.body_to_world([self.radius * angle.cos(), y, self.radius * angle.sin()])
                })
                .collect()
        };
        let (upper, lower) = (ring(half), ring(-half));
        let (upper_centre, lower_centre) = (
            self.body_to_world([0.0, half, 0.0]),
            self.body_to_world([0.0, -half, 0.0]),
        );
        let mut triangles = Vec::with_capacity(4 * segments);
        for k in 0..segments {
            let next = (k + 1) % segments;
            triangles.push([upper_centre, upper[k], upper[next]]);
            triangles.push([lower_centre, lower[next], lower[k]]);
            triangles.push([upper[k], lower[k], lower[next]]);
            triangles.push([upper[k], lower[next], upper[next]]);
        }
        triangles
    }

    fn body_to_world(&self, body: [f32; 3]) -> [f32; 3] {
        let rotation = glam::Quat::from_array(self.rotation);
        (Vec3::from(self.center) + rotation * Vec3::from(body)).to_array()
    }
}

/// A borrowed snapshot of the scene at one instant. Empty slices and `None` are simply not drawn.
#[derive(Clone, Copy, Debug)]
pub struct Frame<'a> {
    /// Heading shown at the top left (e.g. the trajectory id).
    pub title: &'a str,
    /// Time stamp shown beside the title (s).
    pub time: f32,
    /// Package particle positions (m).
    pub package: &'a [[f32; 3]],
    /// Package triangles as indices into `package` (shared topology of every frame).
    pub triangles: &'a [[u32; 3]],
    /// Suction-cup particle positions (m).
    pub cups: &'a [[f32; 3]],
    /// The internal disc, if any.
    pub disc: Option<Disc>,
    /// Recorded motion-capture markers of this instant (m).
    pub recorded_markers: &'a [[f32; 3]],
    /// Simulated positions of the marker sites (m).
    pub simulated_markers: &'a [[f32; 3]],
    /// Recorded centre of the internal object (m).
    pub recorded_object: Option<[f32; 3]>,
}

/// Registers the bundled font once per process under the name "sans-serif"; call it before drawing
/// text with plotters outside the drawing functions of this folder (they call it themselves).
pub fn ensure_font() -> Result<(), RenderError> {
    static REGISTERED: OnceLock<bool> = OnceLock::new();
    let ok = *REGISTERED.get_or_init(|| {
        plotters::style::register_font("sans-serif", FontStyle::Normal, FONT_BYTES).is_ok()
    });
    ok.then_some(()).ok_or(RenderError::Font)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn disc_rotation_turns_its_axis() {
        let half_turn_about_x = std::f32::consts::FRAC_1_SQRT_2;
        let disc = Disc {
            center: [1.0, 2.0, 3.0],
            rotation: [half_turn_about_x, 0.0, 0.0, half_turn_about_x],
            radius: 0.1,
            thickness: 0.02,
        };
        // +90 degrees about X maps body +y to world +z.
        let p = disc.body_to_world([0.0, 1.0, 0.0]);
        assert!(
            (p[0] - 1.0).abs() < 1e-6 && (p[1] - 2.0).abs() < 1e-6 && (p[2] - 4.0).abs() < 1e-6
        );
        let triangles = disc.triangles(12);
        assert_eq!(triangles.len(), 48);
        for corner in triangles.iter().flatten() {
            let r = ((corner[0] - 1.0).powi(2) + (corner[1] - 2.0).powi(2)).sqrt();
            assert!(r <= 0.1 + 1e-5 && (corner[2] - 3.0).abs() <= 0.01 + 1e-6);
        }
    }
}
