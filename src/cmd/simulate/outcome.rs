//! What `rlpkg simulate` writes: the CSV rows of every compared frame, the summary and the
//! closing report.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use rlpkg_mocap::Trajectory;
use rlpkg_replay::loss::chamfer_distance;
use rlpkg_replay::SealFailure;
use rlpkg_sim::Model;

use crate::error::output_error;
use crate::files::write_atomic;

/// The package Chamfer distance of the calibration (`rlpkg_replay::loss`, reference-model.md §8.3)
/// between simulated sites and a frame's markers, in metres; NaN when either set is empty.
pub fn chamfer(simulated: &[[f32; 3]], recorded: &[[f64; 3]]) -> f64 {
    let simulated: Vec<[f64; 3]> = simulated.iter().map(|p| p.map(f64::from)).collect();
    chamfer_distance(&simulated, recorded).unwrap_or(f64::NAN)
}

/// Everything the replay produced.
pub struct Outcome {
    markers_csv: String,
    object_csv: String,
    metrics_csv: String,
    chamfer: Vec<f64>,
    object_error: Vec<f64>,
    times: Vec<f64>,
    /// The PNG stills written.
    pub stills: Vec<PathBuf>,
    /// The GIF written and its frame count.
    pub gif: Option<(PathBuf, usize)>,
    /// The health event that ended the replay early.
    pub health: Option<rlpkg_sim::HealthEvent>,
    /// The first cup whose seal failed.
    pub seal_failure: Option<SealFailure>,
    /// The first frame whose simulated values were not finite (frame, recording time): the replay
    /// ended there, and the files hold the frames before it.
    pub non_finite: Option<(usize, f64)>,
    /// Where the simulator ended: substeps from the start of the rest period.
    pub substeps: u64,
    /// Where the simulator ended (s from the start of the rest period).
    pub simulated_s: f64,
    /// The substep length (s).
    pub dt_s: f32,
}

impl Outcome {
    /// Starts the CSV texts for `marker_sites` simulated marker sites.
    pub fn new(marker_sites: usize) -> Self {
        let mut markers_csv = String::from("frame,t");
        for (prefix, count) in [("m", marker_sites), ("g", 42)] {
            for site in 0..count {
                for axis in ["x", "y", "z"] {
                    let _ = write!(markers_csv, ",{prefix}{site}_{axis}");
                }
            }
        }
        markers_csv.push('\n');
        Self {
            markers_csv,
            object_csv: "t,px,py,pz,qx,qy,qz,qw\n".to_string(),
            metrics_csv: "frame,t,chamfer_m,object_error_m\n".to_string(),
            chamfer: Vec::new(),
            object_error: Vec::new(),
            times: Vec::new(),
            stills: Vec::new(),
            gif: None,
            health: None,
            seal_failure: None,
            non_finite: None,
            substeps: 0,
            simulated_s: 0.0,
            dt_s: 0.0,
        }
    }

    /// Records the CSV rows of frame `k`.
    pub fn record(
        &mut self,
        k: usize,
        recording: &Trajectory,
        marker_sites: &[[f32; 3]],
        grid_sites: &[[f32; 3]],
        disc: rlpkg_sim::DiscState,
    ) {
        let t = recording.tool.t[k];
        let _ = write!(self.markers_csv, "{k},{t:.6}");
        for p in marker_sites.iter().chain(grid_sites) {
            let _ = write!(self.markers_csv, ",{:.6},{:.6},{:.6}", p[0], p[1], p[2]);
        }
        self.markers_csv.push('\n');
        let (p, q) = (disc.position, disc.orientation);
        let _ = writeln!(
            self.object_csv,
            "{t:.6},{:.6},{:.6},{:.6},{:.6},{:.6},{:.6},{:.6}",
            p[0], p[1], p[2], q[0], q[1], q[2], q[3]
        );
        let cd = chamfer(grid_sites, recording.markers.frame(k));
        let recorded = recording.object.position[k];
        let error = (0..3)
            .map(|a| (f64::from(p[a]) - recorded[a]).powi(2))
            .sum::<f64>()
            .sqrt();
        let _ = writeln!(self.metrics_csv, "{k},{t:.6},{cd:.6},{error:.6}");
        self.chamfer.push(cd);
        self.object_error.push(error);
        self.times.push(t);
    }

    /// Writes the three CSV files into `out`.
    pub fn write_csvs(&self, out: &Path) -> anyhow::Result<()> {
        for (name, text) in [
            ("markers_sim.csv", &self.markers_csv),
            ("object_sim.csv", &self.object_csv),
            ("metrics.csv", &self.metrics_csv),
        ] {
            write_atomic(&out.join(name), text.as_bytes()).map_err(output_error)?;
        }
        Ok(())
    }

    /// The content of `summary.json`.
    pub fn summary(
        &self,
        recording: &Trajectory,
        model: &Model,
        rest_s: f64,
        config_source: &str,
        wall_s: f64,
        out: &Path,
    ) -> serde_json::Value {
        let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len().max(1) as f64;
        let max = |v: &[f64]| v.iter().copied().fold(f64::NAN, f64::max);
        let duration = self.times.last().copied().unwrap_or(0.0);
        // The reference's normalisation (§8.5): sums over the 240 Hz samples divided by seconds.
        let per_second = |sum: f64| {
            if duration > 0.0 {
                sum / duration
            } else {
                f64::NAN
            }
        };
        let mut summary = serde_json::json!({
            "trajectory": recording.id,
            "config": config_source,
            "grid": model.grid,
            "package_particles": model.num_package,
            "cup_particles": model.num_cup,
            "dt_s": self.dt_s,
            "rest_s": rest_s,
            "replayed_s": duration,
            "frames_compared": self.times.len(),
            "substeps": self.substeps,
            "wall_s": wall_s,
            "realtime_factor": self.simulated_s / wall_s.max(1e-9),
            "chamfer_mean_m": mean(&self.chamfer),
            "chamfer_max_m": max(&self.chamfer),
            "object_error_mean_m": mean(&self.object_error),
            "object_error_max_m": max(&self.object_error),
            "object_error_final_m": self.object_error.last(),
            "package_particle_loss": per_second(self.chamfer.iter().sum()),
            "internal_object_loss": per_second(self.object_error.iter().map(|e| e * e).sum()),
            "health": match (self.health, self.non_finite) {
                (_, Some((k, t))) => Some(format!("non-finite simulated values at frame {k} (recording t = {t:.4} s)")),
                (Some(e), None) => Some(format!("{:?} at simulated t = {:.4} s", e.reason, e.time)),
                (None, None) => None,
            },
            "files": {
                "markers_sim": out.join("markers_sim.csv"),
                "object_sim": out.join("object_sim.csv"),
                "metrics": out.join("metrics.csv"),
                "stills": self.stills,
                "gif": self.gif.as_ref().map(|g| &g.0),
            },
        });
        // Only when a cup failed: a replay without seal failures keeps its summary's keys.
        if let Some(failure) = &self.seal_failure {
            summary["seal_failure"] = serde_json::json!({
                "cup": failure.cup,
                "mode": failure.mode(),
                "t_s": failure.t,
            });
        }
        summary
    }

    /// The report line of the first seal failure: `cup k failed (mode) at t = ... s`.
    pub fn seal_line(failure: &SealFailure) -> String {
        format!(
            "cup {} failed ({}) at t = {:.3} s",
            failure.cup,
            failure.mode(),
            failure.t
        )
    }

    /// Prints the closing report.
    pub fn print(&self, wall_s: f64, out: &Path) {
        let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len().max(1) as f64;
        println!(
            "replayed {} frames ({:.3} s) in {:.1} s wall: {:.3}x real time",
            self.times.len(),
            self.times.last().copied().unwrap_or(0.0),
            wall_s,
            self.simulated_s / wall_s.max(1e-9)
        );
        println!(
            "chamfer distance mean {:.2} mm, object error mean {:.2} mm, final {:.2} mm",
            1e3 * mean(&self.chamfer),
            1e3 * mean(&self.object_error),
            1e3 * self.object_error.last().copied().unwrap_or(f64::NAN)
        );
        if let Some(failure) = &self.seal_failure {
            println!("{}", Self::seal_line(failure));
        }
        println!(
            "wrote {}/{{markers_sim,object_sim,metrics}}.csv and summary.json",
            out.display()
        );
        println!(
            "      {} PNG stills in {}",
            self.stills.len(),
            out.join("frames").display()
        );
        if let Some((path, frames)) = &self.gif {
            println!("      {} ({frames} frames)", path.display());
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_seal_failure_is_reported_in_one_line() {
        let failure = SealFailure {
            cup: 2,
            kind: rlpkg_sim::SealEventKind::PulledOff,
            t: 1.23456,
        };
        assert_eq!(
            Outcome::seal_line(&failure),
            "cup 2 failed (pulled off) at t = 1.235 s"
        );
    }

    #[test]
    fn chamfer_is_the_symmetric_mean_nearest_distance() {
        let simulated = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]];
        let recorded = [[0.0, 0.1, 0.0]];
        // sim -> rec: (0.1 + sqrt(1.01)) / 2; rec -> sim: 0.1.
        let expected = 0.5 * ((0.1 + 1.01f64.sqrt()) / 2.0 + 0.1);
        assert!((chamfer(&simulated, &recorded) - expected).abs() < 1e-7);
        assert_eq!(
            chamfer(&simulated, &[[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]]),
            0.0
        );
        assert!(chamfer(&[], &recorded).is_nan());
        assert!(chamfer(&simulated, &[]).is_nan());
        // The very function the calibration's loss uses, on the same points.
        let simulated_f64 = simulated.map(|p| p.map(f64::from));
        assert_eq!(
            chamfer(&simulated, &recorded),
            chamfer_distance(&simulated_f64, &recorded).unwrap()
        );
    }
}
