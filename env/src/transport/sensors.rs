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
//! 2 %. Without `[transport.sensors.vacuum]` the load term is [`LEAK_LOAD`] in every cell and the
//! pneumatic response is taken as instantaneous within a control step.
//!
//! # Cell-to-cell vacuum dynamics (`[transport.sensors.vacuum]`)
//! A lip that holds its seal leaks little however hard it is loaded; what moves a real cup's
//! vacuum is air let in where the lip lifts. How much the load alone adds is a property of the cup
//! and the film that nothing here measures, so with this table it is drawn per episode from
//! `load_leak` (e.g. `[0, 0.31]`: down to zero, where the reading carries no trace of the seal's
//! load and only the peeled or detached lip moves it). The cup's volume behind the lip fills
//! through the supply's conductance, a first-order lag: each control step of `Δt` the held vacuum
//! moves `1 − exp(−Δt/τ)` of the way to the balance above, `τ` drawn per episode from
//! `time_constant_s`; the supply fluctuates by `supply_noise_pa` per step, common to every cup,
//! before the transducer's own noise.

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
    /// The cell's vacuum dynamics, drawn per episode (optional; without it the load term is
    /// [`LEAK_LOAD`] and the response instantaneous).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub vacuum: Option<VacuumDynamics>,
    /// How many earlier control steps' observation rows the actor sees beside the current one
    /// (newest first, each name suffixed `_prev<j>`), within [0, [`MAX_HISTORY_STEPS`]]: a
    /// window of memory, so that a trend (a cup's vacuum starting to fall) and the commands still
    /// in flight (each row holds the command sent the step before) are in its input. 0 (the
    /// default) is the current row alone.
    #[serde(default, skip_serializing_if = "is_zero")]
    pub history_steps: usize,
}

fn is_zero(n: &usize) -> bool {
    *n == 0
}

/// `[transport.sensors.vacuum]`: what differs between cells in how a cup's vacuum responds.
/// Every range is `[low, high]`, uniform per episode.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct VacuumDynamics {
    /// Leak ratio added per unit of the cup's utilisation (assumption: no cup here was measured;
    /// [`LEAK_LOAD`] is the value without this table), within [0, 1].
    #[serde(deserialize_with = "rlpkg_toml_input::array")]
    pub load_leak: [f64; 2],
    /// Time constant of the cup's pneumatic response (s), within [0, 1] (assumption: tens of
    /// milliseconds for a small bellows cup on a short hose; 0 is instantaneous).
    #[serde(deserialize_with = "rlpkg_toml_input::array")]
    pub time_constant_s: [f64; 2],
    /// Standard deviation of the supply vacuum's fluctuation per control step, common to every
    /// cup (Pa), within [0, 5000].
    pub supply_noise_pa: f64,
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

/// Largest configurable history window (control steps).
pub const MAX_HISTORY_STEPS: usize = 16;

/// The vacuum (Pa below ambient) a cup holds under the leak model, for supply vacuum
/// `supply_pa`, sealed fraction `sealed_fraction` and utilisation `utilisation` of an attached
/// cup; a detached cup holds `supply_pa / (1 + LEAK_OPEN)`.
pub fn cup_vacuum_pa(
    supply_pa: f64,
    attached: bool,
    sealed_fraction: f64,
    utilisation: f64,
) -> f64 {
    let seal = CupSeal {
        attached,
        sealed_fraction,
        utilisation,
    };
    seal.vacuum_pa(supply_pa, LEAK_LOAD)
}

/// What a cup's vacuum depends on: the simulator's state of its seal.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CupSeal {
    /// Whether the cup holds the film.
    pub attached: bool,
    /// Fraction of the lip still sealed.
    pub sealed_fraction: f64,
    /// The seal's load over its limit (1 at failure).
    pub utilisation: f64,
}

impl CupSeal {
    /// The vacuum (Pa below ambient) the cup holds at balance for supply vacuum `supply_pa` and
    /// the load term `load_leak` (leak ratio per unit of utilisation).
    pub fn vacuum_pa(&self, supply_pa: f64, load_leak: f64) -> f64 {
        let leak = if self.attached {
            LEAK_SEALED
                + LEAK_PEELED * (1.0 - self.sealed_fraction.clamp(0.0, 1.0))
                + load_leak * self.utilisation.max(0.0)
        } else {
            LEAK_OPEN
        };
        supply_pa / (1.0 + leak)
    }
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
    /// Leak ratio per unit of utilisation in this episode's cell.
    load_leak: f64,
    /// Time constant of the cups' pneumatic response in this episode's cell (s).
    time_constant_s: f64,
    /// Each cup's vacuum now (Pa below ambient), before the transducer's noise.
    cup_vacuum_pa: Vec<f64>,
    /// Readings on their way to the policy.
    pub(super) readings: DelayLine,
    /// Actions on their way to the robot.
    pub(super) actions: DelayLine,
    /// The actor's observation rows of the last [`SensorConfig::history_steps`] control steps
    /// before the current one, newest first.
    #[serde(default)]
    pub(super) history: Vec<Vec<f64>>,
    /// The commands the policy sent in the last [`SensorConfig::history_steps`] control steps,
    /// newest first (what the cell's controller knows it sent, still in flight or executed).
    #[serde(default)]
    pub(super) sent: Vec<[f64; 3]>,
}

/// Raw readings of one copy before noise: tool pose and twist (world), cups, wrist wrench.
pub(super) struct Reading {
    pub(super) position: [f64; 3],
    pub(super) orientation: [f64; 4],
    pub(super) velocity: [f64; 3],
    pub(super) angular_velocity: [f64; 3],
    pub(super) cups: Vec<CupSeal>,
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
    /// The control step (s): the interval between two readings.
    step_s: f64,
}

/// The sensor stream of copy `env` for a reset with `seed` (apart from the copy's episode
/// stream, so that the episodes draw the same conditions with sensors as without).
fn sensor_rng(seed: u64, env: usize) -> ChaCha8Rng {
    let mut rng = ChaCha8Rng::seed_from_u64(seed.wrapping_add(env as u64));
    rng.set_stream(2 << 32);
    rng
}

/// Uniform in `[lo, hi]`.
fn uniform(rng: &mut ChaCha8Rng, [lo, hi]: [f64; 2]) -> f64 {
    if lo < hi {
        rng.random_range(lo..=hi)
    } else {
        lo
    }
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
    /// Sensors of `num_envs` copies read every `step_s` seconds (streams set by
    /// [`Sensors::reseed`]).
    pub(super) fn new(config: SensorConfig, num_envs: usize, step_s: f64) -> Self {
        let copy = CopySensors {
            rng: rng_to_words(&sensor_rng(0, 0)),
            supply_pa: 0.0,
            load_leak: LEAK_LOAD,
            time_constant_s: 0.0,
            cup_vacuum_pa: Vec::new(),
            readings: DelayLine::filled(&[], 0),
            actions: DelayLine::filled(&[0.0; 3], 0),
            history: Vec::new(),
            sent: Vec::new(),
        };
        Self {
            config,
            copies: vec![copy; num_envs],
            step_s,
        }
    }

    /// Restarts every copy's sensor stream from `seed`.
    pub(super) fn reseed(&mut self, seed: u64) {
        for (env, copy) in self.copies.iter_mut().enumerate() {
            copy.rng = rng_to_words(&sensor_rng(seed, env));
        }
    }

    /// The noisy reading row of `reading` with the cups holding `vacuum_pa`, drawn from `rng`.
    fn noisy_row(&self, rng: &mut ChaCha8Rng, reading: &Reading, vacuum_pa: &[f64]) -> Vec<f64> {
        let n = &self.config.noise;
        let mut gauss = |sigma: f64| -> f64 {
            let z: f64 = StandardNormal.sample(rng);
            sigma * z
        };
        let mut row = Vec::with_capacity(row::CUPS + vacuum_pa.len() + 6);
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
        row.extend(vacuum_pa.iter().map(|&p| -p + gauss(n.vacuum_pa)));
        for (k, &w) in reading.wrench.iter().enumerate() {
            let sigma = if k < 3 { n.force_n } else { n.torque_n_m };
            row.push(w + gauss(sigma));
        }
        row
    }

    /// Starts copy `env`'s episode: draws its supply vacuum (unless the package's seal has its
    /// own, `package_supply_pa`, which the sensors then read), delays and cell, and fills its
    /// delay lines with the first reading (the cups at balance) and the hold action.
    pub(super) fn start_episode(
        &mut self,
        env: usize,
        package_supply_pa: Option<f64>,
        reading: &Reading,
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
        // Drawn only with the table, so that a config without it keeps its streams.
        let (load_leak, time_constant_s) = match &self.config.vacuum {
            Some(v) => (
                uniform(&mut rng, v.load_leak),
                uniform(&mut rng, v.time_constant_s),
            ),
            None => (LEAK_LOAD, 0.0),
        };
        let cup_vacuum_pa: Vec<f64> = reading
            .cups
            .iter()
            .map(|c| c.vacuum_pa(supply_pa, load_leak))
            .collect();
        let row = self.noisy_row(&mut rng, reading, &cup_vacuum_pa);
        self.copies[env] = CopySensors {
            rng: rng_to_words(&rng),
            supply_pa,
            load_leak,
            time_constant_s,
            cup_vacuum_pa,
            readings: DelayLine::filled(&row, observation_delay),
            actions: DelayLine::filled(&[0.0; 3], action_delay),
            history: Vec::new(),
            sent: vec![[0.0; 3]; self.config.history_steps],
        };
    }

    /// Takes copy `env`'s reading of this control step: each cup's vacuum moves toward its
    /// balance under the supply of this step (with its fluctuation) by the cell's lag.
    pub(super) fn measure(&mut self, env: usize, reading: &Reading) {
        let mut rng = rng_from_words(&self.copies[env].rng);
        let copy = &self.copies[env];
        let mut supply_pa = copy.supply_pa;
        if let Some(v) = &self.config.vacuum {
            let z: f64 = StandardNormal.sample(&mut rng);
            supply_pa += v.supply_noise_pa * z;
        }
        // The exact step of a first-order lag over one control step; none without a lag.
        let follow =
            (copy.time_constant_s > 0.0).then(|| 1.0 - (-self.step_s / copy.time_constant_s).exp());
        let cup_vacuum_pa: Vec<f64> = reading
            .cups
            .iter()
            .zip(&copy.cup_vacuum_pa)
            .map(|(c, &now)| {
                let balance = c.vacuum_pa(supply_pa, copy.load_leak);
                follow.map_or(balance, |k| now + k * (balance - now))
            })
            .collect();
        let row = self.noisy_row(&mut rng, reading, &cup_vacuum_pa);
        let copy = &mut self.copies[env];
        copy.rng = rng_to_words(&rng);
        copy.cup_vacuum_pa = cup_vacuum_pa;
        copy.readings.push(&row);
    }

    /// The action copy `env`'s robot executes now, with `action` the policy's newest.
    pub(super) fn delay_action(&mut self, env: usize, action: &[f32]) -> [f32; 3] {
        let row: Vec<f64> = action.iter().map(|&a| a as f64).collect();
        let copy = &mut self.copies[env];
        if self.config.history_steps > 0 {
            copy.sent.insert(0, [row[0], row[1], row[2]]);
            copy.sent.truncate(self.config.history_steps);
        }
        let out = copy.actions.push(&row);
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
            vacuum: None,
            history_steps: 0,
        }
    }

    /// A reading with every cup attached, sealed over `sealed_fraction` of its lip and at
    /// `utilisation`.
    fn reading_of(sealed_fraction: f64, utilisation: f64) -> Reading {
        let cup = CupSeal {
            attached: true,
            sealed_fraction,
            utilisation,
        };
        Reading {
            position: [0.1, 0.2, 0.3],
            orientation: [0.0, 0.0, 0.0, 1.0],
            velocity: [0.0; 3],
            angular_velocity: [0.0; 3],
            cups: vec![cup; 4],
            wrench: vec![0.0, -3.0, 0.0, 0.0, 0.0, 0.0],
        }
    }

    fn reading() -> Reading {
        reading_of(1.0, 0.2)
    }

    /// A control step of 50 ms.
    const STEP_S: f64 = 0.05;

    #[test]
    fn no_reading_depends_on_the_load_when_the_load_term_is_zero() {
        // Two cells alike but for the load term: the same seeds, the same lip, utilisation 0.1
        // or 0.9. With the term drawn at zero every row the actor gets is the same; with the
        // term of the model without the table, the vacuum rows differ.
        let rows = |vacuum: Option<VacuumDynamics>, utilisation: f64| {
            let mut sensors = Sensors::new(SensorConfig { vacuum, ..config() }, 2, STEP_S);
            sensors.reseed(11);
            let mut out = Vec::new();
            for env in 0..2 {
                sensors.start_episode(env, None, &reading_of(0.9, utilisation));
                for _ in 0..5 {
                    sensors.measure(env, &reading_of(0.7, utilisation));
                    out.push(sensors.copies[env].readings.output().to_vec());
                }
            }
            out
        };
        let zero = VacuumDynamics {
            load_leak: [0.0, 0.0],
            time_constant_s: [0.01, 0.06],
            supply_noise_pa: 100.0,
        };
        assert_eq!(rows(Some(zero.clone()), 0.1), rows(Some(zero), 0.9));
        assert_ne!(rows(None, 0.1), rows(None, 0.9));
        let some = VacuumDynamics {
            load_leak: [0.0, 0.31],
            time_constant_s: [0.01, 0.06],
            supply_noise_pa: 100.0,
        };
        assert_ne!(rows(Some(some.clone()), 0.1), rows(Some(some), 0.9));
    }

    #[test]
    fn the_vacuum_follows_a_step_with_the_cells_time_constant() {
        // A sealed cup whose lip peels to 40 % at once: its vacuum (before the transducer's
        // noise) moves to the new balance as 1 - exp(-t / tau), tau 30 ms, read every 50 ms.
        let tau = 0.03;
        let lagged = SensorConfig {
            vacuum: Some(VacuumDynamics {
                load_leak: [0.0, 0.0],
                time_constant_s: [tau, tau],
                supply_noise_pa: 0.0,
            }),
            ..config()
        };
        let mut sensors = Sensors::new(lagged, 1, STEP_S);
        sensors.reseed(2);
        sensors.start_episode(0, Some(25e3), &reading_of(1.0, 0.5));
        let before = CupSeal {
            attached: true,
            sealed_fraction: 1.0,
            utilisation: 0.0,
        }
        .vacuum_pa(25e3, 0.0);
        let after = CupSeal {
            attached: true,
            sealed_fraction: 0.4,
            utilisation: 0.0,
        }
        .vacuum_pa(25e3, 0.0);
        assert_eq!(sensors.copies[0].cup_vacuum_pa, vec![before; 4]);
        for k in 1..=6 {
            sensors.measure(0, &reading_of(0.4, 0.5));
            let t = k as f64 * STEP_S;
            let expected = after + (before - after) * (-t / tau).exp();
            for &held in &sensors.copies[0].cup_vacuum_pa {
                assert!(
                    (held - expected).abs() < 1e-6 * before,
                    "{t} s: {held} {expected}"
                );
            }
        }
        // Without a lag the vacuum is at its balance at once.
        let mut sensors = Sensors::new(config(), 1, STEP_S);
        sensors.start_episode(0, Some(25e3), &reading_of(1.0, 0.0));
        sensors.measure(0, &reading_of(0.4, 0.0));
        let at_once = cup_vacuum_pa(25e3, true, 0.4, 0.0);
        assert_eq!(sensors.copies[0].cup_vacuum_pa, vec![at_once; 4]);
    }

    #[test]
    fn each_cell_draws_its_load_term_and_lag_within_their_ranges() {
        let mut config = config();
        config.vacuum = Some(VacuumDynamics {
            load_leak: [0.0, 0.31],
            time_constant_s: [0.01, 0.06],
            supply_noise_pa: 0.0,
        });
        let mut sensors = Sensors::new(config, 64, STEP_S);
        sensors.reseed(5);
        for env in 0..64 {
            sensors.start_episode(env, None, &reading());
        }
        let leaks: Vec<f64> = sensors.copies.iter().map(|c| c.load_leak).collect();
        let taus: Vec<f64> = sensors.copies.iter().map(|c| c.time_constant_s).collect();
        assert!(leaks.iter().all(|l| (0.0..=0.31).contains(l)));
        assert!(taus.iter().all(|t| (0.01..=0.06).contains(t)));
        assert!(leaks.iter().any(|&l| l < 0.05) && leaks.iter().any(|&l| l > 0.26));
        assert!(taus.iter().any(|&t| t < 0.02) && taus.iter().any(|&t| t > 0.05));
    }

    #[test]
    fn each_copy_delays_actions_by_its_own_drawn_steps() {
        let mut sensors = Sensors::new(config(), 16, STEP_S);
        sensors.reseed(3);
        for env in 0..16 {
            sensors.start_episode(env, None, &reading());
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
            let mut sensors = Sensors::new(config(), 4, STEP_S);
            sensors.reseed(seed);
            for env in copies {
                sensors.start_episode(env, None, &reading());
                for _ in 0..3 {
                    sensors.measure(env, &reading());
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
        let mut sensors = Sensors::new(config(), 1, STEP_S);
        sensors.reseed(1);
        sensors.start_episode(0, Some(25e3), &reading());
        let (mut sum, mut sum2, n) = (0.0, 0.0, 4000);
        let clean = -cup_vacuum_pa(25e3, true, 1.0, 0.2);
        for _ in 0..n {
            sensors.measure(0, &reading());
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
