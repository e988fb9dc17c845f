//! What the policy sees: the actor's and the critic's observation names and units, the spec built
//! from them, and the rows filled from the simulator state and the copy's episode.

use glam::{DQuat, DVec3};
use rlpkg_sim::Model;

use super::config::ObservationMode;
use super::geometry::{quat, rotation_between, v3};
use super::sensors::{row, CupSeal, Reading};
use super::{load_scene, sim_error, Transport, TransportConfig, ID};
use crate::{EnvError, EnvSpec, Space, SpaceKind, StepBuffers};

/// The actor's observations (name, unit) before the cups': the tool's pose relative to the goal
/// and its twist (from the joint encoders), and the controller's own reference, clock, goal and
/// last command. With `observation = "privileged"` the first twelve are the simulator's exact
/// values and each cup's utilisation (`cup<k>_utilisation`, unit `1`) follows; with `"sensors"`
/// they are measured (noisy, delayed) and each cup's vacuum pressure (`cup<k>_vacuum_pressure`,
/// Pa) follows, then the wrist wrench ([`WRIST_OBSERVATIONS`]) when the cell has the sensor.
pub const ACTOR_OBSERVATIONS: [(&str, &str); 19] = [
    ("goal_dx", "m"),
    ("goal_dy", "m"),
    ("goal_dz", "m"),
    ("goal_rotation_x", "rad"),
    ("goal_rotation_y", "rad"),
    ("goal_rotation_z", "rad"),
    ("tool_velocity_x", "m/s"),
    ("tool_velocity_y", "m/s"),
    ("tool_velocity_z", "m/s"),
    ("tool_angular_velocity_x", "rad/s"),
    ("tool_angular_velocity_y", "rad/s"),
    ("tool_angular_velocity_z", "rad/s"),
    ("path_progress", "1"),
    ("path_speed", "m/s"),
    ("episode_time", "s"),
    ("target_tilt", "rad"),
    ("previous_path_speed_command", "m/s"),
    ("previous_tilt_offset_x", "rad"),
    ("previous_tilt_offset_z", "rad"),
];

/// What two of [`ACTOR_OBSERVATIONS`] become with `[transport.profile_rate]` (index, name,
/// unit): the time along the motion profile instead of the episode's, and the last clock rate
/// instead of the last path speed command.
const PROFILE_RATE_OBSERVATIONS: [(usize, &str, &str); 2] = [
    (14, "profile_clock", "s"),
    (16, "previous_profile_rate", "1"),
];

/// How many of [`ACTOR_OBSERVATIONS`] come from the tool's pose and twist (measured with
/// sensors; the critic then also sees their exact values, named `exact_<name>`).
const MEASURED_TOOL_OBSERVATIONS: usize = 12;

/// The wrist force-torque sensor's readings (name, unit), tool frame.
pub const WRIST_OBSERVATIONS: [(&str, &str); 6] = [
    ("wrist_force_x", "N"),
    ("wrist_force_y", "N"),
    ("wrist_force_z", "N"),
    ("wrist_torque_x", "N m"),
    ("wrist_torque_y", "N m"),
    ("wrist_torque_z", "N m"),
];

/// Words that mark a privileged quantity (one a real cell does not measure): every critic-only
/// name contains one, and so does no name the actor sees with `observation = "sensors"`.
pub const PRIVILEGED_MARKERS: [&str; 8] = [
    "object",
    "load",
    "material",
    "mass",
    "utilisation",
    "exact",
    "supply",
    "delay",
];

/// The critic's observations beyond the actor's (name, unit) for `num_cups` cups and the
/// randomised material parameters `materials`: the object relative to the tool (tool frame),
/// its mass, every cup's normal and shear load, and each material parameter's log scale.
pub fn critic_only_observations(num_cups: usize, materials: &[String]) -> Vec<(String, String)> {
    let mut out: Vec<(String, String)> = [
        ("object_in_tool_x", "m"),
        ("object_in_tool_y", "m"),
        ("object_in_tool_z", "m"),
        ("object_in_tool_qx", "1"),
        ("object_in_tool_qy", "1"),
        ("object_in_tool_qz", "1"),
        ("object_in_tool_qw", "1"),
        ("object_in_tool_vx", "m/s"),
        ("object_in_tool_vy", "m/s"),
        ("object_in_tool_vz", "m/s"),
        ("object_in_tool_wx", "rad/s"),
        ("object_in_tool_wy", "rad/s"),
        ("object_in_tool_wz", "rad/s"),
        ("object_mass", "kg"),
    ]
    .iter()
    .map(|(n, u)| (n.to_string(), u.to_string()))
    .collect();
    for k in 0..num_cups {
        out.push((format!("cup{k}_normal_load"), "N".into()));
        out.push((format!("cup{k}_shear_load"), "N".into()));
    }
    for name in materials {
        out.push((format!("material_log_scale_{name}"), "1".into()));
    }
    out
}

/// The material parameters the package randomisation scales or draws from a posterior, in name
/// order.
pub(super) fn randomised_materials(config: &TransportConfig) -> Vec<String> {
    let package = &config.randomization.package;
    let drawn = package.posterior_draws.iter().flat_map(|d| d.names.iter());
    let names: std::collections::BTreeSet<&String> =
        package.param_scale.keys().chain(drawn).collect();
    names.into_iter().cloned().collect()
}

/// Observation names with their units.
type Named = Vec<(String, String)>;

/// Observation groups (name, unit) of the actor and of the critic for a scene with `num_cups`
/// cups.
fn observation_groups(config: &TransportConfig, num_cups: usize) -> (Named, Named) {
    let owned = |rows: &[(&str, &str)]| -> Named {
        rows.iter()
            .map(|(n, u)| (n.to_string(), u.to_string()))
            .collect()
    };
    let utilisations = (0..num_cups).map(|k| (format!("cup{k}_utilisation"), "1".to_string()));
    let privileged = critic_only_observations(num_cups, &randomised_materials(config));
    let mut actor = owned(&ACTOR_OBSERVATIONS);
    if config.profile_rate.is_some() {
        for (k, name, unit) in PROFILE_RATE_OBSERVATIONS {
            actor[k] = (name.to_string(), unit.to_string());
        }
    }
    match &config.sensors {
        Some(sensors) if config.observation == ObservationMode::Sensors => {
            actor.extend((0..num_cups).map(|k| (format!("cup{k}_vacuum_pressure"), "Pa".into())));
            if sensors.wrist_force_torque {
                actor.extend(owned(&WRIST_OBSERVATIONS));
            }
            let current = actor.clone();
            for j in 1..=sensors.history_steps {
                actor.extend(
                    current
                        .iter()
                        .map(|(n, u)| (format!("{n}_prev{j}"), u.clone())),
                );
            }
            let (command, unit) = match config.profile_rate {
                Some(_) => ("profile_rate", "1"),
                None => ("path_speed", "m/s"),
            };
            for j in 1..=sensors.history_steps {
                actor.extend([
                    (format!("sent_{command}_prev{j}"), unit.to_string()),
                    (format!("sent_tilt_offset_x_prev{j}"), "rad".to_string()),
                    (format!("sent_tilt_offset_z_prev{j}"), "rad".to_string()),
                ]);
            }
            let mut critic = actor.clone();
            critic.extend(
                ACTOR_OBSERVATIONS[..MEASURED_TOOL_OBSERVATIONS]
                    .iter()
                    .map(|(n, u)| (format!("exact_{n}"), u.to_string())),
            );
            critic.extend(utilisations);
            critic.extend(privileged);
            critic.extend(owned(&[
                ("supply_vacuum", "Pa"),
                ("observation_delay", "s"),
                ("action_delay", "s"),
            ]));
            (actor, critic)
        }
        _ => {
            actor.extend(utilisations);
            let critic = actor.iter().cloned().chain(privileged).collect();
            (actor, critic)
        }
    }
}

/// Observation groups, action space and episode length for a scene with `num_cups` cups.
pub(super) fn build_spec(config: &TransportConfig, num_cups: usize) -> EnvSpec {
    let l = &config.limits;
    let tilt = l.max_tilt_offset_deg.to_radians() as f32;
    let (observation, critic) = observation_groups(config, num_cups);
    let space = |rows: &[(String, String)]| Space {
        kind: SpaceKind::Continuous,
        names: rows.iter().map(|r| r.0.clone()).collect(),
        units: rows.iter().map(|r| r.1.clone()).collect(),
        low: vec![f32::MIN; rows.len()],
        high: vec![f32::MAX; rows.len()],
    };
    EnvSpec {
        id: ID.to_string(),
        observation: space(&observation),
        critic_observation: Some(space(&critic)),
        action: Space::continuous(&[
            match &config.profile_rate {
                Some(p) => ("profile_rate", "1", 0.0, p.max_rate as f32),
                None => ("path_speed", "m/s", 0.0, l.max_path_speed_m_s as f32),
            },
            ("tilt_offset_x", "rad", -tilt, tilt),
            ("tilt_offset_z", "rad", -tilt, tilt),
        ]),
        max_episode_steps: (config.time_limit_s * config.control_hz).ceil() as usize,
    }
}

/// The spec of the environment `config` describes, without simulating anything (the scene is
/// loaded for its number of cups).
pub fn spec_of(config: &TransportConfig, source: &str) -> Result<EnvSpec, EnvError> {
    let scene = load_scene(config, source)?;
    let model = Model::new(&scene).map_err(sim_error)?;
    Ok(build_spec(config, model.num_cups()))
}

impl Transport {
    /// Copy `env`'s exact observation row: [`ACTOR_OBSERVATIONS`] from the simulator's tool
    /// state, each cup's utilisation, then [`critic_only_observations`].
    fn privileged_row(&self, env: usize) -> Vec<f64> {
        let state = &self.states[env];
        let cups = self.model.num_cups();
        let loads = &self.loads[env * cups..(env + 1) * cups];
        let mut row: Vec<f64> = Vec::with_capacity(self.spec.critic_obs_dim());
        self.tool_observations(
            env,
            v3(state.tool_position),
            quat(state.tool_orientation),
            v3(state.tool_velocity),
            v3(state.tool_angular_velocity),
            &mut row,
        );
        row.extend(loads.iter().map(|c| c.utilisation as f64));
        let d = &state.disc_in_tool;
        row.extend(d.position.iter().map(|&c| c as f64));
        row.extend(d.orientation.iter().map(|&c| c as f64));
        row.extend(d.velocity.iter().map(|&c| c as f64));
        row.extend(d.angular_velocity.iter().map(|&c| c as f64));
        let spec = self.sim.spec(env);
        row.push(spec.object_mass_kg as f64);
        for c in loads {
            row.extend([c.normal_n as f64, c.shear_n as f64]);
        }
        let base = &self.model.config.params;
        for name in &self.materials {
            let mut now = spec.params;
            let mut reference = *base;
            let ratio = match (now.get_mut(name), reference.get_mut(name)) {
                (Some(a), Some(b)) if *b != 0.0 => (*a / *b) as f64,
                _ => 1.0,
            };
            // A posterior may draw `mu_con` = 0: keep the log finite.
            row.push(ratio.max(1e-6).ln());
        }
        row
    }

    /// Appends [`ACTOR_OBSERVATIONS`] of copy `env` for the tool at position `p`, orientation
    /// `q`, velocity `v` and angular velocity `w` (world).
    fn tool_observations(
        &self,
        env: usize,
        p: DVec3,
        q: DQuat,
        v: DVec3,
        w: DVec3,
        row: &mut Vec<f64>,
    ) {
        let episode = &self.episodes[env];
        let (goal_p, goal_q) = self.goal(episode);
        let length = self.paths[episode.path].length_m;
        row.extend((goal_p - p).to_array());
        row.extend(rotation_between(q, goal_q).to_array());
        row.extend(v.to_array());
        row.extend(w.to_array());
        let time = match self.profile_rate {
            Some(_) => episode.profile_clock,
            None => self.states[env].time - episode.start_time,
        };
        row.extend([
            episode.progress / length,
            episode.path_speed,
            time,
            episode.target_tilt,
        ]);
        row.extend(episode.previous_action);
    }

    /// Writes copy `env`'s actor and critic observations into `obs` / `critic` rows.
    fn observe(&self, env: usize, obs: &mut [f32], critic: &mut [f32]) {
        let exact = self.privileged_row(env);
        let write = |slots: &mut [f32], row: &[f64]| {
            for (slot, &x) in slots.iter_mut().zip(row) {
                *slot = x as f32;
            }
        };
        let Some(sensors) = &self.sensors else {
            write(obs, &exact[..obs.len()]);
            write(critic, &exact);
            return;
        };
        let copy = &sensors.copies[env];
        let mut actor = Vec::with_capacity(critic.len());
        actor.extend(self.current_actor_row(env));
        for earlier in &copy.history {
            actor.extend_from_slice(earlier);
        }
        for sent in &copy.sent {
            actor.extend_from_slice(sent);
        }
        let mut full = actor.clone();
        full.extend_from_slice(&exact[..MEASURED_TOOL_OBSERVATIONS]);
        full.extend_from_slice(&exact[ACTOR_OBSERVATIONS.len()..]);
        full.extend([
            copy.supply_pa,
            copy.readings.delay() as f64 * self.dt,
            copy.actions.delay() as f64 * self.dt,
        ]);
        write(obs, &actor);
        write(critic, &full);
    }

    /// Copy `env`'s actor observations of this control step with sensors (the reading that
    /// reaches the policy now), without the history window.
    fn current_actor_row(&self, env: usize) -> Vec<f64> {
        let sensors = self.sensors.as_ref().expect("called with sensors only");
        let reading = sensors.copies[env].readings.output();
        let at = |k: usize| DVec3::new(reading[k], reading[k + 1], reading[k + 2]);
        let q = DQuat::from_xyzw(
            reading[row::ORIENTATION],
            reading[row::ORIENTATION + 1],
            reading[row::ORIENTATION + 2],
            reading[row::ORIENTATION + 3],
        );
        let mut actor = Vec::new();
        self.tool_observations(
            env,
            at(row::POSITION),
            q,
            at(row::VELOCITY),
            at(row::ANGULAR_VELOCITY),
            &mut actor,
        );
        actor.extend_from_slice(&reading[row::CUPS..]);
        actor
    }

    /// Moves copy `env`'s current actor row into its history window (once per control step,
    /// after the step's observations were written), the oldest row dropping out.
    pub(super) fn remember_observation(&mut self, env: usize) {
        let steps = match &self.sensors {
            Some(sensors) if sensors.config.history_steps > 0 => sensors.config.history_steps,
            _ => return,
        };
        let current = self.current_actor_row(env);
        let history = &mut self.sensors.as_mut().expect("checked above").copies[env].history;
        history.insert(0, current);
        history.truncate(steps);
    }

    /// Copy `env`'s sensor readings now, before noise and the cell's vacuum response.
    fn reading(&self, env: usize, wrist: bool) -> Reading {
        let state = &self.states[env];
        let cups = self.model.num_cups();
        let loads = &self.loads[env * cups..(env + 1) * cups];
        let f64s = |x: [f32; 3]| x.map(|c| c as f64);
        let p = v3(state.tool_position);
        let q = quat(state.tool_orientation);
        let mut wrench = Vec::new();
        if wrist {
            let positions = self.sim.particle_positions(env);
            let (start, size) = (self.model.cup_start(), self.model.cup_size);
            let (mut force, mut torque) = (DVec3::ZERO, DVec3::ZERO);
            for (c, f) in self.cup_forces[env * cups..(env + 1) * cups]
                .iter()
                .enumerate()
            {
                let particles = &positions[start + c * size..start + (c + 1) * size];
                let centre = particles.iter().map(|&x| v3(x)).sum::<DVec3>() / size as f64;
                let f = v3(*f);
                force += f;
                torque += (centre - p).cross(f);
            }
            let to_tool = q.inverse();
            wrench.extend((to_tool * force).to_array());
            wrench.extend((to_tool * torque).to_array());
        }
        Reading {
            position: p.to_array(),
            orientation: q.to_array(),
            velocity: f64s(state.tool_velocity),
            angular_velocity: f64s(state.tool_angular_velocity),
            cups: loads
                .iter()
                .map(|c| CupSeal {
                    attached: c.attached,
                    sealed_fraction: c.sealed_fraction as f64,
                    utilisation: c.utilisation as f64,
                })
                .collect(),
            wrench,
        }
    }

    /// Starts copy `env`'s sensors for its new episode (after the simulator was read).
    pub(super) fn start_sensors(&mut self, env: usize) {
        let Some(mut sensors) = self.sensors.take() else {
            return;
        };
        let wrist = sensors.config.wrist_force_torque;
        // A package with its own vacuum: the supply reads what its seal has (the unrandomised
        // stand-in for a replaced variant has the scene's).
        let package_supply_pa = self.config.randomization.package.vacuum_kpa.map(|_| {
            let kpa = self.sim.spec(env).vacuum_kpa;
            1e3 * kpa.unwrap_or(self.model.config.seal.vacuum_kpa) as f64
        });
        sensors.start_episode(env, package_supply_pa, &self.reading(env, wrist));
        let steps = sensors.config.history_steps;
        self.sensors = Some(sensors);
        // The window starts as if the first row had been seen for ever (as the delay lines do).
        if steps > 0 {
            let first = self.current_actor_row(env);
            self.sensors.as_mut().expect("put back above").copies[env].history = vec![first; steps];
        }
    }

    /// Takes this control step's reading of every copy still running.
    pub(super) fn measure(&mut self) {
        let Some(mut sensors) = self.sensors.take() else {
            return;
        };
        let wrist = sensors.config.wrist_force_torque;
        for env in 0..self.episodes.len() {
            if !self.retired[env] {
                let reading = self.reading(env, wrist);
                sensors.measure(env, &reading);
            }
        }
        self.sensors = Some(sensors);
    }

    /// Fills `out`'s observation rows of copy `env`.
    pub(super) fn observe_into(&self, env: usize, out: &mut StepBuffers, final_rows: bool) {
        let (a, c) = (self.spec.observation.dim(), self.spec.critic_obs_dim());
        if final_rows {
            self.observe(
                env,
                &mut out.final_obs[env * a..(env + 1) * a],
                &mut out.final_critic_obs[env * c..(env + 1) * c],
            );
        } else {
            self.observe(
                env,
                &mut out.obs[env * a..(env + 1) * a],
                &mut out.critic_obs[env * c..(env + 1) * c],
            );
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::transport::test_support::{env, history_table, sensors_table, test_table};
    use crate::VecEnv;

    fn is_privileged(name: &str) -> bool {
        PRIVILEGED_MARKERS.iter().any(|m| name.contains(m))
    }

    #[test]
    fn the_critic_sees_the_actor_s_observations_then_privileged_ones() {
        for (text, actor_privileged) in [(test_table(), 4), (sensors_table(), 0)] {
            let t = env(&text, 1);
            let spec = t.spec();
            let actor = &spec.observation;
            let critic = spec.critic_observation.as_ref().unwrap();
            assert_eq!(actor.names.len(), actor.units.len());
            assert_eq!(critic.names.len(), critic.units.len());
            // With privileged observations the actor sees the cups' utilisations; with sensors,
            // nothing privileged.
            let seen: Vec<&String> = actor.names.iter().filter(|n| is_privileged(n)).collect();
            assert_eq!(seen.len(), actor_privileged, "{seen:?}");
            assert!(seen.iter().all(|n| n.ends_with("_utilisation")));
            assert_eq!(&critic.names[..actor.dim()], &actor.names[..]);
            let extra = &critic.names[actor.dim()..];
            for name in extra {
                assert!(is_privileged(name), "critic-only {name} is not marked");
            }
            for required in ["object_in_tool_x", "object_mass", "cup0_normal_load"] {
                assert!(extra.iter().any(|n| n == required), "{required}");
            }
            assert!(critic.names.iter().any(|n| n == "cup3_utilisation"));
            assert!(critic.units.iter().all(|u| !u.is_empty()));
        }
        let t = env(&sensors_table(), 1);
        let names = &t.spec().observation.names;
        for required in ["cup3_vacuum_pressure", "wrist_torque_z", "goal_dx"] {
            assert!(names.iter().any(|n| n == required), "{required}");
        }
    }

    #[test]
    fn the_history_window_holds_the_earlier_rows_and_the_commands_sent() {
        let mut plain = env(&sensors_table(), 2);
        let mut windowed = env(&history_table(2), 2);
        let base = plain.spec().observation.dim();
        let names = windowed.spec().observation.names.clone();
        assert_eq!(names.len(), 3 * base + 6);
        assert_eq!(names[base], format!("{}_prev1", names[0]));
        assert_eq!(names[3 * base], "sent_path_speed_prev1");
        assert_eq!(names[3 * base + 5], "sent_tilt_offset_z_prev2");
        assert!(!names.iter().any(|n| is_privileged(n)), "{names:?}");
        let critic = windowed.spec().critic_observation.clone().unwrap();
        assert_eq!(&critic.names[..names.len()], &names[..]);
        let (mut a, mut b) = (plain.buffers(), windowed.buffers());
        plain.try_reset(5, &mut a).unwrap();
        windowed.try_reset(5, &mut b).unwrap();
        let width = names.len();
        let row = |out: &StepBuffers, env: usize| out.obs[env * width..(env + 1) * width].to_vec();
        // At the start the window holds the first row, as if seen for ever, and no command.
        for env in 0..2 {
            let r = row(&b, env);
            assert_eq!(&r[..base], &a.obs[env * base..(env + 1) * base]);
            assert_eq!(&r[base..2 * base], &r[..base]);
            assert_eq!(&r[2 * base..3 * base], &r[..base]);
            assert_eq!(&r[3 * base..], &[0.0; 6]);
        }
        let mut earlier: Vec<Vec<f32>> = Vec::new();
        let mut sent: Vec<[f32; 6]> = Vec::new();
        for step in 0..5 {
            let speed = 0.1 * (step + 1) as f32;
            let actions = [speed, 0.02, -0.01, 0.5 * speed, -0.03, 0.0];
            earlier.push(b.obs.clone());
            sent.push(actions);
            plain.step(&actions, &mut a).unwrap();
            windowed.step(&actions, &mut b).unwrap();
            assert!(!b.terminated.iter().chain(&b.truncated).any(|&d| d));
            for env in 0..2 {
                let r = row(&b, env);
                // The current row is the plain task's: the window draws no random number.
                assert_eq!(&r[..base], &a.obs[env * base..(env + 1) * base]);
                let before = &earlier[step][env * width..env * width + base];
                assert_eq!(&r[base..2 * base], before, "step {step}");
                if step > 0 {
                    let two_before = &earlier[step - 1][env * width..env * width + base];
                    assert_eq!(&r[2 * base..3 * base], two_before, "step {step}");
                }
                assert_eq!(
                    &r[3 * base..3 * base + 3],
                    &sent[step][env * 3..env * 3 + 3]
                );
                if step > 0 {
                    let previous = &sent[step - 1][env * 3..env * 3 + 3];
                    assert_eq!(&r[3 * base + 3..], previous);
                }
            }
        }
    }

    /// Columns `names` of `rows` (`dim` wide) of copy `env`.
    fn columns(spec: &[String], rows: &[f32], env: usize, names: &[&str]) -> Vec<f32> {
        let dim = spec.len();
        names
            .iter()
            .map(|n| rows[env * dim + spec.iter().position(|s| s == n).unwrap()])
            .collect()
    }

    #[test]
    fn with_the_package_s_vacuum_randomised_the_supply_reads_the_seal_s_vacuum() {
        let text = sensors_table()
            .replace(
                "param_scale = { k_tri_e = [0.8, 1.25] }",
                "param_scale = { k_tri_e = [0.8, 1.25] }\nvacuum_kpa = [30.0, 40.0]",
            )
            .replace(
                "supply_vacuum_kpa = [20.0, 30.0]",
                "supply_vacuum_kpa = [30.0, 40.0]",
            );
        // The same table without the key: some randomised packages of this seed do not stay
        // sealed (heavy object, soft film) and are replaced by the unrandomised one.
        let plain = {
            let mut p = env(&sensors_table(), 3);
            let mut out = p.buffers();
            p.try_reset(3, &mut out).unwrap();
            p.replaced_variants()
        };
        let mut t = env(&text, 3);
        let mut out = t.buffers();
        t.try_reset(3, &mut out).unwrap();
        // A vacuum above the scene's replaces no more packages than the scene's own.
        assert!(
            t.replaced_variants() <= plain,
            "{} > {plain}",
            t.replaced_variants()
        );
        assert_eq!(
            t.reset_counts(),
            [
                ("settled_variants".to_string(), 2),
                ("replaced_variants".to_string(), t.replaced_variants()),
                ("weak_grasps".to_string(), 0)
            ]
        );
        let scene_kpa = t.model.config.seal.vacuum_kpa;
        let critic = t.spec().critic_observation.clone().unwrap();
        for env in 0..3 {
            let supply = columns(&critic.names, &out.critic_obs, env, &["supply_vacuum"])[0];
            // A kept package seals with its own draw; a replaced one with the scene's vacuum.
            let vacuum = match t.simulator().spec(env).vacuum_kpa {
                Some(v) => {
                    assert!((30.0..=40.0).contains(&v), "{v}");
                    v
                }
                None => scene_kpa,
            };
            assert_eq!(supply, (1e3 * vacuum as f64) as f32);
        }
        // Every kept variant drew its own vacuum.
        let kept: Vec<_> = t
            .variants
            .iter()
            .filter_map(|v| v.snapshot.spec.vacuum_kpa)
            .collect();
        assert_eq!(kept.len(), 2 - t.replaced_variants(), "{kept:?}");
    }

    #[test]
    fn sensors_read_vacuum_below_the_supply_and_the_package_s_weight() {
        let mut t = env(&sensors_table(), 2);
        let mut out = t.buffers();
        t.try_reset(3, &mut out).unwrap();
        for _ in 0..4 {
            t.step(&[0.0; 6], &mut out).unwrap();
        }
        let spec = t.spec().clone();
        let critic = spec.critic_observation.unwrap();
        for env in 0..2 {
            let [supply, obs_delay, act_delay] = columns(
                &critic.names,
                &out.critic_obs,
                env,
                &["supply_vacuum", "observation_delay", "action_delay"],
            )[..] else {
                unreachable!()
            };
            assert!((20e3..=30e3).contains(&supply), "{supply}");
            for d in [obs_delay, act_delay] {
                assert!((d - 0.05).abs() < 1e-6 || (d - 0.1).abs() < 1e-6, "{d}");
            }
            let names: Vec<String> = (0..4).map(|k| format!("cup{k}_vacuum_pressure")).collect();
            let names: Vec<&str> = names.iter().map(String::as_str).collect();
            for p in columns(&spec.observation.names, &out.obs, env, &names) {
                // Sealed cups under a held package: most of the supply vacuum, gauge negative.
                assert!(-p > 0.7 * supply && -p < supply + 1e3, "{p} {supply}");
            }
            // The wrist carries the package: a force of roughly its weight (0.3-0.6 kg object
            // and the film), well clear of the noise.
            let f = columns(
                &spec.observation.names,
                &out.obs,
                env,
                &["wrist_force_x", "wrist_force_y", "wrist_force_z"],
            );
            let magnitude = f.iter().map(|x| x * x).sum::<f32>().sqrt();
            assert!((1.0..15.0).contains(&magnitude), "{f:?}");
        }
    }

    #[test]
    fn sensor_runs_follow_the_seed_on_any_thread_count() {
        let run = |threads: usize| {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap();
            pool.install(|| {
                let mut t = env(&sensors_table(), 3);
                let mut out = t.buffers();
                t.try_reset(7, &mut out).unwrap();
                let mut rows = vec![out.clone()];
                for step in 0..5 {
                    let s = 0.1 * step as f32;
                    t.step(&[s, 0.0, 0.0, 0.5, 0.05, 0.0, 0.2, -0.05, 0.0], &mut out)
                        .unwrap();
                    rows.push(out.clone());
                }
                rows
            })
        };
        let one = run(1);
        assert_eq!(one, run(2));
        // Noise: two copies starting from the same variant still read differently.
        assert_ne!(one[1].obs[..3], one[1].obs[one[1].obs.len() / 3..][..3]);
    }
}
