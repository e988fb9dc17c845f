//! Range checks of every key of the `[transport]` table ([`TransportConfig::validate`]; the
//! sensors' in `sensor_validation.rs`), and the error that names the key, the value and what was
//! expected.

use super::table::TransportConfig;
use crate::EnvError;

/// A configuration problem: `key` = `value` in `source`, expected `expected`.
pub(super) fn bad(source: &str, key: &str, value: impl ToString, expected: &str) -> EnvError {
    EnvError::Config {
        file: source.to_string(),
        key: format!("transport.{key}"),
        value: value.to_string(),
        expected: expected.to_string(),
    }
}

pub(super) fn check(
    source: &str,
    key: &str,
    value: f64,
    low: f64,
    high: f64,
) -> Result<(), EnvError> {
    if value.is_finite() && (low..=high).contains(&value) {
        Ok(())
    } else {
        Err(bad(
            source,
            key,
            value,
            &format!("a number in [{low}, {high}]"),
        ))
    }
}

impl TransportConfig {
    /// Range checks of every key (the robot limits against the recordings: [`Self::check_limits`]).
    pub fn validate(&self, source: &str) -> Result<(), EnvError> {
        let s = source;
        if !(self.grid[0] >= 3 && self.grid[1] >= 3 && self.grid[0] <= 64 && self.grid[1] <= 64) {
            return Err(bad(
                s,
                "grid",
                format!("{:?}", self.grid),
                "[rows, columns] within [3, 64]",
            ));
        }
        if self.paths.is_empty() {
            return Err(bad(s, "paths", "[]", "at least one recording id"));
        }
        check(s, "control_hz", self.control_hz, 10.0, 30.0)?;
        check(s, "time_limit_s", self.time_limit_s, 0.1, 600.0)?;
        if !(1..=1024).contains(&self.settled_variants) {
            return Err(bad(
                s,
                "settled_variants",
                self.settled_variants,
                "an integer in [1, 1024]",
            ));
        }
        check(s, "settle_s", self.settle_s, 0.0, 10.0)?;
        if let Some(ratio) = self.grasp_min_vacuum_ratio {
            check(s, "grasp_min_vacuum_ratio", ratio, 0.5, 0.98)?;
        }
        let l = &self.limits;
        check(
            s,
            "limits.max_path_speed_m_s",
            l.max_path_speed_m_s,
            0.01,
            f64::INFINITY,
        )?;
        check(
            s,
            "limits.max_path_accel_m_s2",
            l.max_path_accel_m_s2,
            0.01,
            f64::INFINITY,
        )?;
        check(
            s,
            "limits.max_tilt_offset_deg",
            l.max_tilt_offset_deg,
            0.0,
            45.0,
        )?;
        if let Some(fade) = l.tilt_offset_fade_m {
            check(s, "limits.tilt_offset_fade_m", fade, 1e-3, 1.0)?;
        }
        check(
            s,
            "limits.max_angular_speed_rad_s",
            l.max_angular_speed_rad_s,
            0.01,
            f64::INFINITY,
        )?;
        check(
            s,
            "limits.max_angular_accel_rad_s2",
            l.max_angular_accel_rad_s2,
            0.01,
            1000.0,
        )?;
        check(s, "limits.tracking_gain", l.tracking_gain, 1e-3, 1.0)?;
        let t = &self.success;
        check(s, "success.position_m", t.position_m, 1e-4, 1.0)?;
        check(s, "success.orientation_deg", t.orientation_deg, 0.01, 90.0)?;
        check(s, "success.tool_speed_m_s", t.tool_speed_m_s, 1e-4, 10.0)?;
        check(
            s,
            "success.object_speed_m_s",
            t.object_speed_m_s,
            1e-4,
            10.0,
        )?;
        check(
            s,
            "failure.max_object_distance_m",
            self.failure.max_object_distance_m,
            0.01,
            10.0,
        )?;
        let w = &self.reward;
        for (key, value) in [
            ("reward.progress", w.progress),
            ("reward.time", w.time),
            ("reward.object_motion", w.object_motion),
            ("reward.seal", w.seal),
            ("reward.jerk", w.jerk),
            ("reward.angular_jerk", w.angular_jerk),
            ("reward.failure", w.failure),
            ("reward.success", w.success),
        ] {
            check(s, key, value, 0.0, 1e6)?;
        }
        check(s, "reward.seal_threshold", w.seal_threshold, 0.0, 1.0)?;
        let r = &self.randomization;
        let [lo, hi] = r.target_tilt_deg;
        if !(lo.is_finite() && hi.is_finite() && 0.0 <= lo && lo <= hi && hi <= 90.0) {
            return Err(bad(
                s,
                "randomization.target_tilt_deg",
                format!("{:?}", r.target_tilt_deg),
                "[low, high] within [0, 90] degrees",
            ));
        }
        check(s, "randomization.goal_jitter_m", r.goal_jitter_m, 0.0, 0.2)?;
        if let Some(replay) = &r.replay {
            check(s, "randomization.replay.share", replay.share, 0.0, 1.0)?;
            if !(replay.memory.is_finite() && (0.0..1.0).contains(&replay.memory)) {
                return Err(bad(
                    s,
                    "randomization.replay.memory",
                    replay.memory,
                    "a number in [0, 1)",
                ));
            }
        }
        if let Some(split) = &r.held_out_draws {
            if !(2..=100).contains(&split.every) {
                return Err(bad(
                    s,
                    "randomization.held_out_draws.every",
                    split.every,
                    "an integer in [2, 100]",
                ));
            }
            if r.package.posterior.is_none() {
                return Err(bad(
                    s,
                    "randomization.held_out_draws",
                    format!("{{ every = {} }}", split.every),
                    "a randomization.package.posterior whose draws it splits",
                ));
            }
        }
        check(
            s,
            "randomization.start_jitter_m",
            r.start_jitter_m,
            0.0,
            0.2,
        )?;
        r.package
            .validate(&format!("{source} [transport.randomization.package]"))
            .map_err(|e| EnvError::ConfigParse {
                file: source.to_string(),
                message: e.to_string(),
            })?;
        if let Some(p) = &self.profile_rate {
            check(s, "profile_rate.limits_scale", p.limits_scale, 1e-3, 3.0)?;
            check(s, "profile_rate.max_rate", p.max_rate, 1.0, 4.0)?;
            check(
                s,
                "profile_rate.max_rate_change_per_s",
                p.max_rate_change_per_s,
                1e-3,
                100.0,
            )?;
        }
        self.validate_sensors(source)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::transport::test_support::{config, test_table};
    use crate::transport::Transport;

    #[test]
    fn configuration_errors_name_the_key_and_the_expected_range() {
        let text = test_table();
        let err = TransportConfig::from_toml_str(
            &text.replace("control_hz = 20.0", "control_hz = 100.0"),
            "t.toml",
        )
        .unwrap_err()
        .to_string();
        assert!(
            err.contains("t.toml")
                && err.contains("transport.control_hz")
                && err.contains("[10, 30]"),
            "{err}"
        );
        // Faster than 1.5 x the recordings' peak speed (0.631 m/s, high velocity) is refused when
        // the paths are loaded; the message names the key, the value, the peak and the bound.
        let err = crate::transport::load_paths(
            &config(&text.replace("max_path_speed_m_s = 0.945", "max_path_speed_m_s = 1.2")),
            true,
            "t.toml",
        )
        .unwrap_err()
        .to_string();
        assert!(
            err.contains("limits.max_path_speed_m_s")
                && err.contains("1.2")
                && err.contains("0.6310")
                && err.contains("0.9466")
                && err.contains("recordings of"),
            "{err}"
        );
        for (from, to, key) in [
            (
                "max_path_accel_m_s2 = 5.2",
                "max_path_accel_m_s2 = 5.3",
                "max_path_accel_m_s2",
            ),
            (
                "max_angular_speed_rad_s = 3.1",
                "max_angular_speed_rad_s = 3.2",
                "max_angular_speed_rad_s",
            ),
        ] {
            let err =
                crate::transport::load_paths(&config(&text.replace(from, to)), true, "t.toml")
                    .unwrap_err()
                    .to_string();
            assert!(err.contains(key), "{err}");
        }
        let err = TransportConfig::from_toml_str(
            &text.replace("goal_jitter_m = 0.03", "goal_jiter_m = 0.03"),
            "t.toml",
        )
        .unwrap_err()
        .to_string();
        assert!(err.contains("goal_jiter_m"), "{err}");
        let rate = "\n[transport.profile_rate]\nlimits_scale = 1.0\nmax_rate = 2.0\nmax_rate_change_per_s = 2.0\n";
        assert!(TransportConfig::from_toml_str(&(text.clone() + rate), "t.toml").is_ok());
        for (from, to, key) in [
            (
                "limits_scale = 1.0",
                "limits_scale = 3.5",
                "profile_rate.limits_scale",
            ),
            ("max_rate = 2.0", "max_rate = 0.5", "profile_rate.max_rate"),
            (
                "max_rate_change_per_s = 2.0",
                "max_rate_change_per_s = -1.0",
                "profile_rate.max_rate_change_per_s",
            ),
            ("max_rate = 2.0", "max_rates = 2.0", "max_rates"),
        ] {
            let err =
                TransportConfig::from_toml_str(&(text.clone() + &rate.replace(from, to)), "t.toml")
                    .unwrap_err()
                    .to_string();
            assert!(err.contains("t.toml") && err.contains(key), "{to}: {err}");
        }
        let replay = "\n[transport.randomization.replay]\nshare = 0.5\nmemory = 0.9\n";
        assert!(TransportConfig::from_toml_str(&(text.clone() + replay), "t.toml").is_ok());
        for (from, to, key) in [
            ("share = 0.5", "share = 1.5", "randomization.replay.share"),
            (
                "memory = 0.9",
                "memory = 1.0",
                "randomization.replay.memory",
            ),
            (
                "memory = 0.9",
                "memory = nan",
                "randomization.replay.memory",
            ),
            ("memory = 0.9", "memori = 0.9", "memori"),
        ] {
            let err = TransportConfig::from_toml_str(
                &(text.clone() + &replay.replace(from, to)),
                "t.toml",
            )
            .unwrap_err()
            .to_string();
            assert!(err.contains("t.toml") && err.contains(key), "{to}: {err}");
        }
        let fade = |value: &str| {
            let line = format!("max_tilt_offset_deg = 20.0\ntilt_offset_fade_m = {value}");
            TransportConfig::from_toml_str(
                &text.replace("max_tilt_offset_deg = 20.0", &line),
                "t.toml",
            )
        };
        assert_eq!(fade("0.15").unwrap().limits.tilt_offset_fade_m, Some(0.15));
        for value in ["0.0", "1.5", "nan"] {
            let err = fade(value).unwrap_err().to_string();
            assert!(err.contains("limits.tilt_offset_fade_m"), "{value}: {err}");
        }
        let grasp = |value: &str| {
            let line = format!("settle_s = 0.5\ngrasp_min_vacuum_ratio = {value}\n");
            TransportConfig::from_toml_str(&text.replace("settle_s = 0.5\n", &line), "t.toml")
        };
        assert_eq!(grasp("0.85").unwrap().grasp_min_vacuum_ratio, Some(0.85));
        for value in ["0.4", "0.99", "nan"] {
            let err = grasp(value).unwrap_err().to_string();
            assert!(err.contains("grasp_min_vacuum_ratio"), "{value}: {err}");
        }
        let err = Transport::new(config(&text.replace("\"HHHHM\"", "\"NOPE\"")), 1, "t.toml")
            .err()
            .unwrap()
            .to_string();
        assert!(
            err.contains("transport.paths") && err.contains("NOPE"),
            "{err}"
        );
    }
}
