//! `rlpkg posterior CONFIG --validate N`: the posterior's draws checked on the simulator
//! ([`rlpkg_calib::validation`]: `N` draws evenly spaced through `samples.csv` replayed with the
//! calibration's own objective, kept where their loss is within the likelihood threshold).
//!
//! Writes, in `<posterior>/validated` (or `--out`): `samples.csv` (the kept draws), `summary.json`
//! (the posterior's, with a `validation` block) and `replayed.csv` (every replayed draw).

use std::ops::ControlFlow;
use std::path::{Path, PathBuf};

use rlpkg_calib::config::CalibrateConfig;
use rlpkg_calib::posterior_files::{SAMPLES_FILE, SUMMARY_FILE};
use rlpkg_calib::validation::{
    Validation, ValidationError, ValidationPlan, ValidationRequest, DRAWS_PER_BATCH, REPLAYED_FILE,
};

use crate::error::{input_error, output_error};
use crate::files::write_atomic;
use crate::interrupt::Interruptible;

/// Largest `--validate`: each draw replays every calibration trajectory.
pub const MAX_VALIDATE: u64 = 4096;

/// The files `--validate` writes into its output folder.
const OUTPUT_FILES: [&str; 3] = [SAMPLES_FILE, SUMMARY_FILE, REPLAYED_FILE];

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

/// Runs `--validate`.
pub fn run(args: ValidateArgs) -> anyhow::Result<()> {
    let config = &args.config;
    let plan = ValidationPlan::new(
        &ValidationRequest {
            config,
            config_path: args.config_path,
            posterior: &args.posterior,
            draws: args.draws,
            draws_option: "--validate",
            threshold: args.epsilon_loss.map(|loss| (loss, "--epsilon-loss")),
        },
        Box::new(Interruptible),
    )
    .map_err(validation_error)?;
    println!(
        "replaying {} of {} posterior draws on {} trajectories ({}), {} draws per batch",
        plan.rows.len(),
        plan.available,
        plan.trajectory_ids.len(),
        config
            .sim
            .max_seconds
            .map_or("whole trajectories".to_string(), |s| format!(
                "first {s} s of each"
            )),
        DRAWS_PER_BATCH
    );
    let _cooperation = crate::interrupt::Cooperation::start();
    let validated = plan
        .run(|replayed, total, kept| {
            if crate::interrupt::requested() {
                return ControlFlow::Break(());
            }
            println!("  {replayed} of {total} replayed, {kept} kept");
            ControlFlow::Continue(())
        })
        .map_err(validation_error)?;

    std::fs::create_dir_all(&args.out).map_err(|e| {
        input_error(format!(
            "{}: cannot create the output folder: {e}",
            args.out.display()
        ))
    })?;
    for (file, text) in OUTPUT_FILES.iter().zip([
        validated.samples_csv.clone(),
        serde_json::to_string_pretty(&validated.summary)?,
        validated.replayed_csv.clone(),
    ]) {
        write_atomic(&args.out.join(file), text.as_bytes()).map_err(output_error)?;
    }
    print_table(&validated.validation, &validated.summary, &args.out);
    Ok(())
}

/// The user's (exit 2) when a file or value is; a failed replay is not, and a stop is an
/// interruption with nothing written.
pub fn validation_error(err: ValidationError) -> anyhow::Error {
    match err {
        ValidationError::Input(_) => input_error(err),
        ValidationError::Stopped => anyhow::anyhow!("interrupted: nothing written"),
        ValidationError::Replay(_) | ValidationError::Json(_) => {
            anyhow::Error::msg(err.to_string())
        }
    }
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
