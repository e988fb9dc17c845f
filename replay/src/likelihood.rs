//! The labelled, phase-balanced log-likelihood of a candidate given the recordings.
//!
//! The residuals are the labelled site errors of every marker whose site is known and the object's
//! position error, each phase of the motion weighted to count the same ([`crate::loss`]'s labelled
//! kind). Model: every residual coordinate is Gaussian with a variance of its own for the package
//! markers (`σ_p²`) and for the object (`σ_o²`), both unknown, with Jeffreys' prior `1/σ²`.
//! Integrating them out gives
//!
//! `ln L(θ) = −(n_p / 2) · ln S_p(θ) − (n_o / 2) · ln S_o(θ) + const`
//!
//! where `S_p`, `S_o` are the phase-balanced mean squared errors (mean over recordings) and `n_p`,
//! `n_o` the number of independent residual coordinates. The noise scales are thus estimated from
//! the data (at every θ) rather than chosen: a fit twice as good anywhere is worth the same.
//!
//! Successive frames at 240 per second are not independent: the model's error is smooth in time.
//! Each residual's count is divided by the frames in [`LikelihoodSettings::decorrelation_s`] (an
//! assumption stated in the calibration config; longer is more cautious: wider posteriors).
//!
//! **Replicas.** A film solved to convergence is multistable: near the edge between two outcomes
//! (it settles into one fold or another) a change of a part in a million in any value moves the
//! replay by centimetres, so one replay's likelihood is a function of the values' last bits, not of
//! the material. With [`LikelihoodSettings::replicas`] `R > 1` every candidate is replayed `R`
//! times, replica `r > 0` with each value scaled by `1 + replica_jitter · u` (`u` uniform in
//! `[−1, 1]`, a fixed stream per replica), and the likelihood is the mean of the replicas'
//! likelihoods: a Monte Carlo estimate of the likelihood marginalised over perturbations nothing
//! measures (the "pseudo-marginal" likelihood), which is a function of the material.

use serde::{Deserialize, Serialize};

use crate::rollout::RolloutOutcome;
use crate::target::Target;

/// Settings of the likelihood.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LikelihoodSettings {
    /// Time (s) over which residuals are taken as one independent observation (assumption).
    pub decorrelation_s: f64,
    /// Replays of each candidate (module docs, "Replicas"); 1: the candidate's own replay only.
    #[serde(default = "one")]
    pub replicas: usize,
    /// Relative perturbation of every value in the replicas after the first (assumption: far
    /// below anything a calibration could resolve, above single precision's resolution).
    #[serde(default = "default_replica_jitter")]
    pub replica_jitter: f64,
}

fn one() -> usize {
    1
}

fn default_replica_jitter() -> f64 {
    1e-6
}

impl Default for LikelihoodSettings {
    fn default() -> Self {
        Self {
            decorrelation_s: 0.1,
            replicas: 1,
            replica_jitter: default_replica_jitter(),
        }
    }
}

impl LikelihoodSettings {
    /// How many replays of each candidate the likelihood averages, as a sentence.
    pub fn replicas_text(&self) -> String {
        match self.replicas {
            1 => "likelihood of one replay per candidate".to_string(),
            r => format!(
                "likelihood averaged over {r} replays per candidate (values x (1 +- {:.0e}) after the first)",
                self.replica_jitter
            ),
        }
    }
}

/// The mean of likelihoods given by their logarithms, as a logarithm (`−∞` when every one is).
pub fn log_mean_exp(log_values: &[f64]) -> f64 {
    let top = log_values.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    if top == f64::NEG_INFINITY || log_values.is_empty() {
        return f64::NEG_INFINITY;
    }
    let sum: f64 = log_values.iter().map(|l| (l - top).exp()).sum();
    top + (sum / log_values.len() as f64).ln()
}

/// The log-likelihood on a fixed set of recordings.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Likelihood {
    /// Independent residual coordinates of the package markers.
    pub package_count: f64,
    /// Independent residual coordinates of the object.
    pub object_count: f64,
    /// Replays per candidate ([`LikelihoodSettings::replicas`]).
    pub replicas: usize,
}

impl Likelihood {
    /// The counts of `targets` (every compared frame and labelled marker of every recording).
    pub fn new(targets: &[Target], settings: &LikelihoodSettings) -> Self {
        let mut package_count = 0.0;
        let mut object_count = 0.0;
        for target in targets {
            let frames = target.times.len();
            let per_observation = (settings.decorrelation_s * target.frame_rate()).max(1.0);
            let labelled: usize = target
                .marker_sites
                .iter()
                .map(|f| f.iter().flatten().count())
                .sum();
            package_count += 3.0 * labelled as f64 / per_observation;
            object_count += 3.0 * frames as f64 / per_observation;
        }
        Self {
            package_count,
            object_count,
            replicas: settings.replicas.max(1),
        }
    }

    /// `ln L` of one candidate from its outcomes on every target (up to a constant); `−∞` when a
    /// rollout diverged or a term cannot be computed. With replicas, `outcomes` holds each
    /// replica's outcomes on every target in turn, and a diverged replica has zero likelihood.
    pub fn log_likelihood(&self, outcomes: &[RolloutOutcome]) -> f64 {
        if self.replicas > 1 && !outcomes.is_empty() && outcomes.len().is_multiple_of(self.replicas)
        {
            let per_replica = outcomes.len() / self.replicas;
            let logs: Vec<f64> = outcomes
                .chunks(per_replica)
                .map(|replica| self.of_one_replay(replica))
                .collect();
            return log_mean_exp(&logs);
        }
        self.of_one_replay(outcomes)
    }

    fn of_one_replay(&self, outcomes: &[RolloutOutcome]) -> f64 {
        if outcomes.is_empty() || outcomes.iter().any(|o| o.diverged.is_some()) {
            return f64::NEG_INFINITY;
        }
        let n = outcomes.len() as f64;
        let package = outcomes
            .iter()
            .map(|o| o.loss.balanced_site_sq())
            .sum::<f64>()
            / n;
        let object = outcomes
            .iter()
            .map(|o| o.loss.balanced_object_sq())
            .sum::<f64>()
            / n;
        self.from_errors(package, object)
    }

    /// `ln L` from the phase-balanced mean squared errors of package markers and object (m²).
    pub fn from_errors(&self, package_sq_m2: f64, object_sq_m2: f64) -> f64 {
        let term = |count: f64, error: f64| {
            if count == 0.0 {
                0.0
            } else if error.is_finite() && error > 0.0 {
                -0.5 * count * error.ln()
            } else {
                f64::NEG_INFINITY
            }
        };
        let value = term(self.package_count, package_sq_m2) + term(self.object_count, object_sq_m2);
        if value.is_nan() {
            f64::NEG_INFINITY
        } else {
            value
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::Arc;

    use rlpkg_sim::Model;

    use crate::rollout::{rollout, set_param, Candidate};
    use crate::synthetic::{synthetic_targets, Observation};

    #[test]
    fn replicas_are_described_with_their_jitter() {
        let one = LikelihoodSettings::default();
        assert_eq!(
            one.replicas_text(),
            "likelihood of one replay per candidate"
        );
        let three = LikelihoodSettings {
            replicas: 3,
            replica_jitter: 1e-6,
            ..one
        };
        assert_eq!(
            three.replicas_text(),
            "likelihood averaged over 3 replays per candidate (values x (1 +- 1e-6) after the first)"
        );
    }
    use crate::{load_scene, Target};

    #[test]
    fn replicas_average_likelihoods_not_their_logarithms() {
        let (a, b) = (-2.0f64, -5.0f64);
        let mean = ((a.exp() + b.exp()) / 2.0).ln();
        assert!((log_mean_exp(&[a, b]) - mean).abs() < 1e-12);
        // Far apart the mean is the larger one's, less ln 2, without overflow.
        assert!((log_mean_exp(&[-1.0e4, -3.0e4]) - (-1.0e4 - 2f64.ln())).abs() < 1e-9);
        assert_eq!(log_mean_exp(&[f64::NEG_INFINITY, -1.0]), -1.0 - 2f64.ln());
        assert_eq!(log_mean_exp(&[f64::NEG_INFINITY; 2]), f64::NEG_INFINITY);
    }

    #[test]
    fn on_a_tiny_scene_the_likelihood_is_highest_at_the_truth() {
        // Synthetic recordings of a 6 x 7 package made with known parameters, with the real
        // occlusion and 0.3 mm of marker noise: moving any parameter away lowers the likelihood.
        let mut scene = load_scene("reference", Some(0), None).unwrap();
        scene.cups.rest_time_s = 0.1;
        scene.health.object_outside = false;
        let model = Arc::new(Model::new(&scene).unwrap());
        let recorded =
            Target::new(&crate::test_support::recorded("HHLHL"), Some(0.4), false).unwrap();
        let truth = Candidate::of_scene(&scene);
        let observation = Observation {
            noise_std_m: 3e-4,
            seed: 1,
        };
        let targets =
            synthetic_targets(&model, std::slice::from_ref(&recorded), &truth, observation)
                .unwrap();
        assert!(targets[0].labelled_share() == 1.0);
        let likelihood = Likelihood::new(&targets, &LikelihoodSettings::default());
        assert!(likelihood.package_count > likelihood.object_count);
        let mut candidates = vec![truth];
        for (name, value) in [
            ("k_tri_e", f64::from(truth.params.k_tri_e) * 3.0),
            ("k_tri_e", f64::from(truth.params.k_tri_e) / 3.0),
            ("k_spr_e", f64::from(truth.params.k_spr_e) * 3.0),
            ("disc_mass_scale", f64::from(truth.disc_mass_scale) * 1.5),
        ] {
            let mut c = truth;
            set_param(&mut c, name, value).unwrap();
            candidates.push(c);
        }
        let outcomes = rollout(&model, &targets, &candidates, &mut ()).unwrap();
        let ll: Vec<f64> = outcomes
            .iter()
            .map(|o| likelihood.log_likelihood(o))
            .collect();
        for (i, value) in ll.iter().enumerate().skip(1) {
            assert!(*value < ll[0], "candidate {i}: {value} vs truth {}", ll[0]);
        }
        // At the truth the site error is the noise: 3 coordinates of (0.3 mm)².
        let site = outcomes[0][0].loss.balanced_site_sq();
        assert!((site / (3.0 * 9e-8) - 1.0).abs() < 0.2, "{site}");
    }

    #[test]
    fn a_fit_twice_as_good_gains_the_same_whatever_the_scale() {
        let l = Likelihood {
            package_count: 300.0,
            object_count: 30.0,
            replicas: 1,
        };
        let gain_at = |e: f64| l.from_errors(e / 2.0, 1e-4) - l.from_errors(e, 1e-4);
        assert!((gain_at(1e-2) - gain_at(1e-6)).abs() < 1e-9);
        assert!((gain_at(1e-2) - 150.0 * 2f64.ln()).abs() < 1e-9);
        assert_eq!(l.from_errors(f64::NAN, 1e-4), f64::NEG_INFINITY);
        assert_eq!(l.from_errors(1e-3, f64::INFINITY), f64::NEG_INFINITY);
    }
}
