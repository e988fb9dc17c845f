//! Marker identities for recordings whose markers carry none: frame-to-frame tracking.
//!
//! The study's `markers.csv` lists each frame's markers without saying which physical marker a
//! point is, and a nearest-neighbour comparison with the simulation cannot tell two markers apart
//! once the fit is off by more than half their spacing (about 23 mm). At 240 frames per second a
//! marker moves a few millimetres between frames, far less than that spacing, so identities can be
//! carried from frame to frame:
//!
//! * frame 0 gives every marker a track of its own (in file order: the recording's
//!   `initial_marker_positions_m`, which places the package);
//! * in each later frame, the tracks seen in the frame before are assigned to the frame's markers
//!   (Hungarian assignment, [`crate::clean::assign`]) on the distance to each track's position
//!   predicted at constant velocity, within [`TrackingSettings::gate_m`];
//! * a marker left over is matched to a track lost earlier (occluded), at the position its last
//!   velocity carries it to, within [`TrackingSettings::relink_gate_m`]; else it starts a new
//!   track.
//!
//! Every disappearance of a track is a **break**: what follows it is only as sure as the relink.
//! [`TrackingReport`] counts breaks, relinks and new tracks so that a recording whose identities
//! cannot be kept says so.

use serde::Serialize;

use crate::clean::assign;
use crate::dataset::MarkerFrames;

/// Distances of the frame-to-frame tracking (m).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TrackingSettings {
    /// Largest distance between a track's predicted position and the marker it takes in the next
    /// frame: well above a frame's prediction error at 240 frames per second, well below the
    /// marker spacing.
    pub gate_m: f64,
    /// Largest distance between a lost track's predicted position and a reappearing marker: under
    /// half the marker spacing, so that a relink does not take a neighbour's identity.
    pub relink_gate_m: f64,
}

impl Default for TrackingSettings {
    fn default() -> Self {
        Self {
            gate_m: 0.01,
            relink_gate_m: 0.02,
        }
    }
}

/// What the tracking of one recording did.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize)]
pub struct TrackingReport {
    /// Markers of the first frame (tracks with an identity from the start).
    pub initial_tracks: usize,
    /// Tracks started after the first frame (markers that could not be relinked).
    pub new_tracks: usize,
    /// Disappearances of a track (occlusions, or a marker beyond the gate).
    pub breaks: usize,
    /// Reappearances matched to a lost track.
    pub relinked: usize,
    /// Points of the recording, and of them the points on a track of the first frame.
    pub points: usize,
    /// Points on a track of the first frame.
    pub points_on_initial_tracks: usize,
    /// The recording carried its markers' ids (kept as they were, nothing tracked).
    pub recorded_ids: bool,
}

impl TrackingReport {
    /// Share of the points whose identity goes back to the first frame.
    pub fn initial_share(&self) -> f64 {
        if self.points == 0 {
            return 0.0;
        }
        self.points_on_initial_tracks as f64 / self.points as f64
    }
}

/// A track's last two sightings.
struct Track {
    last: [f64; 3],
    last_frame: usize,
    /// The sighting in the frame before `last_frame`, for the constant-velocity prediction.
    before: Option<[f64; 3]>,
}

/// Frames a lost track's last velocity is carried over at most: beyond a quarter second an
/// occluded marker's motion is no longer that velocity.
const MAX_PREDICTED_FRAMES: usize = 60;

impl Track {
    /// The position at frame `frame` at the last seen velocity (held still without one).
    fn predicted(&self, frame: usize) -> [f64; 3] {
        let steps = (frame - self.last_frame).min(MAX_PREDICTED_FRAMES) as f64;
        match self.before {
            Some(b) => [0, 1, 2].map(|a| self.last[a] + steps * (self.last[a] - b[a])),
            None => self.last,
        }
    }

    fn see(&mut self, point: [f64; 3], frame: usize) {
        self.before = (self.last_frame + 1 == frame).then_some(self.last);
        self.last = point;
        self.last_frame = frame;
    }
}

fn squared(a: &[f64; 3], b: &[f64; 3]) -> f64 {
    (0..3).map(|i| (a[i] - b[i]).powi(2)).sum()
}

/// The markers of `frames` with an id per point: the track it belongs to (ids `0..n` are the first
/// frame's markers in file order). A recording that already carries ids is returned as it is, with
/// its report counted from the ids.
pub fn track_markers(
    frames: &MarkerFrames,
    settings: &TrackingSettings,
) -> (MarkerFrames, TrackingReport) {
    if frames.is_labelled() {
        return (frames.clone(), report_of_labelled(frames));
    }
    let mut tracks: Vec<Track> = Vec::new();
    let mut report = TrackingReport::default();
    let mut labelled: Vec<Vec<(u32, [f64; 3])>> = Vec::with_capacity(frames.len());
    let times: Vec<f64> = (0..frames.len()).map(|k| frames.t(k)).collect();
    for k in 0..frames.len() {
        let points = frames.frame(k);
        let mut id_of: Vec<Option<usize>> = vec![None; points.len()];
        if k > 0 {
            let active: Vec<usize> = (0..tracks.len())
                .filter(|&i| tracks[i].last_frame + 1 == k)
                .collect();
            let cost: Vec<f64> = active
                .iter()
                .flat_map(|&i| {
                    let p = tracks[i].predicted(k);
                    points.iter().map(move |q| squared(&p, q))
                })
                .collect();
            let pairs = assign(&cost, active.len(), points.len(), settings.gate_m.powi(2));
            for &(row, col) in &pairs {
                id_of[col] = Some(active[row]);
            }
            report.breaks += active.len() - pairs.len();
            let free: Vec<usize> = (0..points.len()).filter(|&c| id_of[c].is_none()).collect();
            let lost: Vec<usize> = (0..tracks.len())
                .filter(|&i| tracks[i].last_frame + 1 < k)
                .collect();
            if !free.is_empty() && !lost.is_empty() {
                let cost: Vec<f64> = lost
                    .iter()
                    .flat_map(|&i| free.iter().map(move |&c| (i, c)))
                    .map(|(i, c)| squared(&tracks[i].predicted(k), &points[c]))
                    .collect();
                let pairs = assign(
                    &cost,
                    lost.len(),
                    free.len(),
                    settings.relink_gate_m.powi(2),
                );
                for &(row, col) in &pairs {
                    id_of[free[col]] = Some(lost[row]);
                }
                report.relinked += pairs.len();
            }
        }
        let mut frame = Vec::with_capacity(points.len());
        for (c, point) in points.iter().enumerate() {
            let id = match id_of[c] {
                Some(id) => {
                    tracks[id].see(*point, k);
                    id
                }
                None => {
                    if k > 0 {
                        report.new_tracks += 1;
                    } else {
                        report.initial_tracks += 1;
                    }
                    tracks.push(Track {
                        last: *point,
                        last_frame: k,
                        before: None,
                    });
                    tracks.len() - 1
                }
            };
            report.points += 1;
            if id < report.initial_tracks {
                report.points_on_initial_tracks += 1;
            }
            frame.push((id as u32, *point));
        }
        labelled.push(frame);
    }
    (MarkerFrames::from_labelled_frames(times, labelled), report)
}

/// The report of a recording that came with ids: tracks of the first frame, later tracks, breaks.
fn report_of_labelled(frames: &MarkerFrames) -> TrackingReport {
    let mut report = TrackingReport {
        recorded_ids: true,
        ..TrackingReport::default()
    };
    let mut initial: Vec<u32> = Vec::new();
    let mut seen_before: Vec<u32> = Vec::new();
    let mut last: Vec<u32> = Vec::new();
    for k in 0..frames.len() {
        let ids = frames.frame_ids(k).unwrap_or_default();
        if k == 0 {
            initial = ids.to_vec();
            report.initial_tracks = ids.len();
        }
        report.breaks += last.iter().filter(|id| !ids.contains(id)).count();
        for id in ids {
            if !seen_before.contains(id) {
                if k > 0 {
                    report.new_tracks += 1;
                }
                seen_before.push(*id);
            } else if !last.contains(id) {
                report.relinked += 1;
            }
        }
        report.points += ids.len();
        report.points_on_initial_tracks += ids.iter().filter(|id| initial.contains(id)).count();
        last = ids.to_vec();
    }
    report
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A 3 x 3 grid of markers 5 cm apart sliding along x at 1 m/s, 240 frames per second, with
    /// per-frame shuffled order, one marker hidden for frames 10..20 and `jump` (m) along z from
    /// then on.
    fn sliding_grid(jump: f64) -> (MarkerFrames, Vec<Vec<u32>>) {
        let dt = 1.0 / 240.0;
        let mut frames = Vec::new();
        let mut truth = Vec::new();
        let mut times = Vec::new();
        for k in 0..60 {
            let shift = k as f64 * dt;
            let mut frame: Vec<(u32, [f64; 3])> = (0..9u32)
                .filter(|&m| !(m == 4 && (10..20).contains(&k)))
                .map(|m| {
                    let (i, j) = ((m % 3) as f64, (m / 3) as f64);
                    let dz = if m == 4 && k >= 20 { jump } else { 0.0 };
                    (m, [0.05 * i + shift, 0.0, 0.05 * j + dz])
                })
                .collect();
            if k > 0 {
                let turn = k % frame.len();
                frame.rotate_left(turn); // order carries no identity
            }
            truth.push(frame.iter().map(|(id, _)| *id).collect());
            frames.push(frame.into_iter().map(|(_, p)| p).collect());
            times.push(k as f64 * dt);
        }
        (MarkerFrames::from_frames(times, frames), truth)
    }

    #[test]
    fn keeps_identities_through_motion_shuffling_and_an_occlusion() {
        // Hidden for 10 frames, it moved 4 cm: its velocity brings the track back to it.
        let (frames, truth) = sliding_grid(0.0);
        let (labelled, report) = track_markers(&frames, &TrackingSettings::default());
        for (k, ids) in truth.iter().enumerate() {
            assert_eq!(labelled.frame_ids(k).unwrap(), &ids[..], "frame {k}");
            assert_eq!(labelled.frame(k), frames.frame(k));
        }
        assert_eq!(report.initial_tracks, 9);
        assert_eq!(
            (report.breaks, report.relinked, report.new_tracks),
            (1, 1, 0)
        );
        assert_eq!(report.initial_share(), 1.0);
        // Ids already known are kept, and the report is counted from them.
        let (again, same) = track_markers(&labelled, &TrackingSettings::default());
        assert_eq!(again, labelled);
        assert!(!report.recorded_ids && same.recorded_ids);
        assert_eq!(
            same,
            TrackingReport {
                recorded_ids: true,
                ..report
            }
        );
    }

    #[test]
    fn a_marker_beyond_both_gates_starts_a_track_of_its_own() {
        let (frames, _) = sliding_grid(0.003);
        let tight = TrackingSettings {
            gate_m: 0.01,
            relink_gate_m: 0.001,
        };
        let (_, report) = track_markers(&frames, &tight);
        // The hidden marker reappears 3 mm off its predicted place: no relink within 1 mm.
        assert_eq!(
            (report.breaks, report.relinked, report.new_tracks),
            (1, 0, 1)
        );
        assert!(report.initial_share() < 1.0);
    }
}
