//! The single-environment paths of the solvers: a block of one lane has no environments to put
//! side by side, so element loops put [`ELEMENT_LANES`] elements side by side instead. Each
//! element's arithmetic is the same as in the per-environment path and results are added in the
//! same element order, so both paths give bit-identical results.

use crate::math::{get3, set3, Lanes, Real, V3};
use crate::model::Triangle;

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

/// The rest shapes `Dm` and `1 / A0` of the triangles of `chunk` (at most [`ELEMENT_LANES`]),
/// triangle `e` in lane `e`; lanes past the last repeat it, as in [`gather_elements`].
#[inline(always)]
pub(crate) fn gather_triangle_rest(chunk: &[Triangle]) -> ([[E8; 2]; 2], E8) {
    let mut dm = [[E8::splat(0.0); 2]; 2];
    let mut inv_area = E8::splat(1.0);
    for e in 0..ELEMENT_LANES {
        let tri = &chunk[e.min(chunk.len() - 1)];
        for (r, row) in tri.rest.dm.iter().enumerate() {
            for (c, value) in row.iter().enumerate() {
                dm[r][c].0[e] = *value;
            }
        }
        inv_area.0[e] = tri.rest.inv_rest_area();
    }
    (dm, inv_area)
}
