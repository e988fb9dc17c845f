//! Timestamped tool trajectories and their interpolation to substeps.
//!
//! Positions and linear velocities are interpolated linearly, orientations by normalised linear
//! interpolation (nlerp) with hemisphere alignment. The reference resamples with a cubic spline
//! and a slightly stretched time base (`reference-model.md` §3.3, §12 item 8); at 240 Hz samples
//! the difference between linear and cubic is far below the mocap noise, and we play the recording
//! at its own timestamps. Before the first sample the tool holds its first pose with zero velocity
//! (the rest period), after the last it holds the last pose with zero velocity.

use glam::DQuat;
use serde::{Deserialize, Serialize};

use crate::error::SimError;

/// One recorded tool sample (world frame, SI).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct ToolSample {
    /// Time (s) from the start of motion.
    pub t: f64,
    /// Tool position (m).
    pub position: [f64; 3],
    /// Tool orientation, quaternion (x, y, z, w).
    pub orientation: [f64; 4],
    /// Tool linear velocity (m/s).
    pub velocity: [f64; 3],
}

/// The tool pose at one instant, as the cups see it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ToolPose {
    /// Position (m).
    pub position: [f32; 3],
    /// Orientation (x, y, z, w), unit.
    pub orientation: [f32; 4],
    /// Linear velocity (m/s).
    pub velocity: [f32; 3],
    /// Angular velocity (rad/s, world frame).
    pub angular_velocity: [f32; 3],
}

/// A validated tool trajectory: at least one sample, strictly increasing finite times.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(try_from = "Vec<ToolSample>", into = "Vec<ToolSample>")]
pub struct ToolTrajectory {
    samples: Vec<ToolSample>,
}

fn normalise(q: [f64; 4]) -> [f64; 4] {
    let n = (q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]).sqrt();
    q.map(|c| c / n)
}

impl ToolTrajectory {
    /// Validates and stores samples (quaternions are normalised).
    pub fn new(samples: Vec<ToolSample>) -> Result<Self, SimError> {
        if samples.is_empty() {
            return Err(SimError::Trajectory("no samples".into()));
        }
        for (i, s) in samples.iter().enumerate() {
            let finite = s.t.is_finite()
                && s.position
                    .iter()
                    .chain(&s.orientation)
                    .chain(&s.velocity)
                    .all(|c| c.is_finite());
            if !finite {
                return Err(SimError::Trajectory(format!(
                    "sample {i} has a non-finite value"
                )));
            }
            let norm = s.orientation.iter().map(|c| c * c).sum::<f64>().sqrt();
            if norm < 1e-6 {
                return Err(SimError::Trajectory(format!(
                    "sample {i} has a zero quaternion"
                )));
            }
            if i > 0 && s.t <= samples[i - 1].t {
                return Err(SimError::Trajectory(format!(
                    "sample {i}: time {} is not after the previous sample's {}",
                    s.t,
                    samples[i - 1].t
                )));
            }
        }
        let samples = samples
            .into_iter()
            .map(|s| ToolSample {
                orientation: normalise(s.orientation),
                ..s
            })
            .collect();
        Ok(ToolTrajectory { samples })
    }

    /// A tool that never moves.
    pub fn hold(position: [f64; 3], orientation: [f64; 4]) -> Self {
        ToolTrajectory {
            samples: vec![ToolSample {
                t: 0.0,
                position,
                orientation: normalise(orientation),
                velocity: [0.0; 3],
            }],
        }
    }

    /// The samples.
    pub fn samples(&self) -> &[ToolSample] {
        &self.samples
    }

    /// Time of the last sample (s).
    pub fn duration(&self) -> f64 {
        self.samples[self.samples.len() - 1].t
    }

    /// The interpolated pose at trajectory time `t` (s, 0 = first sample's time base).
    pub fn pose_at(&self, t: f64) -> ToolPose {
        let s = &self.samples;
        let hold = |x: &ToolSample| ToolPose {
            position: x.position.map(|c| c as f32),
            orientation: x.orientation.map(|c| c as f32),
            velocity: [0.0; 3],
            angular_velocity: [0.0; 3],
        };
        if t <= s[0].t {
            return hold(&s[0]);
        }
        let last = &s[s.len() - 1];
        if t >= last.t {
            return hold(last);
        }
        let k = s.partition_point(|x| x.t <= t); // s[k-1].t <= t < s[k].t
        let (a, b) = (&s[k - 1], &s[k]);
        let u = (t - a.t) / (b.t - a.t);
        let lerp = |x: f64, y: f64| x + (y - x) * u;
        let dot: f64 = (0..4).map(|i| a.orientation[i] * b.orientation[i]).sum();
        let sign = if dot < 0.0 { -1.0 } else { 1.0 };
        let q = normalise(std::array::from_fn(|i| {
            lerp(a.orientation[i], sign * b.orientation[i])
        }));
        // The segment's constant angular velocity: its rotation over its duration.
        let qa = DQuat::from_array(a.orientation);
        let qb = DQuat::from_array(b.orientation.map(|c| sign * c));
        let omega = (qb * qa.inverse()).to_scaled_axis() / (b.t - a.t);
        ToolPose {
            position: std::array::from_fn(|i| lerp(a.position[i], b.position[i]) as f32),
            orientation: q.map(|c| c as f32),
            velocity: std::array::from_fn(|i| lerp(a.velocity[i], b.velocity[i]) as f32),
            angular_velocity: omega.to_array().map(|c| c as f32),
        }
    }
}

impl TryFrom<Vec<ToolSample>> for ToolTrajectory {
    type Error = SimError;
    fn try_from(samples: Vec<ToolSample>) -> Result<Self, SimError> {
        ToolTrajectory::new(samples)
    }
}

impl From<ToolTrajectory> for Vec<ToolSample> {
    fn from(trajectory: ToolTrajectory) -> Self {
        trajectory.samples
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample(t: f64, x: f64, q: [f64; 4]) -> ToolSample {
        ToolSample {
            t,
            position: [x, 0.0, 0.0],
            orientation: q,
            velocity: [x, 0.0, 0.0],
        }
    }

    #[test]
    fn interpolates_and_holds() {
        let q0 = [0.0, 0.0, 0.0, 1.0];
        let h = std::f64::consts::FRAC_1_SQRT_2;
        let traj = ToolTrajectory::new(vec![
            sample(0.0, 0.0, q0),
            sample(1.0, 2.0, [0.0, h, 0.0, h]),
        ])
        .unwrap();
        let mid = traj.pose_at(0.25);
        assert!((mid.position[0] - 0.5).abs() < 1e-6 && (mid.velocity[0] - 0.5).abs() < 1e-6);
        // A quarter turn about y in 1 s.
        assert!((mid.angular_velocity[1] - std::f32::consts::FRAC_PI_2).abs() < 1e-5);
        let n: f32 = mid.orientation.iter().map(|c| c * c).sum();
        assert!((n - 1.0).abs() < 1e-6);
        assert_eq!(traj.pose_at(-3.0).velocity, [0.0; 3]);
        assert_eq!(traj.pose_at(5.0).position[0], 2.0);
        assert_eq!(traj.pose_at(5.0).velocity, [0.0; 3]);
    }

    #[test]
    fn quaternion_sign_flip_does_not_swing() {
        let q = [0.0, 0.0, 0.0, 1.0];
        let traj = ToolTrajectory::new(vec![
            sample(0.0, 0.0, q),
            sample(1.0, 0.0, [0.0, 0.0, 0.0, -1.0]),
        ])
        .unwrap();
        let mid = traj.pose_at(0.5);
        assert!((mid.orientation[3].abs() - 1.0).abs() < 1e-6);
    }

    #[test]
    fn rejects_bad_samples() {
        let q = [0.0, 0.0, 0.0, 1.0];
        assert!(ToolTrajectory::new(vec![]).is_err());
        assert!(ToolTrajectory::new(vec![sample(0.0, 0.0, q), sample(0.0, 1.0, q)]).is_err());
        assert!(ToolTrajectory::new(vec![sample(0.0, f64::NAN, q)]).is_err());
        assert!(ToolTrajectory::new(vec![sample(0.0, 0.0, [0.0; 4])]).is_err());
    }
}
