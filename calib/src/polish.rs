//! Polishing a mode: Levenberg–Marquardt steps on the labelled likelihood, with the residuals'
//! Jacobian of [`crate::fisher`] (all `1 + d` finite differences in one batched rollout) and every
//! trial damping of a step in one more rollout.
//!
//! Why: the likelihood is a sum of squared residuals over a few thousand coordinates, and its
//! sloppy directions (Gutenkunst et al. 2007) make a population search crawl: CMA-ES on ten
//! parameters learns their conditioning over hundreds of generations. The Gauss–Newton curvature
//! `JᵀJ` has it at once, so from a point in the right basin a few steps reach the noise floor.
//! Only a step that raises the log-likelihood is taken; the search stops when none does.

use nalgebra::{DMatrix, DVector};
use serde::Serialize;

use rlpkg_replay::{Likelihood, LikelihoodSettings, ReplayError, RolloutOutcome};

use crate::fisher::fisher_information;
use crate::objective::SimObjective;
use crate::space::ParamSpace;

/// Finite-difference step (unit cube) of the polishing Jacobian: far below the search's last
/// step sizes, and above the simulator's single-precision noise on a converged film solve.
pub const POLISH_STEP: f64 = 1e-4;

/// The dampings tried with each Jacobian, relative to the curvature's diagonal.
const DAMPINGS: [f64; 6] = [1e-4, 1e-3, 1e-2, 1e-1, 1.0, 10.0];

/// The result of a polish.
#[derive(Debug, Clone, Serialize)]
pub struct Polished {
    /// The best point (SI values, search order).
    pub point: Vec<f64>,
    /// Its log-likelihood.
    pub log_likelihood: f64,
    /// Steps taken.
    pub steps: usize,
    /// Candidates simulated.
    pub evaluations: usize,
    /// The best point's outcome on every target.
    #[serde(skip)]
    pub outcome: Vec<RolloutOutcome>,
}

/// Up to `iterations` Levenberg–Marquardt steps from `start` (SI values) on `objective`'s
/// likelihood, each step's dampings tried in one rollout.
pub fn polish(
    objective: &mut SimObjective,
    space: &ParamSpace,
    likelihood: &LikelihoodSettings,
    start: &[f64],
    iterations: usize,
) -> Result<Polished, ReplayError> {
    let counts = Likelihood::new(objective.targets(), likelihood);
    let mut outcome = objective.rollouts(&[start.to_vec()])?.remove(0);
    let mut best = Polished {
        point: start.to_vec(),
        log_likelihood: counts.log_likelihood(&outcome),
        steps: 0,
        evaluations: 1,
        outcome: Vec::new(),
    };
    for _ in 0..iterations {
        let linear = fisher_information(objective, space, &best.point, likelihood, POLISH_STEP)?;
        best.evaluations += 1 + space.dim();
        let unit = space.to_unit(&best.point);
        let trials: Vec<Vec<f64>> = DAMPINGS
            .iter()
            .filter_map(|&damping| step(&linear.information, &linear.gradient, damping))
            .map(|delta| {
                let moved: Vec<f64> = unit
                    .iter()
                    .zip(&delta)
                    .map(|(u, d)| (u + d).clamp(0.0, 1.0))
                    .collect();
                space.from_unit(&moved)
            })
            .collect();
        if trials.is_empty() {
            break;
        }
        let outcomes = objective.rollouts(&trials)?;
        best.evaluations += trials.len();
        let scored = trials
            .into_iter()
            .zip(outcomes)
            .map(|(point, o)| (counts.log_likelihood(&o), point, o))
            .filter(|(ll, _, _)| ll.is_finite())
            .max_by(|a, b| a.0.total_cmp(&b.0));
        match scored {
            Some((ll, point, o)) if ll > best.log_likelihood => {
                best.log_likelihood = ll;
                best.point = point;
                best.steps += 1;
                outcome = o;
            }
            _ => break,
        }
    }
    best.outcome = outcome;
    Ok(best)
}

/// The ascent step `(F + λ diag F)⁻¹ g`, or `None` when the damped system is singular.
fn step(information: &DMatrix<f64>, gradient: &[f64], damping: f64) -> Option<Vec<f64>> {
    let d = gradient.len();
    let mut system = information.clone();
    for i in 0..d {
        system[(i, i)] += damping * information[(i, i)].max(1e-12);
    }
    let delta = system
        .cholesky()?
        .solve(&DVector::from_column_slice(gradient));
    delta
        .iter()
        .all(|v| v.is_finite())
        .then(|| delta.iter().copied().collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_damped_step_solves_the_gauss_newton_system() {
        // F = diag(4, 1), g = (2, 1): the undamped step is (0.5, 1); damping shortens it.
        let f = DMatrix::from_diagonal(&DVector::from_vec(vec![4.0, 1.0]));
        let undamped = step(&f, &[2.0, 1.0], 0.0).unwrap();
        assert!((undamped[0] - 0.5).abs() < 1e-12 && (undamped[1] - 1.0).abs() < 1e-12);
        let damped = step(&f, &[2.0, 1.0], 1.0).unwrap();
        assert!((damped[0] - 0.25).abs() < 1e-12 && (damped[1] - 0.5).abs() < 1e-12);
        assert!(step(&DMatrix::zeros(2, 2), &[1.0, 1.0], 0.0).is_none());
    }
}
