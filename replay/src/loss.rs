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
//!
//! **The labelled loss** ([`LossKind::Labelled`]) compares each marker with its own simulated site
//! instead of the nearest one: per frame the mean squared site error
//! `s_k = mean_{m seen} |site_{σ(m)} − r_m|²` (m²) over the markers whose site `σ(m)` is known
//! ([`crate::Target::marker_sites`]), and each phase of the motion ([`Phase`]) counts the same:
//! `w_object · mean_p mean_{k∈p} e_k + w_package · mean_p mean_{k∈p} s_k`. Beyond half the marker
//! spacing a nearest-neighbour match picks the wrong marker and stops responding to the parameters;
//! the labelled error keeps growing.

use serde::{Deserialize, Serialize};

use crate::phase::Phase;

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

/// Which comparison of package markers a loss uses.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum LossKind {
    /// The paper's: unlabelled package Chamfer distance (m), every frame alike.
    #[default]
    Chamfer,
    /// Each marker against its own site (m²), each phase of the motion alike (module docs).
    Labelled,
}

/// Weights of the two loss terms (the study used object 1.0, package 0.2) and the package term's
/// kind.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LossWeights {
    /// Weight of the mean object squared error (m²).
    pub object: f64,
    /// Weight of the package term: the mean Chamfer distance (m), or with `kind = "labelled"` the
    /// mean squared site error (m²).
    pub package: f64,
    /// The package term: `chamfer` (the paper's, default) or `labelled`.
    #[serde(default, skip_serializing_if = "is_chamfer")]
    pub kind: LossKind,
}

fn is_chamfer(kind: &LossKind) -> bool {
    *kind == LossKind::Chamfer
}

impl Default for LossWeights {
    fn default() -> Self {
        Self {
            object: 1.0,
            package: 0.2,
            kind: LossKind::Chamfer,
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
    /// Mean squared error (m²) of the markers whose site is known against their sites; `None`
    /// when no such marker is seen in the frame.
    pub site_sq_m2: Option<f64>,
    /// Markers of the frame whose site is known.
    pub labelled_markers: usize,
    /// The motion's phase at the frame.
    pub phase: Phase,
}

/// One compared frame: the simulation and the recording at the same time.
#[derive(Debug, Clone, Copy)]
pub struct FrameComparison<'a> {
    /// Index of the data frame.
    pub frame: usize,
    /// Simulated marker sites.
    pub simulated_points: &'a [[f64; 3]],
    /// Recorded markers.
    pub markers: &'a [[f64; 3]],
    /// The site of each recorded marker, where known.
    pub marker_sites: &'a [Option<usize>],
    /// Simulated object position.
    pub simulated_object: &'a [f64; 3],
    /// Recorded object position.
    pub recorded_object: &'a [f64; 3],
    /// The motion's phase.
    pub phase: Phase,
}

/// Mean squared distance between each labelled marker and its site, with the count; `None` when no
/// marker of the frame has a site.
pub fn site_squared_error(
    simulated_points: &[[f64; 3]],
    markers: &[[f64; 3]],
    marker_sites: &[Option<usize>],
) -> Option<(f64, usize)> {
    let (sum, count) = markers
        .iter()
        .zip(marker_sites)
        .filter_map(|(m, site)| site.and_then(|s| simulated_points.get(s)).map(|p| (m, p)))
        .fold((0.0, 0usize), |(sum, n), (m, p)| {
            (sum + squared_distance(m, p), n + 1)
        });
    (count > 0).then(|| (sum / count as f64, count))
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
    pub fn push_frame(&mut self, c: &FrameComparison) -> bool {
        let Some(chamfer_m) = chamfer_distance(c.simulated_points, c.markers) else {
            return false;
        };
        let site = site_squared_error(c.simulated_points, c.markers, c.marker_sites);
        self.frames.push(FrameLoss {
            frame: c.frame,
            chamfer_m,
            object_sq_m2: object_squared_error(c.simulated_object, c.recorded_object),
            site_sq_m2: site.map(|(e, _)| e),
            labelled_markers: site.map_or(0, |(_, n)| n),
            phase: c.phase,
        });
        true
    }

    /// Mean over the phases present of the mean of `value` over the phase's frames (frames where
    /// `value` is `None` do not count); NaN if no frame has a value. A non-finite value makes the
    /// result non-finite.
    pub fn phase_balanced(&self, value: impl Fn(&FrameLoss) -> Option<f64>) -> f64 {
        let phase_means = Phase::ALL.iter().filter_map(|&p| {
            let values: Vec<f64> = self
                .frames
                .iter()
                .filter(|f| f.phase == p)
                .filter_map(&value)
                .collect();
            (!values.is_empty()).then(|| values.iter().sum::<f64>() / values.len() as f64)
        });
        mean(phase_means)
    }

    /// Phase-balanced mean object squared error (m²).
    pub fn balanced_object_sq(&self) -> f64 {
        self.phase_balanced(|f| Some(f.object_sq_m2))
    }

    /// Phase-balanced mean squared site error of the labelled markers (m²).
    pub fn balanced_site_sq(&self) -> f64 {
        self.phase_balanced(|f| f.site_sq_m2)
    }

    /// Mean package Chamfer distance over the compared frames (m); NaN if none.
    pub fn mean_chamfer(&self) -> f64 {
        mean(self.frames.iter().map(|f| f.chamfer_m))
    }

    /// Mean object squared error over the compared frames (m²); NaN if none.
    pub fn mean_object_sq(&self) -> f64 {
        mean(self.frames.iter().map(|f| f.object_sq_m2))
    }

    /// The weighted trajectory loss: `w_object · mean e_k + w_package · mean CD_k`, or for the
    /// labelled kind the phase-balanced object and site errors (module docs).
    ///
    /// A non-finite frame (a diverged rollout) makes the total non-finite, so callers can tell.
    pub fn total(&self, weights: &LossWeights) -> f64 {
        match weights.kind {
            LossKind::Chamfer => {
                weights.object * self.mean_object_sq() + weights.package * self.mean_chamfer()
            }
            LossKind::Labelled => {
                weights.object * self.balanced_object_sq()
                    + weights.package * self.balanced_site_sq()
            }
        }
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

    /// Compares a frame with no labelled marker, in the move phase.
    fn push(
        loss: &mut TrajectoryLoss,
        frame: usize,
        simulated_points: &[[f64; 3]],
        markers: &[[f64; 3]],
        simulated_object: &[f64; 3],
        recorded_object: &[f64; 3],
    ) -> bool {
        loss.push_frame(&FrameComparison {
            frame,
            simulated_points,
            markers,
            marker_sites: &vec![None; markers.len()],
            simulated_object,
            recorded_object,
            phase: Phase::Move,
        })
    }

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
        assert!(!push(&mut loss, 0, &[[0.0; 3]], &[], &[0.0; 3], &[0.0; 3]));
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
        push(
            &mut a,
            0,
            &[[0.01, 0.0, 0.0]],
            &markers,
            &[0.1, 0.0, 0.0],
            &[0.0; 3],
        );
        // Frame 1: CD 0.03, object error 0.
        push(
            &mut a,
            1,
            &[[0.0, 0.03, 0.0]],
            &markers,
            &[0.0; 3],
            &[0.0; 3],
        );
        assert!((a.mean_chamfer() - 0.02).abs() < EPS);
        assert!((a.mean_object_sq() - 0.005).abs() < EPS);
        let w = LossWeights {
            object: 1.0,
            package: 0.2,
            kind: LossKind::Chamfer,
        };
        assert!((a.total(&w) - (0.005 + 0.2 * 0.02)).abs() < EPS);

        let mut b = TrajectoryLoss::new("B");
        // Frame 0: CD 0.06, object error 0.04.
        push(
            &mut b,
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
        push(
            &mut a,
            0,
            &[[f64::NAN; 3]],
            &[[0.0; 3]],
            &[0.0; 3],
            &[0.0; 3],
        );
        assert!(!a.total(&LossWeights::default()).is_finite());
    }

    #[test]
    fn the_labelled_error_keeps_growing_where_the_chamfer_distance_picks_the_wrong_marker() {
        // Two markers 5 cm apart on x; the simulation shifted by d along x. Beyond half the
        // spacing the nearest-neighbour match pairs the shifted sites with the other marker.
        let markers = [[0.0, 0.0, 0.0], [0.05, 0.0, 0.0]];
        let sites = [Some(0), Some(1)];
        let at = |d: f64| {
            let sim = [[d, 0.0, 0.0], [0.05 + d, 0.0, 0.0]];
            let site = site_squared_error(&sim, &markers, &sites).unwrap();
            (chamfer_distance(&sim, &markers).unwrap(), site)
        };
        let (cd_small, (site_small, n)) = at(0.03);
        let (cd_large, (site_large, _)) = at(0.045);
        assert_eq!(n, 2);
        assert!((site_small - 0.03f64.powi(2)).abs() < EPS);
        assert!((site_large - 0.045f64.powi(2)).abs() < EPS);
        // From half the spacing on, the Chamfer distance reads 2.5 cm whatever the shift.
        assert!((cd_small - 0.025).abs() < EPS && (cd_large - 0.025).abs() < EPS);
        // Unknown sites do not count; none known gives none.
        let sim = [[0.01, 0.0, 0.0], [0.05, 0.0, 0.0]];
        let one = site_squared_error(&sim, &markers, &[Some(0), None]).unwrap();
        assert_eq!(one, (0.01f64.powi(2), 1));
        assert_eq!(site_squared_error(&sim, &markers, &[None, None]), None);
    }

    #[test]
    fn every_phase_counts_the_same_in_the_labelled_loss() {
        // Nine frames of error 0.01 m² in the move phase, one of error 0.03 m² in the tilt.
        let mut loss = TrajectoryLoss::new("A");
        let markers = [[0.0; 3]];
        for k in 0..10 {
            let (phase, e) = if k < 9 {
                (Phase::Move, 0.1)
            } else {
                (Phase::Tilt, 0.03f64.sqrt())
            };
            let sim = [[e, 0.0, 0.0]];
            loss.push_frame(&FrameComparison {
                frame: k,
                simulated_points: &sim,
                markers: &markers,
                marker_sites: &[Some(0)],
                simulated_object: &[0.0; 3],
                recorded_object: &[0.0; 3],
                phase,
            });
        }
        let tilt = loss.frames[9].site_sq_m2.unwrap();
        assert!((tilt - 0.03).abs() < 1e-12, "{tilt}");
        assert!((loss.balanced_site_sq() - 0.02).abs() < 1e-12);
        let w = LossWeights {
            object: 1.0,
            package: 1.0,
            kind: LossKind::Labelled,
        };
        assert!((loss.total(&w) - 0.02).abs() < 1e-12);
        // The unweighted per-frame mean would be 0.012.
        let plain: f64 = loss
            .frames
            .iter()
            .map(|f| f.site_sq_m2.unwrap())
            .sum::<f64>()
            / 10.0;
        assert!((plain - 0.012).abs() < 1e-12);
        // The paper's loss is unchanged by phases and sites.
        let paper = LossWeights::default();
        let expected = paper.object * loss.mean_object_sq() + paper.package * loss.mean_chamfer();
        assert_eq!(loss.total(&paper), expected);
    }
}
