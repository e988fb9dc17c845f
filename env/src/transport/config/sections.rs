//! The plain sections of the `[transport]` table: the limits of the action and the robot
//! ([`TransportLimits`]), when an episode succeeds ([`SuccessTolerances`]) or fails
//! ([`FailureLimits`]), and the reward weights ([`RewardWeights`]).

use serde::{Deserialize, Serialize};

/// Bounds of the action and of the robot carrying the tool (SI).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TransportLimits {
    /// Largest speed along the path (m/s); at most 1.5 x the high-velocity recordings' peak
    /// tool speed (0.63 m/s).
    pub max_path_speed_m_s: f64,
    /// Largest change of the path speed per second (m/s²); at most 1.5 x the recordings' peak
    /// tool acceleration (3.47 m/s²).
    pub max_path_accel_m_s2: f64,
    /// Largest tilt of the tool away from the path's nominal orientation, about world x and z
    /// (degrees).
    pub max_tilt_offset_deg: f64,
    /// Distance before the path's end over which the largest tilt offset shrinks linearly to
    /// zero (m; optional, in [0.001, 1]): the tool arrives at the place orientation whatever the
    /// policy asks, and its tilting stops stirring the object once it is there.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub tilt_offset_fade_m: Option<f64>,
    /// The robot's largest angular speed (rad/s); at most 1.5 x the recordings' peak (2.07 rad/s).
    pub max_angular_speed_rad_s: f64,
    /// The robot's largest angular acceleration (rad/s²).
    pub max_angular_accel_rad_s2: f64,
    /// Fraction of the predicted pose error the tracking controller removes per control
    /// interval, in (0, 1].
    pub tracking_gain: f64,
}

/// Tolerances at the place pose.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SuccessTolerances {
    /// Tool within this distance of the place position (m).
    pub position_m: f64,
    /// Tool orientation within this angle of the place orientation (degrees).
    pub orientation_deg: f64,
    /// Tool slower than this (m/s).
    pub tool_speed_m_s: f64,
    /// Object slower than this relative to the tool (m/s): it has settled.
    pub object_speed_m_s: f64,
}

/// Failures besides the seal model's events and health freezes.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FailureLimits {
    /// The package counts as dropped when the object is further than this from the tool (m).
    pub max_object_distance_m: f64,
}

/// Reward weights; every term is reported separately (see [`crate::transport::RewardTerms`]).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RewardWeights {
    /// Per path length travelled (a whole path gives this much).
    pub progress: f64,
    /// Per second of episode time (a penalty).
    pub time: f64,
    /// Per metre the object moves relative to the tool (a penalty).
    pub object_motion: f64,
    /// Per second and unit of the largest cup utilisation above `seal_threshold` (a penalty).
    pub seal: f64,
    /// Utilisation below which the seal term is zero.
    pub seal_threshold: f64,
    /// Per m/s² of change of the tool's linear acceleration between control steps (a penalty).
    pub jerk: f64,
    /// Per rad/s² of change of the tool's angular acceleration between control steps (a penalty).
    pub angular_jerk: f64,
    /// Once, when an episode fails (a penalty).
    pub failure: f64,
    /// Once, when the package is placed (a bonus).
    pub success: f64,
}
