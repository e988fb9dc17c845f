//! Tests of the solvers' dispatch: every compiled copy of a substep gives the same bits.

use std::sync::Arc;

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

use super::{Simd, AVX512_LANES};
use crate::{EpisodeSpec, Model, Placement, Randomization, SceneConfig, Simulator, ToolTrajectory};

/// A shipped scene from `configs/scenes/` on a 6x7 grid.
fn scene(name: &str) -> SceneConfig {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../configs/scenes")
        .join(name);
    let mut c = SceneConfig::load(&path).unwrap();
    c.package.grid = [6, 7];
    c
}

/// `n` packages held 0.5 m above the ground, each with its own object mass, offset, yaw and film
/// stiffness.
fn varied(config: &SceneConfig, n: usize) -> Vec<EpisodeSpec> {
    let size = config.package.size_m;
    let centre = [size[1] / 2.0, 0.5, size[0] / 2.0];
    let cup_point = [centre[0], centre[1] + 0.01, centre[2]];
    let base = EpisodeSpec {
        placement: Placement::new([0.0, 0.5, 0.0], cup_point, centre),
        params: config.params,
        object_mass_kg: 0.5,
        disc_mass_scale: None,
        vacuum_kpa: None,
        trajectory: Arc::new(ToolTrajectory::hold(
            cup_point.map(f64::from),
            [0.0, 0.0, 0.0, 1.0],
        )),
    };
    let randomization = Randomization {
        object_mass_kg: Some([0.3, 0.7]),
        object_offset_m: 0.02,
        package_yaw_deg: [-10.0, 10.0],
        param_scale: [("k_tri_e".to_string(), [0.7, 1.4])].into_iter().collect(),
        ..Randomization::default()
    };
    let mut rng = ChaCha8Rng::seed_from_u64(11);
    (0..n)
        .map(|_| randomization.apply(&base, &mut rng))
        .collect()
}

/// Positions, velocities and the disc of every environment, as bits.
fn bits(sim: &Simulator) -> Vec<Vec<u32>> {
    (0..sim.num_envs())
        .map(|env| {
            let d = sim.disc(env);
            sim.particle_positions(env)
                .iter()
                .chain(&sim.particle_velocities(env))
                .flatten()
                .chain(d.position.iter().chain(&d.orientation).chain(&d.velocity))
                .map(|c| c.to_bits())
                .collect()
        })
        .collect()
}

#[test]
fn every_instruction_set_gives_the_same_bits_for_every_solver() {
    let levels: Vec<Simd> = [Simd::Baseline, Simd::Avx2, Simd::Avx512]
        .into_iter()
        .filter(|&s| s <= Simd::detect())
        .collect();
    // Enough environments for 16-lane blocks (one of them padded).
    let n = 2 * AVX512_LANES + 8;
    for name in [
        "calibrated-study.toml",
        "calibrated-coarse-soft-film.toml",
        "calibrated-global-coarse-real-film-200hz.toml",
    ] {
        let c = scene(name);
        let model = Arc::new(Model::new(&c).unwrap());
        let specs = varied(&c, n);
        let run = |simd: Simd, specs: Vec<EpisodeSpec>| {
            let mut sim = Simulator::with_simd(model.clone(), specs, simd).unwrap();
            let lanes = match (sim.num_envs(), simd) {
                (1, _) => 1,
                (_, Simd::Avx512) => AVX512_LANES,
                _ => crate::LANES,
            };
            assert_eq!(sim.lanes_per_block(), lanes, "{name} {simd:?}");
            sim.step(120);
            bits(&sim)
        };
        let reference = run(Simd::Baseline, specs.clone());
        assert_ne!(reference[0], reference[1], "{name}");
        for &simd in &levels {
            assert!(
                run(simd, specs.clone()) == reference,
                "{name}: {simd:?} batch"
            );
            for env in [0, n - 3] {
                let alone = run(simd, vec![specs[env].clone()]);
                assert!(
                    alone[0] == reference[env],
                    "{name}: {simd:?} env {env} alone"
                );
            }
        }
    }
}
