//! Gap filling: short gaps by a cubic with the velocities beside them, longer ones by linear
//! interpolation (carried with the neighbouring markers); and the origin of every sample.

use super::{runs, Neighbourhood, Series};

/// How a sample of a cleaned track came about.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SampleOrigin {
    /// Not available (never seen, or a gap too long to fill).
    Missing,
    /// Recorded (then filtered).
    Observed,
    /// Filled from the end velocities of a short gap.
    VelocityFilled,
    /// Linearly interpolated across a long gap.
    Interpolated,
}

/// Fills the interior gaps of `track`: up to `max_velocity_frames` missing samples by a cubic through
/// the two end points that has the velocities measured beside the gap (least-squares slopes over
/// `window` samples each side), up to `max_linear_frames` by linear interpolation; longer gaps stay
/// empty. With `neighbours` (the neighbourhood and this track's index in it), the linear
/// interpolation runs in the frame that moves with the neighbouring markers: both ends are carried
/// to each missing frame and blended linearly. Returns the origin of every sample.
pub fn fill_gaps(
    track: &mut Series,
    max_velocity_frames: usize,
    max_linear_frames: usize,
    window: usize,
    neighbours: Option<(&Neighbourhood, usize)>,
) -> Vec<SampleOrigin> {
    let mut origin: Vec<SampleOrigin> = track
        .iter()
        .map(|p| {
            if p.is_some() {
                SampleOrigin::Observed
            } else {
                SampleOrigin::Missing
            }
        })
        .collect();
    let spans = runs(track);
    for pair in spans.windows(2) {
        let (a_start, a_end) = pair[0];
        let (b_start, b_end) = pair[1];
        let (a, b) = (a_end - 1, b_start);
        let gap = b - a - 1;
        let (pa, pb) = (track[a].unwrap(), track[b].unwrap());
        if gap <= max_velocity_frames {
            // Velocities in metres per frame, from least-squares lines over the samples beside the
            // gap; such a slope is the derivative at the middle of its window, not at the gap's edge.
            let window_a = window.min(a_end - a_start);
            let window_b = window.min(b_end - b_start);
            let va = slope(&track[(a_end - window_a)..a_end]);
            let vb = slope(&track[b_start..(b_start + window_b)]);
            let span = (b - a) as f64;
            let curve = va.zip(vb).and_then(|(va, vb)| {
                let at_a = -(window_a as f64 - 1.0) / 2.0;
                let at_b = span + (window_b as f64 - 1.0) / 2.0;
                cubic_through(pa, pb, span, (at_a, va), (at_b, vb))
            });
            let Some(coefficients) = curve else {
                linear_fill(track, &mut origin, a, b);
                continue;
            };
            for f in a + 1..b {
                let s = (f - a) as f64;
                track[f] = Some(std::array::from_fn(|i| {
                    let [c1, c2, c3] = coefficients[i];
                    pa[i] + s * (c1 + s * (c2 + s * c3))
                }));
                origin[f] = SampleOrigin::VelocityFilled;
            }
        } else if gap <= max_linear_frames {
            let carried: Option<Vec<[f64; 3]>> = neighbours.and_then(|(hood, own)| {
                (a + 1..b)
                    .map(|f| {
                        let from_a = hood.transport(own, a, f, pa)?;
                        let from_b = hood.transport(own, b, f, pb)?;
                        let s = (f - a) as f64 / (b - a) as f64;
                        Some(std::array::from_fn(|i| {
                            from_a[i] + s * (from_b[i] - from_a[i])
                        }))
                    })
                    .collect()
            });
            match carried {
                Some(points) => {
                    for (f, p) in (a + 1..b).zip(points) {
                        track[f] = Some(p);
                        origin[f] = SampleOrigin::Interpolated;
                    }
                }
                None => linear_fill(track, &mut origin, a, b),
            }
        }
    }
    origin
}

/// Per axis, the cubic `pa + c1 s + c2 s^2 + c3 s^3` with value `pb` at `s = span` and the given
/// derivatives at the given `s`; `None` if the conditions are degenerate.
fn cubic_through(
    pa: [f64; 3],
    pb: [f64; 3],
    span: f64,
    (sa, va): (f64, [f64; 3]),
    (sb, vb): (f64, [f64; 3]),
) -> Option<[[f64; 3]; 3]> {
    let m = [
        [span, span * span, span * span * span],
        [1.0, 2.0 * sa, 3.0 * sa * sa],
        [1.0, 2.0 * sb, 3.0 * sb * sb],
    ];
    let det = |m: &[[f64; 3]; 3]| {
        m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1])
            - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0])
            + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0])
    };
    let d = det(&m);
    if d.abs() < 1e-9 * span.powi(4).max(1.0) {
        return None;
    }
    // Cramer's rule, one axis at a time.
    Some(std::array::from_fn(|axis| {
        let rhs = [pb[axis] - pa[axis], va[axis], vb[axis]];
        std::array::from_fn(|unknown| {
            let mut replaced = m;
            for row in 0..3 {
                replaced[row][unknown] = rhs[row];
            }
            det(&replaced) / d
        })
    }))
}

fn linear_fill(track: &mut Series, origin: &mut [SampleOrigin], a: usize, b: usize) {
    let (pa, pb) = (track[a].unwrap(), track[b].unwrap());
    for f in a + 1..b {
        let s = (f - a) as f64 / (b - a) as f64;
        track[f] = Some(std::array::from_fn(|i| pa[i] + s * (pb[i] - pa[i])));
        origin[f] = SampleOrigin::Interpolated;
    }
}

/// Least-squares slope (per frame) of consecutive samples; `None` for fewer than two.
fn slope(samples: &[Option<[f64; 3]>]) -> Option<[f64; 3]> {
    let n = samples.len();
    if n < 2 {
        return None;
    }
    let mean_k = (n - 1) as f64 / 2.0;
    let denominator: f64 = (0..n).map(|k| (k as f64 - mean_k).powi(2)).sum();
    let points: Vec<[f64; 3]> = samples.iter().map(|p| p.unwrap()).collect();
    Some(std::array::from_fn(|i| {
        let mean_p = points.iter().map(|p| p[i]).sum::<f64>() / n as f64;
        points
            .iter()
            .enumerate()
            .map(|(k, p)| (k as f64 - mean_k) * (p[i] - mean_p))
            .sum::<f64>()
            / denominator
    }))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::clean::geometry::distance;

    #[test]
    fn gaps_are_filled_by_velocity_linearly_or_left_empty() {
        // A marker on a circle (r = 0.1 m, 0.05 rad per frame): short gap -> cubic with the end
        // velocities, medium -> linear, long -> empty.
        let truth = |k: usize| {
            let a = 0.05 * k as f64;
            [0.1 * a.cos(), 0.1 * a.sin(), 0.5]
        };
        let seen =
            |k: usize| !(10..15).contains(&k) && !(40..60).contains(&k) && !(80..120).contains(&k);
        let mut track: Series = (0..150).map(|k| seen(k).then(|| truth(k))).collect();
        let origin = fill_gaps(&mut track, 5, 20, 4, None);
        let error = |p: [f64; 3], q: [f64; 3]| distance(p, q);
        for k in 10..15 {
            assert_eq!(origin[k], SampleOrigin::VelocityFilled);
            // The chord cuts the arc by ~1 mm here; the velocity fill follows the arc.
            let chord = linear_point(truth(9), truth(15), (k - 9) as f64 / 6.0);
            assert!(
                error(track[k].unwrap(), truth(k)) < 1e-4,
                "frame {k}: {:?}",
                track[k]
            );
            assert!(k != 12 || error(chord, truth(k)) > 5e-4);
        }
        for k in 40..60 {
            assert_eq!(origin[k], SampleOrigin::Interpolated);
            let expected = linear_point(truth(39), truth(60), (k - 39) as f64 / 21.0);
            assert!(error(track[k].unwrap(), expected) < 1e-12);
        }
        assert!((80..120).all(|k| track[k].is_none() && origin[k] == SampleOrigin::Missing));
        assert_eq!(
            origin
                .iter()
                .filter(|o| **o == SampleOrigin::Observed)
                .count(),
            150 - 5 - 20 - 40
        );
    }

    fn linear_point(a: [f64; 3], b: [f64; 3], s: f64) -> [f64; 3] {
        std::array::from_fn(|i| a[i] + s * (b[i] - a[i]))
    }

    #[test]
    fn long_gaps_follow_the_neighbours_rigid_motion() {
        // Five markers on a plate turning at 1 rad/s about a vertical axis 0.2 m away, 250 Hz; the
        // first is hidden for 0.4 s (a quarter of a radian of turn).
        let n = 300;
        let offsets = [
            [0.0, 0.0, 0.0],
            [0.06, 0.0, 0.0],
            [0.0, 0.0, 0.06],
            [-0.06, 0.0, 0.0],
            [0.0, 0.01, -0.06],
        ];
        let position = |k: usize, o: [f64; 3]| {
            let angle = k as f64 / 250.0;
            let (x, z) = (0.2 + o[0], o[2]);
            [
                x * angle.cos() - z * angle.sin(),
                o[1],
                x * angle.sin() + z * angle.cos(),
            ]
        };
        let tracks: Vec<Series> = offsets
            .iter()
            .enumerate()
            .map(|(i, &o)| {
                (0..n)
                    .map(|k| (i != 0 || !(100..200).contains(&k)).then(|| position(k, o)))
                    .collect()
            })
            .collect();
        let hood = Neighbourhood {
            tracks: &tracks,
            count: 4,
            radius_m: 0.12,
        };
        let mut carried = tracks[0].clone();
        let origin = fill_gaps(&mut carried, 0, 150, 4, Some((&hood, 0)));
        let mut straight = tracks[0].clone();
        fill_gaps(&mut straight, 0, 150, 4, None);
        assert!((100..200).all(|k| origin[k] == SampleOrigin::Interpolated));
        let truth = position(150, offsets[0]);
        assert!(
            distance(carried[150].unwrap(), truth) < 1e-9,
            "{:?} vs {truth:?}",
            carried[150]
        );
        // The chord of the arc misses the truth by millimetres.
        assert!(distance(straight[150].unwrap(), truth) > 1e-3);
    }
}
