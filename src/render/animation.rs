//! Animated GIF output: frames are rendered, colour-quantised (NeuQuant) and appended one at a time.

use std::fs::File;
use std::io::BufWriter;
use std::path::{Path, PathBuf};

use super::draw::View;
use super::frame::{Frame, RenderError};
use super::picture::{render_rgb, render_side_by_side, temporary_path};

/// Quantiser speed 1..=30: higher is faster and coarser; 10 keeps shading smooth at a few ms per frame.
const QUANTISER_SPEED: i32 = 10;

/// Writes an endlessly looping GIF; the file appears at its final path only after [`GifWriter::finish`].
pub struct GifWriter {
    encoder: Option<gif::Encoder<BufWriter<File>>>,
    temporary: PathBuf,
    path: PathBuf,
    size: (u16, u16),
    delay_centiseconds: u16,
    frames: usize,
    finished: bool,
}

impl GifWriter {
    /// Starts a GIF of `size` pixels at `path`, showing each frame for `frame_seconds`.
    pub fn create(path: &Path, size: (u32, u32), frame_seconds: f32) -> Result<Self, RenderError> {
        let write_error = |message: String| RenderError::Write {
            path: path.to_path_buf(),
            message,
        };
        let width = u16::try_from(size.0).map_err(|_| write_error("width above 65535".into()))?;
        let height = u16::try_from(size.1).map_err(|_| write_error("height above 65535".into()))?;
        let temporary = temporary_path(path, "");
        let file = File::create(&temporary).map_err(|err| write_error(err.to_string()))?;
        let mut encoder = gif::Encoder::new(BufWriter::new(file), width, height, &[])
            .map_err(|err| write_error(err.to_string()))?;
        encoder
            .set_repeat(gif::Repeat::Infinite)
            .map_err(|err| write_error(err.to_string()))?;
        Ok(Self {
            encoder: Some(encoder),
            temporary,
            path: path.to_path_buf(),
            size: (width, height),
            // GIF delays are in 1/100 s; browsers treat delays below 2 as 10, so keep at least 2.
            delay_centiseconds: (frame_seconds * 100.0).round().clamp(2.0, 65535.0) as u16,
            frames: 0,
            finished: false,
        })
    }

    /// Renders `frame` through `view` and appends it; `view` must have the size given to `create`.
    pub fn add(&mut self, frame: &Frame, view: &View) -> Result<(), RenderError> {
        let (width, height) = view.size();
        if (width, height) != (u32::from(self.size.0), u32::from(self.size.1)) {
            return Err(RenderError::Draw(format!(
                "GIF frame is {width}x{height} but the GIF is {}x{}",
                self.size.0, self.size.1
            )));
        }
        let rgb = render_rgb(frame, view)?;
        self.append_rgb(&rgb)
    }

    /// Renders `frames` side by side, each through its view, and appends them as one frame: the
    /// views must have the GIF's height and their widths must add up to its width.
    pub fn add_side_by_side(&mut self, frames: &[(&Frame, &View)]) -> Result<(), RenderError> {
        let (rgb, size) = render_side_by_side(frames)?;
        if size != (u32::from(self.size.0), u32::from(self.size.1)) {
            return Err(RenderError::Draw(format!(
                "side-by-side frames of {}x{} in a {}x{} GIF",
                size.0, size.1, self.size.0, self.size.1
            )));
        }
        self.append_rgb(&rgb)
    }

    /// Quantises an RGB picture of the GIF's size and appends it.
    fn append_rgb(&mut self, rgb: &[u8]) -> Result<(), RenderError> {
        let mut gif_frame =
            gif::Frame::from_rgb_speed(self.size.0, self.size.1, rgb, QUANTISER_SPEED);
        gif_frame.delay = self.delay_centiseconds;
        let path = &self.path;
        let write_error = |message: String| RenderError::Write {
            path: path.clone(),
            message,
        };
        self.encoder
            .as_mut()
            .ok_or_else(|| write_error("already finished".into()))?
            .write_frame(&gif_frame)
            .map_err(|err| write_error(err.to_string()))?;
        self.frames += 1;
        Ok(())
    }

    /// Number of frames appended so far.
    pub fn frames(&self) -> usize {
        self.frames
    }

    /// Writes the trailer, flushes and renames the file into place; returns its path.
    pub fn finish(mut self) -> Result<PathBuf, RenderError> {
        let encoder = self
            .encoder
            .take()
            .ok_or_else(|| self.write_error("already finished"))?;
        let writer = encoder
            .into_inner()
            .map_err(|err| self.write_error(&err.to_string()))?;
        let file = writer
            .into_inner()
            .map_err(|err| self.write_error(&err.to_string()))?;
        file.sync_all()
            .map_err(|err| self.write_error(&err.to_string()))?;
        std::fs::rename(&self.temporary, &self.path)
            .map_err(|err| self.write_error(&err.to_string()))?;
        self.finished = true;
        Ok(self.path.clone())
    }

    fn write_error(&self, message: &str) -> RenderError {
        RenderError::Write {
            path: self.path.clone(),
            message: message.to_string(),
        }
    }
}

impl Drop for GifWriter {
    /// An unfinished GIF leaves nothing behind.
    fn drop(&mut self) {
        drop(self.encoder.take());
        if !self.finished {
            let _ = std::fs::remove_file(&self.temporary);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::render::test_scene::KnownScene;

    #[test]
    fn gif_decodes_with_the_expected_frame_count_and_size() {
        let scene = KnownScene::new();
        let view = scene.view(320, 180);
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("replay.gif");
        let mut writer = GifWriter::create(&path, view.size(), 0.1).unwrap();
        for k in 0..3 {
            let mut frame = scene.frame();
            frame.time = k as f32 * 0.1;
            writer.add(&frame, &view).unwrap();
        }
        assert_eq!(writer.frames(), 3);
        assert!(!path.exists(), "the GIF must appear only when finished");
        writer.finish().unwrap();

        let mut options = gif::DecodeOptions::new();
        options.set_color_output(gif::ColorOutput::RGBA);
        let mut decoder = options.read_info(File::open(&path).unwrap()).unwrap();
        assert_eq!((decoder.width(), decoder.height()), (320, 180));
        let mut count = 0;
        while let Some(frame) = decoder.read_next_frame().unwrap() {
            assert_eq!(frame.delay, 10);
            // Not a blank picture: more than one colour.
            let first = &frame.buffer[..4];
            assert!(frame.buffer.chunks(4).any(|px| px != first));
            count += 1;
        }
        assert_eq!(count, 3);
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1);
    }

    #[test]
    fn dropped_writer_leaves_no_file_and_wrong_size_is_refused() {
        let scene = KnownScene::new();
        let view = scene.view(320, 180);
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("replay.gif");
        let mut writer = GifWriter::create(&path, (100, 100), 0.1).unwrap();
        let err = writer.add(&scene.frame(), &view).unwrap_err();
        assert!(err.to_string().contains("320x180"), "{err}");
        drop(writer);
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 0);
    }
}
