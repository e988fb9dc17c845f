//! The nominal task ([`TransportConfig::nominal`]): the nominal package at one target tilt, every
//! randomised quantity at the middle of its range.

use super::table::TransportConfig;

impl TransportConfig {
    /// The task with the nominal package at one target tilt: every randomised quantity at the
    /// middle of its range (mass, disc mass scale and vacuum the mean of theirs, the scene's
    /// parameters instead of posterior draws, material scales the
    /// geometric mean of their log-uniform bands), the object centred and upright, the package
    /// unturned, no pick or place jitter, one settled variant. What a command for a known place
    /// pose and an unknown package is optimised on.
    pub fn nominal(&self, target_tilt_deg: f64) -> Self {
        let mut nominal = self.clone();
        let r = &mut nominal.randomization;
        let middle = |[lo, hi]: [f32; 2]| [0.5 * (lo + hi); 2];
        r.target_tilt_deg = [target_tilt_deg; 2];
        r.goal_jitter_m = 0.0;
        r.start_jitter_m = 0.0;
        let p = &mut r.package;
        p.object_mass_kg = p.object_mass_kg.map(middle);
        p.disc_mass_scale = p.disc_mass_scale.map(middle);
        p.object_offset_m = 0.0;
        p.object_tilt_deg = 0.0;
        p.package_yaw_deg = [0.0; 2];
        p.vacuum_kpa = p.vacuum_kpa.map(middle);
        // The scene's own parameters (a calibration's best fit) stand for the posterior.
        p.posterior = None;
        p.posterior_draws = None;
        for band in p.param_scale.values_mut() {
            *band = [(band[0] * band[1]).sqrt(); 2];
        }
        nominal.settled_variants = 1;
        nominal
    }
}

#[cfg(test)]
mod tests {
    use crate::transport::test_support::{config, test_table};
    use crate::transport::Transport;
    use crate::VecEnv;

    #[test]
    fn the_nominal_package_is_the_middle_of_every_range_at_the_tilt_asked() {
        let nominal = config(&test_table()).nominal(42.0);
        nominal.validate("test.toml").unwrap();
        let mut env = Transport::new(nominal, 2, "test.toml").unwrap();
        let mut buffers = env.buffers();
        env.try_reset(7, &mut buffers).unwrap();
        for copy in 0..2 {
            let c = env.conditions(copy);
            assert!(
                (c.target_tilt_rad.to_degrees() - 42.0).abs() < 1e-9,
                "{c:?}"
            );
            assert!((c.object_mass_kg - 0.441).abs() < 1e-6, "{c:?}");
            assert_eq!(c.package_yaw_rad, 0.0);
            assert_eq!(c.goal_jitter_m, [0.0; 3]);
            assert_eq!(c.start_offset_m, [0.0; 3]);
            assert_eq!(c.variant, 0);
        }
        let scale = env.config.randomization.package.param_scale["k_tri_e"];
        assert_eq!(scale, [1.0; 2]);
    }
}
