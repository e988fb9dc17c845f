//! Domain randomisation of one environment at reset: object mass and disc mass scale, where the
//! object lies in the package and how it is turned, the package's yaw under the tool, a scale
//! per material parameter, the cups' supply vacuum and material parameters drawn from a
//! calibration posterior ([`PosteriorDraws`]). Applied to a spec (no rebuild of the batch: pass
//! the result to [`crate::Simulator::reset_env`]); the same seed gives the same values on any
//! thread count, because each environment draws from its own generator.

use std::collections::BTreeMap;
use std::path::PathBuf;
use std::sync::Arc;

use rand::Rng;
use serde::{Deserialize, Serialize};

use crate::config::PARAM_NAMES;
use crate::episode::EpisodeSpec;
use crate::error::SimError;

/// Ranges to draw from; every range is `[low, high]` and drawn uniformly unless said otherwise.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Randomization {
    /// Object mass (kg); `None` keeps the spec's.
    #[serde(default, deserialize_with = "rlpkg_toml_input::option")]
    pub object_mass_kg: Option<[f32; 2]>,
    /// Simulated disc kg per object kg; `None` keeps the spec's.
    #[serde(default, deserialize_with = "rlpkg_toml_input::option")]
    pub disc_mass_scale: Option<[f32; 2]>,
    /// Largest horizontal offset of the object from its nominal place in the package (m),
    /// uniform over a disc of this radius.
    #[serde(default)]
    pub object_offset_m: f32,
    /// Largest tilt of the object's axis from vertical (degrees), about a random horizontal axis.
    #[serde(default)]
    pub object_tilt_deg: f32,
    /// Yaw of the package under the tool (degrees).
    #[serde(default, deserialize_with = "rlpkg_toml_input::array")]
    pub package_yaw_deg: [f32; 2],
    /// Scale per material parameter, by the paper's name (`k_tri_e`, ...), drawn log-uniformly.
    #[serde(default, deserialize_with = "rlpkg_toml_input::map")]
    pub param_scale: BTreeMap<String, [f32; 2]>,
    /// Supply vacuum of the package's cups below ambient (kPa), uniform per package, within
    /// (0, 101.325]; `None` keeps the scene's `seal.vacuum_kpa` (see
    /// [`EpisodeSpec::vacuum_kpa`]).
    #[serde(
        default,
        deserialize_with = "rlpkg_toml_input::option",
        skip_serializing_if = "Option::is_none"
    )]
    pub vacuum_kpa: Option<[f32; 2]>,
    /// A calibration posterior (`rlpkg posterior` output folder, its `summary.json` or its
    /// `samples.csv`) whose draws set the material parameters, one row per package; its table is
    /// [`Randomization::posterior_draws`], read by whoever loads the configuration.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub posterior: Option<PathBuf>,
    /// The draws of `posterior` once loaded (shared: cloning a configuration copies no rows).
    #[serde(skip)]
    pub posterior_draws: Option<Arc<PosteriorDraws>>,
}

/// Draws of material parameters from a calibration posterior: absolute SI values, one row per
/// draw, one column per named parameter (read from a posterior's `samples.csv` by
/// `rlpkg_calib::posterior_files`, which checks every value against [`crate::Params::range`]).
#[derive(Clone, Debug, PartialEq)]
pub struct PosteriorDraws {
    /// Parameter names of the columns (`k_tri_e`, ..., [`PARAM_NAMES`]).
    pub names: Vec<String>,
    /// The draws, `names.len()` values each (SI).
    pub rows: Vec<Vec<f32>>,
}

fn range_ok(r: [f32; 2], lo: f32, hi: f32) -> bool {
    r.iter().all(|v| v.is_finite()) && lo <= r[0] && r[0] <= r[1] && r[1] <= hi
}

impl Randomization {
    /// Checks names and ranges; `source` names the file (and table) in messages.
    pub fn validate(&self, source: &str) -> Result<(), SimError> {
        let bad = |key: &str, value: String, expected: &str| {
            Err(SimError::Range {
                file: source.to_string(),
                key: key.to_string(),
                value,
                expected: expected.to_string(),
            })
        };
        if let Some(r) = self.object_mass_kg {
            if !range_ok(r, 1e-3, 1e3) {
                return bad(
                    "object_mass_kg",
                    format!("{r:?}"),
                    "[low, high] within [0.001, 1000] kg",
                );
            }
        }
        if let Some(r) = self.disc_mass_scale {
            if !range_ok(r, 1e-3, 1e4) {
                return bad(
                    "disc_mass_scale",
                    format!("{r:?}"),
                    "[low, high] within [0.001, 10000]",
                );
            }
        }
        if !(self.object_offset_m.is_finite() && (0.0..=0.5).contains(&self.object_offset_m)) {
            return bad(
                "object_offset_m",
                self.object_offset_m.to_string(),
                "a number in [0, 0.5] m",
            );
        }
        if !(self.object_tilt_deg.is_finite() && (0.0..=90.0).contains(&self.object_tilt_deg)) {
            return bad(
                "object_tilt_deg",
                self.object_tilt_deg.to_string(),
                "a number in [0, 90]",
            );
        }
        if !range_ok(self.package_yaw_deg, -180.0, 180.0) {
            return bad(
                "package_yaw_deg",
                format!("{:?}", self.package_yaw_deg),
                "[low, high] within [-180, 180] degrees",
            );
        }
        if let Some(r) = self.vacuum_kpa {
            if !(range_ok(r, 0.0, 101.325) && r[0] > 0.0) {
                return bad(
                    "vacuum_kpa",
                    format!("{r:?}"),
                    "[low, high] within (0, 101.325] kPa below ambient (a cell supplies 20-30)",
                );
            }
        }
        for (name, r) in &self.param_scale {
            let key = format!("param_scale.{name}");
            if !PARAM_NAMES.contains(&name.as_str()) {
                return bad(
                    &key,
                    name.clone(),
                    "a parameter name such as k_tri_e or mu_con",
                );
            }
            if !range_ok(*r, 1e-3, 1e3) {
                return bad(
                    &key,
                    format!("{r:?}"),
                    "[low, high] scales within [0.001, 1000]",
                );
            }
        }
        Ok(())
    }

    /// `base` with every randomised quantity drawn from `rng` (in a fixed order, so the same
    /// generator state gives the same spec). The supply vacuum and the posterior row are drawn
    /// after everything else, and only when set, so a randomisation without them draws exactly
    /// what it drew before they existed. With a posterior, the row's values replace the spec's
    /// parameters (absolute SI values) and `param_scale` then multiplies them: the scales widen
    /// the posterior rather than the scene's values.
    pub fn apply(&self, base: &EpisodeSpec, rng: &mut impl Rng) -> EpisodeSpec {
        let mut spec = base.clone();
        let mut uniform = |r: [f32; 2]| {
            if r[0] < r[1] {
                rng.random_range(r[0]..=r[1])
            } else {
                r[0]
            }
        };
        if let Some(r) = self.object_mass_kg {
            spec.object_mass_kg = uniform(r);
        }
        if let Some(r) = self.disc_mass_scale {
            spec.disc_mass_scale = Some(uniform(r));
        }
        // Uniform over the disc of radius `object_offset_m`: radius ~ sqrt(u).
        let radius = self.object_offset_m * uniform([0.0, 1.0]).sqrt();
        let heading = uniform([0.0, std::f32::consts::TAU]);
        let (dx, dz) = (radius * heading.cos(), radius * heading.sin());
        let pl = &mut spec.placement;
        pl.disc_position[0] += dx;
        pl.disc_position[2] += dz;
        if let Some(hold) = &mut pl.disc_hold {
            hold[0] += dx;
            hold[2] += dz;
        }
        let tilt = uniform([0.0, self.object_tilt_deg]).to_radians();
        let tilt_axis = uniform([0.0, std::f32::consts::TAU]);
        let (s, c) = (0.5 * tilt).sin_cos();
        pl.disc_orientation = [s * tilt_axis.cos(), 0.0, s * tilt_axis.sin(), c];
        pl.package_yaw_rad = uniform(self.package_yaw_deg).to_radians();
        let scales: Vec<(&String, f32)> = self
            .param_scale
            .iter()
            .map(|(name, r)| (name, uniform([r[0].ln(), r[1].ln()]).exp()))
            .collect();
        if let Some(r) = self.vacuum_kpa {
            spec.vacuum_kpa = Some(uniform(r));
        }
        if let Some(draws) = self
            .posterior_draws
            .as_deref()
            .filter(|d| !d.rows.is_empty())
        {
            let row = &draws.rows[rng.random_range(0..draws.rows.len())];
            for (name, &value) in draws.names.iter().zip(row) {
                if let Some(param) = spec.params.get_mut(name) {
                    *param = value;
                }
            }
        }
        for (name, scale) in scales {
            if let Some(value) = spec.params.get_mut(name) {
                *value *= scale;
            }
        }
        spec
    }
}

#[cfg(test)]
mod tests {
    use std::sync::Arc;

    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    use super::*;
    use crate::{Placement, SceneConfig, ToolTrajectory};

    fn base() -> EpisodeSpec {
        let scene = SceneConfig::preset("physical").unwrap();
        EpisodeSpec {
            placement: Placement::new([0.0, 0.5, 0.0], [0.15, 0.51, 0.127], [0.15, 0.5, 0.127]),
            params: scene.params,
            object_mass_kg: 0.5,
            disc_mass_scale: None,
            vacuum_kpa: None,
            trajectory: Arc::new(ToolTrajectory::hold(
                [0.15, 0.51, 0.127],
                [0.0, 0.0, 0.0, 1.0],
            )),
        }
    }

    fn without_new_keys() -> Randomization {
        Randomization {
            object_mass_kg: Some([0.25, 0.75]),
            disc_mass_scale: Some([0.9, 1.1]),
            object_offset_m: 0.03,
            object_tilt_deg: 10.0,
            package_yaw_deg: [-20.0, 20.0],
            param_scale: [
                ("k_tri_e".to_string(), [0.5, 2.0]),
                ("mu_con".to_string(), [0.8, 1.25]),
            ]
            .into_iter()
            .collect(),
            ..Randomization::default()
        }
    }

    /// The draws as they were made before the vacuum and the posterior existed, written out.
    fn drawn_the_old_way(r: &Randomization, rng: &mut ChaCha8Rng) -> EpisodeSpec {
        let mut spec = base();
        let mut uniform = |r: [f32; 2]| {
            if r[0] < r[1] {
                rng.random_range(r[0]..=r[1])
            } else {
                r[0]
            }
        };
        spec.object_mass_kg = uniform(r.object_mass_kg.unwrap());
        spec.disc_mass_scale = Some(uniform(r.disc_mass_scale.unwrap()));
        let radius = r.object_offset_m * uniform([0.0, 1.0]).sqrt();
        let heading = uniform([0.0, std::f32::consts::TAU]);
        let (dx, dz) = (radius * heading.cos(), radius * heading.sin());
        spec.placement.disc_position[0] += dx;
        spec.placement.disc_position[2] += dz;
        let tilt = uniform([0.0, r.object_tilt_deg]).to_radians();
        let tilt_axis = uniform([0.0, std::f32::consts::TAU]);
        let (s, c) = (0.5 * tilt).sin_cos();
        spec.placement.disc_orientation = [s * tilt_axis.cos(), 0.0, s * tilt_axis.sin(), c];
        spec.placement.package_yaw_rad = uniform(r.package_yaw_deg).to_radians();
        for (name, band) in &r.param_scale {
            let scale = uniform([band[0].ln(), band[1].ln()]).exp();
            *spec.params.get_mut(name).unwrap() *= scale;
        }
        spec
    }

    fn table() -> Arc<PosteriorDraws> {
        Arc::new(PosteriorDraws {
            names: vec!["k_tri_e".into(), "k_spr_e".into(), "mu_con".into()],
            rows: (1..=4)
                .map(|k| {
                    vec![
                        1000.0 * k as f32,
                        10.0 + 10.0 * k as f32,
                        0.4 + 0.1 * k as f32,
                    ]
                })
                .collect(),
        })
    }

    #[test]
    fn without_the_new_keys_the_draws_are_those_of_before() {
        let r = without_new_keys();
        r.validate("test").unwrap();
        for seed in 0..20 {
            let mut new = ChaCha8Rng::seed_from_u64(seed);
            let mut old = ChaCha8Rng::seed_from_u64(seed);
            let spec = r.apply(&base(), &mut new);
            assert_eq!(spec, drawn_the_old_way(&r, &mut old), "seed {seed}");
            assert_eq!(spec.vacuum_kpa, None);
            // The generator is left where it was: the next package draws the same as before.
            assert_eq!(new.random::<u64>(), old.random::<u64>(), "seed {seed}");
        }
    }

    #[test]
    fn the_vacuum_and_the_posterior_are_drawn_after_everything_else() {
        let plain = without_new_keys();
        let extended = Randomization {
            vacuum_kpa: Some([20.0, 30.0]),
            posterior_draws: Some(table()),
            ..without_new_keys()
        };
        extended.validate("test").unwrap();
        for seed in 0..20 {
            let a = plain.apply(&base(), &mut ChaCha8Rng::seed_from_u64(seed));
            let b = extended.apply(&base(), &mut ChaCha8Rng::seed_from_u64(seed));
            assert_eq!(a.placement, b.placement, "seed {seed}");
            assert_eq!(a.object_mass_kg, b.object_mass_kg);
            assert_eq!(a.disc_mass_scale, b.disc_mass_scale);
            let vacuum = b.vacuum_kpa.unwrap();
            assert!((20.0..=30.0).contains(&vacuum), "{vacuum}");
        }
    }

    #[test]
    fn a_posterior_row_sets_absolute_values_and_the_scales_multiply_them() {
        let draws = table();
        let r = Randomization {
            posterior_draws: Some(draws.clone()),
            ..Randomization::default()
        };
        let scene_value = base().params.k_tri_d;
        let mut rows_seen = std::collections::BTreeSet::new();
        for seed in 0..40 {
            let spec = r.apply(&base(), &mut ChaCha8Rng::seed_from_u64(seed));
            let row = draws
                .rows
                .iter()
                .position(|row| row[0] == spec.params.k_tri_e)
                .expect("k_tri_e from one of the rows");
            assert_eq!(spec.params.k_spr_e, draws.rows[row][1]);
            assert_eq!(spec.params.mu_con, draws.rows[row][2]);
            // A parameter the posterior does not name keeps the scene's value.
            assert_eq!(spec.params.k_tri_d, scene_value);
            // The same seed picks the same row.
            let again = r.apply(&base(), &mut ChaCha8Rng::seed_from_u64(seed));
            assert_eq!(again, spec);
            rows_seen.insert(row);
        }
        assert_eq!(rows_seen.len(), 4, "{rows_seen:?}");
        // Scales apply on top of the row: the ratio to the row's value is the drawn scale.
        let scaled = Randomization {
            param_scale: [("k_tri_e".to_string(), [2.0, 2.0])].into_iter().collect(),
            posterior_draws: Some(draws.clone()),
            ..Randomization::default()
        };
        for seed in 0..10 {
            let a = r.apply(&base(), &mut ChaCha8Rng::seed_from_u64(seed));
            let b = scaled.apply(&base(), &mut ChaCha8Rng::seed_from_u64(seed));
            let ratio = b.params.k_tri_e / a.params.k_tri_e;
            assert!((ratio - 2.0).abs() < 1e-6, "seed {seed}: {ratio}");
            assert_eq!(b.params.mu_con, a.params.mu_con);
        }
    }

    #[test]
    fn a_vacuum_range_outside_the_atmosphere_is_refused() {
        for bad in [[0.0, 10.0], [20.0, 120.0], [30.0, 20.0], [f32::NAN, 20.0]] {
            let r = Randomization {
                vacuum_kpa: Some(bad),
                ..Randomization::default()
            };
            let err = r.validate("t.toml").unwrap_err().to_string();
            assert!(
                err.contains("t.toml") && err.contains("vacuum_kpa"),
                "{err}"
            );
        }
    }
}
