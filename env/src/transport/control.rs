//! The path-following controller: the policy's action (path speed, tilt offsets) advances the
//! reference along the episode's path and a tracking controller turns the reference pose into the
//! tool's twist command; the scripted baseline's actions, which play a recorded timing; and the
//! profile baseline's actions, which follow a time-optimal, jerk-limited motion profile.

use glam::{DQuat, DVec3};
use rlpkg_sim::ToolCommand;

use super::geometry::{quat, rotation_between, v3};
use super::profile::{minimum_jerk, plan_path_profile, MotionLimits, PathProfile};
use super::{sim_error, Episode, ProfileRateAction, Transport, TransportLimits, TransportPath};
use crate::{check_action_len, EnvError};

/// The reference reaches the place pose when it is this close (m): braking to the end of the
/// path would otherwise approach it forever.
const PATH_END_SNAP_M: f64 = 1e-3;

/// Fraction of the reference's lag behind a motion profile that the next path speed makes up
/// per control interval: the trapezoidal advance of the reference then settles on the plan
/// without ringing (the lag's recurrence has both roots at 0.5 in magnitude).
const PROFILE_LAG_GAIN: f64 = 0.5;

/// How the nominal orientation tilts along the path, from the pick orientation to the target tilt
/// at the place pose.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum TiltSchedule {
    /// The recording's tilt profile at the same fraction of the path
    /// ([`TransportPath::tilt_fraction`]): what the policy's tilt offsets are relative to.
    #[default]
    Recorded,
    /// The [`minimum_jerk`] blend over the fraction of the path covered: monotone and smooth,
    /// so the tilt never turns back and a plan along the path is limited by the path's speed,
    /// acceleration and jerk rather than by the recording's tilt noise (the profile baseline).
    MinimumJerk,
}

impl PathProfile {
    /// The path speed that plays this plan from time `clock_s` at `rate` over the next control
    /// interval `interval_s` from `progress_m`: the plan's speed at the interval's end times the
    /// rate, plus a share of the reference's lag behind the plan. What the profile baseline
    /// commands at rate 1, and a profile-rate policy's action turns into.
    pub fn path_speed(&self, clock_s: f64, rate: f64, progress_m: f64, interval_s: f64) -> f64 {
        let (planned, _) = self.at(clock_s);
        let (_, speed) = self.at(clock_s + rate * interval_s);
        (rate * speed + PROFILE_LAG_GAIN * (planned - progress_m) / interval_s).max(0.0)
    }
}

impl ProfileRateAction {
    /// The clock rate a profile-rate action asks for: `action` within `[0, max_rate]`, then
    /// within `max_rate_change_per_s` over `interval_s` of `previous_rate`.
    pub fn rate(&self, action: f64, previous_rate: f64, interval_s: f64) -> f64 {
        let change = self.max_rate_change_per_s * interval_s;
        action
            .clamp(0.0, self.max_rate)
            .clamp(previous_rate - change, previous_rate + change)
    }
}

impl TransportLimits {
    /// The largest tilt offset (rad) `remaining_m` before the path's end: `max_tilt_offset_deg`,
    /// shrinking linearly to zero over the last `tilt_offset_fade_m` when that is set.
    pub fn tilt_offset_bound(&self, remaining_m: f64) -> f64 {
        let full = self.max_tilt_offset_deg.to_radians();
        match self.tilt_offset_fade_m {
            Some(fade) => full * (remaining_m / fade).clamp(0.0, 1.0),
            None => full,
        }
    }

    /// The reference's path speed and progress after one control interval `interval_s` on a path
    /// of `length_m`, from `progress_m` at `path_speed_m_s`, when `requested_m_s` is asked for:
    /// the request within the largest speed, the acceleration limit, and the speed from which the
    /// tool still brakes to rest at the path's end; progress by the trapezoidal rule, snapped to
    /// the end within 1 mm. Returns `(speed, progress)`.
    pub fn advance_path(
        &self,
        progress_m: f64,
        path_speed_m_s: f64,
        requested_m_s: f64,
        length_m: f64,
        interval_s: f64,
    ) -> (f64, f64) {
        let remaining = (length_m - progress_m).max(0.0);
        let step = self.max_path_accel_m_s2 * interval_s;
        // Never faster than the tool can still brake to rest at the place pose.
        let brake = (2.0 * self.max_path_accel_m_s2 * remaining).sqrt();
        let speed = requested_m_s
            .clamp(0.0, self.max_path_speed_m_s)
            .clamp(path_speed_m_s - step, path_speed_m_s + step)
            .clamp(0.0, brake.max(0.0));
        let mut progress = (progress_m + 0.5 * (path_speed_m_s + speed) * interval_s).min(length_m);
        if length_m - progress < PATH_END_SNAP_M {
            progress = length_m;
        }
        (speed, progress)
    }
}

impl Transport {
    /// Sets how the nominal orientation tilts along the path (the recorded profile unless set).
    /// The place pose is the same under every schedule.
    pub fn set_tilt_schedule(&mut self, schedule: TiltSchedule) {
        self.tilt_schedule = schedule;
    }

    /// The nominal tilt about world x at arc length `s` of `episode`'s path (rad).
    fn nominal_tilt(&self, episode: &Episode, s: f64) -> f64 {
        let path = &self.paths[episode.path];
        let fraction = match self.tilt_schedule {
            TiltSchedule::Recorded => path.tilt_fraction(s),
            TiltSchedule::MinimumJerk => minimum_jerk(s / path.length_m),
        };
        episode.target_tilt * fraction
    }

    /// The scripted baseline's actions for every copy now: the recorded path's own progress
    /// over time, played `time_scale` times as fast (1 = as recorded, 2 = twice as fast), as the
    /// path speed that brings the reference to where the recording was at the end of the next
    /// control interval, and no tilt offset (the nominal orientation already follows the recorded
    /// tilt profile).
    pub fn scripted_actions(&self, time_scale: f64) -> Vec<f32> {
        self.timed_actions(&self.paths, time_scale)
    }

    /// As [`Transport::scripted_actions`], with the progress over time of `timings[p]` (another
    /// recording, e.g. the medium-velocity one of the same tilt level; see [`super::recorded_timings`])
    /// scaled to the length of path `p`: the recorded timing played along the episode's path.
    pub fn timed_actions(&self, timings: &[TransportPath], time_scale: f64) -> Vec<f32> {
        let t = self.dt;
        self.episodes
            .iter()
            .flat_map(|episode| {
                let path = &self.paths[episode.path];
                let timing = &timings[episode.path];
                let stretch = path.length_m / timing.length_m;
                let elapsed = episode.steps as f64 * t;
                let planned = timing.recorded_progress(time_scale * (elapsed + t)) * stretch;
                let ahead = planned - episode.progress;
                [(ahead.max(0.0) / t) as f32, 0.0, 0.0]
            })
            .collect()
    }

    /// The time-optimal, jerk-limited progress along each copy's path now ([`plan_path_profile`]):
    /// from rest at the pick pose to rest at the place pose under `limits` on the reference
    /// pose's linear and angular speed, acceleration and jerk, the tilt following the nominal
    /// tilt ([`Transport::set_tilt_schedule`]). Plan after a reset; [`Transport::profile_actions`]
    /// plays the plans.
    pub fn plan_profiles(&self, limits: &MotionLimits) -> Result<Vec<PathProfile>, EnvError> {
        self.episodes
            .iter()
            .map(|episode| self.plan_episode(episode, limits))
            .collect()
    }

    /// The time-optimal, jerk-limited progress along `episode`'s path under `limits`.
    fn plan_episode(
        &self,
        episode: &Episode,
        limits: &MotionLimits,
    ) -> Result<PathProfile, EnvError> {
        let path = &self.paths[episode.path];
        let pose = |s: f64| {
            (
                self.reference_position(episode, s),
                self.nominal_tilt(episode, s),
            )
        };
        plan_path_profile(path.length_m, pose, limits, self.dt)
            .map_err(|e| EnvError::Simulator(format!("path {}: {e}", path.id)))
    }

    /// Plans copy `env`'s motion profile for its current episode under the tool's limits times
    /// `[transport.profile_rate].limits_scale` (a no-op without that table).
    pub(super) fn plan_profile(&mut self, env: usize) -> Result<(), EnvError> {
        if let Some(p) = self.profile_rate {
            let limits = MotionLimits::of_tool(&self.config.limits).scaled(p.limits_scale);
            self.plans[env] = Some(self.plan_episode(&self.episodes[env], &limits)?);
        }
        Ok(())
    }

    /// The profile baseline's actions for every copy now: the path speed `profiles[copy]`
    /// plans for the end of the next control interval plus a share of the reference's lag
    /// behind the plan, and no tilt offset (the nominal orientation already follows the tilt
    /// profile at the reference's progress). The actions go through the same clamps and rate
    /// limits as any other ([`Transport::scripted_actions`], a policy's).
    pub fn profile_actions(&self, profiles: &[PathProfile]) -> Vec<f32> {
        let t = self.dt;
        self.episodes
            .iter()
            .zip(profiles)
            .flat_map(|(episode, profile)| {
                let elapsed = episode.steps as f64 * t;
                [
                    profile.path_speed(elapsed, 1.0, episode.progress, t) as f32,
                    0.0,
                    0.0,
                ]
            })
            .collect()
    }

    /// Reference position of `episode`'s path at arc length `s`.
    fn reference_position(&self, episode: &Episode, s: f64) -> DVec3 {
        let path = &self.paths[episode.path];
        path.position(s) + episode.start_offset + episode.goal_jitter * (s / path.length_m)
    }

    /// Nominal orientation at arc length `s`: the pick orientation tilted by the nominal tilt.
    fn nominal_orientation(&self, episode: &Episode, s: f64) -> DQuat {
        DQuat::from_rotation_x(self.nominal_tilt(episode, s))
            * self.paths[episode.path].start_orientation
    }

    /// Place pose of `episode`.
    pub(super) fn goal(&self, episode: &Episode) -> (DVec3, DQuat) {
        let length = self.paths[episode.path].length_m;
        (
            self.reference_position(episode, length),
            self.nominal_orientation(episode, length),
        )
    }

    /// Checks `actions` before a step: 3 finite values per copy, after a reset.
    pub(super) fn check_actions(&self, actions: &[f32]) -> Result<(), EnvError> {
        check_action_len(actions, self.episodes.len(), 3)?;
        if self.variants.is_empty() {
            return Err(EnvError::Simulator("step before reset".into()));
        }
        if let Some(k) = actions.iter().position(|a| !a.is_finite()) {
            return Err(EnvError::NonFiniteAction {
                env: k / 3,
                index: k % 3,
                value: actions[k],
            });
        }
        Ok(())
    }

    /// Commands the tool of every copy still running from its action (`actions`: 3 per copy).
    pub(super) fn command_tools(&mut self, actions: &[f32]) -> Result<(), EnvError> {
        for env in 0..self.episodes.len() {
            if !self.retired[env] {
                self.command(env, &actions[env * 3..env * 3 + 3])?;
            }
        }
        Ok(())
    }

    /// The path speed copy `env`'s first action asks for, the action clamped to its bounds, and
    /// the profile's clock after the interval: the action itself, or with
    /// `[transport.profile_rate]` the speed that plays the profile at the action's clock rate
    /// (its change limited), like [`Transport::profile_actions`] at rate 1.
    fn path_speed_request(&self, env: usize, action: f32) -> (f64, f64, f64) {
        let episode = &self.episodes[env];
        let (Some(p), Some(plan)) = (self.profile_rate, &self.plans[env]) else {
            let speed = (action as f64).clamp(0.0, self.config.limits.max_path_speed_m_s);
            return (speed, speed, episode.profile_clock);
        };
        let t = self.dt;
        let rate = p.rate(action as f64, episode.previous_action[0], t);
        let speed = plan.path_speed(episode.profile_clock, rate, episode.progress, t);
        (speed, rate, episode.profile_clock + rate * t)
    }

    /// Turns copy `env`'s action into the reference for the next interval and commands the tool.
    fn command(&mut self, env: usize, action: &[f32]) -> Result<(), EnvError> {
        let (requested, first, clock) = self.path_speed_request(env, action[0]);
        let l = &self.config.limits;
        let t = self.dt;
        let mut episode = self.episodes[env];
        let length = self.paths[episode.path].length_m;
        let (speed, progress) =
            l.advance_path(episode.progress, episode.path_speed, requested, length, t);
        let tilt = l.tilt_offset_bound(length - progress);
        let a = [
            first,
            (action[1] as f64).clamp(-tilt, tilt),
            (action[2] as f64).clamp(-tilt, tilt),
        ];
        let target = self.reference_position(&episode, progress);
        let feedforward = self.paths[episode.path].tangent(progress) * speed;
        let state = self.states[env];
        let (p0, v0) = (v3(state.tool_position), v3(state.tool_velocity));
        let gain = l.tracking_gain;
        let linear = feedforward + gain * (2.0 * (target - p0) / t - v0 - feedforward);
        let orientation = DQuat::from_rotation_x(a[1])
            * DQuat::from_rotation_z(a[2])
            * self.nominal_orientation(&episode, progress);
        let q0 = quat(state.tool_orientation);
        let w0 = v3(state.tool_angular_velocity);
        let angular = gain * (2.0 * rotation_between(q0, orientation) / t - w0);
        self.sim
            .command_tool(
                env,
                ToolCommand::Twist {
                    linear: linear.as_vec3().to_array(),
                    angular: angular.as_vec3().to_array(),
                },
                t,
            )
            .map_err(sim_error)?;
        episode.last_advance = progress - episode.progress;
        episode.progress = progress;
        episode.path_speed = speed;
        episode.previous_action = a;
        episode.profile_clock = clock;
        self.episodes[env] = episode;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use crate::transport::test_support::{column, env, info, test_table};
    use crate::VecEnv;

    #[test]
    fn scripted_recorded_path_places_the_package_without_a_seal_failure() {
        // One copy replaying its recording's own timing: the high-velocity recordings succeeded on
        // the real robot, so the scripted baseline at time scale 1 must place the package. On the
        // scene's own 16 x 19 grid: on 11 x 13 the heavy disc slips through the coarse sheet when
        // the tool accelerates (the simulator's health check reports it).
        let mut t = env(
            &test_table().replace("grid = [11, 13]", "grid = [16, 19]"),
            1,
        );
        let mut out = t.buffers();
        t.try_reset(2, &mut out).unwrap();
        let recorded = t.paths()[t.episodes[0].path].recorded_duration_s;
        let mut steps = 0;
        while !out.done(0) {
            let actions = t.scripted_actions(1.0);
            t.step(&actions, &mut out).unwrap();
            steps += 1;
        }
        let seconds = steps as f64 * t.control_interval_s();
        assert_eq!(
            info(&t, 0, "episode/success"),
            1.0,
            "ended after {seconds} s: {:?}",
            t.info()
        );
        assert!(out.terminated[0]);
        // Placed about when the recording was (plus the time the object needs to settle).
        assert!(
            seconds > 0.8 * recorded && seconds < recorded + 3.0,
            "{seconds} s against {recorded} s recorded"
        );
    }

    #[test]
    fn the_profile_brings_the_reference_to_the_place_pose_at_rest_within_the_limits() {
        use crate::transport::MotionLimits;
        let mut t = env(&test_table(), 2);
        let mut out = t.buffers();
        t.set_retire_finished(true);
        t.try_reset(3, &mut out).unwrap();
        let limits = MotionLimits::of_tool(&t.config.limits).scaled(0.5);
        let profiles = t.plan_profiles(&limits).unwrap();
        let dt = t.control_interval_s();
        let mut speeds = vec![Vec::new(); 2];
        for _ in 0..((profiles[0].duration_s.max(profiles[1].duration_s) / dt) as usize + 20) {
            let actions = t.profile_actions(&profiles);
            t.step(&actions, &mut out).unwrap();
            for (copy, speed) in speeds.iter_mut().enumerate() {
                speed.push(t.episodes[copy].path_speed);
            }
        }
        for (copy, profile) in profiles.iter().enumerate() {
            let episode = &t.episodes[copy];
            let length = t.paths[episode.path].length_m;
            assert_eq!(profile.length_m, length);
            // The reference reached the place pose and stopped there...
            assert_eq!(episode.progress, length, "copy {copy}: {:?}", t.info());
            assert_eq!(episode.path_speed, 0.0);
            // ...no later than a few control intervals after the plan, and never faster than it.
            let arrival = speeds[copy].iter().rposition(|&v| v > 0.0).unwrap() + 1;
            assert!(
                (arrival as f64 * dt - profile.duration_s).abs() < 5.0 * dt,
                "copy {copy}: at {} s, planned {} s",
                arrival as f64 * dt,
                profile.duration_s
            );
            let fastest = speeds[copy].iter().fold(0.0f64, |a, &b| a.max(b));
            assert!(fastest <= profile.peak_speed_m_s * 1.05, "{fastest}");
        }
    }

    #[test]
    fn the_tilt_offset_fades_to_zero_over_the_last_stretch_of_the_path() {
        let fade = 0.1;
        let text = test_table().replace(
            "max_tilt_offset_deg = 20.0",
            &format!("max_tilt_offset_deg = 3.0\ntilt_offset_fade_m = {fade}"),
        );
        let mut t = env(&text, 1);
        let mut out = t.buffers();
        t.set_retire_finished(true);
        t.try_reset(3, &mut out).unwrap();
        let length = t.paths[t.episodes[0].path].length_m;
        // Small tilts at a moderate speed, which keep the seal, with the bound just above them.
        let (asked, full) = (0.05f32, 3f64.to_radians());
        let (mut faded, mut steps) = (0, 0);
        while t.episodes[0].progress < length && steps < 200 {
            t.step(&[0.3, asked, -asked], &mut out).unwrap();
            steps += 1;
            let episode = &t.episodes[0];
            let remaining = length - episode.progress;
            let [_, x, z] = episode.previous_action;
            assert_eq!(x, -z);
            assert_eq!(
                column(&t, &out, 0, "previous_tilt_offset_x", false),
                x as f32
            );
            if remaining >= fade {
                assert_eq!(x, asked as f64, "{remaining} m before the end");
            } else {
                assert!(
                    x <= full * remaining / fade + 1e-12,
                    "{x} rad {remaining} m before the end"
                );
                faded += 1;
            }
        }
        // The reference arrived with the tool's offsets gone, after a few faded steps.
        assert_eq!(t.episodes[0].progress, length, "{:?}", t.info());
        assert_eq!(t.episodes[0].previous_action[1], 0.0);
        assert!(faded >= 2, "{faded} faded steps");
    }

    #[test]
    fn a_profile_rate_action_plays_the_profile_at_its_rate_within_the_rate_limits() {
        use crate::transport::MotionLimits;
        let text = test_table()
            + "\n[transport.profile_rate]\nlimits_scale = 0.5\nmax_rate = 2.0\nmax_rate_change_per_s = 2.0\n";
        let mut t = env(&text, 2);
        let spec = t.spec().clone();
        assert_eq!(spec.action.names[0], "profile_rate");
        assert_eq!(spec.action.high[0], 2.0);
        assert_eq!(spec.observation.names[14], "profile_clock");
        assert_eq!(spec.observation.names[16], "previous_profile_rate");
        let mut out = t.buffers();
        t.try_reset(3, &mut out).unwrap();
        // The plan the episode plays is the profile baseline's at the same limits.
        let limits = MotionLimits::of_tool(&t.config.limits).scaled(0.5);
        let plans = t.plan_profiles(&limits).unwrap();
        let dt = t.control_interval_s();
        let obs = spec.observation.dim();
        // The rate's largest change per control interval (2 per second).
        let change = 2.0 * dt;
        // Copy 0 plays the plan at rate 1; copy 1 holds the reference (rate 0) for ten steps,
        // then asks for more than the largest rate. Its rate moves towards the rate asked (within
        // [0, 2]) by at most `change` per step, and its clock runs at that rate.
        let (mut rate, mut clock) = (1.0f64, 0.0);
        for step in 0..20 {
            let hold = step < 10;
            t.step(
                &[1.0, 0.0, 0.0, if hold { 0.0 } else { 3.0 }, 0.0, 0.0],
                &mut out,
            )
            .unwrap();
            let played = &t.episodes[0];
            assert!((played.profile_clock - (step + 1) as f64 * dt).abs() < 1e-9);
            let (planned, _) = plans[0].at(played.profile_clock);
            assert!(
                (played.progress - planned).abs() < 5e-3,
                "step {step}: {} m along, planned {planned} m",
                played.progress
            );
            assert_eq!(out.obs[14], played.profile_clock as f32);
            rate = if hold {
                (rate - change).max(0.0)
            } else {
                (rate + change).min(2.0)
            };
            clock += rate * dt;
            let held = &t.episodes[1];
            assert_eq!(held.previous_action[0], rate, "step {step}");
            assert!((held.profile_clock - clock).abs() < 1e-12, "step {step}");
            assert_eq!(out.obs[obs + 16], rate as f32);
        }
        // It stopped, then sped up again.
        assert!(rate > 0.9 && clock < 12.0 * dt, "{rate} {clock}");
        // A baseline drives the same config with path speeds along the recorded tilt.
        t.drive_path_speed();
        t.try_reset(3, &mut out).unwrap();
        t.step(&[0.3, 0.0, 0.0, 0.3, 0.0, 0.0], &mut out).unwrap();
        assert_eq!(t.episodes[0].previous_action[0], 0.3f32 as f64);
        assert_eq!(t.episodes[0].profile_clock, 0.0);
    }
}
