//! `rlpkg eval --params <posterior summary.json or samples.csv>`: the posterior-predictive Table 1
//! ([`rlpkg_calib::predictive`]: the median and 90 % band of each Table 1 column over `--draws`
//! posterior draws replayed in one batch).

use std::path::Path;

use rlpkg_calib::predictive::{
    Band, PredictiveError, PredictivePlan, PredictiveRequest, PredictiveSummary,
};
use rlpkg_mocap::Split;

use crate::error::{input_error, output_error};
use crate::files::write_atomic;
use crate::interrupt::Interruptible;

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

/// Runs the posterior-predictive evaluation.
pub fn run(args: &PredictiveArgs) -> anyhow::Result<()> {
    if args.draws == 0 || args.draws > MAX_DRAWS {
        return Err(input_error(format!(
            "--draws {}: expected 1 to {MAX_DRAWS} posterior draws",
            args.draws
        )));
    }
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
    let plan = PredictivePlan::new(&PredictiveRequest {
        posterior: args.posterior,
        draws: args.draws,
        splits: &splits,
        data: args.data,
    })
    .map_err(|e| predictive_error(e, args.split))?;
    let out = args.out.map(Path::to_path_buf).unwrap_or_else(|| {
        plan.summary_path
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
    let _cooperation = crate::interrupt::Cooperation::start();
    let summary = plan
        .run(&mut Interruptible)
        .map_err(|e| predictive_error(e, args.split))?;
    let json = serde_json::to_string_pretty(&summary)?;
    write_atomic(&out.join("summary.json"), json.as_bytes()).map_err(output_error)?;
    if args.json {
        println!("{json}");
    } else {
        print_table(&summary, &out);
    }
    Ok(())
}

/// The user's (exit 2) when a file or value is (`split` is the `--split` given); a failed replay
/// is not.
fn predictive_error(err: PredictiveError, split: &str) -> anyhow::Error {
    match err {
        PredictiveError::Input(_) => input_error(err),
        PredictiveError::NoTrajectory { data } => input_error(format!(
            "{}: no trajectory in split {split}",
            data.display()
        )),
        PredictiveError::Replay(_) => anyhow::Error::new(err),
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
