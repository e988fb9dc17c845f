//! Tracks as per-frame series of points (`None` where not seen), and their contiguous runs.

/// A point per frame, `None` where it was not seen.
pub type Series = Vec<Option<[f64; 3]>>;

/// Contiguous `Some` runs of a series, as half-open frame ranges.
pub fn runs<T>(series: &[Option<T>]) -> Vec<(usize, usize)> {
    let mut out = Vec::new();
    let mut start = None;
    for (k, item) in series.iter().enumerate() {
        match (item.is_some(), start) {
            (true, None) => start = Some(k),
            (false, Some(s)) => {
                out.push((s, k));
                start = None;
            }
            _ => {}
        }
    }
    if let Some(s) = start {
        out.push((s, series.len()));
    }
    out
}
