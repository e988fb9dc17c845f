//! The import of a take file: its take id, reading it (and its robot file) and converting it.

use std::path::Path;

use crate::motive;
use crate::robot::read_robot;

use super::{convert_with_robot, ImportConfig, ImportError, ImportedTake};

/// The take id of a file: its name without `.csv.gz` / `.csv`.
pub fn take_id(path: &Path) -> String {
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let name = name.strip_suffix(".gz").unwrap_or(&name);
    name.strip_suffix(".csv").unwrap_or(name).to_string()
}

/// Reads, cleans and converts one Motive take.
pub fn import_take(path: &Path, config: &ImportConfig) -> Result<ImportedTake, ImportError> {
    import_take_with_robot(path, None, config)
}

/// Reads, cleans and converts one Motive take; with `robot`, the tool track comes from that robot
/// trajectory file (see [`crate::robot`]) instead of the Motive tool rigid body.
pub fn import_take_with_robot(
    path: &Path,
    robot: Option<&Path>,
    config: &ImportConfig,
) -> Result<ImportedTake, ImportError> {
    let robot = robot.map(read_robot).transpose()?;
    let take = motive::read_take(path)?;
    convert_with_robot(&take, &take_id(path), config, robot.as_ref())
}
