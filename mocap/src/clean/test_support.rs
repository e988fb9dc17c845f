//! Helpers shared by the cleaning tests: a tolerance comparison and a synthetic moving marker.

use super::Series;

pub(super) fn close(a: f64, b: f64, tol: f64) -> bool {
    (a - b).abs() <= tol
}

/// A marker moving along x at `speed` m per frame, seen in `frames`.
pub(super) fn moving(
    n: usize,
    start: [f64; 3],
    speed: f64,
    frames: impl Fn(usize) -> bool,
) -> Series {
    (0..n)
        .map(|k| frames(k).then(|| [start[0] + speed * k as f64, start[1], start[2]]))
        .collect()
}
