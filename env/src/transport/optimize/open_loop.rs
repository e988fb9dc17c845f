//! Open-loop commands in the task: [`Transport::open_loop_actions`] plays a command library on
//! any episodes; [`OpenLoopProblem`] is one [`Transport`] of population x K copies, every
//! candidate's K copies restored from the same settled start states (the K packages of one
//! seeded reset) and rolled out in one batch in evaluation mode (a candidate's cost is minus its
//! episode return, and its risk over the K packages the mean blended with a quantile,
//! [`RiskMeasure`]); [`optimise_open_loop`] runs the iterations of `rlpkg optimize` for the
//! packages of an [`OptimizeConfig`].

use std::time::Instant;

use super::cem::{Cem, RiskMeasure};
use super::config::OptimizeConfig;
use super::copy_state::CopyState;
use super::curve::{CommandLibrary, KnotCurve, ACTIONS};
use super::output::{IterationCosts, OpenLoopResult, OptimizeSummary, ToolSample};
use crate::transport::run_error::{check, RunError};
use crate::transport::{Transport, TransportConfig};
use crate::{EnvError, VecEnv};

impl Transport {
    /// Every copy's actions now under the open-loop commands of `library`: the curves, of the
    /// command for the copy's target tilt, at the time since the copy's episode started (what
    /// `rlpkg optimize` rolls out, so an optimised command can be evaluated on any episodes).
    pub fn open_loop_actions(&self, library: &CommandLibrary) -> Vec<f32> {
        self.episodes
            .iter()
            .flat_map(|episode| {
                let knots = library.knots_for(episode.target_tilt);
                library
                    .curve
                    .actions(knots, episode.steps as f64 * self.dt)
                    .map(|a| a as f32)
            })
            .collect()
    }
}

/// Open-loop commands for K packages, rolled out `population` candidates at a time.
pub struct OpenLoopProblem {
    env: Transport,
    starts: Vec<CopyState>,
    population: usize,
    curve: KnotCurve,
}

impl OpenLoopProblem {
    /// The K = `packages` episodes that a reset from `seed` draws for copies 0..K (the episodes
    /// `rlpkg eval` runs first from that seed), each to be replayed by `population` candidates.
    pub fn new(
        config: TransportConfig,
        source: &str,
        seed: u64,
        packages: usize,
        population: usize,
        curve: KnotCurve,
    ) -> Result<Self, EnvError> {
        if packages == 0 || population == 0 {
            return Err(EnvError::NoEnvs(packages * population));
        }
        let mut env = Transport::new(config, population * packages, source)?;
        // An open-loop command is path speeds.
        env.drive_path_speed();
        let mut buffers = env.buffers();
        env.try_reset(seed, &mut buffers)?;
        let starts = (0..packages).map(|k| CopyState::capture(&env, k)).collect();
        env.set_retire_finished(true);
        Ok(Self {
            env,
            starts,
            population,
            curve,
        })
    }

    /// Packages per candidate.
    pub fn packages(&self) -> usize {
        self.starts.len()
    }

    /// The control interval (s).
    pub fn control_interval_s(&self) -> f64 {
        self.env.control_interval_s()
    }

    /// The task's configuration (its limits bound the decision variables).
    pub fn config(&self) -> &TransportConfig {
        &self.env.config
    }

    /// Puts package `k`'s start into copy `copy`.
    fn restore(&mut self, copy: usize, k: usize) -> Result<(), EnvError> {
        self.starts[k].restore_into(&mut self.env, copy)
    }

    /// Each candidate's cost (minus its episode return) on each package: `costs[c][k]`. At most
    /// `population` candidates; copy `c x K + k` runs candidate `c` on package `k`.
    pub fn costs(&mut self, candidates: &[Vec<f64>]) -> Result<Vec<Vec<f64>>, EnvError> {
        let k = self.packages();
        if candidates.len() > self.population
            || candidates.iter().any(|c| c.len() != self.curve.dimension())
        {
            return Err(EnvError::Simulator(format!(
                "{} candidates of {:?} variables for a population of {} of {}",
                candidates.len(),
                candidates.first().map(Vec::len),
                self.population,
                self.curve.dimension()
            )));
        }
        let copies = self.population * k;
        for copy in 0..copies {
            self.restore(copy, copy % k)?;
        }
        self.env.read_simulator()?;
        // Copies beyond the candidates given run the first one and are not read.
        let of_copy = |copy: usize| (copy / k).min(candidates.len() - 1);
        let mut buffers = self.env.buffers();
        let mut returns = vec![0.0f64; copies];
        let mut done = vec![false; copies];
        let dt = self.env.dt;
        while done.iter().any(|d| !d) {
            let actions: Vec<f32> = (0..copies)
                .flat_map(|copy| {
                    let t = self.env.episodes[copy].steps as f64 * dt;
                    self.curve
                        .actions(&candidates[of_copy(copy)], t)
                        .map(|a| a as f32)
                })
                .collect();
            self.env.step(&actions, &mut buffers)?;
            for copy in 0..copies {
                if !done[copy] {
                    returns[copy] += buffers.rewards[copy] as f64;
                    done[copy] = buffers.done(copy);
                }
            }
        }
        Ok((0..candidates.len())
            .map(|c| (0..k).map(|p| -returns[c * k + p]).collect())
            .collect())
    }

    /// The tool's motion when candidate `x` runs on package 0: its start, then every control
    /// step until the episode ends.
    pub fn trace(&mut self, x: &[f64]) -> Result<Vec<ToolSample>, EnvError> {
        let copies = self.population * self.packages();
        for copy in 0..copies {
            self.restore(copy, copy % self.packages())?;
        }
        self.env.read_simulator()?;
        let dt = self.env.dt;
        let sample = |env: &Transport| {
            let s = &env.states[0];
            let wide = |v: [f32; 3]| v.map(f64::from);
            ToolSample {
                time_s: env.episodes[0].steps as f64 * dt,
                position: wide(s.tool_position),
                orientation: s.tool_orientation.map(f64::from),
                velocity: wide(s.tool_velocity),
                angular_velocity: wide(s.tool_angular_velocity),
            }
        };
        let mut out = vec![sample(&self.env)];
        let mut buffers = self.env.buffers();
        // Only copy 0 is read: the others hold still and retire when their time runs out.
        loop {
            let mut actions = vec![0.0f32; copies * ACTIONS];
            let t = self.env.episodes[0].steps as f64 * dt;
            for (a, v) in actions.iter_mut().zip(self.curve.actions(x, t)) {
                *a = v as f32;
            }
            self.env.step(&actions, &mut buffers)?;
            out.push(sample(&self.env));
            if buffers.done(0) {
                return Ok(out);
            }
        }
    }
}

/// Optimises the open-loop command of `transport`'s task (`source` is its configuration file) for
/// the `[conditions]` packages of `config`: `[cem]` iterations over the `[knots]` of the
/// command; `progress` sees each iteration's costs, `stop` is asked after each iteration.
pub fn optimise_open_loop(
    config: &OptimizeConfig,
    transport: TransportConfig,
    source: &str,
    stop: &dyn Fn() -> bool,
    progress: &mut dyn FnMut(&IterationCosts),
) -> Result<OpenLoopResult, RunError> {
    let curve = KnotCurve {
        knots: config.knots.count,
        horizon_s: config.knots.horizon_s,
    };
    let [mean, std, lower, upper] = config.decision_space(&transport, &curve);
    let mut cem =
        Cem::new(mean, std, lower, upper, config.cem_settings()).map_err(RunError::Input)?;
    let risk = RiskMeasure {
        quantile: config.risk.quantile,
        weight: config.risk.weight,
    };
    let started = Instant::now();
    let mut problem = OpenLoopProblem::new(
        transport,
        source,
        config.conditions.seed,
        config.conditions.packages,
        config.cem.population,
        curve,
    )
    .map_err(RunError::input)?;
    let setup_s = started.elapsed().as_secs_f64();
    let mut history = Vec::new();
    let mut best: Option<(f64, Vec<f64>, Vec<f64>)> = None;
    let mut start_cost = f64::NAN;
    let optimising = Instant::now();
    for iteration in 0..config.cem.iterations {
        let candidates = cem.candidates();
        let package_costs = problem.costs(&candidates)?;
        check(stop)?;
        let costs: Vec<f64> = package_costs.iter().map(|c| risk.of(c)).collect();
        if iteration == 0 {
            start_cost = costs[0];
        }
        let top = cem.update(&candidates, &costs);
        if best.as_ref().is_none_or(|b| costs[top] < b.0) {
            best = Some((
                costs[top],
                candidates[top].clone(),
                package_costs[top].clone(),
            ));
        }
        let mut sorted = costs.clone();
        sorted.sort_by(f64::total_cmp);
        let elites = &sorted[..config.cem.elites];
        let row = IterationCosts {
            iteration,
            mean_candidate: costs[0],
            best: costs[top],
            elite_mean: elites.iter().sum::<f64>() / elites.len() as f64,
            best_so_far: best.as_ref().map_or(f64::NAN, |b| b.0),
        };
        progress(&row);
        history.push(row);
    }
    let optimise_s = optimising.elapsed().as_secs_f64();
    let (best_cost, best_knots, best_package_costs) = best.expect("at least one iteration");
    let trace = problem.trace(&best_knots)?;
    Ok(OpenLoopResult {
        summary: OptimizeSummary {
            target_tilt_deg: None,
            start_cost,
            best_cost,
            best_package_costs,
            episode_time_s: trace.last().map_or(0.0, |s| s.time_s),
            best_knots,
            iterations: history,
        },
        curve,
        control_interval_s: problem.control_interval_s(),
        trace,
        setup_s,
        optimise_s,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_candidate_replays_the_same_packages_and_identical_candidates_cost_the_same() {
        use crate::transport::test_support::{config, test_table};
        let config = config(&test_table());
        let curve = KnotCurve {
            knots: 4,
            horizon_s: 1.5,
        };
        let mut problem = OpenLoopProblem::new(config, "t.toml", 5, 2, 3, curve).unwrap();
        let slow: Vec<f64> = [[0.3; 4], [0.0; 4], [0.0; 4]].concat();
        let fast: Vec<f64> = [[0.8; 4], [0.05; 4], [0.0; 4]].concat();
        let costs = problem
            .costs(&[slow.clone(), fast.clone(), slow.clone()])
            .unwrap();
        assert_eq!(costs.len(), 3);
        assert_eq!(costs[0], costs[2]);
        assert_ne!(costs[0], costs[1]);
        assert!(costs.iter().flatten().all(|c| c.is_finite()));
        // The same again from the same starts.
        assert_eq!(problem.costs(&[slow.clone(), fast]).unwrap()[0], costs[0]);
        let trace = problem.trace(&slow).unwrap();
        assert!(trace.len() > 2);
        assert_eq!(trace[0].time_s, 0.0);
        assert!(trace.windows(2).all(|w| w[1].time_s > w[0].time_s));
    }
}
