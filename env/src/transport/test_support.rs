//! What the transport tests share: a small `[transport]` table on a coarse grid and readers of
//! observation and info columns.

use super::{Transport, TransportConfig};
use crate::{StepBuffers, VecEnv};

/// A small `[transport]` table: coarse grid, the embedded physical scene, two settled variants.
pub(super) fn test_table() -> String {
    let data = concat!(env!("CARGO_MANIFEST_DIR"), "/../data/deformable-sim-real");
    format!(
        r#"
[transport]
scene = "physical"
grid = [11, 13]
recordings = "{data}"
paths = ["HHMHL", "HHHHM", "HHHHH"]
control_hz = 20.0
time_limit_s = 12.0
settled_variants = 2
settle_s = 0.5

[transport.limits]
max_path_speed_m_s = 0.945
max_path_accel_m_s2 = 5.2
max_tilt_offset_deg = 20.0
max_angular_speed_rad_s = 3.1
max_angular_accel_rad_s2 = 30.0
tracking_gain = 0.5

[transport.success]
position_m = 0.02
orientation_deg = 5.0
tool_speed_m_s = 0.05
object_speed_m_s = 0.05

[transport.failure]
max_object_distance_m = 0.4

[transport.reward]
progress = 10.0
time = 0.5
object_motion = 20.0
seal = 4.0
seal_threshold = 0.5
jerk = 0.01
angular_jerk = 0.002
failure = 30.0
success = 15.0

[transport.randomization]
target_tilt_deg = [30.0, 60.0]
goal_jitter_m = 0.03
start_jitter_m = 0.02

[transport.randomization.package]
object_mass_kg = [0.287, 0.595]
object_offset_m = 0.02
object_tilt_deg = 0.0
package_yaw_deg = [-10.0, 10.0]
param_scale = {{ k_tri_e = [0.8, 1.25] }}
"#
    )
}

/// The `[transport]` table of `text`.
pub(super) fn config(text: &str) -> TransportConfig {
    TransportConfig::from_toml_str(text, "test.toml").unwrap()
}

/// `num_envs` copies configured by `text` (not reset).
pub(super) fn env(text: &str, num_envs: usize) -> Transport {
    Transport::new(config(text), num_envs, "test.toml").unwrap()
}

/// Copy `env`'s actor observation `name` in `out` (its final row with `final_row`).
pub(super) fn column(
    t: &Transport,
    out: &StepBuffers,
    env: usize,
    name: &str,
    final_row: bool,
) -> f32 {
    let k = t
        .spec()
        .observation
        .names
        .iter()
        .position(|n| n == name)
        .unwrap();
    let dim = t.spec().observation.dim();
    let rows = if final_row { &out.final_obs } else { &out.obs };
    rows[env * dim + k]
}

/// Copy `env`'s info value `name` of the last step.
pub(super) fn info(t: &Transport, env: usize, name: &str) -> f32 {
    let k = t.info_names().iter().position(|n| n == name).unwrap();
    t.info()[env * t.info_names().len() + k]
}

/// [`test_table`] with `observation = "sensors"`: noisy, delayed readings and a wrist sensor.
pub(super) fn sensors_table() -> String {
    test_table().replace(
        "settle_s = 0.5\n",
        "settle_s = 0.5\nobservation = \"sensors\"\n",
    ) + r#"
[transport.sensors]
supply_vacuum_kpa = [20.0, 30.0]
wrist_force_torque = true
observation_delay_steps = [1, 2]
action_delay_steps = [1, 2]

[transport.sensors.noise]
vacuum_pa = 200.0
force_n = 0.1
torque_n_m = 0.01
position_m = 0.0005
orientation_rad = 0.002
velocity_m_s = 0.005
angular_velocity_rad_s = 0.01
"#
}

/// [`sensors_table`] whose actor also sees its last `steps` observation rows and commands.
pub(super) fn history_table(steps: usize) -> String {
    sensors_table().replace(
        "action_delay_steps = [1, 2]\n",
        &format!("action_delay_steps = [1, 2]\nhistory_steps = {steps}\n"),
    )
}
