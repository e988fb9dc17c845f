//! Motion-capture data for rlpkg: the dataset format (manifest + per-trajectory CSVs + meta), and the
//! import and cleaning of OptiTrack Motive CSV exports, and robot trajectory files as the tool track.

pub mod clean;
pub mod dataset;
pub mod derivative;
pub mod import;
pub mod motive;
pub mod robot;

pub use dataset::{
    load_trajectory, DataError, Dataset, ManifestEntry, MarkerFrames, Meta, ObjectTrack, Split,
    ToolTrack, Trajectory,
};
