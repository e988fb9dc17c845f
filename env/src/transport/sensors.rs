//! The cell's sensors (`observation = "sensors"`): what a real transport cell measures, with noise
//! and latency, so that a policy trained on it needs nothing the simulator alone knows.
//!
//! # Sensors (per control step)
//! - **Vacuum pressure of each cup** (`cup<k>_vacuum_pressure`, Pa, gauge: 0 is ambient, negative
//!   is vacuum), from the leak model below.
//! - **Wrist force-torque sensor** (optional, `wrist_force_{x,y,z}` in N and
//!   `wrist_torque_{x,y,z}` in N m, tool frame): the sum of the forces the cups' springs exert on
//!   the tool and their moment about the tool point.
//! - **Joint encoders** through the robot's forward kinematics: the tool pose (position in m,
//!   orientation) and twist (m/s, rad/s).
//!
//! Each reading gets zero-mean Gaussian noise of its own standard deviation
//! ([`SensorNoise`]), drawn from the copy's own sensor stream. Readings reach the policy through
//! a delay line of `d_obs` control steps, and the policy's actions reach the robot through one of
//! `d_act` steps; both are drawn per episode from their configured ranges, as is the supply
//! vacuum.
//!
//! # Leak model of a suction cup
//! The vacuum generator holds the supply line at `Δp_s` below ambient (the cell's supply vacuum,
//! 20-30 kPa, drawn per episode). The cup connects to it through a fixed conductance `G_s` and
//! leaks to ambient through its lip with conductance `G_l`. With the flows balanced (laminar,
//! linear in the pressure difference), `G_s (Δp_s − Δp_c) = G_l Δp_c`, so the cup holds
//!
//! `Δp_c = Δp_s / (1 + λ)`, with the leak ratio `λ = G_l / G_s`,
//!
//! and the sensor reads the gauge pressure `p_c = −Δp_c`. The lip leaks more the more of it has
//! peeled off and the harder it is loaded:
//!
//! `λ = λ_sealed + λ_peeled (1 − f) + λ_load u` for an attached cup, `λ = λ_open` for a detached one,
//!
//! where `f` is the sealed fraction of the lip and `u` the cup's utilisation (the larger of its
//! peel load over the holding force and its shear load over the friction limit, 1 at failure;
//! [`rlpkg_sim::CupLoad`]). `λ` grows with `1 − f` and `u`, so the vacuum falls (the pressure rises
//! toward ambient) monotonically as the seal is peeled or sheared. The ratios are dimensionless
//! ([`LEAK_SEALED`], [`LEAK_PEELED`], [`LEAK_LOAD`], [`LEAK_OPEN`]): a sound seal holds 98 % of
//! the supply vacuum, one at its failure load about 75 %, a fully peeled lip 20 % and an open cup
//! 2 %. The pneumatic response is taken as instantaneous within a control step (its time constant,
//! tens of milliseconds, is covered by the observation delay).

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};
use serde::{Deserialize, Serialize};

use crate::{rng_from_words, rng_to_words, RNG_WORDS};

/// Leak ratio `λ` of a fully sealed, unloaded lip.
pub const LEAK_SEALED: f64 = 0.02;
/// Leak ratio added by a fully peeled lip (`f = 0`).
pub const LEAK_PEELED: f64 = 3.98;
/// Leak ratio added per unit of cup utilisation.
pub const LEAK_LOAD: f64 = 0.31;
/// Leak ratio of a detached cup (open to ambient).
pub const LEAK_OPEN: f64 = 49.0;

/// The `[transport.sensors]` table (with `observation = "sensors"`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SensorConfig {
    /// The cell's supply vacuum below ambient, `[low, high]` (kPa), uniform per episode.
    #[serde(deserialize_with = "rlpkg_toml_input::array")]
    pub supply_vacuum_kpa: [f64; 2],
    /// Whether the cell has a wrist force-torque sensor (its six readings join the actor's
    /// observations).
    pub wrist_force_torque: bool,
    /// Observation delay `[low, high]` in control steps, uniform integer per episode.
    #[serde(deserialize_with = "rlpkg_toml_input::array")]
    pub observation_delay_steps: [usize; 2],
    /// Action delay `[low, high]` in control steps, uniform integer per episode.
    #[serde(deserialize_with = "rlpkg_toml_input::array")]
    pub action_delay_steps: [usize; 2],
    /// Standard deviations of the readings' noise.
    pub noise: SensorNoise,
}

/// Standard deviation of each sensor's zero-mean Gaussian noise (SI, per component).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SensorNoise {
    /// Cup vacuum pressure (Pa).
    pub vacuum_pa: f64,
    /// Wrist force (N).
    pub force_n: f64,
    /// Wrist torque (N m).
    pub torque_n_m: f64,
    /// Tool position (m).
    pub position_m: f64,
    /// Tool orientation (rad, a small rotation about each axis).
    pub orientation_rad: f64,
    /// Tool linear velocity (m/s).
    pub velocity_m_s: f64,
    /// Tool angular velocity (rad/s).
    pub angular_velocity_rad_s: f64,
}

/// Largest configurable delay (control steps).
pub const MAX_DELAY_STEPS: usize = 10;

/// The vacuum (Pa below ambient) a cup holds under the leak model, for supply vacuum
/// `supply_pa`, sealed fraction `sealed_fraction` and utilisation `utilisation` of an attached
/// cup; a detached cup holds `supply_pa / (1 + LEAK_OPEN)`.
pub fn cup_vacuum_pa(
    supply_pa: f64,
    attached: bool,
    sealed_fraction: f64,
    utilisation: f64,
) -> f64 {
    let leak = if attached {
        LEAK_SEALED
            + LEAK_PEELED * (1.0 - sealed_fraction.clamp(0.0, 1.0))
            + LEAK_LOAD * utilisation.max(0.0)
    } else {
        LEAK_OPEN
    };
    supply_pa / (1.0 + leak)
}

/// A fixed delay of `delay` steps for rows of `width` numbers: what is pushed comes out exactly
/// `delay` pushes later (delay 0: at once).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DelayLine {
    /// The last `delay + 1` rows, oldest first.
    rows: Vec<Vec<f64>>,
    delay: usize,
}

impl DelayLine {
    /// A line of `delay` steps that has held `row` for ever (an episode's first reading).
    pub fn filled(row: &[f64], delay: usize) -> Self {
        Self {
            rows: vec![row.to_vec(); delay + 1],
            delay,
        }
    }

    /// Pushes `row` in and returns the row pushed `delay` steps ago.
    pub fn push(&mut self, row: &[f64]) -> &[f64] {
        self.rows.rotate_left(1);
        let newest = self.rows.last_mut().expect("at least one row");
        newest.clear();
        newest.extend_from_slice(row);
        &self.rows[0]
    }

    /// The row the line gives out now (pushed `delay` steps ago).
    pub fn output(&self) -> &[f64] {
        &self.rows[0]
    }

    /// The delay (steps).
    pub fn delay(&self) -> usize {
        self.delay
    }
}

/// One copy's sensors during an episode.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub(super) struct CopySensors {
    /// The copy's sensor stream, as [`rng_to_words`].
    rng: [u64; RNG_WORDS],
    /// Supply vacuum of the episode (Pa below ambient).
    pub(super) supply_pa: f64,
    /// Readings on their way to the policy.
    pub(super) readings: DelayLine,
    /// Actions on their way to the robot.
    pub(super) actions: DelayLine,
}

/// Raw readings of one copy before noise: tool pose and twist (world), cups, wrist wrench.
pub(super) struct Reading {
    pub(super) position: [f64; 3],
    pub(super) orientation: [f64; 4],
    pub(super) velocity: [f64; 3],
    pub(super) angular_velocity: [f64; 3],
    pub(super) vacuum_pa: Vec<f64>,
    /// Force then torque, tool frame (empty without a wrist sensor).
    pub(super) wrench: Vec<f64>,
}

/// Offsets of a reading row's parts ([`Sensors::row_of`]).
pub(super) mod row {
    /// Tool position (3).
    pub const POSITION: usize = 0;
    /// Tool orientation quaternion x, y, z, w (4).
    pub const ORIENTATION: usize = 3;
    /// Tool linear velocity (3).
    pub const VELOCITY: usize = 7;
    /// Tool angular velocity (3).
    pub const ANGULAR_VELOCITY: usize = 10;
    /// Cup vacuum pressures, then the wrench.
    pub const CUPS: usize = 13;
}

/// The sensors of every copy.
#[derive(Debug, Clone, PartialEq)]
pub(super) struct Sensors {
    pub(super) config: SensorConfig,
    pub(super) copies: Vec<CopySensors>,
}

/// The sensor stream of copy `env` for a reset with `seed` (apart from the copy's episode
/// stream, so that the episodes draw the same conditions with sensors as without).
fn sensor_rng(seed: u64, env: usize) -> ChaCha8Rng {
    let mut rng = ChaCha8Rng::seed_from_u64(seed.wrapping_add(env as u64));
    rng.set_stream(2 << 32);
    rng
}

/// Uniform integer in `[lo, hi]`.
fn uniform_steps(rng: &mut ChaCha8Rng, [lo, hi]: [usize; 2]) -> usize {
    if lo < hi {
        rng.random_range(lo..=hi)
    } else {
        lo
    }
}

impl Sensors {
    /// Sensors of `num_envs` copies (streams set by [`Sensors::reseed`]).
    pub(super) fn new(config: SensorConfig, num_envs: usize) -> Self {
        let copy = CopySensors {
            rng: rng_to_words(&sensor_rng(0, 0)),
            supply_pa: 0.0,
            readings: DelayLine::filled(&[], 0),
            actions: DelayLine::filled(&[0.0; 3], 0),
        };
        Self {
            config,
            copies: vec![copy; num_envs],
        }
    }

    /// Restarts every copy's sensor stream from `seed`.
    pub(super) fn reseed(&mut self, seed: u64) {
        for (env, copy) in self.copies.iter_mut().enumerate() {
            copy.rng = rng_to_words(&sensor_rng(seed, env));
        }
    }

    /// The noisy reading row of `reading`, drawn from `rng`.
    fn noisy_row(&self, rng: &mut ChaCha8Rng, reading: &Reading) -> Vec<f64> {
        let n = &self.config.noise;
        let mut gauss = |sigma: f64| -> f64 {
            let z: f64 = StandardNormal.sample(rng);
            sigma * z
        };
        let mut row = Vec::with_capacity(row::CUPS + reading.vacuum_pa.len() + 6);
        row.extend(reading.position.map(|x| x + gauss(n.position_m)));
        let turn = glam::DVec3::new(
            gauss(n.orientation_rad),
            gauss(n.orientation_rad),
            gauss(n.orientation_rad),
        );
        let q = glam::DQuat::from_array(reading.orientation);
        let q = (glam::DQuat::from_scaled_axis(turn) * q).normalize();
        row.extend(q.to_array());
        row.extend(reading.velocity.map(|x| x + gauss(n.velocity_m_s)));
        row.extend(
            reading
                .angular_velocity
                .map(|x| x + gauss(n.angular_velocity_rad_s)),
        );
        row.extend(reading.vacuum_pa.iter().map(|&p| -p + gauss(n.vacuum_pa)));
        for (k, &w) in reading.wrench.iter().enumerate() {
            let sigma = if k < 3 { n.force_n } else { n.torque_n_m };
            row.push(w + gauss(sigma));
        }
        row
    }

    /// Starts copy `env`'s episode: draws its supply vacuum (unless the package's seal has its
    /// own, `package_supply_pa`, which the sensors then read) and delays, and fills its delay
    /// lines with the first reading (`reading` taken with the supply vacuum) and the hold action.
    pub(super) fn start_episode(
        &mut self,
        env: usize,
        package_supply_pa: Option<f64>,
        reading: impl FnOnce(f64) -> Reading,
    ) {
        let mut rng = rng_from_words(&self.copies[env].rng);
        let [lo, hi] = self.config.supply_vacuum_kpa;
        let supply_pa = match package_supply_pa {
            Some(pa) => pa,
            None if lo < hi => 1e3 * rng.random_range(lo..=hi),
            None => 1e3 * lo,
        };
        let observation_delay = uniform_steps(&mut rng, self.config.observation_delay_steps);
        let action_delay = uniform_steps(&mut rng, self.config.action_delay_steps);
        let row = self.noisy_row(&mut rng, &reading(supply_pa));
        self.copies[env] = CopySensors {
            rng: rng_to_words(&rng),
            supply_pa,
            readings: DelayLine::filled(&row, observation_delay),
            actions: DelayLine::filled(&[0.0; 3], action_delay),
        };
    }

    /// Takes copy `env`'s reading of this control step.
    pub(super) fn measure(&mut self, env: usize, reading: &Reading) {
        let mut rng = rng_from_words(&self.copies[env].rng);
        let row = self.noisy_row(&mut rng, reading);
        let copy = &mut self.copies[env];
        copy.rng = rng_to_words(&rng);
        copy.readings.push(&row);
    }

    /// The action copy `env`'s robot executes now, with `action` the policy's newest.
    pub(super) fn delay_action(&mut self, env: usize, action: &[f32]) -> [f32; 3] {
        let row: Vec<f64> = action.iter().map(|&a| a as f64).collect();
        let out = self.copies[env].actions.push(&row);
        [out[0] as f32, out[1] as f32, out[2] as f32]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn vacuum_falls_monotonically_as_the_seal_leaks() {
        let supply = 25e3;
        let sound = cup_vacuum_pa(supply, true, 1.0, 0.0);
        assert!((sound - supply / 1.02).abs() < 1e-9);
        let mut last = sound;
        for k in 1..=50 {
            let u = k as f64 * 0.04;
            let p = cup_vacuum_pa(supply, true, 1.0, u);
            assert!(p < last, "utilisation {u}");
            last = p;
        }
        let mut last = sound;
        for k in 1..=20 {
            let f = 1.0 - k as f64 * 0.05;
            let p = cup_vacuum_pa(supply, true, f, 0.3);
            assert!(p < cup_vacuum_pa(supply, true, f + 0.05, 0.3) && p < last);
            last = p;
        }
        let open = cup_vacuum_pa(supply, false, 1.0, 0.0);
        assert!(open < cup_vacuum_pa(supply, true, 0.0, 1.0));
        assert!((open / supply - 0.02).abs() < 1e-12);
        // At the failure load about three quarters of the supply vacuum is left.
        let at_failure = cup_vacuum_pa(supply, true, 1.0, 1.0) / supply;
        assert!((0.7..0.8).contains(&at_failure), "{at_failure}");
        // A stronger supply holds a stronger vacuum.
        assert!(cup_vacuum_pa(30e3, true, 0.8, 0.5) > cup_vacuum_pa(20e3, true, 0.8, 0.5));
    }

    #[test]
    fn a_pushed_row_comes_out_exactly_delay_steps_later() {
        for delay in 0..4 {
            let mut line = DelayLine::filled(&[-1.0, -2.0], delay);
            for t in 0..12 {
                let out = line.push(&[t as f64, 10.0 * t as f64]).to_vec();
                let expected = if t >= delay {
                    let s = (t - delay) as f64;
                    vec![s, 10.0 * s]
                } else {
                    vec![-1.0, -2.0]
                };
                assert_eq!(out, expected, "delay {delay}, step {t}");
                assert_eq!(line.output(), &expected[..]);
            }
            assert_eq!(line.delay(), delay);
        }
    }

    fn config() -> SensorConfig {
        SensorConfig {
            supply_vacuum_kpa: [20.0, 30.0],
            wrist_force_torque: true,
            observation_delay_steps: [1, 2],
            action_delay_steps: [1, 2],
            noise: SensorNoise {
                vacuum_pa: 200.0,
                force_n: 0.1,
                torque_n_m: 0.01,
                position_m: 1e-3,
                orientation_rad: 1e-3,
                velocity_m_s: 1e-2,
                angular_velocity_rad_s: 1e-2,
            },
        }
    }

    fn reading(supply_pa: f64) -> Reading {
        Reading {
            position: [0.1, 0.2, 0.3],
            orientation: [0.0, 0.0, 0.0, 1.0],
            velocity: [0.0; 3],
            angular_velocity: [0.0; 3],
            vacuum_pa: vec![cup_vacuum_pa(supply_pa, true, 1.0, 0.2); 4],
            wrench: vec![0.0, -3.0, 0.0, 0.0, 0.0, 0.0],
        }
    }

    #[test]
    fn each_copy_delays_actions_by_its_own_drawn_steps() {
        let mut sensors = Sensors::new(config(), 16);
        sensors.reseed(3);
        for env in 0..16 {
            sensors.start_episode(env, None, reading);
        }
        let delays: Vec<usize> = sensors.copies.iter().map(|c| c.actions.delay()).collect();
        assert!(delays.iter().all(|d| (1..=2).contains(d)));
        assert!(delays.contains(&1) && delays.contains(&2), "{delays:?}");
        for c in &sensors.copies {
            assert!((1..=2).contains(&c.readings.delay()));
            assert!((20e3..=30e3).contains(&c.supply_pa));
        }
        for t in 0..6 {
            for (env, &d) in delays.iter().enumerate() {
                let sent = [t as f32, env as f32, 0.5];
                let applied = sensors.delay_action(env, &sent);
                let expected = if t >= d {
                    [(t - d) as f32, env as f32, 0.5]
                } else {
                    [0.0; 3]
                };
                assert_eq!(applied, expected, "copy {env}, step {t}");
            }
        }
    }

    #[test]
    fn noise_follows_the_seed_and_each_copy_its_own_stream() {
        let run = |seed: u64, copies: std::ops::Range<usize>| {
            let mut sensors = Sensors::new(config(), 4);
            sensors.reseed(seed);
            for env in copies {
                sensors.start_episode(env, None, reading);
                for _ in 0..3 {
                    sensors.measure(env, &reading(25e3));
                }
            }
            sensors.copies
        };
        let all = run(7, 0..4);
        assert_eq!(all, run(7, 0..4));
        // A copy's readings do not depend on which other copies were measured (or in which
        // order, on which thread).
        let alone = run(7, 2..3);
        assert_eq!(all[2], alone[2]);
        assert_ne!(all[1].readings, all[2].readings);
        assert_ne!(all, run(8, 0..4));
        // The noise has about the configured spread.
        let mut sensors = Sensors::new(config(), 1);
        sensors.reseed(1);
        sensors.start_episode(0, None, reading);
        let (mut sum, mut sum2, n) = (0.0, 0.0, 4000);
        let clean = -reading(25e3).vacuum_pa[0];
        for _ in 0..n {
            sensors.measure(0, &reading(25e3));
            let newest = sensors.copies[0].readings.rows.last().unwrap()[row::CUPS] - clean;
            sum += newest;
            sum2 += newest * newest;
        }
        let mean = sum / n as f64;
        let std = (sum2 / n as f64 - mean * mean).sqrt();
        assert!(
            mean.abs() < 20.0 && (std / 200.0 - 1.0).abs() < 0.1,
            "{mean} {std}"
        );
    }
}
