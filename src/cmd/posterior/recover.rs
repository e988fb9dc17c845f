//! `rlpkg posterior CONFIG --recover K`: the parameter-recovery table of a calibration config
//! (crate `rlpkg-calib`, module `recovery`).
//!
//! K known parameter sets are drawn from the middle of the config's box; for each, the simulator
//! records the config's training trajectories synthetically (the real placement, tool motion,
//! occlusion and marker noise level), the config's optimiser calibrates them back from scratch into
//! `<out>/truth-<k>/`, and the posterior of that calibration is compared with the truth.

use std::time::Instant;

use rlpkg_calib::config::{check_unique_ids, CalibrateConfig};
use rlpkg_calib::driver;
use rlpkg_calib::posterior::PosteriorSettings;
use rlpkg_calib::recovery::{self, RecoveryError, RecoverySettings};
use rlpkg_mocap::{Dataset, Split};
use rlpkg_replay::Target;
use serde::Serialize;

use super::PosteriorArgs;
use crate::error::{input_error, output_error};
use crate::files::write_atomic;

/// `recovery.json`: what was recovered and how, then every truth's recovery.
#[derive(Serialize)]
struct RecoveryFile<'a, T: Serialize> {
    config: &'a std::path::Path,
    trajectories: &'a [String],
    max_seconds: Option<f64>,
    noise_std_m: f64,
    wall_s: f64,
    truths: &'a [T],
}

/// A recovery always starts over: a log of other synthetic recordings must not be resumed.
fn remove_outputs(folder: &std::path::Path, files: &[&str]) -> anyhow::Result<()> {
    for file in files {
        let path = folder.join(file);
        if path.exists() {
            std::fs::remove_file(&path)
                .map_err(|e| input_error(format!("{}: cannot remove: {e}", path.display())))?;
        }
    }
    Ok(())
}

/// Runs the recovery of `truths` parameter sets.
pub fn run(
    args: &PosteriorArgs,
    mut config: CalibrateConfig,
    truths: usize,
    posterior: PosteriorSettings,
) -> anyhow::Result<()> {
    if let Some(s) = args.max_seconds {
        if !(s > 0.0 && s.is_finite()) {
            return Err(input_error(format!(
                "--max-seconds {s}: expected a duration > 0 s"
            )));
        }
        config.sim.max_seconds = Some(s);
    }
    if let Some(n) = args.iterations {
        if config.smc.is_some() {
            return Err(input_error(format!(
                "--iterations {n}: the config samples a posterior ([smc]), which has no \
                 iterations; set smc.particles or smc.moves instead"
            )));
        }
        config.optimiser_mut().iterations = n as usize;
    }
    let dataset = Dataset::open(&config.data).map_err(input_error)?;
    let ids = if !args.trajectories.is_empty() {
        check_unique_ids("--trajectories", &args.trajectories).map_err(input_error)?;
        args.trajectories.clone()
    } else if let Some(ids) = &config.trajectories {
        ids.clone()
    } else {
        dataset.ids(Some(Split::Train))
    };
    if ids.is_empty() {
        return Err(input_error(format!(
            "{}: no trajectory to synthesise (the manifest has no train split)",
            config.data.display()
        )));
    }
    let scene = config.scene(&args.config).map_err(input_error)?;
    let (targets, noise_std_m) =
        recovery::recordings(&dataset, &ids, &scene, config.sim.max_seconds)
            .map_err(input_error)?;
    let Some(noise_std_m) = noise_std_m else {
        return Err(input_error(format!(
            "trajectories {}: too few frames to estimate the marker noise (a longer --max-seconds)",
            ids.join(",")
        )));
    };

    let out = args
        .out
        .clone()
        .unwrap_or_else(|| config.out_dir.join("recovery"));
    let space = config.space();
    if let Some(smc) = config.smc {
        return run_sampled(
            args,
            &config,
            smc,
            &scene,
            &targets,
            &ids,
            truths,
            noise_std_m,
        );
    }
    let settings = RecoverySettings {
        optimiser: config.bo_settings(),
        iterations: config.optimiser().iterations,
        weights: config.loss,
        noise_std_m,
        posterior,
        seed: args.seed,
    };
    let draws = recovery::draw_truths(&space, truths, args.seed);
    println!(
        "recovering {truths} truth(s) of {} parameter(s) on {} synthetic trajectory(ies) [{}], {}, \
         marker noise {:.3} mm per axis (estimated from the recordings); output in {}",
        space.dim(),
        ids.len(),
        ids.join(","),
        config
            .sim
            .max_seconds
            .map_or("whole trajectories".to_string(), |s| format!("first {s} s of each")),
        1e3 * noise_std_m,
        out.display()
    );
    let _cooperation = crate::interrupt::Cooperation::start();
    let started = Instant::now();
    let mut recoveries = Vec::with_capacity(truths);
    for (k, truth) in draws.iter().enumerate() {
        let folder = out.join(format!("truth-{k}"));
        remove_outputs(&folder, &driver::OUTPUT_FILES)?;
        let truth_started = Instant::now();
        let recovered = recovery::recover(&scene, &space, &targets, truth, k, &settings, &folder)
            .map_err(|e| match e {
            RecoveryError::Replay(e) => input_error(format!("truth {k}: {e}")),
            other => anyhow::Error::new(other),
        })?;
        println!(
            "truth {k}: best loss {:.4e}, {:.0} s",
            recovered.best_loss,
            truth_started.elapsed().as_secs_f64()
        );
        recoveries.push(recovered);
    }
    let wall_s = started.elapsed().as_secs_f64();
    let json = serde_json::to_string_pretty(&RecoveryFile {
        config: &args.config,
        trajectories: &ids,
        max_seconds: config.sim.max_seconds,
        noise_std_m,
        wall_s,
        truths: &recoveries,
    })?;
    write_atomic(&out.join("recovery.json"), json.as_bytes()).map_err(output_error)?;
    println!();
    print!("{}", recovery::recovery_table(&recoveries));
    println!();
    println!("{}", rlpkg_calib::posterior::IDENTIFIED_RULE);
    println!(
        "{truths} truth(s) in {wall_s:.0} s wall; wrote {}/recovery.json",
        out.display()
    );
    Ok(())
}

/// The recovery of a config that samples its posterior ([smc]): each truth's synthetic recordings
/// sampled from the prior into `<out>/truth-<k>/`.
#[allow(clippy::too_many_arguments)]
fn run_sampled(
    args: &PosteriorArgs,
    config: &CalibrateConfig,
    smc: rlpkg_calib::smc::SmcSettings,
    scene: &rlpkg_sim::SceneConfig,
    targets: &[Target],
    ids: &[String],
    truths: usize,
    noise_std_m: f64,
) -> anyhow::Result<()> {
    let out = args
        .out
        .clone()
        .unwrap_or_else(|| config.out_dir.join("recovery"));
    let space = config.space();
    let draws = recovery::draw_truths(&space, truths, args.seed);
    println!(
        "recovering {truths} truth(s) of {} parameter(s) with a sampled posterior ({}) \
         on {} synthetic trajectory(ies) [{}], marker noise {:.3} mm per axis; output in {}",
        space.dim(),
        smc.sampler_text(),
        ids.len(),
        ids.join(","),
        1e3 * noise_std_m,
        out.display()
    );
    println!("{}", config.likelihood.replicas_text());
    let _cooperation = crate::interrupt::Cooperation::start();
    let started = Instant::now();
    let mut recoveries = Vec::with_capacity(truths);
    for (k, truth) in draws.iter().enumerate() {
        let folder = out.join(format!("truth-{k}"));
        remove_outputs(&folder, &rlpkg_calib::sampled_posterior::POSTERIOR_FILES)?;
        let truth_started = Instant::now();
        let recovered = recovery::recover_sampled(
            scene,
            &space,
            targets,
            truth,
            k,
            &smc,
            &config.likelihood,
            config.loss,
            noise_std_m,
            args.seed,
            &folder,
        )
        .map_err(|e| match e {
            RecoveryError::Replay(e) => input_error(format!("truth {k}: {e}")),
            other => anyhow::Error::new(other),
        })?;
        println!(
            "truth {k}: truth loss {:.4e} ({:.4e} with every value x (1 + {:.0e})), best loss {:.4e}, \
             {} candidates, {:.0} s",
            recovered.truth_loss,
            recovered.nudged_truth_loss,
            rlpkg_calib::recovery::NUDGE,
            recovered.best_loss,
            recovered.evaluations,
            truth_started.elapsed().as_secs_f64()
        );
        for h in &recovered.horizons {
            println!(
                "  search on {:>9}: {:>3} generation(s), best log-likelihood {:.6e} (truth's {:.6e})",
                h.horizon_s.map_or("the whole".to_string(), |s| format!("{s} s")),
                h.generations,
                h.best_log_likelihood,
                h.truth_log_likelihood
            );
        }
        recoveries.push(recovered);
    }
    let wall_s = started.elapsed().as_secs_f64();
    let json = serde_json::to_string_pretty(&RecoveryFile {
        config: &args.config,
        trajectories: ids,
        max_seconds: config.sim.max_seconds,
        noise_std_m,
        wall_s,
        truths: &recoveries,
    })?;
    write_atomic(&out.join("recovery.json"), json.as_bytes()).map_err(output_error)?;
    println!();
    print!("{}", recovery::sampled_recovery_table(&recoveries));
    println!(
        "{truths} truth(s) in {wall_s:.0} s wall; wrote {}/recovery.json",
        out.display()
    );
    Ok(())
}
