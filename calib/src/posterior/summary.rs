//! Per-parameter summaries of the posterior draws, the surrogate-loss profiles, and the files
//! `rlpkg posterior` writes.

use rayon::prelude::*;

use super::surrogate::Surrogate;
use super::{ParameterSummary, PosteriorSettings, Profile, IDENTIFIED_FRACTION, PROFILE_RISE};
use crate::space::ParamSpace;

/// The surrogate-loss profile of every parameter over `settings.profile_draws` of the `draws`
/// (unit cube), evenly spaced in the chain.
pub(super) fn profiles(
    space: &ParamSpace,
    surrogate: &Surrogate,
    draws: &[Vec<f64>],
    settings: &PosteriorSettings,
) -> Vec<Profile> {
    let stride = (draws.len() / settings.profile_draws).max(1);
    let grid: Vec<f64> = (0..settings.profile_points)
        .map(|k| k as f64 / (settings.profile_points - 1) as f64)
        .collect();
    space
        .specs()
        .iter()
        .enumerate()
        .map(|(i, spec)| {
            let surrogate_loss = grid
                .par_iter()
                .map(|&g| {
                    draws
                        .iter()
                        .step_by(stride)
                        .map(|draw| {
                            let mut u = draw.clone();
                            u[i] = g;
                            u
                        })
                        .filter(|u| surrogate.success_probability(u) >= 0.5)
                        .map(|u| surrogate.gp.predict(&u).0)
                        .fold(f64::INFINITY, f64::min)
                        .exp()
                })
                .collect();
            Profile {
                name: spec.name.clone(),
                values: grid
                    .iter()
                    .map(|&g| coordinate_value(space, i, g))
                    .collect(),
                surrogate_loss,
            }
        })
        .collect()
}

/// The posterior summary of parameter `i` from the `draws` (unit cube), its profile, its value at
/// the best evaluation and the surrogate's length scale along it.
pub(super) fn summarise(
    space: &ParamSpace,
    i: usize,
    draws: &[Vec<f64>],
    profile: &Profile,
    best: f64,
    length_scale: f64,
) -> ParameterSummary {
    let spec = &space.specs()[i];
    let mut coordinate: Vec<f64> = draws.iter().map(|d| d[i]).collect();
    coordinate.sort_by(f64::total_cmp);
    let [low, median, high] = [0.05, 0.5, 0.95].map(|q| quantile(&coordinate, q));
    let interval = [
        coordinate_value(space, i, low),
        coordinate_value(space, i, high),
    ];
    let (min, max) = profile
        .surrogate_loss
        .iter()
        .fold((f64::INFINITY, 0.0f64), |(lo, hi), &v| {
            (lo.min(v), hi.max(v))
        });
    let profile_ratio = max / min;
    let prior_fraction = high - low;
    ParameterSummary {
        name: spec.name.clone(),
        log: spec.log,
        lower: spec.lower,
        upper: spec.upper,
        best,
        median: coordinate_value(space, i, median),
        interval,
        interval_decades: spec.log.then(|| (interval[1] / interval[0]).log10()),
        prior_fraction,
        identified: prior_fraction < IDENTIFIED_FRACTION && profile_ratio >= PROFILE_RISE,
        length_scale,
        profile_ratio,
        profile_curvature: profile_curvature(space, i, profile),
    }
}

/// The value of parameter `i` at unit-cube coordinate `u`.
pub(super) fn coordinate_value(space: &ParamSpace, i: usize, u: f64) -> f64 {
    let mut unit = vec![0.5; space.dim()];
    unit[i] = u;
    space.from_unit(&unit)[i]
}

/// The `q`-quantile of sorted values, interpolating linearly between order statistics.
pub fn quantile(sorted: &[f64], q: f64) -> f64 {
    let position = q * (sorted.len() - 1) as f64;
    let below = position.floor() as usize;
    let above = (below + 1).min(sorted.len() - 1);
    sorted[below] + (position - below as f64) * (sorted[above] - sorted[below])
}

/// `profiles.csv`: `parameter,value,surrogate_loss`, one row per parameter and grid value.
pub fn profiles_csv(profiles: &[Profile]) -> String {
    let mut text = String::from("parameter,value,surrogate_loss\n");
    for profile in profiles {
        for (value, loss) in profile.values.iter().zip(&profile.surrogate_loss) {
            text.push_str(&format!("{},{value},{loss}\n", profile.name));
        }
    }
    text
}

/// Grid points of the profile the curvature is fitted on, centred on its minimum.
const CURVATURE_POINTS: usize = 5;

/// The curvature `d² ln(loss) / dx²` of the profile at its minimum, `x` in decades for a log
/// parameter and in search ranges for a linear one: twice the leading coefficient of a
/// least-squares parabola through the [`CURVATURE_POINTS`] finite grid points around the lowest
/// one. NaN when fewer than three are finite. Large means a sharp optimum; near zero a flat one
/// (or a minimum on a bound of a monotone profile, which the profile ratio then shows).
fn profile_curvature(space: &ParamSpace, i: usize, profile: &Profile) -> f64 {
    let spec = &space.specs()[i];
    let n = profile.values.len();
    let x = |k: usize| {
        if spec.log {
            profile.values[k].log10()
        } else {
            (profile.values[k] - spec.lower) / (spec.upper - spec.lower)
        }
    };
    let Some(lowest) = (0..n)
        .filter(|&k| profile.surrogate_loss[k].is_finite())
        .min_by(|&a, &b| profile.surrogate_loss[a].total_cmp(&profile.surrogate_loss[b]))
    else {
        return f64::NAN;
    };
    let start = lowest
        .saturating_sub(CURVATURE_POINTS / 2)
        .min(n.saturating_sub(CURVATURE_POINTS));
    let points: Vec<(f64, f64)> = (start..(start + CURVATURE_POINTS).min(n))
        .filter(|&k| profile.surrogate_loss[k].is_finite())
        .map(|k| (x(k) - x(lowest), profile.surrogate_loss[k].ln()))
        .collect();
    if points.len() < 3 {
        return f64::NAN;
    }
    // Normal equations of y = a x² + b x + c.
    let mut normal = nalgebra::Matrix3::<f64>::zeros();
    let mut rhs = nalgebra::Vector3::<f64>::zeros();
    for &(x, y) in &points {
        let basis = nalgebra::Vector3::new(x * x, x, 1.0);
        normal += basis * basis.transpose();
        rhs += basis * y;
    }
    normal
        .lu()
        .solve(&rhs)
        .map_or(f64::NAN, |coefficients| 2.0 * coefficients[0])
}
