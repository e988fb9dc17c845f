//! Conversion of a Motive take into the dataset format: pick the tool and object rigid bodies and
//! the package markers, clean them (see [`crate::clean`]), optionally trim to the motion, derive
//! velocities and accelerations, and fill `meta.toml` and the manifest entry.
//!
//! Assumptions (all configurable in `configs/import/motive.toml`): the tool is the first rigid body and the
//! object the second; the suction-cup centre sits at a fixed offset in the tool's frame; the
//! package markers are the unlabelled markers; package and object masses come from the config, and
//! every take must be listed there (or a `[default_take]` given). With a robot trajectory file
//! (see [`crate::robot`]) the tool track is the robot's command instead of the tool rigid body.

use std::collections::BTreeMap;
use std::fmt;
use std::path::{Path, PathBuf};

use glam::{DQuat, DVec3};
use nalgebra::Vector3;
use serde::{Deserialize, Serialize};
use thiserror::Error;

use crate::clean::{
    self, percent, Butterworth, CleanError, CleaningConfig, MarkerRetention, Series,
};
use crate::dataset::{
    DataError, ManifestEntry, MarkerFrames, Meta, ObjectTrack, Split, ToolTrack, Trajectory,
};
use crate::derivative::{angular_velocity, gradient};
use crate::description::{PackageDescription, TakeRole};
use crate::motive::{self, MarkerKind, MotiveError, MotiveTake};
use crate::robot::{
    self, covered_frames, read_robot, RigidTransform, RobotConfig, RobotTrajectory,
};

/// An import failure; the message names the file and what was expected.
#[derive(Debug, Error)]
pub enum ImportError {
    /// The take could not be read or parsed.
    #[error(transparent)]
    Motive(#[from] MotiveError),
    /// The config file could not be read, parsed, or holds a value out of range.
    #[error("{}: {message}", path.display())]
    Config {
        /// The config file.
        path: PathBuf,
        /// Key (and line) and what was expected.
        message: String,
    },
    /// A robot trajectory file could not be read or is malformed.
    #[error(transparent)]
    Robot(#[from] DataError),
    /// The take parsed but cannot be converted (a rigid body missing, too few markers, ...).
    #[error("{}: {message}", path.display())]
    Take {
        /// The take file.
        path: PathBuf,
        /// What is missing and what was expected.
        message: String,
    },
}

/// Which marker columns are the package markers.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum MarkerSource {
    /// `Unlabeled <id>` markers (the package's flat markers are not labelled in Motive).
    Unlabeled,
    /// Labelled markers (a marker set labelled in Motive).
    Labeled,
    /// Both.
    All,
}

/// `[conversion]`: how a take maps onto tool, object and package markers.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ConversionConfig {
    /// Name of the tool rigid body; empty = the first rigid body.
    pub tool_body: String,
    /// Name of the object rigid body; empty = the second rigid body.
    pub object_body: String,
    /// Which marker columns are package markers.
    pub markers: MarkerSource,
    /// Suction-cup centre in the tool's local frame (m), added to the tool pose of the first frame
    /// to get `initial_suction_cup_position_m`.
    #[serde(deserialize_with = "rlpkg_toml_input::array")]
    pub tool_to_cup_m: [f64; 3],
    /// Keep only the frames from the start to the end of the tool's motion (plus margins).
    pub trim_to_motion: bool,
    /// Tool speed (m/s) above which the tool counts as moving.
    pub motion_speed_threshold_m_s: f64,
    /// Frames kept before the motion starts and after it ends (s).
    pub motion_margin_s: f64,
    /// Longest rigid-body dropout (s) that is bridged (position and orientation interpolated);
    /// longer ones end the usable frame range.
    pub max_rigid_body_gap_s: f64,
}

impl Default for ConversionConfig {
    fn default() -> Self {
        ConversionConfig {
            tool_body: String::new(),
            object_body: String::new(),
            markers: MarkerSource::Unlabeled,
            tool_to_cup_m: [0.0, -0.005, 0.0],
            trim_to_motion: false,
            motion_speed_threshold_m_s: 0.01,
            motion_margin_s: 0.0,
            max_rigid_body_gap_s: 0.1,
        }
    }
}

/// `[package]`: physical properties written to every `meta.toml` (masses per take in `[takes]`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct PackageConfig {
    /// Package footprint (short side, long side) in m.
    #[serde(deserialize_with = "rlpkg_toml_input::array")]
    pub size_m: [f64; 2],
    /// Package (film) mass in kg.
    pub mass_kg: f64,
    /// Object (disc) diameter in m.
    pub object_diameter_m: f64,
    /// Object body mass without added weights, kg.
    pub object_body_mass_kg: f64,
    /// How far the outermost markers sit inside the package's edges at the smallest mocap x and
    /// z (m), written to every `meta.toml` (replays place the package by it); `--manifest` sets
    /// it from the marker layout. Absent: markers on the edges.
    #[serde(deserialize_with = "rlpkg_toml_input::option")]
    pub marker_inset_m: Option<[f64; 2]>,
    /// Markers of the package's lower layer at the start of every take (m, mocap frame), hidden
    /// by the surface it lies on; written to every `meta.toml` (replays embed them in the lower
    /// sheet); `--manifest` sets them from the marker layout. Empty: none.
    #[serde(deserialize_with = "rlpkg_toml_input::list")]
    pub lower_marker_positions_m: Vec<[f64; 3]>,
}

impl Default for PackageConfig {
    fn default() -> Self {
        PackageConfig {
            size_m: [0.254, 0.3048],
            mass_kg: 0.03,
            object_diameter_m: 0.16,
            object_body_mass_kg: 0.2268,
            marker_inset_m: None,
            lower_marker_positions_m: Vec::new(),
        }
    }
}

/// `[takes."<id>"]` and `[default_take]`: per-take manifest fields. A take's own entry wins over
/// `[default_take]`; a field that neither gives is an error, never a silent default.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TakeConfig {
    /// Train or test (needed unless the take is excluded).
    pub split: Option<Split>,
    /// Clean and report the take but do not write it; false if not given.
    pub exclude: Option<bool>,
    /// A failure take (e.g. the suction seal let go): written, flagged, and in split `excluded`
    /// (out of train and test); false if not given.
    pub failure: Option<bool>,
    /// Object mass including weights (kg).
    pub object_total_mass_kg: Option<f64>,
    /// Mass class label.
    pub mass: Option<String>,
    /// Added mass in lb.
    pub mass_lb: Option<f64>,
    /// Speed class label.
    pub velocity: Option<String>,
    /// Placement orientation label.
    pub orientation: Option<String>,
}

/// The manifest fields of one take, resolved from its `[takes]` entry and `[default_take]`.
#[derive(Debug, Clone, PartialEq)]
pub struct TakeSettings {
    /// Train or test (train for an excluded take that gives none; it is not written); `excluded`
    /// for a failure take.
    pub split: Split,
    /// Not written to the dataset.
    pub exclude: bool,
    /// A failure take (written, flagged, split `excluded`).
    pub failure: bool,
    /// Object mass including weights (kg).
    pub object_total_mass_kg: f64,
    /// Mass class label.
    pub mass: Option<String>,
    /// Added mass in lb.
    pub mass_lb: Option<f64>,
    /// Speed class label.
    pub velocity: Option<String>,
    /// Placement orientation label.
    pub orientation: Option<String>,
}

/// The whole `configs/import/motive.toml`.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ImportConfig {
    /// Cleaning parameters.
    pub cleaning: CleaningConfig,
    /// Take -> trajectory mapping.
    pub conversion: ConversionConfig,
    /// Package and object properties.
    pub package: PackageConfig,
    /// Per-take manifest fields, by take id (the file name without `.csv` / `.csv.gz`).
    pub takes: BTreeMap<String, TakeConfig>,
    /// Robot-to-mocap transform for takes imported with their robot trajectory file.
    pub robot: RobotConfig,
    /// Fields for takes not listed in `takes` (and for fields a listed take leaves out); without
    /// it, an unlisted take is an error.
    pub default_take: Option<TakeConfig>,
}

impl ImportConfig {
    /// Reads and validates a config file.
    pub fn load(path: &Path) -> Result<Self, ImportError> {
        let config_err = |message: String| ImportError::Config {
            path: path.to_path_buf(),
            message,
        };
        let text = std::fs::read_to_string(path)
            .map_err(|e| config_err(format!("cannot read file: {e}")))?;
        let config: ImportConfig = toml::from_str(&text).map_err(|e| {
            let (line, message) = rlpkg_toml_input::error_at(&text, &e);
            config_err(format!("line {line}: {message}"))
        })?;
        config.validate().map_err(config_err)?;
        Ok(config)
    }

    /// Checks every value against its range; the message names the key and the range.
    pub fn validate(&self) -> Result<(), String> {
        self.cleaning.validate()?;
        self.robot.validate()?;
        let c = &self.conversion;
        // (key, value, zero allowed, largest plausible value): a package on a conveyor, not a planet.
        let checks = [
            (
                "conversion.motion_speed_threshold_m_s",
                c.motion_speed_threshold_m_s,
                false,
                100.0,
            ),
            (
                "conversion.motion_margin_s",
                c.motion_margin_s,
                true,
                3600.0,
            ),
            (
                "conversion.max_rigid_body_gap_s",
                c.max_rigid_body_gap_s,
                true,
                3600.0,
            ),
            ("package.size_m[0]", self.package.size_m[0], false, 10.0),
            ("package.size_m[1]", self.package.size_m[1], false, 10.0),
            ("package.mass_kg", self.package.mass_kg, true, 1000.0),
            (
                "package.object_diameter_m",
                self.package.object_diameter_m,
                false,
                10.0,
            ),
            (
                "package.object_body_mass_kg",
                self.package.object_body_mass_kg,
                true,
                1000.0,
            ),
        ];
        for (key, value, zero_allowed, max) in checks {
            let above_zero = if zero_allowed {
                value >= 0.0
            } else {
                value > 0.0
            };
            if !(value.is_finite() && above_zero && value <= max) {
                let low = if zero_allowed { "[0" } else { "(0" };
                return Err(format!(
                    "{key} = {value}: expected a number in {low}, {max}]"
                ));
            }
        }
        if let Some(inset) = self.package.marker_inset_m {
            let size = self.package.size_m[0].min(self.package.size_m[1]);
            if inset
                .iter()
                .any(|v| !(v.is_finite() && *v >= 0.0 && *v < size / 2.0))
            {
                return Err(format!(
                    "package.marker_inset_m = {inset:?}: expected 2 numbers in [0, {}) m (half the smaller side)",
                    size / 2.0
                ));
            }
        }
        if let Some((i, p)) = self
            .package
            .lower_marker_positions_m
            .iter()
            .enumerate()
            .find(|(_, p)| p.iter().any(|v| !(v.is_finite() && v.abs() <= 1e3)))
        {
            return Err(format!(
                "package.lower_marker_positions_m[{i}] = {p:?}: expected finite coordinates of magnitude <= 1e3 m"
            ));
        }
        if c.tool_to_cup_m
            .iter()
            .any(|v| !v.is_finite() || v.abs() > 1.0)
        {
            return Err(format!(
                "conversion.tool_to_cup_m = {:?}: expected 3 numbers within [-1, 1] m",
                c.tool_to_cup_m
            ));
        }
        let listed = self
            .takes
            .iter()
            .map(|(id, t)| (format!("takes.\"{id}\""), t));
        for (key, take) in
            listed.chain(self.default_take.iter().map(|t| ("default_take".into(), t)))
        {
            if let Some(m) = take.object_total_mass_kg {
                if !(m.is_finite() && m > 0.0) {
                    return Err(format!(
                        "{key}.object_total_mass_kg = {m}: expected a number > 0"
                    ));
                }
            }
        }
        for id in self.takes.keys() {
            self.take(id)?;
        }
        Ok(())
    }

    /// Takes from a collection's `manifest.json` the `[takes]` entries of `ids` (split: train,
    /// test, or `excluded` with the failure flag for a failure take; object mass, mass class,
    /// speed and placement angle) and, unless the config gives them, `package.marker_inset_m` and
    /// `package.lower_marker_positions_m` from the marker layout. A take the manifest does not
    /// list, or that the config's `[takes]` also lists, is an error (one source per take).
    pub fn apply_description(
        &mut self,
        description: &PackageDescription,
        ids: &[String],
    ) -> Result<(), String> {
        if self.package.marker_inset_m.is_none() {
            self.package.marker_inset_m = description.marker_inset_m();
        }
        if self.package.lower_marker_positions_m.is_empty() {
            self.package.lower_marker_positions_m = description.bottom_markers_at_start();
        }
        for id in ids {
            let Some(take) = description.take(id) else {
                return Err(format!(
                    "{}: trajectories: no take {id:?}; expected one of: {}",
                    description.path.display(),
                    description
                        .takes
                        .iter()
                        .map(|t| t.id.as_str())
                        .collect::<Vec<_>>()
                        .join(", ")
                ));
            };
            if self.takes.contains_key(id) {
                return Err(format!(
                    "takes.\"{id}\": also given by {}; expected the take's split and masses from one source (drop the [takes] entry or --manifest)",
                    description.path.display()
                ));
            }
            let (split, failure) = match take.role {
                TakeRole::Train => (Split::Train, false),
                TakeRole::Test => (Split::Test, false),
                TakeRole::Failure => (Split::Excluded, true),
            };
            self.takes.insert(
                id.clone(),
                TakeConfig {
                    split: Some(split),
                    exclude: None,
                    failure: Some(failure),
                    object_total_mass_kg: Some(take.object_mass_kg),
                    mass: description.mass_class(take.object_mass_lb),
                    mass_lb: Some(take.object_mass_lb),
                    velocity: Some(take.speed.clone()),
                    orientation: Some(format!("{}", take.placement_angle_deg)),
                },
            );
        }
        Ok(())
    }

    /// The manifest fields of take `id`: its `[takes]` entry, completed by `[default_take]`. An
    /// unlisted take without a `[default_take]`, or a needed field that neither gives, is an error
    /// naming the key.
    pub fn take(&self, id: &str) -> Result<TakeSettings, String> {
        let empty = TakeConfig::default();
        let default = self.default_take.as_ref().unwrap_or(&empty);
        let (own, key) = match self.takes.get(id) {
            Some(own) => (own, format!("takes.\"{id}\"")),
            None if self.default_take.is_some() => (&empty, "default_take".to_string()),
            None => {
                return Err(format!(
                    "take \"{id}\" is not listed in [takes] and there is no [default_take]; expected a [takes.\"{id}\"] entry with split and object_total_mass_kg, or a [default_take] for unlisted takes"
                ))
            }
        };
        let exclude = own.exclude.or(default.exclude).unwrap_or(false);
        // For a listed take, say that [default_take] did not help either.
        let fallback = if key == "default_take" {
            ""
        } else {
            " (and [default_take] gives none)"
        };
        let failure = own.failure.or(default.failure).unwrap_or(false);
        let split = match own.split.or(default.split) {
            Some(Split::Train | Split::Test) if failure => {
                return Err(format!(
                    "{key}: a failure take (failure = true) stays out of train and test; expected no split or split = \"excluded\""
                ))
            }
            Some(split) => split,
            None if failure => Split::Excluded,
            None if exclude => Split::Train,
            None => {
                return Err(format!(
                    "{key}.split is missing{fallback}; expected \"train\", \"test\" or \"excluded\""
                ))
            }
        };
        let object_total_mass_kg = own
            .object_total_mass_kg
            .or(default.object_total_mass_kg)
            .ok_or_else(|| {
                format!(
                    "{key}.object_total_mass_kg is missing{fallback}; expected the object's mass with its added weight in kg"
                )
            })?;
        Ok(TakeSettings {
            split,
            exclude,
            failure,
            object_total_mass_kg,
            mass: own.mass.clone().or_else(|| default.mass.clone()),
            mass_lb: own.mass_lb.or(default.mass_lb),
            velocity: own.velocity.clone().or_else(|| default.velocity.clone()),
            orientation: own
                .orientation
                .clone()
                .or_else(|| default.orientation.clone()),
        })
    }
}

/// What was kept of one take.
#[derive(Debug, Clone, Serialize)]
pub struct RetentionReport {
    /// Take id.
    pub id: String,
    /// The take's export frame rate (Hz), used for every filter.
    pub sample_rate_hz: f64,
    /// Frames in the take.
    pub frames_total: usize,
    /// Frames written (after trimming and dropping frames without both rigid bodies).
    pub frames_kept: usize,
    /// Marker counts over the frames written.
    pub markers: MarkerRetention,
    /// Marker ids (columns) in the take.
    pub input_ids: usize,
    /// Ids attached to an earlier marker by re-identification.
    pub reidentified_ids: usize,
    /// Median and largest distance (m) of a re-identified id to its predicted position.
    pub reid_distance_m: (f64, f64),
    /// Candidate joins refused because the new id lies on the other film sheet, or the sheet of
    /// either cannot be told.
    pub refused_across_sheets: usize,
    /// Physical marker tracks kept.
    pub tracks_kept: usize,
    /// Tracks dropped as too short-lived (spurious reflections).
    pub short_tracks_dropped: usize,
    /// Fewest / most markers in a written frame.
    pub markers_per_frame: (usize, usize),
    /// Marker samples in runs too short for the low-pass (written unfiltered).
    pub unfiltered_samples: usize,
    /// Where the tool track came from when a robot file was given.
    pub robot: Option<RobotFit>,
    /// Written to the dataset (false for takes excluded in the config).
    pub written: bool,
    /// A failure take (written with split `excluded`).
    pub failure: bool,
}

/// The robot-to-mocap transform used for a take imported with its robot file.
#[derive(Debug, Clone, Serialize)]
pub struct RobotFit {
    /// The robot file.
    pub path: PathBuf,
    /// Estimated from the Motive tool body (true) or given in the config (false).
    pub estimated: bool,
    /// RMS distance (m) between the transformed command and the Motive tool body.
    pub rms_m: f64,
    /// Rotation from robot to mocap axes (x, y, z, w).
    pub rotation_xyzw: [f64; 4],
    /// Translation (m).
    pub translation_m: [f64; 3],
}

impl fmt::Display for RetentionReport {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let m = &self.markers;
        writeln!(
            f,
            "{}: frames kept {} of {} ({:.1} %) at {} Hz{}",
            self.id,
            self.frames_kept,
            self.frames_total,
            percent(self.frames_kept, self.frames_total),
            self.sample_rate_hz,
            match (self.written, self.failure) {
                (false, _) => " [excluded by config, not written]",
                (true, true) =>
                    " [failure take: written with split \"excluded\", out of train and test]",
                (true, false) => "",
            }
        )?;
        writeln!(
            f,
            "  marker samples kept {} of {} ({:.1} %); spurious dropped {}; filled: {} by velocity, {} interpolated; unrecovered gap samples {}; written {} ({:.1} % of raw)",
            m.observed_kept,
            m.raw_samples,
            m.kept_percent(),
            m.spurious_samples,
            m.velocity_filled,
            m.interpolated,
            m.unrecovered,
            m.observed_kept + m.velocity_filled + m.interpolated,
            m.output_percent()
        )?;
        write!(
            f,
            "  marker ids {} -> {} tracks ({} re-identified, distance to prediction median {:.1} mm, max {:.1} mm; {} candidate joins refused as on the other sheet or of unknown sheet; {} short-lived dropped); markers per frame {}..{}; {} samples too short to filter",
            self.input_ids,
            self.tracks_kept,
            self.reidentified_ids,
            1e3 * self.reid_distance_m.0,
            1e3 * self.reid_distance_m.1,
            self.refused_across_sheets,
            self.short_tracks_dropped,
            self.markers_per_frame.0,
            self.markers_per_frame.1,
            self.unfiltered_samples
        )?;
        if let Some(fit) = &self.robot {
            let q = fit.rotation_xyzw;
            let p = fit.translation_m;
            write!(
                f,
                "\n  tool track from {} ({} transform: rotation_xyzw = [{:.6}, {:.6}, {:.6}, {:.6}], translation_m = [{:.4}, {:.4}, {:.4}]); RMS distance to the Motive tool body {:.2} mm",
                fit.path.display(),
                if fit.estimated { "estimated" } else { "given" },
                q[0], q[1], q[2], q[3], p[0], p[1], p[2],
                1e3 * fit.rms_m
            )?;
        }
        Ok(())
    }
}

/// One converted take.
#[derive(Debug, Clone)]
pub struct ImportedTake {
    /// The trajectory, ready for [`Trajectory::save`].
    pub trajectory: Trajectory,
    /// Its manifest entry.
    pub entry: ManifestEntry,
    /// What was kept.
    pub report: RetentionReport,
    /// False if the config excludes this take from the dataset.
    pub include: bool,
}

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

/// A rigid body after gap bridging and filtering.
struct Pose {
    position: Series,
    rotation: Vec<Option<[f64; 4]>>,
}

/// Cleans and converts a parsed take into trajectory `id`.
pub fn convert(
    take: &MotiveTake,
    id: &str,
    config: &ImportConfig,
) -> Result<ImportedTake, ImportError> {
    convert_with_robot(take, id, config, None)
}

/// Cleans and converts a parsed take into trajectory `id`; with `robot`, the tool track is the
/// robot's command carried into the mocap frame by the `[robot]` transform (given, or estimated
/// from the Motive tool rigid body), on the frames the robot file covers.
pub fn convert_with_robot(
    take: &MotiveTake,
    id: &str,
    config: &ImportConfig,
    robot: Option<&RobotTrajectory>,
) -> Result<ImportedTake, ImportError> {
    let take_err = |message: String| ImportError::Take {
        path: take.path.clone(),
        message,
    };
    let clean_err = |e: CleanError| take_err(e.to_string());
    let conversion = &config.conversion;
    let cleaning = &config.cleaning;
    let rate = take.header.export_frame_rate_hz;
    let n = take.len();
    let settings = config.take(id).map_err(take_err)?;

    let tool_index = find_body(take, &conversion.tool_body, 0, "tool").map_err(take_err)?;
    let object_index = find_body(take, &conversion.object_body, 1, "object").map_err(take_err)?;
    if tool_index == object_index {
        return Err(take_err(format!(
            "tool and object are the same rigid body '{}'; expected two different bodies",
            take.rigid_bodies[tool_index].name
        )));
    }
    let max_gap = (conversion.max_rigid_body_gap_s * rate).round() as usize;
    let rigid_filter = (cleaning.rigid_body_cutoff_hz > 0.0)
        .then(|| Butterworth::low_pass(cleaning.filter_order, cleaning.rigid_body_cutoff_hz, rate))
        .transpose()
        .map_err(clean_err)?;
    for &index in &[tool_index, object_index] {
        let body = &take.rigid_bodies[index];
        if let Some(k) = body
            .rotation
            .iter()
            .position(|q| q.is_some_and(|q| DQuat::from_array(q).length_squared() < 0.25))
        {
            return Err(take_err(format!(
                "rigid body '{}' has a rotation quaternion of near-zero length at frame {k} (line {}); expected a unit quaternion",
                body.name,
                k + 8
            )));
        }
    }
    let tool = clean_rigid_body(
        take,
        tool_index,
        max_gap,
        cleaning.velocity_window,
        rigid_filter.as_ref(),
    );
    let object = clean_rigid_body(
        take,
        object_index,
        max_gap,
        cleaning.velocity_window,
        rigid_filter.as_ref(),
    );

    // The usable frames: the longest run where both bodies have a pose.
    let both: Vec<Option<()>> = (0..n)
        .map(|k| {
            (tool.position[k].is_some()
                && tool.rotation[k].is_some()
                && object.position[k].is_some())
            .then_some(())
        })
        .collect();
    let (mut start, mut end) = clean::runs(&both)
        .into_iter()
        .max_by_key(|&(s, e)| (e - s, std::cmp::Reverse(s)))
        .ok_or_else(|| {
            take_err("the tool and object rigid bodies are never both tracked".into())
        })?;

    if let Some(robot) = robot {
        let robot_err = |what: &str| {
            take_err(format!(
                "robot file {} (times {} to {} s) {what}; expected the robot times on the take's clock (its frames {} to {} s)",
                robot.path.display(),
                robot.t[0],
                robot.t[robot.t.len() - 1],
                take.time[0],
                take.time[n - 1]
            ))
        };
        let (first, last) = covered_frames(robot, &take.time)
            .ok_or_else(|| robot_err("covers none of the take's frames"))?;
        if first >= end || last <= start {
            return Err(robot_err(
                "covers none of the frames where both rigid bodies are tracked",
            ));
        }
        start = start.max(first);
        end = end.min(last);
    }

    // Motive also exports the labelled markers of a rigid body as `Marker` columns named
    // `<body>:<marker>`; they belong to the tool or object, not to the package.
    let body_prefixes: Vec<String> = take
        .rigid_bodies
        .iter()
        .map(|b| format!("{}:", b.name))
        .collect();
    let fragments: Vec<Series> = take
        .markers
        .iter()
        .filter(|m| {
            !body_prefixes
                .iter()
                .any(|prefix| m.name.starts_with(prefix.as_str()))
        })
        .filter(|m| match conversion.markers {
            MarkerSource::Unlabeled => m.kind == MarkerKind::Unlabeled,
            MarkerSource::Labeled => m.kind == MarkerKind::Labeled,
            MarkerSource::All => m.kind != MarkerKind::RigidBodyMarker,
        })
        .map(|m| m.position.clone())
        .collect();
    if fragments.is_empty() {
        let wanted = match conversion.markers {
            MarkerSource::Unlabeled => "unlabeled",
            MarkerSource::Labeled => "labeled",
            MarkerSource::All => "labeled or unlabeled",
        };
        return Err(take_err(format!(
            "no {wanted} marker columns (conversion.markers); expected the package markers"
        )));
    }
    let cleaned = clean::clean_markers(&fragments, rate, cleaning).map_err(clean_err)?;

    let t_all = &take.time;
    let tool_position: Vec<[f64; 3]> = (start..end).map(|k| tool.position[k].unwrap()).collect();
    if conversion.trim_to_motion {
        let velocity = gradient(&tool_position, &t_all[start..end]);
        let moving: Vec<usize> = (0..velocity.len())
            .filter(|&k| {
                DVec3::from_array(velocity[k]).length() > conversion.motion_speed_threshold_m_s
            })
            .collect();
        if let (Some(&first), Some(&last)) = (moving.first(), moving.last()) {
            let margin = (conversion.motion_margin_s * rate).round() as usize;
            let new_start = start + first.saturating_sub(margin);
            end = (start + last + 1 + margin).min(end);
            start = new_start;
        }
    }
    if end - start < 2 {
        return Err(take_err(format!(
            "only {} usable frame(s); expected at least 2",
            end - start
        )));
    }

    let t: Vec<f64> = t_all[start..end].iter().map(|x| x - t_all[start]).collect();
    let tool_position: Vec<[f64; 3]> = (start..end).map(|k| tool.position[k].unwrap()).collect();
    let tool_rotation: Vec<[f64; 4]> = (start..end).map(|k| tool.rotation[k].unwrap()).collect();
    let object_position: Vec<[f64; 3]> =
        (start..end).map(|k| object.position[k].unwrap()).collect();
    let object_velocity = gradient(&object_position, &t);
    let (tool_track, robot_fit) = match robot {
        None => {
            let tool_velocity = gradient(&tool_position, &t);
            let angular_velocity = angular_velocity(&tool_rotation, &t);
            let track = ToolTrack {
                acceleration: gradient(&tool_velocity, &t),
                angular_acceleration: gradient(&angular_velocity, &t),
                t: t.clone(),
                position: tool_position,
                orientation: tool_rotation,
                velocity: tool_velocity,
                angular_velocity,
            };
            (track, None)
        }
        Some(robot) => {
            let times = &t_all[start..end];
            let commanded = robot::positions_at(robot, times);
            let body: Vec<Vector3<f64>> = tool_position.iter().map(|&p| p.into()).collect();
            let (transform, estimated) = match config.robot.given() {
                Some(given) => (given, false),
                None => {
                    let fitted = RigidTransform::fit(&commanded, &body).ok_or_else(|| {
                        take_err(format!(
                            "robot file {}: the tool path over the imported frames is (nearly) a straight line, so the robot-to-mocap rotation cannot be estimated; expected [robot] rotation_xyzw and translation_m in the config",
                            robot.path.display()
                        ))
                    })?;
                    (fitted, true)
                }
            };
            let rms_m = transform.rms_error(&commanded, &body);
            if rms_m > config.robot.max_fit_rms_m {
                return Err(take_err(format!(
                    "robot file {}: the {} transform puts the commanded tool point {:.1} mm (RMS) from the Motive tool rigid body, more than robot.max_fit_rms_m = {} m; expected the robot file of this take, with the tool point at the body's pivot",
                    robot.path.display(),
                    if estimated { "best-fitting" } else { "given" },
                    1e3 * rms_m,
                    config.robot.max_fit_rms_m
                )));
            }
            let fit = RobotFit {
                path: robot.path.clone(),
                estimated,
                rms_m,
                rotation_xyzw: {
                    let q = transform.rotation;
                    [q.i, q.j, q.k, q.w]
                },
                translation_m: transform.translation.into(),
            };
            (robot::tool_track(robot, times, &transform), Some(fit))
        }
    };
    let object_track = ObjectTrack {
        acceleration: gradient(&object_velocity, &t),
        t: t.clone(),
        position: object_position,
        velocity: object_velocity,
    };
    let frames: Vec<Vec<[f64; 3]>> = (start..end).map(|k| cleaned.frame(k)).collect();
    let initial_markers = frames[0].clone();
    if initial_markers.len() < 3 {
        return Err(take_err(format!(
            "only {} package marker(s) in the first kept frame (t = {} s); expected at least 3 to place the package",
            initial_markers.len(),
            t_all[start]
        )));
    }
    // Markers on another scale than the package (a take exported in metres but labelled
    // millimetres, or the reverse) would convert without a word into a package 1000x off.
    let spread = initial_markers
        .iter()
        .flat_map(|a| {
            initial_markers
                .iter()
                .map(move |b| DVec3::from_array(*a).distance(DVec3::from_array(*b)))
        })
        .fold(0.0, f64::max);
    let diagonal = config.package.size_m[0].hypot(config.package.size_m[1]);
    if !(diagonal / 10.0..=diagonal * 3.0).contains(&spread) {
        return Err(take_err(format!(
            "the package markers of the first kept frame span {spread:.4} m, the package's diagonal \
             (package.size_m) is {diagonal:.3} m; expected the same scale (check the take's 'Length Units')"
        )));
    }
    let counts: Vec<usize> = frames.iter().map(Vec::len).collect();
    let markers_per_frame = (*counts.iter().min().unwrap(), *counts.iter().max().unwrap());

    let object_total_mass_kg = settings.object_total_mass_kg;
    let cup = DQuat::from_array(tool_track.orientation[0])
        .mul_vec3(DVec3::from_array(conversion.tool_to_cup_m))
        .to_array();
    let meta = Meta {
        id: id.to_string(),
        package_size_m: config.package.size_m,
        package_mass_kg: config.package.mass_kg,
        object_diameter_m: config.package.object_diameter_m,
        object_body_mass_kg: config.package.object_body_mass_kg,
        object_total_mass_kg,
        total_mass_kg: config.package.mass_kg + object_total_mass_kg,
        initial_suction_cup_position_m: std::array::from_fn(|i| tool_track.position[0][i] + cup[i]),
        initial_marker_positions_m: initial_markers,
        marker_inset_m: config.package.marker_inset_m,
        initial_lower_marker_positions_m: config.package.lower_marker_positions_m.clone(),
    };
    let entry = ManifestEntry {
        id: id.to_string(),
        split: settings.split,
        mass: settings.mass,
        mass_lb: settings.mass_lb,
        velocity: settings.velocity,
        orientation: settings.orientation,
        frames: t.len(),
        duration_s: *t.last().unwrap(),
        object_total_mass_kg,
        markers_per_frame_min: Some(markers_per_frame.0),
        markers_per_frame_max: Some(markers_per_frame.1),
        marker_rows: Some(counts.iter().sum()),
        failure: settings.failure,
    };
    let include = !settings.exclude;
    let report = RetentionReport {
        id: id.to_string(),
        sample_rate_hz: rate,
        frames_total: n,
        frames_kept: t.len(),
        markers: cleaned.retention(start, end),
        input_ids: cleaned.input_ids,
        reidentified_ids: cleaned.reidentified_ids,
        reid_distance_m: median_and_max(&cleaned.reid_distances_m),
        refused_across_sheets: cleaned.refused_across_sheets,
        tracks_kept: cleaned
            .tracks
            .iter()
            .filter(|tr| tr[start..end].iter().any(Option::is_some))
            .count(),
        short_tracks_dropped: cleaned.short_tracks_dropped,
        markers_per_frame,
        unfiltered_samples: cleaned.unfiltered_samples,
        robot: robot_fit,
        written: include,
        failure: settings.failure,
    };
    let trajectory = Trajectory {
        id: id.to_string(),
        meta,
        tool: tool_track,
        object: object_track,
        markers: MarkerFrames::from_labelled_frames(
            t,
            (start..end).map(|k| cleaned.labelled_frame(k)).collect(),
        ),
    };
    Ok(ImportedTake {
        trajectory,
        entry,
        report,
        include,
    })
}

/// Median and maximum of `values` (zeros when empty).
fn median_and_max(values: &[f64]) -> (f64, f64) {
    let mut sorted = values.to_vec();
    sorted.sort_by(f64::total_cmp);
    match sorted.len() {
        0 => (0.0, 0.0),
        n => (sorted[n / 2], sorted[n - 1]),
    }
}

/// Index of the rigid body called `name`, or the `default_index`-th one if `name` is empty.
fn find_body(
    take: &MotiveTake,
    name: &str,
    default_index: usize,
    role: &str,
) -> Result<usize, String> {
    let names: Vec<&str> = take.rigid_bodies.iter().map(|b| b.name.as_str()).collect();
    if name.is_empty() {
        if default_index < names.len() {
            Ok(default_index)
        } else {
            Err(format!(
                "the {role} is rigid body number {} but the take has {} ({names:?}); expected a tool and an object rigid body",
                default_index + 1,
                names.len()
            ))
        }
    } else {
        names
            .iter()
            .position(|n| *n == name)
            .ok_or_else(|| format!("no rigid body named '{name}' for the {role} (conversion.{role}_body); the take has {names:?}"))
    }
}

/// Bridges short dropouts of a rigid body (position by [`clean::fill_gaps`], orientation by
/// normalised linear interpolation) and low-pass filters position and orientation.
fn clean_rigid_body(
    take: &MotiveTake,
    index: usize,
    max_gap: usize,
    window: usize,
    filter: Option<&Butterworth>,
) -> Pose {
    let body = &take.rigid_bodies[index];
    let mut position = body.position.clone();
    clean::fill_gaps(&mut position, max_gap, max_gap, window, None);
    // Quaternions q and -q are the same rotation: make the series continuous before touching it.
    let mut rotation = body.rotation.clone();
    let mut previous: Option<DQuat> = None;
    for q in rotation.iter_mut().flatten() {
        if previous.is_some_and(|p| p.dot(DQuat::from_array(*q)) < 0.0) {
            *q = q.map(|v| -v);
        }
        previous = Some(DQuat::from_array(*q));
    }
    let spans = clean::runs(&rotation);
    for pair in spans.windows(2) {
        let (a, b) = (pair[0].1 - 1, pair[1].0);
        if b - a - 1 <= max_gap {
            let qa = DQuat::from_array(rotation[a].unwrap());
            let qb = DQuat::from_array(rotation[b].unwrap());
            for (offset, slot) in rotation[a + 1..b].iter_mut().enumerate() {
                // Normalised linear interpolation (the series is continuous, so no sign flip).
                let s = (offset + 1) as f64 / (b - a) as f64;
                *slot = Some(qa.lerp(qb, s).to_array());
            }
        }
    }
    if let Some(filter) = filter {
        filter.filter_series(&mut position);
        for (s, e) in clean::runs(&rotation) {
            for axis in 0..4 {
                let values: Vec<f64> = rotation[s..e].iter().map(|q| q.unwrap()[axis]).collect();
                if let Some(filtered) = filter.filtfilt(&values) {
                    for (k, v) in filtered.into_iter().enumerate() {
                        if let Some(q) = rotation[s + k].as_mut() {
                            q[axis] = v;
                        }
                    }
                }
            }
        }
    }
    for q in rotation.iter_mut().flatten() {
        *q = DQuat::from_array(*q).normalize().to_array();
    }
    Pose { position, rotation }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn fixture(name: &str) -> PathBuf {
        Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("tests/fixtures")
            .join(name)
    }

    const DEFAULT_TAKE: &str = "[default_take]\nsplit = \"train\"\nobject_total_mass_kg = 0.2268\n";

    /// The built-in settings with a `[default_take]` (train, 0.2268 kg), so any take imports.
    fn with_default_take() -> ImportConfig {
        ImportConfig {
            default_take: Some(TakeConfig {
                split: Some(Split::Train),
                object_total_mass_kg: Some(0.2268),
                ..TakeConfig::default()
            }),
            ..ImportConfig::default()
        }
    }

    #[test]
    fn takes_need_their_split_and_mass_from_the_config() {
        let take = motive::parse_take(&labelled_take(), Path::new("lab.csv")).unwrap();
        let mut config = ImportConfig {
            conversion: ConversionConfig {
                markers: MarkerSource::Labeled,
                ..ConversionConfig::default()
            },
            ..ImportConfig::default()
        };
        let msg = convert(&take, "lab", &config).unwrap_err().to_string();
        assert!(
            msg.contains(
                "lab.csv: take \"lab\" is not listed in [takes] and there is no [default_take]"
            ),
            "{msg}"
        );
        config.takes.insert(
            "lab".into(),
            TakeConfig {
                object_total_mass_kg: Some(0.3),
                ..TakeConfig::default()
            },
        );
        let msg = config.validate().unwrap_err();
        assert!(msg.contains("takes.\"lab\".split is missing"), "{msg}");
        // [default_take] completes what the take leaves out; the take's own values win.
        config.default_take = Some(TakeConfig {
            split: Some(Split::Test),
            object_total_mass_kg: Some(0.5),
            ..TakeConfig::default()
        });
        config.validate().unwrap();
        let imported = convert(&take, "lab", &config).unwrap();
        assert_eq!(imported.entry.split, Split::Test);
        assert_eq!(imported.entry.object_total_mass_kg, 0.3);
        assert_eq!(config.take("other").unwrap().object_total_mass_kg, 0.5);
        // An excluded take needs no split.
        config.default_take = None;
        config.takes.get_mut("lab").unwrap().exclude = Some(true);
        assert!(config.take("lab").unwrap().exclude);
    }

    fn shipped_config() -> PathBuf {
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../configs/import/motive.toml")
    }

    /// Non-empty marker triples in the data rows, counted straight from the file's text.
    fn raw_marker_samples(path: &Path) -> usize {
        let take = motive::read_take(path).unwrap();
        let text = {
            use std::io::Read;
            let mut s = String::new();
            flate2::read::GzDecoder::new(std::fs::File::open(path).unwrap())
                .read_to_string(&mut s)
                .unwrap();
            s
        };
        let first_marker_column = 2 + 8 * take.rigid_bodies.len();
        text.lines()
            .skip(7)
            .map(|line| {
                let cells: Vec<&str> = line.split(',').collect();
                cells[first_marker_column..]
                    .chunks(3)
                    .filter(|c| !c[0].is_empty())
                    .count()
            })
            .sum()
    }

    #[test]
    fn the_shipped_config_spells_out_the_defaults() {
        let config = ImportConfig::load(&shipped_config()).unwrap();
        let defaults = with_default_take();
        assert_eq!(config.cleaning, defaults.cleaning);
        assert_eq!(config.conversion, defaults.conversion);
        assert_eq!(config.package, defaults.package);
        assert_eq!(config.robot, defaults.robot);
        assert_eq!(config.takes.len(), 27);
        assert_eq!(
            config
                .takes
                .values()
                .filter(|t| t.split == Some(Split::Test) && t.exclude != Some(true))
                .count(),
            4
        );
    }

    #[test]
    fn the_excerpt_imports_with_known_values() {
        let path = fixture("a30_m0.5_high_excerpt.csv.gz");
        let mut config = ImportConfig::load(&shipped_config()).unwrap();
        config.takes.insert(
            "a30_m0.5_high_excerpt".into(),
            config.takes["a30_m0.5_high"].clone(),
        );
        let imported = import_take(&path, &config).unwrap();
        let (trajectory, report) = (&imported.trajectory, &imported.report);
        assert_eq!(trajectory.id, "a30_m0.5_high_excerpt");
        assert_eq!((report.frames_total, report.frames_kept), (250, 250));
        assert_eq!(report.sample_rate_hz, 250.0);
        assert_eq!(trajectory.tool.t.len(), 250);
        assert!((trajectory.tool.t[249] - 0.996).abs() < 1e-9);
        // Frame 0, `Unlabeled 1000` = (-0.532215, 0.016989, 0.256647) m in the file; the low-pass
        // moves it by a fraction of the 0.3 mm noise.
        let known = [-0.532215, 0.016989, 0.256647];
        let nearest = trajectory
            .meta
            .initial_marker_positions_m
            .iter()
            .map(|p| dist(*p, known))
            .fold(f64::MAX, f64::min);
        assert!(nearest < 1e-3, "nearest initial marker is {nearest} m away");
        // Tool pivot at frame 0 = (-0.399960, 0.033121, 0.150052); the cup 5 mm below it.
        let tool0 = trajectory.tool.position[0];
        assert!(
            dist(tool0, [-0.399960, 0.033121, 0.150052]) < 5e-4,
            "{tool0:?}"
        );
        let cup = trajectory.meta.initial_suction_cup_position_m;
        assert!(
            dist(cup, [tool0[0], tool0[1] - 0.005, tool0[2]]) < 1e-4,
            "{cup:?}"
        );
        assert_eq!(trajectory.meta.object_total_mass_kg, 0.2268);
        // Retention: every raw sample is either kept or dropped as spurious; nearly all are kept.
        let m = report.markers;
        assert_eq!(m.raw_samples, raw_marker_samples(&path));
        assert_eq!(m.observed_kept + m.spurious_samples, m.raw_samples);
        assert!(m.kept_percent() > 97.0, "{report}");
        // 20 top markers are visible from the start; re-identification joins their ids again.
        assert!(report.reidentified_ids > 0);
        assert!(report.tracks_kept < report.input_ids);
        assert!((20..=45).contains(&report.tracks_kept), "{report}");
        assert!(report.markers_per_frame.0 >= 15, "{report}");
        assert_eq!(imported.entry.frames, 250);
        assert!(imported.include);
    }

    #[test]
    fn millimetre_and_metre_exports_give_the_same_trajectory() {
        let config = with_default_take();
        let m = import_take(&fixture("a30_m0.5_high_excerpt.csv.gz"), &config)
            .unwrap()
            .trajectory;
        let mm = import_take(&fixture("a30_m0.5_high_excerpt_mm.csv.gz"), &config)
            .unwrap()
            .trajectory;
        for k in [0, 100, 249] {
            assert!(dist(m.tool.position[k], mm.tool.position[k]) < 1e-9);
            assert!(dist(m.object.position[k], mm.object.position[k]) < 1e-9);
            assert_eq!(m.markers.frame(k).len(), mm.markers.frame(k).len());
            for (a, b) in m.markers.frame(k).iter().zip(mm.markers.frame(k)) {
                assert!(dist(*a, *b) < 1e-9);
            }
        }
    }

    #[test]
    fn markers_on_another_scale_than_the_package_are_refused() {
        // The same take against a package a tenth of its size: as if its units were mislabelled.
        let mut config = with_default_take();
        config.package.size_m = [0.0254, 0.03048];
        let err = import_take(&fixture("a30_m0.5_high_excerpt.csv.gz"), &config)
            .err()
            .unwrap()
            .to_string();
        assert!(err.contains("a30_m0.5_high_excerpt.csv.gz"), "{err}");
        assert!(err.contains("expected the same scale"), "{err}");
        assert!(err.contains("'Length Units'"), "{err}");
    }

    #[test]
    fn trimming_to_motion_drops_the_settle_phase() {
        // packages-v1: the tool is still for the first 0.3 s (75 frames), then lifts.
        let mut config = with_default_take();
        config.conversion.trim_to_motion = true;
        let imported = import_take(&fixture("a30_m0.5_high_excerpt.csv.gz"), &config).unwrap();
        let kept = imported.report.frames_kept;
        assert!((100..=175).contains(&kept), "kept {kept} frames");
        assert_eq!(imported.trajectory.tool.t[0], 0.0);
    }

    #[test]
    fn config_errors_name_file_key_and_range() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("import.toml");
        std::fs::write(&path, "[cleaning]\nfilter_order = 4\nbogus = 1\n").unwrap();
        let msg = ImportConfig::load(&path).unwrap_err().to_string();
        assert!(
            msg.contains("import.toml: line 3") && msg.contains("bogus"),
            "{msg}"
        );
        std::fs::write(&path, "[cleaning]\nmarker_cutoff_hz = -2.0\n").unwrap();
        let msg = ImportConfig::load(&path).unwrap_err().to_string();
        assert!(
            msg.contains("cleaning.marker_cutoff_hz = -2: expected a number >= 0"),
            "{msg}"
        );
        std::fs::write(&path, "[package]\nmarker_inset_m = [0.02, 0.2]\n").unwrap();
        let msg = ImportConfig::load(&path).unwrap_err().to_string();
        assert!(
            msg.contains(
                "package.marker_inset_m = [0.02, 0.2]: expected 2 numbers in [0, 0.127) m"
            ),
            "{msg}"
        );
        std::fs::write(
            &path,
            format!("[conversion]\ntool_body = \"Gripper\"\n{DEFAULT_TAKE}"),
        )
        .unwrap();
        let config = ImportConfig::load(&path).unwrap();
        let msg = import_take(&fixture("a30_m0.5_high_excerpt.csv.gz"), &config)
            .unwrap_err()
            .to_string();
        assert!(
            msg.contains("no rigid body named 'Gripper'") && msg.contains("[\"Tool\", \"Object\"]"),
            "{msg}"
        );
        // A cut-off above the Nyquist frequency of the take is caught when the take's rate is known.
        std::fs::write(
            &path,
            format!("[cleaning]\nmarker_cutoff_hz = 200.0\n{DEFAULT_TAKE}"),
        )
        .unwrap();
        let config = ImportConfig::load(&path).unwrap();
        let msg = import_take(&fixture("a30_m0.5_high_excerpt.csv.gz"), &config)
            .unwrap_err()
            .to_string();
        assert!(
            msg.contains("a30_m0.5_high_excerpt.csv.gz") && msg.contains("(0, 125) Hz"),
            "{msg}"
        );
    }

    /// A synthetic millimetre take: tool and object at rest, three labelled package markers and
    /// one labelled tool marker, 60 frames at 100 Hz.
    fn labelled_take() -> String {
        let mut text = String::from(
            "Format Version,1.23,Take Name,lab,Capture Frame Rate,100,Export Frame Rate,100,Rotation Type,Quaternion,Length Units,Millimeters\n\n",
        );
        let bodies = ["Tool", "Object"];
        let markers = ["Pkg:A", "Pkg:B", "Pkg:C", "Tool:Marker1"];
        let mut rows = [
            vec![",Type".to_string()],
            vec![",Name".into()],
            vec![",ID".into()],
            vec![",".into()],
            vec!["Frame,Time (Seconds)".into()],
        ];
        for (i, body) in bodies.iter().enumerate() {
            for (property, axis) in [
                ("Rotation", "X"),
                ("Rotation", "Y"),
                ("Rotation", "Z"),
                ("Rotation", "W"),
                ("Position", "X"),
                ("Position", "Y"),
                ("Position", "Z"),
            ] {
                for (row, cell) in
                    rows.iter_mut()
                        .zip(["Rigid Body", body, &(i + 1).to_string(), property, axis])
                {
                    row.push(cell.to_string());
                }
            }
        }
        for (i, marker) in markers.iter().enumerate() {
            for axis in ["X", "Y", "Z"] {
                for (row, cell) in
                    rows.iter_mut()
                        .zip(["Marker", marker, &(10 + i).to_string(), "Position", axis])
                {
                    row.push(cell.to_string());
                }
            }
        }
        for row in rows {
            text += &(row.join(",") + "\n");
        }
        for k in 0..60 {
            let mut cells = vec![k.to_string(), format!("{:.2}", k as f64 / 100.0)];
            cells.extend(["0", "0", "0", "1", "100", "200", "300"].map(String::from));
            cells.extend(["0", "0", "0", "1", "100", "150", "300"].map(String::from));
            for (i, _) in markers.iter().enumerate() {
                cells.extend([format!("{}", 50 * i), "180".into(), format!("{}", 300 + k)]);
            }
            text += &(cells.join(",") + "\n");
        }
        text
    }

    #[test]
    fn labelled_package_markers_exclude_the_rigid_bodies_own_markers() {
        let take = motive::parse_take(&labelled_take(), Path::new("lab.csv")).unwrap();
        let mut config = with_default_take();
        config.conversion.markers = MarkerSource::Labeled;
        let imported = convert(&take, "lab", &config).unwrap();
        let initial = &imported.trajectory.meta.initial_marker_positions_m;
        assert_eq!(initial.len(), 3);
        assert!((initial[2][0] - 0.1).abs() < 1e-9 && (initial[2][1] - 0.18).abs() < 1e-9);
        // Only the package's columns count; the tool's own marker is not a package marker.
        assert_eq!(imported.report.markers.raw_samples, 3 * 60);
        assert_eq!(imported.report.tracks_kept, 3);
        config.conversion.markers = MarkerSource::Unlabeled;
        let msg = convert(&take, "lab", &config).unwrap_err().to_string();
        assert!(
            msg.contains("lab.csv: no unlabeled marker columns"),
            "{msg}"
        );
    }

    #[test]
    fn the_robot_transform_is_estimated_from_the_tool_body() {
        // The tool of the synthetic take moves on a helix; the robot file holds the same motion
        // in a robot frame with z up, shifted by (0.4, 0.15, 0) (packages-v1's frames).
        let mut take = motive::parse_take(&labelled_take(), Path::new("lab.csv")).unwrap();
        let helix = |k: usize| {
            let a = k as f64 / 59.0 * std::f64::consts::TAU;
            [0.1 * a.cos(), 0.05 * k as f64 / 59.0, 0.1 * a.sin()]
        };
        for (k, p) in take.rigid_bodies[0].position.iter_mut().enumerate() {
            *p = Some(helix(k));
        }
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("lab_robot.csv");
        let mut text = crate::robot::ROBOT_HEADER.join(",") + "\n";
        for (k, t) in take.time.iter().enumerate() {
            let p = helix(k);
            // p_robot = R^T p_mocap + o, with R taking robot z (up) to mocap y.
            let robot = [p[0] + 0.4, -p[2] + 0.15, p[1]];
            text += &format!(
                "{t},{},{},{},0,0,0,1,0,0,0,0,0,0,0,0,0\n",
                robot[0], robot[1], robot[2]
            );
        }
        std::fs::write(&path, text).unwrap();
        let robot = read_robot(&path).unwrap();
        let mut config = with_default_take();
        config.conversion.markers = MarkerSource::Labeled;
        config.cleaning.rigid_body_cutoff_hz = 0.0;
        let imported = convert_with_robot(&take, "lab", &config, Some(&robot)).unwrap();
        let fit = imported.report.robot.clone().expect("a robot fit");
        assert!(fit.estimated && fit.rms_m < 1e-9, "{fit:?}");
        let half = std::f64::consts::FRAC_1_SQRT_2;
        let expected = [-half, 0.0, 0.0, half];
        let sign = fit.rotation_xyzw[3].signum();
        for (got, want) in fit.rotation_xyzw.iter().zip(expected) {
            assert!((sign * got - want).abs() < 1e-9, "{fit:?}");
        }
        for (i, t) in [-0.4, 0.0, 0.15].into_iter().enumerate() {
            assert!((fit.translation_m[i] - t).abs() < 1e-9, "{fit:?}");
        }
        let tool = &imported.trajectory.tool;
        for k in [0, 30, 59] {
            assert!(dist(tool.position[k], helix(k)) < 1e-9);
        }
        assert!(imported.report.to_string().contains("estimated transform"));
    }

    fn dist(a: [f64; 3], b: [f64; 3]) -> f64 {
        ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
    }
}
