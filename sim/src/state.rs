//! Per-environment inputs ([`EnvSpec`], [`Placement`]) and outputs ([`DiscState`],
//! [`HealthEvent`]) of the batched simulator.

use std::sync::Arc;

use crate::config::Params;
use crate::error::SimError;
use crate::trajectory::ToolTrajectory;

/// Where one environment's package, tool and disc start (world frame, m).
#[derive(Clone, Copy, Debug, PartialEq)]
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
    /// velocity) at trajectory time 0; its rotation stays free throughout. `None`: the disc is
    /// free from the start (the reference's rule), and it slides to wherever the sagging package
    /// lets it rest.
    pub disc_hold: Option<[f32; 3]>,
}

impl Placement {
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
        Ok(Placement {
            package_origin: [min_x, mean_y, min_z],
            cup_point,
            disc_position: [object_position[0], mean_y, object_position[2]],
            disc_hold: None,
        })
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

/// Everything that differs between environments of one batch.
#[derive(Clone, Debug)]
pub struct EnvSpec {
    /// Initial placement.
    pub placement: Placement,
    /// Material parameters.
    pub params: Params,
    /// Object mass (kg) before the config's scaling (reference: `object_total_mass_kg`).
    pub object_mass_kg: f32,
    /// Tool trajectory (time 0 = start of motion, after the configured rest period).
    pub trajectory: Arc<ToolTrajectory>,
}

/// Pose and twist of one environment's disc.
#[derive(Clone, Copy, Debug, PartialEq)]
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
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum HealthReason {
    /// A position or velocity became NaN or infinite.
    NonFinite,
    /// A particle or the disc exceeded `health.max_speed_m_s`.
    TooFast,
    /// A particle or the disc moved further than `health.max_displacement_m` from its start.
    TooFar,
}

/// An environment flagged by the health check; it is frozen from then on.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HealthEvent {
    /// Environment index.
    pub env: usize,
    /// What was wrong.
    pub reason: HealthReason,
    /// Simulated time of the check that caught it (s, from the start of the rest period).
    pub time: f64,
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
