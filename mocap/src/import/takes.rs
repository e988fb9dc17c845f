//! Per-take manifest fields: `[takes."<id>"]` and `[default_take]` of the import config, their
//! resolution for one take, and their filling from a collection's `manifest.json`.

use serde::{Deserialize, Serialize};

use crate::dataset::Split;
use crate::description::{PackageDescription, TakeRole};

use super::ImportConfig;

/// `[takes."<id>"]` and `[default_take]`: per-take manifest fields. A take's own entry wins over
/// `[default_take]`; a field that neither gives is an error, never a silent default.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TakeConfig {
    /// Train or test (needed unless the take is excluded).
    pub split: Option<Split>,
    /// Clean and report the take but do not write it; false if not given.
    pub exclude: Option<bool>,
    /// A failure take (e.g. the suction seal let go): written, flagged, and in split `excluded`
    /// (out of train and test); false if not given.
    pub failure: Option<bool>,
    /// Object mass including weights (kg).
    pub object_total_mass_kg: Option<f64>,
    /// Mass class label.
    pub mass: Option<String>,
    /// Added mass in lb.
    pub mass_lb: Option<f64>,
    /// Speed class label.
    pub velocity: Option<String>,
    /// Placement orientation label.
    pub orientation: Option<String>,
}

/// The manifest fields of one take, resolved from its `[takes]` entry and `[default_take]`.
#[derive(Debug, Clone, PartialEq)]
pub struct TakeSettings {
    /// Train or test (train for an excluded take that gives none; it is not written); `excluded`
    /// for a failure take.
    pub split: Split,
    /// Not written to the dataset.
    pub exclude: bool,
    /// A failure take (written, flagged, split `excluded`).
    pub failure: bool,
    /// Object mass including weights (kg).
    pub object_total_mass_kg: f64,
    /// Mass class label.
    pub mass: Option<String>,
    /// Added mass in lb.
    pub mass_lb: Option<f64>,
    /// Speed class label.
    pub velocity: Option<String>,
    /// Placement orientation label.
    pub orientation: Option<String>,
}

impl ImportConfig {
    /// Takes from a collection's `manifest.json` the `[takes]` entries of `ids` (split: train,
    /// test, or `excluded` with the failure flag for a failure take; object mass, mass class,
    /// speed and placement angle) and, unless the config gives them, `package.marker_inset_m` and
    /// `package.lower_marker_positions_m` from the marker layout. A take the manifest does not
    /// list, or that the config's `[takes]` also lists, is an error (one source per take).
    pub fn apply_description(
        &mut self,
        description: &PackageDescription,
        ids: &[String],
    ) -> Result<(), String> {
        if self.package.marker_inset_m.is_none() {
            self.package.marker_inset_m = description.marker_inset_m();
        }
        if self.package.lower_marker_positions_m.is_empty() {
            self.package.lower_marker_positions_m = description.bottom_markers_at_start();
        }
        for id in ids {
            let Some(take) = description.take(id) else {
                return Err(format!(
                    "{}: trajectories: no take {id:?}; expected one of: {}",
                    description.path.display(),
                    description
                        .takes
                        .iter()
                        .map(|t| t.id.as_str())
                        .collect::<Vec<_>>()
                        .join(", ")
                ));
            };
            if self.takes.contains_key(id) {
                return Err(format!(
                    "takes.\"{id}\": also given by {}; expected the take's split and masses from one source (drop the [takes] entry or --manifest)",
                    description.path.display()
                ));
            }
            let (split, failure) = match take.role {
                TakeRole::Train => (Split::Train, false),
                TakeRole::Test => (Split::Test, false),
                TakeRole::Failure => (Split::Excluded, true),
            };
            self.takes.insert(
                id.clone(),
                TakeConfig {
                    split: Some(split),
                    exclude: None,
                    failure: Some(failure),
                    object_total_mass_kg: Some(take.object_mass_kg),
                    mass: description.mass_class(take.object_mass_lb),
                    mass_lb: Some(take.object_mass_lb),
                    velocity: Some(take.speed.clone()),
                    orientation: Some(format!("{}", take.placement_angle_deg)),
                },
            );
        }
        Ok(())
    }

    /// The manifest fields of take `id`: its `[takes]` entry, completed by `[default_take]`. An
    /// unlisted take without a `[default_take]`, or a needed field that neither gives, is an error
    /// naming the key.
    pub fn take(&self, id: &str) -> Result<TakeSettings, String> {
        let empty = TakeConfig::default();
        let default = self.default_take.as_ref().unwrap_or(&empty);
        let (own, key) = match self.takes.get(id) {
            Some(own) => (own, format!("takes.\"{id}\"")),
            None if self.default_take.is_some() => (&empty, "default_take".to_string()),
            None => {
                return Err(format!(
                    "take \"{id}\" is not listed in [takes] and there is no [default_take]; expected a [takes.\"{id}\"] entry with split and object_total_mass_kg, or a [default_take] for unlisted takes"
                ))
            }
        };
        let exclude = own.exclude.or(default.exclude).unwrap_or(false);
        // For a listed take, say that [default_take] did not help either.
        let fallback = if key == "default_take" {
            ""
        } else {
            " (and [default_take] gives none)"
        };
        let failure = own.failure.or(default.failure).unwrap_or(false);
        let split = match own.split.or(default.split) {
            Some(Split::Train | Split::Test) if failure => {
                return Err(format!(
                    "{key}: a failure take (failure = true) stays out of train and test; expected no split or split = \"excluded\""
                ))
            }
            Some(split) => split,
            None if failure => Split::Excluded,
            None if exclude => Split::Train,
            None => {
                return Err(format!(
                    "{key}.split is missing{fallback}; expected \"train\", \"test\" or \"excluded\""
                ))
            }
        };
        let object_total_mass_kg = own
            .object_total_mass_kg
            .or(default.object_total_mass_kg)
            .ok_or_else(|| {
                format!(
                    "{key}.object_total_mass_kg is missing{fallback}; expected the object's mass with its added weight in kg"
                )
            })?;
        Ok(TakeSettings {
            split,
            exclude,
            failure,
            object_total_mass_kg,
            mass: own.mass.clone().or_else(|| default.mass.clone()),
            mass_lb: own.mass_lb.or(default.mass_lb),
            velocity: own.velocity.clone().or_else(|| default.velocity.clone()),
            orientation: own
                .orientation
                .clone()
                .or_else(|| default.orientation.clone()),
        })
    }
}
