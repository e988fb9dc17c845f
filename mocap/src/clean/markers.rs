//! The cleaning of one take's markers end to end (re-identification, rejection of spurious
//! reflections, gap filling, low-pass) and the cleaned tracks with their bookkeeping.

use super::geometry::{distance, median};
use super::{
    fill_gaps, reidentify, Butterworth, CleanError, CleaningConfig, MarkerRetention, Neighbourhood,
    Reidentified, SampleOrigin, Series,
};

/// The cleaned markers of one take and the bookkeeping behind the retention report.
#[derive(Debug, Clone)]
pub struct CleanedMarkers {
    /// One series per physical marker kept (after re-identification), in order of first appearance.
    pub tracks: Vec<Series>,
    /// Origin of every sample of every kept track.
    pub origin: Vec<Vec<SampleOrigin>>,
    /// Raw marker samples per frame (every non-empty marker cell).
    pub raw_per_frame: Vec<usize>,
    /// Samples per frame dropped as spurious (short-lived tracks or far from the package cluster).
    pub spurious_per_frame: Vec<usize>,
    /// Number of marker ids (columns) in the input.
    pub input_ids: usize,
    /// Ids that were attached to an earlier track by re-identification.
    pub reidentified_ids: usize,
    /// Distance (m) between each re-identified id's first position and the predicted position of
    /// the track it joined.
    pub reid_distances_m: Vec<f64>,
    /// Candidate joins (within the distance gate) refused because the new id lies on another
    /// sheet than the lost marker, or the sheet of either cannot be told.
    pub refused_across_sheets: usize,
    /// Tracks dropped as too short-lived.
    pub short_tracks_dropped: usize,
    /// Samples in runs too short to filter.
    pub unfiltered_samples: usize,
}

impl CleanedMarkers {
    /// Retention counts over the frames `start..end`.
    pub fn retention(&self, start: usize, end: usize) -> MarkerRetention {
        let mut r = MarkerRetention {
            raw_samples: self.raw_per_frame[start..end].iter().sum(),
            spurious_samples: self.spurious_per_frame[start..end].iter().sum(),
            ..Default::default()
        };
        for origin in &self.origin {
            let seen: Vec<usize> = (0..origin.len())
                .filter(|&k| origin[k] != SampleOrigin::Missing)
                .collect();
            let (Some(&first), Some(&last)) = (seen.first(), seen.last()) else {
                continue;
            };
            for (k, o) in origin.iter().enumerate().take(end).skip(start) {
                match o {
                    SampleOrigin::Observed => r.observed_kept += 1,
                    SampleOrigin::VelocityFilled => r.velocity_filled += 1,
                    SampleOrigin::Interpolated => r.interpolated += 1,
                    SampleOrigin::Missing if k > first && k < last => r.unrecovered += 1,
                    SampleOrigin::Missing => {}
                }
            }
        }
        r
    }

    /// The kept markers of frame `k` (in track order).
    pub fn frame(&self, k: usize) -> Vec<[f64; 3]> {
        self.tracks.iter().filter_map(|t| t[k]).collect()
    }

    /// The kept markers of frame `k` with the index of their track as the marker id (in track
    /// order): a physical marker keeps its id through the take.
    pub fn labelled_frame(&self, k: usize) -> Vec<(u32, [f64; 3])> {
        self.tracks
            .iter()
            .enumerate()
            .filter_map(|(id, t)| t[k].map(|p| (id as u32, p)))
            .collect()
    }
}

/// Links id fragments into physical-marker tracks (Hungarian re-identification), rejects spurious
/// reflections, fills gaps and low-pass filters. `fragments` are the input marker columns;
/// `sample_rate_hz` is the take's real frame rate.
pub fn clean_markers(
    fragments: &[Series],
    sample_rate_hz: f64,
    config: &CleaningConfig,
) -> Result<CleanedMarkers, CleanError> {
    let n_frames = fragments.first().map_or(0, Vec::len);
    let frames = |seconds: f64| (seconds * sample_rate_hz).round() as usize;
    let raw_per_frame: Vec<usize> = (0..n_frames)
        .map(|k| fragments.iter().filter(|f| f[k].is_some()).count())
        .collect();

    let Reidentified {
        tracks: linked,
        joined_distances_m: reid_distances_m,
        refused_across_sheets,
        ..
    } = reidentify(fragments, config, sample_rate_hz);

    // Spurious reflections: short-lived tracks, then samples far from the package cluster.
    let min_samples = frames(config.min_track_s);
    let mut spurious_per_frame = vec![0usize; n_frames];
    let mut tracks = Vec::new();
    let mut short_tracks_dropped = 0;
    for track in linked {
        if track.iter().flatten().count() < min_samples.max(1) {
            short_tracks_dropped += 1;
            for (k, p) in track.iter().enumerate() {
                spurious_per_frame[k] += usize::from(p.is_some());
            }
        } else {
            tracks.push(track);
        }
    }
    for k in 0..n_frames {
        let points: Vec<[f64; 3]> = tracks.iter().filter_map(|t| t[k]).collect();
        if points.is_empty() {
            continue;
        }
        let centre: [f64; 3] =
            std::array::from_fn(|axis| median(points.iter().map(|p| p[axis]).collect()));
        for track in tracks.iter_mut() {
            if track[k].is_some_and(|p| distance(p, centre) > config.max_cluster_distance_m) {
                track[k] = None;
                spurious_per_frame[k] += 1;
            }
        }
    }

    // Gap filling, then zero-phase low-pass over every contiguous run.
    let filter = (config.marker_cutoff_hz > 0.0)
        .then(|| {
            Butterworth::low_pass(config.filter_order, config.marker_cutoff_hz, sample_rate_hz)
        })
        .transpose()?;
    let mut origin = Vec::with_capacity(tracks.len());
    let mut unfiltered_samples = 0;
    let observed = tracks.clone();
    let neighbourhood = Neighbourhood {
        tracks: &observed,
        count: config.neighbours,
        radius_m: config.neighbourhood_m,
    };
    for (index, track) in tracks.iter_mut().enumerate() {
        let track_origin = fill_gaps(
            track,
            frames(config.max_velocity_fill_s),
            frames(config.max_interpolated_gap_s),
            config.velocity_window,
            Some((&neighbourhood, index)),
        );
        if let Some(filter) = &filter {
            unfiltered_samples += filter.filter_series(track);
        }
        origin.push(track_origin);
    }
    Ok(CleanedMarkers {
        tracks,
        origin,
        raw_per_frame,
        spurious_per_frame,
        input_ids: fragments.len(),
        reidentified_ids: reid_distances_m.len(),
        reid_distances_m,
        refused_across_sheets: refused_across_sheets.len(),
        short_tracks_dropped,
        unfiltered_samples,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::clean::test_support::moving;

    #[test]
    fn reappearing_marker_gets_its_old_track_back_and_spurious_ones_are_dropped() {
        let n = 200;
        let speed = 0.002; // 0.5 m/s at 250 Hz
        let a = moving(n, [0.0, 0.0, 0.0], speed, |_| true);
        let b = moving(n, [0.06, 0.0, 0.0], speed, |_| true);
        // Marker c is seen until frame 79, then reappears at frame 95 under a new id (column d).
        let c = moving(n, [0.0, 0.0, 0.06], speed, |k| k < 80);
        let d = moving(n, [0.0, 0.0, 0.06], speed, |k| k >= 95);
        // Marker e vanishes at the same time and reappears as f; f's column comes first, so the
        // match is only right if the assignment looks at positions.
        let e = moving(n, [0.06, 0.0, 0.06], speed, |k| k < 80);
        let f = moving(n, [0.06, 0.0, 0.06], speed, |k| k >= 95);
        // A reflection near the markers for 10 frames, and one 1 m away for 100 frames.
        let glint = moving(n, [0.03, 0.01, 0.03], 0.0, |k| (120..130).contains(&k));
        let far = moving(n, [1.0, 1.0, 1.0], 0.0, |k| (20..120).contains(&k));
        let fragments = vec![a, b, c.clone(), e.clone(), f.clone(), d.clone(), glint, far];
        let config = CleaningConfig {
            marker_cutoff_hz: 0.0,
            ..CleaningConfig::default()
        };
        let cleaned = clean_markers(&fragments, 250.0, &config).unwrap();
        assert_eq!(cleaned.reidentified_ids, 2);
        assert_eq!(cleaned.short_tracks_dropped, 1);
        // a, b, c+d, e+f (the far marker is rejected sample by sample, leaving an empty track).
        let non_empty: Vec<&Series> = cleaned
            .tracks
            .iter()
            .filter(|t| t.iter().any(Option::is_some))
            .collect();
        assert_eq!(non_empty.len(), 4);
        let ce = &cleaned.tracks[2];
        assert_eq!(ce[50], c[50]);
        assert_eq!(ce[150], d[150]);
        let ef = &cleaned.tracks[3];
        assert_eq!(ef[150], f[150]);
        // The 15-frame gap (longer than the 0.02 s velocity fill) was interpolated.
        assert_eq!(cleaned.origin[2][85], SampleOrigin::Interpolated);
        let r = cleaned.retention(0, n);
        assert_eq!(r.raw_samples, 200 * 2 + 80 * 2 + 105 * 2 + 10 + 100);
        assert_eq!(r.spurious_samples, 110);
        assert_eq!(r.observed_kept, 200 * 2 + 80 * 2 + 105 * 2);
        assert_eq!(r.interpolated, 30);
        assert_eq!(cleaned.frame(100).len(), 4);
    }
}
