//! Set-ups shared by the simulator's tests.

use std::sync::Arc;

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

use crate::{EpisodeSpec, Placement, Randomization, SceneConfig, Simulator, ToolTrajectory};

/// The package 0.5 m above the ground with the cups held `cup_height` above its centre, the tool
/// at the cup point (so it turns about the cups' centre), a 0.5 kg disc, the scene's parameters.
pub(crate) fn held_spec(config: &SceneConfig, cup_height: f32) -> EpisodeSpec {
    let size = config.package.size_m;
    let centre = [size[1] / 2.0, 0.5, size[0] / 2.0];
    let cup_point = [centre[0], centre[1] + cup_height, centre[2]];
    EpisodeSpec {
        placement: Placement::new([0.0, 0.5, 0.0], cup_point, centre),
        params: config.params,
        object_mass_kg: 0.5,
        disc_mass_scale: None,
        vacuum_kpa: None,
        trajectory: Arc::new(ToolTrajectory::hold(
            cup_point.map(f64::from),
            [0.0, 0.0, 0.0, 1.0],
        )),
    }
}

/// `n` packages around [`held_spec`] (cups 0.01 m up), each with its own object mass, offset, yaw
/// and film stiffness, drawn from `seed`.
pub(crate) fn varied(config: &SceneConfig, n: usize, seed: u64) -> Vec<EpisodeSpec> {
    let randomization = Randomization {
        object_mass_kg: Some([0.3, 0.7]),
        object_offset_m: 0.02,
        package_yaw_deg: [-10.0, 10.0],
        param_scale: [("k_tri_e".to_string(), [0.7, 1.4])].into_iter().collect(),
        ..Randomization::default()
    };
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let base = held_spec(config, 0.01);
    (0..n)
        .map(|_| randomization.apply(&base, &mut rng))
        .collect()
}

/// Positions, velocities and the disc of environment `env`, as bits: what "bit-identical" compares.
pub(crate) fn env_bits(sim: &Simulator, env: usize) -> Vec<u32> {
    let d = sim.disc(env);
    sim.particle_positions(env)
        .iter()
        .chain(&sim.particle_velocities(env))
        .flatten()
        .chain(d.position.iter().chain(&d.orientation).chain(&d.velocity))
        .map(|c| c.to_bits())
        .collect()
}
