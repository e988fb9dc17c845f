//! A time-optimal, jerk-limited motion profile along an episode's path: the baseline an engineer
//! would program. The progress along the path `s(t)` goes from the pick pose at rest to the
//! place pose at rest as fast as limits on the tool's linear speed, acceleration and jerk and on
//! its angular speed, acceleration and jerk allow; the tilt is a function of the same progress
//! (co-scheduled): either the recorded tilt profile or, for the profile baseline, the
//! [`minimum_jerk`] blend from the pick orientation to the target tilt over the whole path.
//!
//! The limits on `s` vary along the path: the recorded paths tilt the tool within their last
//! 0.3 m, and turn the tilt back and forth there, so the path speed the angular limits allow
//! under the recorded tilt is ten times lower there than on the level part; the smooth blend
//! spreads the tilt over the path, so the path's speed, acceleration and jerk limits set the
//! pace instead. The plan is time-optimal path
//! parameterisation rather than one state-to-state profile under constant limits (what Ruckig
//! computes):
//! 1. per interval of an even arc-length grid, the largest path speed and acceleration are the
//!    tool limits over the rate at which the reference position and the tilt change with `s`;
//! 2. a forward and a backward pass give the fastest speed `ṡ(s)` under those limits, from rest
//!    to rest (bang-bang acceleration);
//! 3. a moving average of `ṡ(t)` over the jerk ramp (acceleration limit over jerk limit) makes
//!    the acceleration continuous: a trapezoidal speed profile filtered this way is the
//!    time-optimal 7-segment S-curve;
//! 4. curvature and a changing tilt rate add acceleration and jerk of their own: the reference
//!    pose is sampled at the control interval (what the tracking controller follows) and the
//!    path is slowed where a finite difference exceeds its limit (speed by the excess, the
//!    acceleration by its square), until none does.

use glam::DVec3;
use serde::Serialize;

use super::TransportLimits;

/// Jerk limits are the acceleration limits reached from zero in this time (s), since
/// `[transport.limits]` bounds no jerk: two control intervals at 20 Hz.
pub const JERK_RAMP_S: f64 = 0.1;

/// Intervals of the arc-length grid (four per interval of a resampled recorded path).
const GRID_INTERVALS: usize = 960;

/// Rounds of slowing down where the sampled reference exceeds a limit before planning gives up.
const MAX_ROUNDS: usize = 60;

/// Rounding that a sampled use of a limit may exceed 1 by.
const STRETCH_TOLERANCE: f64 = 1e-9;

/// Extra margin on each slowdown, so the rounds converge rather than approach the limit forever.
const SHRINK_MARGIN: f64 = 1.002;

/// The minimum-jerk blend from 0 to 1 over `u` in [0, 1] (`10u³ - 15u⁴ + 6u⁵`, clamped outside):
/// monotone, with zero slope and curvature at both ends, so a tilt scheduled by it starts and
/// stops at rest.
pub fn minimum_jerk(u: f64) -> f64 {
    let u = u.clamp(0.0, 1.0);
    u * u * u * (10.0 + u * (-15.0 + 6.0 * u))
}

/// Limits on the tool's motion (SI; angular limits on the tilt about world x).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct MotionLimits {
    /// Largest tool speed (m/s).
    pub speed_m_s: f64,
    /// Largest tool acceleration (m/s²).
    pub accel_m_s2: f64,
    /// Largest tool jerk (m/s³).
    pub jerk_m_s3: f64,
    /// Largest angular speed (rad/s).
    pub angular_speed_rad_s: f64,
    /// Largest angular acceleration (rad/s²).
    pub angular_accel_rad_s2: f64,
    /// Largest angular jerk (rad/s³).
    pub angular_jerk_rad_s3: f64,
}

impl MotionLimits {
    /// The robot's own limits of `[transport.limits]` (path speed and acceleration, angular speed
    /// and acceleration), with jerks that reach those accelerations in [`JERK_RAMP_S`].
    pub fn of_tool(limits: &TransportLimits) -> Self {
        Self {
            speed_m_s: limits.max_path_speed_m_s,
            accel_m_s2: limits.max_path_accel_m_s2,
            jerk_m_s3: limits.max_path_accel_m_s2 / JERK_RAMP_S,
            angular_speed_rad_s: limits.max_angular_speed_rad_s,
            angular_accel_rad_s2: limits.max_angular_accel_rad_s2,
            angular_jerk_rad_s3: limits.max_angular_accel_rad_s2 / JERK_RAMP_S,
        }
    }

    /// Every limit times `scale`.
    pub fn scaled(&self, scale: f64) -> Self {
        Self {
            speed_m_s: self.speed_m_s * scale,
            accel_m_s2: self.accel_m_s2 * scale,
            jerk_m_s3: self.jerk_m_s3 * scale,
            angular_speed_rad_s: self.angular_speed_rad_s * scale,
            angular_accel_rad_s2: self.angular_accel_rad_s2 * scale,
            angular_jerk_rad_s3: self.angular_jerk_rad_s3 * scale,
        }
    }

    fn check(&self) -> Result<(), String> {
        let all = [
            ("speed_m_s", self.speed_m_s),
            ("accel_m_s2", self.accel_m_s2),
            ("jerk_m_s3", self.jerk_m_s3),
            ("angular_speed_rad_s", self.angular_speed_rad_s),
            ("angular_accel_rad_s2", self.angular_accel_rad_s2),
            ("angular_jerk_rad_s3", self.angular_jerk_rad_s3),
        ];
        match all.iter().find(|(_, x)| !(x.is_finite() && *x > 0.0)) {
            Some((name, x)) => Err(format!("motion limit {name} = {x}: expected > 0")),
            None => Ok(()),
        }
    }
}

/// The largest sampled speed, acceleration and jerk of a reference pose, linear and angular, as
/// fractions of their limits (1 = at the limit).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LimitUse {
    /// Linear speed, acceleration, jerk.
    pub linear: [f64; 3],
    /// Angular speed, acceleration, jerk.
    pub angular: [f64; 3],
}

impl LimitUse {
    /// The largest use of any limit.
    pub fn worst(&self) -> f64 {
        self.linear
            .iter()
            .chain(&self.angular)
            .fold(0.0, |a, &b| a.max(b))
    }
}

/// A planned progress along one path: `s(t)` from 0 to the path's length, at rest at both ends,
/// sampled every [`PLAN_STEP_S`].
#[derive(Debug, Clone)]
pub struct PathProfile {
    /// Progress at `k` x [`PLAN_STEP_S`] (m).
    progress: Vec<f64>,
    /// Path speed at the same times (m/s).
    speed: Vec<f64>,
    /// Path length (m).
    pub length_m: f64,
    /// Duration from start to rest at the end (s).
    pub duration_s: f64,
    /// Largest path speed of the plan (m/s).
    pub peak_speed_m_s: f64,
}

/// Time step of a planned profile (s).
pub const PLAN_STEP_S: f64 = 0.005;

/// The path's geometry on an even grid of arc length: where the reference is and how fast its
/// position and tilt change with arc length.
struct Grid {
    /// Grid spacing (m).
    step_m: f64,
    /// Per grid interval: |dp/ds| and |dθ/ds| (rad/m).
    position_rate: Vec<f64>,
    tilt_rate: Vec<f64>,
}

impl Grid {
    fn new(length_m: f64, pose: &impl Fn(f64) -> (DVec3, f64)) -> Self {
        let step_m = length_m / GRID_INTERVALS as f64;
        let poses: Vec<(DVec3, f64)> = (0..=GRID_INTERVALS)
            .map(|k| pose(step_m * k as f64))
            .collect();
        let (position_rate, tilt_rate) = poses
            .windows(2)
            .map(|w| {
                (
                    w[1].0.distance(w[0].0) / step_m,
                    (w[1].1 - w[0].1).abs() / step_m,
                )
            })
            .unzip();
        Self {
            step_m,
            position_rate,
            tilt_rate,
        }
    }
}

/// Time-optimal progress along a path of `length_m` whose reference pose at arc length `s` is
/// `pose(s) = (position (m), tilt about world x (rad))`, under `limits` on the pose's motion
/// sampled every `interval_s` (the control interval).
pub fn plan_path_profile(
    length_m: f64,
    pose: impl Fn(f64) -> (DVec3, f64),
    limits: &MotionLimits,
    interval_s: f64,
) -> Result<PathProfile, String> {
    limits.check()?;
    if !(length_m.is_finite() && length_m > 0.0 && interval_s.is_finite() && interval_s > 0.0) {
        return Err(format!(
            "path of {length_m} m sampled every {interval_s} s: expected both > 0"
        ));
    }
    let grid = Grid::new(length_m, &pose);
    // The moving average that turns the acceleration-limited profile into a jerk-limited one
    // ramps the acceleration over this time.
    let ramp = (limits.accel_m_s2 / limits.jerk_m_s3)
        .max(limits.angular_accel_rad_s2 / limits.angular_jerk_rad_s3);
    let mut slowdown = vec![1.0f64; GRID_INTERVALS];
    for _ in 0..MAX_ROUNDS {
        let profile = timed_profile(&grid, limits, &slowdown, ramp, length_m);
        let excesses = profile.excesses(&pose, limits, interval_s);
        if excesses.is_empty() {
            return Ok(profile);
        }
        // Each interval slows by the largest excess around it this round.
        let mut round = vec![1.0f64; GRID_INTERVALS];
        for (from_m, to_m, factor) in excesses {
            // The filter spreads a change over the ramp: slow down around the excess by that much.
            let (from, to) = (
                profile.progress_at_or_before(from_m, ramp),
                profile.progress_at_or_after(to_m, ramp),
            );
            let first = ((from / grid.step_m).floor() as usize).min(GRID_INTERVALS - 1);
            let last = ((to / grid.step_m).ceil() as usize).clamp(first + 1, GRID_INTERVALS);
            for r in &mut round[first..last] {
                *r = r.max(factor * SHRINK_MARGIN);
            }
        }
        for (s, r) in slowdown.iter_mut().zip(&round) {
            *s /= r;
        }
    }
    Err(format!(
        "no profile along the {length_m} m path within the motion limits after {MAX_ROUNDS} rounds"
    ))
}

/// The fastest progress under the first-order limits (tool limits over the rate of change of
/// position and tilt with arc length, times `slowdown` for speed and its square for
/// acceleration, per grid interval): the forward-backward pass of time-optimal path
/// parameterisation, then a moving average of the path speed over `ramp` (a trapezoidal speed
/// profile so filtered is the jerk-limited S-curve).
fn timed_profile(
    grid: &Grid,
    limits: &MotionLimits,
    slowdown: &[f64],
    ramp: f64,
    length_m: f64,
) -> PathProfile {
    let n = GRID_INTERVALS;
    let bound = |linear: f64, angular: f64, i: usize| {
        let by_tilt = if grid.tilt_rate[i] > 0.0 {
            angular / grid.tilt_rate[i]
        } else {
            f64::INFINITY
        };
        (linear / grid.position_rate[i].max(1e-9)).min(by_tilt)
    };
    let interval_speed: Vec<f64> = (0..n)
        .map(|i| bound(limits.speed_m_s, limits.angular_speed_rad_s, i) * slowdown[i])
        .collect();
    let interval_accel: Vec<f64> = (0..n)
        .map(|i| bound(limits.accel_m_s2, limits.angular_accel_rad_s2, i) * slowdown[i].powi(2))
        .collect();
    // Speeds at the grid nodes: at rest at both ends, within both neighbouring intervals' limits.
    let mut v = vec![0.0f64; n + 1];
    for k in 1..n {
        v[k] = interval_speed[k - 1].min(interval_speed[k]);
    }
    let ds = grid.step_m;
    for k in 0..n {
        v[k + 1] = v[k + 1].min((v[k] * v[k] + 2.0 * interval_accel[k] * ds).sqrt());
    }
    for k in (0..n).rev() {
        v[k] = v[k].min((v[k + 1] * v[k + 1] + 2.0 * interval_accel[k] * ds).sqrt());
    }
    // Constant acceleration per interval: the speed is linear in time across it.
    let mut node_time = vec![0.0f64; n + 1];
    for k in 0..n {
        node_time[k + 1] = node_time[k] + 2.0 * ds / (v[k] + v[k + 1]).max(1e-12);
    }
    let end = node_time[n];
    let samples = (end / PLAN_STEP_S).ceil() as usize + 1;
    let mut k = 0;
    let raw: Vec<f64> = (0..samples)
        .map(|j| {
            let t = j as f64 * PLAN_STEP_S;
            while k + 1 < n && node_time[k + 1] < t {
                k += 1;
            }
            let span = node_time[k + 1] - node_time[k];
            let u = ((t - node_time[k]) / span).clamp(0.0, 1.0);
            if t >= end {
                0.0
            } else {
                v[k] + (v[k + 1] - v[k]) * u
            }
        })
        .collect();
    let width = ((ramp / PLAN_STEP_S).round() as usize).max(1);
    let mut speed = Vec::with_capacity(samples + width);
    let mut window = 0.0;
    for j in 0..samples + width - 1 {
        window += raw.get(j).copied().unwrap_or(0.0);
        if j >= width {
            window -= raw[j - width];
        }
        speed.push(window / width as f64);
    }
    let mut progress = Vec::with_capacity(speed.len());
    let mut s = 0.0;
    progress.push(0.0);
    for w in speed.windows(2) {
        s += 0.5 * (w[0] + w[1]) * PLAN_STEP_S;
        progress.push(s);
    }
    // The filter keeps the distance; this removes the time grid's rounding of it.
    let fix = length_m / s.max(1e-12);
    progress
        .iter_mut()
        .for_each(|x| *x = (*x * fix).min(length_m));
    speed.iter_mut().for_each(|x| *x *= fix);
    *progress.last_mut().expect("samples") = length_m;
    let peak_speed_m_s = speed.iter().fold(0.0f64, |a, &b| a.max(b));
    PathProfile {
        duration_s: (progress.len() - 1) as f64 * PLAN_STEP_S,
        progress,
        speed,
        length_m,
        peak_speed_m_s,
    }
}

impl PathProfile {
    /// Progress (m) and path speed (m/s) at time `t` (s; at rest at 0 before the start and at
    /// the path's end after the duration).
    pub fn at(&self, t: f64) -> (f64, f64) {
        if t <= 0.0 {
            return (0.0, 0.0);
        }
        if t >= self.duration_s {
            return (self.length_m, 0.0);
        }
        let x = t / PLAN_STEP_S;
        let j = (x.floor() as usize).min(self.progress.len() - 2);
        let u = x - j as f64;
        let lerp = |xs: &[f64]| xs[j] + (xs[j + 1] - xs[j]) * u;
        (lerp(&self.progress), lerp(&self.speed))
    }

    /// Progress `ramp` seconds before the plan first reaches `s`.
    fn progress_at_or_before(&self, s: f64, ramp: f64) -> f64 {
        let j = self.progress.partition_point(|&x| x < s);
        let back = (ramp / PLAN_STEP_S).ceil() as usize;
        self.progress[j.saturating_sub(back).min(self.progress.len() - 1)]
    }

    /// Progress `ramp` seconds after the plan last is at `s`.
    fn progress_at_or_after(&self, s: f64, ramp: f64) -> f64 {
        let j = self.progress.partition_point(|&x| x <= s);
        let ahead = (ramp / PLAN_STEP_S).ceil() as usize;
        self.progress[(j + ahead).min(self.progress.len() - 1)]
    }

    /// The reference poses `pose(s(t))` every `interval_s` from rest before the start to rest
    /// after the end (three samples of each, so starting and stopping count).
    pub fn sampled_poses(
        &self,
        pose: impl Fn(f64) -> (DVec3, f64),
        interval_s: f64,
    ) -> Vec<(DVec3, f64)> {
        self.sample_times(interval_s)
            .map(|t| pose(self.at(t).0))
            .collect()
    }

    fn sample_times(&self, interval_s: f64) -> impl Iterator<Item = f64> {
        let steps = (self.duration_s / interval_s).ceil() as i64;
        (-3..=steps + 3).map(move |k| k as f64 * interval_s)
    }

    /// The largest speed, acceleration and jerk of the reference pose (finite differences of its
    /// samples every `interval_s`) as fractions of `limits`.
    pub fn limit_use(
        &self,
        pose: impl Fn(f64) -> (DVec3, f64),
        limits: &MotionLimits,
        interval_s: f64,
    ) -> LimitUse {
        let samples = self.sampled_poses(pose, interval_s);
        let positions: Vec<DVec3> = samples.iter().map(|p| p.0).collect();
        let tilts: Vec<f64> = samples.iter().map(|p| p.1).collect();
        let largest = |d: &[Vec<f64>; 3]| d.clone().map(|x| x.into_iter().fold(0.0, f64::max));
        let linear = largest(&differences(&positions, interval_s, |v| v.length()));
        let angular = largest(&differences(&tilts, interval_s, f64::abs));
        LimitUse {
            linear: [
                linear[0] / limits.speed_m_s,
                linear[1] / limits.accel_m_s2,
                linear[2] / limits.jerk_m_s3,
            ],
            angular: [
                angular[0] / limits.angular_speed_rad_s,
                angular[1] / limits.angular_accel_rad_s2,
                angular[2] / limits.angular_jerk_rad_s3,
            ],
        }
    }

    /// Where the sampled reference pose exceeds a limit: for each window of samples over a
    /// limit, the progress it spans and the slowdown of the path speed that would bring it
    /// within (the excess to the power 1, 1/2, 1/3 for speed, acceleration, jerk).
    fn excesses(
        &self,
        pose: impl Fn(f64) -> (DVec3, f64),
        limits: &MotionLimits,
        interval_s: f64,
    ) -> Vec<(f64, f64, f64)> {
        let progress: Vec<f64> = self
            .sample_times(interval_s)
            .map(|t| self.at(t).0)
            .collect();
        let samples: Vec<(DVec3, f64)> = progress.iter().map(|&s| pose(s)).collect();
        let positions: Vec<DVec3> = samples.iter().map(|p| p.0).collect();
        let tilts: Vec<f64> = samples.iter().map(|p| p.1).collect();
        let linear = differences(&positions, interval_s, |v| v.length());
        let angular = differences(&tilts, interval_s, f64::abs);
        let linear_limits = [limits.speed_m_s, limits.accel_m_s2, limits.jerk_m_s3];
        let angular_limits = [
            limits.angular_speed_rad_s,
            limits.angular_accel_rad_s2,
            limits.angular_jerk_rad_s3,
        ];
        let mut out = Vec::new();
        for order in 0..3 {
            for (k, (l, a)) in linear[order].iter().zip(&angular[order]).enumerate() {
                let excess = (l / linear_limits[order]).max(a / angular_limits[order]);
                if excess > 1.0 + STRETCH_TOLERANCE {
                    let factor = excess.powf(1.0 / (order + 1) as f64);
                    out.push((progress[k], progress[k + order + 1], factor));
                }
            }
        }
        out
    }
}

/// The first, second and third finite differences of `xs` (sampled every `dt`), divided by `dt`,
/// `dt²` and `dt³`, with `norm` as the size of a difference.
fn differences<T>(xs: &[T], dt: f64, norm: impl Fn(T) -> f64) -> [Vec<f64>; 3]
where
    T: Copy + std::ops::Sub<Output = T>,
{
    let mut order: Vec<T> = xs.to_vec();
    [1, 2, 3].map(|k| {
        order = order.windows(2).map(|w| w[1] - w[0]).collect();
        let scale = dt.powi(k);
        order.iter().map(|&d| norm(d) / scale).collect()
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A bent 1.3 m path (a straight run, a quarter circle of 0.3 m radius, a straight run)
    /// tilting by 50 degrees along a smooth step in its middle third.
    fn bent_path(s: f64) -> (DVec3, f64) {
        let (straight, radius) = (0.4, 0.3);
        let arc = std::f64::consts::FRAC_PI_2 * radius;
        let position = if s < straight {
            DVec3::new(s, 0.0, 0.0)
        } else if s < straight + arc {
            let a = (s - straight) / radius;
            DVec3::new(straight + radius * a.sin(), radius * (1.0 - a.cos()), 0.0)
        } else {
            DVec3::new(straight + radius, radius + (s - straight - arc), 0.0)
        };
        let u = ((s / 1.3 - 1.0 / 3.0) * 3.0).clamp(0.0, 1.0);
        (position, 50f64.to_radians() * u * u * (3.0 - 2.0 * u))
    }

    fn tool() -> MotionLimits {
        MotionLimits {
            speed_m_s: 0.945,
            accel_m_s2: 5.2,
            jerk_m_s3: 52.0,
            angular_speed_rad_s: 3.1,
            angular_accel_rad_s2: 10.0,
            angular_jerk_rad_s3: 100.0,
        }
    }

    const DT: f64 = 0.05;

    #[test]
    fn the_profile_respects_every_limit_and_ends_at_the_goal_at_rest() {
        let length = 0.4 + std::f64::consts::FRAC_PI_2 * 0.3 + 0.6;
        for scale in [0.25, 0.5, 1.0, 2.0] {
            let limits = tool().scaled(scale);
            let profile = plan_path_profile(length, bent_path, &limits, DT).unwrap();
            let used = profile.limit_use(bent_path, &limits, DT);
            for u in used.linear.iter().chain(&used.angular) {
                assert!(*u <= 1.0 + 1e-9, "scale {scale}: {used:?}");
            }
            // Some limit is reached (within the last slowdown's margin): the profile is not slack.
            assert!(used.worst() > 0.95, "scale {scale}: {used:?}");
            // The 1-D profile itself keeps its bounds at fine resolution.
            let fine = 1e-3;
            let (mut previous, mut largest_speed) = (0.0, 0.0f64);
            let mut t = 0.0;
            while t <= profile.duration_s + fine {
                let (s, v) = profile.at(t);
                assert!(s + 1e-12 >= previous, "progress goes back at {t} s");
                assert!(v >= -1e-9, "{v} m/s at {t} s");
                largest_speed = largest_speed.max(v);
                previous = s;
                t += fine;
            }
            assert!(largest_speed <= profile.peak_speed_m_s * (1.0 + 1e-9));
            // At the goal, at rest, and it stays there.
            let end = profile.duration_s;
            assert!(end.is_finite() && end > 0.0);
            assert_eq!(profile.at(end), (length, 0.0));
            let (s, v) = profile.at(end - 1e-9);
            assert!((s - length).abs() < 1e-6 && v.abs() < 1e-4, "{s} {v}");
            assert_eq!(profile.at(end + 5.0), (length, 0.0));
            assert_eq!(profile.at(0.0), (0.0, 0.0));
        }
    }

    #[test]
    fn larger_limits_are_never_slower() {
        let length = 0.4 + std::f64::consts::FRAC_PI_2 * 0.3 + 0.6;
        let durations: Vec<f64> = [0.2, 0.4, 0.6, 0.8, 1.0, 1.25, 1.5, 2.0, 4.0]
            .iter()
            .map(|&s| {
                plan_path_profile(length, bent_path, &tool().scaled(s), DT)
                    .unwrap()
                    .duration_s
            })
            .collect();
        for pair in durations.windows(2) {
            assert!(pair[1] <= pair[0] + 1e-9, "{durations:?}");
        }
        assert!(durations[8] < 0.7 * durations[0], "{durations:?}");
    }

    #[test]
    fn a_straight_level_path_takes_the_closed_form_s_curve_time() {
        // Without curvature or tilt the bounds are the tool's own; a long path reaches the speed
        // limit: time = length / v + v / a + a / j (acceleration phases at the limit).
        let (v, a, j) = (0.5, 2.0, 40.0);
        let limits = MotionLimits {
            speed_m_s: v,
            accel_m_s2: a,
            jerk_m_s3: j,
            angular_jerk_rad_s3: 1000.0,
            ..tool()
        };
        let profile =
            plan_path_profile(2.0, |s| (DVec3::new(s, 0.0, 0.0), 0.0), &limits, DT).unwrap();
        let expected = 2.0 / v + v / a + a / j;
        assert!(
            (profile.duration_s - expected).abs() <= 2.0 * PLAN_STEP_S,
            "{} vs {expected}",
            profile.duration_s
        );
    }

    #[test]
    fn a_tilt_turning_back_and_forth_slows_the_path_only_where_it_turns() {
        // As the recorded paths do near the place pose: level for 1 m, then within 0.3 m the tilt
        // rises to 45 degrees, falls back to 0 and rises again (7.9 rad/m).
        let theta = 45f64.to_radians();
        let zigzag = |s: f64| {
            let u = ((s - 1.0) / 0.1).clamp(0.0, 3.0);
            let tilt = if u < 1.0 {
                u
            } else if u < 2.0 {
                2.0 - u
            } else {
                u - 2.0
            };
            (DVec3::new(s, 0.0, 0.0), theta * tilt)
        };
        let limits = tool();
        let profile = plan_path_profile(1.3, zigzag, &limits, DT).unwrap();
        let used = profile.limit_use(zigzag, &limits, DT);
        assert!(
            used.worst() <= 1.0 + 1e-9 && used.worst() > 0.95,
            "{used:?}"
        );
        // The level metre at full speed...
        assert!(
            profile.peak_speed_m_s > 0.9 * limits.speed_m_s,
            "{profile:?}"
        );
        // ...so it is crossed faster than at the one speed the tilting part allows throughout.
        let tilting_speed = limits.angular_speed_rad_s / (theta / 0.1);
        let level_part = (0..)
            .map(|k| k as f64 * 0.01)
            .find(|&t| profile.at(t).0 >= 0.8);
        assert!(level_part.unwrap() < 0.8 / tilting_speed, "{level_part:?}");
        // Rotating 135 degrees at no more than the angular speed limit takes its time.
        assert!(profile.duration_s > 3.0 * theta / limits.angular_speed_rad_s);
    }

    #[test]
    fn the_minimum_jerk_blend_is_monotone_and_at_rest_at_both_ends() {
        assert_eq!(minimum_jerk(0.0), 0.0);
        assert_eq!(minimum_jerk(1.0), 1.0);
        assert_eq!(minimum_jerk(-0.5), 0.0);
        assert_eq!(minimum_jerk(1.5), 1.0);
        assert!((minimum_jerk(0.5) - 0.5).abs() < 1e-12);
        let h = 1e-4;
        let values: Vec<f64> = (0..=10_000).map(|k| minimum_jerk(k as f64 * h)).collect();
        assert!(values.windows(2).all(|w| w[1] > w[0]));
        // Zero slope at the ends, the largest slope 15/8 in the middle.
        assert!(values[1] / h < 1e-6 && (1.0 - values[9_999]) / h < 1e-6);
        assert!(((values[5_001] - values[4_999]) / (2.0 * h) - 1.875).abs() < 1e-6);
    }

    /// The bent path of [`bent_path`] with its tilt the minimum-jerk blend to `tilt` over the
    /// whole path (what the profile baseline plans along).
    fn smoothly_tilted(s: f64, tilt: f64) -> (DVec3, f64) {
        let length = 0.4 + std::f64::consts::FRAC_PI_2 * 0.3 + 0.6;
        (bent_path(s).0, tilt * minimum_jerk(s / length))
    }

    #[test]
    fn a_smoothly_tilted_plan_respects_every_limit_tilts_monotonely_and_stops_at_the_goal() {
        let length = 0.4 + std::f64::consts::FRAC_PI_2 * 0.3 + 0.6;
        for (scale, tilt_deg) in [(0.5, 30.0), (1.0, 60.0), (2.0, 60.0), (4.0, 45.0)] {
            let tilt = f64::to_radians(tilt_deg);
            let pose = |s| smoothly_tilted(s, tilt);
            let limits = tool().scaled(scale);
            let profile = plan_path_profile(length, pose, &limits, DT).unwrap();
            // Every limit holds for the reference pose sampled at the control interval...
            let used = profile.limit_use(pose, &limits, DT);
            assert!(
                used.worst() <= 1.0 + 1e-9 && used.worst() > 0.95,
                "x{scale}: {used:?}"
            );
            // ...the tilt never turns back and ends at the target...
            let samples = profile.sampled_poses(pose, DT);
            assert!(
                samples.windows(2).all(|w| w[1].1 >= w[0].1),
                "x{scale}: the tilt turns back"
            );
            let (end_position, end_tilt) = *samples.last().unwrap();
            assert!(end_position.distance(bent_path(length).0) < 1e-9);
            assert!((end_tilt - tilt).abs() < 1e-12);
            // ...and the plan arrives at rest.
            assert_eq!(profile.at(profile.duration_s), (length, 0.0));
            let (_, v) = profile.at(profile.duration_s - 1e-9);
            assert!(v.abs() < 1e-4, "x{scale}: {v} m/s at the end");
        }
    }

    #[test]
    fn the_smooth_tilt_is_faster_than_a_tilt_turning_back_and_forth() {
        // The same path and target tilt: once within 0.3 m turning back and forth (as the
        // recordings do near the place pose), once blended over the path.
        let theta = 45f64.to_radians();
        let zigzag = |s: f64| {
            let u = ((s - 1.0) / 0.1).clamp(0.0, 3.0);
            let tilt = if u < 1.0 {
                u
            } else if u < 2.0 {
                2.0 - u
            } else {
                u - 2.0
            };
            (DVec3::new(s, 0.0, 0.0), theta * tilt)
        };
        let smooth = |s: f64| (DVec3::new(s, 0.0, 0.0), theta * minimum_jerk(s / 1.3));
        let limits = tool();
        let noisy = plan_path_profile(1.3, zigzag, &limits, DT).unwrap();
        let blended = plan_path_profile(1.3, smooth, &limits, DT).unwrap();
        assert!(
            blended.duration_s < 0.7 * noisy.duration_s,
            "{} s against {} s",
            blended.duration_s,
            noisy.duration_s
        );
        // Along a straight path the smooth tilt leaves the path's own limits in charge: within
        // a few control intervals of the closed-form S-curve time.
        let (v, a, j) = (limits.speed_m_s, limits.accel_m_s2, limits.jerk_m_s3);
        let s_curve = 1.3 / v + v / a + a / j;
        assert!(
            blended.duration_s < s_curve + 4.0 * DT,
            "{} s against {s_curve} s",
            blended.duration_s
        );
    }

    #[test]
    fn bad_limits_and_paths_are_refused() {
        let zero = MotionLimits {
            jerk_m_s3: 0.0,
            ..tool()
        };
        let err = plan_path_profile(1.0, bent_path, &zero, DT).unwrap_err();
        assert!(err.contains("jerk_m_s3"), "{err}");
        assert!(plan_path_profile(0.0, bent_path, &tool(), DT).is_err());
        assert!(plan_path_profile(1.0, bent_path, &tool(), f64::NAN).is_err());
    }
}
