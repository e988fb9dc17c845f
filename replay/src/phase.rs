//! The phases of a recorded motion, so that a likelihood can make each of them count.
//!
//! A recording spends most of its frames carrying the package level; the few hundred frames in
//! which the tool tilts are where friction and contact between film and object act. Weighing every
//! frame the same lets the long phases decide the fit. Each compared frame is put in one phase from
//! the recorded tool motion at that frame:
//!
//! * **rest**: before the tool first moves;
//! * **tilt**: the tool turns faster than [`TILT_RAD_S`];
//! * **lift**: the tool moves faster than [`MOVING_M_S`], mostly vertically (world y up);
//! * **move**: the tool moves faster than [`MOVING_M_S`] otherwise;
//! * **hold**: after the first motion, the tool nearly still.
//!
//! The thresholds are assumptions, set above the recorded rates' noise at rest (about 0.02 m/s and
//! 0.2 rad/s in the study's tool tracks, which are differentiated motion capture).

use serde::{Deserialize, Serialize};

use rlpkg_mocap::ToolTrack;

/// Tool speed (m/s) above which the tool counts as moving (assumption, see the module docs).
pub const MOVING_M_S: f64 = 0.05;
/// Tool angular speed (rad/s) above which the tool counts as tilting (assumption).
pub const TILT_RAD_S: f64 = 0.3;
/// Share of a moving tool's speed that is vertical from which the motion counts as a lift.
const LIFT_SHARE: f64 = 0.7;

/// The phase of the motion at one frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Phase {
    /// Before the tool first moves.
    Rest,
    /// Moving, mostly vertically.
    Lift,
    /// Moving otherwise.
    Move,
    /// Turning.
    Tilt,
    /// Nearly still after the first motion.
    Hold,
}

impl Phase {
    /// Every phase, in the order above.
    pub const ALL: [Phase; 5] = [
        Phase::Rest,
        Phase::Lift,
        Phase::Move,
        Phase::Tilt,
        Phase::Hold,
    ];

    /// The phase's name as in files (`rest`, `lift`, ...).
    pub fn name(self) -> &'static str {
        match self {
            Phase::Rest => "rest",
            Phase::Lift => "lift",
            Phase::Move => "move",
            Phase::Tilt => "tilt",
            Phase::Hold => "hold",
        }
    }
}

fn norm(v: &[f64; 3]) -> f64 {
    (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt()
}

/// The phase of each of the first `frames` frames of `tool`.
pub fn phases(tool: &ToolTrack, frames: usize) -> Vec<Phase> {
    let mut started = false;
    (0..frames.min(tool.t.len()))
        .map(|k| {
            let speed = norm(&tool.velocity[k]);
            let turning = norm(&tool.angular_velocity[k]) > TILT_RAD_S;
            let moving = speed > MOVING_M_S;
            started |= moving || turning;
            if turning {
                Phase::Tilt
            } else if moving && tool.velocity[k][1].abs() > LIFT_SHARE * speed {
                Phase::Lift
            } else if moving {
                Phase::Move
            } else if started {
                Phase::Hold
            } else {
                Phase::Rest
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_recorded_transport_has_rest_move_tilt_and_hold() {
        let trajectory = crate::test_support::recorded("HHHHH");
        let phases = phases(&trajectory.tool, trajectory.tool.t.len());
        assert_eq!(phases[0], Phase::Rest);
        let count = |p| phases.iter().filter(|&&q| q == p).count();
        // HHHHH carries the package level, then tilts it back and forth from about 3 s on.
        assert!(count(Phase::Move) > 200, "{}", count(Phase::Move));
        assert!(count(Phase::Tilt) > 200, "{}", count(Phase::Tilt));
        assert!(count(Phase::Hold) > 10);
        // All but a few frames of turning come after 2.5 s.
        let early = (0..phases.len())
            .filter(|&k| phases[k] == Phase::Tilt && trajectory.tool.t[k] < 2.5)
            .count();
        assert!(early * 100 < count(Phase::Tilt), "{early}");
        // Rest only at the start.
        let last_rest = phases.iter().rposition(|&p| p == Phase::Rest).unwrap();
        assert!(phases[..=last_rest].iter().all(|&p| p == Phase::Rest));
    }

    #[test]
    fn a_vertical_motion_is_a_lift() {
        let tool = ToolTrack {
            t: vec![0.0, 0.1, 0.2],
            velocity: vec![[0.0; 3], [0.0, 0.2, 0.01], [0.0; 3]],
            angular_velocity: vec![[0.0; 3]; 3],
            ..ToolTrack::default()
        };
        assert_eq!(
            phases(&tool, 3),
            [Phase::Rest, Phase::Lift, Phase::Hold].to_vec()
        );
    }
}
