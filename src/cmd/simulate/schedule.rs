//! When `rlpkg simulate` stops the replay: every recorded frame (a CSV row), and the pictures on
//! the beat of `--frames-every` and `--png-every`, the rest period included.

use rlpkg_replay::FrameClock;
use rlpkg_sim::SceneConfig;

/// Rate of the recorded data (Hz).
pub const RECORDING_RATE_HZ: f64 = 240.0;

/// The picture beat and the replayed span (the command's options).
#[derive(Clone, Copy, Debug)]
pub struct ScheduleOptions {
    /// One GIF frame every this many recorded frames.
    pub frames_every: usize,
    /// One PNG still every this many seconds of simulated time (plus the first and last instant).
    pub png_every: f64,
    /// Replay only the first this many seconds of the recording.
    pub seconds: Option<f64>,
}

/// One instant at which the replay stops to record or draw.
#[derive(Clone, Copy, Debug)]
pub struct Stop {
    /// Substep count from the start of the rest period.
    pub substep: u64,
    /// Time relative to the start of the recording (negative during the rest period).
    pub t: f64,
    /// The recorded frame compared at this instant, if any.
    pub frame: Option<usize>,
    /// A GIF frame is drawn here.
    pub gif: bool,
    /// A PNG still is drawn here.
    pub png: bool,
}

/// Every stop of the replay in time order: rest-period pictures, then each recorded frame (up to
/// `--seconds`), marking which ones go into the GIF and which become PNG stills.
pub fn schedule(times: &[f64], config: &SceneConfig, options: &ScheduleOptions) -> Vec<Stop> {
    let rest_s = f64::from(config.cups.rest_time_s);
    let limit = options.seconds.unwrap_or(f64::INFINITY);
    let gif_step = options.frames_every as f64 / RECORDING_RATE_HZ;
    let substep_at = |t: f64| FrameClock::SubstepRate.substep_at(config, t);
    let mut stops = Vec::new();
    // Rest period: pictures only, on the same beat as the recorded frames.
    let rest_pictures = (rest_s / gif_step).ceil() as usize;
    for m in 0..rest_pictures {
        let t = -rest_s + m as f64 * gif_step;
        stops.push(Stop {
            substep: substep_at(t),
            t,
            frame: None,
            gif: true,
            png: m == 0,
        });
    }
    let frames = times
        .iter()
        .take_while(|&&t| t <= limit + 1e-9)
        .count()
        .max(1);
    let mut next_png = 0.0;
    for (k, &t) in times.iter().enumerate().take(frames) {
        let png = t + 1e-9 >= next_png || k + 1 == frames;
        if png {
            next_png = (t / options.png_every).floor() * options.png_every + options.png_every;
        }
        stops.push(Stop {
            substep: substep_at(t),
            t,
            frame: Some(k),
            gif: k % options.frames_every == 0 || k + 1 == frames,
            png,
        });
    }
    // Recordings start at t = 0, after the rest period; sorting keeps any other file in time order.
    stops.sort_by_key(|stop| stop.substep);
    stops
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn schedule_stops_at_rest_pictures_then_every_recorded_frame() {
        let times: Vec<f64> = (0..100).map(|k| k as f64 / 240.0).collect();
        let options = ScheduleOptions {
            frames_every: 24,
            png_every: 0.2,
            seconds: Some(0.3),
        };
        // The reference scene: 30 720 substeps per second after a 2 s rest.
        let scene = SceneConfig::preset("reference").unwrap();
        let stops = schedule(&times, &scene, &options);
        let (rest, recorded): (Vec<Stop>, Vec<Stop>) =
            stops.iter().partition(|stop| stop.frame.is_none());
        // 2 s of rest at one picture per 0.1 s, the first one also a still.
        assert_eq!(rest.len(), 20);
        assert_eq!(rest[0].substep, 0);
        assert!(rest.iter().all(|stop| stop.gif && stop.t < 0.0));
        assert_eq!(rest.iter().filter(|stop| stop.png).count(), 1);
        // Frames 0..=72 (t <= 0.3 s), 128 substeps apart after the 61 440 rest substeps.
        assert_eq!(recorded.len(), 73);
        for (k, stop) in recorded.iter().enumerate() {
            assert_eq!(stop.frame, Some(k));
            assert_eq!(stop.substep, 61_440 + 128 * k as u64);
        }
        let gif: Vec<usize> = recorded
            .iter()
            .filter(|s| s.gif)
            .filter_map(|s| s.frame)
            .collect();
        assert_eq!(gif, [0, 24, 48, 72]);
        let png: Vec<usize> = recorded
            .iter()
            .filter(|s| s.png)
            .filter_map(|s| s.frame)
            .collect();
        assert_eq!(png, [0, 48, 72]);
        assert!(stops.windows(2).all(|w| w[0].substep < w[1].substep));
    }
}
