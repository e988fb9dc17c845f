//! The robot limits against the tool's peaks over the recordings ([`LIMIT_HEADROOM`],
//! [`TransportConfig::check_limits`]).

use super::table::TransportConfig;
use super::validation::bad;
use crate::transport::path::ToolPeaks;
use crate::EnvError;

/// How far the robot limits may exceed the recordings' peaks ([`TransportConfig::check_limits`]).
pub const LIMIT_HEADROOM: f64 = 1.5;

impl TransportConfig {
    /// Checks the robot limits against the tool's peaks over the recordings (`peaks`: every
    /// recording of `recordings`, [`crate::transport::load_paths`]): speed, acceleration and
    /// angular speed at most [`LIMIT_HEADROOM`] x their peak. `reference` names the recordings in
    /// messages.
    pub fn check_limits(
        &self,
        peaks: &ToolPeaks,
        reference: &str,
        source: &str,
    ) -> Result<(), EnvError> {
        let l = &self.limits;
        for (key, value, peak, unit) in [
            (
                "limits.max_path_speed_m_s",
                l.max_path_speed_m_s,
                peaks.speed_m_s,
                "m/s",
            ),
            (
                "limits.max_path_accel_m_s2",
                l.max_path_accel_m_s2,
                peaks.accel_m_s2,
                "m/s^2",
            ),
            (
                "limits.max_angular_speed_rad_s",
                l.max_angular_speed_rad_s,
                peaks.angular_speed_rad_s,
                "rad/s",
            ),
        ] {
            let bound = LIMIT_HEADROOM * peak;
            if value > bound {
                return Err(bad(
                    source,
                    key,
                    value,
                    &format!(
                        "at most {LIMIT_HEADROOM} x the peak {peak:.4} {unit} of {reference} = {bound:.4} {unit}"
                    ),
                ));
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use std::path::Path;

    use super::*;

    #[test]
    fn the_repository_configs_keep_their_limits_within_their_recordings_peaks() {
        let root = concat!(env!("CARGO_MANIFEST_DIR"), "/..");
        for name in [
            "transport.toml",
            "transport-sensors.toml",
            "transport-posterior.toml",
            "transport-sensors-posterior.toml",
            "transport-sensors-posterior-soft-film.toml",
        ] {
            let path = format!("{root}/configs/train/{name}");
            // A posterior names its calibration config relative to the repository root, which is
            // not the tests' working folder; the posterior loader's own tests read one.
            let text = rlpkg_toml_input::read_composed(Path::new(&path))
                .unwrap()
                .text
                .replace("\"data/", &format!("\"{root}/data/"))
                .replace("posterior = ", "# posterior = ");
            let config = TransportConfig::from_toml_str(&text, &path).unwrap();
            let paths = crate::transport::load_paths(&config, true, &path).unwrap();
            assert_eq!(paths.len(), 3, "{name}");
        }
    }
}
