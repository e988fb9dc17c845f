//! The least-squares rigid motion mapping one point set onto another (Kabsch).

use nalgebra::{Matrix3, Vector3};

/// Least-squares rotation and centroids mapping points `from` onto `to` (Kabsch); `None` for
/// fewer than three points or points (nearly) in a line, where the rotation is undetermined.
pub(crate) fn rigid_fit(
    from: &[[f64; 3]],
    to: &[[f64; 3]],
) -> Option<(Matrix3<f64>, Vector3<f64>, Vector3<f64>)> {
    if from.len() < 3 {
        return None;
    }
    let centre = |points: &[[f64; 3]]| {
        points
            .iter()
            .map(|p| Vector3::from(*p))
            .sum::<Vector3<f64>>()
            / points.len() as f64
    };
    let (from_centre, to_centre) = (centre(from), centre(to));
    let covariance: Matrix3<f64> = from
        .iter()
        .zip(to)
        .map(|(a, b)| {
            (Vector3::from(*a) - from_centre) * (Vector3::from(*b) - to_centre).transpose()
        })
        .sum();
    let svd = covariance.svd(true, true);
    // Spread along the second principal direction below ~1 mm: the points lie on a line.
    if svd.singular_values[1] < 1e-6 {
        return None;
    }
    let (u, v_t) = (svd.u?, svd.v_t?);
    let mut correction = Matrix3::identity();
    correction[(2, 2)] = (v_t.transpose() * u.transpose()).determinant().signum();
    Some((
        v_t.transpose() * correction * u.transpose(),
        from_centre,
        to_centre,
    ))
}
