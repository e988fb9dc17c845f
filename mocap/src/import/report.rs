//! The retention report of one imported take (what was kept, and the robot fit), and its text.

use std::fmt;
use std::path::PathBuf;

use serde::Serialize;

use crate::clean::{percent, MarkerRetention};

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
