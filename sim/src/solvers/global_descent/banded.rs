//! A symmetric positive definite banded matrix and its Cholesky factor, one matrix per SIMD lane
//! with the band shared by the lanes: every lane's arithmetic is the same sequence of lane-wise
//! operations, so a lane's result does not depend on the others (and a lone lane gives the
//! same bits as in a batch).
//!
//! Hand-written rather than from a crate: the sparse and banded solvers of the Rust ecosystem
//! factor one matrix of `f64`/`f32` at a time, while here the `W` environments of a block are
//! factored together in SIMD lanes (the factor costs `n·b²/2` lane operations, a solve `2·n·b`).

use crate::math::{Lanes, Real, V3};

type L<const W: usize> = Lanes<W>;

/// A banded SPD matrix of size `n` and half bandwidth `b` (entries `(i, j)` with `|i − j| ≤ b`),
/// stored by rows of its lower band; [`Banded::factor`] replaces it by its Cholesky factor.
pub(crate) struct Banded<const W: usize> {
    n: usize,
    b: usize,
    /// Row `i` holds `(i, i − b ..= i)` at `i·(b + 1) ..`; entries before column 0 stay 0. After
    /// factoring: the factor `L` below the diagonal and `1 / L_ii` on it.
    entries: Vec<L<W>>,
}

impl<const W: usize> Banded<W> {
    /// The zero matrix of size `n`, half bandwidth `b`.
    pub(crate) fn new(n: usize, b: usize) -> Self {
        Banded {
            n,
            b,
            entries: vec![L::splat(0.0); n * (b + 1)],
        }
    }

    /// Size and half bandwidth.
    pub(crate) fn shape(&self) -> (usize, usize) {
        (self.n, self.b)
    }

    /// Index of entry `(i, j)`, `j ≤ i ≤ j + b`.
    #[inline(always)]
    fn at(&self, i: usize, j: usize) -> usize {
        i * (self.b + 1) + self.b + j - i
    }

    /// Row `i` of the lower band, entries `(i, i − b ..= i)`.
    #[inline(always)]
    pub(crate) fn row_mut(&mut self, i: usize) -> &mut [L<W>] {
        let w = self.b + 1;
        &mut self.entries[i * w..(i + 1) * w]
    }

    /// Bytes held.
    pub(crate) fn bytes(&self) -> usize {
        self.entries.capacity() * std::mem::size_of::<L<W>>()
    }

    /// Factors the matrix in place, `A = L·Lᵀ` (row-by-row Cholesky-Crout).
    pub(crate) fn factor(&mut self) {
        let (n, b, w) = (self.n, self.b, self.b + 1);
        let one = L::<W>::splat(1.0);
        for i in 0..n {
            let j0 = i.saturating_sub(b);
            for j in j0..=i {
                let k0 = j0.max(j.saturating_sub(b));
                let row_i = &self.entries[self.at(i, k0)..self.at(i, j)];
                let row_j = &self.entries[self.at(j, k0)..j * w + b];
                let mut s = self.entries[self.at(i, j)];
                for (&lik, &ljk) in row_i.iter().zip(row_j) {
                    s -= lik * ljk;
                }
                let at = self.at(i, j);
                self.entries[at] = if j < i {
                    s * self.entries[self.at(j, j)]
                } else {
                    one / s.sqrt()
                };
            }
        }
    }

    /// Solves `A·x = rhs` in place with the factor (three right-hand sides, the components).
    pub(crate) fn solve(&self, rhs: &mut [V3<L<W>>]) {
        let (n, b) = (self.n, self.b);
        for i in 0..n {
            let j0 = i.saturating_sub(b);
            let mut s = rhs[i];
            for (k, &lik) in (j0..i).zip(&self.entries[self.at(i, j0)..self.at(i, i)]) {
                s -= rhs[k] * lik;
            }
            rhs[i] = s * self.entries[self.at(i, i)];
        }
        for i in (0..n).rev() {
            let mut s = rhs[i];
            for k in i + 1..n.min(i + b + 1) {
                s -= rhs[k] * self.entries[self.at(k, i)];
            }
            rhs[i] = s * self.entries[self.at(i, i)];
        }
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
