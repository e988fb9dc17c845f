//! [`Model`]: topology and rest data shared by every environment (Warp's `Model`): particles of
//! the two-layer package and of the cups, membrane triangles with their rest `Dm`, bending edges
//! with their rest angles, the disc's shape, and the masses. Positions are stored as offsets from
//! per-environment anchors (package origin, tool cup point), so one model serves environments
//! placed differently (see [`crate::Placement`]).

use std::collections::HashMap;

use glam::DVec3;

use crate::config::{InertiaModel, SceneConfig};
use crate::error::SimError;
use crate::forces::TriangleRest;

/// Pitch of the real marker grid (2 inches, m).
pub const MARKER_PITCH_M: f32 = 0.0508;

/// The reference's 42 "sampled grid points" (its loss points): the nominal 6 x 7 marker grid,
/// row-major with rows along the package's short side (world z) and columns along its long side
/// (x), [`MARKER_PITCH_M`] apart, starting at `package_origin` and at its height. On a grid of
/// [6 + 5p, 7 + 6p] vertices they lie on the upper sheet's vertices at rest (every (p + 1)-th);
/// on any grid they can be embedded in the sheet ([`crate::Simulator::embed`]).
pub fn marker_grid_points(package_origin: [f32; 3]) -> Vec<[f32; 3]> {
    (0..42)
        .map(|m| {
            let (row, col) = (m / 7, m % 7);
            [
                package_origin[0] + col as f32 * MARKER_PITCH_M,
                package_origin[1],
                package_origin[2] + row as f32 * MARKER_PITCH_M,
            ]
        })
        .collect()
}

/// A membrane triangle: particle indices and rest data.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Triangle {
    /// Particle indices (vertex 0, 1, 2).
    pub idx: [u32; 3],
    /// Rest pose.
    pub rest: TriangleRest,
}

/// A bending element: (o0, o1, v0, v1) as Warp's `add_edge`, and its rest dihedral angle.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BendingEdge {
    /// Particle indices: opposite vertices o0, o1, then the hinge edge v0, v1.
    pub idx: [u32; 4],
    /// Rest angle (rad), from the build-time positions.
    pub rest_angle: f32,
}

/// The rigid disc's shape (a solid cylinder whose axis is the body y axis, centred on the COM).
#[derive(Clone, Debug, PartialEq)]
pub struct DiscShape {
    /// Radius (m).
    pub radius: f32,
    /// Half the thickness (m).
    pub half_height: f32,
    /// Body-frame points on both rims, used for disc-ground contact.
    pub rim_points: Vec<[f32; 3]>,
}

/// Mass properties of the disc for one environment.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DiscMass {
    /// Mass (kg).
    pub mass: f32,
    /// Principal moments in the body frame (kg·m²), axis y is the disc axis.
    pub inertia: [f32; 3],
}

/// Topology and rest data shared by all environments.
#[derive(Clone, Debug)]
pub struct Model {
    /// The scene this model was built from.
    pub config: SceneConfig,
    /// Vertices per layer [rows along the short side (world z), columns along the long side (x)].
    pub grid: [usize; 2],
    /// Cell size [along world x, along world z] (m).
    pub cell: [f32; 2],
    /// Contact radius of every particle (m).
    pub particle_radius: f32,
    /// Particles in one layer.
    pub layer_size: usize,
    /// Package particles (both layers); they come first. The lower sheet ("top" in the reference
    /// code) is `0..layer_size`, the upper sheet ("bottom", attached to the cups)
    /// `layer_size..2·layer_size`.
    pub num_package: usize,
    /// Particles per cup.
    pub cup_size: usize,
    /// All cup particles, after the package particles.
    pub num_cup: usize,
    /// Rest offsets: package particles relative to the package origin, cup particles relative to
    /// the tool's cup point (world orientation, m).
    pub rest_offsets: Vec<[f32; 3]>,
    /// Package triangles: both layers, then the perimeter seam band.
    pub package_triangles: Vec<Triangle>,
    /// Index range of the upper-sheet (cup side) triangles within `package_triangles`.
    pub upper_sheet_triangles: std::ops::Range<usize>,
    /// Index range of the lower-sheet triangles within `package_triangles`.
    pub lower_sheet_triangles: std::ops::Range<usize>,
    /// Cup shell triangles.
    pub cup_triangles: Vec<Triangle>,
    /// Interior bending edges of the package (layers and seam band; boundary edges are dropped,
    /// Warp skips them at run time).
    pub package_edges: Vec<BendingEdge>,
    /// Interior bending edges of the cups.
    pub cup_edges: Vec<BendingEdge>,
    /// Mass of one package particle (kg).
    pub package_particle_mass: f32,
    /// Mass of one cup particle (kg).
    pub cup_particle_mass: f32,
    /// The disc's shape.
    pub disc: DiscShape,
    /// Triangles around each package vertex (for the block-descent integrator).
    pub adjacency: VertexAdjacency,
}

/// A package triangle seen from one of its corners, with what a block-descent sweep needs of its
/// rest shape computed once.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CornerTriangle {
    /// Particle indices (vertex 0, 1, 2).
    pub idx: [u32; 3],
    /// Which of them the vertex is (0-2).
    pub corner: u8,
    /// The rest shape's `Dm`.
    pub dm: [[f32; 2]; 2],
    /// Rest area `A0` and `1 / A0`, in f32 as [`TriangleRest::inv_rest_area`].
    pub rest_area: (f32, f32),
}

/// For each package vertex, the package triangles it belongs to (compressed rows: vertex `i`'s
/// entries are `starts[i]..starts[i + 1]`).
#[derive(Clone, Debug, PartialEq)]
pub struct VertexAdjacency {
    /// Row starts into `triangles`, one per package vertex plus one.
    pub triangle_starts: Vec<u32>,
    /// The triangles, in the order of `Model::package_triangles` within each row.
    pub triangles: Vec<CornerTriangle>,
}

impl VertexAdjacency {
    fn new(num_vertices: usize, triangles: &[Triangle]) -> Self {
        let mut rows = vec![Vec::new(); num_vertices];
        for tri in triangles {
            let inv_rest_area = tri.rest.inv_rest_area();
            for (corner, &v) in tri.idx.iter().enumerate() {
                rows[v as usize].push(CornerTriangle {
                    idx: tri.idx,
                    corner: corner as u8,
                    dm: tri.rest.dm,
                    rest_area: (1.0 / inv_rest_area, inv_rest_area),
                });
            }
        }
        let mut triangle_starts = vec![0u32];
        let mut flat = Vec::new();
        for row in rows {
            flat.extend(row);
            triangle_starts.push(flat.len() as u32);
        }
        VertexAdjacency {
            triangle_starts,
            triangles: flat,
        }
    }

    /// Triangles around vertex `i`.
    pub fn triangles_of(&self, i: usize) -> &[CornerTriangle] {
        &self.triangles[self.triangle_starts[i] as usize..self.triangle_starts[i + 1] as usize]
    }
}

/// Rest dihedral angle as Warp's builder computes it (f64, clamped).
fn rest_dihedral(x: [[f64; 3]; 4]) -> f64 {
    let [x0, x1, x2, x3] = x.map(DVec3::from_array);
    let n1 = (x2 - x0).cross(x3 - x0);
    let n2 = (x3 - x1).cross(x2 - x1);
    let (l1, l2) = (n1.length(), n2.length());
    if l1 < 1e-12 || l2 < 1e-12 {
        return 0.0;
    }
    let cos = (n1.dot(n2) / (l1 * l2)).clamp(-1.0, 1.0);
    let s = n2.cross(n1).dot(x3 - x2);
    cos.acos() * if s < 0.0 { -1.0 } else { 1.0 }
}

/// Warp's `MeshAdjacency` + `add_edge`: every edge shared by two triangles of `tris` becomes one
/// bending element (o0, o1, v0, v1), in first-met order.
fn bending_edges(tris: &[[u32; 3]], pos: &[[f64; 3]]) -> Vec<BendingEdge> {
    let mut order: Vec<(u32, u32)> = Vec::new();
    let mut edges: HashMap<(u32, u32), [i64; 4]> = HashMap::new();
    for t in tris {
        for (a, b, o) in [(t[0], t[1], t[2]), (t[1], t[2], t[0]), (t[2], t[0], t[1])] {
            let key = (a.min(b), a.max(b));
            match edges.get_mut(&key) {
                Some(e) => e[1] = o as i64,
                None => {
                    edges.insert(key, [o as i64, -1, a as i64, b as i64]);
                    order.push(key);
                }
            }
        }
    }
    order
        .iter()
        .filter_map(|key| {
            let e = edges[key];
            if e[1] < 0 {
                return None;
            }
            let idx = e.map(|i| i as u32);
            let x = idx.map(|i| pos[i as usize]);
            Some(BendingEdge {
                idx,
                rest_angle: rest_dihedral(x) as f32,
            })
        })
        .collect()
}

fn make_triangles(tris: &[[u32; 3]], pos: &[[f64; 3]]) -> Vec<Triangle> {
    tris.iter()
        .filter_map(|t| {
            let rest = TriangleRest::from_positions(
                pos[t[0] as usize],
                pos[t[1] as usize],
                pos[t[2] as usize],
            )?;
            Some(Triangle { idx: *t, rest })
        })
        .collect()
}

impl Model {
    /// Builds the package, the cups and the disc shape from a scene config.
    pub fn new(config: &SceneConfig) -> Result<Self, SimError> {
        config.validate("scene config")?;
        let p = &config.package;
        let (rows, cols) = (p.grid[0], p.grid[1]);
        let (dim_x, dim_y) = (cols - 1, rows - 1);
        let cell_x = p.size_m[1] as f64 / dim_x as f64;
        let cell_y = p.size_m[0] as f64 / dim_y as f64;
        let thickness = p.thickness_m as f64;
        let particle_radius = p
            .particle_radius_m
            .unwrap_or_else(|| cell_x.max(cell_y).max(thickness) as f32);
        let layer_size = rows * cols;
        let num_package = 2 * layer_size;

        // Package: local (x·cell_x, y·cell_y, ±t/2) rotated +90° about world x → world offset
        // (x·cell_x, ∓t/2, y·cell_y); layer 0 ("top", local +t/2) is the lower sheet.
        let mut pos: Vec<[f64; 3]> = Vec::with_capacity(num_package);
        for layer_y in [-thickness / 2.0, thickness / 2.0] {
            for y in 0..rows {
                for x in 0..cols {
                    pos.push([x as f64 * cell_x, layer_y, y as f64 * cell_y]);
                }
            }
        }
        let v = |layer: usize, x: usize, y: usize| (layer * layer_size + y * cols + x) as u32;
        let mut layer_tris: [Vec<[u32; 3]>; 2] = [Vec::new(), Vec::new()];
        for (layer, tris) in layer_tris.iter_mut().enumerate() {
            for y in 1..=dim_y {
                for x in 1..=dim_x {
                    tris.push([
                        v(layer, x - 1, y - 1),
                        v(layer, x, y - 1),
                        v(layer, x - 1, y),
                    ]);
                    tris.push([v(layer, x, y - 1), v(layer, x, y), v(layer, x - 1, y)]);
                }
            }
        }
        // Seam band around the perimeter (reference `process_grid_edges`), B = upper, T = lower.
        let sides: [Vec<(usize, usize)>; 4] = [
            (0..=dim_x).map(|x| (x, 0)).collect(),
            (0..=dim_y).map(|y| (0, y)).collect(),
            (0..=dim_x).map(|x| (x, dim_y)).collect(),
            (0..=dim_y).map(|y| (dim_x, y)).collect(),
        ];
        let strips: Vec<Vec<[u32; 3]>> = sides
            .iter()
            .map(|side| {
                side.windows(2)
                    .flat_map(|w| {
                        let ((px, py), (cx, cy)) = (w[0], w[1]);
                        let (bp, bc, tp, tc) =
                            (v(1, px, py), v(1, cx, cy), v(0, px, py), v(0, cx, cy));
                        [[bp, bc, tp], [bc, tc, tp]]
                    })
                    .collect()
            })
            .collect();

        let mut package_triangles = make_triangles(&layer_tris[0], &pos);
        let upper_start = package_triangles.len();
        package_triangles.extend(make_triangles(&layer_tris[1], &pos));
        let upper_sheet_triangles = upper_start..package_triangles.len();
        let lower_sheet_triangles = 0..upper_start;
        let mut package_edges = bending_edges(&layer_tris[0], &pos);
        package_edges.extend(bending_edges(&layer_tris[1], &pos));
        for strip in &strips {
            package_triangles.extend(make_triangles(strip, &pos));
            package_edges.extend(bending_edges(strip, &pos));
        }

        // Cups: flat annuli around the tool's cup point.
        let c = &config.cups;
        let cup_size = c.samples * c.rings;
        let mut cup_tris = Vec::new();
        for (cup, angle) in c.angles_deg.iter().enumerate() {
            let a = (*angle as f64).to_radians();
            let centre = [
                c.circle_radius_m as f64 * a.sin(),
                0.0,
                c.circle_radius_m as f64 * a.cos(),
            ];
            let start = num_package + cup * cup_size;
            for h in 0..c.rings {
                let radius = c.inner_radius_m as f64
                    + (c.outer_radius_m - c.inner_radius_m) as f64 * h as f64 / c.rings as f64;
                for r in 0..c.samples {
                    let th = std::f64::consts::TAU * r as f64 / c.samples as f64;
                    pos.push([
                        centre[0] + radius * th.cos(),
                        0.0,
                        centre[2] + radius * th.sin(),
                    ]);
                }
            }
            let id = |h: usize, r: usize| (start + h * c.samples + r % c.samples) as u32;
            for h in 0..c.rings - 1 {
                for r in 0..c.samples {
                    cup_tris.push([id(h, r), id(h, r + 1), id(h + 1, r)]);
                    cup_tris.push([id(h, r + 1), id(h + 1, r + 1), id(h + 1, r)]);
                }
            }
        }
        let num_cup = c.angles_deg.len() * cup_size;
        let cup_triangles = make_triangles(&cup_tris, &pos);
        let cup_edges = bending_edges(&cup_tris, &pos);

        let package_particle_mass = match (p.particle_mass_kg, p.film_mass_kg) {
            (Some(m), _) => m,
            (None, Some(total)) => total / num_package as f32,
            (None, None) => unreachable!("validated: one mass key is set"),
        };
        let d = &config.disc;
        let hh = d.thickness_m / 2.0;
        let rim_points = [hh, -hh]
            .iter()
            .flat_map(|&y| {
                (0..d.rim_points).map(move |k| {
                    let th = std::f32::consts::TAU * k as f32 / d.rim_points as f32;
                    [d.radius_m * th.cos(), y, d.radius_m * th.sin()]
                })
            })
            .collect();
        let adjacency = VertexAdjacency::new(num_package, &package_triangles);
        Ok(Model {
            adjacency,
            config: config.clone(),
            grid: [rows, cols],
            cell: [cell_x as f32, cell_y as f32],
            particle_radius,
            layer_size,
            num_package,
            cup_size,
            num_cup,
            rest_offsets: pos.iter().map(|q| q.map(|x| x as f32)).collect(),
            package_triangles,
            upper_sheet_triangles,
            lower_sheet_triangles,
            cup_triangles,
            package_edges,
            cup_edges,
            package_particle_mass,
            cup_particle_mass: c.cup_mass_kg / cup_size as f32,
            disc: DiscShape {
                radius: d.radius_m,
                half_height: hh,
                rim_points,
            },
        })
    }

    /// Total particle count (package + cups).
    pub fn num_particles(&self) -> usize {
        self.num_package + self.num_cup
    }

    /// Index of the first cup particle.
    pub fn cup_start(&self) -> usize {
        self.num_package
    }

    /// Index of the upper-sheet (cup side, "bottom" in the reference code) particle at grid
    /// (row along the short side, column along the long side).
    pub fn upper_sheet_particle(&self, row: usize, col: usize) -> usize {
        self.layer_size + row * self.grid[1] + col
    }

    /// Number of cups.
    pub fn num_cups(&self) -> usize {
        self.num_cup / self.cup_size
    }

    /// Disc mass and inertia for an object of `object_mass_kg`, following the configured rule.
    pub fn disc_mass(&self, object_mass_kg: f32) -> DiscMass {
        self.disc_mass_with_scale(object_mass_kg, None)
    }

    /// Disc mass and inertia for an object of `object_mass_kg` scaled by `mass_scale` (`None`:
    /// the scene's `disc.mass_scale`).
    pub fn disc_mass_with_scale(&self, object_mass_kg: f32, mass_scale: Option<f32>) -> DiscMass {
        let d = &self.config.disc;
        let (r, h) = (d.radius_m, d.thickness_m);
        let scaled = mass_scale.unwrap_or(d.mass_scale) * object_mass_kg;
        let cylinder = |m: f32, r: f32| {
            let side = m * (3.0 * r * r + h * h) / 12.0;
            [side, m * r * r / 2.0, side]
        };
        let mass = scaled + d.extra_mass_kg;
        let inertia = match d.inertia {
            InertiaModel::Reference => {
                // The study passes the diameter where the radius belongs: r_used = 2r.
                let wrong = 2.0 * r;
                let side = scaled / 12.0 * (h * h + 3.0 * wrong * wrong);
                let axis = scaled / 12.0 * (6.0 * wrong * wrong);
                let extra = cylinder(d.extra_mass_kg, r);
                [side + extra[0], axis + extra[1], side + extra[2]]
            }
            InertiaModel::SolidCylinder => cylinder(mass, r),
        };
        DiscMass { mass, inertia }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn model(grid: [usize; 2]) -> Model {
        let mut c = SceneConfig::preset("reference").unwrap();
        c.package.grid = grid;
        Model::new(&c).unwrap()
    }

    #[test]
    fn reference_counts_match_the_study() {
        let m = model([21, 25]);
        assert_eq!(m.num_package, 1050);
        assert_eq!(m.num_cup, 96);
        assert_eq!(m.package_triangles.len(), 2096);
        assert_eq!(m.upper_sheet_triangles.len(), 960);
        assert_eq!(m.cup_triangles.len(), 4 * 32);
        assert!((m.particle_radius - 0.0127).abs() < 1e-6);
        assert!((m.cell[0] - 0.0127).abs() < 1e-6 && (m.cell[1] - 0.0127).abs() < 1e-6);
        // Interior edges per layer of an a x b cell grid: a(b−1) + b(a−1) + a·b (diagonals);
        // a seam strip of n quads has 2n − 1 interior edges.
        let (a, b) = (24, 20);
        let layer = a * (b - 1) + b * (a - 1) + a * b;
        let strips = 2 * (2 * a - 1) + 2 * (2 * b - 1);
        assert_eq!(m.package_edges.len(), 2 * layer + strips);
        assert!(m.package_edges.iter().all(|e| e.rest_angle.abs() < 1e-6));
        // Cup ring radii 0.015, 0.02333, 0.03167 around the cup centre at +z.
        let o = m.rest_offsets[m.cup_start() + 16];
        assert!(((o[0]).hypot(o[2] - 0.05) - 0.031_667).abs() < 1e-5);
    }

    #[test]
    fn table2_sizes() {
        for (grid, n) in [
            ([11, 13], 286),
            ([16, 19], 608),
            ([21, 25], 1050),
            ([26, 31], 1612),
        ] {
            assert_eq!(model(grid).num_package, n);
        }
    }

    #[test]
    fn upper_sheet_is_above_and_markers_on_pitch() {
        let m = model([21, 25]);
        let lower = m.rest_offsets[0];
        let upper = m.rest_offsets[m.upper_sheet_particle(0, 0)];
        assert!(upper[1] > lower[1]);
        // Grid [21, 25] = [6 + 5p, 7 + 6p] with p = 3: every 4th upper-sheet vertex is a marker.
        let marks = marker_grid_points([0.0; 3]);
        assert_eq!(marks.len(), 42);
        for (k, mark) in marks.iter().enumerate() {
            let vertex = m.rest_offsets[m.upper_sheet_particle((k / 7) * 4, (k % 7) * 4)];
            assert!((mark[0] - vertex[0]).abs() < 1e-5 && (mark[2] - vertex[2]).abs() < 1e-5);
        }
        assert!((marks[41][0] - 0.3048).abs() < 1e-6 && (marks[41][2] - 0.254).abs() < 1e-6);
    }

    #[test]
    fn disc_inertia_reference_and_physical() {
        let m = model([11, 13]);
        let d = m.disc_mass(0.569_592);
        assert!((d.mass - 57.260).abs() < 1e-2);
        assert!(
            (d.inertia[0] - 0.3661).abs() < 2e-3 && (d.inertia[1] - 0.7300).abs() < 2e-3,
            "{d:?}"
        );
        let p = Model::new(&SceneConfig::preset("physical").unwrap()).unwrap();
        let d = p.disc_mass(0.5);
        // Solid cylinder r = 0.08: I_axis = m r² / 2 = 0.0016.
        assert!((d.mass - 0.5).abs() < 1e-6 && (d.inertia[1] - 0.0016).abs() < 1e-7);
        assert!((p.package_particle_mass * 608.0 - 0.022).abs() < 1e-6);
    }
}
