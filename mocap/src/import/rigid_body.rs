//! The cleaning of a rigid body's track: short dropouts bridged, position and orientation
//! low-pass filtered.

use glam::DQuat;

use crate::clean::{self, Butterworth, Series};
use crate::motive::MotiveTake;

/// A rigid body after gap bridging and filtering.
pub(super) struct Pose {
    pub(super) position: Series,
    pub(super) rotation: Vec<Option<[f64; 4]>>,
}

/// Bridges short dropouts of a rigid body (position by [`clean::fill_gaps`], orientation by
/// normalised linear interpolation) and low-pass filters position and orientation.
pub(super) fn clean_rigid_body(
    take: &MotiveTake,
    index: usize,
    max_gap: usize,
    window: usize,
    filter: Option<&Butterworth>,
) -> Pose {
    let body = &take.rigid_bodies[index];
    let mut position = body.position.clone();
    clean::fill_gaps(&mut position, max_gap, max_gap, window, None);
    // Quaternions q and -q are the same rotation: make the series continuous before touching it.
    let mut rotation = body.rotation.clone();
    let mut previous: Option<DQuat> = None;
    for q in rotation.iter_mut().flatten() {
        if previous.is_some_and(|p| p.dot(DQuat::from_array(*q)) < 0.0) {
            *q = q.map(|v| -v);
        }
        previous = Some(DQuat::from_array(*q));
    }
    let spans = clean::runs(&rotation);
    for pair in spans.windows(2) {
        let (a, b) = (pair[0].1 - 1, pair[1].0);
        if b - a - 1 <= max_gap {
            let qa = DQuat::from_array(rotation[a].unwrap());
            let qb = DQuat::from_array(rotation[b].unwrap());
            for (offset, slot) in rotation[a + 1..b].iter_mut().enumerate() {
                // Normalised linear interpolation (the series is continuous, so no sign flip).
                let s = (offset + 1) as f64 / (b - a) as f64;
                *slot = Some(qa.lerp(qb, s).to_array());
            }
        }
    }
    if let Some(filter) = filter {
        filter.filter_series(&mut position);
        for (s, e) in clean::runs(&rotation) {
            for axis in 0..4 {
                let values: Vec<f64> = rotation[s..e].iter().map(|q| q.unwrap()[axis]).collect();
                if let Some(filtered) = filter.filtfilt(&values) {
                    for (k, v) in filtered.into_iter().enumerate() {
                        if let Some(q) = rotation[s + k].as_mut() {
                            q[axis] = v;
                        }
                    }
                }
            }
        }
    }
    for q in rotation.iter_mut().flatten() {
        *q = DQuat::from_array(*q).normalize().to_array();
    }
    Pose { position, rotation }
}
