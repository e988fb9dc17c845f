//! A recording prepared for replay, and the scene it is replayed in.
//!
//! Scene per trajectory, as the study (reference-model §1, §4): the package corner at the row-0
//! markers, the cups around the recorded initial cup point, the disc at the t = 0 object position
//! with the markers' mean height, a rest period, then the recorded tool motion.

use std::sync::Arc;

use rlpkg_mocap::{track_markers, MarkerFrames, TrackingReport, TrackingSettings, Trajectory};
use rlpkg_sim::{
    EpisodeSpec, Params, Placement, SceneConfig, SimError, ToolSample, ToolTrajectory,
};

use crate::error::ReplayError;
use crate::loss::squared_distance;
use crate::phase::{phases, Phase};

/// Largest distance (m) at which a first-frame marker is tied to a simulated site: half the markers'
/// spacing (about 46 mm), beyond which the site is as likely a neighbour's.
pub const SITE_GATE_M: f64 = 0.023;

/// The package grid (vertices per layer) of the study's 6 x 7 marker lattice with `between`
/// particles between neighbouring markers: `[6 + 5 between, 7 + 6 between]`.
pub fn grid_between_markers(between: usize) -> [usize; 2] {
    [6 + 5 * between, 7 + 6 * between]
}

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
        scene.package.grid = grid_between_markers(p);
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
    /// The lower layer's markers at the start (the dataset's `initial_lower_marker_positions_m`),
    /// embedded in the lower sheet: marker sites after `initial_markers`' ([`Target::sites`]).
    pub lower_markers: Vec<[f32; 3]>,
    /// Trajectory time of each compared frame (s).
    pub times: Vec<f64>,
    /// Markers seen in each compared frame.
    pub markers: Vec<Vec<[f64; 3]>>,
    /// The track (physical marker id) of each marker of each compared frame, parallel to `markers`:
    /// the recording's own ids when it carries them (an imported Motive take's cleaned tracks),
    /// else made by [`Target::track`] ([`rlpkg_mocap::tracking`]), one empty list per frame until
    /// then.
    pub marker_tracks: Vec<Vec<u32>>,
    /// The simulated site (index into [`Target::sites`]) of each marker of each compared frame,
    /// parallel to `markers`: `None` until [`Target::tie_sites`], and for a marker whose track was
    /// not tied (first seen after the first frame, or beyond [`SITE_GATE_M`] of every site).
    pub marker_sites: Vec<Vec<Option<usize>>>,
    /// The motion's phase at each compared frame.
    pub phases: Vec<Phase>,
    /// How the marker identities were kept through the recording ([`rlpkg_mocap::tracking`]);
    /// `None` until [`Target::track`] (only the labelled loss needs identities, so a replay,
    /// an evaluation or a transport episode does not pay for them).
    pub tracking: Option<TrackingReport>,
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
        let markers: Vec<Vec<[f64; 3]>> = (0..frames)
            .map(|k| trajectory.markers.frame(k).to_vec())
            .collect();
        let marker_sites = markers.iter().map(|f| vec![None; f.len()]).collect();
        let marker_tracks = (0..frames)
            .map(|k| {
                trajectory
                    .markers
                    .frame_ids(k)
                    .map_or_else(Vec::new, <[u32]>::to_vec)
            })
            .collect();
        Ok(Self {
            id: trajectory.id.clone(),
            placement,
            object_mass_kg: meta.object_total_mass_kg as f32,
            tool: Arc::new(tool),
            initial_markers,
            lower_markers: meta
                .initial_lower_marker_positions_m
                .iter()
                .map(f32s)
                .collect(),
            times: (0..frames).map(|k| trajectory.markers.t(k)).collect(),
            markers,
            marker_tracks,
            marker_sites,
            phases: phases(&trajectory.tool, frames),
            tracking: None,
            object: trajectory.object.position[..frames].to_vec(),
        })
    }

    /// The marker sites at the start (world frame): the upper layer's row-0 markers, then the
    /// lower layer's. Simulated sites come in this order.
    pub fn sites(&self) -> Vec<[f32; 3]> {
        self.initial_markers
            .iter()
            .chain(&self.lower_markers)
            .copied()
            .collect()
    }

    /// Ties the recording's tracks to simulated sites, each track at the first frame it is seen:
    /// the optimal one-to-one assignment (Hungarian) between that frame's new tracks and the sites
    /// no visible tied track holds, on `sites[k]` (the simulated sites at compared frame `k`, e.g.
    /// of the scene's own parameters), within [`SITE_GATE_M`]. The sites ([`Target::sites`]) are
    /// the package's row-0 markers, which the recording's trimmed frames see displaced by the
    /// package's sag, and the lower layer's markers, first seen once the package is lifted, so a
    /// tie is made where both are at the same time. A site that two tracks would show in one frame is
    /// left unknown there. Returns the tracks tied.
    pub fn tie_sites(&mut self, sites: &[Vec<[f64; 3]>]) -> usize {
        use std::collections::HashMap;
        self.track();
        let mut site_of_track: HashMap<u32, Option<usize>> = HashMap::new();
        for (k, sites_k) in sites.iter().enumerate().take(self.markers.len()) {
            let tracks = &self.marker_tracks[k];
            let new: Vec<usize> = (0..tracks.len())
                .filter(|&m| !site_of_track.contains_key(&tracks[m]))
                .collect();
            if new.is_empty() {
                continue;
            }
            let held: Vec<usize> = tracks
                .iter()
                .filter_map(|t| site_of_track.get(t).copied().flatten())
                .collect();
            let free: Vec<usize> = (0..sites_k.len()).filter(|s| !held.contains(s)).collect();
            let cost: Vec<f64> = new
                .iter()
                .flat_map(|&m| {
                    let marker = self.markers[k][m];
                    free.iter()
                        .map(move |&s| squared_distance(&marker, &sites_k[s]))
                })
                .collect();
            let pairs =
                rlpkg_mocap::clean::assign(&cost, new.len(), free.len(), SITE_GATE_M.powi(2));
            for &m in &new {
                site_of_track.insert(tracks[m], None);
            }
            for (row, col) in pairs {
                site_of_track.insert(tracks[new[row]], Some(free[col]));
            }
        }
        self.marker_sites = self
            .marker_tracks
            .iter()
            .map(|tracks| {
                let mut frame: Vec<Option<usize>> = tracks
                    .iter()
                    .map(|t| site_of_track.get(t).copied().flatten())
                    .collect();
                for m in 0..frame.len() {
                    if frame[m].is_some() && frame.iter().filter(|s| **s == frame[m]).count() > 1 {
                        let twice = frame[m];
                        frame
                            .iter_mut()
                            .filter(|s| **s == twice)
                            .for_each(|s| *s = None);
                    }
                }
                frame
            })
            .collect();
        site_of_track.values().filter(|s| s.is_some()).count()
    }

    /// The same recording compared only up to `seconds` of trajectory time (the frames with
    /// `t <= seconds`, their tracks, sites and phases), or `None` when no frame is that early.
    pub fn within(&self, seconds: f64) -> Option<Target> {
        let frames = self.times.iter().take_while(|&&t| t <= seconds).count();
        if frames == 0 {
            return None;
        }
        let mut short = self.clone();
        short.times.truncate(frames);
        short.markers.truncate(frames);
        short.marker_tracks.truncate(frames);
        short.marker_sites.truncate(frames);
        short.phases.truncate(frames);
        short.object.truncate(frames);
        Some(short)
    }

    /// Gives every compared marker its track ([`rlpkg_mocap::track_markers`] over the compared
    /// frames), once; a recording that carries its ids keeps them (the report then counts them).
    pub fn track(&mut self) {
        if self.tracking.is_some() {
            return;
        }
        let has_ids = self.marker_tracks.iter().any(|ids| !ids.is_empty());
        let frames = if has_ids {
            labelled_frames(&self.times, &self.marker_tracks, &self.markers)
        } else {
            MarkerFrames::from_frames(self.times.clone(), self.markers.clone())
        };
        let (labelled, report) = track_markers(&frames, &TrackingSettings::default());
        self.marker_tracks = (0..labelled.len())
            .map(|k| labelled.frame_ids(k).expect("tracked").to_vec())
            .collect();
        self.tracking = Some(report);
    }

    /// Compared frames per second (1 for a single frame).
    pub fn frame_rate(&self) -> f64 {
        let n = self.times.len();
        let span = self.duration() - self.times.first().copied().unwrap_or(0.0);
        if n > 1 && span > 0.0 {
            (n - 1) as f64 / span
        } else {
            1.0
        }
    }

    /// Share of the compared markers whose simulated site is known.
    pub fn labelled_share(&self) -> f64 {
        let all: usize = self.marker_sites.iter().map(Vec::len).sum();
        let known: usize = self
            .marker_sites
            .iter()
            .map(|f| f.iter().flatten().count())
            .sum();
        if all == 0 {
            0.0
        } else {
            known as f64 / all as f64
        }
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

/// Frames at `times` whose markers `markers` carry the ids `tracks` (parallel lists per frame).
pub(crate) fn labelled_frames(
    times: &[f64],
    tracks: &[Vec<u32>],
    markers: &[Vec<[f64; 3]>],
) -> MarkerFrames {
    MarkerFrames::from_labelled_frames(
        times.to_vec(),
        tracks
            .iter()
            .zip(markers)
            .map(|(ids, points)| ids.iter().copied().zip(points.iter().copied()).collect())
            .collect(),
    )
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

    #[test]
    fn a_target_within_a_time_is_the_target_prepared_up_to_it() {
        let trajectory = crate::test_support::recorded("HHHHH");
        let mut whole = Target::new(&trajectory, None, false).unwrap();
        whole.track();
        let mut prepared = Target::new(&trajectory, Some(1.5), false).unwrap();
        prepared.track();
        let short = whole.within(1.5).unwrap();
        assert!(short.times.len() < whole.times.len());
        assert_eq!(short.times, prepared.times);
        assert_eq!(short.markers, prepared.markers);
        assert_eq!(short.phases, prepared.phases);
        assert_eq!(short.object, prepared.object);
        // Tracks are made over the whole recording, so only their count per frame is compared.
        assert_eq!(
            short.marker_tracks.iter().map(Vec::len).collect::<Vec<_>>(),
            prepared
                .marker_tracks
                .iter()
                .map(Vec::len)
                .collect::<Vec<_>>()
        );
        assert!(whole.within(-1.0).is_none());
    }

    #[test]
    fn a_recording_that_carries_marker_ids_keeps_them() {
        let mut trajectory = crate::test_support::recorded("HHHHH");
        assert!(Target::new(&trajectory, Some(1.0), false)
            .unwrap()
            .marker_tracks
            .iter()
            .all(Vec::is_empty));
        // Ids as an import gives them: here every frame's markers numbered in reverse, which
        // frame-to-frame tracking would never produce.
        let frames = &trajectory.markers;
        let reversed = (0..frames.len())
            .map(|k| {
                let points = frames.frame(k);
                let n = points.len() as u32;
                (0..n).rev().zip(points.iter().copied()).collect()
            })
            .collect();
        let times = (0..frames.len()).map(|k| frames.t(k)).collect();
        trajectory.markers = MarkerFrames::from_labelled_frames(times, reversed);
        let mut target = Target::new(&trajectory, Some(1.0), false).unwrap();
        let given = target.marker_tracks.clone();
        assert_eq!(
            given[0].first(),
            Some(&(target.markers[0].len() as u32 - 1))
        );
        target.track();
        assert_eq!(target.marker_tracks, given);
        let report = target.tracking.as_ref().unwrap();
        assert_eq!(report.initial_tracks, target.markers[0].len());
        assert!(report.recorded_ids);
    }

    #[test]
    fn a_tied_track_keeps_its_site_through_the_recording() {
        for id in ["HHHHH", "HHLLL", "HHMMM"] {
            let mut target = Target::new(&crate::test_support::recorded(id), None, false).unwrap();
            assert_eq!(target.labelled_share(), 0.0, "untied");
            target.track();
            // Sites where every frame sees its markers: each track is tied to a site of its own
            // (at its first frame; a marker that reappears as a new track takes its old site).
            let mut sites: Vec<Vec<[f64; 3]>> = Vec::new();
            let mut site_of_track = std::collections::BTreeMap::new();
            for k in 0..target.markers.len() {
                for (m, &track) in target.marker_tracks[k].iter().enumerate() {
                    let n = site_of_track.len();
                    site_of_track
                        .entry(track)
                        .or_insert((n, target.markers[k][m]));
                    site_of_track.get_mut(&track).unwrap().1 = target.markers[k][m];
                }
                let mut frame = vec![[9.0, 9.0, 9.0]; site_of_track.len()];
                for (site, position) in site_of_track.values() {
                    frame[*site] = *position;
                }
                sites.push(frame);
            }
            let tied = target.tie_sites(&sites);
            assert_eq!(tied, site_of_track.len(), "{id}");
            for k in [0, target.markers.len() / 2] {
                for (m, site) in target.marker_sites[k].iter().enumerate() {
                    assert_eq!(*site, Some(site_of_track[&target.marker_tracks[k][m]].0));
                }
            }
            // A site never shows twice in a frame.
            for sites in &target.marker_sites {
                let mut known: Vec<usize> = sites.iter().flatten().copied().collect();
                let count = known.len();
                known.sort_unstable();
                known.dedup();
                assert_eq!(known.len(), count, "{id}");
            }
            assert_eq!(target.labelled_share(), 1.0, "{id}: {:?}", target.tracking);
            assert_eq!(target.phases.len(), target.times.len());
            // Sites far from every marker tie nothing.
            let far: Vec<Vec<[f64; 3]>> = sites
                .iter()
                .map(|f| f.iter().map(|p| [p[0] + 1.0, p[1], p[2]]).collect())
                .collect();
            assert_eq!(target.tie_sites(&far), 0);
            assert_eq!(target.labelled_share(), 0.0);
        }
    }
}
