//! Motion-capture data for rlpkg: the dataset format (manifest + per-trajectory CSVs + meta), and the
//! import and cleaning of OptiTrack Motive CSV exports, robot trajectory files as the tool track, and
//! a take collection's `manifest.json` (geometry, layout and split).

pub mod clean;
pub mod dataset;
pub mod derivative;
pub mod description;
pub mod detach;
pub mod import;
pub mod motive;
pub mod robot;
pub mod tracking;

pub use dataset::{
    load_trajectory, DataError, Dataset, ManifestEntry, MarkerFrames, Meta, ObjectTrack, Split,
    ToolTrack, Trajectory,
};
pub use detach::{scan_detachment, Detachment, DetachmentConfig, DetachmentScan};
pub use tracking::{track_markers, TrackingReport, TrackingSettings};
