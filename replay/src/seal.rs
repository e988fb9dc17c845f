//! Seal calibration: every recording replayed under a grid of seal capacities (vacuum, lip
//! strength), each compared with the recordings' failure flags, and the capacity that agrees best.
//!
//! The seal's values are the model's, not an environment's (`SealConfig` sets the simulator's step
//! constants), so each capacity is one simulator holding every recording; the capacities run in
//! parallel (rayon), each simulator deterministic on its own. A replay only has to find the first
//! cup that fails, so an environment is retired as soon as one does.

use std::sync::Arc;

use rayon::prelude::*;
use rlpkg_mocap::{scan_detachment, DetachmentConfig, DetachmentScan, Trajectory};
use rlpkg_sim::{HealthEvent, Model, SceneConfig, Simulator};

use crate::error::ReplayError;
use crate::rollout::{FrameClock, SealFailure};
use crate::target::Target;

/// Substeps between two looks at the seal events: an environment is retired within this many
/// substeps of its first failure.
const CHECK_SUBSTEPS: u64 = 32;

/// The seal's capacity values of one candidate (the scene's `[seal]` keys).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SealCapacity {
    /// Vacuum gauge pressure under a sealed cup (kPa).
    pub vacuum_kpa: f32,
    /// A lip element's strength as a multiple of its share of the vacuum force.
    pub lip_strength_ratio: f32,
}

impl SealCapacity {
    /// Writes these values into `scene`'s `[seal]`.
    pub fn apply_to(&self, scene: &mut SceneConfig) {
        scene.seal.vacuum_kpa = self.vacuum_kpa;
        scene.seal.lip_strength_ratio = self.lip_strength_ratio;
    }
}

/// The scene's cup centres in the tool's frame (m): on the `cups.circle_radius_m` circle at
/// `cups.angles_deg` from the tool's +z towards +x, in the tool point's plane (the simulator's
/// layout, cup `i` as in its seal events).
pub fn cup_centres_in_tool_frame(scene: &SceneConfig) -> Vec<[f64; 3]> {
    let radius = f64::from(scene.cups.circle_radius_m);
    scene
        .cups
        .angles_deg
        .iter()
        .map(|&angle| {
            let a = f64::from(angle).to_radians();
            [radius * a.sin(), 0.0, radius * a.cos()]
        })
        .collect()
}

/// The package observed leaving a cup of `scene`'s tool in `trajectory` (cups numbered as the
/// simulator's).
pub fn observed_detachment(
    trajectory: &Trajectory,
    scene: &SceneConfig,
    config: &DetachmentConfig,
) -> DetachmentScan {
    scan_detachment(trajectory, &cup_centres_in_tool_frame(scene), config)
}

/// The replay of one recording under one capacity.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SealReplay {
    /// The first cup that failed within the recording, if any.
    pub failure: Option<SealFailure>,
    /// The health event that froze the environment, if it diverged first.
    pub diverged: Option<HealthEvent>,
}

/// Replays every target under every capacity of `capacities` in `scene`; returns
/// `[capacity][target]`.
pub fn seal_replays(
    scene: &SceneConfig,
    targets: &[Target],
    capacities: &[SealCapacity],
) -> Result<Vec<Vec<SealReplay>>, ReplayError> {
    capacities
        .par_iter()
        .map(|capacity| {
            let mut scene = scene.clone();
            capacity.apply_to(&mut scene);
            replay_one_capacity(&scene, targets)
        })
        .collect()
}

fn replay_one_capacity(
    scene: &SceneConfig,
    targets: &[Target],
) -> Result<Vec<SealReplay>, ReplayError> {
    let model = Arc::new(Model::new(scene)?);
    let specs = targets
        .iter()
        .map(|t| t.episode_spec(scene.params, None))
        .collect();
    let mut sim = Simulator::new(model, specs)?;
    let ends: Vec<u64> = targets
        .iter()
        .map(|t| FrameClock::SubstepLength.substep_at(scene, t.duration()))
        .collect();
    let last = ends.iter().copied().max().unwrap_or(0);
    let rest = f64::from(scene.cups.rest_time_s);
    let mut out = vec![
        SealReplay {
            failure: None,
            diverged: None,
        };
        targets.len()
    ];
    let mut seen_events = 0;
    while sim.substep() < last {
        sim.step((last - sim.substep()).min(CHECK_SUBSTEPS));
        for event in &sim.seal_events()[seen_events..] {
            let Some(cup) = event.cup else { continue };
            let t = event.time - rest;
            let replay = &mut out[event.env];
            if t <= targets[event.env].duration() && replay.failure.is_none_or(|f| t < f.t) {
                replay.failure = Some(SealFailure {
                    cup,
                    kind: event.kind,
                    t,
                });
            }
        }
        seen_events = sim.seal_events().len();
        for (env, &end) in ends.iter().enumerate() {
            if !sim.is_frozen(env) && (out[env].failure.is_some() || sim.substep() >= end) {
                sim.retire(env)?;
            }
        }
        if (0..sim.num_envs()).all(|env| sim.is_frozen(env)) {
            break;
        }
    }
    for event in sim.health_events() {
        out[event.env].diverged.get_or_insert(*event);
    }
    Ok(out)
}

/// The 2 x 2 table of recorded failure flags against simulated cup failures, and the replays
/// of each class that diverged (counted as disagreeing, in neither cell).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Confusion {
    /// Flagged, and a cup failed in the simulator.
    pub flagged_failed: usize,
    /// Flagged, no cup failed.
    pub flagged_held: usize,
    /// Not flagged, a cup failed.
    pub unflagged_failed: usize,
    /// Not flagged, no cup failed.
    pub unflagged_held: usize,
    /// Flagged, the replay diverged.
    pub flagged_diverged: usize,
    /// Not flagged, the replay diverged.
    pub unflagged_diverged: usize,
}

impl Confusion {
    /// Recordings whose flag the simulator reproduced.
    pub fn agreement(&self) -> usize {
        self.flagged_failed + self.unflagged_held
    }

    /// Replays that diverged.
    pub fn diverged(&self) -> usize {
        self.flagged_diverged + self.unflagged_diverged
    }

    /// The mean over the two classes of the share of recordings whose flag the simulator
    /// reproduced: flagged ones that failed and unflagged ones that held (a class without
    /// recordings is left out; 0 with none at all). When failures are rare, raw agreement
    /// rewards a seal that never fails; this scores never failing, like always failing, 0.5.
    pub fn balanced_agreement(&self) -> f64 {
        let flagged = self.flagged_failed + self.flagged_held + self.flagged_diverged;
        let unflagged = self.unflagged_failed + self.unflagged_held + self.unflagged_diverged;
        let rates: Vec<f64> = [
            (self.flagged_failed, flagged),
            (self.unflagged_held, unflagged),
        ]
        .into_iter()
        .filter(|&(_, total)| total > 0)
        .map(|(hit, total)| hit as f64 / total as f64)
        .collect();
        match rates.len() {
            0 => 0.0,
            n => rates.iter().sum::<f64>() / n as f64,
        }
    }
}

/// How one capacity did on every recording.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CapacityScore {
    /// Flags against simulated failures.
    pub confusion: Confusion,
    /// Mean |simulated − observed| time of the first failure (s) over the recordings with both
    /// an observed detachment and a simulated failure; `None` when there is none.
    pub timing_error_s: Option<f64>,
}

/// Scores one capacity's replays against the recordings' failure flags and observed detachment
/// times (`observed[i]`: recording time of the observed detachment, if any).
pub fn score(flags: &[bool], observed: &[Option<f64>], replays: &[SealReplay]) -> CapacityScore {
    let mut confusion = Confusion::default();
    let mut errors = Vec::new();
    for ((&flag, seen), replay) in flags.iter().zip(observed).zip(replays) {
        if replay.diverged.is_some() {
            match flag {
                true => confusion.flagged_diverged += 1,
                false => confusion.unflagged_diverged += 1,
            }
            continue;
        }
        let failed = replay.failure.is_some();
        match (flag, failed) {
            (true, true) => confusion.flagged_failed += 1,
            (true, false) => confusion.flagged_held += 1,
            (false, true) => confusion.unflagged_failed += 1,
            (false, false) => confusion.unflagged_held += 1,
        }
        if let (Some(seen), Some(failure)) = (seen, replay.failure) {
            errors.push((failure.t - seen).abs());
        }
    }
    let timing_error_s =
        (!errors.is_empty()).then(|| errors.iter().sum::<f64>() / errors.len() as f64);
    CapacityScore {
        confusion,
        timing_error_s,
    }
}

/// Per candidate: the distance (grid steps, largest over the axes) to the nearest candidate with
/// a lower balanced agreement; infinite when none has. `grid[i]` is candidate `i`'s index along
/// each searched axis.
pub fn margins(grid: &[[usize; 2]], scores: &[CapacityScore]) -> Vec<f64> {
    grid.iter()
        .zip(scores)
        .map(|(a, sa)| {
            grid.iter()
                .zip(scores)
                .filter(|(_, sb)| {
                    sb.confusion.balanced_agreement() < sa.confusion.balanced_agreement()
                })
                .map(|(b, _)| a[0].abs_diff(b[0]).max(a[1].abs_diff(b[1])) as f64)
                .fold(f64::INFINITY, f64::min)
        })
        .collect()
}

/// The best candidate: the highest balanced agreement ([`Confusion::balanced_agreement`]); ties
/// to the smaller timing error (a candidate with one before one without); then to the largest
/// margin; then to the first.
pub fn pick(grid: &[[usize; 2]], scores: &[CapacityScore]) -> Option<usize> {
    let margins = margins(grid, scores);
    (0..scores.len()).min_by(|&a, &b| {
        let (sa, sb) = (&scores[a], &scores[b]);
        let timing = match (sa.timing_error_s, sb.timing_error_s) {
            (Some(x), Some(y)) => x.total_cmp(&y),
            (Some(_), None) => std::cmp::Ordering::Less,
            (None, Some(_)) => std::cmp::Ordering::Greater,
            (None, None) => std::cmp::Ordering::Equal,
        };
        sb.confusion
            .balanced_agreement()
            .total_cmp(&sa.confusion.balanced_agreement())
            .then(timing)
            .then(margins[b].total_cmp(&margins[a]))
            .then(a.cmp(&b))
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use rlpkg_sim::SealEventKind;

    fn failed_at(t: f64) -> SealReplay {
        SealReplay {
            failure: Some(SealFailure {
                cup: 0,
                kind: SealEventKind::PulledOff,
                t,
            }),
            diverged: None,
        }
    }

    const HELD: SealReplay = SealReplay {
        failure: None,
        diverged: None,
    };

    #[test]
    fn scores_count_the_four_cells_and_time_the_matches() {
        let flags = [true, true, false, false, false];
        let observed = [Some(2.0), None, None, Some(1.0), None];
        let replays = [failed_at(2.5), HELD, failed_at(3.0), failed_at(0.5), HELD];
        let s = score(&flags, &observed, &replays);
        assert_eq!(
            s.confusion,
            Confusion {
                flagged_failed: 1,
                flagged_held: 1,
                unflagged_failed: 2,
                unflagged_held: 1,
                flagged_diverged: 0,
                unflagged_diverged: 0,
            }
        );
        assert_eq!(s.confusion.agreement(), 2);
        // Half the flagged failures and a third of the unflagged holds.
        assert!((s.confusion.balanced_agreement() - (0.5 + 1.0 / 3.0) / 2.0).abs() < 1e-12);
        // |2.5 - 2.0| and |0.5 - 1.0|.
        assert_eq!(s.timing_error_s, Some(0.5));
        assert_eq!(score(&flags, &[None; 5], &replays).timing_error_s, None);
    }

    /// A score on 5 unflagged recordings, `agreement` of them held.
    fn scored(agreement: usize, timing: Option<f64>) -> CapacityScore {
        CapacityScore {
            confusion: Confusion {
                unflagged_held: agreement,
                unflagged_failed: 5 - agreement,
                ..Confusion::default()
            },
            timing_error_s: timing,
        }
    }

    #[test]
    fn balanced_agreement_prefers_catching_rare_failures_to_never_failing() {
        // 5 flagged and 22 unflagged recordings: a seal that never fails agrees with 22, one
        // that fails 4 of the 5 flagged and 6 of the unflagged with 20.
        let never = CapacityScore {
            confusion: Confusion {
                flagged_held: 5,
                unflagged_held: 22,
                ..Confusion::default()
            },
            timing_error_s: None,
        };
        let catching = CapacityScore {
            confusion: Confusion {
                flagged_failed: 4,
                flagged_held: 1,
                unflagged_failed: 6,
                unflagged_held: 16,
                ..Confusion::default()
            },
            timing_error_s: Some(0.3),
        };
        assert!(never.confusion.agreement() > catching.confusion.agreement());
        assert_eq!(never.confusion.balanced_agreement(), 0.5);
        let expected = (4.0 / 5.0 + 16.0 / 22.0) / 2.0;
        assert!((catching.confusion.balanced_agreement() - expected).abs() < 1e-12);
        let line = [[0, 0], [1, 0]];
        assert_eq!(pick(&line, &[never, catching]), Some(1));
        assert_eq!(Confusion::default().balanced_agreement(), 0.0);
    }

    #[test]
    fn the_best_agreement_wins_then_timing_then_margin() {
        let line = |n: usize| (0..n).map(|i| [i, 0]).collect::<Vec<_>>();
        // Agreement first, whatever the timing.
        let scores = [scored(3, Some(0.1)), scored(5, Some(2.0)), scored(4, None)];
        assert_eq!(pick(&line(3), &scores), Some(1));
        // Tied agreement: the smaller timing error; one with a timing before one without.
        let scores = [scored(5, None), scored(5, Some(0.4)), scored(5, Some(0.2))];
        assert_eq!(pick(&line(3), &scores), Some(2));
        // Tied agreement and timing: the one furthest from a worse candidate.
        let scores = [
            scored(2, None),
            scored(5, None),
            scored(5, None),
            scored(5, None),
            scored(5, None),
            scored(1, None),
        ];
        assert_eq!(
            margins(&line(6), &scores),
            vec![5.0, 1.0, 2.0, 2.0, 1.0, f64::INFINITY]
        );
        assert_eq!(pick(&line(6), &scores), Some(2), "first of the two middles");
        assert_eq!(pick(&[], &[]), None);
    }

    #[test]
    fn margins_measure_grid_steps_over_both_axes() {
        // A 3 x 3 grid with one worse candidate in the corner (0, 0).
        let grid: Vec<[usize; 2]> = (0..3).flat_map(|i| (0..3).map(move |j| [i, j])).collect();
        let mut scores = vec![scored(4, None); 9];
        scores[0] = scored(1, None);
        let m = margins(&grid, &scores);
        assert_eq!(m[8], 2.0, "(2, 2) is two steps from (0, 0)");
        assert_eq!(m[4], 1.0);
        assert_eq!(
            pick(&grid, &scores),
            Some(2),
            "(0, 2): the first at distance 2"
        );
    }

    #[test]
    fn capacities_replayed_together_match_each_alone() {
        // A vacuum too weak to lift the package and a strong one, on a recording of the study:
        // the weak one loses a cup, the strong one none, and the parallel batch gives each
        // capacity's replays exactly as alone.
        let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
        let scene_path = root.join("../configs/scenes/physical-soft-film.toml");
        let mut scene =
            crate::target::load_scene(scene_path.to_str().unwrap(), Some(0), None).unwrap();
        scene.cups.rest_time_s = 0.1;
        scene.health.object_outside = false;
        let recording = rlpkg_mocap::Dataset::open(&root.join("../data/deformable-sim-real"))
            .unwrap()
            .load("HHLHL")
            .unwrap();
        let targets = [Target::new(&recording, Some(0.3), false).unwrap()];
        let weak = SealCapacity {
            vacuum_kpa: 0.01,
            lip_strength_ratio: 3.0,
        };
        let strong = SealCapacity {
            vacuum_kpa: 100.0,
            ..weak
        };
        let both = seal_replays(&scene, &targets, &[weak, strong]).unwrap();
        let failure = both[0][0].failure.expect("the weak vacuum loses a cup");
        assert!((0.0..=0.3).contains(&failure.t), "{failure:?}");
        assert_eq!(both[1][0].failure, None);
        assert_eq!(both[0], seal_replays(&scene, &targets, &[weak]).unwrap()[0]);
        assert_eq!(
            both[1],
            seal_replays(&scene, &targets, &[strong]).unwrap()[0]
        );
    }

    #[test]
    fn diverged_replays_disagree() {
        let mut diverged = failed_at(1.0);
        diverged.diverged = Some(HealthEvent {
            env: 0,
            reason: rlpkg_sim::HealthReason::NonFinite,
            time: 1.0,
        });
        let s = score(&[true], &[Some(1.0)], &[diverged]);
        assert_eq!(s.confusion.flagged_diverged, 1);
        assert_eq!(s.confusion.diverged(), 1);
        assert_eq!(s.confusion.agreement(), 0);
        assert_eq!(s.confusion.balanced_agreement(), 0.0);
        assert_eq!(s.timing_error_s, None);
    }
}
