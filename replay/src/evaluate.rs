//! Evaluation helpers for `rlpkg eval --params`: per-marker errors over the package (the paper's
//! Fig. 10), the sensitivity perturbation (every calibrated value scaled up by a percentage, as the
//! study's `eval`), and the real-time factor of a rollout (Table 2).

use crate::rollout::{get_param, set_param, Candidate};

use crate::loss::squared_distance;

/// The values the study scales in its sensitivity evaluation: the 9 calibrated ones plus the
/// attachment springs (reference-model §10). The disc mass scale is a scene quantity and is not
/// perturbed.
pub const PERTURBED_PARAMETERS: [&str; 11] = [
    "k_tri_e", "k_tri_a", "k_tri_d", "k_edge_e", "k_edge_d", "k_con_e", "k_con_d", "k_con_f",
    "mu_con", "k_spr_e", "k_spr_d",
];

/// `candidate` with every [`PERTURBED_PARAMETERS`] value multiplied by `1 + percent / 100`.
pub fn perturbed(candidate: &Candidate, percent: f64) -> Candidate {
    let mut c = *candidate;
    let factor = 1.0 + percent / 100.0;
    for name in PERTURBED_PARAMETERS {
        let value = get_param(&c, name).expect("known name");
        set_param(&mut c, name, value * factor).expect("known name");
    }
    c
}

/// Per simulated marker site: mean over frames of the distance to the nearest recorded marker.
#[derive(Debug, Clone, PartialEq)]
pub struct SiteErrors {
    sums: Vec<f64>,
    counts: Vec<usize>,
}

impl SiteErrors {
    /// Accumulators for `sites` marker sites.
    pub fn new(sites: usize) -> Self {
        Self {
            sums: vec![0.0; sites],
            counts: vec![0; sites],
        }
    }

    /// Adds one frame: each site's distance to its nearest recorded marker (frames without
    /// markers are skipped).
    pub fn record(&mut self, simulated: &[[f64; 3]], markers: &[[f64; 3]]) {
        if markers.is_empty() {
            return;
        }
        for (i, s) in simulated.iter().enumerate().take(self.sums.len()) {
            let d2 = markers
                .iter()
                .map(|m| squared_distance(s, m))
                .fold(f64::INFINITY, f64::min);
            self.sums[i] += d2.sqrt();
            self.counts[i] += 1;
        }
    }

    /// Mean error per site (m); NaN for a site never compared.
    pub fn means(&self) -> Vec<f64> {
        self.sums
            .iter()
            .zip(&self.counts)
            .map(|(s, &n)| if n == 0 { f64::NAN } else { s / n as f64 })
            .collect()
    }
}

/// Real-time factor of a batched rollout: recorded seconds replayed (summed over environments)
/// per wall-clock second, the study's `t_last / elapsed` generalised to a batch.
pub fn real_time_factor(replayed_seconds: &[f64], wall_seconds: f64) -> f64 {
    replayed_seconds.iter().sum::<f64>() / wall_seconds
}

#[cfg(test)]
mod tests {
    use super::*;
    use rlpkg_sim::SceneConfig;

    #[test]
    fn perturbation_scales_the_studys_values_only() {
        let base = Candidate::of_scene(&SceneConfig::preset("reference").unwrap());
        let c = perturbed(&base, 20.0);
        let (p, b) = (&c.params, &base.params);
        assert!((p.k_tri_e / b.k_tri_e - 1.2).abs() < 1e-6);
        assert!((p.mu_con / b.mu_con - 1.2).abs() < 1e-6);
        assert!((p.k_spr_d / b.k_spr_d - 1.2).abs() < 1e-6);
        // The cup shell and the disc mass are not part of the study's perturbation.
        assert_eq!(p.k_cup_e, b.k_cup_e);
        assert_eq!(c.disc_mass_scale, base.disc_mass_scale);
        assert_eq!(perturbed(&base, 0.0), base);
    }

    #[test]
    fn site_errors_average_nearest_distances() {
        let mut e = SiteErrors::new(2);
        let markers = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]];
        e.record(&[[0.0, 0.1, 0.0], [1.0, 0.0, 0.3]], &markers);
        e.record(&[[0.0, 0.3, 0.0], [0.9, 0.0, 0.0]], &markers);
        e.record(&[[5.0, 0.0, 0.0], [5.0, 0.0, 0.0]], &[]);
        let m = e.means();
        assert!(
            (m[0] - 0.2).abs() < 1e-12 && (m[1] - 0.2).abs() < 1e-12,
            "{m:?}"
        );
        assert!(SiteErrors::new(1).means()[0].is_nan());
        assert!((real_time_factor(&[2.0, 4.0], 3.0) - 2.0).abs() < 1e-12);
    }
}
