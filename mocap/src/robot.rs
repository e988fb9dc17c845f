//! A robot's own trajectory file (the commanded tool motion) and its transform into the
//! motion-capture frame, so that the tool track of a dataset can come from the robot's command
//! instead of the Motive tool rigid body.
//!
//! Format: a CSV file with the header
//! `time_s,pos_x,pos_y,pos_z,quat_x,quat_y,quat_z,quat_w,vel_x,vel_y,vel_z,omega_x,omega_y,omega_z,acc_x,acc_y,acc_z`
//! and one row per command sample, in the robot base frame, SI units: time (s, on the Motive take's
//! clock, strictly increasing), tool-point position (m), tool orientation as a unit quaternion
//! (x, y, z, w), linear velocity (m/s), angular velocity (rad/s, base frame) and linear
//! acceleration (m/s²), the last three the analytic derivatives of the commanded path.

use std::path::{Path, PathBuf};

use nalgebra::{Matrix3, Quaternion, Rotation3, UnitQuaternion, Vector3};
use serde::{Deserialize, Serialize};

use crate::clean::rigid_fit;
use crate::dataset::{check_increasing, read_rows, DataError, ToolTrack};
use crate::derivative::gradient;

/// Header of a robot trajectory file.
pub const ROBOT_HEADER: [&str; 17] = [
    "time_s", "pos_x", "pos_y", "pos_z", "quat_x", "quat_y", "quat_z", "quat_w", "vel_x", "vel_y",
    "vel_z", "omega_x", "omega_y", "omega_z", "acc_x", "acc_y", "acc_z",
];

/// The commanded tool motion, robot base frame, one entry per row of the file.
#[derive(Debug, Clone, PartialEq)]
pub struct RobotTrajectory {
    /// The file it was read from.
    pub path: PathBuf,
    /// Time (s).
    pub t: Vec<f64>,
    /// Tool-point position (m).
    pub position: Vec<[f64; 3]>,
    /// Tool orientation (x, y, z, w), normalised.
    pub orientation: Vec<[f64; 4]>,
    /// Linear velocity (m/s).
    pub velocity: Vec<[f64; 3]>,
    /// Angular velocity (rad/s).
    pub angular_velocity: Vec<[f64; 3]>,
    /// Linear acceleration (m/s²).
    pub acceleration: Vec<[f64; 3]>,
}

/// Reads and validates a robot trajectory file; errors name the file, the line and what was
/// expected.
pub fn read_robot(path: &Path) -> Result<RobotTrajectory, DataError> {
    let rows = read_rows(path, &ROBOT_HEADER)?;
    check_increasing(path, &rows)?;
    let mut robot = RobotTrajectory {
        path: path.to_path_buf(),
        t: Vec::with_capacity(rows.len()),
        position: Vec::with_capacity(rows.len()),
        orientation: Vec::with_capacity(rows.len()),
        velocity: Vec::with_capacity(rows.len()),
        angular_velocity: Vec::with_capacity(rows.len()),
        acceleration: Vec::with_capacity(rows.len()),
    };
    for (line, v) in &rows {
        let q = [v[4], v[5], v[6], v[7]];
        let norm = q.iter().map(|c| c * c).sum::<f64>().sqrt();
        if (norm - 1.0).abs() > 1e-3 {
            return Err(DataError::Malformed {
                path: path.to_path_buf(),
                line: *line,
                message: format!(
                    "quat_x,quat_y,quat_z,quat_w must be a unit quaternion, its norm is {norm}"
                ),
            });
        }
        robot.t.push(v[0]);
        robot.position.push([v[1], v[2], v[3]]);
        robot.orientation.push(q.map(|c| c / norm));
        robot.velocity.push([v[8], v[9], v[10]]);
        robot.angular_velocity.push([v[11], v[12], v[13]]);
        robot.acceleration.push([v[14], v[15], v[16]]);
    }
    Ok(robot)
}

/// The command sampled at time `t` (linear interpolation between rows; quaternions normalised
/// after interpolating along the shorter arc); `None` outside the file's time span.
fn sample(robot: &RobotTrajectory, t: f64) -> Option<Sample> {
    const SLACK_S: f64 = 1e-6;
    let (first, last) = (*robot.t.first()?, *robot.t.last()?);
    if t < first - SLACK_S || t > last + SLACK_S {
        return None;
    }
    let t = t.clamp(first, last);
    let b = robot.t.partition_point(|&x| x < t).min(robot.t.len() - 1);
    let a = b.saturating_sub(1);
    let s = if a == b {
        0.0
    } else {
        (t - robot.t[a]) / (robot.t[b] - robot.t[a])
    };
    let lerp3 = |v: &[[f64; 3]]| -> Vector3<f64> {
        Vector3::from(v[a]) + s * (Vector3::from(v[b]) - Vector3::from(v[a]))
    };
    let (qa, mut qb) = (robot.orientation[a], robot.orientation[b]);
    if qa.iter().zip(&qb).map(|(x, y)| x * y).sum::<f64>() < 0.0 {
        qb = qb.map(|c| -c);
    }
    let q: [f64; 4] = std::array::from_fn(|i| qa[i] + s * (qb[i] - qa[i]));
    Some(Sample {
        position: lerp3(&robot.position),
        orientation: UnitQuaternion::from_quaternion(Quaternion::new(q[3], q[0], q[1], q[2])),
        velocity: lerp3(&robot.velocity),
        angular_velocity: lerp3(&robot.angular_velocity),
        acceleration: lerp3(&robot.acceleration),
    })
}

/// One interpolated command sample.
struct Sample {
    position: Vector3<f64>,
    orientation: UnitQuaternion<f64>,
    velocity: Vector3<f64>,
    angular_velocity: Vector3<f64>,
    acceleration: Vector3<f64>,
}

/// A rigid transform from the robot base frame into the motion-capture frame:
/// `p_mocap = rotation * p_robot + translation`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RigidTransform {
    /// Rotation from robot to mocap axes.
    pub rotation: UnitQuaternion<f64>,
    /// Translation (m, mocap frame).
    pub translation: Vector3<f64>,
}

impl RigidTransform {
    /// Maps a point.
    pub fn point(&self, p: Vector3<f64>) -> Vector3<f64> {
        self.rotation * p + self.translation
    }

    /// Least-squares rigid transform mapping `robot` points onto `mocap` points (Kabsch, see
    /// [`crate::clean`]); `None` for fewer than three pairs or points that (nearly) lie on a line,
    /// where the rotation about that line is undetermined.
    pub fn fit(robot: &[Vector3<f64>], mocap: &[Vector3<f64>]) -> Option<RigidTransform> {
        if robot.len() != mocap.len() {
            return None;
        }
        // The spread (RMS) of the path along its second principal direction must reach 1 mm, or
        // the rotation about the path's line is noise.
        let n = robot.len().max(1) as f64;
        let centre = robot.iter().sum::<Vector3<f64>>() / n;
        let covariance: Matrix3<f64> = robot
            .iter()
            .map(|p| (p - centre) * (p - centre).transpose())
            .sum::<Matrix3<f64>>()
            / n;
        let mut variances: Vec<f64> = covariance.symmetric_eigenvalues().iter().copied().collect();
        variances.sort_by(|a, b| b.total_cmp(a));
        if variances.len() < 2 || variances[1] < 1e-6 {
            return None;
        }
        let robot: Vec<[f64; 3]> = robot.iter().map(|&p| p.into()).collect();
        let mocap: Vec<[f64; 3]> = mocap.iter().map(|&p| p.into()).collect();
        let (matrix, robot_centre, mocap_centre) = rigid_fit(&robot, &mocap)?;
        let rotation =
            UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(matrix));
        Some(RigidTransform {
            rotation,
            translation: mocap_centre - rotation * robot_centre,
        })
    }

    /// Root-mean-square distance (m) between the mapped `robot` points and the `mocap` points.
    pub fn rms_error(&self, robot: &[Vector3<f64>], mocap: &[Vector3<f64>]) -> f64 {
        let sum: f64 = robot
            .iter()
            .zip(mocap)
            .map(|(r, m)| (self.point(*r) - m).norm_squared())
            .sum();
        (sum / robot.len().max(1) as f64).sqrt()
    }
}

/// `[robot]` of `configs/import/motive.toml`: how a robot trajectory file maps into the mocap frame.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RobotConfig {
    /// Rotation from robot to mocap axes (x, y, z, w); with `translation_m`, or neither to estimate
    /// the transform from the Motive tool rigid body.
    #[serde(deserialize_with = "rlpkg_toml_input::option")]
    pub rotation_xyzw: Option<[f64; 4]>,
    /// Translation (m): `p_mocap = rotation * p_robot + translation_m`.
    #[serde(deserialize_with = "rlpkg_toml_input::option")]
    pub translation_m: Option<[f64; 3]>,
    /// Largest accepted RMS distance (m) between the transformed command and the Motive tool
    /// rigid body over the imported frames (catches a wrong file pair or a wrong transform).
    pub max_fit_rms_m: f64,
}

impl Default for RobotConfig {
    fn default() -> Self {
        RobotConfig {
            rotation_xyzw: None,
            translation_m: None,
            max_fit_rms_m: 0.005,
        }
    }
}

impl RobotConfig {
    /// Checks the keys; the message names the key and what was expected.
    pub fn validate(&self) -> Result<(), String> {
        // Above 1 m the check would pass any file, including another take's.
        if !(self.max_fit_rms_m.is_finite()
            && self.max_fit_rms_m > 0.0
            && self.max_fit_rms_m <= 1.0)
        {
            return Err(format!(
                "robot.max_fit_rms_m = {}: expected a number in (0, 1] m",
                self.max_fit_rms_m
            ));
        }
        match (self.rotation_xyzw, self.translation_m) {
            (None, None) => Ok(()),
            (Some(q), Some(t)) => {
                let norm = q.iter().map(|c| c * c).sum::<f64>().sqrt();
                if !q.iter().all(|c| c.is_finite()) || (norm - 1.0).abs() > 1e-3 {
                    return Err(format!(
                        "robot.rotation_xyzw = {q:?}: expected a unit quaternion (x, y, z, w), its norm is {norm}"
                    ));
                }
                if !t.iter().all(|c| c.is_finite() && c.abs() <= 100.0) {
                    return Err(format!(
                        "robot.translation_m = {t:?}: expected 3 numbers within [-100, 100] m"
                    ));
                }
                Ok(())
            }
            _ => Err(
                "robot.rotation_xyzw and robot.translation_m: expected both (a given transform) or neither (estimated from the Motive tool rigid body)"
                    .into(),
            ),
        }
    }

    /// The transform given in the config, if any (assumes [`Self::validate`] passed).
    pub fn given(&self) -> Option<RigidTransform> {
        let (q, t) = (self.rotation_xyzw?, self.translation_m?);
        Some(RigidTransform {
            rotation: UnitQuaternion::from_quaternion(Quaternion::new(q[3], q[0], q[1], q[2])),
            translation: Vector3::from(t),
        })
    }
}

/// The robot command at the take's frame times `times` (s, Motive clock), where the file covers
/// them: the index of the first covered frame and the positions (robot frame), or `None` if no
/// frame is covered. Covered frames form one run, as the file's times are one interval.
pub fn covered_frames(robot: &RobotTrajectory, times: &[f64]) -> Option<(usize, usize)> {
    let start = times.iter().position(|&t| sample(robot, t).is_some())?;
    let len = times[start..]
        .iter()
        .take_while(|&&t| sample(robot, t).is_some())
        .count();
    Some((start, start + len))
}

/// Robot-frame positions of the command at `times` (all inside the file's span).
pub fn positions_at(robot: &RobotTrajectory, times: &[f64]) -> Vec<Vector3<f64>> {
    times
        .iter()
        .map(|&t| {
            sample(robot, t)
                .expect("time inside the robot file")
                .position
        })
        .collect()
}

/// The tool track in the mocap frame at `times` (all inside the file's span), time shifted so the
/// first is 0: position, velocity, angular velocity and acceleration rotated by `transform`,
/// orientation conjugated by its rotation (`q_mocap = q_T q_robot q_T⁻¹`, so the tool's local axes
/// are the robot's tool axes carried into the mocap frame, as a Motive rigid body created while the
/// tool had the identity orientation), and the angular acceleration by central differences of the
/// angular velocity (the file has none).
pub fn tool_track(robot: &RobotTrajectory, times: &[f64], transform: &RigidTransform) -> ToolTrack {
    let r = transform.rotation;
    let t0 = times.first().copied().unwrap_or(0.0);
    let mut track = ToolTrack::default();
    for &t in times {
        let s = sample(robot, t).expect("time inside the robot file");
        let q = r * s.orientation * r.inverse();
        track.t.push(t - t0);
        track.position.push(transform.point(s.position).into());
        track.orientation.push([q.i, q.j, q.k, q.w]);
        track.velocity.push((r * s.velocity).into());
        track.angular_velocity.push((r * s.angular_velocity).into());
        track.acceleration.push((r * s.acceleration).into());
    }
    track.angular_acceleration = gradient(&track.angular_velocity, &track.t);
    track
}

#[cfg(test)]
mod tests {
    use super::*;

    /// packages-v1's transform: `p_mocap = R (p_robot - o)`, R turns robot z (up) into mocap y.
    fn packages_v1() -> RigidTransform {
        let r = Matrix3::new(1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, -1.0, 0.0);
        let rotation = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(r));
        RigidTransform {
            rotation,
            translation: -(rotation * Vector3::new(0.4, 0.15, 0.0)),
        }
    }

    #[test]
    fn kabsch_recovers_a_known_transform_and_refuses_a_line() {
        let truth = packages_v1();
        let robot: Vec<Vector3<f64>> = (0..50)
            .map(|k| {
                let s = k as f64 / 49.0;
                Vector3::new(0.5 * s, 0.3 * (3.0 * s).sin(), 0.033 + 0.15 * s * s)
            })
            .collect();
        let mocap: Vec<Vector3<f64>> = robot.iter().map(|p| truth.point(*p)).collect();
        let fit = RigidTransform::fit(&robot, &mocap).unwrap();
        assert!(fit.rotation.angle_to(&truth.rotation) < 1e-9);
        assert!((fit.translation - truth.translation).norm() < 1e-9);
        assert!(fit.rms_error(&robot, &mocap) < 1e-9);
        let line: Vec<Vector3<f64>> = (0..10)
            .map(|k| Vector3::new(k as f64 * 0.01, 0.0, 0.0))
            .collect();
        assert!(RigidTransform::fit(&line, &line).is_none());
    }

    #[test]
    fn reads_rows_interpolates_and_rotates_into_the_mocap_frame() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("r_robot.csv");
        // A 90 degree turn about robot z over 1 s at 0.5 rad/s... sampled every 0.5 s.
        let mut text = ROBOT_HEADER.join(",") + "\n";
        for k in 0..3 {
            let t = 0.5 * k as f64;
            let angle = 0.5 * t;
            text += &format!(
                "{t},{},0,0.1,0,0,{},{},0.2,0,0,0,0,0.5,0.1,0,0\n",
                0.2 * t,
                (angle / 2.0).sin(),
                (angle / 2.0).cos()
            );
        }
        std::fs::write(&path, text).unwrap();
        let robot = read_robot(&path).unwrap();
        assert_eq!(robot.t, vec![0.0, 0.5, 1.0]);
        let transform = packages_v1();
        let times = [0.25, 0.5, 0.75];
        let track = tool_track(&robot, &times, &transform);
        assert_eq!(track.t, vec![0.0, 0.25, 0.5]);
        // Position halfway between rows, then p_mocap = R (p - o): (0.05 - 0.4, 0.1, -(0 - 0.15)).
        let p = track.position[0];
        assert!(
            (p[0] + 0.35).abs() < 1e-12
                && (p[1] - 0.1).abs() < 1e-12
                && (p[2] - 0.15).abs() < 1e-12,
            "{p:?}"
        );
        // Robot z (the turn axis) is mocap y; robot x velocity stays mocap x.
        assert!((track.angular_velocity[1][1] - 0.5).abs() < 1e-12);
        assert!((track.velocity[1][0] - 0.2).abs() < 1e-12);
        // The orientation turns about mocap y by 0.25 rad at t = 0.5 s.
        let q = track.orientation[1];
        assert!(q[0].abs() < 1e-12 && q[2].abs() < 1e-12, "{q:?}");
        assert!((q[1] - (0.125f64).sin()).abs() < 1e-12, "{q:?}");
        assert!(track
            .angular_acceleration
            .iter()
            .all(|a| a.iter().all(|c| c.abs() < 1e-9)));
        assert_eq!(
            covered_frames(&robot, &[-0.1, 0.0, 0.6, 1.0, 1.2]),
            Some((1, 4))
        );
    }

    #[test]
    fn a_bad_row_names_file_and_line() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("r_robot.csv");
        let mut text = ROBOT_HEADER.join(",") + "\n";
        text += "0,0,0,0,0,0,0,1,0,0,0,0,0,0,0,0,0\n";
        text += "0.004,0,0,0,0,0,0,2,0,0,0,0,0,0,0,0,0\n";
        std::fs::write(&path, &text).unwrap();
        let msg = read_robot(&path).unwrap_err().to_string();
        assert!(
            msg.contains("r_robot.csv:3:") && msg.contains("unit quaternion"),
            "{msg}"
        );
        std::fs::write(&path, "t,x\n0,0\n").unwrap();
        let msg = read_robot(&path).unwrap_err().to_string();
        assert!(
            msg.contains("r_robot.csv:1:") && msg.contains("time_s,pos_x"),
            "{msg}"
        );
    }
}
