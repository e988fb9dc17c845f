//! The cleaning parameters (`[cleaning]` in `configs/import/motive.toml`) and their ranges.

use serde::{Deserialize, Serialize};

/// Cleaning parameters (`[cleaning]` in `configs/import/motive.toml`); times in seconds, distances in m.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct CleaningConfig {
    /// Butterworth order (each pass; filtfilt doubles the effective order).
    pub filter_order: usize,
    /// Marker low-pass cut-off in Hz, at the take's real export frame rate; 0 disables.
    pub marker_cutoff_hz: f64,
    /// Rigid-body (tool, object) low-pass cut-off in Hz; 0 disables.
    pub rigid_body_cutoff_hz: f64,
    /// Re-identification: largest accepted distance (m) between a new id's first position and the
    /// predicted position of a lost track.
    pub reid_max_distance_m: f64,
    /// Re-identification: the accepted distance grows by this much (m) per second the track was
    /// lost (the prediction gets less certain over long dropouts).
    pub reid_distance_growth_m_per_s: f64,
    /// Re-identification: how long (s) a lost track stays a candidate.
    pub reid_max_lost_s: f64,
    /// Re-identification: half the smallest distance between the package's two film sheets. Two
    /// markers seen together farther apart than this along the package's normal are on different
    /// sheets, and a marker within this distance of the markers of one sheet is on that sheet (see
    /// [`fragment_sheets`]); a new id joins a lost track only when both their sheets are told and
    /// the same (see [`reidentify`]).
    ///
    /// [`fragment_sheets`]: super::fragment_sheets
    /// [`reidentify`]: super::reidentify
    pub reid_max_sheet_offset_m: f64,
    /// Number of nearby tracks whose motion carries a hidden marker along (re-identification and
    /// long-gap interpolation).
    pub neighbours: usize,
    /// Only tracks this close (m) to the hidden marker count as neighbours.
    pub neighbourhood_m: f64,
    /// Spurious reflections: tracks seen for less than this (s) after re-identification are dropped.
    pub min_track_s: f64,
    /// Spurious reflections: samples farther than this (m) from the frame's marker median are dropped.
    pub max_cluster_distance_m: f64,
    /// Gaps up to this long (s) are filled from the velocities at both ends (a cubic).
    pub max_velocity_fill_s: f64,
    /// Gaps up to this long (s) (and longer than the previous) are linearly interpolated; longer
    /// gaps stay empty.
    pub max_interpolated_gap_s: f64,
    /// Samples on each side of a gap used to estimate the end velocities.
    pub velocity_window: usize,
}

impl Default for CleaningConfig {
    fn default() -> Self {
        CleaningConfig {
            filter_order: 4,
            marker_cutoff_hz: 12.0,
            rigid_body_cutoff_hz: 12.0,
            reid_max_distance_m: 0.02,
            reid_distance_growth_m_per_s: 0.02,
            reid_max_lost_s: 1.5,
            reid_max_sheet_offset_m: 0.006,
            neighbours: 4,
            neighbourhood_m: 0.12,
            min_track_s: 0.2,
            max_cluster_distance_m: 0.3,
            max_velocity_fill_s: 0.02,
            max_interpolated_gap_s: 1.0,
            velocity_window: 4,
        }
    }
}

impl CleaningConfig {
    /// Checks every value against its range; the error names the key and the range.
    pub fn validate(&self) -> Result<(), String> {
        let positive = [
            ("reid_max_distance_m", self.reid_max_distance_m),
            ("reid_max_sheet_offset_m", self.reid_max_sheet_offset_m),
            ("neighbourhood_m", self.neighbourhood_m),
            ("max_cluster_distance_m", self.max_cluster_distance_m),
        ];
        for (key, v) in positive {
            if !(v.is_finite() && v > 0.0) {
                return Err(format!("cleaning.{key} = {v}: expected a number > 0"));
            }
        }
        let non_negative = [
            ("marker_cutoff_hz", self.marker_cutoff_hz),
            ("rigid_body_cutoff_hz", self.rigid_body_cutoff_hz),
            ("reid_max_lost_s", self.reid_max_lost_s),
            (
                "reid_distance_growth_m_per_s",
                self.reid_distance_growth_m_per_s,
            ),
            ("min_track_s", self.min_track_s),
            ("max_velocity_fill_s", self.max_velocity_fill_s),
            ("max_interpolated_gap_s", self.max_interpolated_gap_s),
        ];
        for (key, v) in non_negative {
            if !(v.is_finite() && v >= 0.0) {
                return Err(format!("cleaning.{key} = {v}: expected a number >= 0"));
            }
        }
        if !(1..=10).contains(&self.filter_order) {
            return Err(format!(
                "cleaning.filter_order = {}: expected 1..=10",
                self.filter_order
            ));
        }
        if !(1..=50).contains(&self.velocity_window) {
            return Err(format!(
                "cleaning.velocity_window = {}: expected 1..=50",
                self.velocity_window
            ));
        }
        if !(1..=20).contains(&self.neighbours) {
            return Err(format!(
                "cleaning.neighbours = {}: expected 1..=20",
                self.neighbours
            ));
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn config_ranges_are_checked() {
        assert!(CleaningConfig::default().validate().is_ok());
        let bad = CleaningConfig {
            reid_max_distance_m: -1.0,
            ..CleaningConfig::default()
        };
        assert!(bad
            .validate()
            .unwrap_err()
            .contains("cleaning.reid_max_distance_m"));
    }
}
