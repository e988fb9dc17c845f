//! The zero-phase Butterworth low-pass (scipy's `butter` + `sosfiltfilt`) and its application
//! to every contiguous run of a track.

use sci_rs::signal::filter::design::{
    butter_dyn, DigitalFilter, FilterBandType, FilterOutputType, Sos,
};
use sci_rs::signal::filter::sosfiltfilt_dyn;

use super::{runs, CleanError, Series};

/// A digital Butterworth low-pass in second-order sections, applied forward and backward.
#[derive(Debug, Clone)]
pub struct Butterworth {
    sections: Vec<Sos<f64>>,
}

impl Butterworth {
    /// Designs an `order`-th order low-pass with its -3 dB point at `cutoff_hz`, for samples taken
    /// at `sample_rate_hz` (scipy: `butter(order, cutoff_hz, fs=sample_rate_hz, output="sos")`).
    pub fn low_pass(order: usize, cutoff_hz: f64, sample_rate_hz: f64) -> Result<Self, CleanError> {
        if !(1..=10).contains(&order) {
            return Err(CleanError::Filter(format!(
                "order must be in 1..=10, found {order}"
            )));
        }
        let nyquist = sample_rate_hz / 2.0;
        if !(cutoff_hz > 0.0 && cutoff_hz < nyquist) {
            return Err(CleanError::Filter(format!(
                "cut-off must be in (0, {nyquist}) Hz (half the sampling rate {sample_rate_hz} Hz), found {cutoff_hz}"
            )));
        }
        let design = butter_dyn(
            order,
            vec![cutoff_hz],
            Some(FilterBandType::Lowpass),
            Some(false),
            Some(FilterOutputType::Sos),
            Some(sample_rate_hz),
        );
        match design {
            DigitalFilter::Sos(sos) => Ok(Butterworth { sections: sos.sos }),
            _ => Err(CleanError::Filter(
                "the design did not return second-order sections".into(),
            )),
        }
    }

    /// The second-order sections as (b, a) coefficient triples, scipy's `sos` rows.
    pub fn sections(&self) -> Vec<([f64; 3], [f64; 3])> {
        self.sections.iter().map(|s| (s.b, s.a)).collect()
    }

    /// The shortest series `filtfilt` accepts: the odd-extension padding (3 x (2 x sections + 1)
    /// samples, as scipy's `sosfiltfilt`) must fit inside it.
    pub fn min_len(&self) -> usize {
        3 * (2 * self.sections.len() + 1) + 1
    }

    /// Zero-phase filtering (scipy `sosfiltfilt`); `None` if `x` is shorter than [`Self::min_len`].
    pub fn filtfilt(&self, x: &[f64]) -> Option<Vec<f64>> {
        (x.len() >= self.min_len()).then(|| sosfiltfilt_dyn(x.iter(), &self.sections))
    }

    /// Filters every coordinate of every contiguous run of `series` long enough for the filter;
    /// returns how many samples sat in runs too short to filter (left as they were).
    pub fn filter_series(&self, series: &mut Series) -> usize {
        let mut unfiltered = 0;
        for (start, end) in runs(series) {
            for axis in 0..3 {
                let values: Vec<f64> = series[start..end]
                    .iter()
                    .map(|p| p.unwrap()[axis])
                    .collect();
                match self.filtfilt(&values) {
                    Some(filtered) => {
                        for (k, v) in filtered.into_iter().enumerate() {
                            if let Some(p) = series[start + k].as_mut() {
                                p[axis] = v;
                            }
                        }
                    }
                    None if axis == 0 => unfiltered += end - start,
                    None => {}
                }
            }
        }
        unfiltered
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::clean::test_support::close;

    #[test]
    fn butterworth_sections_match_scipy() {
        // Reference: scipy 1.17.1, `scipy.signal.butter(4, 12.0, fs=250.0, output="sos")` and
        // `butter(3, 5.0, fs=50.0, output="sos")` (the study's design), printed with repr().
        let cases: [(usize, f64, f64, Vec<[f64; 6]>); 2] = [
            (
                4,
                12.0,
                250.0,
                vec![
                    [
                        0.0003588407958559482,
                        0.0007176815917118963,
                        0.0003588407958559482,
                        1.0,
                        -1.4984959033971867,
                        0.5693282483273973,
                    ],
                    [1.0, 2.0, 1.0, 1.0, -1.7148025270468699, 0.7958594614085954],
                ],
            ),
            (
                3,
                5.0,
                50.0,
                vec![
                    [
                        0.018098933007514428,
                        0.036197866015028855,
                        0.018098933007514428,
                        1.0,
                        -0.5095254494944288,
                        0.0,
                    ],
                    [1.0, 1.0, 0.0, 1.0, -1.2505164308487402, 0.5457233155094579],
                ],
            ),
        ];
        for (order, cutoff, fs, expected) in cases {
            let sections = Butterworth::low_pass(order, cutoff, fs).unwrap().sections();
            assert_eq!(sections.len(), expected.len());
            for ((b, a), row) in sections.iter().zip(&expected) {
                for i in 0..3 {
                    assert!(
                        close(b[i], row[i], 1e-12),
                        "order {order}: b = {b:?}, scipy {row:?}"
                    );
                    assert!(
                        close(a[i], row[3 + i], 1e-12),
                        "order {order}: a = {a:?}, scipy {row:?}"
                    );
                }
            }
        }
    }

    #[test]
    fn filtfilt_matches_scipy_sosfiltfilt() {
        // Reference: scipy 1.17.1, x = sin(0.1 k) + 0.5 cos(1.3 k), k = 0..59,
        // `sosfiltfilt(butter(4, 12.0, fs=250.0, output="sos"), x)` at k = 0, 17, 59.
        let x: Vec<f64> = (0..60)
            .map(|k| (0.1 * k as f64).sin() + 0.5 * (1.3 * k as f64).cos())
            .collect();
        let y = Butterworth::low_pass(4, 12.0, 250.0)
            .unwrap()
            .filtfilt(&x)
            .unwrap();
        for (k, expected) in [
            (0, 0.5072783684786611),
            (17, 0.9957843620531247),
            (59, -0.218559026164071),
        ] {
            assert!(
                close(y[k], expected, 1e-10),
                "y[{k}] = {}, scipy {expected}",
                y[k]
            );
        }
    }

    #[test]
    fn zero_phase_keeps_a_slow_sine_in_place_and_removes_a_fast_one() {
        let fs = 250.0;
        let filter = Butterworth::low_pass(4, 12.0, fs).unwrap();
        let slow: Vec<f64> = (0..1000)
            .map(|k| (2.0 * std::f64::consts::PI * 2.0 * k as f64 / fs).sin())
            .collect();
        let fast: Vec<f64> = (0..1000)
            .map(|k| (2.0 * std::f64::consts::PI * 60.0 * k as f64 / fs).sin())
            .collect();
        let mixed: Vec<f64> = slow.iter().zip(&fast).map(|(a, b)| a + b).collect();
        let y = filter.filtfilt(&mixed).unwrap();
        // A one-sample delay would move a 2 Hz sine by up to 0.05; no delay leaves it within 1e-3.
        let worst = (100..900)
            .map(|k| (y[k] - slow[k]).abs())
            .fold(0.0, f64::max);
        assert!(
            worst < 1e-3,
            "largest deviation from the unshifted 2 Hz sine: {worst}"
        );
        assert!(filter.filtfilt(&vec![1.0; filter.min_len() - 1]).is_none());
    }

    #[test]
    fn invalid_designs_are_rejected() {
        assert!(Butterworth::low_pass(4, 130.0, 250.0)
            .unwrap_err()
            .to_string()
            .contains("(0, 125) Hz"));
        assert!(Butterworth::low_pass(0, 10.0, 250.0).is_err());
    }
}
