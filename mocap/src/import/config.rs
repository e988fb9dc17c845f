//! The import config (`configs/import/motive.toml`): its sections, loading and range checks.

use std::collections::BTreeMap;
use std::path::Path;

use serde::{Deserialize, Serialize};

use crate::clean::CleaningConfig;
use crate::robot::RobotConfig;

use super::{ImportError, TakeConfig};

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
pub struct PackageProperties {
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

impl Default for PackageProperties {
    fn default() -> Self {
        PackageProperties {
            size_m: [0.254, 0.3048],
            mass_kg: 0.03,
            object_diameter_m: 0.16,
            object_body_mass_kg: 0.2268,
            marker_inset_m: None,
            lower_marker_positions_m: Vec::new(),
        }
    }
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
    pub package: PackageProperties,
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
}
