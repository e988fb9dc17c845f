//! `rlpkg eval runs/<transport run>`: the trained policy and the scripted baseline (the recorded
//! high-velocity path, time-scaled) over the same seeded, randomised episodes, side by side.

use std::path::Path;

use rlpkg_agents::runners::{evaluation_memory_bytes, TrainedPolicy};
use rlpkg_agents::{AgentError, Trainer};
use rlpkg_env::transport::{run_episodes, OutcomeSummary, TransportConfig, ID};
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
    rows: Vec<OutcomeSummary>,
}

/// Whether `run` holds a transport run (its configuration names the transport environment).
pub fn is_transport_run(trainer: &Trainer) -> bool {
    trainer.config().run.env == ID
}

/// Evaluates the policy of `trainer` (loaded from `run`) and the scripted baseline at each of
/// `scales` over `episodes` randomised episodes from `seed`; prints the table (or JSON).
pub fn run(
    run: &Path,
    trainer: &Trainer,
    episodes: usize,
    seed: u64,
    scales: &[f64],
    json: bool,
) -> anyhow::Result<()> {
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
    let report = TransportReport {
        run: run.display().to_string(),
        update: trainer.update,
        global_step: trainer.global_step,
        seed,
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
        print!("{}", OutcomeSummary::table(&report.rows));
    }
    Ok(())
}
