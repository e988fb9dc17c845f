//! Quantities fixed for a whole batch, derived once from the model's config: the substep, the
//! contact with the ground, the health limits and the seal law's constants. Settings of one
//! solver only live with that solver (`solvers::*`).

use crate::episode::CupLoad;
use crate::forces::ContactMaterial;
use crate::model::Model;

/// Quantities fixed for a whole batch, derived from the model's config.
pub(crate) struct StepConstants {
    /// Substep length (s).
    pub(crate) dt: f32,
    /// Substep length in f64, for the lanes' clocks (s).
    pub(crate) dt64: f64,
    /// Rest period before trajectory time 0 (s).
    pub(crate) rest_time: f64,
    pub(crate) check_every: u64,
    pub(crate) max_speed: f32,
    pub(crate) max_displacement: f32,
    /// Particle-ground contact material.
    pub(crate) ground: ContactMaterial<f32>,
    pub(crate) angular_damping: f32,
    pub(crate) max_particle_speed: f32,
    pub(crate) seal: SealConstants,
    /// Reach of the disc's centre beyond the package's particles before it counts as outside (m).
    pub(crate) object_outside_margin: f32,
    pub(crate) object_outside: bool,
}

impl StepConstants {
    pub(crate) fn new(model: &Model) -> Self {
        let c = &model.config;
        StepConstants {
            dt: c.dt(),
            dt64: 1.0 / c.integrator.substep_rate_hz,
            rest_time: c.cups.rest_time_s as f64,
            check_every: c.health.check_every as u64,
            max_speed: c.health.max_speed_m_s,
            max_displacement: c.health.max_displacement_m,
            ground: ContactMaterial {
                ke: c.contact.soft_ke,
                kd: c.contact.soft_kd,
                kf: c.contact.soft_kf,
                mu: c.contact.soft_mu,
            },
            angular_damping: c.integrator.angular_damping,
            max_particle_speed: c.integrator.max_particle_speed_m_s,
            seal: SealConstants::new(model),
            object_outside_margin: model.particle_radius + c.disc.radius_m,
            object_outside: c.health.object_outside,
        }
    }
}

/// Seal quantities of a batch (see [`crate::config::SealConfig`] for the model); an environment
/// with its own vacuum ([`crate::EpisodeSpec::vacuum_kpa`]) uses [`SealConstants::with_vacuum`].
#[derive(Clone, Copy, Debug)]
pub(crate) struct SealConstants {
    pub(crate) enabled: bool,
    /// Low-pass filter weight per substep, dt / (τ + dt).
    pub(crate) filter: f32,
    /// Vacuum force of a fully sealed cup, Δp·π·r² (N).
    pub(crate) full_capacity: f32,
    /// Pull a lip element holds before it peels (N).
    pub(crate) element_strength: f32,
    pub(crate) friction: f32,
    pub(crate) min_sealed_fraction: f32,
    /// Lip radius r (m), lip strength ratio and lip elements per cup: what the capacity and the
    /// element strength of another vacuum are computed from.
    lip_radius_m: f32,
    lip_strength_ratio: f32,
    cup_size: usize,
}

/// (full capacity, element strength) of a cup at `vacuum_kpa` (N).
fn capacities(vacuum_kpa: f32, lip_radius_m: f32, ratio: f32, cup_size: usize) -> (f32, f32) {
    let full_capacity = vacuum_kpa * 1e3 * std::f32::consts::PI * lip_radius_m.powi(2);
    (full_capacity, ratio * full_capacity / cup_size as f32)
}

impl SealConstants {
    pub(crate) fn new(model: &Model) -> Self {
        let s = &model.config.seal;
        let dt = model.config.dt();
        let (full_capacity, element_strength) = capacities(
            s.vacuum_kpa,
            s.lip_radius_m,
            s.lip_strength_ratio,
            model.cup_size,
        );
        SealConstants {
            enabled: s.enabled,
            filter: dt / (s.load_filter_s + dt),
            full_capacity,
            element_strength,
            friction: s.friction,
            min_sealed_fraction: s.min_sealed_fraction,
            lip_radius_m: s.lip_radius_m,
            lip_strength_ratio: s.lip_strength_ratio,
            cup_size: model.cup_size,
        }
    }

    /// These constants at an environment's own vacuum (kPa); `None` keeps the scene's (the very
    /// same numbers, so such an environment runs as it did without the option).
    pub(crate) fn with_vacuum(&self, vacuum_kpa: Option<f32>) -> Self {
        match vacuum_kpa {
            None => *self,
            Some(v) => {
                let (full_capacity, element_strength) =
                    capacities(v, self.lip_radius_m, self.lip_strength_ratio, self.cup_size);
                SealConstants {
                    full_capacity,
                    element_strength,
                    ..*self
                }
            }
        }
    }

    /// A cup's load as reported: normal and shear parts of the film's force `force` on the cup
    /// along `axis`, its capacity and utilisation.
    pub(crate) fn cup_load(
        &self,
        attached: bool,
        sealed_fraction: f32,
        force: [f32; 3],
        axis: [f32; 3],
    ) -> CupLoad {
        let normal = force[0] * axis[0] + force[1] * axis[1] + force[2] * axis[2];
        let shear = (0..3)
            .map(|c| (force[c] - normal * axis[c]).powi(2))
            .sum::<f32>()
            .sqrt();
        let capacity = self.full_capacity * sealed_fraction;
        let clamp = self.friction * (capacity - normal);
        let pull = if capacity > 0.0 {
            normal / capacity
        } else {
            f32::INFINITY
        };
        let slide = if clamp > 0.0 {
            shear / clamp
        } else {
            f32::INFINITY
        };
        CupLoad {
            attached,
            normal_n: normal,
            shear_n: shear,
            capacity_n: capacity,
            sealed_fraction,
            utilisation: if attached { pull.max(slide) } else { 0.0 },
        }
    }
}
