//! What the policy sees: the actor's and the critic's observation names and units, the spec built
//! from them, and the rows filled from the simulator state and the copy's episode.

use rlpkg_sim::Model;

use super::geometry::{quat, rotation_between, v3};
use super::{load_scene, sim_error, Transport, TransportConfig, ID};
use crate::{EnvError, EnvSpec, Space, SpaceKind, StepBuffers};

/// The actor's observations (name, unit) before the per-cup utilisations
/// (`cup<k>_utilisation`, unit `1`): quantities a real cell measures (robot state, its own
/// commands and goal, vacuum sensors).
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

/// Words that mark a privileged quantity (one a real cell does not measure): the actor's
/// observation names contain none of them, every critic-only name contains one.
pub const PRIVILEGED_MARKERS: [&str; 4] = ["object", "load", "material", "mass"];

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

/// The material parameters the package randomisation scales, in name order.
pub(super) fn randomised_materials(config: &TransportConfig) -> Vec<String> {
    config
        .randomization
        .package
        .param_scale
        .keys()
        .cloned()
        .collect()
}

/// Observation groups, action space and episode length for a scene with `num_cups` cups.
pub(super) fn build_spec(config: &TransportConfig, num_cups: usize) -> EnvSpec {
    let l = &config.limits;
    let tilt = l.max_tilt_offset_deg.to_radians() as f32;
    let mut observation: Vec<(String, String)> = ACTOR_OBSERVATIONS
        .iter()
        .map(|(n, u)| (n.to_string(), u.to_string()))
        .collect();
    observation.extend((0..num_cups).map(|k| (format!("cup{k}_utilisation"), "1".to_string())));
    let critic: Vec<(String, String)> = observation
        .iter()
        .cloned()
        .chain(critic_only_observations(
            num_cups,
            &randomised_materials(config),
        ))
        .collect();
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
            ("path_speed", "m/s", 0.0, l.max_path_speed_m_s as f32),
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
    /// Writes copy `env`'s actor and critic observations into `obs` / `critic` rows.
    fn observe(&self, env: usize, obs: &mut [f32], critic: &mut [f32]) {
        let episode = &self.episodes[env];
        let state = &self.states[env];
        let cups = self.model.num_cups();
        let loads = &self.loads[env * cups..(env + 1) * cups];
        let (goal_p, goal_q) = self.goal(episode);
        let p = v3(state.tool_position);
        let q = quat(state.tool_orientation);
        let to_goal = goal_p - p;
        let rotation = rotation_between(q, goal_q);
        let v = v3(state.tool_velocity);
        let w = v3(state.tool_angular_velocity);
        let length = self.paths[episode.path].length_m;
        let mut row: Vec<f64> = Vec::with_capacity(critic.len());
        row.extend(to_goal.to_array());
        row.extend(rotation.to_array());
        row.extend(v.to_array());
        row.extend(w.to_array());
        row.extend([
            episode.progress / length,
            episode.path_speed,
            state.time - episode.start_time,
            episode.target_tilt,
        ]);
        row.extend(episode.previous_action);
        row.extend(loads.iter().map(|c| c.utilisation as f64));
        let actor_dim = obs.len();
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
            row.push(ratio.ln());
        }
        for (slot, &x) in obs.iter_mut().zip(&row[..actor_dim]) {
            *slot = x as f32;
        }
        for (slot, &x) in critic.iter_mut().zip(&row) {
            *slot = x as f32;
        }
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
    use crate::transport::test_support::{env, test_table};
    use crate::VecEnv;

    #[test]
    fn actor_observes_no_privileged_quantity() {
        let t = env(&test_table(), 1);
        let spec = t.spec();
        let actor = &spec.observation;
        let critic = spec.critic_observation.as_ref().unwrap();
        assert_eq!(actor.names.len(), actor.units.len());
        assert_eq!(critic.names.len(), critic.units.len());
        for name in &actor.names {
            assert!(
                !PRIVILEGED_MARKERS.iter().any(|m| name.contains(m)),
                "actor observation {name} is privileged"
            );
        }
        // The critic sees everything the actor sees, then privileged quantities only.
        assert_eq!(&critic.names[..actor.dim()], &actor.names[..]);
        let extra = &critic.names[actor.dim()..];
        assert!(!extra.is_empty());
        for name in extra {
            assert!(
                PRIVILEGED_MARKERS.iter().any(|m| name.contains(m)),
                "critic-only observation {name} is not marked privileged"
            );
        }
        for required in ["object_in_tool_x", "object_mass", "cup0_normal_load"] {
            assert!(extra.iter().any(|n| n == required), "{required}");
        }
        assert!(actor.names.iter().any(|n| n == "cup3_utilisation"));
        assert!(critic.units.iter().all(|u| !u.is_empty()));
    }
}
