//! The scene the `[transport]` table names ([`load_scene`]), with its grid and robot limits.

use std::path::Path;

use rlpkg_sim::{SceneConfig, ToolLimits};

use super::table::TransportConfig;
use crate::EnvError;

/// The scene `config.scene` names (file or preset) with the configured grid and the robot limits
/// of `[transport.limits]`; it must have the seal model on.
pub fn load_scene(config: &TransportConfig, source: &str) -> Result<SceneConfig, EnvError> {
    let mut scene = match config.scene.as_str() {
        "physical" | "reference" => SceneConfig::preset(&config.scene),
        path => SceneConfig::load(Path::new(path)),
    }
    .map_err(|e| EnvError::ConfigParse {
        file: source.to_string(),
        message: format!("transport.scene = {:?}: {e}", config.scene),
    })?;
    if !scene.seal.enabled {
        return Err(EnvError::Config {
            file: source.to_string(),
            key: "transport.scene".into(),
            value: config.scene.clone(),
            expected: "a scene with SI masses and the seal model on ([seal] enabled = true), \
                       e.g. configs/scenes/physical-explicit.toml"
                .into(),
        });
    }
    if config.randomization.package.object_tilt_deg > 0.0
        && !(scene.disc.hold_at_recorded_start && scene.disc.hold_orientation)
    {
        return Err(EnvError::Config {
            file: source.to_string(),
            key: "transport.randomization.package.object_tilt_deg".into(),
            value: config.randomization.package.object_tilt_deg.to_string(),
            expected: format!(
                "0 with the scene {:?}: a tilted object needs a scene that turns the disc to its \
                 tilt during the rest ([disc] hold_at_recorded_start = true and hold_orientation \
                 = true); started tilted, its rim cuts through the flat package's film",
                config.scene
            ),
        });
    }
    scene.package.grid = config.grid;
    let l = &config.limits;
    scene.tool_limits = ToolLimits {
        max_speed_m_s: l.max_path_speed_m_s as f32,
        max_accel_m_s2: l.max_path_accel_m_s2 as f32,
        max_angular_speed_rad_s: l.max_angular_speed_rad_s as f32,
        max_angular_accel_rad_s2: l.max_angular_accel_rad_s2 as f32,
    };
    scene.validate(source).map_err(|e| EnvError::ConfigParse {
        file: source.to_string(),
        message: e.to_string(),
    })?;
    Ok(scene)
}

#[cfg(test)]
mod tests {
    use crate::transport::test_support::{config, test_table};
    use crate::transport::Transport;

    #[test]
    fn a_tilted_object_needs_a_scene_that_turns_the_disc_during_the_rest() {
        let text = test_table().replace("object_tilt_deg = 0.0", "object_tilt_deg = 20.0");
        let error = Transport::new(config(&text), 1, "test.toml").err().unwrap();
        let message = error.to_string();
        assert!(
            message.contains("test.toml")
                && message.contains("object_tilt_deg")
                && message.contains("hold_orientation"),
            "{message}"
        );
    }
}
