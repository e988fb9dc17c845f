//! Rendering a [`Frame`] into pixels, alone or side by side, and writing it as a PNG.

use std::path::{Path, PathBuf};

use plotters::prelude::*;

use super::draw::{self, View};
use super::frame::{ensure_font, Frame, RenderError};

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
pub fn temporary_path(path: &Path, suffix: &str) -> PathBuf {
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
    use crate::render::test_scene::KnownScene;

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
