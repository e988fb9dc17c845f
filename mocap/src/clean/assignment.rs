//! Gated optimal assignment of rows to columns (Hungarian / Jonker-Volgenant), as used to match
//! new marker ids to lost tracks.

/// Optimal assignment of rows to columns for a row-major `rows x cols` cost matrix (Hungarian /
/// Jonker-Volgenant via `lsap`, scipy's `linear_sum_assignment`), keeping only pairs whose cost is
/// at most `max_cost` (a row may stay unassigned rather than take a pair above it). Non-finite
/// costs are forbidden.
pub fn assign(cost: &[f64], rows: usize, cols: usize, max_cost: f64) -> Vec<(usize, usize)> {
    assert_eq!(cost.len(), rows * cols, "cost matrix must be rows x cols");
    let allowed = |c: f64| c.is_finite() && c <= max_cost;
    let finite_max = cost
        .iter()
        .copied()
        .filter(|c| c.is_finite())
        .fold(0.0, f64::max);
    let (matrix, width) = if max_cost.is_finite() {
        // Gating: every row may also take one of `rows` dummy columns at cost `max_cost`, so a
        // pair above the threshold is never chosen to make room for another pair.
        let forbidden = 2.0 * (finite_max.max(max_cost.abs()) + 1.0);
        let width = cols + rows;
        let mut matrix = vec![max_cost.max(0.0); rows * width];
        for r in 0..rows {
            for c in 0..cols {
                let value = cost[r * cols + c];
                matrix[r * width + c] = if allowed(value) { value } else { forbidden };
            }
        }
        (matrix, width)
    } else {
        // No threshold: forbidden (non-finite) pairs only when unavoidable, then dropped.
        let forbidden = 2.0 * finite_max + 1.0;
        let matrix = cost
            .iter()
            .map(|&c| if c.is_finite() { c } else { forbidden })
            .collect();
        (matrix, cols)
    };
    let Ok((row_index, col_index)) = lsap::solve(rows, width, &matrix, false) else {
        return Vec::new();
    };
    row_index
        .into_iter()
        .zip(col_index)
        .filter(|&(r, c)| c < cols && allowed(cost[r * cols + c]))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::clean::test_support::close;

    /// Small deterministic generator so the test needs no extra crate.
    fn lcg(state: &mut u64) -> f64 {
        *state = state
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (*state >> 11) as f64 / (1u64 << 53) as f64
    }

    fn brute_force(cost: &[f64], rows: usize, cols: usize) -> f64 {
        // Best total over every injective map from the smaller side into the larger one.
        fn go(
            cost: &[f64],
            rows: usize,
            cols: usize,
            r: usize,
            used: &mut Vec<bool>,
            transpose: bool,
        ) -> f64 {
            let (n_small, n_large) = if transpose {
                (cols, rows)
            } else {
                (rows, cols)
            };
            if r == n_small {
                return 0.0;
            }
            let mut best = f64::INFINITY;
            for c in 0..n_large {
                if !used[c] {
                    used[c] = true;
                    let here = if transpose {
                        cost[c * cols + r]
                    } else {
                        cost[r * cols + c]
                    };
                    best = best.min(here + go(cost, rows, cols, r + 1, used, transpose));
                    used[c] = false;
                }
            }
            best
        }
        let transpose = cols < rows;
        go(
            cost,
            rows,
            cols,
            0,
            &mut vec![false; rows.max(cols)],
            transpose,
        )
    }

    #[test]
    fn hungarian_matches_brute_force() {
        let mut state = 7;
        for trial in 0..200 {
            let rows = 1 + trial % 5;
            let cols = 1 + (trial / 5) % 5;
            let cost: Vec<f64> = (0..rows * cols).map(|_| lcg(&mut state)).collect();
            let pairs = assign(&cost, rows, cols, f64::INFINITY);
            assert_eq!(pairs.len(), rows.min(cols));
            let total: f64 = pairs.iter().map(|&(r, c)| cost[r * cols + c]).sum();
            let best = brute_force(&cost, rows, cols);
            assert!(
                close(total, best, 1e-12),
                "{rows}x{cols}: {total} vs brute force {best}"
            );
        }
    }

    #[test]
    fn assignment_threshold_drops_expensive_pairs() {
        // Without gating the optimum would be (0,1)+(1,0) = 0.9, and both pairs would be dropped.
        let cost = [0.001, 0.5, 0.4, f64::INFINITY];
        assert_eq!(assign(&cost, 2, 2, 0.01), vec![(0, 0)]);
        assert_eq!(assign(&cost, 2, 2, 0.45), vec![(0, 0)]);
        let mut pairs = assign(&cost, 2, 2, 1.0);
        pairs.sort();
        assert_eq!(pairs, vec![(0, 1), (1, 0)]);
    }
}
