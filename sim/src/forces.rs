//! Warp 1.6 `warp.sim` force laws (`integrator_euler.py`), one element at a time, generic over
//! [`Real`] so the same code runs on one `f32`, on `f64` (tests) and on W lanes at once.
//!
//! Every function returns the forces *on* the element's particles (Warp's `atomic_add`/`atomic_sub`
//! signs already applied). Deliberate differences from Warp are listed where they occur.
//!
//! Both solvers build on these laws: the explicit one sums them per particle, block descent
//! differentiates them per vertex (`solvers::block_descent::vertex`). What both share (the
//! bending element, [`ContactMaterial`], the disc's shape) lives here, so the solvers depend on
//! this module and never on each other.

use crate::math::{Real, V3};

/// Damped spring (`eval_springs`). Returns the force on particle `i`; particle `j` gets the
/// opposite. Like Warp there is no guard for zero length (springs never collapse in practice).
#[inline(always)]
#[allow(clippy::too_many_arguments)]
pub fn spring<T: Real>(xi: V3<T>, xj: V3<T>, vi: V3<T>, vj: V3<T>, rest: T, ke: T, kd: T) -> V3<T> {
    let xij = xi - xj;
    let vij = vi - vj;
    let l = xij.length();
    let dir = xij * (T::splat(1.0) / l);
    let c = l - rest;
    let dcdt = dir.dot(vij);
    -(dir * (ke * c + kd * dcdt))
}

/// Rest data of a triangle: Warp's `tri_poses` (the inverse 2x2 rest edge matrix `Dm`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TriangleRest {
    /// `Dm = D⁻¹`, row-major `[[Dm00, Dm01], [Dm10, Dm11]]`.
    pub dm: [[f32; 2]; 2],
}

impl TriangleRest {
    /// Warp's `add_triangle` rest computation from three rest positions (in f64 like Warp's
    /// numpy). Returns `None` for a degenerate triangle (Warp skips those).
    pub fn from_positions(p: [f64; 3], q: [f64; 3], r: [f64; 3]) -> Option<Self> {
        let sub = |a: [f64; 3], b: [f64; 3]| [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
        let dot = |a: [f64; 3], b: [f64; 3]| a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
        let cross = |a: [f64; 3], b: [f64; 3]| {
            [
                a[1] * b[2] - a[2] * b[1],
                a[2] * b[0] - a[0] * b[2],
                a[0] * b[1] - a[1] * b[0],
            ]
        };
        let unit = |a: [f64; 3]| {
            let l = dot(a, a).sqrt();
            [a[0] / l, a[1] / l, a[2] / l]
        };
        let (qp, rp) = (sub(q, p), sub(r, p));
        let n = unit(cross(qp, rp));
        let e1 = unit(qp);
        let e2 = unit(cross(n, e1));
        let d = [[dot(e1, qp), dot(e1, rp)], [dot(e2, qp), dot(e2, rp)]];
        let det = d[0][0] * d[1][1] - d[0][1] * d[1][0];
        if det.is_nan() || det <= 0.0 || det.is_infinite() {
            return None;
        }
        let inv = [
            [d[1][1] / det, -d[0][1] / det],
            [-d[1][0] / det, d[0][0] / det],
        ];
        Some(TriangleRest {
            dm: inv.map(|row| row.map(|v| v as f32)),
        })
    }

    /// `1 / A0 = 2·det(Dm)`, computed in f32 exactly as Warp's kernel does.
    pub fn inv_rest_area(&self) -> f32 {
        (self.dm[0][0] * self.dm[1][1] - self.dm[0][1] * self.dm[1][0]) * 2.0
    }

    /// `Dm` in every lane of `T`. Written out: `dm.map(|row| row.map(T::splat))` is compiled as a
    /// call, outside the substep's instruction set.
    #[inline(always)]
    pub fn dm_splat<T: Real>(&self) -> [[T; 2]; 2] {
        let dm = &self.dm;
        [
            [T::splat(dm[0][0]), T::splat(dm[0][1])],
            [T::splat(dm[1][0]), T::splat(dm[1][1])],
        ]
    }
}

/// Membrane triangle (`eval_triangles`): Warp's St.Venant-Kirchhoff-like deviatoric term plus an
/// area-preservation term, with Rayleigh-type damping. `k_mu`, `k_lambda`, `k_damp` are the
/// material values (`k_tri_e`, `k_tri_a`, `k_tri_d`); like Warp they are scaled by the rest area
/// here. Returns the forces on vertices 0, 1, 2. Drag/lift are 0 in the reference and omitted.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
pub fn triangle<T: Real>(
    x: [V3<T>; 3],
    v: [V3<T>; 3],
    dm: [[T; 2]; 2],
    inv_rest_area: T,
    k_mu: T,
    k_lambda: T,
    k_damp: T,
) -> [V3<T>; 3] {
    let rest_area = T::splat(1.0) / inv_rest_area;
    let k_mu = k_mu * rest_area;
    let k_lambda = k_lambda * rest_area;
    let k_damp = k_damp * rest_area;

    let x10 = x[1] - x[0];
    let x20 = x[2] - x[0];
    let v10 = v[1] - v[0];
    let v20 = v[2] - v[0];

    let f1 = x10 * dm[0][0] + x20 * dm[1][0];
    let f2 = x10 * dm[0][1] + x20 * dm[1][1];
    let dfdt1 = v10 * dm[0][0] + v20 * dm[1][0];
    let dfdt2 = v10 * dm[0][1] + v20 * dm[1][1];
    let p1 = f1 * k_mu + dfdt1 * k_damp;
    let p2 = f2 * k_mu + dfdt2 * k_damp;
    let mut h1 = p1 * dm[0][0] + p2 * dm[0][1];
    let mut h2 = p1 * dm[1][0] + p2 * dm[1][1];

    let alpha = T::splat(1.0) + k_mu / k_lambda;
    let n = x10.cross(x20);
    let area = n.length() * T::splat(0.5);
    let c = area * inv_rest_area - alpha;
    let n = n.normalize();
    let half_inv = inv_rest_area * T::splat(0.5);
    let dcdq = x20.cross(n) * half_inv;
    let dcdr = n.cross(x10) * half_inv;
    let f_area = k_lambda * c;
    let dcdt = dcdq.dot(v[1]) + dcdr.dot(v[2]) - (dcdq + dcdr).dot(v[0]);
    let f_damp = k_damp * dcdt;
    h1 += dcdq * (f_area + f_damp);
    h2 += dcdr * (f_area + f_damp);
    [h1 + h2, -h1, -h2]
}

/// Warp's `eval_bending` dihedral angle of element (o0, o1, v0, v1) (positions `x[0..4]`), or
/// `None` in a lane where a wing is degenerate. The `acos` argument is clamped to [−1, 1]
/// (Warp 1.6 does not clamp and can produce NaN for nearly flat hinges).
#[inline(always)]
pub fn dihedral_angle<T: Real>(x: [V3<T>; 4]) -> T {
    let n1 = (x[2] - x[0]).cross(x[3] - x[0]);
    let n2 = (x[3] - x[1]).cross(x[2] - x[1]);
    let (l1, l2) = (n1.length(), n2.length());
    let cos = n1.dot(n2) * (T::splat(1.0) / l1) * (T::splat(1.0) / l2);
    let e_hat = (x[3] - x[2]).normalize();
    cos.acos_clamped() * n2.cross(n1).dot(e_hat).sign()
}

/// Dihedral bending (`eval_bending`, after Bridson et al.) of element (o0, o1, v0, v1) with
/// positions `x` and velocities `v` in that order. Returns the forces on the four particles; zero
/// in lanes where a wing is degenerate (|n| < 1e-6, Warp returns early there).
#[inline(always)]
pub fn bending<T: Real>(x: [V3<T>; 4], v: [V3<T>; 4], rest_angle: T, ke: T, kd: T) -> [V3<T>; 4] {
    // The same arithmetic as the block-descent solver's element, without its stiffness.
    bending_element(x, v, rest_angle, ke, kd, T::splat(0.0)).0
}

/// Dihedral bending (Warp's `eval_bending`) of element positions `x`, velocities `v`, for both
/// solvers: the forces on its four vertices (opposite vertices, then the hinge) and the gradients
/// `∇θ` they are along, with the Gauss-Newton stiffness factor `s`: vertex k's stiffness block is
/// `s·∇θ_k∇θ_kᵀ` with `s = |e|·(ke + kd/h)` (the explicit solver passes `1/h = 0` and uses only
/// the forces, see [`bending`]).
#[inline(always)]
pub fn bending_element<T: Real>(
    x: [V3<T>; 4],
    v: [V3<T>; 4],
    rest_angle: T,
    ke: T,
    kd: T,
    inv_h: T,
) -> ([V3<T>; 4], [V3<T>; 4], T) {
    let one = T::splat(1.0);
    let eps = T::splat(1.0e-6);
    let n1 = (x[2] - x[0]).cross(x[3] - x[0]);
    let n2 = (x[3] - x[1]).cross(x[2] - x[1]);
    let (l1, l2) = (n1.length(), n2.length());
    let ok = l1.min(l2);
    let l1 = T::select_lt(l1, eps, one, l1);
    let l2 = T::select_lt(l2, eps, one, l2);
    let rcp1 = one / l1;
    let rcp2 = one / l2;
    let cos = n1.dot(n2) * rcp1 * rcp2;
    let n1 = n1 * rcp1 * rcp1;
    let n2 = n2 * rcp2 * rcp2;
    let e = x[3] - x[2];
    let e_hat = e.normalize();
    let e_len = e.length();
    let s = n2.cross(n1).dot(e_hat).sign();
    let angle = cos.acos_clamped() * s;
    let d = [
        n1 * e_len,
        n2 * e_len,
        n1 * (x[0] - x[3]).dot(e_hat) + n2 * (x[1] - x[3]).dot(e_hat),
        n1 * (x[2] - x[0]).dot(e_hat) + n2 * (x[2] - x[1]).dot(e_hat),
    ];
    let rate = d[0].dot(v[0]) + d[1].dot(v[1]) + d[2].dot(v[2]) + d[3].dot(v[3]);
    let f_total = -e_len * (ke * (angle - rest_angle) + kd * rate);
    let f_total = T::select_lt(ok, eps, T::splat(0.0), f_total);
    let stiffness = T::select_lt(ok, eps, T::splat(0.0), e_len * (ke + kd * inv_h));
    let forces = [
        d[0] * f_total,
        d[1] * f_total,
        d[2] * f_total,
        d[3] * f_total,
    ];
    (forces, d, stiffness)
}

/// Contact material: stiffness, damping, friction stiffness, friction coefficient.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ContactMaterial<T> {
    /// Normal stiffness `ke` (N/m).
    pub ke: T,
    /// Normal damping `kd` (N·s/m).
    pub kd: T,
    /// Friction stiffness `kf` (N·s/m): viscous friction below the Coulomb cap.
    pub kf: T,
    /// Coulomb friction coefficient `mu`.
    pub mu: T,
}

/// Particle against the ground plane y = 0 (`eval_particle_ground_contacts`). Returns the force on
/// the particle (zero when not touching).
#[inline(always)]
pub fn particle_ground<T: Real>(x: V3<T>, v: V3<T>, radius: T, m: ContactMaterial<T>) -> V3<T> {
    let zero = T::splat(0.0);
    let c = (x.y - radius).min(zero);
    let vn = v.y;
    let fn_ = c * m.ke + vn.min(zero) * m.kd;
    let vt = V3::new(v.x, zero, v.z);
    let vs = vt.length();
    let dir = vt.normalize();
    let ft = (vs * m.kf).min(m.mu * fn_.abs());
    let f = -(V3::new(zero, fn_, zero) + dir * ft);
    // Warp returns early for c >= 0.
    V3::select_lt(c, zero, f, V3::zero())
}

/// Signed distance from a body-frame point to a solid cylinder of `radius` and `half_height`
/// whose axis is the body y axis, and the outward unit normal of the closest surface point
/// (body frame). Negative inside.
#[inline(always)]
pub fn cylinder_distance<T: Real>(p: V3<T>, radius: T, half_height: T) -> (T, V3<T>) {
    let zero = T::splat(0.0);
    let one = T::splat(1.0);
    let rho = (p.x * p.x + p.z * p.z).sqrt();
    let safe_rho = T::select_lt(zero, rho, rho, one);
    // On the axis the radial direction is arbitrary: take +x.
    let radial_x = T::select_lt(zero, rho, p.x / safe_rho, one);
    let radial_z = T::select_lt(zero, rho, p.z / safe_rho, zero);
    let sy = p.y.sign();
    let dr = rho - radius;
    let dy = p.y.abs() - half_height;
    let side = V3::new(radial_x, zero, radial_z);
    let cap = V3::new(zero, sy, zero);
    // Inside (dr <= 0 and dy <= 0): the nearer face.
    let inside_d = dr.max(dy);
    let inside_n = V3::select_lt(dr, dy, cap, side);
    // Outside: side, cap or rim.
    let pdr = dr.max(zero);
    let pdy = dy.max(zero);
    let out_d = (pdr * pdr + pdy * pdy).sqrt();
    let safe_out = T::select_lt(zero, out_d, out_d, one);
    let out_n = V3::new(radial_x * pdr, sy * pdy, radial_z * pdr) / safe_out;
    let d = T::select_lt(zero, inside_d, out_d, inside_d);
    let n = V3::select_lt(zero, inside_d, out_n, inside_n);
    (d, n)
}

/// Particle against the rigid disc (`eval_particle_contacts`). `bx`: world position of the
/// contact point (the body-frame closest point moved with the current pose), `n`: contact normal
/// (world), `com`, `v_com`, `omega`: the disc. Returns (force on the particle, lever arm `r` from
/// the disc COM to the contact point); the disc gets the opposite force and torque `r × (−force)`.
/// Zero force when `c = n·(x − bx) − radius > 0` (particle adhesion 0).
#[inline(always)]
#[allow(clippy::too_many_arguments)]
pub fn particle_disc<T: Real>(
    x: V3<T>,
    v: V3<T>,
    radius: T,
    n: V3<T>,
    bx: V3<T>,
    com: V3<T>,
    v_com: V3<T>,
    omega: V3<T>,
    m: ContactMaterial<T>,
) -> (V3<T>, V3<T>) {
    let zero = T::splat(0.0);
    let r = bx - com;
    let c = n.dot(x - bx) - radius;
    let bv = v_com + omega.cross(r);
    let rel = v - bv;
    let vn = n.dot(rel);
    let vt = rel - n * vn;
    let fn_ = n * (c * m.ke);
    let fd = n * (vn.min(zero) * m.kd);
    let ft = vt.normalize() * (m.kf * vt.length()).min((m.mu * c * m.ke).abs());
    let f_total = fn_ + (fd + ft);
    let f = V3::select_lt(zero, c, V3::zero(), -f_total);
    (f, r)
}

/// Warp's `norm_huber` with delta = 1: ½|v|² below 1, |v| − ½ above.
#[inline(always)]
fn norm_huber<T: Real>(v: V3<T>) -> T {
    let a = v.dot(v);
    let one = T::splat(1.0);
    T::select_lt(one, a, a.sqrt() - T::splat(0.5), a * T::splat(0.5))
}

/// A point of the rigid body against the ground plane (`eval_rigid_contacts`, shape thickness
/// subtracted). `p`: world point, `v`: its velocity. Returns the force on the body at that point.
#[inline(always)]
pub fn rigid_ground<T: Real>(p: V3<T>, v: V3<T>, thickness: T, m: ContactMaterial<T>) -> V3<T> {
    let zero = T::splat(0.0);
    let d = p.y - thickness;
    let vn = v.y;
    let vt = V3::new(v.x, zero, v.z);
    let fn_ = d * m.ke;
    let fd = vn.min(zero) * m.kd;
    let vs = norm_huber(vt);
    let safe_vs = T::select_lt(zero, vs, vs, T::splat(1.0));
    let cap = -(m.mu * (fn_ + fd));
    let ft = T::select_lt(zero, vs, (m.kf * vs).min(cap), zero);
    let f_total = V3::new(zero, fn_ + fd, zero) + vt * (ft / safe_vs);
    V3::select_lt(d, zero, -f_total, V3::zero())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn v(a: [f64; 3]) -> V3<f64> {
        V3::new(a[0], a[1], a[2])
    }
    fn close(a: V3<f64>, b: V3<f64>, tol: f64) -> bool {
        (a - b).length() <= tol * (1.0 + b.length())
    }
    /// Central finite difference of `energy` at `x[k]`, returning the negative gradient (force).
    fn fd_force<const N: usize>(
        energy: impl Fn([V3<f64>; N]) -> f64,
        x: [V3<f64>; N],
        k: usize,
    ) -> V3<f64> {
        let h = 1e-7;
        let mut g = [0.0; 3];
        for (c, gc) in g.iter_mut().enumerate() {
            let mut xp = x;
            let mut xm = x;
            match c {
                0 => {
                    xp[k].x += h;
                    xm[k].x -= h
                }
                1 => {
                    xp[k].y += h;
                    xm[k].y -= h
                }
                _ => {
                    xp[k].z += h;
                    xm[k].z -= h
                }
            }
            *gc = -(energy(xp) - energy(xm)) / (2.0 * h);
        }
        v(g)
    }

    #[test]
    fn spring_hand_values() {
        // Stretched along x by 0.5 beyond rest 1.0, approaching at 2 m/s.
        let f = spring(
            v([1.5, 0.0, 0.0]),
            v([0.0; 3]),
            v([-2.0, 0.0, 0.0]),
            v([0.0; 3]),
            1.0,
            100.0,
            3.0,
        );
        // s = 100·0.5 + 3·(−2) = 44; f_i = −dir·s.
        assert!(close(f, v([-44.0, 0.0, 0.0]), 1e-12), "{f:?}");
    }

    #[test]
    fn spring_matches_energy_gradient() {
        let (ke, rest) = (250.0, 0.3);
        let x = [v([0.1, 0.2, -0.3]), v([0.4, -0.1, 0.2])];
        let energy = |x: [V3<f64>; 2]| 0.5 * ke * ((x[0] - x[1]).length() - rest).powi(2);
        let f = spring(x[0], x[1], V3::zero(), V3::zero(), rest, ke, 0.0);
        assert!(close(f, fd_force(energy, x, 0), 1e-6));
        assert!(close(-f, fd_force(energy, x, 1), 1e-6));
    }

    fn rest_tri() -> ([[f64; 3]; 3], TriangleRest) {
        let p = [[0.0, 0.0, 0.0], [0.2, 0.0, 0.0], [0.0, 0.0, 0.1]];
        (p, TriangleRest::from_positions(p[0], p[1], p[2]).unwrap())
    }
    fn dm64(r: &TriangleRest) -> [[f64; 2]; 2] {
        r.dm.map(|row| row.map(|x| x as f64))
    }

    #[test]
    fn triangle_rest_data_and_hand_values() {
        let (p, rest) = rest_tri();
        // Area 0.01 m² → 1/A0 = 100.
        assert!((rest.inv_rest_area() - 100.0).abs() < 1e-3);
        // Stretch x by 10 %: rest frame e1 = x̂, e2 = ẑ, Dm = diag(5, 10), F1 = (1.1, 0, 0).
        // Deviatoric force on vertex 1: −A0·k_mu·F1·Dm00 = −0.01·1000·1.1·5 = −55 x̂.
        // Area term: α = 1 + 1000/1000 = 2, C = 1.1 − 2 = −0.9, ∂C/∂x1 = (x20 × n̂)/(2·A0) = 5 x̂,
        // force −A0·k_lambda·C·5 = +45 x̂. Total −10 x̂.
        let x = [v(p[0]), v([0.22, 0.0, 0.0]), v(p[2])];
        let f = triangle(x, [V3::zero(); 3], dm64(&rest), 100.0, 1000.0, 1000.0, 0.0);
        assert!(close(f[1], v([-10.0, 0.0, 0.0]), 1e-9), "{:?}", f[1]);
        assert!(close(f[0] + f[1] + f[2], V3::zero(), 1e-12));
    }

    #[test]
    fn triangle_elastic_part_matches_energy_gradient() {
        let (_, rest) = rest_tri();
        let dm = dm64(&rest);
        let inv_a = 2.0 * (dm[0][0] * dm[1][1] - dm[0][1] * dm[1][0]);
        let a0 = 1.0 / inv_a;
        let (k_mu, k_lambda) = (2.0e3, 5.0e2);
        let alpha = 1.0 + k_mu / k_lambda;
        let energy = |x: [V3<f64>; 3]| {
            let (x10, x20) = (x[1] - x[0], x[2] - x[0]);
            let f1 = x10 * dm[0][0] + x20 * dm[1][0];
            let f2 = x10 * dm[0][1] + x20 * dm[1][1];
            let area = x10.cross(x20).length() * 0.5;
            a0 * (0.5 * k_mu * (f1.dot(f1) + f2.dot(f2))
                + 0.5 * k_lambda * (area / a0 - alpha).powi(2))
        };
        let x = [
            v([0.01, 0.02, -0.01]),
            v([0.23, -0.01, 0.02]),
            v([-0.02, 0.03, 0.12]),
        ];
        let f = triangle(x, [V3::zero(); 3], dm, inv_a, k_mu, k_lambda, 0.0);
        for k in 0..3 {
            assert!(
                close(f[k], fd_force(energy, x, k), 1e-5),
                "vertex {k}: {:?} vs {:?}",
                f[k],
                fd_force(energy, x, k)
            );
        }
    }

    #[test]
    fn triangle_damping_opposes_stretch_rate() {
        let (p, rest) = rest_tri();
        let x = [v(p[0]), v(p[1]), v(p[2])];
        let vel = [V3::zero(), v([1.0, 0.0, 0.0]), V3::zero()];
        let f = triangle(x, vel, dm64(&rest), 100.0, 0.0, 1.0, 10.0);
        assert!(f[1].x < 0.0 && f[0].x > 0.0);
        assert!(close(f[0] + f[1] + f[2], V3::zero(), 1e-12));
    }

    fn hinge(fold: f64) -> [V3<f64>; 4] {
        // Edge along z from v0 = (0,0,0) to v1 = (0,0,1); wings at ±x, the o1 wing rotated by `fold`.
        [
            v([-1.0, 0.0, 0.5]),
            v([fold.cos(), fold.sin(), 0.5]),
            v([0.0; 3]),
            v([0.0, 0.0, 1.0]),
        ]
    }

    #[test]
    fn bending_hand_values() {
        let x = hinge(0.3);
        let angle = dihedral_angle(x);
        assert!((angle.abs() - 0.3).abs() < 1e-9, "angle {angle}");
        let f = bending(x, [V3::zero(); 4], 0.0, 2.0, 0.0);
        // |e| = 1, unit wing heights: |f on wing| = ke·|angle|·|e| / h = 0.6.
        assert!((f[0].length() - 0.6).abs() < 1e-9 && (f[1].length() - 0.6).abs() < 1e-9);
        assert!(close(f[0] + f[1] + f[2] + f[3], V3::zero(), 1e-12));
        // Flat hinge at rest angle: no force, no NaN even though cos θ rounds to ±1.
        let flat = bending(hinge(0.0), [V3::zero(); 4], 0.0, 2.0, 1.0);
        assert!(flat.iter().all(|f| f.length() < 1e-12));
    }

    #[test]
    fn bending_matches_energy_gradient() {
        let (ke, rest) = (3.0, 0.1);
        let x = [
            v([-1.0, 0.1, 0.4]),
            v([0.9, 0.35, 0.6]),
            v([0.05, 0.0, -0.02]),
            v([0.0, 0.02, 1.1]),
        ];
        // Warp's force is −ke·|e|·(θ−θ0)·∇θ: the gradient of ½·ke·L·(θ−θ0)² with L = |e| frozen.
        let l = (x[3] - x[2]).length();
        let energy = |y: [V3<f64>; 4]| 0.5 * ke * l * (dihedral_angle(y) - rest).powi(2);
        let f = bending(x, [V3::zero(); 4], rest, ke, 0.0);
        for k in 0..4 {
            assert!(
                close(f[k], fd_force(energy, x, k), 1e-5),
                "vertex {k}: {:?} vs {:?}",
                f[k],
                fd_force(energy, x, k)
            );
        }
    }

    #[test]
    fn ground_contact_hand_values_and_gradient() {
        let m = ContactMaterial {
            ke: 1e4,
            kd: 1e2,
            kf: 10.0,
            mu: 0.5,
        };
        // 2 mm penetration, sinking at 0.1 m/s, sliding at 1 m/s along x.
        let f = particle_ground(v([0.0, 0.008, 0.0]), v([1.0, -0.1, 0.0]), 0.01, m);
        // fn = −0.002·1e4 + (−0.1)·1e2 = −30; ft = min(10, 15) = 10.
        assert!(close(f, v([-10.0, 30.0, 0.0]), 1e-9), "{f:?}");
        let none = particle_ground(v([0.0, 0.02, 0.0]), v([1.0, -0.1, 0.0]), 0.01, m);
        assert_eq!(none, V3::zero());
        let e = |x: [V3<f64>; 1]| 0.5 * m.ke * (x[0].y - 0.01).min(0.0).powi(2);
        let x = [v([0.3, 0.004, 0.1])];
        assert!(close(
            particle_ground(x[0], V3::zero(), 0.01, m),
            fd_force(e, x, 0),
            1e-6
        ));
    }

    #[test]
    fn cylinder_distance_cases() {
        let (r, h) = (0.08, 0.0075);
        let (d, n) = cylinder_distance(v([0.0, 0.02, 0.0]), r, h);
        assert!((d - 0.0125).abs() < 1e-12 && close(n, v([0.0, 1.0, 0.0]), 1e-12));
        let (d, n) = cylinder_distance(v([0.0, 0.0, -0.1]), r, h);
        assert!((d - 0.02).abs() < 1e-12 && close(n, v([0.0, 0.0, -1.0]), 1e-12));
        let (d, _) = cylinder_distance(v([0.11, 0.0475, 0.0]), r, h);
        assert!((d - 0.05).abs() < 1e-12);
        let (d, n) = cylinder_distance(v([0.01, -0.005, 0.0]), r, h);
        assert!((d + 0.0025).abs() < 1e-12 && close(n, v([0.0, -1.0, 0.0]), 1e-12));
    }

    #[test]
    fn disc_contact_hand_values_and_gradient() {
        let m = ContactMaterial {
            ke: 2e4,
            kd: 0.0,
            kf: 0.0,
            mu: 0.0,
        };
        let (r, h, pr) = (0.08, 0.0075, 0.01);
        let com = v([0.0, 0.5, 0.0]);
        let force = |x: V3<f64>| {
            let (d, n) = cylinder_distance(x - com, r, h);
            particle_disc(
                x,
                V3::zero(),
                pr,
                n,
                x - n * d,
                com,
                V3::zero(),
                V3::zero(),
                m,
            )
        };
        // Particle 5 mm above the top face: c = 0.005 − 0.01 = −0.005 → 100 N upward.
        let (f, arm) = force(com + v([0.02, 0.0125, 0.0]));
        assert!(close(f, v([0.0, 100.0, 0.0]), 1e-9), "{f:?}");
        assert!(close(arm, v([0.02, 0.0075, 0.0]), 1e-12));
        let e = |x: [V3<f64>; 1]| {
            let (d, _) = cylinder_distance(x[0] - com, r, h);
            0.5 * m.ke * (d - pr).min(0.0).powi(2)
        };
        for p in [
            v([0.03, 0.51, 0.02]),
            v([0.085, 0.5, 0.01]),
            v([0.083, 0.5095, 0.0]),
        ] {
            let (f, _) = force(p);
            assert!(close(f, fd_force(e, [p], 0), 1e-5), "{f:?}");
        }
    }

    #[test]
    fn disc_friction_is_capped_by_coulomb() {
        let m = ContactMaterial {
            ke: 1e4,
            kd: 0.0,
            kf: 1e6,
            mu: 0.5,
        };
        let com = v([0.0; 3]);
        let x = v([0.0, 0.0125, 0.0]);
        let (d, n) = cylinder_distance(x - com, 0.08, 0.0075);
        let (f, _) = particle_disc(
            x,
            v([1.0, 0.0, 0.0]),
            0.01,
            n,
            x - n * d,
            com,
            V3::zero(),
            V3::zero(),
            m,
        );
        // Normal 50 N, friction capped at 0.5·50 = 25 N against the sliding direction.
        assert!(close(f, v([-25.0, 50.0, 0.0]), 1e-9), "{f:?}");
    }

    #[test]
    fn rigid_ground_pushes_up_and_rubs() {
        let m = ContactMaterial {
            ke: 1e5,
            kd: 1e3,
            kf: 1e3,
            mu: 0.5,
        };
        let f = rigid_ground(v([0.0, -0.001, 0.0]), v([2.0, 0.0, 0.0]), 0.0, m);
        // fn = −100 → +100 up; Huber |vt| = 2 − ½ = 1.5, ft = min(1500, 50) = 50 along vt / 1.5
        // (Warp normalises by the Huber norm), i.e. 66.7 N opposing x.
        assert!(close(f, v([-200.0 / 3.0, 100.0, 0.0]), 1e-9), "{f:?}");
        assert_eq!(
            rigid_ground(v([0.0, 0.01, 0.0]), v([2.0, 0.0, 0.0]), 0.0, m),
            V3::zero()
        );
    }
}
