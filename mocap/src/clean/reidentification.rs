//! Re-identification: the id fragments of a marker that reappears under a new id joined into one
//! track (Hungarian matching to recently lost tracks, never across the package's film sheets).

use nalgebra::Vector3;

use super::geometry::distance;
use super::sheets::{partner_side, sheet_at, sheet_evidence};
use super::{assign, CleaningConfig, Neighbourhood, Series, Sheet};

/// A candidate join that re-identification refused because the new id lies on another sheet than
/// the lost track, or the sheet of either cannot be told.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SheetRefusal {
    /// Frame where the new id first appears.
    pub frame: usize,
    /// The new id's fragment (index into the input).
    pub fragment: usize,
    /// The lost track it was not joined to (index into [`Reidentified::tracks`]).
    pub track: usize,
}

/// What re-identification made of the fragments.
#[derive(Debug, Clone, Default)]
pub struct Reidentified {
    /// One series per physical marker, in order of first appearance.
    pub tracks: Vec<Series>,
    /// The track each fragment went to (`None` for a fragment that is never seen).
    pub track_of: Vec<Option<usize>>,
    /// Per joined id, the distance (m) of its first position to the lost track's prediction.
    pub joined_distances_m: Vec<f64>,
    /// Candidate joins within the distance gate that the sheet test refused (other sheet, or a
    /// sheet that cannot be told).
    pub refused_across_sheets: Vec<SheetRefusal>,
}

/// Joins fragments (one per marker id) into tracks: when ids first appear at frame k they are
/// matched (Hungarian) to tracks lost at most `reid_max_lost_s` ago, with cost = distance to the
/// track's predicted position divided by the accepted distance (`reid_max_distance_m` plus
/// `reid_distance_growth_m_per_s` per second lost); pairs above 1 are not matched.
///
/// A new id is never joined to a lost marker of the other film sheet, nor to one whose sheet cannot
/// be told. Each id's sheet comes from [`fragment_sheets`] (over the id's whole life); a track's is
/// that of its first id whose sheet is known. Where that is unknown, the sheet is established at one
/// frame from the markers of known sheet around the point (see [`sheet_at`]): the new id's where it
/// first appears, the lost marker's where it was last seen. The two join only when both sheets are
/// known and the same, whatever the distance along the package's normal: without its sheet, a
/// marker may be the other sheet's partner 12 mm behind the lost one, within the distance gate.
/// When no id's sheet shows at all, the markers lie on one layer and join on distance alone.
///
/// [`fragment_sheets`]: super::fragment_sheets
pub fn reidentify(
    fragments: &[Series],
    config: &CleaningConfig,
    sample_rate_hz: f64,
) -> Reidentified {
    let evidence = sheet_evidence(fragments, config);
    let sheets = &evidence.sheets;
    // Markers on one layer (a single sheet, or none seen at another) never show a sheet.
    let one_layer = sheets.iter().all(Option::is_none);
    // The sheet of an unknown-sheet id at one frame, from the fragments of known sheet seen then.
    let sheet_then = |frame: usize, point: [f64; 3]| {
        let normal = evidence.normals[frame]?;
        let seen: Vec<(Option<Sheet>, Vector3<f64>)> = fragments
            .iter()
            .zip(sheets)
            .filter_map(|(f, &sheet)| f[frame].map(|p| (sheet, Vector3::from(p))))
            .collect();
        let points: Vec<Vector3<f64>> = seen.iter().map(|&(_, q)| q).collect();
        let p = Vector3::from(point);
        partner_side(&points, p, normal, config).or_else(|| sheet_at(&seen, p, normal, config))
    };
    let max_lost_frames = (config.reid_max_lost_s * sample_rate_hz).round() as usize;
    let n_frames = fragments.first().map_or(0, Vec::len);
    let mut starts: Vec<(usize, usize)> = fragments
        .iter()
        .enumerate()
        .filter_map(|(i, f)| f.iter().position(Option::is_some).map(|k| (k, i)))
        .collect();
    starts.sort();
    let mut tracks: Vec<Series> = Vec::new();
    // Last observed frame of each track, and its sheet (that of its first id whose sheet is known).
    let mut last_seen: Vec<usize> = Vec::new();
    let mut track_sheet: Vec<Option<Sheet>> = Vec::new();
    let mut joined = Vec::new();
    let mut track_of = vec![None; fragments.len()];
    let mut refused = Vec::new();
    let mut s = 0;
    while s < starts.len() {
        let k = starts[s].0;
        let mut e = s;
        while e < starts.len() && starts[e].0 == k {
            e += 1;
        }
        let newcomers: Vec<usize> = starts[s..e].iter().map(|&(_, i)| i).collect();
        s = e;
        let lost: Vec<usize> = (0..tracks.len())
            .filter(|&j| last_seen[j] < k && k - last_seen[j] - 1 <= max_lost_frames)
            .collect();
        let mut target: Vec<Option<(usize, f64)>> = vec![None; newcomers.len()];
        if !lost.is_empty() {
            let neighbourhood = Neighbourhood {
                tracks: &tracks,
                count: config.neighbours,
                radius_m: config.neighbourhood_m,
            };
            // Without neighbours, the best guess is where the marker was last seen.
            let predicted: Vec<[f64; 3]> = lost
                .iter()
                .map(|&j| {
                    let anchor = tracks[j][last_seen[j]].expect("track seen at its last frame");
                    neighbourhood
                        .transport(j, last_seen[j], k, anchor)
                        .unwrap_or(anchor)
                })
                .collect();
            let lost_sheets: Vec<Option<Sheet>> = lost
                .iter()
                .map(|&j| {
                    track_sheet[j].or_else(|| {
                        let anchor = tracks[j][last_seen[j]].expect("track seen at its last frame");
                        sheet_then(last_seen[j], anchor)
                    })
                })
                .collect();
            let accepted: Vec<f64> = lost
                .iter()
                .map(|&j| {
                    let lost_s = (k - last_seen[j]) as f64 / sample_rate_hz;
                    config.reid_max_distance_m + config.reid_distance_growth_m_per_s * lost_s
                })
                .collect();
            let mut cost = Vec::with_capacity(newcomers.len() * lost.len());
            for &i in &newcomers {
                let first = fragments[i][k].expect("fragment starts at k");
                let sheet = sheets[i].or_else(|| sheet_then(k, first));
                for (c, (&p, limit)) in predicted.iter().zip(&accepted).enumerate() {
                    let same_sheet = one_layer || (sheet.is_some() && sheet == lost_sheets[c]);
                    let scaled = distance(first, p) / limit;
                    if !same_sheet {
                        if scaled <= 1.0 {
                            refused.push(SheetRefusal {
                                frame: k,
                                fragment: i,
                                track: lost[c],
                            });
                        }
                        cost.push(f64::INFINITY);
                    } else {
                        cost.push(scaled);
                    }
                }
            }
            for (r, c) in assign(&cost, newcomers.len(), lost.len(), 1.0) {
                target[r] = Some((lost[c], cost[r * lost.len() + c] * accepted[c]));
            }
        }
        for (r, &i) in newcomers.iter().enumerate() {
            let fragment = &fragments[i];
            let last = fragment
                .iter()
                .rposition(Option::is_some)
                .expect("non-empty fragment");
            match target[r] {
                Some((j, distance)) => {
                    joined.push(distance);
                    track_of[i] = Some(j);
                    track_sheet[j] = track_sheet[j].or(sheets[i]);
                    for f in k..=last {
                        if fragment[f].is_some() {
                            tracks[j][f] = fragment[f];
                        }
                    }
                    last_seen[j] = last;
                }
                None => {
                    let mut track = vec![None; n_frames];
                    track[k..=last].copy_from_slice(&fragment[k..=last]);
                    track_of[i] = Some(tracks.len());
                    tracks.push(track);
                    last_seen.push(last);
                    track_sheet.push(sheets[i]);
                }
            }
        }
    }
    Reidentified {
        tracks,
        track_of,
        joined_distances_m: joined,
        refused_across_sheets: refused,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::clean::fragment_sheets;
    use crate::clean::test_support::moving;

    #[test]
    fn reidentification_never_joins_markers_across_sheets() {
        // Two sheets 12 mm apart (y = 0.012 and y = 0), 3 x 2 markers each, moving along x at
        // 0.5 m/s (250 Hz). Top marker U is lost at frame 80 and reappears under a new id at frame
        // 147; the bottom sheet first shows at frame 95, marker L right under U. L is 12 mm from
        // U's predicted position, within the 20 mm gate, so only the sheet test keeps them apart.
        let n = 250;
        let speed = 0.002;
        let grid = [
            (-0.06, -0.035),
            (0.0, -0.035),
            (0.06, -0.035),
            (-0.06, 0.035),
            (0.06, 0.035),
        ];
        let mut fragments: Vec<Series> = Vec::new();
        for &(x, z) in &grid {
            fragments.push(moving(n, [x, 0.012, z], speed, |_| true));
        }
        let u_before = moving(n, [0.0, 0.012, 0.035], speed, |k| k < 80);
        let u_after = moving(n, [0.0, 0.012, 0.035], speed, |k| k >= 147);
        let l = moving(n, [0.0, 0.0, 0.035], speed, |k| k >= 95);
        fragments.push(u_before.clone());
        for &(x, z) in &grid {
            fragments.push(moving(n, [x, 0.0, z], speed, |k| k >= 95));
        }
        fragments.push(l.clone());
        fragments.push(u_after.clone());
        let config = CleaningConfig::default();
        let Reidentified {
            tracks,
            joined_distances_m: joined,
            ..
        } = reidentify(&fragments, &config, 250.0);
        // Every track stays on one sheet.
        for track in &tracks {
            let heights: Vec<f64> = track.iter().flatten().map(|p| p[1]).collect();
            assert!(
                heights.iter().all(|y| (y - heights[0]).abs() < 1e-9),
                "a track mixes sheets: heights {:?}",
                heights
            );
        }
        assert_eq!(joined.len(), 1, "only U's two ids are one marker");
        let u = tracks
            .iter()
            .find(|t| t[0] == u_before[0])
            .expect("U's track");
        assert_eq!(u[150], u_after[150]);
        assert!(u[100].is_none());
        assert!(tracks.iter().any(|t| t[100] == l[100] && t[0].is_none()));
        // The same data without the sheet test (a gate wider than the sheets' gap) joins L to U.
        let no_sheets = CleaningConfig {
            reid_max_sheet_offset_m: 1.0,
            ..config
        };
        let tracks = reidentify(&fragments, &no_sheets, 250.0).tracks;
        let u = tracks.iter().find(|t| t[0] == u_before[0]).unwrap();
        assert_eq!(
            u[100], l[100],
            "without the sheet test L continues U's track"
        );
    }

    #[test]
    fn a_lost_marker_whose_sheet_cannot_be_told_takes_no_new_id() {
        // Two sheets 12 mm apart (top y = 0.012, bottom y = 0), 3 x 2 places 60 mm apart, rising
        // at 0.05 m/s (250 Hz); both markers of five places are seen throughout. At the sixth, top
        // marker U is seen for two frames only (too few for its sheet to show over its life);
        // the bottom marker L under it first shows at frame 40, and U comes back under a new id
        // at frame 60. L is within the distance gate of U's prediction; U2 is U.
        let n = 120;
        let rise = 0.0002;
        let at = |x: f64, y: f64, z: f64, seen: &dyn Fn(usize) -> bool| -> Series {
            (0..n)
                .map(|k| seen(k).then_some([x, y + rise * k as f64, z]))
                .collect()
        };
        let mut fragments: Vec<Series> = Vec::new();
        for (x, z) in [
            (-0.06, -0.035),
            (0.0, -0.035),
            (0.06, -0.035),
            (-0.06, 0.035),
            (0.06, 0.035),
        ] {
            fragments.push(at(x, 0.012, z, &|_| true));
            fragments.push(at(x, 0.0, z, &|_| true));
        }
        let (u, l, u2) = (fragments.len(), fragments.len() + 1, fragments.len() + 2);
        fragments.push(at(0.0, 0.012, 0.035, &|k| k < 2));
        fragments.push(at(0.0, 0.0, 0.035, &|k| k >= 40));
        fragments.push(at(0.0, 0.012, 0.035, &|k| k >= 60));
        let config = CleaningConfig::default();

        // Level with the top markers around it when last seen, U is on the top sheet: L (below
        // its partner U2) is refused, U2 joins.
        let result = reidentify(&fragments, &config, 250.0);
        assert_eq!(result.track_of[u2], result.track_of[u]);
        assert_ne!(result.track_of[l], result.track_of[u]);
        assert!(result
            .refused_across_sheets
            .iter()
            .any(|r| r.fragment == l && Some(r.track) == result.track_of[u]));

        // With a neighbourhood smaller than the places' spacing, nothing around U tells its sheet
        // and its prediction is where it was last seen: L, 4 mm below that as the package rose,
        // is not joined to it (nor is U2: the sheet of the lost marker cannot be told).
        let near = CleaningConfig {
            neighbourhood_m: 0.05,
            ..config
        };
        let result = reidentify(&fragments, &near, 250.0);
        assert_ne!(result.track_of[l], result.track_of[u]);
        assert_ne!(result.track_of[u2], result.track_of[u]);
        for track in &result.tracks {
            let first = track.iter().position(Option::is_some).unwrap();
            let height = |k: usize| track[k].map(|p| p[1] - rise * k as f64);
            assert!(
                (first..n)
                    .all(|k| height(k).is_none_or(|y| (y - height(first).unwrap()).abs() < 1e-9)),
                "a track mixes sheets"
            );
        }
    }

    #[test]
    fn a_marker_back_on_its_own_sheet_is_joined_however_far_off_the_fitted_plane() {
        // Two sheets 12 mm apart, 3 x 2 stacked markers each (top over bottom), moving along x at
        // 0.5 m/s (250 Hz), all seen throughout but top marker U: lost at frame 80, back at frame
        // 90 under a new id, 8 mm higher (the sheet bulged there). 8 mm off the plane fitted
        // around the prediction is beyond the 6 mm that plane allows, but U is seen above its
        // bottom partner both before and after: one marker of the top sheet.
        let n = 200;
        let speed = 0.002;
        let places = [
            (-0.06, -0.035),
            (0.0, -0.035),
            (0.06, -0.035),
            (-0.06, 0.035),
            (0.0, 0.035),
            (0.06, 0.035),
        ];
        let mut fragments: Vec<Series> = Vec::new();
        for &(x, z) in &places {
            fragments.push(moving(n, [x, 0.0, z], speed, |_| true));
            if (x, z) != (0.0, 0.035) {
                fragments.push(moving(n, [x, 0.012, z], speed, |_| true));
            }
        }
        let u_before = moving(n, [0.0, 0.012, 0.035], speed, |k| k < 80);
        let u_after = moving(n, [0.0, 0.020, 0.035], speed, |k| k >= 90);
        fragments.push(u_before.clone());
        fragments.push(u_after.clone());
        let config = CleaningConfig::default();
        let sheets = fragment_sheets(&fragments, &config);
        let (before, after) = (fragments.len() - 2, fragments.len() - 1);
        assert_eq!(sheets[before], Some(Sheet::Front), "{sheets:?}");
        assert_eq!(sheets[after], Some(Sheet::Front));
        assert_eq!(sheets[0], Some(Sheet::Back), "a bottom marker");
        let result = reidentify(&fragments, &config, 250.0);
        assert_eq!(
            result.joined_distances_m.len(),
            1,
            "U's two ids are one marker"
        );
        assert_eq!(result.track_of[after], result.track_of[before]);
        let u = &result.tracks[result.track_of[before].unwrap()];
        assert_eq!((u[50], u[150]), (u_before[50], u_after[150]));
        assert!(result.refused_across_sheets.is_empty());
    }
}
