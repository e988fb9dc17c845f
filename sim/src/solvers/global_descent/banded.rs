//! A symmetric positive definite banded matrix and its Cholesky factor, one matrix per SIMD lane
//! with the band shared by the lanes: every lane's arithmetic is the same sequence of lane-wise
//! operations, so a lane's result does not depend on the others (and a lone lane gives the
//! same bits as in a batch).
//!
//! Hand-written rather than from a crate: the sparse and banded solvers of the Rust ecosystem
//! factor one matrix of `f64`/`f32` at a time, while here the `W` environments of a block are
//! factored together in SIMD lanes (the factor costs `n·b²/2` lane operations, a solve `2·n·b`).

use crate::math::{lane_vec, LaneVec, Lanes, Real, V3};

type L<const W: usize> = Lanes<W>;

/// A banded SPD matrix of size `n` and half bandwidth `b` (entries `(i, j)` with `|i − j| ≤ b`),
/// stored by rows of its lower band; [`Banded::factor`] replaces it by its Cholesky factor.
pub(crate) struct Banded<const W: usize> {
    n: usize,
    b: usize,
    /// Row `i` holds `(i, i − b ..= i)` at `i·(b + 1) ..`; entries before column 0 stay 0. After
    /// factoring: the factor `L` below the diagonal and `1 / L_ii` on it.
    entries: LaneVec<L<W>>,
    /// The factor again by columns: column `j` holds `(j ..= j + b, j)` at `j·(b + 1) ..` (`1 / L_jj`
    /// first), so the backward solve reads it in order instead of one band row apart per entry.
    columns: LaneVec<L<W>>,
}

impl<const W: usize> Banded<W> {
    /// The zero matrix of size `n`, half bandwidth `b`.
    pub(crate) fn new(n: usize, b: usize) -> Self {
        Banded {
            n,
            b,
            entries: lane_vec(L::splat(0.0), n * (b + 1)),
            columns: lane_vec(L::splat(0.0), n * (b + 1)),
        }
    }

    /// Size and half bandwidth.
    pub(crate) fn shape(&self) -> (usize, usize) {
        (self.n, self.b)
    }

    /// Row `i` of the lower band, entries `(i, i − b ..= i)`.
    #[inline(always)]
    pub(crate) fn row_mut(&mut self, i: usize) -> &mut [L<W>] {
        let w = self.b + 1;
        &mut self.entries[i * w..(i + 1) * w]
    }

    /// Bytes held.
    pub(crate) fn bytes(&self) -> usize {
        (self.entries.capacity() + self.columns.capacity()) * std::mem::size_of::<L<W>>()
    }

    /// Factors the matrix in place, `A = L·Lᵀ` (row-by-row Cholesky-Crout).
    #[inline(always)]
    pub(crate) fn factor(&mut self) {
        let (n, b) = (self.n, self.b);
        for i in 0..n {
            // Row `i`'s entries four at a time (the last group holds the diagonal).
            let j0 = i.saturating_sub(b);
            let mut j = j0;
            while j + 4 <= i + 1 {
                self.factor_entries::<4>(i, j0, j);
                j += 4;
            }
            match i + 1 - j {
                1 => self.factor_entries::<1>(i, j0, j),
                2 => self.factor_entries::<2>(i, j0, j),
                3 => self.factor_entries::<3>(i, j0, j),
                _ => {}
            }
        }
    }

    /// Entries `(i, j .. j + G)` of the factor, `j0` the first column of row `i`: each is
    /// `(A_ij − Σ_k L_ik·L_jk)` summed in column order from `j0` (times `1 / L_jj`, or its
    /// inverse square root on the diagonal). The `G` sums run side by side, so the additions of
    /// one entry do not wait on each other's latency; each entry's operations stay as they are.
    #[inline(always)]
    fn factor_entries<const G: usize>(&mut self, i: usize, j0: usize, j: usize) {
        let b = self.b;
        let at = |r: usize, c: usize| r * (b + 1) + b + c - r;
        let (e, columns) = (&mut self.entries, &mut self.columns);
        let len = j - j0;
        let mut s: [L<W>; G] = std::array::from_fn(|g| e[at(i, j + g)]);
        let row_i = &e[at(i, j0)..at(i, j0) + len];
        let rows: [&[L<W>]; G] = std::array::from_fn(|g| &e[at(j + g, j0)..at(j + g, j0) + len]);
        for k in 0..len {
            let lik = row_i[k];
            for (sg, row) in s.iter_mut().zip(&rows) {
                *sg -= lik * row[k];
            }
        }
        // The columns of this group: entry `j + g` needs the `g` before it.
        for (g, mut sg) in s.into_iter().enumerate() {
            for k in j..j + g {
                sg -= e[at(i, k)] * e[at(j + g, k)];
            }
            let value = if j + g < i {
                sg * e[at(j + g, j + g)]
            } else {
                L::splat(1.0) / sg.sqrt()
            };
            e[at(i, j + g)] = value;
            columns[(j + g) * (b + 1) + i - (j + g)] = value;
        }
    }

    /// Solves `A·x = rhs` in place with the factor (three right-hand sides, the components).
    #[inline(always)]
    pub(crate) fn solve(&self, rhs: &mut [V3<L<W>>]) {
        let (n, b) = (self.n, self.b);
        // Forward, two rows side by side (their sums share all columns but row `i`'s first and
        // row `i + 1`'s last; each sum in column order).
        let mut i = 0;
        while i + 1 < n {
            let (j0, j1) = (i.saturating_sub(b), (i + 1).saturating_sub(b));
            let (row0, row1) = (self.row(i), self.row(i + 1));
            let (mut s0, mut s1) = (rhs[i], rhs[i + 1]);
            for k in j0..j1 {
                s0 -= rhs[k] * row0[b + k - i];
            }
            for k in j1..i {
                let r = rhs[k];
                s0 -= r * row0[b + k - i];
                s1 -= r * row1[b + k - i - 1];
            }
            rhs[i] = s0 * row0[b];
            s1 -= rhs[i] * row1[b - 1];
            rhs[i + 1] = s1 * row1[b];
            i += 2;
        }
        if i < n {
            let j0 = i.saturating_sub(b);
            let row = self.row(i);
            let mut s = rhs[i];
            for k in j0..i {
                s -= rhs[k] * row[b + k - i];
            }
            rhs[i] = s * row[b];
        }
        // Backward, each sum in column order from `i + 1`.
        let w = b + 1;
        for i in (0..n).rev() {
            let column = &self.columns[i * w..(i + 1) * w];
            let end = n.min(i + w);
            let mut s = rhs[i];
            for (r, l) in rhs[i + 1..end].iter().zip(&column[1..end - i]) {
                s -= *r * *l;
            }
            rhs[i] = s * column[0];
        }
    }

    /// Row `i` of the lower band (see [`Banded::row_mut`]).
    #[inline(always)]
    fn row(&self, i: usize) -> &[L<W>] {
        let w = self.b + 1;
        &self.entries[i * w..(i + 1) * w]
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::{get3, set3};

    /// A random SPD banded matrix per lane (diagonally dominant), dense.
    fn dense_spd(n: usize, b: usize, lane: usize) -> Vec<Vec<f64>> {
        let mut a = vec![vec![0.0; n]; n];
        let mut seed = 12345u64 + lane as u64 * 777;
        let mut next = || {
            seed = seed
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (seed >> 33) as f64 / (1u64 << 31) as f64 - 0.5
        };
        for i in 0..n {
            for j in i.saturating_sub(b)..i {
                let v = next();
                a[i][j] = v;
                a[j][i] = v;
            }
        }
        for i in 0..n {
            a[i][i] = a[i].iter().map(|v: &f64| v.abs()).sum::<f64>() + 0.5 + next().abs();
        }
        a
    }

    fn dense_solve(mut a: Vec<Vec<f64>>, mut x: Vec<f64>) -> Vec<f64> {
        let n = x.len();
        for c in 0..n {
            for r in c + 1..n {
                let f = a[r][c] / a[c][c];
                for k in c..n {
                    a[r][k] -= f * a[c][k];
                }
                x[r] -= f * x[c];
            }
        }
        for r in (0..n).rev() {
            let s: f64 = (r + 1..n).map(|k| a[r][k] * x[k]).sum();
            x[r] = (x[r] - s) / a[r][r];
        }
        x
    }

    #[test]
    fn banded_cholesky_solves_each_lane_like_a_dense_solve() {
        const W: usize = 4;
        let (n, b) = (23, 5);
        let dense: Vec<_> = (0..W).map(|l| dense_spd(n, b, l)).collect();
        let mut m = Banded::<W>::new(n, b);
        assert_eq!(m.shape(), (n, b));
        for i in 0..n {
            let j0 = i.saturating_sub(b);
            let row = m.row_mut(i);
            for j in j0..=i {
                for (l, a) in dense.iter().enumerate() {
                    row[b + j - i].0[l] = a[i][j] as f32;
                }
            }
        }
        m.factor();
        let rhs_of = |i: usize, l: usize| [i as f64 + l as f64, 1.0 - i as f64, 0.3 * l as f64];
        let mut x = vec![V3::<L<W>>::zero(); n];
        for (i, xi) in x.iter_mut().enumerate() {
            for l in 0..W {
                set3(xi, l, rhs_of(i, l).map(|c| c as f32));
            }
        }
        m.solve(&mut x);
        for (l, a) in dense.iter().enumerate() {
            for c in 0..3 {
                let want = dense_solve(a.clone(), (0..n).map(|i| rhs_of(i, l)[c]).collect());
                for i in 0..n {
                    let got = get3(&x[i], l)[c] as f64;
                    assert!(
                        (got - want[i]).abs() < 1e-4 * (1.0 + want[i].abs()),
                        "lane {l} row {i} component {c}: {got} vs {}",
                        want[i]
                    );
                }
            }
        }
    }
}
