//! Numeric types shared by the force laws: a [`Real`] trait implemented for `f32`, `f64` (tests,
//! finite differences) and [`Lanes`] (W environments side by side), plus small 3-vector,
//! quaternion and symmetric 3×3 matrix ([`Sym3`], the solvers' stiffness blocks) types generic
//! over it.
//!
//! Every force law is written once, generically; on [`Lanes`] each arithmetic operation is the
//! same operation written out for each of the W lanes, which the compiler turns into one SIMD
//! instruction. Lanes never interact, all operations are plain IEEE-754 (no fused multiply-add, no
//! reassociation, `acos` is a polynomial built from the same operations), so lane `l` computes
//! exactly what the scalar `f32` code computes for that environment: this is what makes results
//! bit-identical whatever the batch.

use std::ops::{Add, AddAssign, Div, Mul, Neg, Sub, SubAssign};

/// A floating-point value, or W of them processed in lockstep.
pub trait Real:
    Copy
    + Add<Output = Self>
    + Sub<Output = Self>
    + Mul<Output = Self>
    + Div<Output = Self>
    + Neg<Output = Self>
    + AddAssign
    + SubAssign
{
    /// The same value in every lane.
    fn splat(value: f32) -> Self;
    /// Square root (IEEE, correctly rounded).
    fn sqrt(self) -> Self;
    /// Per lane: `if a < b { yes } else { no }`.
    fn select_lt(a: Self, b: Self, yes: Self, no: Self) -> Self;

    /// Absolute value.
    #[inline(always)]
    fn abs(self) -> Self {
        Self::select_lt(self, Self::splat(0.0), -self, self)
    }
    /// Minimum (`b` when either is NaN, like `minps`).
    #[inline(always)]
    fn min(self, other: Self) -> Self {
        Self::select_lt(self, other, self, other)
    }
    /// Maximum (`b` when either is NaN, like `maxps`).
    #[inline(always)]
    fn max(self, other: Self) -> Self {
        Self::select_lt(other, self, self, other)
    }
    /// Clamp to `[lo, hi]`.
    #[inline(always)]
    fn clamp(self, lo: f32, hi: f32) -> Self {
        self.max(Self::splat(lo)).min(Self::splat(hi))
    }
    /// Warp's `sign`: −1 for negative values, +1 otherwise (so sign(0) = +1).
    #[inline(always)]
    fn sign(self) -> Self {
        Self::select_lt(self, Self::splat(0.0), Self::splat(-1.0), Self::splat(1.0))
    }
    /// `acos` with the argument clamped to [−1, 1] (Warp's unclamped `acos` gives NaN when rounding
    /// pushes a cosine past 1). Abramowitz & Stegun 4.4.46, absolute error below 1e-7 in f32.
    #[inline(always)]
    fn acos_clamped(self) -> Self {
        let x = self.clamp(-1.0, 1.0);
        let a = x.abs();
        // The published coefficients, kept as printed.
        #[allow(clippy::excessive_precision)]
        let coefficients = [
            0.006_670_090_1,
            -0.017_088_125_6,
            0.030_891_881_0,
            -0.050_174_304_6,
            0.088_978_987_4,
            -0.214_598_801_6,
            1.570_796_305_0,
        ];
        // Horner's scheme written out: a loop here would be one of the many tiny loops that make
        // LLVM's loop passes slow on a substep with every force law inlined.
        let [c0, c1, c2, c3, c4, c5, c6] = coefficients;
        let mut p = Self::splat(-0.001_262_491_1);
        p = p * a + Self::splat(c0);
        p = p * a + Self::splat(c1);
        p = p * a + Self::splat(c2);
        p = p * a + Self::splat(c3);
        p = p * a + Self::splat(c4);
        p = p * a + Self::splat(c5);
        p = p * a + Self::splat(c6);
        let r = (Self::splat(1.0) - a).sqrt() * p;
        Self::select_lt(
            x,
            Self::splat(0.0),
            Self::splat(std::f32::consts::PI) - r,
            r,
        )
    }
}

impl Real for f32 {
    #[inline(always)]
    fn splat(value: f32) -> Self {
        value
    }
    #[inline(always)]
    fn sqrt(self) -> Self {
        f32::sqrt(self)
    }
    #[inline(always)]
    fn select_lt(a: Self, b: Self, yes: Self, no: Self) -> Self {
        if a < b {
            yes
        } else {
            no
        }
    }
}

impl Real for f64 {
    #[inline(always)]
    fn splat(value: f32) -> Self {
        value as f64
    }
    #[inline(always)]
    fn sqrt(self) -> Self {
        f64::sqrt(self)
    }
    #[inline(always)]
    fn select_lt(a: Self, b: Self, yes: Self, no: Self) -> Self {
        if a < b {
            yes
        } else {
            no
        }
    }
    #[inline(always)]
    fn acos_clamped(self) -> Self {
        self.clamp(-1.0, 1.0).acos()
    }
}

/// W `f32` values, one per environment of a block.
#[derive(Clone, Copy, Debug, PartialEq)]
#[repr(transparent)]
pub struct Lanes<const W: usize>(pub [f32; W]);

/// `Lanes([f(0), f(1), …, f(W − 1)])`, written out without a loop for the widths the simulator
/// uses (1, 4, 8 and 16). Every arithmetic operation is inlined into the solvers' substeps, thousands
/// of them per substep: written as loops, each would be one more loop for LLVM's loop passes to
/// visit across the whole function, and compiling the simulator would take most of an hour.
#[inline(always)]
fn lanewise<const W: usize>(f: impl Fn(usize) -> f32) -> Lanes<W> {
    macro_rules! written_out {
        ($($l:literal)*) => {{
            let mut out = [0.0; W];
            $(out[$l] = f($l);)*
            Lanes(out)
        }};
    }
    match W {
        1 => written_out!(0),
        4 => written_out!(0 1 2 3),
        8 => written_out!(0 1 2 3 4 5 6 7),
        16 => written_out!(0 1 2 3 4 5 6 7 8 9 10 11 12 13 14 15),
        _ => Lanes(std::array::from_fn(f)),
    }
}

macro_rules! lane_binop {
    ($trait:ident, $method:ident, $op:tt) => {
        impl<const W: usize> $trait for Lanes<W> {
            type Output = Self;
            #[inline(always)]
            fn $method(self, rhs: Self) -> Self {
                lanewise(|l| self.0[l] $op rhs.0[l])
            }
        }
    };
}
lane_binop!(Add, add, +);
lane_binop!(Sub, sub, -);
lane_binop!(Mul, mul, *);
lane_binop!(Div, div, /);

impl<const W: usize> Neg for Lanes<W> {
    type Output = Self;
    #[inline(always)]
    fn neg(self) -> Self {
        lanewise(|l| -self.0[l])
    }
}
impl<const W: usize> AddAssign for Lanes<W> {
    #[inline(always)]
    fn add_assign(&mut self, rhs: Self) {
        *self = *self + rhs;
    }
}
impl<const W: usize> SubAssign for Lanes<W> {
    #[inline(always)]
    fn sub_assign(&mut self, rhs: Self) {
        *self = *self - rhs;
    }
}

impl<const W: usize> Real for Lanes<W> {
    #[inline(always)]
    fn splat(value: f32) -> Self {
        // Not `[value; W]`, which is compiled as a loop (see `lanewise`).
        lanewise(|_| value)
    }
    #[inline(always)]
    fn sqrt(self) -> Self {
        lanewise(|l| self.0[l].sqrt())
    }
    #[inline(always)]
    fn select_lt(a: Self, b: Self, yes: Self, no: Self) -> Self {
        lanewise(|l| if a.0[l] < b.0[l] { yes.0[l] } else { no.0[l] })
    }
}

/// A vector of lane values whose buffer starts on a 64-byte cache line, so that no 16-lane value
/// (one line) or 8-lane value (half a line) straddles two: from the allocator's 16-byte alignment
/// most of them did, and a load or store split across two lines costs two.
pub(crate) type LaneVec<T> = aligned_vec::AVec<T, aligned_vec::ConstAlign<64>>;

/// `n` copies of `value` in a [`LaneVec`].
pub(crate) fn lane_vec<T: Clone>(value: T, n: usize) -> LaneVec<T> {
    LaneVec::from_iter(64, std::iter::repeat_n(value, n))
}

/// A 3-vector of [`Real`]s.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct V3<T> {
    /// x component.
    pub x: T,
    /// y component (up).
    pub y: T,
    /// z component.
    pub z: T,
}

impl<T: Real> V3<T> {
    /// Builds a vector from its components.
    #[inline(always)]
    pub fn new(x: T, y: T, z: T) -> Self {
        V3 { x, y, z }
    }
    /// The zero vector.
    #[inline(always)]
    pub fn zero() -> Self {
        Self::splat([0.0; 3])
    }
    /// The same `f32` vector in every lane.
    #[inline(always)]
    pub fn splat(v: [f32; 3]) -> Self {
        V3::new(T::splat(v[0]), T::splat(v[1]), T::splat(v[2]))
    }
    /// Dot product.
    #[inline(always)]
    pub fn dot(self, o: Self) -> T {
        self.x * o.x + self.y * o.y + self.z * o.z
    }
    /// Cross product.
    #[inline(always)]
    pub fn cross(self, o: Self) -> Self {
        V3::new(
            self.y * o.z - self.z * o.y,
            self.z * o.x - self.x * o.z,
            self.x * o.y - self.y * o.x,
        )
    }
    /// Euclidean length.
    #[inline(always)]
    pub fn length(self) -> T {
        self.dot(self).sqrt()
    }
    /// Warp's `normalize`: `v / |v|`, or zero when `|v| = 0`.
    #[inline(always)]
    pub fn normalize(self) -> Self {
        let len = self.length();
        let zero = T::splat(0.0);
        let safe = T::select_lt(zero, len, len, T::splat(1.0));
        let n = self / safe;
        let keep = |c: T| T::select_lt(zero, len, c, zero);
        V3::new(keep(n.x), keep(n.y), keep(n.z))
    }
    /// Component-wise select: `if a < b { yes } else { no }` with a scalar condition per lane.
    #[inline(always)]
    pub fn select_lt(a: T, b: T, yes: Self, no: Self) -> Self {
        V3::new(
            T::select_lt(a, b, yes.x, no.x),
            T::select_lt(a, b, yes.y, no.y),
            T::select_lt(a, b, yes.z, no.z),
        )
    }
}

impl<T: Real> Add for V3<T> {
    type Output = Self;
    #[inline(always)]
    fn add(self, o: Self) -> Self {
        V3::new(self.x + o.x, self.y + o.y, self.z + o.z)
    }
}
impl<T: Real> Sub for V3<T> {
    type Output = Self;
    #[inline(always)]
    fn sub(self, o: Self) -> Self {
        V3::new(self.x - o.x, self.y - o.y, self.z - o.z)
    }
}
impl<T: Real> Neg for V3<T> {
    type Output = Self;
    #[inline(always)]
    fn neg(self) -> Self {
        V3::new(-self.x, -self.y, -self.z)
    }
}
impl<T: Real> Mul<T> for V3<T> {
    type Output = Self;
    #[inline(always)]
    fn mul(self, s: T) -> Self {
        V3::new(self.x * s, self.y * s, self.z * s)
    }
}
impl<T: Real> Div<T> for V3<T> {
    type Output = Self;
    #[inline(always)]
    fn div(self, s: T) -> Self {
        V3::new(self.x / s, self.y / s, self.z / s)
    }
}
impl<T: Real> AddAssign for V3<T> {
    #[inline(always)]
    fn add_assign(&mut self, o: Self) {
        *self = *self + o;
    }
}
impl<T: Real> SubAssign for V3<T> {
    #[inline(always)]
    fn sub_assign(&mut self, o: Self) {
        *self = *self - o;
    }
}

/// A unit quaternion (x, y, z, w), Warp's convention.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Quat<T> {
    /// Vector part.
    pub v: V3<T>,
    /// Scalar part.
    pub w: T,
}

impl<T: Real> Quat<T> {
    /// Rotates `p` by this quaternion (Warp's `quat_rotate`).
    #[inline(always)]
    pub fn rotate(self, p: V3<T>) -> V3<T> {
        let two = T::splat(2.0);
        let a = p * (two * self.w * self.w - T::splat(1.0));
        let b = self.v.cross(p) * (self.w * two);
        let c = self.v * (self.v.dot(p) * two);
        a + b + c
    }
    /// Rotates `p` by the inverse of this quaternion (Warp's `quat_rotate_inv`).
    #[inline(always)]
    pub fn rotate_inv(self, p: V3<T>) -> V3<T> {
        Quat {
            v: -self.v,
            w: self.w,
        }
        .rotate(p)
    }
    /// Hamilton product `self ⊗ o`.
    #[inline(always)]
    pub fn compose(self, o: Self) -> Self {
        Quat {
            v: o.v * self.w + self.v * o.w + self.v.cross(o.v),
            w: self.w * o.w - self.v.dot(o.v),
        }
    }
    /// Normalised copy.
    #[inline(always)]
    pub fn normalize(self) -> Self {
        let len = (self.v.dot(self.v) + self.w * self.w).sqrt();
        Quat {
            v: self.v / len,
            w: self.w / len,
        }
    }
}

/// Lane `l` of a 3-vector of lanes.
#[inline(always)]
pub(crate) fn get3<const W: usize>(v: &V3<Lanes<W>>, l: usize) -> [f32; 3] {
    [v.x.0[l], v.y.0[l], v.z.0[l]]
}

/// Sets lane `l` of a 3-vector of lanes.
#[inline(always)]
pub(crate) fn set3<const W: usize>(v: &mut V3<Lanes<W>>, l: usize, a: [f32; 3]) {
    v.x.0[l] = a[0];
    v.y.0[l] = a[1];
    v.z.0[l] = a[2];
}

/// A symmetric 3×3 matrix.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Sym3<T> {
    /// Entries xx, xy, xz, yy, yz, zz.
    pub m: [T; 6],
}

impl<T: Real> Sym3<T> {
    /// The zero matrix.
    #[inline(always)]
    pub fn zero() -> Self {
        Sym3 {
            m: [T::splat(0.0); 6],
        }
    }
    /// `d·I`.
    #[inline(always)]
    pub fn diagonal(d: T) -> Self {
        let z = T::splat(0.0);
        Sym3 {
            m: [d, z, z, d, z, d],
        }
    }
    /// `s·a·aᵀ`.
    #[inline(always)]
    pub fn outer(a: V3<T>, s: T) -> Self {
        let (x, y, z) = (a.x * s, a.y * s, a.z * s);
        Sym3 {
            m: [x * a.x, x * a.y, x * a.z, y * a.y, y * a.z, z * a.z],
        }
    }
    /// `s·(I − n·nᵀ)`: the projection onto the plane normal to the unit vector `n`, scaled.
    #[inline(always)]
    pub fn tangential(n: V3<T>, s: T) -> Self {
        let mut p = Self::diagonal(s);
        p.sub_assign(Self::outer(n, s));
        p
    }
    /// `self += o`.
    #[inline(always)]
    pub fn add_assign(&mut self, o: Self) {
        // Written out, not a loop (see `lanewise`).
        let (m, o) = (&mut self.m, o.m);
        m[0] += o[0];
        m[1] += o[1];
        m[2] += o[2];
        m[3] += o[3];
        m[4] += o[4];
        m[5] += o[5];
    }
    /// `self −= o`.
    #[inline(always)]
    pub fn sub_assign(&mut self, o: Self) {
        let (m, o) = (&mut self.m, o.m);
        m[0] -= o[0];
        m[1] -= o[1];
        m[2] -= o[2];
        m[3] -= o[3];
        m[4] -= o[4];
        m[5] -= o[5];
    }
    /// `self + o`.
    #[inline(always)]
    pub fn plus(mut self, o: Self) -> Self {
        self.add_assign(o);
        self
    }
    /// Per lane: `if a < b { yes } else { no }`.
    #[inline(always)]
    pub fn select_lt(a: T, b: T, yes: Self, no: Self) -> Self {
        let (y, n) = (yes.m, no.m);
        Sym3 {
            m: [
                T::select_lt(a, b, y[0], n[0]),
                T::select_lt(a, b, y[1], n[1]),
                T::select_lt(a, b, y[2], n[2]),
                T::select_lt(a, b, y[3], n[3]),
                T::select_lt(a, b, y[4], n[4]),
                T::select_lt(a, b, y[5], n[5]),
            ],
        }
    }
    /// `self·s`.
    #[inline(always)]
    pub fn scale(self, s: T) -> Self {
        Sym3 {
            m: [
                self.m[0] * s,
                self.m[1] * s,
                self.m[2] * s,
                self.m[3] * s,
                self.m[4] * s,
                self.m[5] * s,
            ],
        }
    }
    /// Keeps `self` in lanes where `a < b`, zero elsewhere.
    #[inline(always)]
    pub fn keep_lt(self, a: T, b: T) -> Self {
        let z = T::splat(0.0);
        let m = self.m;
        Sym3 {
            m: [
                T::select_lt(a, b, m[0], z),
                T::select_lt(a, b, m[1], z),
                T::select_lt(a, b, m[2], z),
                T::select_lt(a, b, m[3], z),
                T::select_lt(a, b, m[4], z),
                T::select_lt(a, b, m[5], z),
            ],
        }
    }
    /// `self·v`.
    #[inline(always)]
    pub fn mul_vec(&self, v: V3<T>) -> V3<T> {
        let [xx, xy, xz, yy, yz, zz] = self.m;
        V3::new(
            xx * v.x + xy * v.y + xz * v.z,
            xy * v.x + yy * v.y + yz * v.z,
            xz * v.x + yz * v.y + zz * v.z,
        )
    }
    /// Solves `self·u = b` by the adjugate (the matrix is positive definite: the inertia term
    /// alone makes it so).
    #[inline(always)]
    pub fn solve(&self, b: V3<T>) -> V3<T> {
        let [xx, xy, xz, yy, yz, zz] = self.m;
        let c_xx = yy * zz - yz * yz;
        let c_xy = xz * yz - xy * zz;
        let c_xz = xy * yz - xz * yy;
        let c_yy = xx * zz - xz * xz;
        let c_yz = xy * xz - xx * yz;
        let c_zz = xx * yy - xy * xy;
        let det = xx * c_xx + xy * c_xy + xz * c_xz;
        let inv = T::splat(1.0) / det;
        V3::new(
            (c_xx * b.x + c_xy * b.y + c_xz * b.z) * inv,
            (c_xy * b.x + c_yy * b.y + c_yz * b.z) * inv,
            (c_xz * b.x + c_yz * b.y + c_zz * b.z) * inv,
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn acos_matches_std_and_clamps() {
        let mut worst = 0.0f64;
        for i in 0..=2000 {
            let x = -1.0 + i as f32 / 1000.0;
            let err = (x.acos_clamped() as f64 - (x as f64).acos()).abs();
            worst = worst.max(err);
        }
        assert!(worst < 5e-7, "acos error {worst}");
        assert_eq!(1.000_001f32.acos_clamped(), 0.0);
        assert!(((-1.5f32).acos_clamped() - std::f32::consts::PI).abs() < 1e-6);
    }

    #[test]
    fn lanes_agree_with_scalar_bit_for_bit() {
        let xs = [0.3f32, -0.7, 1.0, 0.999_999, -0.0, 2.5, 1e-8, -1e-3];
        let lanes = Lanes(xs).acos_clamped() * Lanes(xs) + Lanes(xs).abs().sqrt();
        for l in 0..8 {
            let scalar = xs[l].acos_clamped() * xs[l] + Real::sqrt(Real::abs(xs[l]));
            assert_eq!(lanes.0[l].to_bits(), scalar.to_bits(), "lane {l}");
        }
    }

    #[test]
    fn quaternion_rotation_is_a_rotation() {
        let h = std::f32::consts::FRAC_1_SQRT_2;
        let q = Quat {
            v: V3::new(h, 0.0, 0.0),
            w: h,
        };
        let r = q.rotate(V3::new(0.0f32, 0.0, 1.0));
        assert!((r.y + 1.0).abs() < 1e-6 && r.x.abs() < 1e-6 && r.z.abs() < 1e-6);
        let back = q.rotate_inv(r);
        assert!((back.z - 1.0).abs() < 1e-6);
        let qq = q.compose(q).normalize();
        let r2 = qq.rotate(V3::new(0.0f32, 1.0, 0.0));
        assert!((r2.y + 1.0).abs() < 1e-6);
    }

    #[test]
    fn sym3_solve_inverts_the_matrix() {
        let mut a = Sym3::diagonal(2.0f64);
        a.add_assign(Sym3::outer(V3::new(1.0, 2.0, -1.0), 3.0));
        let b = V3::new(0.5, -1.0, 2.0);
        let u = a.solve(b);
        assert!((a.mul_vec(u) - b).length() <= 1e-12 * b.length());
    }
}
