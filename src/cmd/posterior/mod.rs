//! `rlpkg posterior <config.toml>`: an approximate posterior over a calibration's parameters from
//! its `evaluations.csv` (crate `rlpkg-calib`, module `posterior`), without new simulations.
//!
//! Writes `samples.csv` (one row per draw, SI values), `summary.json` (the calibration config it
//! came from; per parameter: median, 90 % interval, profile, identified; the threshold, the
//! sampler's figures) and `profiles.csv` (the surrogate loss along each parameter), and prints the
//! identifiability table.
//!
//! - [`recover`]: `rlpkg posterior CONFIG --recover K`, the parameter-recovery table;
//! - [`validate`]: `rlpkg posterior CONFIG --validate N`, the draws replayed on the simulator and
//!   kept where they fit;
//! - [`spread`]: `rlpkg posterior CONFIG --spread NUDGE`, how far the replays move under a nudge
//!   of the parameters far below what the recordings resolve.

mod recover;
mod spread;
mod validate;

use std::path::{Path, PathBuf};

use clap::Args;
use rlpkg_calib::config::CalibrateConfig;
use rlpkg_calib::posterior::{self, Posterior, PosteriorError, PosteriorSettings, Threshold};
use rlpkg_calib::posterior_files::{self, SAMPLES_FILE, SUMMARY_FILE};

use crate::error::{input_error, output_error};
use crate::files::write_atomic;

/// Arguments of `rlpkg posterior`.
#[derive(Args, Debug)]
pub struct PosteriorArgs {
    /// Calibration config (TOML) whose parameter box is the prior, e.g. configs/calibrate/soft-film.toml.
    pub config: PathBuf,
    /// Calibration folder holding `evaluations.csv` [default: the config's `out_dir`].
    #[arg(long, value_name = "DIR")]
    pub from: Option<PathBuf>,
    /// Output folder [default: `posterior` in the calibration folder].
    #[arg(long, value_name = "DIR")]
    pub out: Option<PathBuf>,
    /// Seed of the surrogate fit and the sampler.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Posterior draws to write.
    #[arg(long, value_name = "N", default_value_t = 4000,
          value_parser = clap::value_parser!(u64).range(1..=1_000_000))]
    pub samples: u64,
    /// Likelihood threshold: this quantile of the finite losses in the log.
    #[arg(
        long,
        value_name = "Q",
        default_value_t = 0.1,
        conflicts_with = "epsilon_loss"
    )]
    pub epsilon_quantile: f64,
    /// Likelihood threshold as a loss instead (e.g. 1.1 x the best loss).
    #[arg(long, value_name = "LOSS")]
    pub epsilon_loss: Option<f64>,
    /// Sampler steps discarded at the start (at most one million).
    #[arg(long, value_name = "N", default_value_t = 1000,
          value_parser = clap::value_parser!(u64).range(0..=1_000_000))]
    pub burn_in: u64,
    /// Keep every N-th sampler step.
    #[arg(long, value_name = "N", default_value_t = 10,
          value_parser = clap::value_parser!(u64).range(1..=10_000))]
    pub thin: u64,
    /// Parameter recovery instead: calibrate synthetic recordings of K known parameter sets
    /// (drawn from the middle of the box) back with the config's optimiser and report how the
    /// posterior recovers them; writes to `<out_dir>/recovery` unless --out is given.
    #[arg(long, value_name = "K", conflicts_with = "from",
          value_parser = clap::value_parser!(u64).range(1..=100))]
    pub recover: Option<u64>,
    /// Recovery: synthesise only these recorded trajectories, comma-separated [default: the
    /// config's list or the train split].
    #[arg(long, value_delimiter = ',', value_name = "IDS", requires = "recover")]
    pub trajectories: Vec<String>,
    /// Recovery: compare only the first S seconds [default: the config's `sim.max_seconds`].
    #[arg(long, value_name = "S", requires = "recover")]
    pub max_seconds: Option<f64>,
    /// Recovery: batches after the initial design [default: the config's `optimiser.iterations`].
    #[arg(long, value_name = "N", requires = "recover",
          value_parser = clap::value_parser!(u64).range(1..=100_000))]
    pub iterations: Option<u64>,
    /// Validate an existing posterior instead: replay N of its draws with the calibration's
    /// objective and keep those within the likelihood threshold (the posterior's own, or
    /// --epsilon-loss); writes to `<posterior>/validated` unless --out is given.
    #[arg(long, value_name = "N", conflicts_with = "recover",
          value_parser = clap::value_parser!(u64).range(1..=validate::MAX_VALIDATE))]
    pub validate: Option<u64>,
    /// Fit the surrogate to these `replayed.csv` files of earlier `--validate` runs as well as to
    /// the calibration's evaluations (comma-separated): the replays, diverged ones included, tell
    /// it where the simulator does not fit.
    #[arg(long, value_delimiter = ',', value_name = "FILES", conflicts_with_all = ["recover", "validate"])]
    pub replays: Vec<PathBuf>,
    /// The simulator's own sensitivity instead: replay the config's recordings at its scene's
    /// values with each parameter, then all of them, scaled by 1 + NUDGE (e.g. 1e-6), and print
    /// how far the marker sites move beside the recordings' marker noise.
    #[arg(long, value_name = "NUDGE", conflicts_with_all = ["recover", "validate", "from", "replays"])]
    pub spread: Option<f64>,
    /// Validation: the posterior folder [default: `posterior` in the calibration folder].
    #[arg(long, value_name = "DIR", requires = "validate")]
    pub posterior: Option<PathBuf>,
}

/// The hidden folder inside the output folder the posterior's files are staged in.
const STAGING_PREFIX: &str = ".posterior-";

/// The files `rlpkg posterior` writes into its output folder.
const OUTPUT_FILES: [&str; 3] = [SAMPLES_FILE, SUMMARY_FILE, "profiles.csv"];

/// Runs `rlpkg posterior`.
pub fn run(args: PosteriorArgs) -> anyhow::Result<()> {
    let config = CalibrateConfig::load(&args.config).map_err(input_error)?;
    let threshold = threshold(&args)?;
    let space = config.space();
    let settings = PosteriorSettings {
        threshold,
        draws: args.samples as usize,
        burn_in: args.burn_in as usize,
        thin: args.thin as usize,
        seed: args.seed,
        ..PosteriorSettings::default()
    };
    if let Some(nudge) = args.spread {
        return spread::run(&args, config, nudge);
    }
    if let Some(truths) = args.recover {
        return recover::run(&args, config, truths as usize, settings);
    }
    if config.smc.is_some() {
        return Err(input_error(format!(
            "{}: samples its posterior on the simulator ([smc]): `rlpkg calibrate` writes its \
             samples.csv, posterior.toml and fisher.toml; `rlpkg posterior` infers one from a \
             Bayesian optimisation's evaluations ([optimiser])",
            args.config.display()
        )));
    }
    let calibration = args.from.clone().unwrap_or(config.out_dir.clone());
    if let Some(draws) = args.validate {
        let posterior = args
            .posterior
            .clone()
            .unwrap_or(calibration.join("posterior"));
        return validate::run(validate::ValidateArgs {
            config_path: &args.config,
            config,
            out: args.out.clone().unwrap_or(posterior.join("validated")),
            posterior,
            draws: draws as usize,
            epsilon_loss: args.epsilon_loss,
        });
    }
    let log_path = calibration.join("evaluations.csv");
    let mut evaluations = posterior::read_evaluations(&log_path, &space)
        .map_err(|e| input_error(format!("{e} (parameters of {})", args.config.display())))?;
    for path in &args.replays {
        let replayed = rlpkg_calib::validation::read_replayed(path, &config)
            .map_err(validate::validation_error)?;
        println!(
            "with {} replayed draws of {}",
            replayed.len(),
            path.display()
        );
        evaluations.extend(replayed);
    }
    check_threshold_below_worst(&args, &evaluations, &log_path)?;
    let result = posterior::infer(&space, &evaluations, &settings).map_err(|e| match e {
        // A threshold the log cannot meet is the option's: name it first.
        PosteriorError::Setting(_) if args.epsilon_loss.is_some() => input_error(format!(
            "--epsilon-loss {:?}: {}: {e}",
            args.epsilon_loss.unwrap_or_default(),
            log_path.display()
        )),
        PosteriorError::TooFew { .. } | PosteriorError::Setting(_) => {
            input_error(format!("{}: {e}", log_path.display()))
        }
        other => anyhow::Error::new(other),
    })?;

    // One command at a time in the output folder; its files are staged and moved into place
    // together, the summary last, so that a folder with a summary holds the whole posterior.
    let out = args.out.clone().unwrap_or(calibration.join("posterior"));
    let _lock = crate::files::lock_folder(&out, true)?;
    for path in crate::files::remove_staging_leftovers(&out, STAGING_PREFIX)? {
        eprintln!("removed the leftover staging folder {}", path.display());
    }
    let staging = crate::files::Staging::new(&out, STAGING_PREFIX)?;
    let summary =
        posterior_files::summary_json(&args.config, &calibration, &args.replays, &result.summary)?;
    for (file, text) in OUTPUT_FILES.iter().zip([
        posterior_files::samples_csv(&space, &result.draws),
        summary,
        posterior::profiles_csv(&result.profiles),
    ]) {
        write_atomic(&staging.path(file), text.as_bytes()).map_err(output_error)?;
    }
    staging.place(&[SAMPLES_FILE, "profiles.csv", SUMMARY_FILE])?;
    print_table(&result, &log_path, &out);
    Ok(())
}

/// An `--epsilon-loss` at or above every finite loss of the log keeps every evaluation: the
/// posterior would be the prior's box, said as if it were inferred.
fn check_threshold_below_worst(
    args: &PosteriorArgs,
    evaluations: &[posterior::Evaluation],
    log_path: &Path,
) -> anyhow::Result<()> {
    let Some(loss) = args.epsilon_loss else {
        return Ok(());
    };
    let worst = evaluations
        .iter()
        .map(|e| e.loss)
        .filter(|l| l.is_finite() && *l > 0.0)
        .fold(f64::NAN, f64::max);
    if worst.is_finite() && loss >= worst {
        return Err(input_error(format!(
            "--epsilon-loss {loss:?}: {}: every evaluation is within it (the worst finite loss \
             is {worst:.6e}), so the posterior would be the prior's box; expected a loss below \
             {worst:.6e}",
            log_path.display()
        )));
    }
    Ok(())
}

/// The threshold from `--epsilon-quantile` or `--epsilon-loss`, range-checked.
fn threshold(args: &PosteriorArgs) -> anyhow::Result<Threshold> {
    if let Some(loss) = args.epsilon_loss {
        if !(loss > 0.0 && loss.is_finite()) {
            return Err(input_error(format!(
                "--epsilon-loss {loss}: expected a finite loss > 0"
            )));
        }
        return Ok(Threshold::Loss(loss));
    }
    let q = args.epsilon_quantile;
    if !(q > 0.0 && q < 1.0) {
        return Err(input_error(format!(
            "--epsilon-quantile {q}: expected a quantile in (0, 1)"
        )));
    }
    Ok(Threshold::Quantile(q))
}

fn print_table(result: &Posterior, log_path: &Path, out: &Path) {
    let s = &result.summary;
    println!(
        "posterior of {} parameter(s) from {} evaluations ({} failed) in {}",
        s.parameters.len(),
        s.evaluations,
        s.failed,
        log_path.display()
    );
    println!(
        "likelihood threshold: loss {:.4e} ({}; best loss {:.4e}); surrogate noise std {:.3} in ln(loss)",
        s.epsilon_loss, s.epsilon_rule, s.best_loss, s.noise_std_ln_loss
    );
    println!(
        "{} draws of {} walkers (burn-in {}, thin {}), acceptance {:.2}, seed {}",
        s.draws, s.walkers, s.burn_in, s.thin, s.acceptance, s.seed
    );
    if s.acceptance < 0.1 {
        println!("warning: low acceptance; a longer --burn-in or a larger --thin gives better-mixed draws");
    }
    println!();
    println!(
        "{:<16} {:<6} {:>10} {:>10}  {:<23} {:>13} {:>6} {:>9} {:>9}  identified",
        "parameter",
        "scale",
        "best",
        "median",
        "90 % interval",
        "width",
        "range",
        "profile",
        "curvature"
    );
    for p in &s.parameters {
        let width = match p.interval_decades {
            Some(decades) => format!("{decades:.2} decades"),
            None => format!("{:.3e}", p.interval[1] - p.interval[0]),
        };
        println!(
            "{:<16} {:<6} {:>10.3e} {:>10.3e}  [{:>9.3e}, {:>9.3e}] {:>13} {:>5.0}% {:>8.3}x {:>9.3}  {}",
            p.name,
            if p.log { "log" } else { "linear" },
            p.best,
            p.median,
            p.interval[0],
            p.interval[1],
            width,
            100.0 * p.prior_fraction,
            p.profile_ratio,
            p.profile_curvature,
            if p.identified { "yes" } else { "no" }
        );
    }
    println!();
    println!("{}", posterior::IDENTIFIED_RULE);
    println!(
        "range: share of the search range the interval covers; profile: highest / lowest surrogate \
         loss along the parameter; curvature: of ln(loss) at the profile's lowest point, per decade^2 \
         (log) or per search range^2 (linear)"
    );
    println!();
    println!("loss profiles (surrogate loss / its lowest value, lower bound to upper bound, every other grid value; log-spaced for log parameters):");
    for profile in &result.profiles {
        let lowest = profile
            .surrogate_loss
            .iter()
            .copied()
            .fold(f64::INFINITY, f64::min);
        let cells: Vec<String> = profile
            .surrogate_loss
            .iter()
            .step_by(2)
            .map(|l| {
                if l.is_finite() {
                    format!("{:>5.2}", l / lowest)
                } else {
                    "  inf".to_string()
                }
            })
            .collect();
        println!("{:<16} {}", profile.name, cells.join(" "));
    }
    println!("wrote {}/{{{}}}", out.display(), OUTPUT_FILES.join(", "));
}
