//! The structured calibration loss of the paper (eq. 2 and eq. 3) and the Table 1 metrics.
//!
//! Definitions, per compared frame k (all in SI units):
//!
//! * **Package Chamfer distance** (eq. 2, metres, *not* squared), between the simulated package points
//!   S and the markers R_k seen in that frame, each direction averaged over its own point count:
//!
//!   `CD_k = ½ · mean_{s∈S} min_{r∈R_k} |s − r|  +  ½ · mean_{r∈R_k} min_{s∈S} |s − r|`
//!
//!   This is the study's symmetric mean nearest-neighbour distance (reference-model §8.3).
//! * **Object squared position error** (eq. 3, m²): `e_k = |p_sim,k − p_rec,k|²`.
//!
//! Unlike the study's code, which divided running sums by the trajectory's duration (§8.5), every
//! figure here is a per-frame mean: the trajectory loss is
//! `w_object · mean_k e_k + w_package · mean_k CD_k`, and Table 1 reports per-frame statistics.

use serde::{Deserialize, Serialize};

/// Chamfer distance (eq. 2) between simulated points and recorded markers, in metres.
///
/// Returns `None` when either set is empty (a frame in which no marker was seen is not compared).
pub fn chamfer_distance(simulated: &[[f64; 3]], markers: &[[f64; 3]]) -> Option<f64> {
    if simulated.is_empty() || markers.is_empty() {
        return None;
    }
    let sim_to_markers = mean_nearest_distance(simulated, markers);
    let markers_to_sim = mean_nearest_distance(markers, simulated);
    Some(0.5 * sim_to_markers + 0.5 * markers_to_sim)
}

/// Mean over `from` of the distance to the nearest point of `to` (both non-empty).
fn mean_nearest_distance(from: &[[f64; 3]], to: &[[f64; 3]]) -> f64 {
    let total: f64 = from
        .iter()
        .map(|a| {
            to.iter()
                .map(|b| squared_distance(a, b))
                .fold(f64::INFINITY, f64::min)
                .sqrt()
        })
        .sum();
    total / from.len() as f64
}

/// Squared Euclidean distance between two points.
pub fn squared_distance(a: &[f64; 3], b: &[f64; 3]) -> f64 {
    (0..3).map(|i| (a[i] - b[i]).powi(2)).sum()
}

/// Object squared position error (eq. 3), in m².
pub fn object_squared_error(simulated: &[f64; 3], recorded: &[f64; 3]) -> f64 {
    squared_distance(simulated, recorded)
}

/// Weights of the two loss terms (the study used object 1.0, package 0.2).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LossWeights {
    /// Weight of the mean object squared error (m²).
    pub object: f64,
    /// Weight of the mean package Chamfer distance (m).
    pub package: f64,
}

impl Default for LossWeights {
    fn default() -> Self {
        Self {
            object: 1.0,
            package: 0.2,
        }
    }
}

/// Loss metrics of one compared frame.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct FrameLoss {
    /// Index of the data frame.
    pub frame: usize,
    /// Package Chamfer distance (m).
    pub chamfer_m: f64,
    /// Object squared position error (m²).
    pub object_sq_m2: f64,
}

/// Per-frame losses of one rollout against one recorded trajectory.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct TrajectoryLoss {
    /// Trajectory id (e.g. `HHHHH`).
    pub id: String,
    /// One entry per compared frame, in frame order.
    pub frames: Vec<FrameLoss>,
}

impl TrajectoryLoss {
    /// An empty loss record for trajectory `id`.
    pub fn new(id: impl Into<String>) -> Self {
        Self {
            id: id.into(),
            frames: Vec::new(),
        }
    }

    /// Compares one frame and records it; frames without markers are skipped (returns `false`).
    pub fn push_frame(
        &mut self,
        frame: usize,
        simulated_points: &[[f64; 3]],
        markers: &[[f64; 3]],
        simulated_object: &[f64; 3],
        recorded_object: &[f64; 3],
    ) -> bool {
        let Some(chamfer_m) = chamfer_distance(simulated_points, markers) else {
            return false;
        };
        self.frames.push(FrameLoss {
            frame,
            chamfer_m,
            object_sq_m2: object_squared_error(simulated_object, recorded_object),
        });
        true
    }

    /// Mean package Chamfer distance over the compared frames (m); NaN if none.
    pub fn mean_chamfer(&self) -> f64 {
        mean(self.frames.iter().map(|f| f.chamfer_m))
    }

    /// Mean object squared error over the compared frames (m²); NaN if none.
    pub fn mean_object_sq(&self) -> f64 {
        mean(self.frames.iter().map(|f| f.object_sq_m2))
    }

    /// The weighted trajectory loss `w_object · mean e_k + w_package · mean CD_k`.
    ///
    /// A non-finite frame (a diverged rollout) makes the total non-finite, so callers can tell.
    pub fn total(&self, weights: &LossWeights) -> f64 {
        weights.object * self.mean_object_sq() + weights.package * self.mean_chamfer()
    }
}

/// Mean of an iterator of values (NaN when empty).
fn mean(values: impl Iterator<Item = f64>) -> f64 {
    let (sum, count) = values.fold((0.0, 0usize), |(s, n), v| (s + v, n + 1));
    if count == 0 {
        f64::NAN
    } else {
        sum / count as f64
    }
}

/// Mean, maximum and population standard deviation of a set of values.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Stats {
    /// Arithmetic mean.
    pub mean: f64,
    /// Maximum.
    pub max: f64,
    /// Population standard deviation (divides by the count).
    pub std: f64,
}

impl Stats {
    /// Statistics of `values`; NaN fields when `values` is empty.
    pub fn of(values: &[f64]) -> Self {
        if values.is_empty() {
            return Self {
                mean: f64::NAN,
                max: f64::NAN,
                std: f64::NAN,
            };
        }
        let mean = values.iter().sum::<f64>() / values.len() as f64;
        let var = values.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / values.len() as f64;
        let max = values.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        Self {
            mean,
            max,
            std: var.sqrt(),
        }
    }
}

/// One row of the paper's Table 1: statistics over every compared frame of every trajectory in a split.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Table1Row {
    /// Row label, e.g. `train` or `test`.
    pub split: String,
    /// Number of trajectories.
    pub trajectories: usize,
    /// Number of compared frames (pooled over trajectories).
    pub frames: usize,
    /// Package Chamfer distance per frame (m).
    pub chamfer_m: Stats,
    /// Object squared position error per frame (m²).
    pub object_mse_m2: Stats,
}

impl Table1Row {
    /// Pools the frames of `losses` (frames and trajectories together) into one row.
    pub fn from_losses(split: impl Into<String>, losses: &[TrajectoryLoss]) -> Self {
        let chamfer: Vec<f64> = losses
            .iter()
            .flat_map(|l| l.frames.iter().map(|f| f.chamfer_m))
            .collect();
        let object: Vec<f64> = losses
            .iter()
            .flat_map(|l| l.frames.iter().map(|f| f.object_sq_m2))
            .collect();
        Self {
            split: split.into(),
            trajectories: losses.len(),
            frames: chamfer.len(),
            chamfer_m: Stats::of(&chamfer),
            object_mse_m2: Stats::of(&object),
        }
    }
}

/// The paper's Table 1 as aligned text: one line per row, CD in metres and object MSE in m².
pub fn table1_text(rows: &[Table1Row]) -> String {
    let mut out = format!(
        "{:<6} {:>5} {:>7} | {:>10} {:>10} {:>10} | {:>11} {:>11} {:>11}\n",
        "split",
        "traj",
        "frames",
        "CD mean m",
        "CD max m",
        "CD std m",
        "MSE mean m2",
        "MSE max m2",
        "MSE std m2"
    );
    for r in rows {
        out.push_str(&format!(
            "{:<6} {:>5} {:>7} | {:>10.5} {:>10.5} {:>10.5} | {:>11.3e} {:>11.3e} {:>11.3e}\n",
            r.split,
            r.trajectories,
            r.frames,
            r.chamfer_m.mean,
            r.chamfer_m.max,
            r.chamfer_m.std,
            r.object_mse_m2.mean,
            r.object_mse_m2.max,
            r.object_mse_m2.std
        ));
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    const EPS: f64 = 1e-12;

    #[test]
    fn chamfer_of_hand_computed_sets() {
        // S = {(0,0,0), (1,0,0)}, R = {(0,1,0)}.
        // S→R: distances 1 and √2, mean (1 + √2)/2. R→S: nearest is (0,0,0) at 1, mean 1.
        let s = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]];
        let r = [[0.0, 1.0, 0.0]];
        let expected = 0.5 * (1.0 + 2f64.sqrt()) / 2.0 + 0.5 * 1.0;
        let cd = chamfer_distance(&s, &r).unwrap();
        assert!((cd - expected).abs() < EPS, "{cd} vs {expected}");
        // Symmetric by construction.
        assert!((chamfer_distance(&r, &s).unwrap() - expected).abs() < EPS);
    }

    #[test]
    fn chamfer_is_unsquared_and_zero_on_identical_sets() {
        let s = [[0.1, 0.2, 0.3], [0.4, -0.5, 0.6]];
        assert_eq!(chamfer_distance(&s, &s), Some(0.0));
        // Shifting one set by 3 cm along z gives exactly 0.03 m (not 0.0009 m²).
        let shifted: Vec<[f64; 3]> = s.iter().map(|p| [p[0], p[1], p[2] + 0.03]).collect();
        let cd = chamfer_distance(&s, &shifted).unwrap();
        assert!((cd - 0.03).abs() < EPS, "{cd}");
    }

    #[test]
    fn chamfer_uses_each_sides_own_count() {
        // Three sim points at x = 0, 1, 2; one marker at x = 0.
        // S→R: (0 + 1 + 2)/3 = 1. R→S: 0. CD = 0.5.
        let s = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [2.0, 0.0, 0.0]];
        let r = [[0.0, 0.0, 0.0]];
        assert!((chamfer_distance(&s, &r).unwrap() - 0.5).abs() < EPS);
    }

    #[test]
    fn empty_frames_are_not_compared() {
        assert_eq!(chamfer_distance(&[[0.0; 3]], &[]), None);
        let mut loss = TrajectoryLoss::new("X");
        assert!(!loss.push_frame(0, &[[0.0; 3]], &[], &[0.0; 3], &[0.0; 3]));
        assert!(loss.frames.is_empty());
        assert!(loss.mean_chamfer().is_nan());
    }

    #[test]
    fn object_error_is_squared_metres() {
        let e = object_squared_error(&[0.0, 0.0, 0.0], &[0.03, 0.04, 0.0]);
        assert!((e - 0.0025).abs() < EPS);
    }

    #[test]
    fn trajectory_total_and_table_row() {
        let markers = [[0.0, 0.0, 0.0]];
        let mut a = TrajectoryLoss::new("A");
        // Frame 0: CD 0.01 (both sides 0.01), object error (0.1)² = 0.01.
        a.push_frame(
            0,
            &[[0.01, 0.0, 0.0]],
            &markers,
            &[0.1, 0.0, 0.0],
            &[0.0; 3],
        );
        // Frame 1: CD 0.03, object error 0.
        a.push_frame(1, &[[0.0, 0.03, 0.0]], &markers, &[0.0; 3], &[0.0; 3]);
        assert!((a.mean_chamfer() - 0.02).abs() < EPS);
        assert!((a.mean_object_sq() - 0.005).abs() < EPS);
        let w = LossWeights {
            object: 1.0,
            package: 0.2,
        };
        assert!((a.total(&w) - (0.005 + 0.2 * 0.02)).abs() < EPS);

        let mut b = TrajectoryLoss::new("B");
        // Frame 0: CD 0.06, object error 0.04.
        b.push_frame(
            0,
            &[[0.0, 0.0, 0.06]],
            &markers,
            &[0.0, 0.2, 0.0],
            &[0.0; 3],
        );
        let row = Table1Row::from_losses("test", &[a, b]);
        assert_eq!((row.trajectories, row.frames), (2, 3));
        // Pooled CD: {0.01, 0.03, 0.06}: mean 0.1/3, max 0.06.
        let mean: f64 = 0.1 / 3.0;
        let std = (((0.01f64 - mean).powi(2) + (0.03 - mean).powi(2) + (0.06 - mean).powi(2))
            / 3.0)
            .sqrt();
        assert!((row.chamfer_m.mean - mean).abs() < EPS);
        assert!((row.chamfer_m.max - 0.06).abs() < EPS);
        assert!((row.chamfer_m.std - std).abs() < EPS);
        // Pooled object: {0.01, 0, 0.04}.
        assert!((row.object_mse_m2.mean - 0.05 / 3.0).abs() < EPS);
        assert!((row.object_mse_m2.max - 0.04).abs() < EPS);
        let text = table1_text(&[row]);
        assert_eq!(text.lines().count(), 2);
        assert!(
            text.lines()
                .nth(1)
                .unwrap()
                .starts_with("test       2       3 |    0.03333    0.06000"),
            "{text}"
        );
    }

    #[test]
    fn diverged_frames_make_the_total_non_finite() {
        let mut a = TrajectoryLoss::new("A");
        a.push_frame(0, &[[f64::NAN; 3]], &[[0.0; 3]], &[0.0; 3], &[0.0; 3]);
        assert!(!a.total(&LossWeights::default()).is_finite());
    }
}
