//! Surface-point embedding: arbitrary points (e.g. recorded marker positions at t0) attached to one
//! sheet of the package by nearest triangle and barycentric coordinates at rest, then evaluated on
//! the deformed sheet of any environment. Used for the calibration loss and the simulate CSVs.

use crate::model::Model;

/// The package's two film layers.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Sheet {
    /// The layer the cups hold.
    Upper,
    /// The layer facing away from the cups (the one a package lies on).
    Lower,
}

/// One embedded point: a triangle of a sheet and barycentric weights of the closest point.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EmbeddedPoint {
    /// Particle indices of the triangle.
    pub triangle: [u32; 3],
    /// Barycentric weights (sum 1, all ≥ 0).
    pub weights: [f32; 3],
    /// Distance from the original point to the sheet at rest (m); the evaluated point lies on the
    /// sheet, this offset is dropped.
    pub rest_distance: f32,
}

/// A set of embedded points.
#[derive(Clone, Debug, PartialEq)]
pub struct SurfaceEmbedding {
    /// The points, in input order.
    pub points: Vec<EmbeddedPoint>,
}

/// Closest point on triangle (a, b, c) to p, as barycentric weights (Ericson, Real-Time
/// Collision Detection, 5.1.5).
fn closest_barycentric(p: [f64; 3], a: [f64; 3], b: [f64; 3], c: [f64; 3]) -> [f64; 3] {
    let sub = |u: [f64; 3], v: [f64; 3]| [u[0] - v[0], u[1] - v[1], u[2] - v[2]];
    let dot = |u: [f64; 3], v: [f64; 3]| u[0] * v[0] + u[1] * v[1] + u[2] * v[2];
    let (ab, ac, ap) = (sub(b, a), sub(c, a), sub(p, a));
    let (d1, d2) = (dot(ab, ap), dot(ac, ap));
    if d1 <= 0.0 && d2 <= 0.0 {
        return [1.0, 0.0, 0.0];
    }
    let bp = sub(p, b);
    let (d3, d4) = (dot(ab, bp), dot(ac, bp));
    if d3 >= 0.0 && d4 <= d3 {
        return [0.0, 1.0, 0.0];
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        let v = d1 / (d1 - d3);
        return [1.0 - v, v, 0.0];
    }
    let cp = sub(p, c);
    let (d5, d6) = (dot(ab, cp), dot(ac, cp));
    if d6 >= 0.0 && d5 <= d6 {
        return [0.0, 0.0, 1.0];
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        let w = d2 / (d2 - d6);
        return [1.0 - w, 0.0, w];
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
        let w = (d4 - d3) / ((d4 - d3) + (d5 - d6));
        return [0.0, 1.0 - w, w];
    }
    let denom = 1.0 / (va + vb + vc);
    let (v, w) = (vb * denom, vc * denom);
    [1.0 - v - w, v, w]
}

impl Model {
    /// Embeds points given relative to the package origin into `sheet` at rest (nearest
    /// triangle; the first one wins ties).
    pub fn embed_in_sheet(&self, sheet: Sheet, points: &[[f32; 3]]) -> SurfaceEmbedding {
        let rest = |i: u32| self.rest_offsets[i as usize].map(|c| c as f64);
        let range = match sheet {
            Sheet::Upper => self.upper_sheet_triangles.clone(),
            Sheet::Lower => self.lower_sheet_triangles.clone(),
        };
        let tris = &self.package_triangles[range];
        let points = points
            .iter()
            .map(|p| {
                let p = p.map(|c| c as f64);
                let mut best = (f64::INFINITY, tris[0].idx, [1.0, 0.0, 0.0]);
                for t in tris {
                    let [a, b, c] = t.idx.map(rest);
                    let w = closest_barycentric(p, a, b, c);
                    let q: [f64; 3] =
                        std::array::from_fn(|k| w[0] * a[k] + w[1] * b[k] + w[2] * c[k]);
                    let d2 = (0..3).map(|k| (q[k] - p[k]).powi(2)).sum::<f64>();
                    if d2 < best.0 {
                        best = (d2, t.idx, w);
                    }
                }
                EmbeddedPoint {
                    triangle: best.1,
                    weights: best.2.map(|w| w as f32),
                    rest_distance: best.0.sqrt() as f32,
                }
            })
            .collect();
        SurfaceEmbedding { points }
    }
}

impl EmbeddedPoint {
    /// The point on a deformed configuration given by `position(particle)`.
    pub fn evaluate_with(&self, position: impl Fn(usize) -> [f32; 3]) -> [f32; 3] {
        let [a, b, c] = self.triangle.map(|i| position(i as usize));
        let w = self.weights;
        std::array::from_fn(|k| w[0] * a[k] + w[1] * b[k] + w[2] * c[k])
    }
}

impl SurfaceEmbedding {
    /// This set's points followed by `other`'s.
    pub fn chain(mut self, other: SurfaceEmbedding) -> Self {
        self.points.extend(other.points);
        self
    }

    /// The embedded points on a deformed configuration (`positions` of every particle).
    pub fn evaluate(&self, positions: &[[f32; 3]]) -> Vec<[f32; 3]> {
        self.points
            .iter()
            .map(|e| e.evaluate_with(|i| positions[i]))
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::SceneConfig;

    #[test]
    fn vertices_and_interior_points_round_trip() {
        let mut c = SceneConfig::preset("reference").unwrap();
        c.package.grid = [11, 13];
        let m = Model::new(&c).unwrap();
        let v = m.upper_sheet_particle(3, 4);
        let interior = [0.031, m.rest_offsets[v][1] + 0.002, 0.047];
        let outside = [-0.05, 0.0, 0.1];
        let e = m.embed_in_sheet(Sheet::Upper, &[m.rest_offsets[v], interior, outside]);
        let at_rest = e.evaluate(&m.rest_offsets);
        for k in 0..3 {
            assert!((at_rest[0][k] - m.rest_offsets[v][k]).abs() < 1e-6);
        }
        assert!((at_rest[1][0] - 0.031).abs() < 1e-6 && (at_rest[1][2] - 0.047).abs() < 1e-6);
        assert!((e.points[1].rest_distance - 0.002).abs() < 1e-6);
        // Outside the sheet: clamped to the edge x = 0.
        assert!(at_rest[2][0].abs() < 1e-6 && (e.points[2].rest_distance - 0.05).abs() < 1e-3);
        // Moving the whole sheet moves the points with it.
        let shifted: Vec<[f32; 3]> = m
            .rest_offsets
            .iter()
            .map(|p| [p[0], p[1] + 1.0, p[2]])
            .collect();
        let moved = e.evaluate(&shifted);
        assert!((moved[1][1] - at_rest[1][1] - 1.0).abs() < 1e-6);
    }

    #[test]
    fn a_point_embeds_in_the_sheet_asked_for() {
        let mut c = SceneConfig::preset("reference").unwrap();
        c.package.grid = [11, 13];
        let m = Model::new(&c).unwrap();
        let upper = m.rest_offsets[m.upper_sheet_particle(3, 4)];
        // The same point in plan, half-way between the layers: each sheet takes its own triangle.
        let lower_y = m.rest_offsets[3 * m.grid[1] + 4][1];
        let between = [upper[0], 0.5 * (upper[1] + lower_y), upper[2]];
        let on_upper = m
            .embed_in_sheet(Sheet::Upper, &[between])
            .evaluate(&m.rest_offsets)[0];
        let on_lower = m
            .embed_in_sheet(Sheet::Lower, &[between])
            .evaluate(&m.rest_offsets)[0];
        assert!((on_upper[1] - upper[1]).abs() < 1e-6, "{on_upper:?}");
        assert!((on_lower[1] - lower_y).abs() < 1e-6, "{on_lower:?}");
        let lower = m.embed_in_sheet(Sheet::Lower, &[between]);
        assert!(lower.points[0]
            .triangle
            .iter()
            .all(|&i| (i as usize) < m.layer_size));
        let both = m
            .embed_in_sheet(Sheet::Upper, &[between])
            .chain(lower)
            .evaluate(&m.rest_offsets);
        assert_eq!(both, vec![on_upper, on_lower]);
    }
}
