//! Pictures of a package scene: PNG stills and animated GIFs, pure Rust (plotters bitmap backend with a
//! bundled DejaVu Sans font, the `gif` crate for animation).
//!
//! A caller fills a [`Frame`] (borrowed snapshot of one instant), builds one [`View`] for the whole
//! sequence from the [`Bounds`] of everything that will be shown, then calls [`write_png`] or feeds a
//! [`GifWriter`]. Files are written to a temporary name in the target folder and renamed into place.
//!
//! Layout: `frame` (what a picture shows, errors, the font), `camera` (projection), `draw` (the
//! drawing of a frame), `picture` (pixels and PNG files), `animation` (GIF files), [`plot`]
//! (charts of a replay and of the transport task).

mod animation;
mod camera;
mod draw;
mod frame;
mod picture;
pub mod plot;
#[cfg(test)]
mod test_scene;

pub use animation::GifWriter;
pub use camera::Bounds;
pub use draw::View;
pub use frame::{Disc, Frame, RenderError};
pub use picture::{write_png, write_png_side_by_side};
