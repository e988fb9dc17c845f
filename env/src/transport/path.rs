//! A tool path taken from a recording: the recorded tool positions resampled evenly in arc
//! length, the recorded tilt profile along it, and the recording's pick set-up (package
//! placement, tool start pose).

use glam::{DQuat, DVec3};
use rlpkg_mocap::{ToolTrack, Trajectory};
use rlpkg_sim::Placement;

/// Points per path (evenly spaced in arc length; 1.2-1.4 m paths give ~6 mm spacing).
const PATH_POINTS: usize = 241;

/// One recorded path.
#[derive(Debug, Clone, PartialEq)]
pub struct TransportPath {
    /// Recording id, e.g. `HHHHM`.
    pub id: String,
    /// Tool positions evenly spaced in arc length, from pick to place (m, world).
    pub points: Vec<DVec3>,
    /// Fraction of the final tilt reached at each point (0 at pick, 1 at place, clamped).
    pub tilt_fraction: Vec<f64>,
    /// Path length (m).
    pub length_m: f64,
    /// The recording's tilt at placement: angle between the tool's axis (its y) at the end and
    /// at the start (rad).
    pub recorded_final_tilt_rad: f64,
    /// Tool orientation at pick (x, y, z, w).
    pub start_orientation: DQuat,
    /// Package, cups and object at pick, as the replay of the recording places them.
    pub placement: Placement,
    /// The recording's object mass (kg).
    pub object_mass_kg: f32,
    /// The recording's peak tool speed (m/s).
    pub recorded_peak_speed_m_s: f64,
    /// The recording's duration (s).
    pub recorded_duration_s: f64,
    /// Times of the recorded samples kept for [`TransportPath::recorded_progress`] (s from the
    /// recording's start, every fourth sample: 60 Hz).
    pub recorded_time_s: Vec<f64>,
    /// Arc length the recorded tool had covered at those times (m).
    pub recorded_arc_m: Vec<f64>,
}

/// The largest tool speed, acceleration and angular speed along recordings: what the robot
/// limits of `[transport.limits]` are checked against.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct ToolPeaks {
    /// Peak tool speed (m/s).
    pub speed_m_s: f64,
    /// Peak tool acceleration (m/s²).
    pub accel_m_s2: f64,
    /// Peak tool angular speed (rad/s).
    pub angular_speed_rad_s: f64,
}

impl ToolPeaks {
    /// The peaks of one recorded tool track.
    pub fn of(tool: &ToolTrack) -> Self {
        let peak = |v: &[[f64; 3]]| {
            v.iter()
                .map(|x| DVec3::from(*x).length())
                .fold(0.0, f64::max)
        };
        Self {
            speed_m_s: peak(&tool.velocity),
            accel_m_s2: peak(&tool.acceleration),
            angular_speed_rad_s: peak(&tool.angular_velocity),
        }
    }

    /// The larger of each peak of `self` and `other`.
    pub fn max(self, other: Self) -> Self {
        Self {
            speed_m_s: self.speed_m_s.max(other.speed_m_s),
            accel_m_s2: self.accel_m_s2.max(other.accel_m_s2),
            angular_speed_rad_s: self.angular_speed_rad_s.max(other.angular_speed_rad_s),
        }
    }
}

/// Angle between the tool's y axis under `q` and under `q0` (rad).
fn tilt_between(q0: DQuat, q: DQuat) -> f64 {
    let (a, b) = (q0 * DVec3::Y, q * DVec3::Y);
    a.dot(b).clamp(-1.0, 1.0).acos()
}

impl TransportPath {
    /// The path of `trajectory`, with its pick set-up (`placement`, as the replay builds it).
    pub fn from_recording(trajectory: &Trajectory, placement: Placement) -> Result<Self, String> {
        let tool = &trajectory.tool;
        let n = tool.position.len();
        if n < 2 {
            return Err(format!("{}: fewer than two tool samples", trajectory.id));
        }
        let positions: Vec<DVec3> = tool.position.iter().map(|p| DVec3::from(*p)).collect();
        let orientations: Vec<DQuat> = tool
            .orientation
            .iter()
            .map(|q| DQuat::from_array(*q).normalize())
            .collect();
        let mut arc = vec![0.0f64; n];
        for i in 1..n {
            arc[i] = arc[i - 1] + positions[i].distance(positions[i - 1]);
        }
        let length_m = arc[n - 1];
        if !(length_m.is_finite() && length_m > 0.05) {
            return Err(format!(
                "{}: tool path of {length_m} m, expected a path longer than 0.05 m",
                trajectory.id
            ));
        }
        let q0 = orientations[0];
        let recorded_final_tilt_rad = tilt_between(q0, orientations[n - 1]);
        let tilt: Vec<f64> = orientations.iter().map(|&q| tilt_between(q0, q)).collect();
        let mut points = Vec::with_capacity(PATH_POINTS);
        let mut tilt_fraction = Vec::with_capacity(PATH_POINTS);
        let mut i = 0;
        for k in 0..PATH_POINTS {
            let s = length_m * k as f64 / (PATH_POINTS - 1) as f64;
            while i + 2 < n && arc[i + 1] < s {
                i += 1;
            }
            let span = arc[i + 1] - arc[i];
            let u = if span > 0.0 {
                ((s - arc[i]) / span).clamp(0.0, 1.0)
            } else {
                0.0
            };
            points.push(positions[i].lerp(positions[i + 1], u));
            let t = tilt[i] + (tilt[i + 1] - tilt[i]) * u;
            let fraction = if recorded_final_tilt_rad > 1e-3 {
                (t / recorded_final_tilt_rad).clamp(0.0, 1.0)
            } else {
                0.0
            };
            tilt_fraction.push(fraction);
        }
        // The place pose has the full target tilt whatever the recording's last sample shows.
        *tilt_fraction.last_mut().expect("points") = 1.0;
        let recorded_peak_speed_m_s = tool
            .velocity
            .iter()
            .map(|v| DVec3::from(*v).length())
            .fold(0.0, f64::max);
        Ok(Self {
            id: trajectory.id.clone(),
            points,
            tilt_fraction,
            length_m,
            recorded_final_tilt_rad,
            start_orientation: q0,
            placement,
            object_mass_kg: trajectory.meta.object_total_mass_kg as f32,
            recorded_peak_speed_m_s,
            recorded_duration_s: tool.t[n - 1] - tool.t[0],
            recorded_time_s: (0..n)
                .step_by(4)
                .chain([n - 1])
                .map(|i| tool.t[i] - tool.t[0])
                .collect(),
            recorded_arc_m: (0..n).step_by(4).chain([n - 1]).map(|i| arc[i]).collect(),
        })
    }

    /// Index and interpolation weight of arc length `s` (clamped to the path).
    fn locate(&self, s: f64) -> (usize, f64) {
        let segments = (self.points.len() - 1) as f64;
        let x = (s / self.length_m).clamp(0.0, 1.0) * segments;
        let i = (x.floor() as usize).min(self.points.len() - 2);
        (i, x - i as f64)
    }

    /// Position at arc length `s` (m).
    pub fn position(&self, s: f64) -> DVec3 {
        let (i, u) = self.locate(s);
        self.points[i].lerp(self.points[i + 1], u)
    }

    /// Unit tangent at arc length `s`.
    pub fn tangent(&self, s: f64) -> DVec3 {
        let (i, _) = self.locate(s);
        (self.points[i + 1] - self.points[i]).normalize_or_zero()
    }

    /// Arc length the recorded tool had covered `t` seconds after its start (clamped to the
    /// recording).
    pub fn recorded_progress(&self, t: f64) -> f64 {
        let times = &self.recorded_time_s;
        let k = times.partition_point(|&x| x <= t);
        if k == 0 {
            return self.recorded_arc_m[0];
        }
        if k >= times.len() {
            return *self.recorded_arc_m.last().expect("samples");
        }
        let (t0, t1) = (times[k - 1], times[k]);
        let u = if t1 > t0 { (t - t0) / (t1 - t0) } else { 0.0 };
        self.recorded_arc_m[k - 1] + (self.recorded_arc_m[k] - self.recorded_arc_m[k - 1]) * u
    }

    /// Fraction of the final tilt at arc length `s`.
    pub fn tilt_fraction(&self, s: f64) -> f64 {
        let (i, u) = self.locate(s);
        self.tilt_fraction[i] + (self.tilt_fraction[i + 1] - self.tilt_fraction[i]) * u
    }
}
