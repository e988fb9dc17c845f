//! Time derivatives of sampled tracks, shared by the Motive import and the robot trajectory files.

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
