//! `rlpkg posterior CONFIG --spread NUDGE`: how far the calibration's replays move when its
//! parameters are nudged far below what the recordings can tell apart, beside the recordings'
//! marker noise ([`rlpkg_calib::spread_check`]).

use rlpkg_calib::config::CalibrateConfig;
use rlpkg_calib::spread_check::SpreadCheck;

use super::PosteriorArgs;
use crate::error::input_error;

/// Runs the spread check of `config` at its scene's own parameter values.
pub fn run(args: &PosteriorArgs, config: CalibrateConfig, nudge: f64) -> anyhow::Result<()> {
    if !(nudge > 0.0 && nudge < 1.0) {
        return Err(input_error(format!(
            "--spread {nudge}: expected a relative nudge in (0, 1), e.g. 1e-6"
        )));
    }
    let check = SpreadCheck::new(&config, &args.config).map_err(input_error)?;
    let scene = &check.scene;
    println!(
        "replays of {} ({}) at the scene's own values, each parameter and then all of them x (1 + {nudge:e}); \
         solver {:?}, {} iterations per substep at {} substeps/s",
        check.trajectory_ids.join(", "),
        config
            .sim
            .max_seconds
            .map_or("whole".to_string(), |s| format!("first {s} s")),
        scene.integrator.solver,
        scene.integrator.iterations,
        scene.integrator.substep_rate_hz
    );
    let report = check.run(nudge).map_err(input_error)?;
    let spreads = &report.spreads;
    println!();
    println!(
        "{:<16} {:>10} {:>10} {:>10} {:>12}",
        "nudged", "median mm", "p90 mm", "max mm", "disc max mm"
    );
    for s in spreads {
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
        for s in spreads {
            print!("{:<16}", s.parameter);
            for (_, p90) in &s.phase_p90_m {
                print!(" {:>9.4}", 1e3 * p90);
            }
            println!();
        }
    }
    if let (Some(sigma), Some(noise_m)) = (report.noise_std_m, report.noise_distance_m()) {
        let p90 = report.largest_p90_m();
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
        match report.smooth() {
            Some(true) => {
                println!("smooth at the noise's scale: a likelihood at this noise can be climbed")
            }
            Some(false) => println!(
                "rough: replays this close apart in parameters differ by more than the noise; a \
                 likelihood at this noise cannot be climbed (more solver iterations per substep, \
                 `[sim] iterations`, make the film's solve converge)"
            ),
            None => {}
        }
    }
    Ok(())
}
