//! The film's elements around a vertex for the block-descent solver: membrane triangles (per
//! vertex, at the current iterate; per element for a global step's residual) and bending (per
//! element, at the start of each sweep), per
//! environment across lanes or, for a single-environment block, [`ELEMENT_LANES`] elements
//! side by side (see [`crate::solvers::across_elements`]).

use crate::forces::bending_element;
use crate::math::{Lanes, Real, Sym3, V3};
use crate::model::Model;
use crate::solvers::across_elements::{gather_elements, gather_triangle_rest, E8, ELEMENT_LANES};

use super::vertex::{triangle_forces, triangle_vertex, LaneCorners, Membrane};
use super::BlockDescent;

type L<const W: usize> = Lanes<W>;

/// Lane `e` of `v`, in every lane of the block's vectors (used with one-lane blocks).
#[inline(always)]
fn lane_vector<const W: usize>(v: &V3<E8>, e: usize) -> V3<L<W>> {
    V3::new(L::splat(v.x.0[e]), L::splat(v.y.0[e]), L::splat(v.z.0[e]))
}

/// Lane `e` of `m`, in every lane of the block's matrices (used with one-lane blocks).
#[inline(always)]
fn lane_matrix<const W: usize>(m: &Sym3<E8>, e: usize) -> Sym3<L<W>> {
    Sym3 {
        m: [
            L::splat(m.m[0].0[e]),
            L::splat(m.m[1].0[e]),
            L::splat(m.m[2].0[e]),
            L::splat(m.m[3].0[e]),
            L::splat(m.m[4].0[e]),
            L::splat(m.m[5].0[e]),
        ],
    }
}

/// Lane 0's membrane material in every lane of [`E8`] (the single-environment paths).
#[inline(always)]
fn lane0_membrane<const W: usize>(m: Membrane<L<W>>) -> Membrane<E8> {
    Membrane {
        mu: E8::splat(m.mu.0[0]),
        lambda: E8::splat(m.lambda.0[0]),
        damp: E8::splat(m.damp.0[0]),
        alpha: E8::splat(m.alpha.0[0]),
    }
}

impl<const W: usize> BlockDescent<W> {
    /// Adds the membrane force and stiffness of package vertex `i` to `force` and `stiff`, one
    /// triangle at a time in adjacency order.
    #[inline(always)]
    #[allow(clippy::too_many_arguments)]
    pub(super) fn add_membrane(
        &self,
        model: &Model,
        x: &[V3<L<W>>],
        i: usize,
        membrane: Membrane<L<W>>,
        inv_h: L<W>,
        force: &mut V3<L<W>>,
        stiff: &mut Sym3<L<W>>,
    ) {
        if W == 1 {
            return self.add_membrane_across_elements(model, x, i, membrane, inv_h, force, stiff);
        }
        for tri in model.adjacency.triangles_of(i) {
            let [a, b, c] = tri.idx.map(|j| j as usize);
            let (area, inv_area) = tri.rest_area;
            let (f, kk) = triangle_vertex(
                [x[a], x[b], x[c]],
                [self.x_rate[a], self.x_rate[b], self.x_rate[c]],
                tri.corner as usize,
                [
                    [L::splat(tri.dm[0][0]), L::splat(tri.dm[0][1])],
                    [L::splat(tri.dm[1][0]), L::splat(tri.dm[1][1])],
                ],
                (L::splat(area), L::splat(inv_area)),
                membrane,
                inv_h,
            );
            *force += f;
            stiff.add_assign(kk);
        }
    }

    /// [`Self::add_membrane`] for a single-environment block (lane 0 only): the vertex's
    /// triangles side by side in [`ELEMENT_LANES`] lanes, each with the same arithmetic as in
    /// the per-environment path, summed in the same order, so the results are bit-identical.
    #[inline(always)]
    #[allow(clippy::too_many_arguments)]
    fn add_membrane_across_elements(
        &self,
        model: &Model,
        x: &[V3<L<W>>],
        i: usize,
        membrane: Membrane<L<W>>,
        inv_h: L<W>,
        force: &mut V3<L<W>>,
        stiff: &mut Sym3<L<W>>,
    ) {
        let membrane = lane0_membrane(membrane);
        let inv_h = E8::splat(inv_h.0[0]);
        for chunk in model.adjacency.triangles_of(i).chunks(ELEMENT_LANES) {
            let (xs, vs) = gather_elements(chunk.len(), |e| chunk[e].idx, x, &self.x_rate);
            let mut dm = [[E8::splat(0.0); 2]; 2];
            let mut area = E8::splat(1.0);
            let mut inv_area = E8::splat(1.0);
            let mut first = E8::splat(0.0);
            let mut second = E8::splat(0.0);
            for e in 0..ELEMENT_LANES {
                let tri = &chunk[e.min(chunk.len() - 1)];
                for (r, row) in tri.dm.iter().enumerate() {
                    for (c, value) in row.iter().enumerate() {
                        dm[r][c].0[e] = *value;
                    }
                }
                (area.0[e], inv_area.0[e]) = tri.rest_area;
                first.0[e] = (tri.corner == 0) as u8 as f32;
                second.0[e] = (tri.corner == 1) as u8 as f32;
            }
            let corners = LaneCorners { first, second };
            let (f, kk) = triangle_vertex(xs, vs, corners, dm, (area, inv_area), membrane, inv_h);
            for e in 0..chunk.len() {
                *force += lane_vector(&f, e);
                stiff.add_assign(lane_matrix(&kk, e));
            }
        }
    }

    /// Membrane forces on every package vertex at positions `x` (velocities from the current
    /// iterate), into `out`: each triangle once, forces only (a global step's residual).
    #[inline(always)]
    pub(super) fn membrane_forces(
        &self,
        model: &Model,
        x: &[V3<L<W>>],
        membrane: Membrane<L<W>>,
        out: &mut [V3<L<W>>],
    ) {
        out.fill(V3::zero());
        if W == 1 {
            return self.membrane_forces_across_elements(model, x, membrane, out);
        }
        for tri in &model.package_triangles {
            let [a, b, c] = tri.idx.map(|j| j as usize);
            let inv_area = tri.rest.inv_rest_area();
            let forces = triangle_forces(
                [x[a], x[b], x[c]],
                [self.x_rate[a], self.x_rate[b], self.x_rate[c]],
                tri.rest.dm_splat(),
                (L::splat(1.0 / inv_area), L::splat(inv_area)),
                membrane,
            );
            out[a] += forces[0];
            out[b] += forces[1];
            out[c] += forces[2];
        }
    }

    /// [`Self::membrane_forces`] for a single-environment block: [`ELEMENT_LANES`] triangles side
    /// by side, added in triangle order.
    #[inline(always)]
    fn membrane_forces_across_elements(
        &self,
        model: &Model,
        x: &[V3<L<W>>],
        membrane: Membrane<L<W>>,
        out: &mut [V3<L<W>>],
    ) {
        let membrane = lane0_membrane(membrane);
        for chunk in model.package_triangles.chunks(ELEMENT_LANES) {
            let (xs, vs) = gather_elements(chunk.len(), |e| chunk[e].idx, x, &self.x_rate);
            let (dm, inv_area) = gather_triangle_rest(chunk);
            let area = E8::splat(1.0) / inv_area;
            let forces = triangle_forces(xs, vs, dm, (area, inv_area), membrane);
            for (e, tri) in chunk.iter().enumerate() {
                for (corner, &j) in tri.idx.iter().enumerate() {
                    out[j as usize] += lane_vector(&forces[corner], e);
                }
            }
        }
    }

    /// Bending forces and stiffness blocks of every package vertex at positions `x`, with the
    /// material `mat` (ke, kd).
    #[inline(always)]
    pub(super) fn bending_at_sweep_start(
        &mut self,
        model: &Model,
        x: &[V3<L<W>>],
        mat: [L<W>; 2],
        inv_h: L<W>,
    ) {
        for (f, k) in self
            .bend_force
            .iter_mut()
            .zip(self.bend_stiffness.iter_mut())
        {
            *f = V3::zero();
            *k = Sym3::zero();
        }
        if W == 1 {
            return self.bending_across_elements(model, x, mat, inv_h);
        }
        for edge in &model.package_edges {
            let id = [
                edge.idx[0] as usize,
                edge.idx[1] as usize,
                edge.idx[2] as usize,
                edge.idx[3] as usize,
            ];
            let (forces, grads, s) = bending_element(
                [x[id[0]], x[id[1]], x[id[2]], x[id[3]]],
                [
                    self.x_rate[id[0]],
                    self.x_rate[id[1]],
                    self.x_rate[id[2]],
                    self.x_rate[id[3]],
                ],
                L::splat(edge.rest_angle),
                mat[0],
                mat[1],
                inv_h,
            );
            // Written out: as an iterator over the four vertices, LLVM keeps the arrays on the
            // stack and the loop's state in memory (at 16 lanes, half of bending's time).
            self.add_bending(id[0], forces[0], grads[0], s);
            self.add_bending(id[1], forces[1], grads[1], s);
            self.add_bending(id[2], forces[2], grads[2], s);
            self.add_bending(id[3], forces[3], grads[3], s);
        }
    }

    /// Adds one vertex's share of a bending element: its force `f` and stiffness `s·d·dᵀ`.
    #[inline(always)]
    fn add_bending(&mut self, j: usize, f: V3<L<W>>, d: V3<L<W>>, s: L<W>) {
        self.bend_force[j] += f;
        self.bend_stiffness[j].add_assign(Sym3::outer(d, s));
    }

    /// [`Self::bending_at_sweep_start`] for a single-environment block: [`ELEMENT_LANES`] edges
    /// side by side, added in edge order (bit-identical, as [`Self::add_membrane_across_elements`]).
    #[inline(always)]
    fn bending_across_elements(
        &mut self,
        model: &Model,
        x: &[V3<L<W>>],
        mat: [L<W>; 2],
        inv_h: L<W>,
    ) {
        let (ke, kd) = (E8::splat(mat[0].0[0]), E8::splat(mat[1].0[0]));
        let inv_h = E8::splat(inv_h.0[0]);
        for chunk in model.package_edges.chunks(ELEMENT_LANES) {
            let (xs, vs) = gather_elements(chunk.len(), |e| chunk[e].idx, x, &self.x_rate);
            let rest = Lanes(std::array::from_fn(|e| {
                chunk[e.min(chunk.len() - 1)].rest_angle
            }));
            let (forces, grads, s) = bending_element(xs, vs, rest, ke, kd, inv_h);
            let blocks = [
                Sym3::outer(grads[0], s),
                Sym3::outer(grads[1], s),
                Sym3::outer(grads[2], s),
                Sym3::outer(grads[3], s),
            ];
            for (e, edge) in chunk.iter().enumerate() {
                for (k, &j) in edge.idx.iter().enumerate() {
                    self.bend_force[j as usize] += lane_vector(&forces[k], e);
                    self.bend_stiffness[j as usize].add_assign(lane_matrix(&blocks[k], e));
                }
            }
        }
    }
}
