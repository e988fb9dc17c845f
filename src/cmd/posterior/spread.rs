//! `rlpkg posterior CONFIG --spread NUDGE`: how far the calibration's replays move when its
//! parameters are nudged far below what the recordings can tell apart
//! ([`SimObjective::spread`](rlpkg_calib::objective::SimObjective::spread)), beside the
//! recordings' marker noise. A spread near the noise means the loss is rough at the scale the
//! likelihood resolves: the scene is not fit for calibration at that solver setting.

use rlpkg_calib::config::CalibrateConfig;
use rlpkg_calib::objective::SimObjective;
use rlpkg_replay::synthetic::marker_noise_std;

use super::PosteriorArgs;
use crate::cmd::calibrate::training_trajectories;
use crate::error::input_error;

/// Nudges up to this size are far below what a recording resolves: their spread says whether the
/// loss is smooth.
const ROUGHNESS_NUDGE: f64 = 1e-5;

/// Runs the spread check of `config` at its scene's own parameter values.
pub fn run(args: &PosteriorArgs, config: CalibrateConfig, nudge: f64) -> anyhow::Result<()> {
    if !(nudge > 0.0 && nudge < 1.0) {
        return Err(input_error(format!(
            "--spread {nudge}: expected a relative nudge in (0, 1), e.g. 1e-6"
        )));
    }
    let (ids, trajectories) = training_trajectories(&config)?;
    let scene = config.scene(&args.config).map_err(input_error)?;
    let names: Vec<String> = config.params.iter().map(|p| p.name.clone()).collect();
    let objective = SimObjective::new(
        &scene,
        names,
        &trajectories,
        config.loss,
        config.sim.max_seconds,
    )
    .map_err(input_error)?;
    let noise: Vec<f64> = objective
        .targets()
        .iter()
        .filter_map(marker_noise_std)
        .collect();
    println!(
        "replays of {} ({}) at the scene's own values, each parameter and then all of them x (1 + {nudge:e}); \
         solver {:?}, {} iterations per substep at {} substeps/s",
        ids.join(", "),
        config
            .sim
            .max_seconds
            .map_or("whole".to_string(), |s| format!("first {s} s")),
        scene.integrator.solver,
        scene.integrator.iterations,
        scene.integrator.substep_rate_hz
    );
    let spreads = objective
        .spread(&objective.base_values(), nudge)
        .map_err(input_error)?;
    println!();
    println!(
        "{:<16} {:>10} {:>10} {:>10} {:>12}",
        "nudged", "median mm", "p90 mm", "max mm", "disc max mm"
    );
    for s in &spreads {
        println!(
            "{:<16} {:>10.4} {:>10.4} {:>10.4} {:>12.4}",
            s.parameter,
            1e3 * s.median_m,
            1e3 * s.p90_m,
            1e3 * s.max_m,
            1e3 * s.disc_max_m
        );
    }
    println!();
    println!(
        "worst site per frame, over every frame of every recording: its median, 90th percentile and largest"
    );
    if let Some(first) = spreads.first() {
        println!();
        print!("{:<16}", "p90 mm by phase");
        for (phase, _) in &first.phase_p90_m {
            print!(" {:>9}", phase.name());
        }
        println!();
        for s in &spreads {
            print!("{:<16}", s.parameter);
            for (_, p90) in &s.phase_p90_m {
                print!(" {:>9.4}", 1e3 * p90);
            }
            println!();
        }
    }
    if let Some(sigma) = noise.iter().copied().reduce(f64::max) {
        // A site's noise is sigma per axis: sqrt(3) sigma as a distance.
        let noise_m = 3f64.sqrt() * sigma;
        let p90 = spreads.iter().map(|s| s.p90_m).fold(0.0, f64::max);
        println!(
            "marker noise of the recordings: {:.4} mm per axis ({:.4} mm as a distance)",
            1e3 * sigma,
            1e3 * noise_m
        );
        let against = if p90 < noise_m { "under" } else { "over" };
        println!(
            "largest p90 spread: {:.4} mm, {against} the markers' noise",
            1e3 * p90
        );
        // Far below the recordings' resolution, any spread is the solver's, not the material's.
        if nudge <= ROUGHNESS_NUDGE {
            if p90 < noise_m {
                println!("smooth at the noise's scale: a likelihood at this noise can be climbed");
            } else {
                println!(
                    "rough: replays this close apart in parameters differ by more than the noise; a \
                     likelihood at this noise cannot be climbed (more solver iterations per substep, \
                     `[sim] iterations`, make the film's solve converge)"
                );
            }
        }
    }
    Ok(())
}
