//! Retention counts: how many marker samples of a frame range were kept, dropped as spurious,
//! filled or left missing.

use serde::Serialize;

/// Counts over a frame range, for the retention report.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize)]
pub struct MarkerRetention {
    /// Raw marker samples in the range.
    pub raw_samples: usize,
    /// Samples dropped as spurious reflections.
    pub spurious_samples: usize,
    /// Recorded samples kept.
    pub observed_kept: usize,
    /// Samples added by velocity-based filling.
    pub velocity_filled: usize,
    /// Samples added by linear interpolation.
    pub interpolated: usize,
    /// Samples missing inside a kept track's lifetime (gaps too long to fill).
    pub unrecovered: usize,
}

impl MarkerRetention {
    /// Recorded samples kept, as a percentage of the raw samples.
    pub fn kept_percent(&self) -> f64 {
        percent(self.observed_kept, self.raw_samples)
    }

    /// Samples in the output (kept + filled + interpolated), as a percentage of the raw samples.
    pub fn output_percent(&self) -> f64 {
        percent(
            self.observed_kept + self.velocity_filled + self.interpolated,
            self.raw_samples,
        )
    }
}

/// `part / whole` in percent (100 for an empty whole).
pub fn percent(part: usize, whole: usize) -> f64 {
    if whole == 0 {
        100.0
    } else {
        100.0 * part as f64 / whole as f64
    }
}
