//! Cleaning of motion-capture tracks (the paper's §6.2), in this order: Hungarian
//! re-identification of markers that reappear under a new id, rejection of spurious reflections,
//! velocity-based filling of short gaps, linear interpolation of long gaps (in the frame that moves
//! with the neighbouring markers), zero-phase Butterworth low-pass, and a retention count of what
//! was kept.
//!
//! Tracks are per-frame `Option<[f64; 3]>` series on one uniform time base (`None` = not seen).
//!
//! One file per concept: [`Series`] and its runs (`series.rs`), the parameters (`config.rs`),
//! re-identification (`reidentification.rs`) with the film-sheet test it relies on (`sheets.rs`)
//! and the assignment it solves (`assignment.rs`), gap filling (`gap_filling.rs`) with the
//! neighbourhood that carries hidden markers (`neighbourhood.rs`, `kabsch.rs`), the low-pass
//! (`butterworth.rs`), the whole marker cleaning (`markers.rs`) and its retention counts
//! (`retention.rs`).

mod assignment;
mod butterworth;
mod config;
mod error;
mod gap_filling;
mod geometry;
mod kabsch;
mod markers;
mod neighbourhood;
mod reidentification;
mod retention;
mod series;
mod sheets;
#[cfg(test)]
mod test_support;

pub use assignment::assign;
pub use butterworth::Butterworth;
pub use config::CleaningConfig;
pub use error::CleanError;
pub use gap_filling::{fill_gaps, SampleOrigin};
pub(crate) use kabsch::rigid_fit;
pub use markers::{clean_markers, CleanedMarkers};
pub use neighbourhood::Neighbourhood;
pub use reidentification::{reidentify, Reidentified, SheetRefusal};
pub use retention::{percent, MarkerRetention};
pub use series::{runs, Series};
pub use sheets::{fragment_sheets, Sheet};
