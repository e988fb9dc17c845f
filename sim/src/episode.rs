//! What one environment's episode is given and what it reports: its inputs ([`EpisodeSpec`],
//! [`Placement`]) and its outputs ([`DiscState`], [`EnvObservation`], [`CupLoad`],
//! [`HealthEvent`], [`SealEvent`]). The evolving state of the environments is not here: it lives
//! in the simulator's blocks (`state::State`), struct-of-arrays across environments.

use std::sync::Arc;

use serde::{Deserialize, Serialize};

use crate::config::Params;
use crate::error::SimError;
use crate::trajectory::ToolTrajectory;

/// Where one environment's package, tool and disc start (world frame, m).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Placement {
    /// Package grid corner: lower-sheet/upper-sheet vertex (0, 0) sits here (± half the
    /// thickness in y). The package extends along +x (long side) and +z (short side).
    pub package_origin: [f32; 3],
    /// The tool's cup point (the reference's `initial_suction_cup_position`); cups are placed
    /// around it.
    pub cup_point: [f32; 3],
    /// Initial disc centre (orientation is the identity: disc axis along world y).
    pub disc_position: [f32; 3],
    /// Where the disc is held during the rest period, if anywhere. The disc centre is moved
    /// kinematically from `disc_position` to this point over the first half of the rest, held
    /// there for the second half while the package settles around it, and released (at zero
    /// velocity) at trajectory time 0; its rotation is free throughout, or carried too
    /// (`DiscConfig::hold_orientation`). `None`: the disc is
    /// free from the start (the reference's rule), and it slides to wherever the sagging package
    /// lets it rest.
    pub disc_hold: Option<[f32; 3]>,
    /// Yaw of the package under the tool (rad, about world y through `cup_point`): the package's
    /// particles, the disc and its hold point are turned by it before the cups attach.
    #[serde(default)]
    pub package_yaw_rad: f32,
    /// Disc orientation (x, y, z, w); the identity keeps the disc axis along world y. With a
    /// `disc_hold` and `DiscConfig::hold_orientation`, the disc starts level and is turned to this
    /// orientation over the first half of the rest (about the tilt's axis, on the centre's time
    /// profile), held there for the second half and released with the centre. Otherwise it is
    /// the initial orientation.
    #[serde(default = "identity_quat")]
    pub disc_orientation: [f32; 4],
}

fn identity_quat() -> [f32; 4] {
    [0.0, 0.0, 0.0, 1.0]
}

impl Placement {
    /// A placement with a free disc in its identity orientation and no package yaw.
    pub fn new(package_origin: [f32; 3], cup_point: [f32; 3], disc_position: [f32; 3]) -> Self {
        Placement {
            package_origin,
            cup_point,
            disc_position,
            disc_hold: None,
            package_yaw_rad: 0.0,
            disc_orientation: identity_quat(),
        }
    }

    /// The reference rule (`reference-model.md` §1, §4): package origin = (min x, mean y, min z)
    /// of the initial (row 0) markers; the disc at the object's x, z and the markers' mean y.
    pub fn from_markers(
        initial_markers: &[[f32; 3]],
        cup_point: [f32; 3],
        object_position: [f32; 3],
    ) -> Result<Self, SimError> {
        if initial_markers.is_empty() || initial_markers.iter().flatten().any(|c| !c.is_finite()) {
            return Err(SimError::Trajectory(
                "initial markers must be a non-empty set of finite points".into(),
            ));
        }
        let min_x = initial_markers
            .iter()
            .map(|m| m[0])
            .fold(f32::INFINITY, f32::min);
        let min_z = initial_markers
            .iter()
            .map(|m| m[2])
            .fold(f32::INFINITY, f32::min);
        let mean_y = (initial_markers.iter().map(|m| m[1] as f64).sum::<f64>()
            / initial_markers.len() as f64) as f32;
        Ok(Placement::new(
            [min_x, mean_y, min_z],
            cup_point,
            [object_position[0], mean_y, object_position[2]],
        ))
    }

    /// This placement with the disc held at `target` during the rest period (see
    /// [`Placement::disc_hold`]): the recorded start of a trajectory, so a replay begins where the
    /// recording does.
    pub fn holding_disc_at(self, target: [f32; 3]) -> Self {
        Placement {
            disc_hold: Some(target),
            ..self
        }
    }
}

/// How one environment's episode is set up: what differs between the environments of a batch
/// (the `env` crate's `EnvSpec` is the trainer-facing description of a whole task).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct EpisodeSpec {
    /// Initial placement.
    pub placement: Placement,
    /// Material parameters.
    pub params: Params,
    /// Object mass (kg) before the config's scaling (reference: `object_total_mass_kg`).
    pub object_mass_kg: f32,
    /// Simulated disc kg per object kg for this environment; `None` takes the scene's
    /// `disc.mass_scale`.
    pub disc_mass_scale: Option<f32>,
    /// Supply vacuum of this environment's cups below ambient (kPa); `None` takes the scene's
    /// `seal.vacuum_kpa`. Sets the seal's capacity and lip strength (and the reported
    /// [`CupLoad::capacity_n`]) of this environment only.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub vacuum_kpa: Option<f32>,
    /// Tool trajectory (time 0 = start of motion, after the configured rest period).
    pub trajectory: Arc<ToolTrajectory>,
}

/// Pose and twist of one environment's disc.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct DiscState {
    /// Centre of mass (m).
    pub position: [f32; 3],
    /// Orientation (x, y, z, w).
    pub orientation: [f32; 4],
    /// Linear velocity (m/s).
    pub velocity: [f32; 3],
    /// Angular velocity, world frame (rad/s).
    pub angular_velocity: [f32; 3],
}

/// Why an environment was frozen.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum HealthReason {
    /// A position or velocity became NaN or infinite.
    NonFinite,
    /// A particle or the disc exceeded `health.max_speed_m_s`.
    TooFast,
    /// A particle or the disc moved further than `health.max_displacement_m` from its start.
    TooFar,
    /// The disc left the package: its centre is outside the box around the package's particles
    /// grown by the particle radius and the disc's radius, e.g. it fell through a sheet.
    ObjectOutside,
}

/// An environment flagged by the health check; it is frozen from then on.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct HealthEvent {
    /// Environment index.
    pub env: usize,
    /// What was wrong.
    pub reason: HealthReason,
    /// The environment's own time at the check that caught it (s, from the start of its
    /// episode, i.e. of the rest period).
    pub time: f64,
}

/// One environment's tool, disc and seal summary at the current substep (see
/// [`crate::Simulator::read_states`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct EnvObservation {
    /// The environment's own time (s, from the start of its episode).
    pub time: f64,
    /// Tool position (m, world).
    pub tool_position: [f32; 3],
    /// Tool orientation (x, y, z, w).
    pub tool_orientation: [f32; 4],
    /// Tool linear velocity (m/s, world).
    pub tool_velocity: [f32; 3],
    /// Tool angular velocity (rad/s, world).
    pub tool_angular_velocity: [f32; 3],
    /// The disc in the world frame.
    pub disc: DiscState,
    /// The disc relative to the tool, in the tool frame: position and orientation relative to
    /// the tool's, velocity relative to the tool's point velocity there, angular velocity
    /// relative to the tool's.
    pub disc_in_tool: DiscState,
    /// Cups still sealed.
    pub cups_attached: u32,
    /// Whether the environment is frozen (health check) or retired.
    pub frozen: bool,
}

/// One cup's load at the current substep (see [`crate::Simulator::read_cup_loads`]), after the
/// seal model's low-pass filter.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct CupLoad {
    /// Whether the cup holds the film.
    pub attached: bool,
    /// Pull of the film on the cup along the cup's axis (N; negative: the film pushes on it).
    pub normal_n: f32,
    /// Tangential load in the cup's plane (N).
    pub shear_n: f32,
    /// Vacuum holding force of the sealed area, Δp·A·(sealed fraction) (N).
    pub capacity_n: f32,
    /// Fraction of the lip still sealed.
    pub sealed_fraction: f32,
    /// max(normal / capacity, shear / (μ·(capacity − normal))): 1 is the failure limit; what a
    /// real gripper sees as vacuum loss.
    pub utilisation: f32,
}

/// Why a cup did not seal at pick time.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub enum NoSealReason {
    /// The lip is further than `seal.max_gap_m` from the film's plane (m).
    Gap(f32),
    /// The film's plane is tilted more than `seal.max_tilt_deg` from the cup face (degrees).
    Tilt(f32),
    /// The film under the lip deviates more than `seal.max_fold_m` from a plane (m).
    Fold(f32),
}

/// What happened to a seal.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub enum SealEventKind {
    /// Loading failed: the cup never attached.
    NotSealed(NoSealReason),
    /// Lip elements peeled until the vacuum was lost.
    Peeled,
    /// The normal pull exceeded the vacuum force.
    PulledOff,
    /// The shear load exceeded friction times the clamping force: the cup slid off.
    Slid,
    /// No cup holds the package any more: it is dropped.
    Dropped,
}

/// A seal event of one environment.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct SealEvent {
    /// Environment index.
    pub env: usize,
    /// Cup index (`None` for [`SealEventKind::Dropped`]).
    pub cup: Option<usize>,
    /// What happened.
    pub kind: SealEventKind,
    /// The environment's own time (s).
    pub time: f64,
    /// The cup's load at that moment (filtered).
    pub load: CupLoad,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn placement_follows_the_reference_rule() {
        let markers = [[0.2, 0.25, -0.5], [0.1, 0.27, -0.4], [0.3, 0.23, -0.6]];
        let p = Placement::from_markers(&markers, [0.2, 0.26, -0.45], [0.21, 0.1, -0.47]).unwrap();
        assert_eq!(p.package_origin[0], 0.1);
        assert_eq!(p.package_origin[2], -0.6);
        assert!((p.package_origin[1] - 0.25).abs() < 1e-6);
        assert_eq!(p.disc_position[0], 0.21);
        assert!((p.disc_position[1] - 0.25).abs() < 1e-6);
        assert!(Placement::from_markers(&[], [0.0; 3], [0.0; 3]).is_err());
        assert!(Placement::from_markers(&[[f32::NAN, 0.0, 0.0]], [0.0; 3], [0.0; 3]).is_err());
    }
}
