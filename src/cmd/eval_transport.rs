//! `rlpkg eval runs/<transport run>`: the trained policy and the scripted baseline (the recorded
//! high-velocity path, time-scaled) over the same seeded, randomised episodes, side by side.

use std::path::Path;

use rlpkg_agents::runners::{evaluation_memory_bytes, TrainedPolicy};
use rlpkg_agents::{AgentError, Trainer};
use rlpkg_env::transport::{
    recorded_timings, run_episodes, OutcomeSummary, TransportConfig, TransportPath, ID,
};
use rlpkg_env::{EnvError, Transport};
use serde::Serialize;

use crate::error::input_error;

/// What `rlpkg eval` prints for a transport run.
#[derive(Serialize)]
struct TransportReport {
    run: String,
    update: usize,
    global_step: u64,
    seed: u64,
    /// Recorded baselines: velocity level, and for each path the recording whose timing it plays.
    recorded: Vec<RecordedBaseline>,
    rows: Vec<OutcomeSummary>,
}

/// The recordings one recorded baseline takes its timing from.
#[derive(Serialize)]
struct RecordedBaseline {
    velocity: String,
    /// `path id -> recording id` for each configured path.
    timings: Vec<(String, String)>,
}

/// Whether `run` holds a transport run (its configuration names the transport environment).
pub fn is_transport_run(trainer: &Trainer) -> bool {
    trainer.config().run.env == ID
}

/// Evaluates the policy of `trainer` (loaded from `run`), the scripted baseline at each of
/// `scales` and the recorded baseline of each velocity level in `recorded` over `episodes`
/// randomised episodes from `seed`; prints the table (or JSON).
pub fn run(
    run: &Path,
    trainer: &Trainer,
    episodes: usize,
    seed: u64,
    scales: &[f64],
    recorded: &[String],
    json: bool,
) -> anyhow::Result<()> {
    let recorded: Vec<&str> = match recorded {
        [none] if none == "none" => Vec::new(),
        levels => levels.iter().map(String::as_str).collect(),
    };
    if let Some(bad) = recorded
        .iter()
        .find(|v| !["low", "medium", "high"].contains(v))
    {
        return Err(input_error(format!(
            "--recorded {bad}: expected velocity levels low, medium, high (comma-separated) or none"
        )));
    }
    if let Some(bad) = scales
        .iter()
        .find(|s| !(s.is_finite() && **s > 0.0 && **s <= 10.0))
    {
        return Err(input_error(format!(
            "--scripted {bad}: expected time scales in (0, 10]"
        )));
    }
    let config = trainer.config();
    let table = config
        .transport
        .as_ref()
        .ok_or_else(|| input_error(format!("{}: no [transport] table", run.display())))?;
    let transport = TransportConfig::from_table(table, &config.source).map_err(input_error)?;
    let policy = TrainedPolicy::from_trainer(trainer);
    let widths: usize = policy.model.actor_layers().iter().map(|l| l.d_out).sum();
    rlpkg_agents::config::check_memory(
        &format!("--episodes {episodes}"),
        evaluation_memory_bytes(episodes, policy.spec.observation.dim(), widths),
    )
    .map_err(input_error)?;
    let make = || Transport::new(transport.clone(), episodes, &config.source);
    let mut rows = Vec::new();
    let mut env = make().map_err(input_error)?;
    let outcomes =
        run_episodes::<AgentError>(&mut env, seed, |_, obs| Ok(policy.act(obs, episodes)))?;
    rows.push(OutcomeSummary::of("policy", &outcomes));
    for &scale in scales {
        let mut env = make().map_err(input_error)?;
        let outcomes =
            run_episodes::<EnvError>(&mut env, seed, |env, _| Ok(env.scripted_actions(scale)))?;
        rows.push(OutcomeSummary::of(&format!("scripted x{scale}"), &outcomes));
    }
    let mut baselines = Vec::new();
    for velocity in recorded {
        let timings =
            recorded_timings(&transport, velocity, &config.source).map_err(input_error)?;
        // The same episodes, with time to finish the slowest recording (the low-velocity ones
        // take 19-22 s): the time limit does not change what an episode draws.
        let mut long = transport.clone();
        long.time_limit_s = long.time_limit_s.max(longest_timing_s(&timings) * 1.25);
        let mut env = Transport::new(long, episodes, &config.source).map_err(input_error)?;
        let outcomes =
            run_episodes::<EnvError>(
                &mut env,
                seed,
                |env, _| Ok(env.timed_actions(&timings, 1.0)),
            )?;
        rows.push(OutcomeSummary::of(
            &format!("recorded {velocity}"),
            &outcomes,
        ));
        baselines.push(RecordedBaseline {
            velocity: velocity.to_string(),
            timings: transport
                .paths
                .iter()
                .cloned()
                .zip(timings.iter().map(|t| t.id.clone()))
                .collect(),
        });
    }
    let report = TransportReport {
        run: run.display().to_string(),
        update: trainer.update,
        global_step: trainer.global_step,
        seed,
        recorded: baselines,
        rows,
    };
    if json {
        println!("{}", serde_json::to_string_pretty(&report)?);
    } else {
        println!(
            "{} (update {}, {} steps): {} randomised episodes from seed {} per driver; \
             scripted xS = the recorded high-velocity path played S times as fast",
            report.run, report.update, report.global_step, episodes, seed
        );
        for b in &report.recorded {
            let pairs: Vec<String> = b
                .timings
                .iter()
                .map(|(path, timing)| format!("{path} with {timing}'s timing"))
                .collect();
            println!("recorded {}: {}", b.velocity, pairs.join(", "));
        }
        print!("{}", OutcomeSummary::table(&report.rows));
    }
    Ok(())
}

/// Duration of the longest recording in `timings` (s).
fn longest_timing_s(timings: &[TransportPath]) -> f64 {
    timings
        .iter()
        .map(|t| t.recorded_duration_s)
        .fold(0.0, f64::max)
}
