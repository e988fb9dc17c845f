//! What a robot runs between a profile-rate policy and its path follower: [`ProfileReference`]
//! plans the motion profile Transport-v0 plans with `[transport.profile_rate]` along the cell's
//! own path and turns each action (the profile's clock rate) into the next path speed and
//! progress, with the environment's own functions ([`PathProfile::path_speed`],
//! [`ProfileRateAction::rate`], [`TransportLimits::advance_path`]).

use std::path::PathBuf;

use glam::DVec3;
use numpy::{PyReadonlyArrayDyn, PyUntypedArrayMethods};
use pyo3::prelude::*;
use rlpkg_env::transport::{
    plan_path_profile, MotionLimits, PathProfile, ProfileRateAction, TransportLimits,
};

use rlpkg_env::tasks::read_transport_config;

use crate::{real, real_array, value_error};

/// What `positions` takes.
const POSITIONS: &str = "a (K, 3) array of real numbers with K >= 2 (the path's reference \
                         positions in m, in order along the path)";

/// What `tilts` takes.
const TILTS: &str =
    "a (K,) array of real numbers, one per position (the tilt about world x in rad)";

/// A path given as poses at increasing arc length: positions joined by straight segments, the
/// tilt interpolated linearly along them.
struct SampledPath {
    /// Arc length at each sample (m), from 0, strictly increasing.
    arc_m: Vec<f64>,
    positions: Vec<DVec3>,
    tilts_rad: Vec<f64>,
}

impl SampledPath {
    fn new(positions: &PyReadonlyArrayDyn<f64>, tilts: &PyReadonlyArrayDyn<f64>) -> PyResult<Self> {
        let shape = positions.shape();
        if shape.len() != 2 || shape[1] != 3 || shape[0] < 2 {
            return Err(value_error(format!(
                "positions: shape {shape:?}; expected {POSITIONS}"
            )));
        }
        let k = shape[0];
        if tilts.shape() != [k] {
            return Err(value_error(format!(
                "tilts: shape {:?}; expected {TILTS} ({k} values)",
                tilts.shape()
            )));
        }
        // In logical (row-major) order whatever the strides: three coordinates per point.
        let coordinates: Vec<f64> = positions.as_array().iter().copied().collect();
        let positions: Vec<DVec3> = coordinates
            .chunks_exact(3)
            .map(|r| DVec3::new(r[0], r[1], r[2]))
            .collect();
        let tilts_rad: Vec<f64> = tilts.as_array().iter().copied().collect();
        if let Some(i) = positions.iter().position(|p| !p.is_finite()) {
            return Err(value_error(format!(
                "positions[{i}]: {:?}; expected finite coordinates (m)",
                positions[i].to_array()
            )));
        }
        if let Some(i) = tilts_rad.iter().position(|t| !t.is_finite()) {
            return Err(value_error(format!(
                "tilts[{i}]: {}; expected a finite angle (rad)",
                tilts_rad[i]
            )));
        }
        let mut arc_m = Vec::with_capacity(k);
        arc_m.push(0.0);
        for (i, pair) in positions.windows(2).enumerate() {
            let segment = pair[1].distance(pair[0]);
            if segment <= 0.0 {
                return Err(value_error(format!(
                    "positions[{}] repeats positions[{i}]; expected distinct consecutive points",
                    i + 1
                )));
            }
            arc_m.push(arc_m[i] + segment);
        }
        Ok(Self {
            arc_m,
            positions,
            tilts_rad,
        })
    }

    fn length_m(&self) -> f64 {
        self.arc_m[self.arc_m.len() - 1]
    }

    /// Position and tilt at arc length `s` (clamped to the path).
    fn pose(&self, s: f64) -> (DVec3, f64) {
        let s = s.clamp(0.0, self.length_m());
        let i = self
            .arc_m
            .partition_point(|&a| a <= s)
            .clamp(1, self.arc_m.len() - 1)
            - 1;
        let u = (s - self.arc_m[i]) / (self.arc_m[i + 1] - self.arc_m[i]);
        (
            self.positions[i].lerp(self.positions[i + 1], u),
            self.tilts_rad[i] + u * (self.tilts_rad[i + 1] - self.tilts_rad[i]),
        )
    }
}

/// The reference a profile-rate policy drives, one episode long.
#[pyclass(module = "rlpkg._native")]
pub struct ProfileReference {
    path: SampledPath,
    plan: PathProfile,
    limits: TransportLimits,
    action: ProfileRateAction,
    interval_s: f64,
    clock_s: f64,
    rate: f64,
    progress_m: f64,
    path_speed_m_s: f64,
}

#[pymethods]
impl ProfileReference {
    /// Plans the profile along the path through `positions` (K x 3, m) with the nominal `tilts`
    /// (K, rad about world x) under the limits of the Transport-v0 configuration `config` (its
    /// `[transport.limits]` times `[transport.profile_rate].limits_scale`, at its control rate),
    /// and starts at the path's start, at rest, at rate 1 (as an episode starts).
    /// `positions` and `tilts` may be any array-likes of real numbers (lists, float32 arrays):
    /// they are converted to float64.
    #[new]
    fn new(
        config: PathBuf,
        positions: &Bound<'_, PyAny>,
        tilts: &Bound<'_, PyAny>,
    ) -> PyResult<Self> {
        let positions = real_array("positions", positions, POSITIONS)?;
        let tilts = real_array("tilts", tilts, TILTS)?;
        let settings = read_transport_config(&config).map_err(value_error)?;
        let Some(action) = settings.profile_rate else {
            return Err(value_error(format!(
                "{}: no [transport.profile_rate] table; expected the configuration of a \
                 profile-rate policy",
                config.display()
            )));
        };
        let path = SampledPath::new(&positions, &tilts)?;
        let interval_s = 1.0 / settings.control_hz;
        let limits = MotionLimits::of_tool(&settings.limits).scaled(action.limits_scale);
        let plan = plan_path_profile(path.length_m(), |s| path.pose(s), &limits, interval_s)
            .map_err(value_error)?;
        Ok(Self {
            path,
            plan,
            limits: settings.limits,
            action,
            interval_s,
            clock_s: 0.0,
            rate: 1.0,
            progress_m: 0.0,
            path_speed_m_s: 0.0,
        })
    }

    /// Advances one control interval with the policy's first action (the clock rate) and returns
    /// `(progress_m, path_speed_m_s)`, the reference's place along the path and its speed.
    fn step(&mut self, action: &Bound<'_, PyAny>) -> PyResult<(f64, f64)> {
        let action = real("action", action, "a finite clock rate (a number)")?;
        if !action.is_finite() {
            return Err(value_error(format!(
                "action: {action}; expected a finite clock rate"
            )));
        }
        let t = self.interval_s;
        let rate = self.action.rate(action, self.rate, t);
        let requested = self.plan.path_speed(self.clock_s, rate, self.progress_m, t);
        let (speed, progress) = self.limits.advance_path(
            self.progress_m,
            self.path_speed_m_s,
            requested,
            self.path.length_m(),
            t,
        );
        self.clock_s += rate * t;
        self.rate = rate;
        self.progress_m = progress;
        self.path_speed_m_s = speed;
        Ok((progress, speed))
    }

    /// The tilt offsets about world x and z (rad) the policy's second and third actions give at
    /// the reference's progress: within `[transport.limits].max_tilt_offset_deg`, shrinking to
    /// zero over the path's last `tilt_offset_fade_m` when the configuration sets it.
    fn tilt_offsets(
        &self,
        action_x: &Bound<'_, PyAny>,
        action_z: &Bound<'_, PyAny>,
    ) -> PyResult<(f64, f64)> {
        let action_x = real("action_x", action_x, "a finite tilt offset (rad)")?;
        let action_z = real("action_z", action_z, "a finite tilt offset (rad)")?;
        if !(action_x.is_finite() && action_z.is_finite()) {
            return Err(value_error(format!(
                "tilt offsets ({action_x}, {action_z}): expected finite angles (rad)"
            )));
        }
        let bound = self
            .limits
            .tilt_offset_bound(self.path.length_m() - self.progress_m);
        Ok((action_x.clamp(-bound, bound), action_z.clamp(-bound, bound)))
    }

    /// The reference position (m) and nominal tilt (rad) at arc length `progress_m` (clamped to
    /// the path).
    fn pose(&self, progress_m: &Bound<'_, PyAny>) -> PyResult<([f64; 3], f64)> {
        let progress_m = real("progress_m", progress_m, "an arc length along the path (m)")?;
        if progress_m.is_nan() {
            return Err(value_error(
                "progress_m: NaN; expected an arc length along the path (m)",
            ));
        }
        let (position, tilt) = self.path.pose(progress_m);
        Ok((position.to_array(), tilt))
    }

    /// The plan's progress (m) and path speed (m/s) at time `t_s` along it.
    fn planned(&self, t_s: &Bound<'_, PyAny>) -> PyResult<(f64, f64)> {
        let t_s = real("t_s", t_s, "a time along the plan (s)")?;
        if t_s.is_nan() {
            return Err(value_error("t_s: NaN; expected a time along the plan (s)"));
        }
        Ok(self.plan.at(t_s))
    }

    /// The actor's `profile_clock` (s): time along the plan.
    #[getter]
    fn clock_s(&self) -> f64 {
        self.clock_s
    }

    /// The actor's `previous_profile_rate`: the rate of the last step (1 at the start).
    #[getter]
    fn rate(&self) -> f64 {
        self.rate
    }

    #[getter]
    fn progress_m(&self) -> f64 {
        self.progress_m
    }

    #[getter]
    fn path_speed_m_s(&self) -> f64 {
        self.path_speed_m_s
    }

    /// Path length (m).
    #[getter]
    fn length_m(&self) -> f64 {
        self.path.length_m()
    }

    /// The plan's duration at rate 1 (s).
    #[getter]
    fn duration_s(&self) -> f64 {
        self.plan.duration_s
    }

    /// The control interval (s).
    #[getter]
    fn interval_s(&self) -> f64 {
        self.interval_s
    }
}
