//! The recorded tool paths the episodes follow and the recorded timings a scripted baseline plays
//! along them, read from the motion-capture dataset ([`rlpkg_mocap`]) with the pick set-up the
//! replay builds ([`rlpkg_replay`]).

use std::path::Path;

use super::{TransportConfig, TransportPath};
use crate::EnvError;

/// The recorded paths `config.paths` names, from `config.recordings`, with the pick set-up the
/// scene's replay rule gives (`hold_disc`: the scene's `disc.hold_at_recorded_start`).
pub fn load_paths(
    config: &TransportConfig,
    hold_disc: bool,
    source: &str,
) -> Result<Vec<TransportPath>, EnvError> {
    let data_error = |message: String| EnvError::ConfigParse {
        file: source.to_string(),
        message,
    };
    let dataset = rlpkg_mocap::Dataset::open(Path::new(&config.recordings))
        .map_err(|e| data_error(format!("transport.recordings: {e}")))?;
    config
        .paths
        .iter()
        .map(|id| {
            let trajectory = dataset
                .load(id)
                .map_err(|e| data_error(format!("transport.paths: {e}")))?;
            let target = rlpkg_replay::Target::new(&trajectory, Some(0.0), hold_disc)
                .map_err(|e| data_error(format!("transport.paths: {e}")))?;
            TransportPath::from_recording(&trajectory, target.placement)
                .map_err(|e| data_error(format!("transport.paths: {e}")))
        })
        .collect()
}

/// Recording levels in order (`low`, `medium`, `high`), for nearest-level matching.
const LEVELS: [&str; 3] = ["low", "medium", "high"];

/// For each of `config.paths`, the recording of velocity level `velocity` (`low`, `medium` or
/// `high`) whose timing a recorded baseline plays along that path ([`Transport::timed_actions`]):
/// the one with the path's placement tilt level and object mass level, else the nearest tilt
/// level (the dataset has no low-velocity recording at the high tilt), then the nearest mass.
pub fn recorded_timings(
    config: &TransportConfig,
    velocity: &str,
    source: &str,
) -> Result<Vec<TransportPath>, EnvError> {
    let data_error = |message: String| EnvError::ConfigParse {
        file: source.to_string(),
        message,
    };
    let level = |x: &Option<String>| {
        x.as_deref()
            .and_then(|v| LEVELS.iter().position(|l| *l == v))
    };
    let wanted = LEVELS.iter().position(|l| *l == velocity).ok_or_else(|| {
        data_error(format!(
            "velocity level `{velocity}`: expected low, medium or high"
        ))
    })?;
    let dataset = rlpkg_mocap::Dataset::open(Path::new(&config.recordings))
        .map_err(|e| data_error(format!("transport.recordings: {e}")))?;
    config
        .paths
        .iter()
        .map(|id| {
            let entry = |id: &str| dataset.entries.iter().find(|e| e.id == id);
            let path_entry = entry(id)
                .ok_or_else(|| data_error(format!("transport.paths: no recording `{id}`")))?;
            let (tilt, mass) = (level(&path_entry.orientation), level(&path_entry.mass));
            let distance = |a: Option<usize>, b: Option<usize>| match (a, b) {
                (Some(a), Some(b)) => a.abs_diff(b),
                _ => LEVELS.len(),
            };
            let chosen = dataset
                .entries
                .iter()
                .filter(|e| level(&e.velocity) == Some(wanted))
                .min_by_key(|e| {
                    (
                        distance(level(&e.orientation), tilt),
                        distance(level(&e.mass), mass),
                        e.id.clone(),
                    )
                })
                .ok_or_else(|| {
                    data_error(format!(
                        "transport.recordings: no {velocity}-velocity recording"
                    ))
                })?;
            let trajectory = dataset
                .load(&chosen.id)
                .map_err(|e| data_error(format!("transport.recordings: {e}")))?;
            let target = rlpkg_replay::Target::new(&trajectory, Some(0.0), false)
                .map_err(|e| data_error(format!("transport.recordings: {e}")))?;
            TransportPath::from_recording(&trajectory, target.placement)
                .map_err(|e| data_error(format!("transport.recordings: {e}")))
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::transport::test_support::{config, env, test_table};
    use crate::VecEnv;

    #[test]
    fn recorded_timings_match_the_tilt_level_and_play_along_the_path() {
        let config = config(&test_table());
        let pick = |velocity: &str| -> Vec<String> {
            recorded_timings(&config, velocity, "test.toml")
                .unwrap()
                .into_iter()
                .map(|t| t.id)
                .collect()
        };
        // Paths HHMHL, HHHHM, HHHHH: tilt low / medium / high, masses medium / high / high.
        assert_eq!(pick("medium"), ["HHMML", "HHHMM", "HHMMH"]);
        assert_eq!(pick("high"), ["HHMHL", "HHHHM", "HHHHH"]);
        // No low-velocity recording has the high tilt: the nearest (medium) tilt stands in.
        assert_eq!(pick("low"), ["HHMLL", "HHHLM", "HHHLM"]);
        assert!(recorded_timings(&config, "fast", "test.toml").is_err());
        // The paths' own timings are the scripted baseline; a slower recording asks for less speed.
        let mut t = env(&test_table(), 3);
        let mut out = t.buffers();
        t.try_reset(2, &mut out).unwrap();
        let own = recorded_timings(&config, "high", "test.toml").unwrap();
        let low = recorded_timings(&config, "low", "test.toml").unwrap();
        let speed = |a: &[f32]| a.iter().step_by(3).sum::<f32>();
        let (mut slow_total, mut scripted_total) = (0.0, 0.0);
        for _ in 0..10 {
            let scripted = t.scripted_actions(1.0);
            assert_eq!(t.timed_actions(&own, 1.0), scripted);
            slow_total += speed(&t.timed_actions(&low, 1.0));
            scripted_total += speed(&scripted);
            t.step(&scripted, &mut out).unwrap();
        }
        assert!(
            slow_total < 0.7 * scripted_total,
            "{slow_total} vs {scripted_total}"
        );
    }
}
