//! Identifiability at a fit: the Fisher information of the labelled likelihood.
//!
//! Which combinations of parameters do the recordings pin down? At a point θ̂ the residuals
//! (each labelled marker against its site, the object against the recorded object) are
//! differentiated by finite differences, all `1 + d` candidates in one batched rollout, giving per
//! residual a Jacobian `J` in the unit cube of the search space (log units for log parameters).
//! With the likelihood of [`rlpkg_replay::likelihood`],
//! `ln L = −(n_p/2) ln S_p − (n_o/2) ln S_o`, its Gauss–Newton information is
//!
//! `F = (n_p / S_p) · Σ w Jᵀ J (package) + (n_o / S_o) · Σ w Jᵀ J (object)`
//!
//! with the same weights `w` that make `S` phase-balanced. The eigenvectors of `F` are the
//! directions in parameter space, their eigenvalues how sharply the recordings see them: a
//! direction of standard deviation `1/√λ` (in units of the box) is pinned when that is small, and
//! sloppy (Gutenkunst et al. 2007) when it is comparable to the box. Per parameter, the Cramér–Rao
//! bound `√(F⁻¹)_ii` (all the others free) gives a 90 % interval of `2 · 1.645 · √(F⁻¹)_ii` of the
//! box; **identifiable** when that is under [`IDENTIFIABLE_SHARE`].

use std::collections::BTreeMap;

use nalgebra::{DMatrix, SymmetricEigen};
use serde::Serialize;

use rlpkg_replay::{FrameObservation, LikelihoodSettings, Observer, ReplayError, Target};

use crate::objective::SimObjective;
use crate::space::ParamSpace;

/// Shortest residual series (frames) whose correlation time is counted.
const MIN_SERIES: usize = 50;

/// Share of the box under which a parameter's 90 % Cramér–Rao interval counts as identifiable.
pub const IDENTIFIABLE_SHARE: f64 = 0.3;

/// One eigen-direction of the information.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Direction {
    /// Eigenvalue (1 / variance along the direction, unit-cube units).
    pub information: f64,
    /// Standard deviation along the direction, as a share of the box.
    pub sd_box: f64,
    /// The unit eigenvector, one component per parameter (search order).
    pub vector: Vec<f64>,
}

/// One parameter's information.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ParameterInformation {
    /// Parameter name.
    pub name: String,
    /// Cramér–Rao standard deviation with every other parameter free (share of the box).
    pub sd_box: f64,
    /// The 90 % interval it implies, as a share of the box (capped at 1).
    pub interval_box: f64,
    /// `interval_box < IDENTIFIABLE_SHARE`.
    pub identifiable: bool,
}

/// The Fisher analysis at one point.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct FisherAnalysis {
    /// The point (SI values by name).
    pub at: BTreeMap<String, f64>,
    /// Finite-difference step in the unit cube.
    pub step: f64,
    /// Eigen-directions, most informative first.
    pub directions: Vec<Direction>,
    /// Per parameter, in the search order.
    pub parameters: Vec<ParameterInformation>,
    /// Compared frames left out because a perturbed rollout diverged before them.
    pub incomplete_frames: usize,
    /// The phase-balanced package and object errors at the point (m²).
    pub errors_m2: [f64; 2],
    /// The integrated autocorrelation time (s) of the markers' residuals at the point: how long
    /// the model's error stays alike, against the likelihood's assumed `decorrelation_s`.
    pub residual_correlation_s: f64,
    /// Gradient of the log-likelihood at the point (unit cube, search order).
    pub gradient: Vec<f64>,
    /// The information matrix itself (unit cube): the Gauss–Newton curvature a local search
    /// steps with.
    #[serde(skip)]
    pub information: DMatrix<f64>,
}

/// Integrated autocorrelation time (in samples) of one series: `1 + 2 Σ ρ_j`, summed while the
/// autocorrelation stays above 0.05 (the noisy tail would only add noise).
fn integrated_autocorrelation(series: &[f64]) -> f64 {
    let n = series.len();
    let mean = series.iter().sum::<f64>() / n as f64;
    let centred: Vec<f64> = series.iter().map(|v| v - mean).collect();
    let variance = centred.iter().map(|v| v * v).sum::<f64>();
    if variance <= 0.0 {
        return 1.0;
    }
    let mut tau = 1.0;
    for lag in 1..n / 2 {
        let rho = centred[..n - lag]
            .iter()
            .zip(&centred[lag..])
            .map(|(a, b)| a * b)
            .sum::<f64>()
            / variance;
        if rho < 0.05 {
            break;
        }
        tau += 2.0 * rho;
    }
    tau
}

/// Collects residuals of every candidate frame by frame and adds each frame's `Jᵀ J` once all
/// candidates have reported it.
struct JacobianObserver<'a> {
    targets: &'a [Target],
    /// Per candidate 1..=d: the step taken in its coordinate (signed, unit cube).
    steps: Vec<f64>,
    /// Frames with labelled markers, per target and phase; frames, per target and phase.
    package_frames: Vec<BTreeMap<rlpkg_replay::Phase, usize>>,
    object_frames: Vec<BTreeMap<rlpkg_replay::Phase, usize>>,
    current: Option<(usize, usize)>,
    residuals: Vec<Option<Vec<f64>>>,
    sums: [f64; 2],
    gram: [DMatrix<f64>; 2],
    /// `Σ w r J` per term (half the gradient of the term's `S`).
    slope: [Vec<f64>; 2],
    incomplete: usize,
    /// The point's residual coordinates per (target, track, axis), frame after frame.
    series: BTreeMap<(usize, u32, usize), Vec<f64>>,
}

impl<'a> JacobianObserver<'a> {
    fn new(targets: &'a [Target], steps: Vec<f64>) -> Self {
        let d = steps.len();
        let mut package_frames = Vec::new();
        let mut object_frames = Vec::new();
        for t in targets {
            let mut package = BTreeMap::new();
            let mut object = BTreeMap::new();
            for k in 0..t.times.len() {
                if t.markers[k].is_empty() {
                    continue;
                }
                *object.entry(t.phases[k]).or_insert(0) += 1;
                if t.marker_sites[k].iter().any(Option::is_some) {
                    *package.entry(t.phases[k]).or_insert(0) += 1;
                }
            }
            package_frames.push(package);
            object_frames.push(object);
        }
        Self {
            targets,
            steps,
            package_frames,
            object_frames,
            current: None,
            residuals: vec![None; d + 1],
            sums: [0.0; 2],
            gram: [DMatrix::zeros(d, d), DMatrix::zeros(d, d)],
            slope: [vec![0.0; d], vec![0.0; d]],
            incomplete: 0,
            series: BTreeMap::new(),
        }
    }

    /// Adds the buffered frame.
    fn flush(&mut self) {
        let Some((t, k)) = self.current.take() else {
            return;
        };
        let residuals = std::mem::replace(&mut self.residuals, vec![None; self.steps.len() + 1]);
        if residuals.iter().any(Option::is_none) {
            self.incomplete += 1;
            return;
        }
        let r: Vec<Vec<f64>> = residuals.into_iter().map(Option::unwrap).collect();
        let target = &self.targets[t];
        let labelled_tracks = target.marker_tracks[k]
            .iter()
            .zip(&target.marker_sites[k])
            .filter(|(_, s)| s.is_some())
            .map(|(t, _)| *t);
        for (m, track) in labelled_tracks.enumerate() {
            for axis in 0..3 {
                self.series
                    .entry((t, track, axis))
                    .or_default()
                    .push(r[0][3 * m + axis]);
            }
        }
        let phase = target.phases[k];
        let n_targets = self.targets.len() as f64;
        let labelled = target.marker_sites[k].iter().flatten().count();
        let d = self.steps.len();
        // Layout of a residual: 3 per labelled marker, then the object's 3.
        let blocks = [
            (0..3 * labelled, labelled),
            (3 * labelled..3 * labelled + 3, 1),
        ];
        for (term, (range, count)) in blocks.into_iter().enumerate() {
            if count == 0 {
                continue;
            }
            let frames = if term == 0 {
                &self.package_frames[t]
            } else {
                &self.object_frames[t]
            };
            let weight =
                1.0 / (n_targets * frames.len() as f64 * frames[&phase] as f64 * count as f64);
            for i in range {
                self.sums[term] += weight * r[0][i] * r[0][i];
                let row: Vec<f64> = (0..d)
                    .map(|c| (r[c + 1][i] - r[0][i]) / self.steps[c])
                    .collect();
                for a in 0..d {
                    self.slope[term][a] += weight * row[a] * r[0][i];
                    for b in 0..d {
                        self.gram[term][(a, b)] += weight * row[a] * row[b];
                    }
                }
            }
        }
    }
}

impl Observer for JacobianObserver<'_> {
    fn frame(&mut self, o: &FrameObservation) {
        if self.current != Some((o.target, o.frame)) {
            self.flush();
            self.current = Some((o.target, o.frame));
        }
        let target = &self.targets[o.target];
        let mut r = Vec::new();
        for (marker, site) in target.markers[o.frame]
            .iter()
            .zip(&target.marker_sites[o.frame])
        {
            if let Some(p) = site.and_then(|s| o.simulated_points.get(s)) {
                r.extend((0..3).map(|a| p[a] - marker[a]));
            }
        }
        let object = &target.object[o.frame];
        r.extend((0..3).map(|a| f64::from(o.disc.position[a]) - object[a]));
        self.residuals[o.candidate] = Some(r);
    }

    fn finish(&mut self, _simulator: &rlpkg_sim::Simulator) {
        self.flush();
    }
}

/// The Fisher analysis of `objective`'s likelihood at `at` (SI values in the space's order), with
/// finite differences of `step` in the unit cube (taken away from the nearer bound).
pub fn fisher_information(
    objective: &mut SimObjective,
    space: &ParamSpace,
    at: &[f64],
    likelihood: &LikelihoodSettings,
    step: f64,
) -> Result<FisherAnalysis, ReplayError> {
    let d = space.dim();
    let base = space.to_unit(at);
    let mut candidates = vec![at.to_vec()];
    let mut steps = Vec::with_capacity(d);
    for i in 0..d {
        let signed = if base[i] < 0.5 { step } else { -step };
        let mut u = base.clone();
        u[i] += signed;
        candidates.push(space.from_unit(&u));
        // The step actually taken, after the map to values and back.
        steps.push(space.to_unit(&candidates[i + 1])[i] - base[i]);
    }
    let counts = rlpkg_replay::Likelihood::new(objective.targets(), likelihood);
    let targets = objective.targets().to_vec();
    let mut observer = JacobianObserver::new(&targets, steps);
    objective.rollouts_observed(&candidates, &mut observer)?;
    let [s_p, s_o] = observer.sums;
    // Length-weighted mean correlation time over the series of at least MIN_SERIES frames.
    let (mut weighted, mut total) = (0.0, 0.0);
    for ((t, _, _), series) in &observer.series {
        let rate = targets[*t].frame_rate();
        if series.len() >= MIN_SERIES {
            weighted += integrated_autocorrelation(series) / rate * series.len() as f64;
            total += series.len() as f64;
        }
    }
    let residual_correlation_s = if total > 0.0 {
        weighted / total
    } else {
        f64::NAN
    };
    let scale = |count: f64, s: f64| if s > 0.0 { count / s } else { 0.0 };
    let information = &observer.gram[0] * scale(counts.package_count, s_p)
        + &observer.gram[1] * scale(counts.object_count, s_o);
    // ∂ ln L = −(n/2) ∂S / S per term, ∂S = 2 Σ w r J.
    let gradient: Vec<f64> = (0..d)
        .map(|a| {
            -scale(counts.package_count, s_p) * observer.slope[0][a]
                - scale(counts.object_count, s_o) * observer.slope[1][a]
        })
        .collect();
    let eigen = SymmetricEigen::new(information.clone());
    let mut order: Vec<usize> = (0..d).collect();
    order.sort_by(|&a, &b| eigen.eigenvalues[b].total_cmp(&eigen.eigenvalues[a]));
    let directions = order
        .iter()
        .map(|&j| {
            let value = eigen.eigenvalues[j].max(0.0);
            let mut vector: Vec<f64> = eigen.eigenvectors.column(j).iter().copied().collect();
            // Sign: largest component positive, so that a printed direction is stable.
            let largest = vector
                .iter()
                .copied()
                .max_by(|a, b| a.abs().total_cmp(&b.abs()))
                .unwrap_or(1.0);
            if largest < 0.0 {
                vector.iter_mut().for_each(|v| *v = -*v);
            }
            Direction {
                information: value,
                sd_box: if value > 0.0 {
                    value.sqrt().recip()
                } else {
                    f64::INFINITY
                },
                vector,
            }
        })
        .collect();
    // The covariance bound from the eigen-decomposition (directions of no information: infinite).
    let mut variance = vec![0.0; d];
    for j in 0..d {
        let value = eigen.eigenvalues[j];
        for (i, v) in variance.iter_mut().enumerate() {
            let component = eigen.eigenvectors[(i, j)];
            *v += if value > 1e-12 {
                component * component / value
            } else if component.abs() > 1e-9 {
                f64::INFINITY
            } else {
                0.0
            };
        }
    }
    let parameters = space
        .specs()
        .iter()
        .zip(variance)
        .map(|(spec, var)| {
            let sd = var.sqrt();
            let interval = (2.0 * 1.645 * sd).min(1.0);
            ParameterInformation {
                name: spec.name.clone(),
                sd_box: sd,
                interval_box: interval,
                identifiable: interval < IDENTIFIABLE_SHARE,
            }
        })
        .collect();
    Ok(FisherAnalysis {
        at: space
            .names()
            .iter()
            .map(|n| n.to_string())
            .zip(at.iter().copied())
            .collect(),
        step,
        directions,
        parameters,
        incomplete_frames: observer.incomplete,
        errors_m2: [s_p, s_o],
        residual_correlation_s,
        gradient,
        information,
    })
}

/// The analysis as text: per parameter its Cramér–Rao interval, then the eigen-directions with
/// their largest components.
pub fn fisher_table(analysis: &FisherAnalysis) -> String {
    let mut text = format!(
        "{:<16} {:>10} {:>14} {:>12}\n",
        "parameter", "sd (box)", "90 % (box)", "identifiable"
    );
    for p in &analysis.parameters {
        text.push_str(&format!(
            "{:<16} {:>10.3e} {:>13.1} % {:>12}\n",
            p.name,
            p.sd_box,
            100.0 * p.interval_box,
            if p.identifiable { "yes" } else { "no" }
        ));
    }
    text.push_str(&format!(
        "residual correlation time at the point: {:.3} s\n",
        analysis.residual_correlation_s
    ));
    text.push_str("eigen-directions (sd as a share of the box; components over 0.3 shown):\n");
    let names: Vec<&str> = analysis
        .parameters
        .iter()
        .map(|p| p.name.as_str())
        .collect();
    for (j, dir) in analysis.directions.iter().enumerate() {
        let parts: Vec<String> = dir
            .vector
            .iter()
            .zip(&names)
            .filter(|(v, _)| v.abs() > 0.3)
            .map(|(v, n)| format!("{v:+.2} {n}"))
            .collect();
        text.push_str(&format!(
            "  {:>2}: sd {:>9.3e}  {}\n",
            j + 1,
            dir.sd_box,
            parts.join(", ")
        ));
    }
    text
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::Arc;

    use rlpkg_replay::loss::{LossKind, LossWeights};
    use rlpkg_replay::synthetic::{synthetic_targets, Observation};
    use rlpkg_replay::{load_scene, rollout, Candidate};
    use rlpkg_sim::Model;

    use crate::space::ParamSpec;

    #[test]
    fn a_parameter_the_recording_sees_is_identified_and_one_it_cannot_is_not() {
        // 0.3 s of a recording on a coarse package: the membrane's stiffness shapes the sag
        // (seen); the cups' damping has no effect on this scene (the recovery tests check that).
        let mut scene = load_scene("reference", Some(0), None).unwrap();
        scene.cups.rest_time_s = 0.1;
        scene.health.object_outside = false;
        let model = Arc::new(Model::new(&scene).unwrap());
        let root =
            std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../data/deformable-sim-real");
        let dataset = rlpkg_mocap::Dataset::open(&root).unwrap();
        let recorded = Target::new(&dataset.load("HHLHL").unwrap(), Some(0.3), false).unwrap();
        let truth = Candidate::of_scene(&scene);
        let observation = Observation {
            noise_std_m: 3e-4,
            seed: 2,
        };
        let targets =
            synthetic_targets(&model, std::slice::from_ref(&recorded), &truth, observation)
                .unwrap();
        let weights = LossWeights {
            object: 1.0,
            package: 1.0,
            kind: LossKind::Labelled,
        };
        let names = vec!["k_tri_e".to_string(), "k_cup_d".to_string()];
        let mut objective =
            SimObjective::from_targets(&scene, names.clone(), targets.clone(), weights).unwrap();
        let at = objective.base_values();
        let space = ParamSpace::new(vec![
            ParamSpec {
                name: "k_tri_e".into(),
                lower: at[0] / 10.0,
                upper: at[0] * 10.0,
                log: true,
            },
            ParamSpec {
                name: "k_cup_d".into(),
                lower: at[1] / 10.0,
                upper: at[1] * 10.0,
                log: true,
            },
        ])
        .unwrap();
        let settings = LikelihoodSettings::default();
        let analysis = fisher_information(&mut objective, &space, &at, &settings, 1e-3).unwrap();
        assert_eq!(analysis.incomplete_frames, 0);
        let [k_tri_e, k_cup_d] = [&analysis.parameters[0], &analysis.parameters[1]];
        assert!(k_tri_e.identifiable, "{analysis:?}");
        assert!(!k_cup_d.identifiable, "{analysis:?}");
        assert_eq!(analysis.directions[1].information, 0.0);
        assert!(analysis.directions[0].vector[0].abs() > 0.9);
        // The errors the analysis weighs are the likelihood's own.
        let outcomes = rollout(&model, &targets, &[truth], &mut ()).unwrap();
        let site = outcomes[0][0].loss.balanced_site_sq();
        assert!((analysis.errors_m2[0] / site - 1.0).abs() < 1e-9);
        assert!(!fisher_table(&analysis).is_empty());
        // At the truth the residuals are the recordings' white noise: no correlation in time.
        let frame = 1.0 / 240.0;
        assert!(
            analysis.residual_correlation_s < 2.0 * frame,
            "{analysis:?}"
        );
    }

    #[test]
    fn the_correlation_time_of_a_smooth_series_is_long_and_of_white_noise_one_sample() {
        let smooth: Vec<f64> = (0..2000).map(|k| (k as f64 / 100.0).sin()).collect();
        assert!(integrated_autocorrelation(&smooth) > 50.0);
        let mut state = 1u64;
        let noise: Vec<f64> = (0..2000)
            .map(|_| {
                state = state
                    .wrapping_mul(6364136223846793005)
                    .wrapping_add(1442695040888963407);
                (state >> 11) as f64 / (1u64 << 53) as f64 - 0.5
            })
            .collect();
        let tau = integrated_autocorrelation(&noise);
        assert!((0.9..1.3).contains(&tau), "{tau}");
    }
}
