//! Pictures of a package scene: PNG stills and animated GIFs, pure Rust (plotters bitmap backend with a
//! bundled DejaVu Sans font, the `gif` crate for animation).
//!
//! A caller fills a [`Frame`] (borrowed snapshot of one instant), builds one [`View`] for the whole
//! sequence from the [`Bounds`] of everything that will be shown, then calls [`write_png`] or feeds a
//! [`GifWriter`]. Files are written to a temporary name in the target folder and renamed into place.

mod animation;
mod camera;
mod draw;
pub mod plot;

use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use glam::Vec3;
use plotters::prelude::*;

pub use animation::GifWriter;
pub use camera::Bounds;
pub use draw::View;

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
    fn triangles(&self, segments: usize) -> Vec<[[f32; 3]; 3]> {
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
/// text with plotters outside this module (the functions here call it themselves).
pub fn ensure_font() -> Result<(), RenderError> {
    static REGISTERED: OnceLock<bool> = OnceLock::new();
    let ok = *REGISTERED.get_or_init(|| {
        plotters::style::register_font("sans-serif", FontStyle::Normal, FONT_BYTES).is_ok()
    });
    ok.then_some(()).ok_or(RenderError::Font)
}

/// Renders `frame` into a packed RGB buffer of `view.size()` pixels.
pub fn render_rgb(frame: &Frame, view: &View) -> Result<Vec<u8>, RenderError> {
    ensure_font()?;
    draw::render(frame, view)
}

/// Renders `frames` side by side, each through its view (all of the same height), into one packed
/// RGB buffer; returns it with its size.
pub fn render_side_by_side(
    frames: &[(&Frame, &View)],
) -> Result<(Vec<u8>, (u32, u32)), RenderError> {
    let height = frames.first().map_or(0, |(_, view)| view.size().1);
    if frames.iter().any(|(_, view)| view.size().1 != height) {
        return Err(RenderError::Draw(
            "side-by-side views differ in height".into(),
        ));
    }
    let width: u32 = frames.iter().map(|(_, view)| view.size().0).sum();
    let images = frames
        .iter()
        .map(|(frame, view)| render_rgb(frame, view))
        .collect::<Result<Vec<_>, _>>()?;
    let mut rgb = Vec::with_capacity(3 * width as usize * height as usize);
    for row in 0..height as usize {
        for ((_, view), image) in frames.iter().zip(&images) {
            let stride = 3 * view.size().0 as usize;
            rgb.extend_from_slice(&image[row * stride..(row + 1) * stride]);
        }
    }
    Ok((rgb, (width, height)))
}

/// Writes `frame` as a PNG at `path` (atomically: temporary file in the same folder, then rename).
pub fn write_png(path: &Path, frame: &Frame, view: &View) -> Result<(), RenderError> {
    write_png_side_by_side(path, &[(frame, view)])
}

/// Writes `frames` side by side (see [`render_side_by_side`]) as one PNG at `path`.
pub fn write_png_side_by_side(path: &Path, frames: &[(&Frame, &View)]) -> Result<(), RenderError> {
    let (pixels, size) = render_side_by_side(frames)?;
    let write_error = |message: String| RenderError::Write {
        path: path.to_path_buf(),
        message,
    };
    // The PNG encoder picks the format from the extension, so the temporary name ends in `.png` too.
    let temporary = temporary_path(path, ".png");
    let result = (|| {
        let mut backend = BitMapBackend::new(&temporary, size);
        backend
            .blit_bitmap((0, 0), size, &pixels)
            .map_err(|err| write_error(err.to_string()))?;
        backend
            .present()
            .map_err(|err| write_error(err.to_string()))?;
        drop(backend);
        std::fs::rename(&temporary, path).map_err(|err| write_error(err.to_string()))
    })();
    if result.is_err() {
        let _ = std::fs::remove_file(&temporary);
    }
    result
}

/// A hidden sibling of `path` that is unique to this process and this call.
fn temporary_path(path: &Path, suffix: &str) -> PathBuf {
    use std::sync::atomic::{AtomicU64, Ordering};
    static COUNTER: AtomicU64 = AtomicU64::new(0);
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let unique = COUNTER.fetch_add(1, Ordering::Relaxed);
    path.with_file_name(format!(
        ".{name}.{}.{unique}.tmp{suffix}",
        std::process::id()
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A flat 0.3 m x 0.25 m sheet of two triangles at height 0.25 m and two recorded markers.
    pub(crate) struct KnownScene {
        package: Vec<[f32; 3]>,
        triangles: Vec<[u32; 3]>,
        markers: Vec<[f32; 3]>,
    }

    impl KnownScene {
        pub(crate) fn new() -> Self {
            Self {
                package: vec![
                    [0.0, 0.25, 0.0],
                    [0.3, 0.25, 0.0],
                    [0.0, 0.25, 0.25],
                    [0.3, 0.25, 0.25],
                ],
                triangles: vec![[0, 1, 2], [1, 3, 2]],
                markers: vec![[0.05, 0.25, 0.05], [0.25, 0.25, 0.2]],
            }
        }

        /// The scene with a disc inside the sheet and the recorded object at its centre.
        pub(crate) fn frame(&self) -> Frame<'_> {
            Frame {
                title: "test",
                time: 0.5,
                package: &self.package,
                triangles: &self.triangles,
                cups: &[],
                disc: Some(Disc {
                    center: [0.15, 0.25, 0.12],
                    rotation: [0.0, 0.0, 0.0, 1.0],
                    radius: 0.08,
                    thickness: 0.015,
                }),
                recorded_markers: &self.markers,
                simulated_markers: &[],
                recorded_object: Some([0.15, 0.25, 0.12]),
            }
        }

        pub(crate) fn view(&self, width: u32, height: u32) -> View {
            let mut bounds = Bounds::empty();
            self.package.iter().for_each(|&p| bounds.include(p));
            View::new(&bounds.padded(0.05), &bounds.padded(0.02), width, height)
        }
    }

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

    #[test]
    fn rendered_scene_has_package_pixels_where_the_package_is() {
        let scene = KnownScene::new();
        let view = scene.view(640, 360);
        let empty_frame = Frame {
            triangles: &[],
            disc: None,
            recorded_markers: &[],
            recorded_object: None,
            ..scene.frame()
        };
        let camera = view.main_camera();
        // A point of the sheet between disc and corner: covered by the sheet only.
        let (x, y, _) = camera.project([0.28, 0.25, 0.02]);
        let at = |rgb: &[u8]| {
            let k = 3 * (y.round() as usize * 640 + x.round() as usize);
            [rgb[k], rgb[k + 1], rgb[k + 2]]
        };
        let background = at(&render_rgb(&empty_frame, &view).unwrap());
        let with_sheet = at(&render_rgb(&scene.frame(), &view).unwrap());
        assert_eq!(background, [250, 250, 248]);
        assert_ne!(with_sheet, background);
        // Bluish: the package colour dominates.
        assert!(with_sheet[2] > with_sheet[0] + 20, "{with_sheet:?}");
        // The disc centre is drawn in the disc's orange, seen through the translucent sheet.
        let (dx, dy, _) = camera.project([0.15, 0.26, 0.12]);
        let rgb = render_rgb(&scene.frame(), &view).unwrap();
        let k = 3 * (dy.round() as usize * 640 + dx.round() as usize + 20);
        assert!(rgb[k] > rgb[k + 2] + 20, "{:?}", &rgb[k..k + 3]);
    }

    #[test]
    fn png_is_written_atomically_and_is_a_png() {
        let scene = KnownScene::new();
        let view = scene.view(320, 180);
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("frame.png");
        write_png(&path, &scene.frame(), &view).unwrap();
        let bytes = std::fs::read(&path).unwrap();
        assert_eq!(&bytes[..8], b"\x89PNG\r\n\x1a\n");
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1);
        let missing = dir.path().join("no-such-dir").join("frame.png");
        let err = write_png(&missing, &scene.frame(), &view).unwrap_err();
        assert!(err.to_string().contains("no-such-dir"), "{err}");
    }
}
