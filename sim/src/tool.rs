//! How the tool moves: along a recorded [`ToolTrajectory`], or by a [`ToolCommand`] every control
//! step, within the robot's [`ToolLimits`].
//!
//! A command covers one control interval of length `T`. Over it the tool accelerates uniformly
//! from its current twist to the twist the command asks for (linear and angular parts alike), so
//! the substeps interpolate a smooth path: position `p0 + v0·τ + ½·a·τ²`, orientation
//! `exp(w0·τ + ½·α·τ²) ⊗ q0` (world-frame rotation vector; exact when the axis does not change
//! within the interval). After `T`, until the next command, the tool keeps its last twist, as a
//! robot's velocity interface does until its watchdog.
//!
//! Limits are applied to the commanded twist: first the acceleration (the change of twist over
//! `T`), then the speed (radial projection onto the speed ball, which never raises the
//! acceleration because projection onto a convex set containing the current twist is
//! non-expansive). Every clamp is reported in the returned [`ToolCommandReport`] and counted
//! per environment; nothing is clipped silently.

use std::sync::Arc;

use glam::{DQuat, DVec3};
use serde::{Deserialize, Serialize};

use crate::config::ToolLimits;
use crate::trajectory::{ToolPose, ToolTrajectory};

/// What the tool should do over the next control interval (world frame, SI).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum ToolCommand {
    /// Reach this twist at the end of the interval.
    Twist {
        /// Linear velocity (m/s).
        linear: [f32; 3],
        /// Angular velocity (rad/s).
        angular: [f32; 3],
    },
    /// Move towards this pose and stop there: the twist asked for points at the pose, with a
    /// speed that covers the remaining distance in one interval at most, stays within the speed
    /// limit, and can still brake to rest at the acceleration limit (the same for the rotation).
    /// Repeated every interval, the tool converges to the pose without overshooting.
    Pose {
        /// Position (m).
        position: [f32; 3],
        /// Orientation (x, y, z, w); normalised here.
        orientation: [f32; 4],
    },
}

/// What the limits did to one command.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct ToolCommandReport {
    /// Linear acceleration asked for and applied (m/s², norms).
    pub accel_requested: f32,
    /// Applied linear acceleration (m/s²).
    pub accel_applied: f32,
    /// Linear speed at the end of the interval, asked for and applied (m/s).
    pub speed_requested: f32,
    /// Applied end speed (m/s).
    pub speed_applied: f32,
    /// Angular acceleration asked for (rad/s²).
    pub angular_accel_requested: f32,
    /// Applied angular acceleration (rad/s²).
    pub angular_accel_applied: f32,
    /// Angular speed at the end of the interval asked for (rad/s).
    pub angular_speed_requested: f32,
    /// Applied end angular speed (rad/s).
    pub angular_speed_applied: f32,
}

impl ToolCommandReport {
    /// Whether any limit clamped the command.
    pub fn clamped(&self) -> bool {
        self.accel_applied < self.accel_requested
            || self.speed_applied < self.speed_requested
            || self.angular_accel_applied < self.angular_accel_requested
            || self.angular_speed_applied < self.angular_speed_requested
    }
}

/// Pose and twist of the tool at one instant (world frame).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct ToolState {
    /// Position (m).
    pub position: [f64; 3],
    /// Orientation (x, y, z, w).
    pub orientation: [f64; 4],
    /// Linear velocity (m/s).
    pub velocity: [f64; 3],
    /// Angular velocity (rad/s).
    pub angular_velocity: [f64; 3],
}

impl ToolState {
    /// The pose as the cups see it (f32).
    pub fn pose(&self) -> ToolPose {
        ToolPose {
            position: self.position.map(|c| c as f32),
            orientation: self.orientation.map(|c| c as f32),
            velocity: self.velocity.map(|c| c as f32),
            angular_velocity: self.angular_velocity.map(|c| c as f32),
        }
    }
}

/// One commanded control interval: uniform acceleration from `start`'s twist.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub(crate) struct ToolSegment {
    /// Environment time at which the interval starts (s).
    pub(crate) t0: f64,
    /// Pose and twist at `t0`.
    pub(crate) start: ToolState,
    /// Linear acceleration (m/s²).
    pub(crate) accel: [f64; 3],
    /// Angular acceleration (rad/s²).
    pub(crate) angular_accel: [f64; 3],
    /// Interval length (s).
    pub(crate) duration: f64,
}

impl ToolSegment {
    pub(crate) fn state_at(&self, t: f64) -> ToolState {
        let tau = (t - self.t0).max(0.0);
        let ramp = tau.min(self.duration);
        let coast = tau - ramp;
        let v0 = DVec3::from(self.start.velocity);
        let w0 = DVec3::from(self.start.angular_velocity);
        let (a, alpha) = (DVec3::from(self.accel), DVec3::from(self.angular_accel));
        let v1 = v0 + a * ramp;
        let w1 = w0 + alpha * ramp;
        let p = DVec3::from(self.start.position) + v0 * ramp + a * (0.5 * ramp * ramp) + v1 * coast;
        let phi = w0 * ramp + alpha * (0.5 * ramp * ramp) + w1 * coast;
        let q =
            (DQuat::from_scaled_axis(phi) * DQuat::from_array(self.start.orientation)).normalize();
        ToolState {
            position: p.to_array(),
            orientation: q.to_array(),
            velocity: v1.to_array(),
            angular_velocity: w1.to_array(),
        }
    }
}

/// What drives one environment's tool.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub(crate) enum ToolDrive {
    /// A recorded trajectory, started after the rest period.
    Trajectory(Arc<ToolTrajectory>),
    /// Commands, one control interval at a time.
    Commanded(ToolSegment),
}

impl ToolDrive {
    /// The tool at environment time `t` (the rest period is `rest_time` long).
    pub(crate) fn state_at(&self, t: f64, rest_time: f64) -> ToolState {
        match self {
            ToolDrive::Trajectory(traj) => {
                let pose = traj.pose_at(t - rest_time);
                ToolState {
                    position: pose.position.map(f64::from),
                    orientation: pose.orientation.map(f64::from),
                    velocity: pose.velocity.map(f64::from),
                    angular_velocity: pose.angular_velocity.map(f64::from),
                }
            }
            ToolDrive::Commanded(segment) => segment.state_at(t),
        }
    }
}

/// Clamps `target` so that it differs from `current` by at most `max_delta` and has a norm of at
/// most `max_norm`; returns it with (requested change, applied change, requested norm, applied norm).
fn limit(current: DVec3, target: DVec3, max_delta: f64, max_norm: f64) -> (DVec3, [f64; 4]) {
    let delta = target - current;
    let clamped = current + delta.clamp_length_max(max_delta);
    let applied = clamped.clamp_length_max(max_norm);
    (
        applied,
        [
            delta.length(),
            (applied - current).length(),
            target.length(),
            applied.length(),
        ],
    )
}

/// The segment that carries out `command` from `now` (the tool's state at `t0`) over `duration`
/// seconds within `limits`, and what the limits did.
pub(crate) fn plan(
    t0: f64,
    now: ToolState,
    command: ToolCommand,
    duration: f64,
    limits: &ToolLimits,
) -> (ToolSegment, ToolCommandReport) {
    let v0 = DVec3::from(now.velocity);
    let w0 = DVec3::from(now.angular_velocity);
    let (v_target, w_target) = match command {
        ToolCommand::Twist { linear, angular } => (
            DVec3::from(linear.map(f64::from)),
            DVec3::from(angular.map(f64::from)),
        ),
        ToolCommand::Pose {
            position,
            orientation,
        } => {
            let distance = DVec3::from(position.map(f64::from)) - DVec3::from(now.position);
            let q1 = DQuat::from_array(orientation.map(f64::from)).normalize();
            let q0 = DQuat::from_array(now.orientation);
            let mut dq = q1 * q0.inverse();
            if dq.w < 0.0 {
                dq = -dq; // the short way round
            }
            let rotation = dq.to_scaled_axis();
            // Towards the goal at the largest end speed v1 that stays within the limit and
            // still lets the tool stop after this interval at the acceleration limit a, in whole
            // intervals of uniform acceleration (stopping distance at most v1^2 / (2 a) + v1 T / 2):
            // d - (v0 + v1) T / 2 >= v1^2 / (2 a) + v1 T / 2.
            let approach = |gap: DVec3, now: DVec3, max_speed: f32, max_accel: f32| {
                let (d, a) = (gap.length(), max_accel as f64);
                let along = now.dot(gap.normalize_or_zero());
                let room = (d - along * duration / 2.0).max(0.0);
                let step = a * duration;
                let speed = ((step * step + 2.0 * a * room).sqrt() - step)
                    .min(max_speed as f64)
                    .max(0.0);
                gap.normalize_or_zero() * speed
            };
            (
                approach(distance, v0, limits.max_speed_m_s, limits.max_accel_m_s2),
                approach(
                    rotation,
                    w0,
                    limits.max_angular_speed_rad_s,
                    limits.max_angular_accel_rad_s2,
                ),
            )
        }
    };
    let (v1, lin) = limit(
        v0,
        v_target,
        limits.max_accel_m_s2 as f64 * duration,
        limits.max_speed_m_s as f64,
    );
    let (w1, ang) = limit(
        w0,
        w_target,
        limits.max_angular_accel_rad_s2 as f64 * duration,
        limits.max_angular_speed_rad_s as f64,
    );
    let report = ToolCommandReport {
        accel_requested: (lin[0] / duration) as f32,
        accel_applied: (lin[1] / duration) as f32,
        speed_requested: lin[2] as f32,
        speed_applied: lin[3] as f32,
        angular_accel_requested: (ang[0] / duration) as f32,
        angular_accel_applied: (ang[1] / duration) as f32,
        angular_speed_requested: ang[2] as f32,
        angular_speed_applied: ang[3] as f32,
    };
    let segment = ToolSegment {
        t0,
        start: now,
        accel: ((v1 - v0) / duration).to_array(),
        angular_accel: ((w1 - w0) / duration).to_array(),
        duration,
    };
    (segment, report)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn still() -> ToolState {
        ToolState {
            position: [0.0, 0.5, 0.0],
            orientation: [0.0, 0.0, 0.0, 1.0],
            velocity: [0.0; 3],
            angular_velocity: [0.0; 3],
        }
    }

    #[test]
    fn repeated_pose_commands_converge_without_overshoot() {
        let limits = ToolLimits::default();
        let target = DQuat::from_rotation_z(0.4);
        let goal = [0.3, 0.62, -0.1];
        let command = ToolCommand::Pose {
            position: goal.map(|c| c as f32),
            orientation: target.to_array().map(|c| c as f32),
        };
        let mut state = still();
        let (mut t, dt) = (0.0, 0.05);
        let mut closest = f64::INFINITY;
        for _ in 0..40 {
            let (seg, report) = plan(t, state, command, dt, &limits);
            assert!(report.speed_applied <= limits.max_speed_m_s + 1e-6);
            t += dt;
            state = seg.state_at(t);
            let gap = (DVec3::from(goal) - DVec3::from(state.position)).length();
            // Never past the goal along x (it starts short of it).
            assert!(state.position[0] <= goal[0] + 1e-6, "{:?}", state.position);
            closest = closest.min(gap);
        }
        assert!(closest < 1e-3, "{closest}");
        let speed = DVec3::from(state.velocity).length();
        assert!(speed < 0.02, "{speed}");
        assert!(DQuat::from_array(state.orientation).angle_between(target) < 1e-2);
    }

    #[test]
    fn limits_clamp_and_report() {
        let limits = ToolLimits::default();
        let fast = ToolCommand::Twist {
            linear: [5.0, 0.0, 0.0],
            angular: [0.0, 0.0, 0.0],
        };
        // 5 m/s in 0.1 s would be 50 m/s²: clamped to 10 m/s², so 1 m/s at the end.
        let (seg, report) = plan(0.0, still(), fast, 0.1, &limits);
        assert!(report.clamped());
        assert!((report.accel_requested - 50.0).abs() < 1e-3);
        assert!((report.accel_applied - 10.0).abs() < 1e-3);
        assert!((seg.state_at(0.1).velocity[0] - 1.0).abs() < 1e-9);
        // From 1.9 m/s, asking 3 m/s: the acceleration fits (1.1 m/s over 0.2 s) but the speed is
        // capped at 2 m/s.
        let mut moving = still();
        moving.velocity = [1.9, 0.0, 0.0];
        let faster = ToolCommand::Twist {
            linear: [3.0, 0.0, 0.0],
            angular: [0.0, 0.0, 0.0],
        };
        let (seg, report) = plan(0.0, moving, faster, 0.2, &limits);
        assert!(report.clamped() && (report.speed_applied - 2.0).abs() < 1e-6);
        assert!((seg.state_at(5.0).velocity[0] - 2.0).abs() < 1e-9);
        // After the interval the tool coasts at its last twist.
        let p1 = seg.state_at(0.2).position[0];
        assert!((seg.state_at(0.7).position[0] - p1 - 1.0).abs() < 1e-9);
    }
}
