//! The global-descent solver ([`crate::config::Solver::GlobalDescent`]): the implicit Euler step
//! of block descent, solved by its vertex sweeps interleaved with a global step through a
//! prefactored banded system.
//!
//! Why: real packaging film (`k_tri_e` 1e4–2e4 N/m) on particles of ~77 mg has its fastest
//! in-plane mode at `ω·h ≈ 30` for `h` = 1/300 s. Vertex sweeps (Gauss-Seidel) move a
//! disturbance one vertex per sweep, so stiffness that couples the whole sheet converges slowly:
//! the unconverged film stretches and lets the disc through, or the step diverges. A global solve
//! has no such limit.
//!
//! Method (a two-level solver of the same incremental potential as [`super::block_descent`], so
//! the same force laws and the same solution): before each sweep, the residual force `r` of every
//! package vertex (inertia, membrane, bending, attachment springs, contacts; the membrane's per
//! triangle, each once and without stiffness, a fraction of a sweep's cost) is turned into a
//! displacement `Δx = P⁻¹·r` by one matrix `P` for the whole sheet, then block descent's sweep
//! and disc step follow. `P` is the projective-dynamics system matrix (Bouaziz et al. 2014):
//! `m/h²·I + (k_mu + k_lambda + k_damp/h)·L` with `L` the membrane's rest Laplacian (the exact
//! Hessian of Warp's `k_mu` term), plus, on the diagonal, the attachment springs and the contacts
//! that may touch during the step. It is scalar (the same for x, y and z), so the package's
//! `2·M·N` particles, interleaved layer by layer, make a band of half width `2·min(M, N) + 1`; it is
//! refactored every substep (contacts and seals change) in the SIMD lanes of the block, which
//! costs less than one sweep. Where `P` overestimates the true stiffness (bending out of plane,
//! sliding on a contact) the global step moves too little and the sweep, which is good at local
//! and soft modes, takes over; where it underestimates it by less than a factor two, the step
//! still lowers the potential. Together: the stiff in-plane modes converge in a few iterations at
//! 300 substeps per second, where plain sweeps need 1200 substeps per second.
//!
//! Compared with the alternatives: projective dynamics proper would need its own membrane,
//! bending and contact models (the calibrated parameters would no longer apply); Newton with
//! block-Jacobi preconditioned conjugate gradients needs about `√(ω·h)²` iterations per Newton
//! step at this stiffness; a full 3x3-block banded factor (half width `≈ 6·min(M, N)`) costs
//! ~25x this scalar one per substep. Chebyshev-accelerated sweeps (`chebyshev_rho`) still move
//! information one vertex per sweep.
//!
//! Everything else (cups, inertial predictions, frozen contact data, disc, velocities, spring
//! forces for the seal model, the lane rules) is block descent's.

mod banded;
#[cfg(test)]
mod tests;

use crate::forces;
use crate::math::{lane_vec, LaneVec, Lanes, Real, V3};
use crate::model::Model;
use crate::state::State;

use super::block_descent::{BlockDescent, GlobalStep};
use super::{Integrator, Substep};
use banded::Banded;

type L<const W: usize> = Lanes<W>;

/// The global-descent solver of a block: block descent's sweeps and buffers, and the global
/// system.
pub(crate) struct GlobalDescent<const W: usize> {
    descent: BlockDescent<W>,
    global: GlobalSystem<W>,
}

impl<const W: usize> Integrator<W> for GlobalDescent<W> {
    fn new(model: &Model) -> Self {
        GlobalDescent {
            descent: BlockDescent::new(model),
            global: GlobalSystem::new(model),
        }
    }

    #[inline(always)]
    fn substep(&mut self, step: &Substep<'_, W>, state: &mut State<W>) {
        self.descent.substep_with(step, state, &mut self.global);
    }

    fn bytes(&self) -> usize {
        self.descent.bytes() + self.global.bytes()
    }
}

/// The package's global system `P` (see the module documentation) and its buffers.
struct GlobalSystem<const W: usize> {
    /// Row of each package particle in the band (the two layers interleaved).
    row_of: Vec<u32>,
    /// The membrane's rest Laplacian `Σ A0·(g_a·g_b)` over the package triangles (`g` the
    /// corners' weights in `F`), as the band's rows (shared by every lane).
    laplacian: Vec<f32>,
    /// `P` of each lane, factored every substep.
    system: Banded<W>,
    /// Residual forces per package particle, then the global displacement.
    residual: LaneVec<V3<L<W>>>,
    /// The residual in band order.
    rhs: LaneVec<V3<L<W>>>,
    /// The diagonal terms of `P` besides the membrane's, per package particle.
    diagonal: LaneVec<L<W>>,
}

impl<const W: usize> GlobalSystem<W> {
    fn new(model: &Model) -> Self {
        let n = model.num_package;
        let [rows, cols] = model.grid;
        let layer = model.layer_size;
        // Interleave the layers, and run along the grid's shorter side: half bandwidth
        // 2·(shorter side) + 1.
        let row_of: Vec<u32> = (0..n)
            .map(|i| {
                let (sheet, cell) = (i / layer, i % layer);
                let (r, c) = (cell / cols, cell % cols);
                let along = if rows <= cols { c * rows + r } else { cell };
                (2 * along + sheet) as u32
            })
            .collect();
        let band = model
            .package_triangles
            .iter()
            .flat_map(|t| {
                let idx = t.idx.map(|j| row_of[j as usize] as i64);
                [
                    (idx[0] - idx[1]).abs(),
                    (idx[1] - idx[2]).abs(),
                    (idx[0] - idx[2]).abs(),
                ]
            })
            .max()
            .unwrap_or(0) as usize;
        let w = band + 1;
        let mut laplacian = vec![0.0f64; n * w];
        for t in &model.package_triangles {
            let dm = t.rest.dm.map(|r| r.map(f64::from));
            let g1 = [dm[0][0], dm[0][1]];
            let g2 = [dm[1][0], dm[1][1]];
            let g = [[-(g1[0] + g2[0]), -(g1[1] + g2[1])], g1, g2];
            let area = 1.0 / t.rest.inv_rest_area() as f64;
            for a in 0..3 {
                for b in 0..3 {
                    let (ra, rb) = (
                        row_of[t.idx[a] as usize] as usize,
                        row_of[t.idx[b] as usize] as usize,
                    );
                    if rb <= ra {
                        laplacian[ra * w + band + rb - ra] +=
                            area * (g[a][0] * g[b][0] + g[a][1] * g[b][1]);
                    }
                }
            }
        }
        GlobalSystem {
            row_of,
            laplacian: laplacian.into_iter().map(|v| v as f32).collect(),
            system: Banded::new(n, band),
            residual: lane_vec(V3::zero(), n),
            rhs: lane_vec(V3::zero(), n),
            diagonal: LaneVec::with_capacity(64, n),
        }
    }

    fn bytes(&self) -> usize {
        let v3 = std::mem::size_of::<V3<L<W>>>();
        self.system.bytes()
            + (self.residual.capacity() + self.rhs.capacity()) * v3
            + self.laplacian.capacity() * 4
            + self.diagonal.capacity() * std::mem::size_of::<L<W>>()
            + self.row_of.capacity() * 4
    }
}

impl<const W: usize> GlobalStep<W> for GlobalSystem<W> {
    /// Assembles and factors `P` for the substep: inertia and membrane, the sealed attachment
    /// springs, and the contact stiffness of the particles that may touch the disc or the ground
    /// (within two particle radii at the inertial prediction, per lane).
    #[inline(always)]
    fn prepare(&mut self, step: &Substep<'_, W>, state: &State<W>) {
        let (model, k, p) = (step.model, step.k, &step.setup.params);
        let n = model.num_package;
        let zero = L::<W>::splat(0.0);
        let inv_h = L::<W>::splat(1.0 / k.dt);
        let inertial = (L::splat(1.0) / p.inv_mass_package) * inv_h * inv_h;
        let membrane = p.tri[0] + p.tri[1] + p.tri[2] * inv_h;
        let diagonal = &mut self.diagonal;
        diagonal.clear();
        diagonal.resize(n, inertial);
        let spring = p.spring[0] + p.spring[1] * inv_h;
        for s in &state.springs {
            for l in 0..W {
                diagonal[s.target[l] as usize].0[l] += spring.0[l] * s.sealed.0[l];
            }
        }
        let radius = model.particle_radius;
        let near = L::<W>::splat(2.0 * radius);
        let c = &p.disc_contact;
        let disc_contact = c.ke + (c.kd + c.kf) * inv_h;
        let ground_contact = L::<W>::splat(k.ground.ke + (k.ground.kd + k.ground.kf) / k.dt);
        let (dr, dh) = (
            L::<W>::splat(model.disc.radius),
            L::<W>::splat(model.disc.half_height),
        );
        let disc = state.disc;
        for (i, d) in diagonal.iter_mut().enumerate() {
            let x = state.x[i];
            let local = disc.q.rotate_inv(x - disc.com);
            let (gap, _) = forces::cylinder_distance(local, dr, dh);
            *d += L::select_lt(gap, near, disc_contact, zero);
            *d += L::select_lt(x.y, near, ground_contact, zero);
        }
        let (_, band) = self.system.shape();
        let w = band + 1;
        for (i, d) in diagonal.iter().enumerate() {
            let r = self.row_of[i] as usize;
            let rest = &self.laplacian[r * w..(r + 1) * w];
            let row = self.system.row_mut(r);
            for (entry, &lap) in row.iter_mut().zip(rest) {
                *entry = membrane * L::splat(lap);
            }
            row[band] += *d;
        }
        self.system.factor();
    }

    #[inline(always)]
    fn residual(&mut self) -> Option<&mut [V3<L<W>>]> {
        Some(&mut self.residual[..])
    }

    #[inline(always)]
    fn solve(&mut self) {
        for (r, &row) in self.residual.iter().zip(&self.row_of) {
            self.rhs[row as usize] = *r;
        }
        self.system.solve(&mut self.rhs);
        for (r, &row) in self.residual.iter_mut().zip(&self.row_of) {
            *r = self.rhs[row as usize];
        }
    }
}
