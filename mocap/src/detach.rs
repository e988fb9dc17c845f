//! Observed detachment: when the recorded package leaves a suction cup, from the recording alone.
//!
//! After the lift the package hangs from the cups, so the top-layer markers next to a cup keep
//! their place in the tool's frame (the `tool.csv` pose) up to the film's give. The scan takes those
//! places at a reference frame (the tool risen [`DetachmentConfig::reference_rise_m`] above its start),
//! then, frame by frame, measures how far the markers around each cup moved: a cup's drift is the
//! smallest distance from one of its reference places to the nearest recorded marker (markers are
//! unlabelled; the smallest, so that one marker occluded or refilled elsewhere does not count). A
//! drift beyond [`DetachmentConfig::threshold_m`] held for [`DetachmentConfig::hold_s`] is the
//! package leaving that cup, timed at the start of the run.

use glam::{DQuat, DVec3};
use serde::{Deserialize, Serialize};

use crate::dataset::Trajectory;

/// The world's up axis: the mocap frame (and the simulator's world) is Y up.
const WORLD_UP: DVec3 = DVec3::Y;

/// Settings of the detachment scan (SI units).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct DetachmentConfig {
    /// The tool's rise above its first-frame position (m) at which the reference places are taken
    /// (the end of the lift: the package hangs from the cups).
    pub reference_rise_m: f64,
    /// Drift (m) beyond which the markers around a cup have left it.
    pub threshold_m: f64,
    /// How long (s) the drift must last: shorter excursions are noise or occlusion fill.
    pub hold_s: f64,
    /// Reference markers of a cup: the nearest this many top-layer markers to its centre ...
    pub markers_per_cup: usize,
    /// ... within this distance of the centre in the tool's plane (m).
    pub cup_reach_m: f64,
    /// Top layer: markers at most this deep below the tool point along the tool's axis at the
    /// reference frame (m); reflections above the tool point are left out.
    pub top_layer_depth_m: f64,
    /// A reference place with no recorded marker within this distance is unseen in that frame (m):
    /// an occluded marker is not a drift.
    pub max_match_m: f64,
}

impl Default for DetachmentConfig {
    /// 10 mm held for 0.1 s, two markers per cup within 45 mm, top layer within 30 mm, 30 mm match.
    fn default() -> Self {
        Self {
            reference_rise_m: 0.1,
            threshold_m: 0.01,
            hold_s: 0.1,
            markers_per_cup: 2,
            cup_reach_m: 0.045,
            top_layer_depth_m: 0.03,
            max_match_m: 0.03,
        }
    }
}

/// The package observed leaving a cup.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Detachment {
    /// Cup index (the order of the cup centres given to [`scan_detachment`]).
    pub cup: usize,
    /// Recording time (s) at which the drift began.
    pub t: f64,
}

/// What [`scan_detachment`] found in one recording.
#[derive(Clone, Debug, PartialEq)]
pub struct DetachmentScan {
    /// Recording time of the reference frame; `None` if the tool never rose far enough.
    pub reference_t: Option<f64>,
    /// Reference markers found per cup.
    pub reference_markers: Vec<usize>,
    /// Per cup, the largest drift held for `hold_s` (m; 0 when never seen that long).
    pub max_held_drift_m: Vec<f64>,
    /// The first cup the package left, if any.
    pub detachment: Option<Detachment>,
}

/// Position `p` (world) in the tool's frame of frame `k`.
fn in_tool_frame(trajectory: &Trajectory, k: usize, p: [f64; 3]) -> DVec3 {
    let q = DQuat::from_array(trajectory.tool.orientation[k]);
    let origin = DVec3::from_array(trajectory.tool.position[k]);
    q.inverse() * (DVec3::from_array(p) - origin)
}

/// Scans `trajectory` for the package leaving one of the cups centred at `cups` (tool frame, m).
pub fn scan_detachment(
    trajectory: &Trajectory,
    cups: &[[f64; 3]],
    config: &DetachmentConfig,
) -> DetachmentScan {
    let tool = &trajectory.tool;
    let frames = tool.t.len().min(trajectory.markers.len());
    let mut scan = DetachmentScan {
        reference_t: None,
        reference_markers: vec![0; cups.len()],
        max_held_drift_m: vec![0.0; cups.len()],
        detachment: None,
    };
    if frames == 0 {
        return scan;
    }
    let start = DVec3::from_array(tool.position[0]);
    let Some(reference) = (0..frames).find(|&k| {
        (DVec3::from_array(tool.position[k]) - start).dot(WORLD_UP) >= config.reference_rise_m
    }) else {
        return scan;
    };
    scan.reference_t = Some(tool.t[reference]);
    // The tool's up axis in its own frame, from the reference frame's orientation.
    let up = DQuat::from_array(tool.orientation[reference]).inverse() * WORLD_UP;
    let planar = |v: DVec3| v - up * v.dot(up);
    let top: Vec<DVec3> = trajectory
        .markers
        .frame(reference)
        .iter()
        .map(|&p| in_tool_frame(trajectory, reference, p))
        .filter(|p| (0.0..=config.top_layer_depth_m).contains(&-p.dot(up)))
        .collect();
    let places: Vec<Vec<DVec3>> = cups
        .iter()
        .map(|&centre| {
            let centre = planar(DVec3::from_array(centre));
            let mut near: Vec<(f64, DVec3)> = top
                .iter()
                .map(|&p| ((planar(p) - centre).length(), p))
                .filter(|(d, _)| *d <= config.cup_reach_m)
                .collect();
            near.sort_by(|a, b| a.0.total_cmp(&b.0));
            near.truncate(config.markers_per_cup);
            near.into_iter().map(|(_, p)| p).collect()
        })
        .collect();
    scan.reference_markers = places.iter().map(Vec::len).collect();

    // Per cup: the drift of every frame from the reference on (None: no place seen).
    let drifts: Vec<Vec<Option<f64>>> = places
        .iter()
        .map(|cup_places| {
            (reference..frames)
                .map(|k| {
                    let markers: Vec<DVec3> = trajectory
                        .markers
                        .frame(k)
                        .iter()
                        .map(|&p| in_tool_frame(trajectory, k, p))
                        .collect();
                    cup_places
                        .iter()
                        .filter_map(|place| {
                            let nearest = markers
                                .iter()
                                .map(|m| (*m - *place).length())
                                .fold(f64::INFINITY, f64::min);
                            (nearest <= config.max_match_m).then_some(nearest)
                        })
                        .reduce(f64::min)
                })
                .collect()
        })
        .collect();
    let times = &tool.t[reference..frames];
    for (cup, drift) in drifts.iter().enumerate() {
        // A run of seen frames: its start and the smallest drift in it so far.
        let mut run_start = 0;
        for (i, d) in drift.iter().enumerate() {
            let Some(d) = *d else {
                run_start = i + 1;
                continue;
            };
            // The window [j, i] of the last hold_s seconds; held drift = its smallest value.
            let mut j = i;
            while j > run_start && times[i] - times[j] < config.hold_s {
                j -= 1;
            }
            if times[i] - times[j] < config.hold_s {
                continue; // not seen for hold_s yet
            }
            let held = drift[j..=i].iter().flatten().copied().fold(d, f64::min);
            scan.max_held_drift_m[cup] = scan.max_held_drift_m[cup].max(held);
            if held > config.threshold_m && scan.detachment.is_none_or(|e| times[j] < e.t) {
                scan.detachment = Some(Detachment { cup, t: times[j] });
            }
        }
    }
    scan
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::dataset::{MarkerFrames, Meta, ObjectTrack, ToolTrack};

    const RATE_HZ: f64 = 250.0;
    const CUPS: [[f64; 3]; 2] = [[0.035, -0.005, 0.035], [-0.035, -0.005, -0.035]];

    /// A synthetic take: the tool rises 0.15 m in the first 0.4 s, then turns about Y while moving
    /// along x; two markers 10 mm under the tool next to each cup (and one reflection above the
    /// tool, and a bottom-layer marker) ride along; from `leave` on, the markers of cup 1 slide
    /// `drift` away in the tool frame. `occlude` hides every marker of cup 1 over a time range.
    fn take(leave: Option<(f64, f64)>, occlude: Option<(f64, f64)>) -> Trajectory {
        let n = (3.0 * RATE_HZ) as usize;
        let t: Vec<f64> = (0..n).map(|k| k as f64 / RATE_HZ).collect();
        let mut position = Vec::new();
        let mut orientation = Vec::new();
        let mut frames = Vec::new();
        let local_markers = [
            ([0.06, -0.01, 0.035], 0),
            ([0.0, -0.01, 0.04], 0),
            ([-0.06, -0.01, -0.035], 1),
            ([0.0, -0.01, -0.04], 1),
            ([0.0, 0.02, 0.0], 2),    // a reflection above the tool point
            ([0.03, -0.07, 0.03], 2), // bottom layer
        ];
        for &tk in &t {
            let rise = 0.15 * (tk / 0.4).min(1.0);
            let p = DVec3::new(0.5 * (tk - 0.4).max(0.0), 0.033 + rise, 0.0);
            let q = DQuat::from_rotation_y(0.8 * (tk - 0.4).max(0.0));
            position.push(p.to_array());
            orientation.push(q.to_array());
            let mut frame = Vec::new();
            for (local, cup) in local_markers {
                let mut local = DVec3::from_array(local);
                if cup == 1 {
                    if let Some((at, drift)) = leave {
                        if tk >= at {
                            local.y -= drift;
                        }
                    }
                    if occlude.is_some_and(|(a, b)| (a..b).contains(&tk)) {
                        continue;
                    }
                }
                // 0.3 mm of alternating noise.
                let noise = if frame.len() % 2 == 0 { 3e-4 } else { -3e-4 };
                frame.push((p + q * local + DVec3::splat(noise)).to_array());
            }
            frames.push(frame);
        }
        let zeros = vec![[0.0; 3]; n];
        Trajectory {
            id: "synthetic".into(),
            meta: Meta {
                id: "synthetic".into(),
                package_size_m: [0.254, 0.3048],
                package_mass_kg: 0.03,
                object_diameter_m: 0.16,
                object_body_mass_kg: 0.2,
                object_total_mass_kg: 0.2,
                total_mass_kg: 0.23,
                initial_suction_cup_position_m: [0.0; 3],
                initial_marker_positions_m: Vec::new(),
                marker_inset_m: None,
                initial_lower_marker_positions_m: Vec::new(),
            },
            tool: ToolTrack {
                t: t.clone(),
                position,
                orientation,
                velocity: zeros.clone(),
                angular_velocity: zeros.clone(),
                acceleration: zeros.clone(),
                angular_acceleration: zeros.clone(),
            },
            object: ObjectTrack {
                t: t.clone(),
                position: zeros.clone(),
                velocity: zeros.clone(),
                acceleration: zeros,
            },
            markers: MarkerFrames::from_frames(t, frames),
        }
    }

    fn config() -> DetachmentConfig {
        DetachmentConfig {
            reference_rise_m: 0.149,
            ..DetachmentConfig::default()
        }
    }

    #[test]
    fn a_package_held_through_turns_is_not_flagged() {
        let scan = scan_detachment(&take(None, None), &CUPS, &config());
        assert_eq!(scan.reference_markers, vec![2, 2]);
        let reference = scan.reference_t.unwrap();
        assert!((0.39..0.41).contains(&reference), "{reference}");
        assert_eq!(scan.detachment, None);
        assert!(scan.max_held_drift_m.iter().all(|&d| d < 1e-3), "{scan:?}");
    }

    #[test]
    fn markers_leaving_a_cup_are_flagged_at_the_start_of_the_drift() {
        let scan = scan_detachment(&take(Some((1.5, 0.02)), None), &CUPS, &config());
        let found = scan.detachment.expect("detached");
        assert_eq!(found.cup, 1);
        assert!((found.t - 1.5).abs() < 1e-9, "{found:?}");
        assert!(scan.max_held_drift_m[1] > 0.019);
        assert!(scan.max_held_drift_m[0] < 1e-3);
    }

    #[test]
    fn short_excursions_small_drifts_and_occlusions_are_not_flagged() {
        // Under the threshold.
        let small = scan_detachment(&take(Some((1.5, 0.008)), None), &CUPS, &config());
        assert_eq!(small.detachment, None);
        assert!(small.max_held_drift_m[1] > 0.007);
        // Beyond it for less than hold_s: the drift returns (markers occluded from 1.55 s on,
        // refilled nowhere) before it was held.
        let brief = scan_detachment(
            &take(Some((1.5, 0.02)), Some((1.55, 3.0))),
            &CUPS,
            &config(),
        );
        assert_eq!(brief.detachment, None);
        // Every marker of a cup occluded for a while: unseen, not drifted.
        let hidden = scan_detachment(&take(None, Some((1.0, 1.5))), &CUPS, &config());
        assert_eq!(hidden.detachment, None);
    }

    #[test]
    fn a_tool_that_never_lifts_gives_no_reference() {
        let strict = DetachmentConfig {
            reference_rise_m: 0.5,
            ..config()
        };
        let scan = scan_detachment(&take(Some((1.5, 0.02)), None), &CUPS, &strict);
        assert_eq!(scan.reference_t, None);
        assert_eq!(scan.detachment, None);
    }
}
