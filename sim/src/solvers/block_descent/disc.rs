//! The disc's block of the block-descent solver: its 6x6 Newton system (translation and
//! rotation), and the film's contacts on it through the frozen contact data.

use crate::forces::ContactMaterial;
use crate::math::{get3, set3, Lanes, Quat, Real, Sym3, V3};
use crate::solvers::across_elements::{E8, ELEMENT_LANES};
use crate::state::State;

use super::vertex::contact_vertex;
use super::BlockDescent;

type L<const W: usize> = Lanes<W>;

/// A 6x6 symmetric system of one lane block: the disc's translation and rotation.
pub(super) struct Disc6<const W: usize> {
    /// Hessian (upper triangle used).
    pub(super) h: [[L<W>; 6]; 6],
    /// Generalised force.
    pub(super) g: [L<W>; 6],
}

impl<const W: usize> Disc6<W> {
    pub(super) fn new() -> Self {
        Disc6 {
            h: [[L::splat(0.0); 6]; 6],
            g: [L::splat(0.0); 6],
        }
    }

    /// Adds a force `f` acting at arm `r` from the centre, with stiffness `k` (with respect to the
    /// point's position), in lanes where `gap < 0` (see [`point_terms`]). Other lanes are left
    /// bit for bit as they were.
    #[inline(always)]
    pub(super) fn add_point(&mut self, gap: L<W>, f: V3<L<W>>, k: &Sym3<L<W>>, r: V3<L<W>>) {
        let (g, h) = point_terms(f, k, r);
        self.add_terms(gap, |a| g[a], |n| h[n]);
    }

    /// Adds the terms of one point (entry `a` of its generalised force `g(a)`, entry `n` of its
    /// Hessian's upper triangle `h(n)`, as [`point_terms`] returns them) in lanes where `gap < 0`.
    #[inline(always)]
    fn add_terms(&mut self, gap: L<W>, g: impl Fn(usize) -> L<W>, h: impl Fn(usize) -> L<W>) {
        let zero = L::splat(0.0);
        for a in 0..6 {
            self.g[a] = L::select_lt(gap, zero, self.g[a] + g(a), self.g[a]);
        }
        let mut n = 0;
        for a in 0..6 {
            for b in a..6 {
                self.h[a][b] = L::select_lt(gap, zero, self.h[a][b] + h(n), self.h[a][b]);
                n += 1;
            }
        }
    }

    /// Solves for the Newton step (LDLᵀ, upper triangle used).
    #[inline(always)]
    pub(super) fn solve(&self) -> [L<W>; 6] {
        let mut a = self.h;
        for r in 0..6 {
            for c in 0..r {
                a[r][c] = a[c][r];
            }
        }
        let mut d = [L::<W>::splat(0.0); 6];
        let mut lo = [[L::<W>::splat(0.0); 6]; 6];
        for j in 0..6 {
            let mut dj = a[j][j];
            for k in 0..j {
                dj -= lo[j][k] * lo[j][k] * d[k];
            }
            d[j] = dj;
            for i in j + 1..6 {
                let mut s = a[i][j];
                for k in 0..j {
                    s -= lo[i][k] * lo[j][k] * d[k];
                }
                lo[i][j] = s / dj;
            }
        }
        let mut y = self.g;
        for i in 0..6 {
            for k in 0..i {
                let t = lo[i][k] * y[k];
                y[i] -= t;
            }
        }
        for i in 0..6 {
            y[i] = y[i] / d[i];
        }
        for i in (0..6).rev() {
            for k in i + 1..6 {
                let t = lo[k][i] * y[k];
                y[i] -= t;
            }
        }
        y
    }
}

/// A force `f` with stiffness `k` (with respect to the point's position) acting at arm `r` from
/// the disc's centre: the generalised force `[f, r × f]` and the upper triangle of the Hessian
/// `JᵀKJ`, `J = [I, −[r]×]`, row by row.
#[inline(always)]
fn point_terms<T: Real>(f: V3<T>, k: &Sym3<T>, r: V3<T>) -> ([T; 6], [T; 21]) {
    let zero = T::splat(0.0);
    let t = r.cross(f);
    // Columns of J: the point's displacement per unit of each coordinate.
    let one = T::splat(1.0);
    let ex = V3::new(one, zero, zero);
    let ey = V3::new(zero, one, zero);
    let ez = V3::new(zero, zero, one);
    let cols = [ex, ey, ez, ex.cross(r), ey.cross(r), ez.cross(r)];
    let kc = [
        k.mul_vec(cols[0]),
        k.mul_vec(cols[1]),
        k.mul_vec(cols[2]),
        k.mul_vec(cols[3]),
        k.mul_vec(cols[4]),
        k.mul_vec(cols[5]),
    ];
    let mut h = [zero; 21];
    let mut n = 0;
    for a in 0..6 {
        for b in a..6 {
            h[n] = cols[a].dot(kc[b]);
            n += 1;
        }
    }
    ([f.x, f.y, f.z, t.x, t.y, t.z], h)
}

/// Contact of a particle at `x` moving with `v` with the disc at pose (`com`, `q`) moving with
/// (`disc_v`, `disc_w`), through the frozen contact `normal` (world) and `point` (body frame):
/// gap (negative when touching), force on the particle, stiffness, arm from the centre to the
/// contact point.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn disc_contact_at<T: Real>(
    x: V3<T>,
    v: V3<T>,
    normal: V3<T>,
    point: V3<T>,
    (com, q): (V3<T>, Quat<T>),
    (disc_v, disc_w): (V3<T>, V3<T>),
    (rad, reach2): (T, T),
    material: ContactMaterial<T>,
    inv_h: T,
) -> (T, V3<T>, Sym3<T>, V3<T>) {
    let arm = q.rotate(point);
    let bx = com + arm;
    let rel = x - com;
    let dist2 = rel.dot(rel);
    let gap = normal.dot(x - bx) - rad;
    // Beyond the disc's bounding sphere a frozen contact plane would reach too far.
    let gap = T::select_lt(reach2, dist2, T::splat(1.0), gap);
    let surface_v = disc_v + disc_w.cross(arm);
    let (f, kk) = contact_vertex(gap, normal, v - surface_v, material, inv_h);
    (gap, f, kk, arm)
}

/// The rotation vector taking `from` to `to` (both unit quaternions), short way round.
#[inline(always)]
pub(super) fn rotation_between<const W: usize>(to: Quat<L<W>>, from: Quat<L<W>>) -> V3<L<W>> {
    let conj = Quat {
        v: -from.v,
        w: from.w,
    };
    let d = to.compose(conj);
    d.v * (d.w.sign() * L::splat(2.0))
}

/// `q` turned by the small rotation vector `theta` (first order, renormalised).
#[inline(always)]
pub(super) fn turned<const W: usize>(q: Quat<L<W>>, theta: V3<L<W>>) -> Quat<L<W>> {
    let zero = L::splat(0.0);
    let spin = Quat { v: theta, w: zero }.compose(q);
    let half = L::splat(0.5);
    Quat {
        v: q.v + spin.v * half,
        w: q.w + spin.w * half,
    }
    .normalize()
}

/// `R·diag(i)·Rᵀ·u` for the rotation `q`.
#[inline(always)]
pub(super) fn world_inertia_times<const W: usize>(
    q: Quat<L<W>>,
    i: V3<L<W>>,
    u: V3<L<W>>,
) -> V3<L<W>> {
    let b = q.rotate_inv(u);
    q.rotate(V3::new(b.x * i.x, b.y * i.y, b.z * i.z))
}

impl<const W: usize> BlockDescent<W> {
    /// The film's contacts on the disc for a single-environment block: [`ELEMENT_LANES`]
    /// candidates side by side, added to `sys` in candidate order (bit-identical, as
    /// [`Self::add_membrane_across_elements`]).
    #[inline(always)]
    #[allow(clippy::too_many_arguments)]
    pub(super) fn add_disc_contacts_across_elements(
        &self,
        state: &State<W>,
        m: ContactMaterial<L<W>>,
        sys: &mut Disc6<W>,
        (com, q): (V3<L<W>>, Quat<L<W>>),
        (disc_v, disc_w): (V3<L<W>>, V3<L<W>>),
        (rad, reach2): (L<W>, L<W>),
        inv_h: L<W>,
    ) {
        let wide = |v: V3<L<W>>| {
            V3::new(
                E8::splat(v.x.0[0]),
                E8::splat(v.y.0[0]),
                E8::splat(v.z.0[0]),
            )
        };
        let pose = (
            wide(com),
            Quat {
                v: wide(q.v),
                w: E8::splat(q.w.0[0]),
            },
        );
        let motion = (wide(disc_v), wide(disc_w));
        let sizes = (E8::splat(rad.0[0]), E8::splat(reach2.0[0]));
        let material = ContactMaterial {
            ke: E8::splat(m.ke.0[0]),
            kd: E8::splat(m.kd.0[0]),
            kf: E8::splat(m.kf.0[0]),
            mu: E8::splat(m.mu.0[0]),
        };
        let inv_h = E8::splat(inv_h.0[0]);
        for chunk in self.disc_candidates.chunks(ELEMENT_LANES) {
            let mut x = V3::<E8>::zero();
            let mut v = V3::<E8>::zero();
            let mut normal = V3::<E8>::zero();
            let mut point = V3::<E8>::zero();
            for e in 0..ELEMENT_LANES {
                // Short chunks repeat their last candidate; those lanes are not added below.
                let i = chunk[e.min(chunk.len() - 1)] as usize;
                set3(&mut x, e, get3(&state.x[i], 0));
                set3(&mut v, e, get3(&self.particle_rate(&state.v, i), 0));
                set3(&mut normal, e, get3(&state.contact_normal[i], 0));
                set3(&mut point, e, get3(&state.contact_point[i], 0));
            }
            let (gap, f, kk, arm) =
                disc_contact_at(x, v, normal, point, pose, motion, sizes, material, inv_h);
            let (g, h) = point_terms(-f, &kk, arm);
            for e in 0..chunk.len() {
                let lane = |a: E8| L::<W>::splat(a.0[e]);
                sys.add_terms(lane(gap), |a| lane(g[a]), |n| lane(h[n]));
            }
        }
    }

    /// Contact of particle `i` with the disc at pose (`com`, `q`) moving with (`disc_v`,
    /// `disc_w`): gap (negative when touching), force on the particle, stiffness, arm from the
    /// centre to the contact point.
    #[inline(always)]
    #[allow(clippy::too_many_arguments)]
    pub(super) fn disc_contact(
        &self,
        state: &State<W>,
        material: ContactMaterial<L<W>>,
        i: usize,
        com: V3<L<W>>,
        q: Quat<L<W>>,
        disc_v: V3<L<W>>,
        disc_w: V3<L<W>>,
        rad: L<W>,
        reach2: L<W>,
        inv_h: L<W>,
    ) -> (L<W>, V3<L<W>>, Sym3<L<W>>, V3<L<W>>) {
        disc_contact_at(
            state.x[i],
            self.particle_rate(&state.v, i),
            state.contact_normal[i],
            state.contact_point[i],
            (com, q),
            (disc_v, disc_w),
            (rad, reach2),
            material,
            inv_h,
        )
    }

    /// The step velocity of particle `i`'s current iterate (package particles) or its velocity
    /// `v` (cup particles, which move kinematically).
    #[inline(always)]
    fn particle_rate(&self, v: &[V3<L<W>>], i: usize) -> V3<L<W>> {
        if i < self.x_rate.len() {
            self.x_rate[i]
        } else {
            v[i]
        }
    }
}
