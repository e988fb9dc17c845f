//! A recording prepared for replay, and the scene it is replayed in.
//!
//! Scene per trajectory, as the study (reference-model §1, §4): the package corner at the row-0
//! markers, the cups around the recorded initial cup point, the disc at the t = 0 object position
//! with the markers' mean height, a rest period, then the recorded tool motion.

use std::sync::Arc;

use rlpkg_mocap::Trajectory;
use rlpkg_sim::{
    EpisodeSpec, Params, Placement, SceneConfig, SimError, ToolSample, ToolTrajectory,
};

use crate::error::ReplayError;

/// 6 x 7 marker grid with `between` particles between markers, and optionally the time step.
pub fn load_scene(
    preset: &str,
    between: Option<usize>,
    dt: Option<f64>,
) -> Result<SceneConfig, SimError> {
    let mut scene = match preset {
        "reference" | "physical" => SceneConfig::preset(preset)?,
        path => SceneConfig::load(std::path::Path::new(path))?,
    };
    if let Some(p) = between {
        scene.package.grid = [6 + 5 * p, 7 + 6 * p];
    }
    if let Some(dt) = dt {
        scene.integrator.substep_rate_hz = 1.0 / dt;
    }
    scene.validate(preset)?;
    Ok(scene)
}

/// A recorded trajectory prepared for replay: placement, tool motion and the frames to compare.
#[derive(Debug, Clone)]
pub struct Target {
    /// Trajectory id.
    pub id: String,
    /// Initial placement of package, cups and disc.
    pub placement: Placement,
    /// Recorded object mass (kg), before the scene's scaling.
    pub object_mass_kg: f32,
    /// Recorded tool motion.
    pub tool: Arc<ToolTrajectory>,
    /// Row-0 markers, embedded in the upper sheet for the loss.
    pub initial_markers: Vec<[f32; 3]>,
    /// Trajectory time of each compared frame (s).
    pub times: Vec<f64>,
    /// Markers seen in each compared frame.
    pub markers: Vec<Vec<[f64; 3]>>,
    /// Recorded object position in each compared frame.
    pub object: Vec<[f64; 3]>,
}

impl Target {
    /// Prepares `trajectory`, keeping the frames with `t <= max_seconds` (all when `None`). With
    /// `hold_disc` the disc is held at the recorded start during the rest
    /// (`DiscConfig::hold_at_recorded_start`).
    pub fn new(
        trajectory: &Trajectory,
        max_seconds: Option<f64>,
        hold_disc: bool,
    ) -> Result<Self, ReplayError> {
        let fail = |message: String| ReplayError::Trajectory {
            id: trajectory.id.clone(),
            message,
        };
        let meta = &trajectory.meta;
        let f32s = |p: &[f64; 3]| p.map(|c| c as f32);
        let initial_markers: Vec<[f32; 3]> =
            meta.initial_marker_positions_m.iter().map(f32s).collect();
        let first_object = trajectory
            .object
            .position
            .first()
            .ok_or_else(|| fail("no object position".into()))?;
        let mut placement = Placement::from_markers(
            &initial_markers,
            f32s(&meta.initial_suction_cup_position_m),
            f32s(first_object),
        )
        .map_err(|e| fail(e.to_string()))?;
        // Markers set in from the edges: the package's corner lies that far beyond them.
        if let Some([dx, dz]) = meta.marker_inset_m {
            placement.package_origin[0] -= dx as f32;
            placement.package_origin[2] -= dz as f32;
        }
        let placement = if hold_disc {
            placement.holding_disc_at(f32s(first_object))
        } else {
            placement
        };
        let tool = &trajectory.tool;
        let samples = (0..tool.t.len())
            .map(|i| ToolSample {
                t: tool.t[i],
                position: tool.position[i],
                orientation: tool.orientation[i],
                velocity: tool.velocity[i],
            })
            .collect();
        let tool = ToolTrajectory::new(samples).map_err(|e| fail(e.to_string()))?;
        let limit = max_seconds.unwrap_or(f64::INFINITY);
        let frames = (0..trajectory.markers.len())
            .take_while(|&k| trajectory.markers.t(k) <= limit)
            .count()
            .min(trajectory.object.position.len());
        if frames == 0 {
            return Err(fail("no frame to compare".into()));
        }
        Ok(Self {
            id: trajectory.id.clone(),
            placement,
            object_mass_kg: meta.object_total_mass_kg as f32,
            tool: Arc::new(tool),
            initial_markers,
            times: (0..frames).map(|k| trajectory.markers.t(k)).collect(),
            markers: (0..frames)
                .map(|k| trajectory.markers.frame(k).to_vec())
                .collect(),
            object: trajectory.object.position[..frames].to_vec(),
        })
    }

    /// The simulator environment that replays this recording with material `params`; the disc mass
    /// scale is the scene's when `disc_mass_scale` is `None`.
    pub fn episode_spec(&self, params: Params, disc_mass_scale: Option<f32>) -> EpisodeSpec {
        EpisodeSpec {
            placement: self.placement,
            params,
            object_mass_kg: self.object_mass_kg,
            disc_mass_scale,
            vacuum_kpa: None,
            trajectory: self.tool.clone(),
        }
    }

    /// Simulated duration needed (s of trajectory time).
    pub fn duration(&self) -> f64 {
        self.times.last().copied().unwrap_or(0.0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn scene_grid_and_time_step_overrides() {
        let s = load_scene("reference", Some(1), Some(1e-4)).unwrap();
        assert_eq!(s.package.grid, [11, 13]);
        assert!((s.dt() - 1e-4).abs() < 1e-9);
        assert!(load_scene("nonexistent.toml", None, None).is_err());
    }
}
