//! The single-environment paths of the solvers: a block of one lane has no environments to put
//! side by side, so element loops put [`ELEMENT_LANES`] elements side by side instead. Each
//! element's arithmetic is the same as in the per-environment path and results are added in the
//! same element order, so both paths give bit-identical results.

use crate::math::{get3, set3, Lanes, V3};

/// Elements processed together by the single-environment paths (SIMD across elements).
pub(crate) const ELEMENT_LANES: usize = 8;

/// [`ELEMENT_LANES`] elements side by side.
pub(crate) type E8 = Lanes<ELEMENT_LANES>;

/// Lane 0's positions `x` and velocities `v` at the `N` vertices of `count` elements (`vertices(e)`
/// of element `e`), element `e` in lane `e`. Lanes past `count` repeat the last element; callers
/// do not add them.
#[inline(always)]
pub(crate) fn gather_elements<const W: usize, const N: usize>(
    count: usize,
    vertices: impl Fn(usize) -> [u32; N],
    x: &[V3<Lanes<W>>],
    v: &[V3<Lanes<W>>],
) -> ([V3<E8>; N], [V3<E8>; N]) {
    let mut xs = [V3::<E8>::zero(); N];
    let mut vs = [V3::<E8>::zero(); N];
    for e in 0..ELEMENT_LANES {
        for (k, &j) in vertices(e.min(count - 1)).iter().enumerate() {
            set3(&mut xs[k], e, get3(&x[j as usize], 0));
            set3(&mut vs[k], e, get3(&v[j as usize], 0));
        }
    }
    (xs, vs)
}
