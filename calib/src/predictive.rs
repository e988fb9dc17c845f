//! The posterior-predictive Table 1 (`rlpkg eval --params <posterior summary.json or samples.csv>`).
//!
//! The same Table 1 as for one scene, computed for a number of posterior draws (evenly spaced
//! through `samples.csv`) in one batched replay of the whole recordings (draws x trajectories
//! environments), and reported per column as the median and the 90 % band (5 % and 95 %
//! quantiles) over the draws. A draw that diverges on a trajectory is counted and left out of the
//! bands: its Table 1 would only cover the frames before the divergence.
//!
//! The draws are parameters of the scene the posterior's calibration simulated: the calibration
//! config its `summary.json` records ([`posterior_files::recorded_calibration`]).

use std::path::{Path, PathBuf};
use std::sync::Arc;

use rlpkg_mocap::{Dataset, Split};
use rlpkg_replay::loss::{Table1Row, TrajectoryLoss};
use rlpkg_replay::{rollout, set_param, Candidate, Observer, ReplayError, Target};
use rlpkg_sim::{Model, SceneConfig};
use serde::Serialize;

use crate::posterior::quantile;
use crate::posterior_files::{self, Samples, SAMPLES_FILE, SUMMARY_FILE};

/// What stops a posterior-predictive evaluation.
#[derive(Debug, thiserror::Error)]
pub enum PredictiveError {
    /// A file or value given to it (the message names it and what was expected).
    #[error("{0}")]
    Input(String),
    /// The requested splits of the dataset hold no trajectory.
    #[error("{}: no trajectory in the requested splits", data.display())]
    NoTrajectory {
        /// The dataset folder.
        data: PathBuf,
    },
    /// The batched replay failed.
    #[error(transparent)]
    Replay(#[from] ReplayError),
}

fn input(err: impl std::fmt::Display) -> PredictiveError {
    PredictiveError::Input(err.to_string())
}

/// What to evaluate.
pub struct PredictiveRequest<'a> {
    /// `summary.json` or `samples.csv` of a posterior folder, or the folder.
    pub posterior: &'a Path,
    /// Draws to replay (at least 1).
    pub draws: usize,
    /// The splits of the dataset to replay, one Table 1 row each.
    pub splits: &'a [Split],
    /// Dataset folder [default: the calibration config's `data`].
    pub data: Option<&'a Path>,
}

/// Median and 90 % band of one Table 1 column over the draws.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct Band {
    /// Median.
    pub median: f64,
    /// 5 % quantile.
    pub low: f64,
    /// 95 % quantile.
    pub high: f64,
}

impl Band {
    /// The band of `values` (all NaN when there are none).
    pub fn of(mut values: Vec<f64>) -> Self {
        values.sort_by(f64::total_cmp);
        if values.is_empty() {
            return Self {
                median: f64::NAN,
                low: f64::NAN,
                high: f64::NAN,
            };
        }
        Self {
            median: quantile(&values, 0.5),
            low: quantile(&values, 0.05),
            high: quantile(&values, 0.95),
        }
    }
}

/// The predictive Table 1 row of one split.
#[derive(Debug, Serialize)]
pub struct PredictiveRow {
    /// The split's name.
    pub split: String,
    /// Trajectories of the split.
    pub trajectories: usize,
    /// Draws in the bands (those that diverged on no trajectory of the split).
    pub draws: usize,
    /// Draws left out of the bands.
    pub diverged_draws: usize,
    /// Mean Chamfer distance per frame (m).
    pub chamfer_mean_m: Band,
    /// Largest Chamfer distance (m).
    pub chamfer_max_m: Band,
    /// Standard deviation of the Chamfer distance (m).
    pub chamfer_std_m: Band,
    /// Mean object squared error per frame (m²).
    pub object_mse_mean_m2: Band,
    /// Largest object squared error (m²).
    pub object_mse_max_m2: Band,
    /// Standard deviation of the object squared error (m²).
    pub object_mse_std_m2: Band,
}

/// The evaluation's `summary.json`.
#[derive(Debug, Serialize)]
pub struct PredictiveSummary {
    /// The posterior's `samples.csv`.
    pub posterior: PathBuf,
    /// The calibration config the draws are parameters of.
    pub config: PathBuf,
    /// Indices (rows of `samples.csv`, from 0) of the replayed draws.
    pub draw_rows: Vec<usize>,
    /// One row per split.
    pub table1: Vec<PredictiveRow>,
    /// Per draw, its Table 1 (one row per split).
    pub per_draw: Vec<Vec<Table1Row>>,
}

/// An evaluation set up: the posterior read, its draws as candidates of its calibration's scene,
/// the recordings as targets; nothing replayed yet ([`PredictivePlan::run`]).
pub struct PredictivePlan {
    /// The posterior's `summary.json`.
    pub summary_path: PathBuf,
    samples_path: PathBuf,
    config_path: PathBuf,
    rows: Vec<usize>,
    candidates: Vec<Candidate>,
    splits: Vec<Split>,
    selected: Vec<(Split, Target)>,
    scene: SceneConfig,
}

impl PredictivePlan {
    /// Reads the posterior `request` names and its calibration, picks the draws and loads the
    /// requested splits of the dataset.
    pub fn new(request: &PredictiveRequest) -> Result<Self, PredictiveError> {
        if request.draws == 0 {
            return Err(input("0 draws: expected at least one posterior draw"));
        }
        let files = posterior_files::locate(request.posterior).map_err(input)?;
        let samples_path = files.samples;
        let summary_path = files.summary.ok_or_else(|| {
            input(format!(
                "{}: no {SUMMARY_FILE} beside it; --params {} needs the {SUMMARY_FILE} and \
                 {SAMPLES_FILE} that `rlpkg posterior` writes side by side",
                samples_path.display(),
                request.posterior.display()
            ))
        })?;
        let (config_path, config) =
            posterior_files::recorded_calibration(&summary_path).map_err(input)?;
        let names: Vec<String> = config.params.iter().map(|p| p.name.clone()).collect();
        let samples = Samples::read_columns(&samples_path, &names).map_err(input)?;
        let rows = samples
            .evenly_spaced_rows(&samples_path, request.draws, "--draws")
            .map_err(input)?;
        let scene = config.scene(&config_path).map_err(input)?;
        let base = Candidate::of_scene(&scene);
        let candidates = rows
            .iter()
            .map(|&row| {
                let mut candidate = base;
                for (name, &value) in names.iter().zip(&samples.rows[row]) {
                    set_param(&mut candidate, name, value).map_err(input)?;
                }
                Ok(candidate)
            })
            .collect::<Result<Vec<_>, PredictiveError>>()?;

        let data = request.data.unwrap_or(&config.data);
        let dataset = Dataset::open(data).map_err(input)?;
        let mut selected: Vec<(Split, Target)> = Vec::new();
        for &split in request.splits {
            for id in dataset.ids(Some(split)) {
                let trajectory = dataset.load(&id).map_err(input)?;
                let target = Target::new(&trajectory, None, scene.disc.hold_at_recorded_start)
                    .map_err(input)?;
                selected.push((split, target));
            }
        }
        if selected.is_empty() {
            return Err(PredictiveError::NoTrajectory {
                data: data.to_path_buf(),
            });
        }
        Ok(Self {
            summary_path,
            samples_path,
            config_path,
            rows,
            candidates,
            splits: request.splits.to_vec(),
            selected,
            scene,
        })
    }

    /// Replays every draw on every selected recording in one batch (`observer` on the rollout)
    /// and bands each split's Table 1 over the draws.
    pub fn run(self, observer: &mut dyn Observer) -> Result<PredictiveSummary, PredictiveError> {
        let targets: Vec<Target> = self.selected.iter().map(|(_, t)| t.clone()).collect();
        let model = Arc::new(Model::new(&self.scene).map_err(input)?);
        let outcomes = rollout(&model, &targets, &self.candidates, observer)?;
        let selected = &self.selected;
        let per_draw: Vec<Vec<Table1Row>> = outcomes
            .iter()
            .map(|o| {
                self.splits
                    .iter()
                    .map(|&split| {
                        let losses: Vec<TrajectoryLoss> = selected
                            .iter()
                            .zip(o)
                            .filter(|((s, _), _)| *s == split)
                            .map(|(_, o)| o.loss.clone())
                            .collect();
                        Table1Row::from_losses(split.name(), &losses)
                    })
                    .collect()
            })
            .collect();
        let table1 = self
            .splits
            .iter()
            .enumerate()
            .map(|(row, &split)| {
                let healthy: Vec<&Table1Row> = outcomes
                    .iter()
                    .zip(&per_draw)
                    .filter(|(o, _)| {
                        selected
                            .iter()
                            .zip(o.iter())
                            .all(|((s, _), o)| *s != split || o.diverged.is_none())
                    })
                    .map(|(_, t)| &t[row])
                    .collect();
                let band = |f: &dyn Fn(&Table1Row) -> f64| {
                    Band::of(healthy.iter().map(|r| f(r)).collect())
                };
                PredictiveRow {
                    split: split.name().into(),
                    trajectories: per_draw[0][row].trajectories,
                    draws: healthy.len(),
                    diverged_draws: outcomes.len() - healthy.len(),
                    chamfer_mean_m: band(&|r| r.chamfer_m.mean),
                    chamfer_max_m: band(&|r| r.chamfer_m.max),
                    chamfer_std_m: band(&|r| r.chamfer_m.std),
                    object_mse_mean_m2: band(&|r| r.object_mse_m2.mean),
                    object_mse_max_m2: band(&|r| r.object_mse_m2.max),
                    object_mse_std_m2: band(&|r| r.object_mse_m2.std),
                }
            })
            .collect();
        Ok(PredictiveSummary {
            posterior: self.samples_path,
            config: self.config_path,
            draw_rows: self.rows,
            table1,
            per_draw,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bands_are_the_median_and_the_90_percent_quantiles() {
        let band = Band::of((0..=100).rev().map(f64::from).collect());
        for (got, expected) in [(band.low, 5.0), (band.median, 50.0), (band.high, 95.0)] {
            assert!((got - expected).abs() < 1e-9, "{got} for {expected}");
        }
        let none = Band::of(Vec::new());
        assert!(none.median.is_nan() && none.low.is_nan() && none.high.is_nan());
    }

    #[test]
    fn samples_without_their_summary_are_refused_naming_it() {
        let dir = tempfile::tempdir().unwrap();
        let samples = dir.path().join(SAMPLES_FILE);
        std::fs::write(&samples, "k_tri_e\n1000\n").unwrap();
        let request = PredictiveRequest {
            posterior: &samples,
            draws: 1,
            splits: &[Split::Test],
            data: None,
        };
        let err = PredictivePlan::new(&request)
            .err()
            .expect("refused")
            .to_string();
        assert!(
            err.contains("no summary.json beside it") && err.contains("--params"),
            "{err}"
        );
        let none = PredictiveRequest {
            draws: 0,
            ..request
        };
        assert!(PredictivePlan::new(&none).is_err());
    }
}
