//! `rlpkg eval --params <posterior summary.json or samples.csv>`: the posterior-predictive Table 1.
//!
//! The same Table 1 as `eval --params <scene.toml>`, computed for `--draws` posterior draws (evenly
//! spaced through `samples.csv`) in one batched replay of the whole recordings (draws x
//! trajectories environments), and reported per column as the median and the 90 % band (5 % and
//! 95 % quantiles) over the draws. A draw that diverges on a trajectory is counted and left out of
//! the bands: its Table 1 would only cover the frames before the divergence.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use rlpkg_calib::posterior::quantile;
use rlpkg_calib::posterior_files::{self, Samples, SAMPLES_FILE, SUMMARY_FILE};
use rlpkg_mocap::{Dataset, Split};
use rlpkg_replay::loss::{Table1Row, TrajectoryLoss};
use rlpkg_replay::{rollout, set_param, Candidate, Observer, Target};
use rlpkg_sim::Model;
use serde::Serialize;

use crate::error::{input_error, output_error};
use crate::files::write_atomic;

/// The rows of the `samples.csv` at `path`, whose columns must be the calibration's `names`.
pub fn read_samples(path: &Path, names: &[String]) -> anyhow::Result<Vec<Vec<f64>>> {
    let samples = Samples::read(path).map_err(input_error)?;
    samples.expect_columns(path, names).map_err(input_error)?;
    Ok(samples.rows)
}

/// Largest `--draws`: each draw replays every selected trajectory.
const MAX_DRAWS: usize = 256;

/// What `eval --params` needs of its arguments for a posterior.
pub struct PredictiveArgs<'a> {
    /// `summary.json` or `samples.csv` of an `rlpkg posterior` folder.
    pub posterior: &'a Path,
    /// Draws to replay.
    pub draws: usize,
    /// `train`, `test` or `all`.
    pub split: &'a str,
    /// Dataset folder [default: the calibration config's `data`].
    pub data: Option<&'a Path>,
    /// Output folder.
    pub out: Option<&'a Path>,
    /// Print JSON instead of the table.
    pub json: bool,
}

/// Median and 90 % band of one Table 1 column over the draws.
#[derive(Debug, Clone, Copy, Serialize)]
struct Band {
    median: f64,
    low: f64,
    high: f64,
}

impl Band {
    fn of(mut values: Vec<f64>) -> Self {
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
struct PredictiveRow {
    split: String,
    trajectories: usize,
    /// Draws in the bands (those that diverged on no trajectory of the split).
    draws: usize,
    diverged_draws: usize,
    chamfer_mean_m: Band,
    chamfer_max_m: Band,
    chamfer_std_m: Band,
    object_mse_mean_m2: Band,
    object_mse_max_m2: Band,
    object_mse_std_m2: Band,
}

#[derive(Serialize)]
struct PredictiveSummary {
    posterior: PathBuf,
    config: PathBuf,
    /// Indices (rows of `samples.csv`, from 0) of the replayed draws.
    draw_rows: Vec<usize>,
    table1: Vec<PredictiveRow>,
    /// Per draw, its Table 1 (one row per split).
    per_draw: Vec<Vec<Table1Row>>,
}

/// Runs the posterior-predictive evaluation.
pub fn run(args: &PredictiveArgs) -> anyhow::Result<()> {
    if args.draws == 0 || args.draws > MAX_DRAWS {
        return Err(input_error(format!(
            "--draws {}: expected 1 to {MAX_DRAWS} posterior draws",
            args.draws
        )));
    }
    let files = posterior_files::locate(args.posterior).map_err(input_error)?;
    let samples_path = files.samples;
    let summary_path = files.summary.ok_or_else(|| {
        input_error(format!(
            "{}: no {SUMMARY_FILE} beside it; --params {} needs the {SUMMARY_FILE} and \
             {SAMPLES_FILE} that `rlpkg posterior` writes side by side",
            samples_path.display(),
            args.posterior.display()
        ))
    })?;
    let (config_path, config) =
        posterior_files::recorded_calibration(&summary_path).map_err(input_error)?;
    let names: Vec<String> = config.params.iter().map(|p| p.name.clone()).collect();
    let samples = read_samples(&samples_path, &names)?;
    let rows = evenly_spaced(&samples_path, samples.len(), args.draws, "--draws")?;
    let scene = config.scene(&config_path).map_err(input_error)?;
    let base = Candidate::of_scene(&scene);
    let candidates = rows
        .iter()
        .map(|&row| {
            let mut candidate = base;
            for (name, &value) in names.iter().zip(&samples[row]) {
                set_param(&mut candidate, name, value).map_err(input_error)?;
            }
            Ok(candidate)
        })
        .collect::<anyhow::Result<Vec<_>>>()?;

    let splits: Vec<Split> = match args.split {
        "train" => vec![Split::Train],
        "test" => vec![Split::Test],
        "all" => vec![Split::Train, Split::Test],
        other => {
            return Err(input_error(format!(
                "--split {other}: expected train, test or all"
            )))
        }
    };
    let data = args.data.unwrap_or(&config.data);
    let dataset = Dataset::open(data).map_err(input_error)?;
    let mut selected: Vec<(Split, Target)> = Vec::new();
    for &split in &splits {
        for id in dataset.ids(Some(split)) {
            let trajectory = dataset.load(&id).map_err(input_error)?;
            let target = Target::new(&trajectory, None, scene.disc.hold_at_recorded_start)
                .map_err(input_error)?;
            selected.push((split, target));
        }
    }
    if selected.is_empty() {
        return Err(input_error(format!(
            "{}: no trajectory in split {}",
            data.display(),
            args.split
        )));
    }
    let out = args.out.map(Path::to_path_buf).unwrap_or_else(|| {
        summary_path
            .parent()
            .unwrap_or(Path::new("."))
            .join(format!("eval-{}", args.split))
    });
    std::fs::create_dir_all(&out).map_err(|e| {
        input_error(format!(
            "{}: cannot create the output folder: {e}",
            out.display()
        ))
    })?;

    let targets: Vec<Target> = selected.iter().map(|(_, t)| t.clone()).collect();
    let model = Arc::new(Model::new(&scene).map_err(input_error)?);
    let _cooperation = crate::interrupt::Cooperation::start();
    let outcomes = rollout(&model, &targets, &candidates, &mut Interruptible)?;

    let per_draw: Vec<Vec<Table1Row>> = outcomes
        .iter()
        .map(|o| {
            splits
                .iter()
                .map(|&split| {
                    let losses: Vec<TrajectoryLoss> = selected
                        .iter()
                        .zip(o)
                        .filter(|((s, _), _)| *s == split)
                        .map(|(_, o)| o.loss.clone())
                        .collect();
                    Table1Row::from_losses(split_name(split), &losses)
                })
                .collect()
        })
        .collect();
    let table1 = splits
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
            let band =
                |f: &dyn Fn(&Table1Row) -> f64| Band::of(healthy.iter().map(|r| f(r)).collect());
            PredictiveRow {
                split: split_name(split).into(),
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
    let summary = PredictiveSummary {
        posterior: samples_path.clone(),
        config: config_path,
        draw_rows: rows,
        table1,
        per_draw,
    };
    let json = serde_json::to_string_pretty(&summary)?;
    write_atomic(&out.join("summary.json"), json.as_bytes()).map_err(output_error)?;
    if args.json {
        println!("{json}");
    } else {
        print_table(&summary, &out);
    }
    Ok(())
}

/// `draws` rows evenly spaced through the `available` rows of `samples_path`, refused naming
/// `flag` when there are fewer.
pub fn evenly_spaced(
    samples_path: &Path,
    available: usize,
    draws: usize,
    flag: &str,
) -> anyhow::Result<Vec<usize>> {
    if available < draws {
        return Err(input_error(format!(
            "{}: {available} draws; expected at least {flag} {draws}",
            samples_path.display()
        )));
    }
    Ok((0..draws).map(|i| i * available / draws).collect())
}

fn split_name(split: Split) -> &'static str {
    match split {
        Split::Train => "train",
        Split::Test => "test",
        Split::Excluded => "excluded",
    }
}

fn print_table(s: &PredictiveSummary, out: &Path) {
    println!(
        "posterior-predictive Table 1: {} draws of {} (config {}); median [5 %, 95 %] over the draws",
        s.draw_rows.len(),
        s.posterior.display(),
        s.config.display()
    );
    let cell = |b: &Band, precision: usize| {
        if precision == 0 {
            format!("{:.3e} [{:.3e}, {:.3e}]", b.median, b.low, b.high)
        } else {
            format!("{:.5} [{:.5}, {:.5}]", b.median, b.low, b.high)
        }
    };
    for r in &s.table1 {
        println!(
            "{} ({} trajectories; {} draws, {} diverged and left out):",
            r.split, r.trajectories, r.draws, r.diverged_draws
        );
        println!("  CD mean m      {}", cell(&r.chamfer_mean_m, 5));
        println!("  CD max m       {}", cell(&r.chamfer_max_m, 5));
        println!("  CD std m       {}", cell(&r.chamfer_std_m, 5));
        println!("  MSE mean m2    {}", cell(&r.object_mse_mean_m2, 0));
        println!("  MSE max m2     {}", cell(&r.object_mse_max_m2, 0));
        println!("  MSE std m2     {}", cell(&r.object_mse_std_m2, 0));
    }
    println!("wrote {}/summary.json", out.display());
}

/// Lets Ctrl-C stop a replay.
pub(super) struct Interruptible;

impl Observer for Interruptible {
    fn stop(&mut self) -> bool {
        crate::interrupt::requested()
    }
}
