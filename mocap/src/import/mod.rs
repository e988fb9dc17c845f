//! Conversion of a Motive take into the dataset format: pick the tool and object rigid bodies and
//! the package markers, clean them (see [`crate::clean`]), optionally trim to the motion, derive
//! velocities and accelerations, and fill `meta.toml` and the manifest entry.
//!
//! Assumptions (all configurable in `configs/import/motive.toml`): the tool is the first rigid body and the
//! object the second; the suction-cup centre sits at a fixed offset in the tool's frame; the
//! package markers are the unlabelled markers; package and object masses come from the config, and
//! every take must be listed there (or a `[default_take]` given). With a robot trajectory file
//! (see [`crate::robot`]) the tool track is the robot's command instead of the tool rigid body.
//!
//! One file per concept: the config (`config.rs`) and its per-take settings (`takes.rs`), the
//! error (`error.rs`), reading a take file (`take_file.rs`), the conversion of a parsed take
//! (`conversion.rs`) with the cleaning of its rigid bodies (`rigid_body.rs`), and the retention
//! report (`report.rs`).

mod config;
mod conversion;
mod error;
mod report;
mod rigid_body;
mod take_file;
mod takes;
#[cfg(test)]
mod tests;

pub use config::{ConversionConfig, ImportConfig, MarkerSource, PackageProperties};
pub use conversion::{convert, convert_with_robot, ImportedTake};
pub use error::ImportError;
pub use report::{RetentionReport, RobotFit};
pub use take_file::{import_take, import_take_with_robot, take_id};
pub use takes::{TakeConfig, TakeSettings};
