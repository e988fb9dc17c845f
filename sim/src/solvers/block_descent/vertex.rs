//! Per-vertex force and stiffness of every force term, for the block-descent solver: implicit
//! Euler solved by a Newton step on one vertex at a time (Vertex Block Descent, Chen et al. 2024),
//! Gauss-Seidel over the vertices. Bending's per-element terms are shared with the explicit
//! solver ([`crate::forces::bending_element`]).
//!
//! Each function returns the force on one vertex of an element (the negative gradient of the
//! element's energy, with the same force laws as [`crate::forces`]) and its stiffness block
//! `K = −∂f/∂x_vertex`, a symmetric positive semi-definite 3×3 matrix. Where the exact block can be
//! indefinite the part that can be negative is dropped (Gauss-Newton), which slows convergence a
//! little but never changes the solution: the fixed point is where the forces balance. Velocity
//! terms use the step's velocity `v = (x − x_start) / h`, so a damping coefficient `kd` adds
//! `kd / h` times its direction to the stiffness.
//!
//! Differences from the explicit model, on purpose: the membrane's deviatoric damping acts on the
//! Green strain rate (`sym(FᵀḞ)`) instead of `Ḟ`, so a rigid rotation of the film is not damped
//! (Warp's `Ḟ` damping brakes any spin of the package).

use crate::forces::ContactMaterial;
use crate::math::{Real, Sym3, V3};

/// Which corner of a triangle the vertex being solved is: one corner for every lane (`usize`), or
/// one per lane ([`LaneCorners`]). Both give the same arithmetic per lane.
pub trait Corner<T: Real>: Copy {
    /// Weight of the corner in the columns of `F = Ds·Dm` (`Ds = [x1 − x0, x2 − x0]`):
    /// `F_c = Σ_k w_kc·x_k`.
    fn weights(self, dm: [[T; 2]; 2]) -> [T; 2];
    /// The corner's gradient of the area ratio, from those of corners 1 (`d1`) and 2 (`d2`).
    fn area_gradient(self, d1: V3<T>, d2: V3<T>) -> V3<T>;
}

impl<T: Real> Corner<T> for usize {
    #[inline(always)]
    fn weights(self, dm: [[T; 2]; 2]) -> [T; 2] {
        match self {
            0 => [-(dm[0][0] + dm[1][0]), -(dm[0][1] + dm[1][1])],
            1 => [dm[0][0], dm[0][1]],
            _ => [dm[1][0], dm[1][1]],
        }
    }
    #[inline(always)]
    fn area_gradient(self, d1: V3<T>, d2: V3<T>) -> V3<T> {
        match self {
            0 => -(d1 + d2),
            1 => d1,
            _ => d2,
        }
    }
}

/// A corner per lane, for one vertex's triangles side by side in the lanes of `T`: 1 in the
/// lanes where the vertex is corner 0 (`first`) or corner 1 (`second`), 0 elsewhere.
#[derive(Clone, Copy, Debug)]
pub struct LaneCorners<T> {
    /// 1 where the vertex is corner 0.
    pub first: T,
    /// 1 where the vertex is corner 1.
    pub second: T,
}

impl<T: Real> Corner<T> for LaneCorners<T> {
    #[inline(always)]
    fn weights(self, dm: [[T; 2]; 2]) -> [T; 2] {
        let half = T::splat(0.5);
        let pick = |c0: T, c1: T, c2: T| {
            T::select_lt(
                half,
                self.first,
                c0,
                T::select_lt(half, self.second, c1, c2),
            )
        };
        [
            pick(-(dm[0][0] + dm[1][0]), dm[0][0], dm[1][0]),
            pick(-(dm[0][1] + dm[1][1]), dm[0][1], dm[1][1]),
        ]
    }
    #[inline(always)]
    fn area_gradient(self, d1: V3<T>, d2: V3<T>) -> V3<T> {
        let half = T::splat(0.5);
        V3::select_lt(
            half,
            self.first,
            -(d1 + d2),
            V3::select_lt(half, self.second, d1, d2),
        )
    }
}

/// Membrane material per unit rest area (`k_tri_e`, `k_tri_a`, `k_tri_d`) and Warp's rest area
/// ratio `α = 1 + μ/λ` (computed once, not per element).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Membrane<T> {
    /// `k_mu` (N/m).
    pub mu: T,
    /// `k_lambda` (N/m).
    pub lambda: T,
    /// `k_damp` (N·s/m).
    pub damp: T,
    /// `1 + mu/lambda`.
    pub alpha: T,
}

impl<T: Real> Membrane<T> {
    /// From (k_mu, k_lambda, k_damp).
    pub fn new(mat: [T; 3]) -> Self {
        Membrane {
            mu: mat[0],
            lambda: mat[1],
            damp: mat[2],
            alpha: T::splat(1.0) + mat[0] / mat[1],
        }
    }
}

/// What a membrane triangle's forces on its corners are made of: `P = ∂E/∂F` (columns `p1`,
/// `p2`), the gradients of the area ratio at corners 1 and 2, and the area term's scalar factor.
struct TriangleStress<T> {
    p1: V3<T>,
    p2: V3<T>,
    dcdq: V3<T>,
    dcdr: V3<T>,
    area_factor: T,
}

/// The stress of a membrane triangle (see [`triangle_vertex`]) at positions `x`, velocities `v`,
/// with the material scaled by `rest_area` = A0.
#[inline(always)]
fn triangle_stress<T: Real>(
    x: [V3<T>; 3],
    v: [V3<T>; 3],
    dm: [[T; 2]; 2],
    rest_area: (T, T),
    mat: Membrane<T>,
) -> TriangleStress<T> {
    let (rest_area, inv_rest_area) = rest_area;
    let (k_mu, k_lambda, k_damp) = (
        mat.mu * rest_area,
        mat.lambda * rest_area,
        mat.damp * rest_area,
    );
    let x10 = x[1] - x[0];
    let x20 = x[2] - x[0];
    let v10 = v[1] - v[0];
    let v20 = v[2] - v[0];
    let f1 = x10 * dm[0][0] + x20 * dm[1][0];
    let f2 = x10 * dm[0][1] + x20 * dm[1][1];
    let g1 = v10 * dm[0][0] + v20 * dm[1][0];
    let g2 = v10 * dm[0][1] + v20 * dm[1][1];
    // Green strain rate sym(FᵀḞ): zero for a rigid rotation.
    let half = T::splat(0.5);
    let e11 = f1.dot(g1);
    let e22 = f2.dot(g2);
    let e12 = (f1.dot(g2) + f2.dot(g1)) * half;
    let p1 = f1 * k_mu + (f1 * e11 + f2 * e12) * k_damp;
    let p2 = f2 * k_mu + (f1 * e12 + f2 * e22) * k_damp;

    let n = x10.cross(x20);
    let n_len = n.length();
    let c = n_len * half * inv_rest_area - mat.alpha;
    let n = n * (T::splat(1.0) / n_len);
    let half_inv = inv_rest_area * half;
    let dcdq = x20.cross(n) * half_inv;
    let dcdr = n.cross(x10) * half_inv;
    let dcdt = dcdq.dot(v[1]) + dcdr.dot(v[2]) - (dcdq + dcdr).dot(v[0]);
    TriangleStress {
        p1,
        p2,
        dcdq,
        dcdr,
        area_factor: k_lambda * c + k_damp * dcdt,
    }
}

/// Membrane triangle (Warp's energy `A0·[μ/2·tr(FᵀF) + λ/2·(J − α)²]`, α = 1 + μ/λ, `J` the area
/// ratio) at corner `corner` of positions `x`, velocities `v`; `rest_area` = (A0, 1/A0). The
/// stiffness is exact for the deviatoric part and Gauss-Newton (`A0·λ·∇J∇Jᵀ`) for the area part.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
pub fn triangle_vertex<T: Real>(
    x: [V3<T>; 3],
    v: [V3<T>; 3],
    corner: impl Corner<T>,
    dm: [[T; 2]; 2],
    rest_area: (T, T),
    mat: Membrane<T>,
    inv_h: T,
) -> (V3<T>, Sym3<T>) {
    let s = triangle_stress(x, v, dm, rest_area, mat);
    let w = corner.weights(dm);
    // dE/dx_k = P·w_k (P = ∂E/∂F, columns p1, p2).
    let mut grad = s.p1 * w[0] + s.p2 * w[1];
    let dj = corner.area_gradient(s.dcdq, s.dcdr);
    grad += dj * s.area_factor;

    let (k_mu, k_lambda, k_damp) = (
        mat.mu * rest_area.0,
        mat.lambda * rest_area.0,
        mat.damp * rest_area.0,
    );
    let ww = w[0] * w[0] + w[1] * w[1];
    let mut k = Sym3::diagonal(ww * (k_mu + k_damp * inv_h));
    k.add_assign(Sym3::outer(dj, k_lambda + k_damp * inv_h));
    (-grad, k)
}

/// The forces of [`triangle_vertex`] on all three corners at once, without stiffness: what a
/// residual needs, each triangle evaluated once instead of once per corner.
#[inline(always)]
pub fn triangle_forces<T: Real>(
    x: [V3<T>; 3],
    v: [V3<T>; 3],
    dm: [[T; 2]; 2],
    rest_area: (T, T),
    mat: Membrane<T>,
) -> [V3<T>; 3] {
    let s = triangle_stress(x, v, dm, rest_area, mat);
    let grad1 = s.p1 * dm[0][0] + s.p2 * dm[0][1] + s.dcdq * s.area_factor;
    let grad2 = s.p1 * dm[1][0] + s.p2 * dm[1][1] + s.dcdr * s.area_factor;
    [grad1 + grad2, -grad1, -grad2]
}

/// Damped spring between a free vertex `x` and a fixed point `anchor` (the attachment springs;
/// the cups are kinematic). Stiffness: `ke·[d̂d̂ᵀ + max(0, 1 − L/l)·(I − d̂d̂ᵀ)] + kd/h·d̂d̂ᵀ`.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
pub fn spring_vertex<T: Real>(
    x: V3<T>,
    anchor: V3<T>,
    v: V3<T>,
    anchor_v: V3<T>,
    rest: T,
    ke: T,
    kd: T,
    inv_h: T,
) -> (V3<T>, Sym3<T>) {
    let d = x - anchor;
    let l = d.length();
    let dir = d * (T::splat(1.0) / l);
    let stretch = l - rest;
    let rate = dir.dot(v - anchor_v);
    let force = -(dir * (ke * stretch + kd * rate));
    let lateral = (T::splat(1.0) - rest / l).max(T::splat(0.0)) * ke;
    let mut k = Sym3::tangential(dir, lateral);
    k.add_assign(Sym3::outer(dir, ke + kd * inv_h));
    (force, k)
}

/// Penalty contact along a unit normal `n` with gap `c` (< 0: penetrating), relative velocity
/// `rel` (the vertex's minus the surface's), and viscous friction capped by Coulomb
/// (`min(kf·|v_t|, μ·|c·ke|)`, as [`crate::forces::particle_disc`]). Returns the force on the
/// vertex and its stiffness; zero where `c ≥ 0`.
#[inline(always)]
pub fn contact_vertex<T: Real>(
    c: T,
    n: V3<T>,
    rel: V3<T>,
    m: ContactMaterial<T>,
    inv_h: T,
) -> (V3<T>, Sym3<T>) {
    let zero = T::splat(0.0);
    let vn = n.dot(rel);
    let vt = rel - n * vn;
    let vt_len = vt.length();
    let cap = (m.mu * c * m.ke).abs();
    let ft_mag = (m.kf * vt_len).min(cap);
    let force = -(n * (c * m.ke) + n * (vn.min(zero) * m.kd) + vt.normalize() * ft_mag);
    // Approaching: the damping is on. Sticking (kf·|v_t| < cap): viscous friction kf/h;
    // sliding: the Coulomb force turns with v_t, stiffness cap/|u| with u = v_t·h.
    let normal = m.ke + T::select_lt(vn, zero, m.kd * inv_h, zero);
    let sliding = cap / (vt_len.max(T::splat(1e-9)) / inv_h);
    let tangential = (m.kf * inv_h).min(sliding);
    let mut k = Sym3::outer(n, normal);
    k.add_assign(Sym3::tangential(n, tangential));
    (
        V3::select_lt(c, zero, force, V3::zero()),
        k.keep_lt(c, zero),
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::forces::bending_element;

    type V = V3<f64>;

    fn v(a: [f64; 3]) -> V {
        V3::new(a[0], a[1], a[2])
    }

    fn axis(k: usize) -> V {
        let mut a = [0.0; 3];
        a[k] = 1.0;
        v(a)
    }

    /// `−∂f/∂x` by central differences of `force(x)`, column by column.
    fn fd_stiffness(force: impl Fn(V) -> V, x: V, eps: f64) -> [[f64; 3]; 3] {
        let mut k = [[0.0; 3]; 3];
        for c in 0..3 {
            let fp = force(x + axis(c) * eps);
            let fm = force(x - axis(c) * eps);
            let col = (fp - fm) * (-0.5 / eps);
            k[0][c] = col.x;
            k[1][c] = col.y;
            k[2][c] = col.z;
        }
        k
    }

    /// Negative central-difference gradient of `energy` at `x`.
    fn fd_force(energy: impl Fn(V) -> f64, x: V, eps: f64) -> V {
        let g = |c: usize| (energy(x + axis(c) * eps) - energy(x - axis(c) * eps)) / (2.0 * eps);
        v([-g(0), -g(1), -g(2)])
    }

    fn full(s: &Sym3<f64>) -> [[f64; 3]; 3] {
        let [xx, xy, xz, yy, yz, zz] = s.m;
        [[xx, xy, xz], [xy, yy, yz], [xz, yz, zz]]
    }

    fn assert_matrix_close(a: [[f64; 3]; 3], b: [[f64; 3]; 3], tol: f64) {
        let scale = b.iter().flatten().fold(1e-12f64, |m, x| m.max(x.abs()));
        for r in 0..3 {
            for c in 0..3 {
                assert!(
                    (a[r][c] - b[r][c]).abs() <= tol * scale,
                    "entry ({r},{c}): {} vs {} (scale {scale})\n{a:?}\n{b:?}",
                    a[r][c],
                    b[r][c]
                );
            }
        }
    }

    fn assert_vec_close(a: V, b: V, tol: f64) {
        let scale = b.length().max(1e-12);
        assert!((a - b).length() <= tol * scale, "{a:?} vs {b:?}");
    }

    /// Smallest eigenvalue bound: the matrix is PSD if all leading minors are >= −tol.
    fn assert_psd(s: &Sym3<f64>) {
        let m = full(s);
        let scale = m.iter().flatten().fold(1e-12f64, |a, x| a.max(x.abs()));
        for u in [
            [1.0, 0.0, 0.0],
            [0.0, 1.0, 0.0],
            [0.0, 0.0, 1.0],
            [1.0, 1.0, 0.0],
            [1.0, -1.0, 0.5],
            [0.3, 0.7, -1.0],
        ] {
            let q = s.mul_vec(v(u)).dot(v(u));
            assert!(q >= -1e-9 * scale, "not PSD: {m:?}");
        }
    }

    const DM: [[f64; 2]; 2] = [[10.0, -2.0], [0.0, 8.0]];

    fn rest_triangle() -> [V; 3] {
        // Dm is the inverse of [[0.1, 0.025], [0, 0.125]] (columns: rest edges in the plane).
        [
            v([0.0, 0.0, 0.0]),
            v([0.1, 0.0, 0.0]),
            v([0.025, 0.0, 0.125]),
        ]
    }

    /// `triangle_vertex` on the test triangle (rest shape `DM`) with material `mat`, 1/h = 1.
    fn test_triangle(x: [V; 3], v: [V; 3], corner: usize, mat: [f64; 3]) -> (V, Sym3<f64>) {
        let inv_area = (DM[0][0] * DM[1][1] - DM[0][1] * DM[1][0]) * 2.0;
        triangle_vertex(
            x,
            v,
            corner,
            DM,
            (1.0 / inv_area, inv_area),
            Membrane::new(mat),
            1.0,
        )
    }

    fn triangle_energy(x: [V; 3], mat: [f64; 3]) -> f64 {
        let inv_area = (DM[0][0] * DM[1][1] - DM[0][1] * DM[1][0]) * 2.0;
        let a0 = 1.0 / inv_area;
        let (x10, x20) = (x[1] - x[0], x[2] - x[0]);
        let f1 = x10 * DM[0][0] + x20 * DM[1][0];
        let f2 = x10 * DM[0][1] + x20 * DM[1][1];
        let j = x10.cross(x20).length() * 0.5 * inv_area;
        let alpha = 1.0 + mat[0] / mat[1];
        a0 * (0.5 * mat[0] * (f1.dot(f1) + f2.dot(f2)) + 0.5 * mat[1] * (j - alpha).powi(2))
    }

    #[test]
    fn triangle_force_is_the_energy_gradient_and_its_stiffness_matches_finite_differences() {
        let mat = [2.0e3, 3.0e3, 0.0];
        let base = rest_triangle();
        // A stretched, sheared, bent triangle.
        let x = [
            base[0] + v([0.003, -0.002, 0.001]),
            base[1] + v([0.012, 0.004, -0.003]),
            base[2] + v([-0.004, 0.010, 0.015]),
        ];
        let zero = [V3::zero(); 3];
        for corner in 0..3 {
            let at = |p: V| {
                let mut y = x;
                y[corner] = p;
                y
            };
            let (f, _) = test_triangle(x, zero, corner, mat);
            let fd = fd_force(|p| triangle_energy(at(p), mat), x[corner], 1e-6);
            assert_vec_close(f, fd, 1e-6);
        }
        // Where the area term is at its minimum (J = α) the Gauss-Newton stiffness is exact.
        let alpha: f64 = 1.0 + mat[0] / mat[1];
        let s = alpha.sqrt();
        let x = [base[0] * s, base[1] * s, base[2] * s];
        for corner in 0..3 {
            let at = |p: V| {
                let mut y = x;
                y[corner] = p;
                y
            };
            let force = |p: V| test_triangle(at(p), zero, corner, mat).0;
            let (_, k) = test_triangle(x, zero, corner, mat);
            assert_matrix_close(full(&k), fd_stiffness(force, x[corner], 1e-7), 1e-5);
            assert_psd(&k);
        }
    }

    #[test]
    fn triangle_damping_ignores_rigid_rotation_and_resists_stretching() {
        let mat = [2.0e3, 3.0e3, 5.0];
        let x = rest_triangle();
        let still = [V3::zero(); 3];
        // Spin about the y axis: v = ω × x.
        let w = v([0.0, 3.0, 0.0]);
        let spin = x.map(|p| w.cross(p));
        let stretch = x.map(|p| v([p.x * 2.0, 0.0, 0.0]));
        for corner in 0..3 {
            let (f0, _) = test_triangle(x, still, corner, mat);
            let (fs, _) = test_triangle(x, spin, corner, mat);
            assert!((fs - f0).length() < 1e-9, "{fs:?} vs {f0:?}");
        }
        // Stretching along x: the far corner (1) is pulled back.
        let (f, _) = test_triangle(x, stretch, 1, mat);
        let (f0, _) = test_triangle(x, still, 1, mat);
        assert!((f - f0).x < -1e-3, "{f:?} vs {f0:?}");
    }

    fn hinge() -> [V; 4] {
        [
            v([0.0, 0.0, 0.05]),
            v([0.0, 0.01, -0.05]),
            v([-0.05, 0.0, 0.0]),
            v([0.05, 0.0, 0.0]),
        ]
    }

    /// [`bending_element`] at one vertex (`role` 0, 1: opposite vertices; 2, 3: hinge): its force
    /// and stiffness block `|e|·(ke + kd/h)·∇θ∇θᵀ` (Gauss-Newton).
    fn bending_vertex<T: Real>(
        x: [V3<T>; 4],
        v: [V3<T>; 4],
        role: usize,
        rest_angle: T,
        ke: T,
        kd: T,
        inv_h: T,
    ) -> (V3<T>, Sym3<T>) {
        let (f, d, s) = bending_element(x, v, rest_angle, ke, kd, inv_h);
        (f[role], Sym3::outer(d[role], s))
    }

    #[test]
    fn bending_stiffness_matches_finite_differences_at_the_rest_angle() {
        let x = hinge();
        let rest = crate::forces::dihedral_angle(x);
        let zero = [V3::zero(); 4];
        let (ke, kd) = (0.3, 0.0);
        // Away from rest the force is Warp's bending force.
        let bent = [x[0], x[1] + v([0.0, 0.02, 0.0]), x[2], x[3]];
        let warp = crate::forces::bending(bent, zero, rest, ke, kd);
        for role in 0..4 {
            let (f, _) = bending_vertex(bent, zero, role, rest, ke, kd, 1.0);
            assert_vec_close(f, warp[role], 1e-12);
        }
        // At the rest angle the Gauss-Newton stiffness is exact.
        for role in 0..4 {
            let at = |p: V| {
                let mut y = x;
                y[role] = p;
                y
            };
            let force = |p: V| bending_vertex(at(p), zero, role, rest, ke, kd, 1.0).0;
            let (_, k) = bending_vertex(x, zero, role, rest, ke, kd, 1.0);
            assert_matrix_close(full(&k), fd_stiffness(force, x[role], 1e-7), 1e-5);
            assert_psd(&k);
        }
    }

    #[test]
    fn spring_force_is_the_energy_gradient_and_its_stiffness_matches_finite_differences() {
        let anchor = v([0.01, 0.2, -0.03]);
        let (rest, ke) = (0.05, 40.0);
        let energy = |p: V| 0.5 * ke * ((p - anchor).length() - rest).powi(2);
        let force = |p: V| spring_vertex(p, anchor, V3::zero(), V3::zero(), rest, ke, 0.0, 1.0).0;
        // Stretched: the exact stiffness is PSD and used as it is.
        let x = v([0.02, 0.13, -0.01]);
        assert_vec_close(force(x), fd_force(energy, x, 1e-7), 1e-6);
        let (_, k) = spring_vertex(x, anchor, V3::zero(), V3::zero(), rest, ke, 0.0, 1.0);
        assert_matrix_close(full(&k), fd_stiffness(force, x, 1e-7), 1e-5);
        // Compressed: the lateral part (negative) is dropped, the stiffness stays PSD.
        let x = v([0.012, 0.17, -0.028]);
        let (_, k) = spring_vertex(x, anchor, V3::zero(), V3::zero(), rest, ke, 0.0, 1.0);
        assert_psd(&k);
        // It agrees with the explicit model's spring.
        let (vx, va) = (v([0.1, -0.2, 0.3]), v([0.0, 0.1, 0.0]));
        let (f, _) = spring_vertex(x, anchor, vx, va, rest, ke, 0.7, 1.0);
        let warp = -crate::forces::spring(anchor, x, va, vx, rest, ke, 0.7);
        assert_vec_close(f, warp, 1e-12);
    }

    #[test]
    fn contact_stiffness_matches_finite_differences_and_the_explicit_law() {
        let m = ContactMaterial {
            ke: 1.0e3,
            kd: 0.4,
            kf: 0.05,
            mu: 0.5,
        };
        let frictionless = ContactMaterial { kf: 0.0, ..m };
        let n = v([0.0, 0.6, 0.8]);
        let surface = v([0.0, 0.1, 0.0]);
        let gap = |p: V| n.dot(p - surface) - 0.005;
        let force = |p: V| contact_vertex(gap(p), n, V3::zero(), frictionless, 1.0).0;
        let x = surface + n * 0.002;
        let energy = |p: V| 0.5 * m.ke * gap(p).min(0.0).powi(2);
        assert_vec_close(force(x), fd_force(energy, x, 1e-8), 1e-6);
        let (_, k) = contact_vertex(gap(x), n, V3::zero(), frictionless, 1.0);
        assert_matrix_close(full(&k), fd_stiffness(force, x, 1e-8), 1e-5);
        // Not touching: nothing.
        let (f, k) = contact_vertex(0.001, n, v([1.0, 0.0, 0.0]), m, 1.0);
        assert_eq!(f, V3::zero());
        assert_eq!(k, Sym3::zero());
        // With a velocity it is the explicit particle-disc law.
        let rel = v([0.3, -0.2, 0.1]);
        let (f, k) = contact_vertex(gap(x), n, rel, m, 100.0);
        let (warp, _) = crate::forces::particle_disc(
            x,
            rel,
            0.005,
            n,
            surface,
            surface,
            V3::zero(),
            V3::zero(),
            m,
        );
        assert_vec_close(f, warp, 1e-12);
        assert_psd(&k);
    }

    #[test]
    fn triangle_forces_are_the_three_corners_forces_and_sum_to_zero() {
        let base = rest_triangle();
        let x = [
            base[0],
            base[1] + v([0.004, -0.002, 0.001]),
            base[2] + v([-0.003, 0.005, 0.0]),
        ];
        let vel = [v([0.1, 0.0, -0.2]), v([0.0, 0.3, 0.1]), v([-0.2, 0.1, 0.0])];
        let mat = [2.0e3, 3.0e3, 0.5];
        let inv_area = (DM[0][0] * DM[1][1] - DM[0][1] * DM[1][0]) * 2.0;
        let all = triangle_forces(x, vel, DM, (1.0 / inv_area, inv_area), Membrane::new(mat));
        let mut sum = V3::zero();
        for (corner, f) in all.into_iter().enumerate() {
            let (fc, _) = test_triangle(x, vel, corner, mat);
            assert_vec_close(f, fc, 1e-12);
            sum += f;
        }
        assert!(sum.length() < 1e-9 * all[0].length(), "{sum:?}");
    }

    #[test]
    fn corners_per_lane_match_one_corner_per_call_bit_for_bit() {
        use crate::math::Lanes;
        type L4 = Lanes<4>;
        let x32 = |a: [f32; 3]| V3::new(a[0], a[1], a[2]);
        let x = [
            x32([0.0, 0.01, 0.0]),
            x32([0.11, -0.004, 0.003]),
            x32([0.02, 0.006, 0.13]),
        ];
        let v = [
            x32([0.3, -0.1, 0.0]),
            x32([0.0, 0.2, -0.4]),
            x32([0.1, 0.0, 0.05]),
        ];
        let dm = [[10.0f32, -2.0], [0.0, 8.0]];
        let inv_area = (dm[0][0] * dm[1][1] - dm[0][1] * dm[1][0]) * 2.0;
        let mat = Membrane::new([2.0e3f32, 3.0e3, 0.1]);
        let lanes = |a: V3<f32>| V3::new(L4::splat(a.x), L4::splat(a.y), L4::splat(a.z));
        // Lanes 0..3 are corners 0, 1, 2, 1.
        let corners = LaneCorners {
            first: Lanes([1.0, 0.0, 0.0, 0.0]),
            second: Lanes([0.0, 1.0, 0.0, 1.0]),
        };
        let (f, k) = triangle_vertex(
            x.map(lanes),
            v.map(lanes),
            corners,
            dm.map(|row| row.map(L4::splat)),
            (L4::splat(1.0 / inv_area), L4::splat(inv_area)),
            Membrane {
                mu: L4::splat(mat.mu),
                lambda: L4::splat(mat.lambda),
                damp: L4::splat(mat.damp),
                alpha: L4::splat(mat.alpha),
            },
            L4::splat(60.0),
        );
        for (lane, corner) in [0usize, 1, 2, 1].into_iter().enumerate() {
            let (fc, kc) = triangle_vertex(x, v, corner, dm, (1.0 / inv_area, inv_area), mat, 60.0);
            let got = [f.x.0[lane], f.y.0[lane], f.z.0[lane]].map(f32::to_bits);
            assert_eq!(got, [fc.x, fc.y, fc.z].map(f32::to_bits), "lane {lane}");
            assert_eq!(k.m.map(|e| e.0[lane].to_bits()), kc.m.map(f32::to_bits));
        }
    }
}
