//! Tests of the solvers' dispatch: every compiled copy of a substep gives the same bits.

use std::sync::Arc;

use super::{Simd, AVX512_LANES};
use crate::test_support::{env_bits, varied};
use crate::{EpisodeSpec, Model, SceneConfig, Simulator};

/// A shipped scene from `configs/scenes/` on a 6x7 grid.
fn scene(name: &str) -> SceneConfig {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../configs/scenes")
        .join(name);
    let mut c = SceneConfig::load(&path).unwrap();
    c.package.grid = [6, 7];
    c
}

/// Positions, velocities and the disc of every environment, as bits.
fn bits(sim: &Simulator) -> Vec<Vec<u32>> {
    (0..sim.num_envs()).map(|env| env_bits(sim, env)).collect()
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
        let specs = varied(&c, n, 11);
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
