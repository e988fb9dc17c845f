//! The search space: named parameters with bounds, mapped to and from the unit cube.
//!
//! A parameter whose range spans decades (a stiffness from 1e2 to 1e6) is searched on a log scale, so
//! that the GP's length scales mean "a factor" rather than "an absolute amount". This replaces the
//! study's redundant `10^e · d` encoding (reference-model §12, item 15) with one dimension per parameter.

use serde::{Deserialize, Serialize};

/// Errors in a parameter specification.
#[derive(Debug, thiserror::Error)]
pub enum SpaceError {
    /// A bound is not finite, or `lower >= upper`.
    #[error("parameter `{name}`: bounds [{lower}, {upper}] must be finite with lower < upper")]
    Bounds {
        /// Parameter name.
        name: String,
        /// Lower bound.
        lower: f64,
        /// Upper bound.
        upper: f64,
    },
    /// `log = true` with a non-positive lower bound.
    #[error("parameter `{name}`: log scale needs a lower bound > 0 (got {lower})")]
    LogBound {
        /// Parameter name.
        name: String,
        /// Lower bound.
        lower: f64,
    },
    /// The same name appears twice.
    #[error("parameter `{0}` is listed twice")]
    Duplicate(String),
    /// No parameter at all.
    #[error("the search space needs at least one parameter")]
    Empty,
}

/// One calibrated parameter: a name of the simulator (`k_tri_e`, `mu_con`, ...), bounds and scale.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ParamSpec {
    /// Simulator parameter name.
    pub name: String,
    /// Lower bound (SI units of the parameter).
    pub lower: f64,
    /// Upper bound.
    pub upper: f64,
    /// Search on a log scale (for ranges spanning decades).
    #[serde(default)]
    pub log: bool,
}

/// An ordered list of parameters and the map between their values and the unit cube.
#[derive(Debug, Clone, PartialEq)]
pub struct ParamSpace {
    specs: Vec<ParamSpec>,
}

impl ParamSpace {
    /// Validates the specifications (bounds, log bounds, unique names).
    pub fn new(specs: Vec<ParamSpec>) -> Result<Self, SpaceError> {
        if specs.is_empty() {
            return Err(SpaceError::Empty);
        }
        for (i, s) in specs.iter().enumerate() {
            if !(s.lower.is_finite() && s.upper.is_finite() && s.lower < s.upper) {
                return Err(SpaceError::Bounds {
                    name: s.name.clone(),
                    lower: s.lower,
                    upper: s.upper,
                });
            }
            if s.log && s.lower <= 0.0 {
                return Err(SpaceError::LogBound {
                    name: s.name.clone(),
                    lower: s.lower,
                });
            }
            if specs[..i].iter().any(|o| o.name == s.name) {
                return Err(SpaceError::Duplicate(s.name.clone()));
            }
        }
        Ok(Self { specs })
    }

    /// The parameter specifications, in search order.
    pub fn specs(&self) -> &[ParamSpec] {
        &self.specs
    }

    /// Number of dimensions.
    pub fn dim(&self) -> usize {
        self.specs.len()
    }

    /// Parameter names, in search order.
    pub fn names(&self) -> Vec<&str> {
        self.specs.iter().map(|s| s.name.as_str()).collect()
    }

    /// Maps parameter values to the unit cube (values outside the bounds map outside [0, 1]).
    pub fn to_unit(&self, values: &[f64]) -> Vec<f64> {
        self.specs
            .iter()
            .zip(values)
            .map(|(s, &v)| {
                if s.log {
                    (v.ln() - s.lower.ln()) / (s.upper.ln() - s.lower.ln())
                } else {
                    (v - s.lower) / (s.upper - s.lower)
                }
            })
            .collect()
    }

    /// Maps a point of the unit cube (clamped to it) to parameter values.
    pub fn from_unit(&self, unit: &[f64]) -> Vec<f64> {
        self.specs
            .iter()
            .zip(unit)
            .map(|(s, &u)| {
                let u = u.clamp(0.0, 1.0);
                if s.log {
                    (s.lower.ln() + u * (s.upper.ln() - s.lower.ln())).exp()
                } else {
                    s.lower + u * (s.upper - s.lower)
                }
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn spec(name: &str, lower: f64, upper: f64, log: bool) -> ParamSpec {
        ParamSpec {
            name: name.into(),
            lower,
            upper,
            log,
        }
    }

    #[test]
    fn maps_linear_and_log_dimensions() {
        let space = ParamSpace::new(vec![
            spec("k_tri_e", 1e2, 1e6, true),
            spec("mu_con", 0.0, 2.0, false),
        ])
        .unwrap();
        let u = space.to_unit(&[1e4, 0.5]);
        assert!(
            (u[0] - 0.5).abs() < 1e-12 && (u[1] - 0.25).abs() < 1e-12,
            "{u:?}"
        );
        let v = space.from_unit(&[0.75, 1.0]);
        assert!(
            (v[0] - 1e5).abs() < 1e-6 && (v[1] - 2.0).abs() < 1e-12,
            "{v:?}"
        );
        // Round trip.
        let back = space.from_unit(&space.to_unit(&[3.3e3, 1.7]));
        assert!((back[0] - 3.3e3).abs() < 1e-8 && (back[1] - 1.7).abs() < 1e-12);
        // from_unit clamps to the box.
        assert_eq!(space.from_unit(&[-1.0, 2.0])[1], 2.0);
    }

    #[test]
    fn rejects_bad_specs() {
        assert!(matches!(ParamSpace::new(vec![]), Err(SpaceError::Empty)));
        assert!(matches!(
            ParamSpace::new(vec![spec("a", 1.0, 1.0, false)]),
            Err(SpaceError::Bounds { .. })
        ));
        assert!(matches!(
            ParamSpace::new(vec![spec("a", 0.0, 1.0, true)]),
            Err(SpaceError::LogBound { .. })
        ));
        assert!(matches!(
            ParamSpace::new(vec![spec("a", 0.0, 1.0, false), spec("a", 0.0, 2.0, false)]),
            Err(SpaceError::Duplicate(_))
        ));
    }
}
