//! Sampling-based trajectory optimisation of the transport task's open-loop command: the
//! cross-entropy method (CEM) over the knots of smooth curves in time of the three actions (path
//! speed, tilt offsets about x and z), scored by rolling every candidate out in the simulator.
//!
//! - [`KnotCurve`]: the decision variables (knots evenly spaced over a horizon) and the actions
//!   they give at each control step (uniform Catmull-Rom interpolation, held after the horizon);
//! - [`Cem`]: the sampling distribution (a diagonal Gaussian clipped to the action bounds), its
//!   candidates and the update from their costs;
//! - [`OpenLoopProblem`]: one [`Transport`] of population x K copies, every candidate's K copies
//!   restored from the same settled start states (the K packages of one seeded reset) and rolled
//!   out in one batch in evaluation mode; a candidate's cost is minus its episode return, and
//!   its risk over the K packages the mean blended with a quantile ([`RiskMeasure`]);
//! - [`optimise_open_loop`]: the iterations of `rlpkg optimize` for the packages of an
//!   [`OptimizeConfig`].
//!
//! The module lives beside the task because a candidate's copy is a replica of another copy's
//! episode (its draw, its random stream, its simulator state): that needs the task's own
//! per-copy state, which the public surface does not expose.

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};
use rlpkg_sim::EnvSnapshot;

use std::time::Instant;

use super::episode::Episode;
use super::evaluation::{check, RunError};
use super::optimize_config::OptimizeConfig;
use super::optimize_output::{IterationCosts, OpenLoopResult, OptimizeSummary};
use super::sensors::CopySensors;
use super::{sim_error, Transport, TransportConfig};
use crate::{EnvError, VecEnv};

/// Actions per control step: path speed (m/s), tilt offsets about x and z (rad).
pub const ACTIONS: usize = 3;

/// Smooth curves in time of the three actions, each given by `knots` values evenly spaced over
/// `[0, horizon_s]`. The decision vector holds the path speed's knots, then the tilt offset
/// about x's, then about z's.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct KnotCurve {
    /// Knots per action (at least 2).
    pub knots: usize,
    /// Time of the last knot (s); each action holds its last knot's value after it.
    pub horizon_s: f64,
}

impl KnotCurve {
    /// Length of a decision vector.
    pub fn dimension(&self) -> usize {
        ACTIONS * self.knots
    }

    /// The value at time `t` of the curve through `knots` (uniform Catmull-Rom: through every
    /// knot, continuous slope; the end tangents extrapolate linearly, so a linear sequence of
    /// knots gives that line exactly).
    pub fn value(&self, knots: &[f64], t: f64) -> f64 {
        let n = knots.len();
        let spacing = self.horizon_s / (n - 1) as f64;
        let x = (t / spacing).clamp(0.0, (n - 1) as f64);
        let i = (x.floor() as usize).min(n - 2);
        let u = x - i as f64;
        let p1 = knots[i];
        let p2 = knots[i + 1];
        let p0 = if i == 0 { 2.0 * p1 - p2 } else { knots[i - 1] };
        let p3 = if i + 2 < n {
            knots[i + 2]
        } else {
            2.0 * p2 - p1
        };
        let (u2, u3) = (u * u, u * u * u);
        0.5 * (2.0 * p1
            + (p2 - p0) * u
            + (2.0 * p0 - 5.0 * p1 + 4.0 * p2 - p3) * u2
            + (3.0 * p1 - p0 - 3.0 * p2 + p3) * u3)
    }

    /// The actions of decision vector `x` at time `t` (s from the episode's start).
    pub fn actions(&self, x: &[f64], t: f64) -> [f64; ACTIONS] {
        std::array::from_fn(|a| self.value(&x[a * self.knots..(a + 1) * self.knots], t))
    }
}

/// Open-loop commands for known place poses: each optimised for the nominal package at one
/// target tilt; an episode plays the command of the tilt nearest its own. One command is a
/// library of one, played whatever the tilt.
#[derive(Debug, Clone, PartialEq)]
pub struct CommandLibrary {
    /// The curve every command's knots describe.
    pub curve: KnotCurve,
    /// `(target tilt (rad), knots)` of each command.
    pub commands: Vec<(f64, Vec<f64>)>,
}

impl CommandLibrary {
    /// The knots of the command whose tilt is nearest `target_tilt_rad` (the first on a tie).
    pub fn knots_for(&self, target_tilt_rad: f64) -> &[f64] {
        let distance = |(tilt, _): &&(f64, Vec<f64>)| (tilt - target_tilt_rad).abs();
        let nearest = self
            .commands
            .iter()
            .min_by(|a, b| distance(a).total_cmp(&distance(b)))
            .expect("a library holds at least one command");
        &nearest.1
    }
}

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

/// Settings of the cross-entropy method.
#[derive(Debug, Clone, PartialEq)]
pub struct CemSettings {
    /// Candidates per iteration (the distribution's mean is the first).
    pub population: usize,
    /// Lowest-cost candidates the distribution is refitted to.
    pub elites: usize,
    /// Weight of the elites' mean and spread in each update (1 = replace the old ones).
    pub smoothing: f64,
    /// Seed of the samples.
    pub seed: u64,
}

/// The cross-entropy method's sampling distribution: a diagonal Gaussian whose samples are
/// clipped to `[lower, upper]`.
#[derive(Debug, Clone)]
pub struct Cem {
    /// Mean of each decision variable.
    pub mean: Vec<f64>,
    /// Standard deviation of each decision variable.
    pub std: Vec<f64>,
    lower: Vec<f64>,
    upper: Vec<f64>,
    settings: CemSettings,
    rng: ChaCha8Rng,
}

impl Cem {
    /// The distribution at `mean` with spread `std`, within `[lower, upper]`.
    pub fn new(
        mean: Vec<f64>,
        std: Vec<f64>,
        lower: Vec<f64>,
        upper: Vec<f64>,
        settings: CemSettings,
    ) -> Result<Self, String> {
        let n = mean.len();
        if std.len() != n || lower.len() != n || upper.len() != n || n == 0 {
            return Err(format!(
                "{n} means, {} spreads, {} lower and {} upper bounds: expected as many, >= 1",
                std.len(),
                lower.len(),
                upper.len()
            ));
        }
        if settings.population < 2 || settings.elites == 0 || settings.elites > settings.population
        {
            return Err(format!(
                "population {} and elites {}: expected population >= 2 and 1 <= elites <= \
                 population",
                settings.population, settings.elites
            ));
        }
        if !(settings.smoothing > 0.0 && settings.smoothing <= 1.0) {
            return Err(format!(
                "smoothing {}: expected in (0, 1]",
                settings.smoothing
            ));
        }
        let rng = ChaCha8Rng::seed_from_u64(settings.seed);
        let mean = mean
            .iter()
            .zip(lower.iter().zip(&upper))
            .map(|(m, (l, u))| m.clamp(*l, *u))
            .collect();
        Ok(Self {
            mean,
            std,
            lower,
            upper,
            settings,
            rng,
        })
    }

    /// This iteration's candidates: the mean, then `population - 1` clipped samples (drawn in
    /// order from the seeded stream, so the same whatever the threads that score them).
    pub fn candidates(&mut self) -> Vec<Vec<f64>> {
        let mut out = vec![self.mean.clone()];
        for _ in 1..self.settings.population {
            out.push(
                (0..self.mean.len())
                    .map(|i| {
                        let z: f64 = StandardNormal.sample(&mut self.rng);
                        (self.mean[i] + self.std[i] * z).clamp(self.lower[i], self.upper[i])
                    })
                    .collect(),
            );
        }
        out
    }

    /// Refits the distribution to the `elites` lowest-cost `candidates` (ties keep the earlier
    /// candidate; a non-finite cost ranks last), blended with the old one by `smoothing`.
    /// Returns the index of the lowest-cost candidate.
    pub fn update(&mut self, candidates: &[Vec<f64>], costs: &[f64]) -> usize {
        let rank = |c: f64| if c.is_finite() { c } else { f64::INFINITY };
        let mut order: Vec<usize> = (0..candidates.len()).collect();
        order.sort_by(|&a, &b| rank(costs[a]).total_cmp(&rank(costs[b])).then(a.cmp(&b)));
        let elites = &order[..self.settings.elites.min(order.len())];
        let w = self.settings.smoothing;
        let count = elites.len() as f64;
        for (i, (mean, std)) in self.mean.iter_mut().zip(&mut self.std).enumerate() {
            let m = elites.iter().map(|&e| candidates[e][i]).sum::<f64>() / count;
            let var = elites
                .iter()
                .map(|&e| (candidates[e][i] - m).powi(2))
                .sum::<f64>()
                / count;
            *mean = w * m + (1.0 - w) * *mean;
            *std = w * var.sqrt() + (1.0 - w) * *std;
        }
        order[0]
    }
}

/// How a candidate's costs over K packages combine into one: `(1 - weight) x mean + weight x
/// quantile`, the quantile by linear interpolation between the sorted costs.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RiskMeasure {
    /// Quantile level in [0, 1] (0.9: the cost nine packages in ten stay below).
    pub quantile: f64,
    /// Weight of the quantile in [0, 1] (0: the mean alone).
    pub weight: f64,
}

impl RiskMeasure {
    /// The risk of `costs` (one per package; at least one).
    pub fn of(&self, costs: &[f64]) -> f64 {
        let mean = costs.iter().sum::<f64>() / costs.len() as f64;
        if self.weight == 0.0 {
            return mean;
        }
        let mut sorted = costs.to_vec();
        sorted.sort_by(f64::total_cmp);
        let x = self.quantile.clamp(0.0, 1.0) * (sorted.len() - 1) as f64;
        let i = (x.floor() as usize).min(sorted.len() - 1);
        let j = (i + 1).min(sorted.len() - 1);
        let q = sorted[i] + (sorted[j] - sorted[i]) * (x - i as f64);
        (1.0 - self.weight) * mean + self.weight * q
    }
}

/// One copy's episode at a moment (its draw, random stream, simulator state and sensors), to
/// restore into any copy of a [`Transport`] on the same model.
#[derive(Debug, Clone)]
pub(super) struct CopyState {
    episode: Episode,
    rng: ChaCha8Rng,
    snapshot: EnvSnapshot,
    sensors: Option<CopySensors>,
}

impl CopyState {
    /// Copy `k` of `env` now.
    pub(super) fn capture(env: &Transport, k: usize) -> Self {
        Self {
            episode: env.episodes[k],
            rng: env.rngs[k].clone(),
            snapshot: env.sim.snapshot(k),
            sensors: env.sensors.as_ref().map(|s| s.copies[k].clone()),
        }
    }

    /// Puts this state into copy `copy` of `env` (un-retired; call `read_simulator` after the
    /// last restore of a batch).
    pub(super) fn restore_into(&self, env: &mut Transport, copy: usize) -> Result<(), EnvError> {
        env.sim.restore(copy, &self.snapshot).map_err(sim_error)?;
        env.episodes[copy] = self.episode;
        env.rngs[copy] = self.rng.clone();
        if let (Some(sensors), Some(saved)) = (&mut env.sensors, &self.sensors) {
            sensors.copies[copy] = saved.clone();
        }
        env.retired[copy] = false;
        Ok(())
    }
}

/// The tool at one control step of a rollout (world frame, SI).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ToolSample {
    /// Time since the episode's start (s).
    pub time_s: f64,
    /// Tool-point position (m).
    pub position: [f64; 3],
    /// Orientation (x, y, z, w).
    pub orientation: [f64; 4],
    /// Linear velocity (m/s).
    pub velocity: [f64; 3],
    /// Angular velocity (rad/s).
    pub angular_velocity: [f64; 3],
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
    fn the_knot_curve_passes_through_its_knots_reproduces_lines_and_holds_after_the_horizon() {
        let curve = KnotCurve {
            knots: 5,
            horizon_s: 2.0,
        };
        let knots = [0.1, 0.7, -0.3, 0.4, 0.2];
        for (i, k) in knots.iter().enumerate() {
            assert!((curve.value(&knots, 0.5 * i as f64) - k).abs() < 1e-12);
        }
        let close = |a: f64, b: f64| (a - b).abs() < 1e-12;
        assert!(close(curve.value(&knots, 5.0), 0.2));
        assert!(close(curve.value(&knots, -1.0), 0.1));
        let line = [1.0, 1.5, 2.0, 2.5, 3.0];
        for j in 0..=40 {
            let t = 0.05 * j as f64;
            assert!((curve.value(&line, t) - (1.0 + t)).abs() < 1e-12, "{t}");
        }
        // Continuous slope at an interior knot.
        let h = 1e-6;
        let left = (curve.value(&knots, 1.0) - curve.value(&knots, 1.0 - h)) / h;
        let right = (curve.value(&knots, 1.0 + h) - curve.value(&knots, 1.0)) / h;
        assert!((left - right).abs() < 1e-4, "{left} {right}");
        // The decision vector's three blocks are the three actions.
        let x: Vec<f64> = [[0.5; 5], [0.1; 5], [-0.2; 5]].concat();
        let actions = curve.actions(&x, 0.7);
        assert!(close(actions[0], 0.5) && close(actions[1], 0.1) && close(actions[2], -0.2));
        assert_eq!(curve.dimension(), 15);
    }

    fn settings(population: usize, elites: usize, smoothing: f64) -> CemSettings {
        CemSettings {
            population,
            elites,
            smoothing,
            seed: 7,
        }
    }

    #[test]
    fn cem_candidates_are_seeded_bounded_and_start_with_the_mean() {
        let make = || {
            Cem::new(
                vec![0.5, 0.0],
                vec![1.0, 0.2],
                vec![0.0, -0.1],
                vec![1.0, 0.1],
                settings(50, 5, 1.0),
            )
            .unwrap()
        };
        let (mut a, mut b) = (make(), make());
        let candidates = a.candidates();
        assert_eq!(candidates, b.candidates());
        assert_eq!(candidates[0], vec![0.5, 0.0]);
        assert_eq!(candidates.len(), 50);
        assert!(candidates
            .iter()
            .all(|c| (0.0..=1.0).contains(&c[0]) && (-0.1..=0.1).contains(&c[1])));
        // Samples differ from each other and from the next iteration's.
        assert_ne!(candidates[1], candidates[2]);
        assert_ne!(candidates[1], a.candidates()[1]);
    }

    #[test]
    fn the_cem_update_refits_to_the_elites_and_converges_on_a_quadratic() {
        let mut cem = Cem::new(
            vec![0.0, 0.0],
            vec![1.0, 1.0],
            vec![-5.0; 2],
            vec![5.0; 2],
            settings(4, 2, 1.0),
        )
        .unwrap();
        let candidates = vec![
            vec![0.0, 0.0],
            vec![1.0, 3.0],
            vec![3.0, 1.0],
            vec![2.0, 2.0],
        ];
        let best = cem.update(&candidates, &[5.0, f64::NAN, 1.0, 2.0]);
        assert_eq!(best, 2);
        assert_eq!(cem.mean, vec![2.5, 1.5]);
        assert_eq!(cem.std, vec![0.5, 0.5]);
        // Sampling, scoring and refitting finds the minimum of a bowl at (1.2, -0.7).
        let mut cem = Cem::new(
            vec![-3.0, 3.0],
            vec![2.0, 2.0],
            vec![-5.0; 2],
            vec![5.0; 2],
            settings(40, 8, 0.8),
        )
        .unwrap();
        let cost = |x: &[f64]| (x[0] - 1.2).powi(2) + (x[1] + 0.7).powi(2);
        let start = cost(&cem.mean);
        for _ in 0..30 {
            let candidates = cem.candidates();
            let costs: Vec<f64> = candidates.iter().map(|c| cost(c)).collect();
            cem.update(&candidates, &costs);
        }
        assert!(cost(&cem.mean) < 1e-4 * start, "{:?}", cem.mean);
        assert!(Cem::new(
            vec![0.0],
            vec![1.0],
            vec![0.0],
            vec![1.0],
            settings(4, 5, 1.0)
        )
        .is_err());
        assert!(Cem::new(
            vec![0.0],
            vec![1.0],
            vec![0.0],
            vec![1.0],
            settings(4, 2, 0.0)
        )
        .is_err());
    }

    #[test]
    fn the_risk_blends_the_mean_with_a_quantile() {
        let costs = [4.0, 1.0, 3.0, 2.0, 10.0];
        let mean = RiskMeasure {
            quantile: 0.9,
            weight: 0.0,
        };
        assert_eq!(mean.of(&costs), 4.0);
        let worst = RiskMeasure {
            quantile: 1.0,
            weight: 1.0,
        };
        assert_eq!(worst.of(&costs), 10.0);
        let blend = RiskMeasure {
            quantile: 0.5,
            weight: 0.5,
        };
        assert_eq!(blend.of(&costs), 0.5 * 4.0 + 0.5 * 3.0);
        let between = RiskMeasure {
            quantile: 0.875,
            weight: 1.0,
        };
        // The 0.875 quantile of 1, 2, 3, 4, 10 lies halfway between 4 and 10.
        assert!((between.of(&costs) - 7.0).abs() < 1e-12);
    }

    #[test]
    fn a_library_plays_the_command_of_the_nearest_tilt() {
        let curve = KnotCurve {
            knots: 2,
            horizon_s: 1.0,
        };
        let command = |v: f64| vec![v, v, 0.0, 0.0, 0.0, 0.0];
        let library = CommandLibrary {
            curve,
            commands: vec![
                (35f64.to_radians(), command(0.3)),
                (45f64.to_radians(), command(0.5)),
                (55f64.to_radians(), command(0.7)),
            ],
        };
        for (tilt, speed) in [
            (30.0, 0.3),
            (39.9, 0.3),
            (40.1, 0.5),
            (49.0, 0.5),
            (60.0, 0.7),
        ] {
            let tilt: f64 = tilt;
            assert_eq!(library.knots_for(tilt.to_radians())[0], speed, "{tilt}");
        }
    }

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
