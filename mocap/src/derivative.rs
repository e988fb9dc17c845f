//! Time derivatives of sampled series by finite differences: velocities and accelerations of the
//! imported tracks, and the angular velocity of an orientation series.

use glam::DQuat;

/// Time derivative by central differences (one-sided at the ends), like `numpy.gradient`.
pub fn gradient<const N: usize>(values: &[[f64; N]], t: &[f64]) -> Vec<[f64; N]> {
    let n = values.len();
    (0..n)
        .map(|k| {
            let (a, b) = (k.saturating_sub(1), (k + 1).min(n - 1));
            if a == b {
                return [0.0; N];
            }
            std::array::from_fn(|i| (values[b][i] - values[a][i]) / (t[b] - t[a]))
        })
        .collect()
}

/// World-frame angular velocity of a quaternion (x, y, z, w) series: omega = 2 (dq/dt) q*.
pub fn angular_velocity(q: &[[f64; 4]], t: &[f64]) -> Vec<[f64; 3]> {
    let dq = gradient(q, t);
    q.iter()
        .zip(&dq)
        .map(|(q, dq)| {
            // The derivative is not a unit quaternion: `*` is the plain Hamilton product.
            let product = DQuat::from_array(*dq) * DQuat::from_array(*q).conjugate();
            [2.0 * product.x, 2.0 * product.y, 2.0 * product.z]
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use glam::DVec3;

    use super::*;

    fn dist(a: [f64; 3], b: [f64; 3]) -> f64 {
        ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
    }

    #[test]
    fn gradient_is_central_inside_and_one_sided_at_the_ends() {
        let t = [0.0, 1.0, 3.0, 4.0];
        let x = [[0.0], [1.0], [9.0], [16.0]];
        assert_eq!(gradient(&x, &t), [[1.0], [3.0], [5.0], [7.0]]);
        assert_eq!(gradient(&[[2.0, 3.0]], &[0.5]), [[0.0, 0.0]]);
    }

    #[test]
    fn angular_velocity_of_a_steady_turn() {
        // 0.5 rad/s about world Y, sampled at 100 Hz.
        let t: Vec<f64> = (0..50).map(|k| k as f64 * 0.01).collect();
        let q: Vec<[f64; 4]> = t
            .iter()
            .map(|t| [0.0, (0.25 * t).sin(), 0.0, (0.25 * t).cos()])
            .collect();
        for w in angular_velocity(&q, &t) {
            assert!(dist(w, [0.0, 0.5, 0.0]) < 1e-4, "{w:?}");
        }
        // Motive's (x, y, z, w) order is glam's: a quarter turn about Y takes X to -Z.
        let quarter = (std::f64::consts::PI / 4.0).sin_cos();
        let v = DQuat::from_array([0.0, quarter.0, 0.0, quarter.1]).mul_vec3(DVec3::X);
        assert!(dist(v.to_array(), [0.0, 0.0, -1.0]) < 1e-12, "{v:?}");
    }
}
