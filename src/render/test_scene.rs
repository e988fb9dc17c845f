//! A small known scene the rendering tests draw.

use super::camera::Bounds;
use super::draw::View;
use super::frame::{Disc, Frame};

/// A flat 0.3 m x 0.25 m sheet of two triangles at height 0.25 m and two recorded markers.
pub struct KnownScene {
    package: Vec<[f32; 3]>,
    triangles: Vec<[u32; 3]>,
    markers: Vec<[f32; 3]>,
}

impl KnownScene {
    pub fn new() -> Self {
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
    pub fn frame(&self) -> Frame<'_> {
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

    pub fn view(&self, width: u32, height: u32) -> View {
        let mut bounds = Bounds::empty();
        self.package.iter().for_each(|&p| bounds.include(p));
        View::new(&bounds.padded(0.05), &bounds.padded(0.02), width, height)
    }
}
