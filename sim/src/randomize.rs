//! Domain randomisation of one environment at reset: object mass and disc mass scale, where the
//! object lies in the package and how it is turned, the package's yaw under the tool, and a scale
//! per material parameter. Applied to a spec (no rebuild of the batch: pass the result to
//! [`crate::Simulator::reset_env`]); the same seed gives the same values on any thread count,
//! because each environment draws from its own generator.

use std::collections::BTreeMap;

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
    /// generator state gives the same spec).
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
        for (name, r) in &self.param_scale {
            let scale = uniform([r[0].ln(), r[1].ln()]).exp();
            if let Some(value) = spec.params.get_mut(name) {
                *value *= scale;
            }
        }
        spec
    }
}
