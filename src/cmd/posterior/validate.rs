//! `rlpkg posterior CONFIG --validate N`: the posterior's draws checked on the simulator.
//!
//! `rlpkg posterior` samples the GP surrogate of the calibration loss; where the calibration's
//! evaluations are sparse, the surrogate can promise a fit the simulator does not give (and
//! packages no gripper carries). This replays `N` draws, evenly spaced through `samples.csv`,
//! with the calibration's own objective (its trajectories, their first `sim.max_seconds`, its loss
//! weights) and keeps those whose loss is within the posterior's likelihood threshold `ε`:
//! rejection with the surrogate posterior as the proposal, so the kept draws are that posterior
//! restricted to parameters that really fit the recordings. A draw that diverges is rejected.
//!
//! Writes, in `<posterior>/validated` (or `--out`): `samples.csv` (the kept draws, the format of
//! any posterior, so `randomization.package.posterior` and `eval --params` take the folder),
//! `summary.json` (the posterior's, with a `validation` block: threshold, counts and the kept
//! draws' 90 % intervals) and `replayed.csv` (every replayed draw: its row in the posterior's
//! `samples.csv`, its values, loss, Chamfer, object MSE and whether it was kept).

use std::path::{Path, PathBuf};

use rlpkg_calib::config::CalibrateConfig;
use rlpkg_calib::driver::{BatchObjective, CandidateResult};
use rlpkg_calib::objective::SimObjective;
use rlpkg_calib::posterior::{quantile, Evaluation};
use rlpkg_calib::posterior_files::{self, samples_csv, SAMPLES_FILE, SUMMARY_FILE};
use serde::Serialize;

use super::predictive::{evenly_spaced, read_samples, Interruptible};
use crate::cmd::calibrate::training_trajectories;
use crate::error::{input_error, output_error};
use crate::files::write_atomic;

/// Largest `--validate`: each draw replays every calibration trajectory.
pub const MAX_VALIDATE: u64 = 4096;

/// Draws replayed in one batched rollout (and between two progress lines).
const CHUNK: usize = 16;

/// The files `--validate` writes into its output folder.
const OUTPUT_FILES: [&str; 3] = [SAMPLES_FILE, SUMMARY_FILE, "replayed.csv"];

/// What `--validate` needs of the command line.
pub struct ValidateArgs<'a> {
    /// The calibration config the posterior was inferred for.
    pub config_path: &'a Path,
    /// Its parsed contents.
    pub config: CalibrateConfig,
    /// Folder of the posterior to validate.
    pub posterior: PathBuf,
    /// Output folder.
    pub out: PathBuf,
    /// Draws to replay.
    pub draws: usize,
    /// Threshold instead of the posterior's own `epsilon_loss`.
    pub epsilon_loss: Option<f64>,
}

/// One parameter of the kept draws.
#[derive(Debug, Serialize)]
struct KeptInterval {
    name: String,
    /// 5 % and 95 % quantiles of the kept draws (SI).
    interval: [f64; 2],
    /// `log10(high / low)`, for log parameters.
    interval_decades: Option<f64>,
}

/// The `validation` block of the output's `summary.json`.
#[derive(Debug, Serialize)]
struct Validation {
    /// The posterior folder whose draws were replayed.
    posterior: PathBuf,
    /// The loss a draw must not exceed to be kept.
    epsilon_loss: f64,
    /// Where that threshold came from.
    epsilon_from: &'static str,
    replayed: usize,
    kept: usize,
    diverged: usize,
    /// Replayed loss of the kept draws: lowest and median.
    kept_loss_min: Option<f64>,
    kept_loss_median: Option<f64>,
    /// Per parameter, the kept draws' 90 % interval (empty when none is kept).
    parameters: Vec<KeptInterval>,
}

/// Runs `--validate`.
pub fn run(args: ValidateArgs) -> anyhow::Result<()> {
    let summary_path = args.posterior.join(SUMMARY_FILE);
    let samples_path = args.posterior.join(SAMPLES_FILE);
    let mut summary = posterior_files::read_summary(&summary_path).map_err(|e| {
        input_error(format!(
            "{e}; --validate needs the {SUMMARY_FILE} and {SAMPLES_FILE} of an `rlpkg posterior` \
             folder"
        ))
    })?;
    let (epsilon_loss, epsilon_from) = match args.epsilon_loss {
        Some(loss) => (loss, "--epsilon-loss"),
        None => {
            let loss = summary["epsilon_loss"].as_f64().ok_or_else(|| {
                input_error(format!(
                    "{}: no `epsilon_loss` (the likelihood threshold `rlpkg posterior` records)",
                    summary_path.display()
                ))
            })?;
            (loss, "the posterior's epsilon_loss")
        }
    };
    if !(epsilon_loss > 0.0 && epsilon_loss.is_finite()) {
        return Err(input_error(format!(
            "threshold {epsilon_loss} ({epsilon_from}): expected a finite loss > 0"
        )));
    }
    let config = &args.config;
    let names: Vec<String> = config.params.iter().map(|p| p.name.clone()).collect();
    let samples = read_samples(&samples_path, &names)?;
    let rows = evenly_spaced(&samples_path, samples.len(), args.draws, "--validate")?;

    let (ids, trajectories) = training_trajectories(config)?;
    let scene = config.scene(args.config_path).map_err(input_error)?;
    let mut objective = SimObjective::new(
        &scene,
        names.clone(),
        &trajectories,
        config.loss,
        config.sim.max_seconds,
    )
    .map_err(input_error)?
    .with_observer(Box::new(Interruptible));
    println!(
        "replaying {} of {} posterior draws on {} trajectories ({}), {} draws per batch",
        rows.len(),
        samples.len(),
        ids.len(),
        config
            .sim
            .max_seconds
            .map_or("whole trajectories".to_string(), |s| format!(
                "first {s} s of each"
            )),
        CHUNK
    );
    let _cooperation = crate::interrupt::Cooperation::start();
    let mut results: Vec<CandidateResult> = Vec::with_capacity(rows.len());
    for chunk in rows.chunks(CHUNK) {
        let batch: Vec<Vec<f64>> = chunk.iter().map(|&r| samples[r].clone()).collect();
        let replayed = objective.evaluate(&batch).map_err(anyhow::Error::msg)?;
        if crate::interrupt::requested() {
            anyhow::bail!("interrupted: nothing written");
        }
        results.extend(replayed);
        let kept = results.iter().filter(|r| r.loss <= epsilon_loss).count();
        println!(
            "  {} of {} replayed, {kept} kept",
            results.len(),
            rows.len()
        );
    }

    let kept: Vec<usize> = (0..rows.len())
        .filter(|&i| results[i].loss <= epsilon_loss)
        .collect();
    let kept_draws: Vec<Vec<f64>> = kept.iter().map(|&i| samples[rows[i]].clone()).collect();
    let mut kept_losses: Vec<f64> = kept.iter().map(|&i| results[i].loss).collect();
    kept_losses.sort_by(f64::total_cmp);
    let parameters = if kept_draws.is_empty() {
        Vec::new()
    } else {
        config
            .params
            .iter()
            .enumerate()
            .map(|(k, p)| {
                let mut values: Vec<f64> = kept_draws.iter().map(|d| d[k]).collect();
                values.sort_by(f64::total_cmp);
                let interval = [quantile(&values, 0.05), quantile(&values, 0.95)];
                KeptInterval {
                    name: p.name.clone(),
                    interval,
                    interval_decades: p.log.then(|| (interval[1] / interval[0]).log10()),
                }
            })
            .collect()
    };
    let validation = Validation {
        posterior: args.posterior.clone(),
        epsilon_loss,
        epsilon_from,
        replayed: rows.len(),
        kept: kept.len(),
        diverged: results.iter().filter(|r| !r.loss.is_finite()).count(),
        kept_loss_min: kept_losses.first().copied(),
        kept_loss_median: (!kept_losses.is_empty()).then(|| quantile(&kept_losses, 0.5)),
        parameters,
    };
    summary["validation"] = serde_json::to_value(&validation)?;

    let mut replayed_csv = replayed_header(&names) + "\n";
    for (i, (&row, r)) in rows.iter().zip(&results).enumerate() {
        replayed_csv.push_str(&format!(
            "{row},{},{},{},{},{}\n",
            join(&samples[row]),
            r.loss,
            r.chamfer_m,
            r.object_mse_m2,
            kept.binary_search(&i).is_ok()
        ));
    }
    std::fs::create_dir_all(&args.out).map_err(|e| {
        input_error(format!(
            "{}: cannot create the output folder: {e}",
            args.out.display()
        ))
    })?;
    for (file, text) in OUTPUT_FILES.iter().zip([
        samples_csv(&config.space(), &kept_draws),
        serde_json::to_string_pretty(&summary)?,
        replayed_csv,
    ]) {
        write_atomic(&args.out.join(file), text.as_bytes()).map_err(output_error)?;
    }
    print_table(&validation, &summary, &args.out);
    Ok(())
}

/// Largest `replayed.csv` read back (bytes), checked before reading.
const MAX_REPLAYED_BYTES: u64 = 64 << 20;

/// The header of `replayed.csv` for parameters `names`.
fn replayed_header(names: &[String]) -> String {
    format!("row,{},loss,chamfer_m,object_mse_m2,kept", names.join(","))
}

/// The draws of a `replayed.csv` as evaluations of `config`'s parameters (a diverged replay is a
/// failed evaluation), so that `rlpkg posterior --replays` fits its surrogate to them as well.
pub fn read_replayed(path: &Path, config: &CalibrateConfig) -> anyhow::Result<Vec<Evaluation>> {
    let size = std::fs::metadata(path)
        .map_err(|e| input_error(format!("{}: {e}", path.display())))?
        .len();
    if size > MAX_REPLAYED_BYTES {
        return Err(input_error(format!(
            "{}: {size} bytes; expected a replayed.csv of `rlpkg posterior --validate` (at most {} MiB)",
            path.display(),
            MAX_REPLAYED_BYTES >> 20
        )));
    }
    let text = std::fs::read_to_string(path)
        .map_err(|e| input_error(format!("{}: {e}", path.display())))?;
    let names: Vec<String> = config.params.iter().map(|p| p.name.clone()).collect();
    let header = replayed_header(&names);
    let mut lines = text.lines();
    let first = lines.next().unwrap_or("");
    if first != header {
        return Err(input_error(format!(
            "{}: header `{first}`; expected `{header}` (a replayed.csv of `rlpkg posterior \
             --validate` for the parameters of this config)",
            path.display()
        )));
    }
    lines
        .enumerate()
        .map(|(i, line)| {
            let at = || format!("{}: line {}", path.display(), i + 2);
            let cells: Vec<&str> = line.split(',').map(str::trim).collect();
            if cells.len() != names.len() + 5 {
                return Err(input_error(format!(
                    "{}: {} cells; expected {}",
                    at(),
                    cells.len(),
                    names.len() + 5
                )));
            }
            let mut params = Vec::with_capacity(names.len());
            for (p, cell) in config.params.iter().zip(&cells[1..=names.len()]) {
                match cell.parse::<f64>() {
                    Ok(v) if (p.lower..=p.upper).contains(&v) => params.push(v),
                    _ => {
                        return Err(input_error(format!(
                            "{}: {} = `{cell}`; expected a number within [{:e}, {:e}]",
                            at(),
                            p.name,
                            p.lower,
                            p.upper
                        )))
                    }
                }
            }
            let loss = cells[names.len() + 1].parse::<f64>().map_err(|_| {
                input_error(format!(
                    "{}: loss = `{}`; expected a number (NaN or inf for a diverged replay)",
                    at(),
                    cells[names.len() + 1]
                ))
            })?;
            Ok(Evaluation { params, loss })
        })
        .collect()
}

/// `values` as `samples_csv` writes a draw.
fn join(values: &[f64]) -> String {
    values
        .iter()
        .map(f64::to_string)
        .collect::<Vec<_>>()
        .join(",")
}

fn print_table(v: &Validation, summary: &serde_json::Value, out: &Path) {
    println!(
        "kept {} of {} replayed draws ({:.1} %) with loss <= {:.4e} ({}); {} diverged",
        v.kept,
        v.replayed,
        100.0 * v.kept as f64 / v.replayed as f64,
        v.epsilon_loss,
        v.epsilon_from,
        v.diverged
    );
    if let (Some(min), Some(median)) = (v.kept_loss_min, v.kept_loss_median) {
        println!("kept draws' loss: lowest {min:.4e}, median {median:.4e}");
    }
    if !v.parameters.is_empty() {
        println!();
        println!(
            "{:<16} {:<25} {:>13}  {:<25} {:>13}",
            "parameter", "surrogate 90 % interval", "width", "kept 90 % interval", "width"
        );
        let width = |decades: Option<f64>, interval: [f64; 2]| match decades {
            Some(d) => format!("{d:.2} decades"),
            None => format!("{:.3e}", interval[1] - interval[0]),
        };
        for (p, s) in v.parameters.iter().zip(
            summary["parameters"]
                .as_array()
                .map(Vec::as_slice)
                .unwrap_or(&[]),
        ) {
            let surrogate = [
                s["interval"][0].as_f64().unwrap_or(f64::NAN),
                s["interval"][1].as_f64().unwrap_or(f64::NAN),
            ];
            println!(
                "{:<16} [{:>9.3e}, {:>9.3e}] {:>13}  [{:>9.3e}, {:>9.3e}] {:>13}",
                p.name,
                surrogate[0],
                surrogate[1],
                width(s["interval_decades"].as_f64(), surrogate),
                p.interval[0],
                p.interval[1],
                width(p.interval_decades, p.interval),
            );
        }
    }
    println!("wrote {}/{{{}}}", out.display(), OUTPUT_FILES.join(", "));
}
