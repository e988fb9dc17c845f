//! Receding-horizon control (model-predictive control) of the transport task on the batched
//! simulator: every control step, each running episode's exact state is restored into a
//! population of candidate copies, the cross-entropy method optimises the command over the next
//! `horizon` seconds (the same knot curves as the open-loop optimisation, their time counted
//! from now) by rolling the candidates out, and the best candidate's first action is applied.
//!
//! The model is the simulator itself with the episode's true package (mass, object place,
//! material): what such a loop achieves with a perfect model, and what it costs per control step.

use std::time::Instant;

use super::cem::{Cem, CemSettings};
use super::config::{MpcTable, OptimizeConfig};
use super::copy_state::CopyState;
use super::curve::{KnotCurve, ACTIONS};
use super::output::MpcRun;
use crate::transport::run_error::{check, RunError};
use crate::transport::{run_traced_episodes, OutcomeSummary, Transport, TransportConfig};
use crate::{EnvError, VecEnv};

/// The search of each control step.
#[derive(Debug, Clone, PartialEq)]
pub struct HorizonSearch {
    /// The command over the horizon: knots evenly spaced over `[0, curve.horizon_s]` from now.
    pub curve: KnotCurve,
    /// CEM iterations per control step.
    pub iterations: usize,
    /// Population, elites, smoothing and the seed the per-step seeds derive from.
    pub cem: CemSettings,
    /// The first control step's mean (a decision vector of `curve`).
    pub initial_mean: Vec<f64>,
    /// Every step's initial spread.
    pub std: Vec<f64>,
    /// Bounds of the decision variables.
    pub lower: Vec<f64>,
    pub upper: Vec<f64>,
}

/// A receding-horizon controller for every copy of one plant [`Transport`].
pub struct RecedingHorizon {
    candidates: Transport,
    search: HorizonSearch,
    /// Rollout length: the horizon in control steps.
    horizon_steps: usize,
    /// Each plant copy's mean for its next step (warm start: the last plan shifted by a step).
    means: Vec<Vec<f64>>,
    /// Control steps planned so far (seeds each step's samples).
    step: u64,
}

impl RecedingHorizon {
    /// A controller for the copies of `plant` (after its reset), with `search.cem.population`
    /// candidate copies per plant copy.
    pub fn new(plant: &Transport, search: HorizonSearch) -> Result<Self, EnvError> {
        let dimension = search.curve.dimension();
        let sizes = [
            search.initial_mean.len(),
            search.std.len(),
            search.lower.len(),
            search.upper.len(),
        ];
        if sizes.iter().any(|&n| n != dimension) || search.iterations == 0 {
            return Err(EnvError::Simulator(format!(
                "a horizon search of {:?} variables and {} iterations: expected {dimension} \
                 variables and >= 1 iteration",
                sizes, search.iterations
            )));
        }
        let plants = plant.num_envs();
        let mut candidates = Transport::with_scene(
            plant.config.clone(),
            plant.model.config.clone(),
            plant.paths.clone(),
            plants * search.cem.population,
        )?;
        // The plant's settled variants: the candidates never reset, they replay its copies.
        candidates.variants = plant.variants.clone();
        candidates.tilt_schedule = plant.tilt_schedule;
        candidates.profile_rate = plant.profile_rate;
        candidates.set_retire_finished(true);
        let horizon_steps = (search.curve.horizon_s / plant.dt).round().max(1.0) as usize;
        Ok(Self {
            candidates,
            means: vec![search.initial_mean.clone(); plants],
            search,
            horizon_steps,
            step: 0,
        })
    }

    /// The horizon in control steps.
    pub fn horizon_steps(&self) -> usize {
        self.horizon_steps
    }

    /// This control step's action for every copy of `plant` (zeros for a retired one): each
    /// running copy's state is optimised over from its candidates, all in one batch.
    pub fn actions(&mut self, plant: &Transport) -> Result<Vec<f32>, EnvError> {
        let plants = plant.num_envs();
        let population = self.search.cem.population;
        let running: Vec<bool> = (0..plants).map(|k| !plant.retired[k]).collect();
        let states: Vec<Option<CopyState>> = (0..plants)
            .map(|k| running[k].then(|| CopyState::capture(plant, k)))
            .collect();
        let mut searches: Vec<Cem> = (0..plants)
            .map(|k| {
                let settings = CemSettings {
                    seed: step_seed(self.search.cem.seed, self.step, k),
                    ..self.search.cem.clone()
                };
                Cem::new(
                    self.means[k].clone(),
                    self.search.std.clone(),
                    self.search.lower.clone(),
                    self.search.upper.clone(),
                    settings,
                )
                .map_err(EnvError::Simulator)
            })
            .collect::<Result<_, _>>()?;
        let mut best: Vec<(f64, Vec<f64>)> = vec![(f64::INFINITY, Vec::new()); plants];
        for _ in 0..self.search.iterations {
            let samples: Vec<Vec<Vec<f64>>> = searches.iter_mut().map(Cem::candidates).collect();
            let returns = self.roll_out(&states, &samples)?;
            for k in (0..plants).filter(|&k| running[k]) {
                let costs: Vec<f64> = (0..population)
                    .map(|c| -returns[k * population + c])
                    .collect();
                let top = searches[k].update(&samples[k], &costs);
                if costs[top] < best[k].0 || best[k].1.is_empty() {
                    best[k] = (costs[top], samples[k][top].clone());
                }
            }
        }
        let dt = plant.dt;
        let mut actions = vec![0.0f32; plants * ACTIONS];
        for k in (0..plants).filter(|&k| running[k]) {
            let plan = &best[k].1;
            for (a, v) in actions[k * ACTIONS..(k + 1) * ACTIONS]
                .iter_mut()
                .zip(self.search.curve.actions(plan, 0.0))
            {
                *a = v as f32;
            }
            self.means[k] = shifted(&self.search.curve, plan, dt);
        }
        self.step += 1;
        Ok(actions)
    }

    /// Each candidate copy's return over the horizon from its plant copy's state: copy `k x P +
    /// c` runs `samples[k][c]` from state `k` (a retired plant copy's candidates stay retired).
    fn roll_out(
        &mut self,
        states: &[Option<CopyState>],
        samples: &[Vec<Vec<f64>>],
    ) -> Result<Vec<f64>, EnvError> {
        let population = self.search.cem.population;
        let env = &mut self.candidates;
        let copies = states.len() * population;
        for copy in 0..copies {
            match &states[copy / population] {
                Some(state) => state.restore_into(env, copy)?,
                None => env.retired[copy] = true,
            }
        }
        env.read_simulator()?;
        let start: Vec<usize> = env.episodes.iter().map(|e| e.steps).collect();
        let mut buffers = env.buffers();
        let mut returns = vec![0.0f64; copies];
        let mut done: Vec<bool> = (0..copies).map(|c| env.retired[c]).collect();
        let dt = env.dt;
        for _ in 0..self.horizon_steps {
            if done.iter().all(|d| *d) {
                break;
            }
            let actions: Vec<f32> = (0..copies)
                .flat_map(|copy| {
                    let sample = &samples[copy / population][copy % population];
                    let t = (env.episodes[copy].steps - start[copy]) as f64 * dt;
                    self.search.curve.actions(sample, t).map(|a| a as f32)
                })
                .collect();
            env.step(&actions, &mut buffers)?;
            for copy in 0..copies {
                if !done[copy] {
                    returns[copy] += buffers.rewards[copy] as f64;
                    done[copy] = buffers.done(copy);
                }
            }
        }
        Ok(returns)
    }
}

/// The seed of plant copy `k`'s samples at control step `step`: distinct per copy and step,
/// fixed by the configured seed.
fn step_seed(seed: u64, step: u64, k: usize) -> u64 {
    seed.wrapping_mul(0x9E37_79B9_7F4A_7C15)
        .wrapping_add(step.wrapping_mul(0xBF58_476D_1CE4_E5B9))
        .wrapping_add(k as u64)
}

/// The decision vector of the plan `x` a control step `dt` later: each action's knots resampled
/// from its curve at their times plus `dt` (the last held).
fn shifted(curve: &KnotCurve, x: &[f64], dt: f64) -> Vec<f64> {
    let spacing = curve.horizon_s / (curve.knots - 1) as f64;
    (0..ACTIONS)
        .flat_map(|a| {
            let knots = &x[a * curve.knots..(a + 1) * curve.knots];
            (0..curve.knots).map(move |j| curve.value(knots, j as f64 * spacing + dt))
        })
        .collect()
}

/// Runs the `[conditions]` packages' episodes of `config` on `transport`'s task (`source` is its
/// configuration file) under receding-horizon control with `settings` (its `[mpc]` table), timing
/// the planning. Before each control step, `progress` sees how many episodes are still running
/// and `stop` is asked.
pub fn control_packages(
    config: &OptimizeConfig,
    settings: &MpcTable,
    transport: TransportConfig,
    source: &str,
    stop: &dyn Fn() -> bool,
    progress: &mut dyn FnMut(usize),
) -> Result<MpcRun, RunError> {
    let curve = KnotCurve {
        knots: settings.knots,
        horizon_s: settings.horizon_s,
    };
    let [initial_mean, std, lower, upper] = config.decision_space(&transport, &curve);
    let packages = config.conditions.packages;
    let mut plant = Transport::new(transport, packages, source).map_err(RunError::input)?;
    // The horizon search's commands are path speeds.
    plant.drive_path_speed();
    let search = HorizonSearch {
        curve,
        iterations: settings.iterations,
        cem: config.cem_settings(),
        initial_mean,
        std,
        lower,
        upper,
    };
    let mut controller: Option<RecedingHorizon> = None;
    let (mut planning_s, mut episode_steps, mut control_steps) = (0.0, 0usize, 0usize);
    let (outcomes, _) =
        run_traced_episodes::<RunError>(&mut plant, config.conditions.seed, &[], |env, _| {
            check(stop)?;
            // Built after the plant's reset, from its settled packages.
            let mpc = match &mut controller {
                Some(mpc) => mpc,
                None => controller.insert(RecedingHorizon::new(env, search.clone())?),
            };
            let running = (0..packages).filter(|&k| !env.is_retired(k)).count();
            let started = Instant::now();
            let actions = mpc.actions(env)?;
            planning_s += started.elapsed().as_secs_f64();
            episode_steps += running;
            control_steps += 1;
            progress(running);
            Ok(actions)
        })?;
    Ok(MpcRun {
        outcome: OutcomeSummary::of("mpc", &outcomes),
        control_steps,
        control_interval_s: plant.control_interval_s(),
        planning_s,
        wall_per_control_step_s: planning_s / episode_steps.max(1) as f64,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::transport::test_support::{config, test_table};

    fn search(population: usize) -> HorizonSearch {
        let curve = KnotCurve {
            knots: 3,
            horizon_s: 0.3,
        };
        let block = |v: f64| vec![v; 3];
        let tilt = 20f64.to_radians();
        HorizonSearch {
            curve,
            iterations: 2,
            cem: CemSettings {
                population,
                elites: 2,
                smoothing: 0.8,
                seed: 3,
            },
            initial_mean: [block(0.4), block(0.0), block(0.0)].concat(),
            std: [block(0.2), block(0.05), block(0.05)].concat(),
            lower: [block(0.0), block(-tilt), block(-tilt)].concat(),
            upper: [block(0.945), block(tilt), block(tilt)].concat(),
        }
    }

    #[test]
    fn the_shifted_plan_continues_the_curve_a_step_later() {
        let curve = KnotCurve {
            knots: 3,
            horizon_s: 1.0,
        };
        let x: Vec<f64> = [[0.1, 0.3, 0.5], [0.0; 3], [0.2, 0.2, 0.2]].concat();
        let next = shifted(&curve, &x, 0.25);
        // A line continues (0.1 + 0.4 t at t + 0.25), held after the horizon.
        let expected = [0.2, 0.4, 0.5];
        for (got, want) in next[..3].iter().zip(expected) {
            assert!((got - want).abs() < 1e-12, "{next:?}");
        }
        assert!(
            next[6..].iter().all(|v| (v - 0.2).abs() < 1e-12),
            "{next:?}"
        );
    }

    #[test]
    fn the_controller_acts_within_bounds_and_does_not_change_the_plant() {
        let mut plant = Transport::new(config(&test_table()), 2, "test.toml").unwrap();
        let mut buffers = plant.buffers();
        plant.set_retire_finished(true);
        plant.try_reset(4, &mut buffers).unwrap();
        let before: Vec<_> = (0..2).map(|k| plant.sim.snapshot(k)).collect();
        let mut mpc = RecedingHorizon::new(&plant, search(4)).unwrap();
        assert_eq!(mpc.horizon_steps(), 6);
        let first = mpc.actions(&plant).unwrap();
        assert_eq!(first.len(), 2 * ACTIONS);
        let s = search(4);
        for (i, a) in first.iter().enumerate() {
            let j = (i % ACTIONS) * 3;
            assert!(
                s.lower[j] as f32 <= *a && *a <= s.upper[j] as f32,
                "{first:?}"
            );
        }
        // Planning reads the plant and leaves it alone.
        for (k, snapshot) in before.iter().enumerate() {
            assert_eq!(&plant.sim.snapshot(k), snapshot);
        }
        plant.step(&first, &mut buffers).unwrap();
        let second = mpc.actions(&plant).unwrap();
        assert!(second.iter().all(|a| a.is_finite()));
        assert!(RecedingHorizon::new(
            &plant,
            HorizonSearch {
                iterations: 0,
                ..search(4)
            }
        )
        .is_err());
    }
}
