//! Which of the package's two film sheets a marker is on: the package's normal in every frame,
//! partners seen across the sheets, and markers level with those of a known sheet.

use nalgebra::{Matrix3, Vector3};

use super::geometry::median;
use super::{CleaningConfig, Series};

/// Markers used to fit the local sheet plane: the nearest ones, so the plane stays local on a
/// package that sags.
const SHEET_PLANE_MARKERS: usize = 8;

/// The (up to [`SHEET_PLANE_MARKERS`]) points nearest to `centre` within `radius_m`.
fn nearest(points: &[Vector3<f64>], centre: &Vector3<f64>, radius_m: f64) -> Vec<Vector3<f64>> {
    let mut near: Vec<(f64, Vector3<f64>)> = points
        .iter()
        .map(|p| ((p - centre).norm(), *p))
        .filter(|&(d, _)| d <= radius_m)
        .collect();
    near.sort_by(|a, b| a.0.total_cmp(&b.0));
    near.truncate(SHEET_PLANE_MARKERS);
    near.into_iter().map(|(_, p)| p).collect()
}

/// Unit normal of the plane through `points` (their direction of least spread); `None` for fewer
/// than three or for points that do not span a plane (spread along the second direction below 1.2
/// times that along the normal, or below 1 mm).
fn plane_normal(points: &[Vector3<f64>]) -> Option<Vector3<f64>> {
    if points.len() < 3 {
        return None;
    }
    let mean = points.iter().sum::<Vector3<f64>>() / points.len() as f64;
    let covariance: Matrix3<f64> = points
        .iter()
        .map(|p| (p - mean) * (p - mean).transpose())
        .sum::<Matrix3<f64>>()
        / points.len() as f64;
    let eigen = covariance.symmetric_eigen();
    let mut order = [0, 1, 2];
    order.sort_by(|&a, &b| eigen.eigenvalues[a].total_cmp(&eigen.eigenvalues[b]));
    let (least, middle) = (eigen.eigenvalues[order[0]], eigen.eigenvalues[order[1]]);
    // Variances: a spread ratio of 1.2 is a ratio of 1.44. A lifted package sags, so the markers
    // around a point are far from flat (measured on packages-v1: 15-30 mm RMS off the best plane
    // over 12 cm); the least-spread direction is still the local normal.
    (middle >= 1.44 * least.max(0.0) && middle >= 1e-6)
        .then(|| eigen.eigenvectors.column(order[0]).normalize())
}

/// Which of the package's two film sheets a marker is on, relative to the package's normal as
/// [`fragment_sheets`] orients it over a take.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Sheet {
    /// The sheet on the side the normal points to.
    Front,
    /// The other sheet.
    Back,
}

/// Frames of evidence an id needs before its sheet counts as known, and the share of them that
/// must agree (the rest is noise or a stray reflection beside it).
const SHEET_MIN_VOTES: u32 = 3;
const SHEET_AGREEMENT: f64 = 0.9;
/// Markers whose sheet is known that place an id without a partner on the other sheet: the
/// nearest ones, so the sheets' curvature adds little to their offsets.
const SHEET_NEIGHBOURS: usize = 4;

/// The side that at least [`SHEET_AGREEMENT`] of at least [`SHEET_MIN_VOTES`] votes
/// (`[front, back]`) agree on.
fn decided(votes: [u32; 2]) -> Option<Sheet> {
    let total = votes[0] + votes[1];
    if total < SHEET_MIN_VOTES {
        None
    } else if votes[0] as f64 >= SHEET_AGREEMENT * total as f64 {
        Some(Sheet::Front)
    } else if votes[1] as f64 >= SHEET_AGREEMENT * total as f64 {
        Some(Sheet::Back)
    } else {
        None
    }
}

/// The sheet of every fragment, where the data show it. In every frame the package's normal is
/// the least-spread direction of the markers seen within `max_cluster_distance_m` of their median,
/// turned to agree with the previous frame's (so "front" means one sheet for the whole take). Two
/// kinds of evidence, per frame:
/// - a marker whose nearest neighbour within `neighbourhood_m` lies off it along the package's
///   normal by more than `reid_max_sheet_offset_m` and by at least half their distance is on the
///   other sheet than that neighbour, in front of it or behind;
/// - an id never seen beside such a partner is placed by the markers whose sheet the first kind
///   decided, as [`sheet_at`] does.
///
/// An id gets the side that at least 90 % of at least three frames agree on, the first kind of
/// evidence before the second; `None` when neither decides.
pub fn fragment_sheets(fragments: &[Series], config: &CleaningConfig) -> Vec<Option<Sheet>> {
    sheet_evidence(fragments, config).sheets
}

/// What [`fragment_sheets`] found: the sheet of every fragment and the package's normal in every
/// frame (`None` where the markers do not span a plane).
pub(super) struct SheetEvidence {
    pub(super) sheets: Vec<Option<Sheet>>,
    pub(super) normals: Vec<Option<Vector3<f64>>>,
}

pub(super) fn sheet_evidence(fragments: &[Series], config: &CleaningConfig) -> SheetEvidence {
    let n_frames = fragments.first().map_or(0, Vec::len);
    let seen_at = |k: usize| -> Vec<(usize, Vector3<f64>)> {
        fragments
            .iter()
            .enumerate()
            .filter_map(|(i, f)| f[k].map(|p| (i, Vector3::from(p))))
            .collect()
    };
    let mut normals: Vec<Option<Vector3<f64>>> = vec![None; n_frames];
    let mut partner_votes = vec![[0u32; 2]; fragments.len()];
    let mut reference: Option<Vector3<f64>> = None;
    for (k, frame_normal) in normals.iter_mut().enumerate() {
        let seen = seen_at(k);
        let points: Vec<Vector3<f64>> = seen.iter().map(|&(_, p)| p).collect();
        // The package's markers, without reflections far from them (as in `clean_markers`).
        let centre: Vector3<f64> =
            Vector3::from_fn(|axis, _| median(points.iter().map(|p| p[axis]).collect()));
        let package: Vec<Vector3<f64>> = points
            .iter()
            .filter(|p| (*p - centre).norm() <= config.max_cluster_distance_m)
            .copied()
            .collect();
        let Some(mut normal) = plane_normal(&package) else {
            continue;
        };
        // Continuity over the take; the first normal points up (Motive's +y).
        if normal.dot(&reference.unwrap_or(Vector3::y())) < 0.0 {
            normal = -normal;
        }
        reference = Some(normal);
        *frame_normal = Some(normal);
        for &(i, p) in &seen {
            if let Some(sheet) = partner_side(&points, p, normal, config) {
                partner_votes[i][usize::from(sheet == Sheet::Back)] += 1;
            }
        }
    }
    let by_partner: Vec<Option<Sheet>> = partner_votes.iter().map(|&v| decided(v)).collect();

    let mut level_votes = vec![[0u32; 2]; fragments.len()];
    for (k, normal) in normals.iter().enumerate() {
        let Some(normal) = *normal else { continue };
        let seen: Vec<(Option<Sheet>, Vector3<f64>)> = seen_at(k)
            .into_iter()
            .map(|(j, q)| (by_partner[j], q))
            .collect();
        for (i, p) in seen_at(k) {
            if partner_votes[i] != [0, 0] {
                continue;
            }
            if let Some(sheet) = sheet_at(&seen, p, normal, config) {
                level_votes[i][usize::from(sheet == Sheet::Back)] += 1;
            }
        }
    }
    let sheets = by_partner
        .into_iter()
        .zip(level_votes)
        .map(|(sheet, votes)| sheet.or_else(|| decided(votes)))
        .collect();
    SheetEvidence { sheets, normals }
}

/// The sheet of the marker at `p` in one frame when its nearest neighbour among `points` (which
/// hold `p` itself) is its partner on the other sheet: within `neighbourhood_m`, off it along the
/// package's `normal` by more than `reid_max_sheet_offset_m` and by at least half their distance.
/// The side it lies on is its sheet.
pub(super) fn partner_side(
    points: &[Vector3<f64>],
    p: Vector3<f64>,
    normal: Vector3<f64>,
    config: &CleaningConfig,
) -> Option<Sheet> {
    let q = points
        .iter()
        .filter(|&&q| q != p)
        .min_by(|a, b| (*a - p).norm().total_cmp(&(*b - p).norm()))?;
    let gap = (p - q).norm();
    let along = (p - q).dot(&normal);
    (gap <= config.neighbourhood_m
        && along.abs() > config.reid_max_sheet_offset_m
        && along.abs() >= 0.5 * gap)
        .then_some(if along < 0.0 {
            Sheet::Back
        } else {
            Sheet::Front
        })
}

/// The sheet of the marker at `p` in one frame, from the markers seen with it (`seen`, with their
/// sheets where known; `p`'s own entry, of unknown sheet, counts only for the plane): among the
/// (up to [`SHEET_NEIGHBOURS`]) nearest markers of known sheet within `neighbourhood_m`, it lies
/// level (within `reid_max_sheet_offset_m`, median, along the local normal: the plane of the
/// markers around `p`, turned to agree with the package's `normal`) with those of one sheet and
/// off those of the other on that sheet's side, or level with those of the only sheet seen.
/// `None` when they do not tell.
pub(super) fn sheet_at(
    seen: &[(Option<Sheet>, Vector3<f64>)],
    p: Vector3<f64>,
    normal: Vector3<f64>,
    config: &CleaningConfig,
) -> Option<Sheet> {
    let offset = config.reid_max_sheet_offset_m;
    let mut known: Vec<(f64, Sheet, Vector3<f64>)> = seen
        .iter()
        .filter_map(|&(sheet, q)| sheet.map(|sheet| ((q - p).norm(), sheet, q)))
        .filter(|&(d, _, _)| d <= config.neighbourhood_m)
        .collect();
    known.sort_by(|a, b| a.0.total_cmp(&b.0));
    known.truncate(SHEET_NEIGHBOURS);
    let points: Vec<Vector3<f64>> = seen.iter().map(|&(_, q)| q).collect();
    let local = plane_normal(&nearest(&points, &p, config.neighbourhood_m)).map_or(normal, |n| {
        if n.dot(&normal) < 0.0 {
            -n
        } else {
            n
        }
    });
    // How far in front of each sheet's known markers this one lies (median).
    let side = |sheet: Sheet| {
        let along: Vec<f64> = known
            .iter()
            .filter(|k| k.1 == sheet)
            .map(|k| (p - k.2).dot(&local))
            .collect();
        (!along.is_empty()).then(|| median(along))
    };
    match (side(Sheet::Front), side(Sheet::Back)) {
        (Some(f), Some(b)) if f.abs() <= offset && b > offset => Some(Sheet::Front),
        (Some(f), Some(b)) if b.abs() <= offset && f < -offset => Some(Sheet::Back),
        (Some(f), None) if f.abs() <= offset => Some(Sheet::Front),
        (None, Some(b)) if b.abs() <= offset => Some(Sheet::Back),
        _ => None,
    }
}
