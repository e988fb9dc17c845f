//! Many different, moving environments from the recordings: each environment replays one recorded
//! tool motion (the recordings cycled over the batch) with its own randomised object mass. A load
//! like the one reinforcement learning puts on the simulator, unlike a batch of identical
//! motionless packages (`rlpkg_sim::bench::bench_simulator`).

use std::path::Path;
use std::sync::Arc;

use rand::rngs::StdRng;
use rand::SeedableRng;
use rlpkg_mocap::Dataset;
use rlpkg_sim::{EpisodeSpec, Model, Params, Randomization, SceneConfig, Simulator};

use crate::error::ReplayError;
use crate::target::Target;

/// Object masses drawn for the replayed environments (kg): around the recorded disc-plus-weight
/// masses, 0.285, 0.426 and 0.570 kg.
pub const OBJECT_MASS_RANGE_KG: [f32; 2] = [0.25, 0.65];

/// Every recording of the dataset at `root`, in id order, prepared for replay (all frames).
pub fn load_targets(root: &Path, hold_disc: bool) -> Result<Vec<Target>, ReplayError> {
    let dataset = Dataset::open(root)?;
    dataset
        .ids(None)
        .iter()
        .map(|id| Target::new(&dataset.load(id)?, None, hold_disc))
        .collect()
}

/// `envs` environments: environment `i` replays `targets[i % targets.len()]` with material
/// `params` and the quantities of `randomization` drawn from its own generator (seeded from `seed`
/// and `i`, so the batch is the same for a seed whatever the thread count or batch order).
pub fn replay_specs(
    targets: &[Target],
    params: Params,
    envs: usize,
    randomization: &Randomization,
    seed: u64,
) -> Vec<EpisodeSpec> {
    (0..envs)
        .map(|env| {
            let base = targets[env % targets.len()].episode_spec(params, None);
            randomization.apply(&base, &mut env_rng(seed, env))
        })
        .collect()
}

/// The generator of environment `env`: distinct streams per environment and seed.
fn env_rng(seed: u64, env: usize) -> StdRng {
    StdRng::seed_from_u64(seed ^ (env as u64 + 1).wrapping_mul(0x9E37_79B9_7F4A_7C15))
}

/// The benchmark's replay batch: `config` on a `grid` package without the rest period (so that
/// even a short measurement is of moving packages), `envs` environments replaying `targets` in
/// turn with object masses drawn uniformly from [`OBJECT_MASS_RANGE_KG`].
pub fn replay_simulator(
    config: &SceneConfig,
    grid: [usize; 2],
    envs: usize,
    targets: &[Target],
    seed: u64,
) -> Result<Simulator, ReplayError> {
    if targets.is_empty() {
        return Err(ReplayError::Trajectory {
            id: String::new(),
            message: "no recording to replay".into(),
        });
    }
    let mut config = config.clone();
    config.package.grid = grid;
    config.cups.rest_time_s = 0.0;
    let model = Arc::new(Model::new(&config)?);
    let randomization = Randomization {
        object_mass_kg: Some(OBJECT_MASS_RANGE_KG),
        ..Randomization::default()
    };
    let specs = replay_specs(targets, config.params, envs, &randomization, seed);
    Ok(Simulator::new(model, specs)?)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn targets() -> Vec<Target> {
        let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../data/deformable-sim-real");
        load_targets(&root, false).unwrap()
    }

    #[test]
    fn replay_specs_cycle_the_recordings_with_masses_in_range_and_reproducible() {
        let targets = targets();
        assert_eq!(targets.len(), 18);
        let params = SceneConfig::preset("reference").unwrap().params;
        let randomization = Randomization {
            object_mass_kg: Some(OBJECT_MASS_RANGE_KG),
            ..Randomization::default()
        };
        let specs = replay_specs(&targets, params, 40, &randomization, 7);
        for (env, spec) in specs.iter().enumerate() {
            let target = &targets[env % 18];
            assert!(Arc::ptr_eq(&spec.trajectory, &target.tool), "env {env}");
            assert_eq!(spec.placement.cup_point, target.placement.cup_point);
            let [low, high] = OBJECT_MASS_RANGE_KG;
            assert!((low..=high).contains(&spec.object_mass_kg), "env {env}");
        }
        let masses =
            |specs: &[EpisodeSpec]| specs.iter().map(|s| s.object_mass_kg).collect::<Vec<_>>();
        // Different environments draw different masses; the same seed gives the same batch, and
        // a smaller batch is a prefix of a larger one.
        let m = masses(&specs);
        assert!(m.windows(2).all(|w| w[0] != w[1]), "{m:?}");
        assert_eq!(
            m,
            masses(&replay_specs(&targets, params, 40, &randomization, 7))
        );
        assert_eq!(
            m[..5],
            masses(&replay_specs(&targets, params, 5, &randomization, 7))
        );
        assert_ne!(
            m,
            masses(&replay_specs(&targets, params, 40, &randomization, 8))
        );
    }

    #[test]
    fn replay_batch_moves_different_environments() {
        let targets = targets();
        let scene = SceneConfig::preset("reference").unwrap();
        let mut sim = replay_simulator(&scene, [11, 13], 3, &targets[..2], 1).unwrap();
        let start: Vec<[f64; 3]> = (0..3).map(|e| sim.tool_state(e).position).collect();
        sim.step(3072); // 0.1 s: no rest period, the recorded motion has begun
        assert!(sim.health_events().is_empty(), "{:?}", sim.health_events());
        for (env, from) in start.iter().enumerate() {
            let now = sim.tool_state(env).position;
            let moved = (0..3).map(|k| (now[k] - from[k]).powi(2)).sum::<f64>();
            assert!(moved.sqrt() > 1e-3, "env {env} tool moved {}", moved.sqrt());
        }
        // Environments 0 and 2 replay the same recording with different masses.
        assert_eq!(start[0], start[2]);
        assert_ne!(start[0], start[1]);
        assert_ne!(sim.spec(0).object_mass_kg, sim.spec(2).object_mass_kg);
        assert!(replay_simulator(&scene, [6, 7], 3, &[], 1).is_err());
    }
}
