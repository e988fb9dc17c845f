//! The recorded tool paths the episodes follow and the recorded timings a scripted baseline plays
//! along them, read from the motion-capture dataset ([`rlpkg_mocap`]) with the pick set-up the
//! replay builds ([`rlpkg_replay`]).

use std::path::Path;

use super::{ToolPeaks, TransportConfig, TransportPath};
use crate::EnvError;

/// The recorded paths `config.paths` names, from `config.recordings`, with the pick set-up the
/// scene's replay rule gives (`hold_disc`: the scene's `disc.hold_at_recorded_start`). The robot
/// limits are checked against the peaks of every recording of the dataset
/// ([`TransportConfig::check_limits`]): the fastest tool motion recorded.
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
    let mut peaks = ToolPeaks::default();
    let paths = config
        .paths
        .iter()
        .map(|id| {
            let trajectory = dataset
                .load(id)
                .map_err(|e| data_error(format!("transport.paths: {e}")))?;
            peaks = peaks.max(ToolPeaks::of(&trajectory.tool));
            let target = rlpkg_replay::Target::new(&trajectory, Some(0.0), hold_disc)
                .map_err(|e| data_error(format!("transport.paths: {e}")))?;
            TransportPath::from_recording(&trajectory, target.placement)
                .map_err(|e| data_error(format!("transport.paths: {e}")))
        })
        .collect::<Result<Vec<_>, _>>()?;
    // The rest of the dataset: the limits are bounded by the fastest recorded motion, whichever
    // recordings a configuration follows (an evaluation follows each held-out one in turn).
    for entry in &dataset.entries {
        if !config.paths.contains(&entry.id) {
            let trajectory = dataset
                .load(&entry.id)
                .map_err(|e| data_error(format!("transport.recordings: {e}")))?;
            peaks = peaks.max(ToolPeaks::of(&trajectory.tool));
        }
    }
    let described = format!(
        "the {} recordings of {}",
        dataset.entries.len(),
        config.recordings
    );
    config.check_limits(&peaks, &described, source)?;
    Ok(paths)
}

/// Recording levels in order (`low`, `medium`, `high`), for nearest-level matching.
const LEVELS: [&str; 3] = ["low", "medium", "high"];

/// A manifest level as a number to measure nearness by: its place among [`LEVELS`], or the
/// value itself when the manifest gives a number (an imported dataset's tilt in degrees, `30`).
fn rank(value: &Option<String>) -> Option<f64> {
    let value = value.as_deref()?;
    match LEVELS.iter().position(|l| *l == value) {
        Some(i) => Some(i as f64),
        None => value.parse::<f64>().ok().filter(|x| x.is_finite()),
    }
}

/// For each of `config.paths`, the recording of velocity level `velocity` (`low`, `medium` or
/// `high`, the manifest's `velocity`) whose timing a recorded baseline plays along that path
/// ([`Transport::timed_actions`]): the one with the path's placement tilt (`orientation`) and
/// object mass level (`mass`), else the nearest tilt (the study's dataset has no low-velocity
/// recording at the high tilt), then the nearest mass.
pub fn recorded_timings(
    config: &TransportConfig,
    velocity: &str,
    source: &str,
) -> Result<Vec<TransportPath>, EnvError> {
    let data_error = |message: String| EnvError::ConfigParse {
        file: source.to_string(),
        message,
    };
    if !LEVELS.contains(&velocity) {
        return Err(data_error(format!(
            "velocity level `{velocity}`: expected low, medium or high"
        )));
    }
    let dataset = rlpkg_mocap::Dataset::open(Path::new(&config.recordings))
        .map_err(|e| data_error(format!("transport.recordings: {e}")))?;
    config
        .paths
        .iter()
        .map(|id| {
            let entry = |id: &str| dataset.entries.iter().find(|e| e.id == id);
            let path_entry = entry(id)
                .ok_or_else(|| data_error(format!("transport.paths: no recording `{id}`")))?;
            let (tilt, mass) = (rank(&path_entry.orientation), rank(&path_entry.mass));
            let distance = |a: Option<f64>, b: Option<f64>| match (a, b) {
                (Some(a), Some(b)) => (a - b).abs(),
                _ => f64::INFINITY,
            };
            let chosen = dataset
                .entries
                .iter()
                .filter(|e| e.velocity.as_deref() == Some(velocity))
                .min_by(|a, b| {
                    let key = |e: &rlpkg_mocap::ManifestEntry| {
                        (
                            distance(rank(&e.orientation), tilt),
                            distance(rank(&e.mass), mass),
                        )
                    };
                    let ((ta, ma), (tb, mb)) = (key(a), key(b));
                    ta.total_cmp(&tb)
                        .then(ma.total_cmp(&mb))
                        .then_with(|| a.id.cmp(&b.id))
                })
                .ok_or_else(|| {
                    data_error(format!(
                        "transport.recordings: {} has no {velocity}-velocity recording (manifest \
                         `velocity`) to time the path `{id}` with",
                        config.recordings
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
