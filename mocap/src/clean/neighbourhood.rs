//! A hidden marker carried along with the tracks around it (their rigid motion, or their mean
//! displacement).

use nalgebra::Vector3;

use super::geometry::distance;
use super::{rigid_fit, Series};

/// Other markers' tracks, used to carry a hidden marker along with the package around it.
pub struct Neighbourhood<'a> {
    /// Observed tracks (no filled samples).
    pub tracks: &'a [Series],
    /// How many of the nearest tracks to use.
    pub count: usize,
    /// Only tracks this close (m) to the point count.
    pub radius_m: f64,
}

impl Neighbourhood<'_> {
    /// Where `point`, at frame `from` and belonging to track `own` (left out), is at frame `to` if it
    /// moved with up to `count` nearby tracks seen at both frames: with three or more (not in a
    /// line), the rigid motion that best maps their positions (Kabsch), so a package that turns is
    /// followed; with one or two, their mean displacement; with none, `None`.
    pub fn transport(
        &self,
        own: usize,
        from: usize,
        to: usize,
        point: [f64; 3],
    ) -> Option<[f64; 3]> {
        let mut near: Vec<(f64, [f64; 3], [f64; 3])> = self
            .tracks
            .iter()
            .enumerate()
            .filter(|&(i, _)| i != own)
            .filter_map(|(_, t)| match (t[from], t[to]) {
                (Some(a), Some(b)) => Some((distance(a, point), a, b)),
                _ => None,
            })
            .filter(|&(d, _, _)| d <= self.radius_m)
            .collect();
        if near.is_empty() {
            return None;
        }
        near.sort_by(|a, b| a.0.total_cmp(&b.0));
        near.truncate(self.count);
        let from_points: Vec<[f64; 3]> = near.iter().map(|n| n.1).collect();
        let to_points: Vec<[f64; 3]> = near.iter().map(|n| n.2).collect();
        let moved = match rigid_fit(&from_points, &to_points) {
            Some((rotation, from_centre, to_centre)) => {
                let p = rotation * (Vector3::from(point) - from_centre) + to_centre;
                [p.x, p.y, p.z]
            }
            None => {
                let n = from_points.len() as f64;
                std::array::from_fn(|axis| {
                    point[axis]
                        + from_points
                            .iter()
                            .zip(&to_points)
                            .map(|(a, b)| b[axis] - a[axis])
                            .sum::<f64>()
                            / n
                })
            }
        };
        Some(moved)
    }
}
