//! Parameter recovery: does the calibration, with its posterior, find parameters it is given?
//!
//! For each of a few known parameter sets ("truths", drawn from the middle of the search box), the
//! simulator makes synthetic recordings of the real ones ([`rlpkg_replay::synthetic`]: the real
//! placement, tool motion, occlusion pattern and marker noise level), the same Bayesian
//! optimisation calibrates them back from scratch (the truth is not a seed point), and the
//! posterior of its evaluations ([`crate::posterior`]) is compared with the truth: the relative
//! error of the median and whether the 90 % interval covers the truth, for identified parameters.
//! A parameter the posterior calls not identified is reported as such, never with a value.

use std::path::Path;
use std::sync::Arc;

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rlpkg_mocap::Dataset;
use rlpkg_replay::loss::LossWeights;
use rlpkg_replay::synthetic::{marker_noise_std, synthetic_targets, Observation};
use rlpkg_replay::{ReplayError, Target};
use rlpkg_sim::{Model, SceneConfig};

use crate::bo::BoSettings;
use crate::driver::{self, DriverError, Plan};
use crate::objective::SimObjective;
use crate::posterior::{self, PosteriorError, PosteriorSettings, PosteriorSummary};
use crate::space::ParamSpace;

/// Errors of a recovery run.
#[derive(Debug, thiserror::Error)]
pub enum RecoveryError {
    /// The synthetic recordings or the objective could not be set up.
    #[error(transparent)]
    Replay(#[from] ReplayError),
    /// The calibration failed.
    #[error(transparent)]
    Driver(#[from] DriverError),
    /// The posterior failed.
    #[error(transparent)]
    Posterior(#[from] PosteriorError),
    /// The sampled posterior failed.
    #[error(transparent)]
    Sampled(#[from] crate::sampled_posterior::SampledPosteriorError),
}

/// Share of each unit-cube side, centred, that truths are drawn from: away from the bounds, where
/// a posterior interval is cut by the box and coverage says little.
const TRUTH_SPAN: f64 = 0.6;

/// How a recovery run calibrates and observes.
#[derive(Debug, Clone)]
pub struct RecoverySettings {
    /// The calibration's optimiser settings.
    pub optimiser: BoSettings,
    /// Batches after the initial design.
    pub iterations: usize,
    /// The calibration's loss weights.
    pub weights: LossWeights,
    /// Marker and object noise of the synthetic recordings (m, per coordinate).
    pub noise_std_m: f64,
    /// The posterior's settings.
    pub posterior: PosteriorSettings,
    /// Seed of the truths and the noise.
    pub seed: u64,
}

/// How one parameter of one truth was recovered.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct ParameterRecovery {
    /// Parameter name.
    pub name: String,
    /// The true value (SI).
    pub truth: f64,
    /// Whether the posterior identifies the parameter ([`posterior::IDENTIFIED_RULE`]).
    pub identified: bool,
    /// `|median − truth| / truth` when identified.
    pub relative_error: Option<f64>,
    /// Whether the 90 % interval covers the truth, when identified.
    pub covered: Option<bool>,
}

/// The recovery of one truth.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct TruthRecovery {
    /// Index of the truth.
    pub truth: usize,
    /// The calibration's best loss on the synthetic recordings.
    pub best_loss: f64,
    /// One entry per parameter, in search order.
    pub parameters: Vec<ParameterRecovery>,
    /// The posterior's full summary.
    pub posterior: PosteriorSummary,
}

/// A recovery's recordings: `ids` of `dataset` prepared for replay on `scene` (their first
/// `max_seconds`), and the level of their marker noise the synthetic ones get: the median over
/// them of [`marker_noise_std`] (`None` when none is long enough to estimate it).
pub fn recordings(
    dataset: &Dataset,
    ids: &[String],
    scene: &SceneConfig,
    max_seconds: Option<f64>,
) -> Result<(Vec<Target>, Option<f64>), ReplayError> {
    let targets = ids
        .iter()
        .map(|id| {
            let trajectory = dataset.load(id)?;
            Target::new(&trajectory, max_seconds, scene.disc.hold_at_recorded_start)
        })
        .collect::<Result<Vec<_>, ReplayError>>()?;
    let mut noises: Vec<f64> = targets.iter().filter_map(marker_noise_std).collect();
    noises.sort_by(f64::total_cmp);
    let noise_std_m = noises.get(noises.len() / 2).copied();
    Ok((targets, noise_std_m))
}

/// `count` truths drawn uniformly from the central [`TRUTH_SPAN`] of the unit cube (log-uniform
/// for log parameters), in SI units.
pub fn draw_truths(space: &ParamSpace, count: usize, seed: u64) -> Vec<Vec<f64>> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let low = 0.5 - TRUTH_SPAN / 2.0;
    (0..count)
        .map(|_| {
            let unit: Vec<f64> = (0..space.dim())
                .map(|_| low + TRUTH_SPAN * rng.random::<f64>())
                .collect();
            space.from_unit(&unit)
        })
        .collect()
}

/// Recovers `truth` (values of `space`'s parameters on top of `scene`): synthetic recordings of
/// `targets`, a calibration writing its files into `out_dir`, the posterior of its evaluations.
pub fn recover(
    scene: &SceneConfig,
    space: &ParamSpace,
    targets: &[Target],
    truth: &[f64],
    index: usize,
    settings: &RecoverySettings,
    out_dir: &Path,
) -> Result<TruthRecovery, RecoveryError> {
    let names: Vec<String> = space.names().iter().map(|n| n.to_string()).collect();
    let model = Arc::new(Model::new(scene).map_err(ReplayError::from)?);
    let truth_candidate =
        SimObjective::from_targets(scene, names.clone(), targets.to_vec(), settings.weights)?
            .candidate_for(truth);
    let observation = Observation {
        noise_std_m: settings.noise_std_m,
        seed: settings.seed.wrapping_add(index as u64),
    };
    let synthetic = synthetic_targets(&model, targets, &truth_candidate, observation)?;
    let mut objective = SimObjective::from_targets(scene, names, synthetic, settings.weights)?;
    let plan = Plan {
        space: space.clone(),
        settings: settings.optimiser.clone(),
        seed_points: Vec::new(),
        iterations: settings.iterations,
        out_dir: out_dir.to_path_buf(),
    };
    let best = driver::run(&plan, &mut objective, |_| {})?;
    let evaluations = posterior::read_evaluations(&out_dir.join("evaluations.csv"), space)?;
    let result = posterior::infer(space, &evaluations, &settings.posterior)?;
    let parameters = result
        .summary
        .parameters
        .iter()
        .zip(truth)
        .map(|(p, &truth)| {
            let identified = p.identified;
            ParameterRecovery {
                name: p.name.clone(),
                truth,
                identified,
                relative_error: identified.then(|| (p.median - truth).abs() / truth.abs()),
                covered: identified.then(|| p.interval[0] <= truth && truth <= p.interval[1]),
            }
        })
        .collect();
    Ok(TruthRecovery {
        truth: index,
        best_loss: best.fit.loss,
        parameters,
        posterior: result.summary,
    })
}

/// How a sampled posterior ([`crate::sampled_posterior`]) recovered one parameter of one truth.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct SampledParameterRecovery {
    /// Parameter name.
    pub name: String,
    /// The true value (SI).
    pub truth: f64,
    /// Posterior median.
    pub median: f64,
    /// The 90 % interval's share of the box (decades for log parameters).
    pub box_share: f64,
    /// Whether the 90 % interval covers the truth.
    pub covered: bool,
    /// Whether the Fisher information at the best draw calls it identifiable
    /// ([`crate::fisher::IDENTIFIABLE_SHARE`]).
    pub identifiable: bool,
}

/// The sampled recovery of one truth.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct SampledTruthRecovery {
    /// Index of the truth.
    pub truth: usize,
    /// The labelled loss of the truth itself on its synthetic recordings (its noise floor).
    pub truth_loss: f64,
    /// The loss of the truth with every parameter scaled by `1 + NUDGE` ([`NUDGE`]): how rough
    /// the objective is where it should be smoothest (a smooth loss barely moves).
    pub nudged_truth_loss: f64,
    /// The loss of the best draw found.
    pub best_loss: f64,
    /// Log-likelihood of the truth and of the best draw.
    pub log_likelihoods: [f64; 2],
    /// Simulated candidates.
    pub evaluations: usize,
    /// One entry per parameter, in search order.
    pub parameters: Vec<SampledParameterRecovery>,
    /// Per horizon of the mode search, the truth's log-likelihood beside the search's best: the
    /// first horizon whose best falls short of the truth is where the search left its basin.
    pub horizons: Vec<HorizonCheck>,
}

/// The mode search on one horizon against the truth.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct HorizonCheck {
    /// The horizon (s of trajectory time; `None`: the whole recordings).
    pub horizon_s: Option<f64>,
    /// The truth's log-likelihood on it.
    pub truth_log_likelihood: f64,
    /// The best the search found on it.
    pub best_log_likelihood: f64,
    /// The search's generations on it.
    pub generations: usize,
}

/// The relative change of every parameter at which a recovery probes the truth's loss: a few
/// times single precision's resolution, so the simulator sees another number, and far below any
/// interval a calibration could report.
pub const NUDGE: f64 = 1e-6;

/// Recovers `truth` with a sampled posterior: synthetic recordings of `targets` (noise
/// `noise_std_m`, seed `seed + index`), SMC from the prior with the labelled likelihood, files in
/// `out_dir`; then the truth's own loss and likelihood for comparison.
#[allow(clippy::too_many_arguments)]
pub fn recover_sampled(
    scene: &SceneConfig,
    space: &ParamSpace,
    targets: &[Target],
    truth: &[f64],
    index: usize,
    smc: &crate::smc::SmcSettings,
    likelihood: &rlpkg_replay::LikelihoodSettings,
    weights: LossWeights,
    noise_std_m: f64,
    seed: u64,
    out_dir: &Path,
) -> Result<SampledTruthRecovery, RecoveryError> {
    let names: Vec<String> = space.names().iter().map(|n| n.to_string()).collect();
    let model = Arc::new(Model::new(scene).map_err(ReplayError::from)?);
    // The real recordings with their tracks tied to sites: the synthetic ones hide the sites the
    // real frames do not see.
    let real = SimObjective::from_targets(scene, names.clone(), targets.to_vec(), weights)?
        .with_replicas(likelihood);
    // With replicas the recordings are made by a replica of its own, not the truth's exact
    // values: near an edge between two outcomes those are matched by their own bits only, and a
    // real film shows what its neighbourhood does ([`rlpkg_replay::likelihood`], "Replicas").
    let recorded = if likelihood.replicas > 1 {
        real.replica_values(truth, likelihood.replicas)
    } else {
        truth.to_vec()
    };
    let truth_candidate = real.candidate_for(&recorded);
    let observation = Observation {
        noise_std_m,
        seed: seed.wrapping_add(index as u64),
    };
    let synthetic = synthetic_targets(&model, real.targets(), &truth_candidate, observation)?;
    let mut objective =
        SimObjective::from_targets(scene, names, synthetic, weights)?.with_replicas(likelihood);
    let settings = crate::smc::SmcSettings {
        seed: smc.seed.wrapping_add(index as u64),
        ..*smc
    };
    let posterior = crate::sampled_posterior::sample_posterior(
        &mut objective,
        space,
        &settings,
        likelihood,
        out_dir,
        |_, _| {},
    )?;
    let nudged: Vec<f64> = truth.iter().map(|v| v * (1.0 + NUDGE)).collect();
    let at_truth = objective.rollouts(&[truth.to_vec(), nudged])?;
    let counts = rlpkg_replay::Likelihood::new(objective.targets(), likelihood);
    let truth_loss = crate::objective::summarise(&at_truth[0], &weights).loss;
    let mut horizons: Vec<HorizonCheck> = Vec::new();
    for g in &posterior.search_log {
        match horizons.last_mut() {
            Some(last) if last.horizon_s == g.horizon_s => {
                last.best_log_likelihood = last.best_log_likelihood.max(g.best_log_likelihood);
                last.generations += 1;
            }
            _ => horizons.push(HorizonCheck {
                horizon_s: g.horizon_s,
                truth_log_likelihood: f64::NAN,
                best_log_likelihood: g.best_log_likelihood,
                generations: 1,
            }),
        }
    }
    for check in &mut horizons {
        check.truth_log_likelihood = match check.horizon_s {
            None => counts.log_likelihood(&at_truth[0]),
            Some(h) => {
                let outcome = objective
                    .rollouts_within(h, &[truth.to_vec()])
                    .expect("searched on")?
                    .remove(0);
                let short = objective.targets_within(h).expect("rolled out above");
                rlpkg_replay::Likelihood::new(short, likelihood).log_likelihood(&outcome)
            }
        };
    }
    let parameters = posterior
        .parameters
        .iter()
        .zip(&posterior.fisher.parameters)
        .zip(truth)
        .map(|((p, f), &truth)| SampledParameterRecovery {
            name: p.name.clone(),
            truth,
            median: p.median,
            box_share: p.box_share,
            covered: p.lower_5 <= truth && truth <= p.upper_95,
            identifiable: f.identifiable,
        })
        .collect();
    Ok(SampledTruthRecovery {
        truth: index,
        truth_loss,
        nudged_truth_loss: crate::objective::summarise(&at_truth[1], &weights).loss,
        best_loss: posterior.best.fit.loss,
        log_likelihoods: [
            counts.log_likelihood(&at_truth[0]),
            posterior.best_log_likelihood,
        ],
        evaluations: posterior.evaluations + posterior.polished_evaluations,
        parameters,
        horizons,
    })
}

/// The sampled recovery table: per truth its loss and the best loss found (with replicas, means
/// over the replicas) and the log-likelihood the best falls short of the truth's (`ln L` gap; at
/// most 0 when the search reached the truth's), then per parameter the interval's median share of
/// the box, its coverage of the truths and how often the Fisher analysis called it identifiable.
pub fn sampled_recovery_table(recoveries: &[SampledTruthRecovery]) -> String {
    let mut text = format!(
        "{:<6} {:>12} {:>12} {:>12} {:>7} {:>11} {:>12}
",
        "truth", "truth loss", "nudged loss", "best loss", "ratio", "ln L gap", "evaluations"
    );
    for r in recoveries {
        text.push_str(&format!(
            "{:<6} {:>12.4e} {:>12.4e} {:>12.4e} {:>7.3} {:>11.1} {:>12}
",
            r.truth,
            r.truth_loss,
            r.nudged_truth_loss,
            r.best_loss,
            r.best_loss / r.truth_loss,
            r.log_likelihoods[0] - r.log_likelihoods[1],
            r.evaluations
        ));
    }
    let Some(first) = recoveries.first() else {
        return text;
    };
    text.push_str(&format!(
        "
{:<16} {:>16} {:>9} {:>13} {:>22}
",
        "parameter", "median box share", "covered", "identifiable", "covered if identifiable"
    ));
    for (i, p) in first.parameters.iter().enumerate() {
        let mut shares: Vec<f64> = recoveries
            .iter()
            .map(|r| r.parameters[i].box_share)
            .collect();
        shares.sort_by(f64::total_cmp);
        let covered = recoveries
            .iter()
            .filter(|r| r.parameters[i].covered)
            .count();
        let identifiable: Vec<&SampledParameterRecovery> = recoveries
            .iter()
            .map(|r| &r.parameters[i])
            .filter(|p| p.identifiable)
            .collect();
        let covered_identifiable = identifiable.iter().filter(|p| p.covered).count();
        text.push_str(&format!(
            "{:<16} {:>14.1} % {:>6}/{:<2} {:>10}/{:<2} {:>19}/{:<2}
",
            p.name,
            100.0 * shares[shares.len() / 2],
            covered,
            recoveries.len(),
            identifiable.len(),
            recoveries.len(),
            covered_identifiable,
            identifiable.len()
        ));
    }
    text
}

/// The recovery table: one row per truth and parameter, then per parameter how often it was
/// identified, the median relative error and the coverage over the truths where it was.
pub fn recovery_table(recoveries: &[TruthRecovery]) -> String {
    let mut text = format!(
        "{:<6} {:<16} {:>11} {:>11}  {:>9}  {:<8} identified\n",
        "truth", "parameter", "true value", "median", "rel error", "covered"
    );
    for r in recoveries {
        for (p, summary) in r.parameters.iter().zip(&r.posterior.parameters) {
            let (median, error, covered) = match (p.relative_error, p.covered) {
                (Some(error), Some(covered)) => (
                    format!("{:.3e}", summary.median),
                    format!("{:.1} %", 100.0 * error),
                    if covered { "yes" } else { "no" }.to_string(),
                ),
                _ => ("-".into(), "-".into(), "-".into()),
            };
            text.push_str(&format!(
                "{:<6} {:<16} {:>11.3e} {:>11}  {:>9}  {:<8} {}\n",
                r.truth,
                p.name,
                p.truth,
                median,
                error,
                covered,
                if p.identified {
                    "yes"
                } else {
                    "no (not determined by the recordings)"
                }
            ));
        }
    }
    text.push_str(&format!(
        "\n{:<16} {:>10}  {:>16}  {:>8}\n",
        "parameter", "identified", "median rel error", "covered"
    ));
    let Some(first) = recoveries.first() else {
        return text;
    };
    for (i, p) in first.parameters.iter().enumerate() {
        let identified: Vec<&ParameterRecovery> = recoveries
            .iter()
            .map(|r| &r.parameters[i])
            .filter(|p| p.identified)
            .collect();
        let mut errors: Vec<f64> = identified.iter().filter_map(|p| p.relative_error).collect();
        errors.sort_by(f64::total_cmp);
        let median_error = if errors.is_empty() {
            "-".to_string()
        } else {
            format!("{:.1} %", 100.0 * errors[errors.len() / 2])
        };
        let covered = identified
            .iter()
            .filter(|p| p.covered == Some(true))
            .count();
        text.push_str(&format!(
            "{:<16} {:>7}/{:<2}  {:>16}  {:>5}/{:<2}\n",
            p.name,
            identified.len(),
            recoveries.len(),
            median_error,
            covered,
            identified.len()
        ));
    }
    text
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::space::ParamSpec;
    use rlpkg_replay::load_scene;

    #[test]
    fn recordings_carry_their_median_noise_and_a_short_one_none() {
        let root =
            std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../data/deformable-sim-real");
        let dataset = Dataset::open(&root).unwrap();
        let scene = load_scene("reference", Some(0), None).unwrap();
        let ids: Vec<String> = ["HHHHH", "HHLHL", "HHHHM"].map(String::from).to_vec();
        let (targets, noise) = recordings(&dataset, &ids, &scene, Some(1.0)).unwrap();
        assert_eq!(targets.len(), 3);
        let mut each: Vec<f64> = targets
            .iter()
            .map(|t| marker_noise_std(t).unwrap())
            .collect();
        each.sort_by(f64::total_cmp);
        assert_eq!(noise, Some(each[1]));
        let (_, short) = recordings(&dataset, &ids[..1], &scene, Some(0.005)).unwrap();
        assert_eq!(
            short, None,
            "two frames give no second differences to speak of"
        );
        let missing = recordings(&dataset, &["NOPE".to_string()], &scene, None);
        assert!(missing.is_err());
    }

    fn recorded(id: &str) -> rlpkg_mocap::Trajectory {
        let root =
            std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../data/deformable-sim-real");
        rlpkg_mocap::Dataset::open(&root).unwrap().load(id).unwrap()
    }

    /// Coarse 6 x 7 grid, short rest, 0.2 s of the recorded HHHHH tool motion (seconds of CPU): the
    /// scene, a box of the membrane's stiffness and of a parameter without effect, the recording
    /// and its marker noise.
    fn two_parameter_case() -> (SceneConfig, ParamSpace, Target, f64) {
        let mut scene = load_scene("reference", Some(0), None).unwrap();
        scene.cups.rest_time_s = 0.1;
        // The disc slips through the 6 x 7 sheet; the check is about the inference.
        scene.health.object_outside = false;
        let space = ParamSpace::new(vec![
            ParamSpec {
                name: "k_tri_e".into(),
                lower: 1.0e3,
                upper: 1.0e6,
                log: true,
            },
            // No effect on this scene: WITHOUT_EFFECT below.
            ParamSpec {
                name: WITHOUT_EFFECT.into(),
                lower: 1.0e-3,
                upper: 1.0e1,
                log: true,
            },
        ])
        .unwrap();
        let real = Target::new(&recorded("HHHHH"), Some(0.2), false).unwrap();
        let noise = rlpkg_replay::synthetic::marker_noise_std(&real).unwrap();
        (scene, space, real, noise)
    }

    #[test]
    fn recovers_an_identified_parameter_and_reports_a_parameter_without_effect_as_not_identified() {
        let (scene, space, real, noise) = two_parameter_case();
        let settings = RecoverySettings {
            optimiser: BoSettings {
                initial_points: 8,
                batch_size: 4,
                random_candidates: 300,
                seed: 1,
                ..BoSettings::default()
            },
            iterations: 4,
            weights: LossWeights::default(),
            noise_std_m: noise,
            posterior: PosteriorSettings {
                draws: 2000,
                burn_in: 300,
                thin: 5,
                profile_draws: 64,
                ..PosteriorSettings::default()
            },
            seed: 3,
        };
        let truth = space.from_unit(&[0.6, 0.4]);
        let dir = tempfile::tempdir().unwrap();
        let r = recover(&scene, &space, &[real], &truth, 0, &settings, dir.path()).unwrap();
        let [stiffness, inert] = [&r.parameters[0], &r.parameters[1]];
        assert!(stiffness.identified, "{:?}", r.posterior.parameters[0]);
        assert_eq!(
            stiffness.covered,
            Some(true),
            "{:?}",
            r.posterior.parameters[0]
        );
        assert!(!inert.identified, "{:?}", r.posterior.parameters[1]);
        assert_eq!((inert.relative_error, inert.covered), (None, None));
        let table = recovery_table(&[r]);
        assert!(table.contains("not determined"), "{table}");
    }

    /// A parameter with no effect on the 6 x 7 reference scene over 0.2 s; checked here, so the
    /// recovery test above does not rest on an assumption.
    const WITHOUT_EFFECT: &str = "k_cup_d";

    #[test]
    fn the_parameter_without_effect_has_none() {
        let mut scene = load_scene("reference", Some(0), None).unwrap();
        scene.cups.rest_time_s = 0.1;
        scene.health.object_outside = false;
        let real = Target::new(&recorded("HHHHH"), Some(0.2), false).unwrap();
        let objective = SimObjective::from_targets(
            &scene,
            vec![WITHOUT_EFFECT.into()],
            vec![real.clone()],
            LossWeights::default(),
        )
        .unwrap();
        let model = Arc::new(Model::new(&scene).unwrap());
        let candidates = [
            objective.candidate_for(&[1e-3]),
            objective.candidate_for(&[1e1]),
        ];
        let out = rlpkg_replay::rollout(&model, &[real], &candidates, &mut ()).unwrap();
        assert_eq!(out[0][0].loss.frames, out[1][0].loss.frames);
    }

    #[test]
    fn a_sampled_posterior_covers_the_truth_of_an_identifiable_parameter() {
        let (scene, space, real, noise) = two_parameter_case();
        let smc = crate::smc::SmcSettings {
            particles: 48,
            ess_fraction: 0.5,
            moves: 2,
            final_moves: 2,
            max_stages: 100,
            seed: 1,
            mode_search: None,
            polish_iterations: 0,
            chaos_replays: 0,
            chaos_points: 1,
            prior_share: 0.0,
        };
        let weights = LossWeights {
            object: 1.0,
            package: 1.0,
            kind: rlpkg_replay::loss::LossKind::Labelled,
        };
        let truth = space.from_unit(&[0.6, 0.4]);
        let dir = tempfile::tempdir().unwrap();
        let r = recover_sampled(
            &scene,
            &space,
            &[real],
            &truth,
            0,
            &smc,
            &rlpkg_replay::LikelihoodSettings::default(),
            weights,
            noise,
            3,
            dir.path(),
        )
        .unwrap();
        let [stiffness, inert] = [&r.parameters[0], &r.parameters[1]];
        assert!(stiffness.identifiable && stiffness.covered, "{r:?}");
        assert!(stiffness.box_share < 0.3, "{r:?}");
        // No effect: the posterior stays as wide as the prior, and the Fisher analysis says so.
        assert!(!inert.identifiable && inert.box_share > 0.7, "{r:?}");
        assert!(r.best_loss <= 1.2 * r.truth_loss, "{r:?}");
        assert!(r.nudged_truth_loss.is_finite(), "{r:?}");
        assert!(sampled_recovery_table(&[r]).contains("k_tri_e"));
    }

    #[test]
    fn truths_lie_in_the_middle_of_the_box_and_depend_on_the_seed() {
        let space = ParamSpace::new(vec![ParamSpec {
            name: "k_tri_e".into(),
            lower: 1.0,
            upper: 1.0e4,
            log: true,
        }])
        .unwrap();
        let truths = draw_truths(&space, 50, 7);
        assert!(truths
            .iter()
            .all(|t| (10f64.powf(0.8)..=10f64.powf(3.2)).contains(&t[0])));
        assert_eq!(truths, draw_truths(&space, 50, 7));
        assert_ne!(truths, draw_truths(&space, 50, 8));
    }
}
