//! Synthetic recordings: what the simulator itself does with known parameters, observed the way
//! motion capture observes the real package, for parameter-recovery checks of a calibration.
//!
//! A synthetic recording keeps everything of a real one but its observations: the placement and
//! the tool motion are the recording's, the markers of each frame are the simulated marker sites
//! ([`rollout`]'s embedded row-0 markers) and the object is the simulated disc. Two properties of
//! real data carry over, because a calibration that only ever sees perfect data tells nothing
//! about how well real data pins a parameter down:
//!
//! * **Occlusion**: frame `k` shows only the sites that the real frame `k` shows: the sites of its
//!   markers whose identity is known ([`Target::marker_sites`]), and for the others the sites
//!   nearest to them. A frame shows as many markers as the real one, at most one per site, and
//!   every synthetic marker carries its site.
//! * **Noise**: independent Gaussian noise on every coordinate of every marker and of the object,
//!   with the standard deviation of the real recording's markers ([`marker_noise_std`]).

use std::sync::Arc;

use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};
use rlpkg_sim::Model;

use crate::loss::squared_distance;
use crate::rollout::{rollout, Candidate, FrameObservation, Observer};
use crate::target::Target;
use crate::ReplayError;

/// Largest frame-to-frame marker step (m) taken as the same marker by [`marker_noise_std`]: well
/// above the noise (about 0.3 mm) and a frame's motion at 240 frames per second (a few mm at
/// 1 m/s), well below the markers' spacing (about 5 cm).
const SAME_MARKER_M: f64 = 0.01;

/// The per-axis standard deviation (m) of the marker noise of a recording, estimated from its
/// frames: every marker seen in three consecutive frames (matched by nearest neighbour) gives a
/// second difference `x(k+1) − 2 x(k) + x(k−1)`, which is noise of variance `6 σ²` plus the
/// motion's acceleration times the frame interval squared (about 0.2 mm at 10 m/s² and 240 frames
/// per second). The median absolute second difference, scaled to a standard deviation
/// (`1.4826 · median / √6`), is robust to the rare mismatched marker. `None` with fewer than 100
/// second differences.
pub fn marker_noise_std(target: &Target) -> Option<f64> {
    let nearest = |p: &[f64; 3], frame: &[[f64; 3]]| {
        frame
            .iter()
            .map(|q| (squared_distance(p, q), *q))
            .min_by(|a, b| a.0.total_cmp(&b.0))
            .filter(|(d2, _)| *d2 <= SAME_MARKER_M * SAME_MARKER_M)
            .map(|(_, q)| q)
    };
    let mut deviations: Vec<f64> = Vec::new();
    for k in 1..target.markers.len().saturating_sub(1) {
        for p in &target.markers[k] {
            let (Some(before), Some(after)) = (
                nearest(p, &target.markers[k - 1]),
                nearest(p, &target.markers[k + 1]),
            ) else {
                continue;
            };
            deviations.extend((0..3).map(|a| (after[a] - 2.0 * p[a] + before[a]).abs()));
        }
    }
    if deviations.len() < 100 {
        return None;
    }
    let middle = deviations.len() / 2;
    let (_, median, _) = deviations.select_nth_unstable_by(middle, f64::total_cmp);
    Some(1.4826 * *median / 6f64.sqrt())
}

/// How a synthetic recording observes the simulation.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Observation {
    /// Standard deviation (m) of the Gaussian noise on every coordinate of markers and object.
    pub noise_std_m: f64,
    /// Seed of the noise (each target draws from its own stream of it).
    pub seed: u64,
}

/// Synthetic recordings of `truth` on every target (see the module docs): the targets' placement,
/// tool motion and frame times, with the simulated marker sites seen where the real frames see
/// markers and the simulated disc as the object, plus noise. Fails if the truth diverges on a
/// target.
pub fn synthetic_targets(
    model: &Arc<Model>,
    targets: &[Target],
    truth: &Candidate,
    observation: Observation,
) -> Result<Vec<Target>, ReplayError> {
    struct Recorder {
        markers: Vec<Vec<Vec<[f64; 3]>>>,
        object: Vec<Vec<[f64; 3]>>,
    }
    impl Observer for Recorder {
        fn frame(&mut self, o: &FrameObservation) {
            self.markers[o.target].push(o.simulated_points.to_vec());
            self.object[o.target].push(o.disc.position.map(f64::from));
        }
    }
    let mut recorder = Recorder {
        markers: vec![Vec::new(); targets.len()],
        object: vec![Vec::new(); targets.len()],
    };
    let outcomes = rollout(model, targets, &[*truth], &mut recorder)?;
    targets
        .iter()
        .enumerate()
        .map(|(t, target)| {
            if let Some(event) = &outcomes[0][t].diverged {
                return Err(ReplayError::Trajectory {
                    id: target.id.clone(),
                    message: format!(
                        "the true parameters diverge at {:.3} s; no synthetic recording",
                        event.time
                    ),
                });
            }
            let mut rng = StdRng::seed_from_u64(observation.seed);
            // A separate stream per target: the noise of one does not depend on the others.
            for _ in 0..t {
                rng = StdRng::seed_from_u64(rng.random());
            }
            let mut noisy = |p: [f64; 3]| p.map(|v| v + observation.noise_std_m * normal(&mut rng));
            let simulated = &recorder.markers[t];
            let visible: Vec<Vec<usize>> = (0..simulated.len())
                .map(|k| visible_sites(&simulated[k], &target.markers[k], &target.marker_sites[k]))
                .collect();
            let markers: Vec<Vec<[f64; 3]>> = visible
                .iter()
                .zip(simulated)
                .map(|(seen, sites)| seen.iter().map(|&s| noisy(sites[s])).collect())
                .collect();
            let marker_sites = visible
                .iter()
                .map(|seen| seen.iter().map(|&s| Some(s)).collect())
                .collect();
            let marker_tracks: Vec<Vec<u32>> = visible
                .iter()
                .map(|seen| seen.iter().map(|&s| s as u32).collect())
                .collect();
            // Identities are the sites themselves; the report counts them as recorded.
            let labelled = crate::target::labelled_frames(&target.times, &marker_tracks, &markers);
            let tracking = Some(rlpkg_mocap::track_markers(&labelled, &Default::default()).1);
            let object = recorder.object[t].iter().map(|&p| noisy(p)).collect();
            Ok(Target {
                markers,
                marker_tracks,
                marker_sites,
                tracking,
                object,
                ..target.clone()
            })
        })
        .collect()
}

/// The sites seen in a frame whose real markers are `recorded` with sites `known`: each known
/// site, and for each marker of unknown site the nearest site not yet seen; each site once, in site
/// order.
fn visible_sites(sites: &[[f64; 3]], recorded: &[[f64; 3]], known: &[Option<usize>]) -> Vec<usize> {
    let mut seen = vec![false; sites.len()];
    for site in known.iter().flatten() {
        if let Some(s) = seen.get_mut(*site) {
            *s = true;
        }
    }
    for (marker, _) in recorded.iter().zip(known).filter(|(_, k)| k.is_none()) {
        let nearest = (0..sites.len()).filter(|&s| !seen[s]).min_by(|&a, &b| {
            squared_distance(&sites[a], marker).total_cmp(&squared_distance(&sites[b], marker))
        });
        if let Some(nearest) = nearest {
            seen[nearest] = true;
        }
    }
    (0..sites.len()).filter(|&s| seen[s]).collect()
}

/// A standard normal draw (Box–Muller; `rand` alone has no normal distribution).
fn normal(rng: &mut StdRng) -> f64 {
    let u: f64 = 1.0 - rng.random::<f64>(); // (0, 1]: finite logarithm
    let v: f64 = rng.random();
    (-2.0 * u.ln()).sqrt() * (std::f64::consts::TAU * v).cos()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::load_scene;

    use crate::test_support::recorded;

    #[test]
    fn the_real_marker_noise_is_a_fraction_of_a_millimetre() {
        let target = Target::new(&recorded("HHHHH"), Some(2.0), false).unwrap();
        let sigma = marker_noise_std(&target).unwrap();
        assert!((2e-5..2e-3).contains(&sigma), "{sigma}");
    }

    #[test]
    fn keeps_the_real_occlusion_and_adds_the_stated_noise() {
        let mut scene = load_scene("reference", Some(0), None).unwrap();
        scene.cups.rest_time_s = 0.1;
        scene.health.object_outside = false;
        let model = Arc::new(Model::new(&scene).unwrap());
        let target = Target::new(&recorded("HHLHL"), Some(0.1), false).unwrap();
        let truth = Candidate::of_scene(&scene);
        let targets = std::slice::from_ref(&target);
        let exact = Observation {
            noise_std_m: 0.0,
            seed: 0,
        };
        let clean = synthetic_targets(&model, targets, &truth, exact).unwrap();
        let noisy = synthetic_targets(
            &model,
            targets,
            &truth,
            Observation {
                noise_std_m: 1e-3,
                seed: 5,
            },
        )
        .unwrap();
        assert_eq!(clean[0].times, target.times);
        let mut residuals = Vec::new();
        for k in 0..target.times.len() {
            // As many markers as the real frame shows (at most one per site).
            let shown = clean[0].markers[k].len();
            assert!(
                shown >= 1 && shown <= target.markers[k].len().min(target.initial_markers.len())
            );
            assert_eq!(noisy[0].markers[k].len(), shown);
            for (a, b) in clean[0].markers[k].iter().zip(&noisy[0].markers[k]) {
                residuals.extend((0..3).map(|i| b[i] - a[i]));
            }
        }
        let n = residuals.len() as f64;
        let std = (residuals.iter().map(|r| r * r).sum::<f64>() / n).sqrt();
        assert!(
            (std - 1e-3).abs() < 0.1e-3,
            "noise std {std} over {n} values"
        );
        // Without noise the truth reproduces its own recording exactly.
        let again = rollout(&model, &clean, &[truth], &mut ()).unwrap();
        assert!(again[0][0].loss.mean_object_sq() < 1e-20);
        // Deterministic for a seed.
        let noisy_again = synthetic_targets(
            &model,
            targets,
            &truth,
            Observation {
                noise_std_m: 1e-3,
                seed: 5,
            },
        )
        .unwrap();
        assert_eq!(noisy_again[0].markers, noisy[0].markers);
    }
}
