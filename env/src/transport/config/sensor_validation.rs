//! The checks of `observation` against `[transport.sensors]` and of the sensors' ranges.

use super::observation::ObservationMode;
use super::table::TransportConfig;
use super::validation::{bad, check};
use crate::transport::sensors::{MAX_DELAY_STEPS, MAX_HISTORY_STEPS};
use crate::EnvError;

impl TransportConfig {
    /// Checks `observation` against `[transport.sensors]` and the sensors' ranges.
    pub(super) fn validate_sensors(&self, s: &str) -> Result<(), EnvError> {
        let sensors = match (self.observation, &self.sensors) {
            (ObservationMode::Privileged, None) => return Ok(()),
            (ObservationMode::Privileged, Some(_)) => {
                return Err(bad(
                    s,
                    "sensors",
                    "a table",
                    "no [transport.sensors] table unless observation = \"sensors\"",
                ))
            }
            (ObservationMode::Sensors, None) => {
                return Err(bad(
                    s,
                    "sensors",
                    "missing",
                    "a [transport.sensors] table with observation = \"sensors\"",
                ))
            }
            (ObservationMode::Sensors, Some(sensors)) => sensors,
        };
        let [lo, hi] = sensors.supply_vacuum_kpa;
        if !(lo.is_finite() && hi.is_finite() && 1.0 <= lo && lo <= hi && hi <= 90.0) {
            return Err(bad(
                s,
                "sensors.supply_vacuum_kpa",
                format!("{:?}", sensors.supply_vacuum_kpa),
                "[low, high] within [1, 90] kPa below ambient (a cell supplies 20-30)",
            ));
        }
        // With the package's vacuum randomised the supply reading is the vacuum its seal has:
        // a second, different range would describe another cell.
        if let Some([plo, phi]) = self.randomization.package.vacuum_kpa {
            if lo as f32 != plo || hi as f32 != phi {
                return Err(bad(
                    s,
                    "sensors.supply_vacuum_kpa",
                    format!("{:?}", sensors.supply_vacuum_kpa),
                    &format!(
                        "the range of transport.randomization.package.vacuum_kpa, [{plo}, {phi}]: \
                         the sensors then read the vacuum each package's seal has"
                    ),
                ));
            }
        }
        for (key, [lo, hi]) in [
            (
                "sensors.observation_delay_steps",
                sensors.observation_delay_steps,
            ),
            ("sensors.action_delay_steps", sensors.action_delay_steps),
        ] {
            if !(lo <= hi && hi <= MAX_DELAY_STEPS) {
                return Err(bad(
                    s,
                    key,
                    format!("[{lo}, {hi}]"),
                    &format!("[low, high] control steps within [0, {MAX_DELAY_STEPS}]"),
                ));
            }
        }
        if sensors.history_steps > MAX_HISTORY_STEPS {
            return Err(bad(
                s,
                "sensors.history_steps",
                sensors.history_steps.to_string(),
                &format!("earlier control steps within [0, {MAX_HISTORY_STEPS}]"),
            ));
        }
        let n = &sensors.noise;
        for (key, value, high) in [
            ("sensors.noise.vacuum_pa", n.vacuum_pa, 1e4),
            ("sensors.noise.force_n", n.force_n, 100.0),
            ("sensors.noise.torque_n_m", n.torque_n_m, 10.0),
            ("sensors.noise.position_m", n.position_m, 0.1),
            ("sensors.noise.orientation_rad", n.orientation_rad, 0.5),
            ("sensors.noise.velocity_m_s", n.velocity_m_s, 1.0),
            (
                "sensors.noise.angular_velocity_rad_s",
                n.angular_velocity_rad_s,
                5.0,
            ),
        ] {
            check(s, key, value, 0.0, high)?;
        }
        if let Some(v) = &sensors.vacuum {
            for (key, [lo, hi], high) in [
                ("sensors.vacuum.load_leak", v.load_leak, 1.0),
                ("sensors.vacuum.time_constant_s", v.time_constant_s, 1.0),
            ] {
                if !(lo.is_finite() && hi.is_finite() && 0.0 <= lo && lo <= hi && hi <= high) {
                    return Err(bad(
                        s,
                        key,
                        format!("[{lo}, {hi}]"),
                        &format!("[low, high] within [0, {high}]"),
                    ));
                }
            }
            check(
                s,
                "sensors.vacuum.supply_noise_pa",
                v.supply_noise_pa,
                0.0,
                5e3,
            )?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::transport::test_support::{config, sensors_table, test_table};

    #[test]
    fn the_cells_vacuum_response_is_checked_and_names_its_key() {
        let table = sensors_table()
            + "\n[transport.sensors.vacuum]\nload_leak = [0.0, 0.31]\n\
               time_constant_s = [0.01, 0.06]\nsupply_noise_pa = 100.0\n";
        let vacuum = config(&table).sensors.unwrap().vacuum.unwrap();
        assert_eq!(vacuum.load_leak, [0.0, 0.31]);
        for (from, to, key) in [
            (
                "load_leak = [0.0, 0.31]",
                "load_leak = [0.31, 0.0]",
                "load_leak",
            ),
            (
                "load_leak = [0.0, 0.31]",
                "load_leak = [-0.1, 0.31]",
                "load_leak",
            ),
            ("[0.01, 0.06]", "[0.01, 6.0]", "time_constant_s"),
            (
                "supply_noise_pa = 100.0",
                "supply_noise_pa = 1e9",
                "supply_noise_pa",
            ),
        ] {
            let err = TransportConfig::from_toml_str(&table.replace(from, to), "t.toml")
                .unwrap_err()
                .to_string();
            assert!(
                err.contains("t.toml") && err.contains(&format!("sensors.vacuum.{key}")),
                "{to}: {err}"
            );
        }
    }

    #[test]
    fn sensor_settings_are_checked_and_name_their_key() {
        let text = sensors_table();
        let sensors = config(&text).sensors.expect("sensors");
        assert_eq!(sensors.observation_delay_steps, [1, 2]);
        for (from, to, key) in [
            (
                "observation = \"sensors\"",
                "observation = \"sonar\"",
                "transport.observation",
            ),
            (
                "action_delay_steps = [1, 2]",
                "action_delay_steps = [2, 1]",
                "transport.sensors.action_delay_steps",
            ),
            (
                "observation_delay_steps = [1, 2]",
                "observation_delay_steps = [1, 20]",
                "transport.sensors.observation_delay_steps",
            ),
            (
                "supply_vacuum_kpa = [20.0, 30.0]",
                "supply_vacuum_kpa = [30.0, 20.0]",
                "transport.sensors.supply_vacuum_kpa",
            ),
            (
                "vacuum_pa = 200.0",
                "vacuum_pa = -1.0",
                "transport.sensors.noise.vacuum_pa",
            ),
            (
                "observation = \"sensors\"",
                "observation = \"privileged\"",
                "transport.sensors",
            ),
        ] {
            assert!(text.contains(from), "{from}");
            let err = TransportConfig::from_toml_str(&text.replace(from, to), "t.toml")
                .unwrap_err()
                .to_string();
            assert!(err.contains("t.toml") && err.contains(key), "{to}: {err}");
        }
        // Sensors asked for without their table.
        let without = test_table().replace(
            "settle_s = 0.5\n",
            "settle_s = 0.5\nobservation = \"sensors\"\n",
        );
        let err = TransportConfig::from_toml_str(&without, "t.toml")
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("transport.sensors") && err.contains("missing"),
            "{err}"
        );
    }

    #[test]
    fn a_sensor_supply_range_contradicting_the_package_vacuum_is_refused() {
        let text = sensors_table().replace(
            "param_scale = { k_tri_e = [0.8, 1.25] }",
            "param_scale = { k_tri_e = [0.8, 1.25] }\nvacuum_kpa = [20.0, 30.0]",
        );
        config(&text);
        let err = TransportConfig::from_toml_str(
            &text.replace(
                "supply_vacuum_kpa = [20.0, 30.0]",
                "supply_vacuum_kpa = [25.0, 30.0]",
            ),
            "t.toml",
        )
        .unwrap_err()
        .to_string();
        assert!(
            err.contains("t.toml")
                && err.contains("transport.sensors.supply_vacuum_kpa")
                && err.contains("randomization.package.vacuum_kpa"),
            "{err}"
        );
        let err = TransportConfig::from_toml_str(
            &text.replace(
                "\nvacuum_kpa = [20.0, 30.0]\n",
                "\nvacuum_kpa = [0.0, 30.0]\n",
            ),
            "t.toml",
        )
        .unwrap_err()
        .to_string();
        assert!(
            err.contains("t.toml") && err.contains("vacuum_kpa"),
            "{err}"
        );
    }
}
