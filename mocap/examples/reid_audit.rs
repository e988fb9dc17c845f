//! Audits re-identification on Motive takes of a two-sheet package (packages-v1): how many joins
//! link markers of different sheets, how many genuine joins the sheet test refuses, and how close
//! the cleaned markers stay to the recorded samples.
//!
//! ```sh
//! cargo run --release -p rlpkg-mocap --example reid_audit -- configs/import/motive.toml ../shared/data/packages-v1/*.csv.gz
//! ```
//!
//! The sheet of each marker id is worked out from information the importer does not use: the tool
//! rigid body's orientation. The package's markers are stacked, top over bottom: measured on
//! packages-v1, a marker's nearest neighbour is its partner on the other sheet 12-40 mm away
//! (the disc inside holds the sheets apart), or else a marker of the same sheet 58 mm or more away.
//! So two ids seen in one frame closer than [`PAIR_M`], mostly along the tool's up axis
//! ([`ALONG_MIN`]), are the two sheets' markers at one place, and the one farther along the up axis
//! is on the top sheet (the cups hold the top sheet). An id that never has such a partner is on the top sheet if it is seen
//! before the lift (the bottom sheet lies on the conveyor, unseen), and of unknown sheet
//! otherwise; joins and refusals that involve an unknown sheet are counted apart.
//!
//! With `REID_AUDIT_DETAILS=1` it also prints, per take, how the importer's sheets
//! ([`fragment_sheets`]) agree with these, and every join across sheets and every genuine join
//! refused.

use std::path::Path;

use glam::{DQuat, DVec3};
use rlpkg_mocap::clean::{self, fragment_sheets, reidentify, Series};
use rlpkg_mocap::import::ImportConfig;
use rlpkg_mocap::motive::{read_take, MarkerKind};

/// Two ids seen together closer than this, mostly along the tool's up axis, are the two sheets'
/// markers at one place (m).
const PAIR_M: f64 = 0.045;
/// ... and "mostly along the up axis" means at least this share of their distance (within 45
/// degrees of it): a partner lies straight below, while a reflection or a marker of the same sheet
/// seen 40 mm away across a slope lies off to the side.
const ALONG_MIN: f64 = 0.7;
/// packages-v1: the tool starts lifting the package at 0.3 s.
const LIFT_S: f64 = 0.3;
/// A cleaned sample farther than this from every recorded sample of its frame is not a recorded
/// marker (m).
const FAR_M: f64 = 0.002;

#[derive(Clone, Copy, PartialEq, Eq, Debug)]
enum Sheet {
    Top,
    Bottom,
    /// Paired both ways (conflicting evidence).
    Conflict,
    Unknown,
}

#[derive(Default)]
struct Counts {
    ids: usize,
    ids_paired: usize,
    ids_before_lift: usize,
    ids_conflict: usize,
    ids_unknown: usize,
    joins: usize,
    joins_same_sheet: usize,
    joins_across_sheets: usize,
    joins_unknown: usize,
    refusals: usize,
    refused_genuine: usize,
    refused_other_sheet: usize,
    refused_unknown: usize,
    observed_samples: usize,
    squared_error_m2: f64,
    far_samples: usize,
    raw_samples: usize,
    raw_unmatched: usize,
    spurious_dropped: usize,
}

impl Counts {
    fn add(&mut self, o: &Counts) {
        self.ids += o.ids;
        self.ids_paired += o.ids_paired;
        self.ids_before_lift += o.ids_before_lift;
        self.ids_conflict += o.ids_conflict;
        self.ids_unknown += o.ids_unknown;
        self.joins += o.joins;
        self.joins_same_sheet += o.joins_same_sheet;
        self.joins_across_sheets += o.joins_across_sheets;
        self.joins_unknown += o.joins_unknown;
        self.refusals += o.refusals;
        self.refused_genuine += o.refused_genuine;
        self.refused_other_sheet += o.refused_other_sheet;
        self.refused_unknown += o.refused_unknown;
        self.observed_samples += o.observed_samples;
        self.squared_error_m2 += o.squared_error_m2;
        self.far_samples += o.far_samples;
        self.raw_samples += o.raw_samples;
        self.raw_unmatched += o.raw_unmatched;
        self.spurious_dropped += o.spurious_dropped;
    }

    fn row(&self, name: &str) -> String {
        format!(
            "| {name} | {} ({} paired, {} before lift, {} conflicting, {} unknown) | {} | {} | {} | {} | {} | {} | {} | {} | {:.3} | {} | {} of {} ({} dropped as spurious) |",
            self.ids,
            self.ids_paired,
            self.ids_before_lift,
            self.ids_conflict,
            self.ids_unknown,
            self.joins,
            self.joins_same_sheet,
            self.joins_across_sheets,
            self.joins_unknown,
            self.refusals,
            self.refused_genuine,
            self.refused_other_sheet,
            self.refused_unknown,
            1e3 * (self.squared_error_m2 / self.observed_samples.max(1) as f64).sqrt(),
            self.far_samples,
            self.raw_unmatched,
            self.raw_samples,
            self.spurious_dropped,
        )
    }
}

fn distance(a: [f64; 3], b: [f64; 3]) -> f64 {
    (0..3).map(|i| (a[i] - b[i]).powi(2)).sum::<f64>().sqrt()
}

/// The sheet of every fragment, and whether a partner on the other sheet decided it (see the
/// module docs).
fn sheets(fragments: &[Series], up: &[Option<[f64; 3]>], lift_frame: usize) -> Vec<(Sheet, bool)> {
    let mut votes = vec![(0usize, 0usize); fragments.len()];
    for (k, up) in up.iter().enumerate() {
        let Some(up) = up else { continue };
        let seen: Vec<(usize, [f64; 3])> = fragments
            .iter()
            .enumerate()
            .filter_map(|(i, f)| f[k].map(|p| (i, p)))
            .collect();
        for (a, &(i, p)) in seen.iter().enumerate() {
            for &(j, q) in &seen[a + 1..] {
                let along: f64 = (0..3).map(|c| (p[c] - q[c]) * up[c]).sum();
                if distance(p, q) < PAIR_M && along.abs() >= ALONG_MIN * distance(p, q) {
                    let (upper, lower) = if along > 0.0 { (i, j) } else { (j, i) };
                    votes[upper].0 += 1;
                    votes[lower].1 += 1;
                }
            }
        }
    }
    fragments
        .iter()
        .zip(votes)
        .map(|(f, (top, bottom))| {
            if top + bottom == 0 {
                let before_lift = f[..lift_frame.min(f.len())].iter().any(Option::is_some);
                (
                    if before_lift {
                        Sheet::Top
                    } else {
                        Sheet::Unknown
                    },
                    false,
                )
            } else if top >= 9 * bottom {
                (Sheet::Top, true)
            } else if bottom >= 9 * top {
                (Sheet::Bottom, true)
            } else {
                (Sheet::Conflict, true)
            }
        })
        .collect()
}

fn audit(path: &Path, config: &ImportConfig) -> Counts {
    let take = read_take(path).unwrap_or_else(|e| panic!("{e}"));
    let rate = take.header.export_frame_rate_hz;
    let fragments: Vec<Series> = take
        .markers
        .iter()
        .filter(|m| m.kind == MarkerKind::Unlabeled)
        .map(|m| m.position.clone())
        .collect();
    let up: Vec<Option<[f64; 3]>> = take.rigid_bodies[0]
        .rotation
        .iter()
        .map(|q| q.map(|q| DQuat::from_array(q).mul_vec3(DVec3::Y).to_array()))
        .collect();
    let lift_frame = (LIFT_S * rate).round() as usize;
    let labelled = sheets(&fragments, &up, lift_frame);
    let sheet: Vec<Sheet> = labelled.iter().map(|l| l.0).collect();
    let mut c = Counts {
        ids: fragments.len(),
        ..Counts::default()
    };
    for &(s, paired) in &labelled {
        match s {
            Sheet::Conflict => c.ids_conflict += 1,
            Sheet::Unknown => c.ids_unknown += 1,
            _ if paired => c.ids_paired += 1,
            _ => c.ids_before_lift += 1,
        }
    }

    let cleaning = &config.cleaning;
    let result = reidentify(&fragments, cleaning, rate);
    let details = std::env::var_os("REID_AUDIT_DETAILS").is_some();
    let method = fragment_sheets(&fragments, cleaning);
    if details {
        // Agreement of the importer's sheets with the tool-based ones: [top, bottom] per side.
        let mut table = [[0usize; 2]; 3];
        for (m, g) in method.iter().zip(&sheet) {
            let row = match m {
                Some(clean::Sheet::Front) => 0,
                Some(clean::Sheet::Back) => 1,
                None => 2,
            };
            match g {
                Sheet::Top => table[row][0] += 1,
                Sheet::Bottom => table[row][1] += 1,
                _ => {}
            }
        }
        println!(
            "  {}: importer front/back/unknown x tool top/bottom: {table:?}",
            path.display()
        );
    }
    let start = |i: usize| fragments[i].iter().position(Option::is_some);
    // The fragment of `track` seen last before frame `k`.
    let last_before = |track: usize, k: usize| {
        (0..fragments.len())
            .filter(|&i| result.track_of[i] == Some(track))
            .filter(|&i| start(i).is_some_and(|s| s < k))
            .max_by_key(|&i| start(i))
    };
    let same = |a: Sheet, b: Sheet| match (a, b) {
        (Sheet::Top, Sheet::Top) | (Sheet::Bottom, Sheet::Bottom) => Some(true),
        (Sheet::Top, Sheet::Bottom) | (Sheet::Bottom, Sheet::Top) => Some(false),
        _ => None,
    };
    let starts_own_track = |i: usize| {
        result.track_of[i].is_some_and(|t| {
            (0..fragments.len())
                .filter(|&j| result.track_of[j] == Some(t))
                .min_by_key(|&j| start(j))
                == Some(i)
        })
    };
    for i in 0..fragments.len() {
        let (Some(track), Some(k)) = (result.track_of[i], start(i)) else {
            continue;
        };
        if starts_own_track(i) {
            continue;
        }
        c.joins += 1;
        let previous = last_before(track, k).expect("a joined id follows another");
        match same(sheet[i], sheet[previous]) {
            Some(true) => c.joins_same_sheet += 1,
            Some(false) => {
                c.joins_across_sheets += 1;
                if details {
                    println!(
                        "  across: frame {k} id {i} ({:?}, importer {:?}, {} frames) joins id {previous} ({:?}, importer {:?}) last seen {:?}",
                        sheet[i], method[i], fragments[i].iter().flatten().count(), sheet[previous], method[previous],
                        fragments[previous].iter().rposition(Option::is_some)
                    );
                }
            }
            None => c.joins_unknown += 1,
        }
    }
    for refusal in &result.refused_across_sheets {
        c.refusals += 1;
        let previous = last_before(refusal.track, refusal.frame).expect("a lost track was seen");
        match same(sheet[refusal.fragment], sheet[previous]) {
            // Genuine: the same sheet, and the new id went nowhere else.
            Some(true) if starts_own_track(refusal.fragment) => {
                c.refused_genuine += 1;
                if details {
                    println!(
                        "  refused: frame {} id {} ({:?}, importer {:?}) from track of id {previous} ({:?}, importer {:?}) last seen {:?}",
                        refusal.frame, refusal.fragment, sheet[refusal.fragment], method[refusal.fragment],
                        sheet[previous], method[previous], fragments[previous].iter().rposition(Option::is_some)
                    );
                }
            }
            Some(true) => {}
            Some(false) => c.refused_other_sheet += 1,
            None => c.refused_unknown += 1,
        }
    }

    // The whole cleaning, against the recorded samples.
    let cleaned =
        clean::clean_markers(&fragments, rate, cleaning).unwrap_or_else(|e| panic!("{e}"));
    c.spurious_dropped = cleaned.spurious_per_frame.iter().sum();
    for k in 0..take.len() {
        let raw: Vec<[f64; 3]> = fragments.iter().filter_map(|f| f[k]).collect();
        let out: Vec<[f64; 3]> = cleaned.frame(k);
        for (track, origin) in cleaned.tracks.iter().zip(&cleaned.origin) {
            if let (Some(p), clean::SampleOrigin::Observed) = (track[k], origin[k]) {
                let nearest = raw.iter().map(|&q| distance(p, q)).fold(f64::MAX, f64::min);
                c.observed_samples += 1;
                if nearest > FAR_M {
                    c.far_samples += 1;
                } else {
                    c.squared_error_m2 += nearest * nearest;
                }
            }
        }
        c.raw_samples += raw.len();
        c.raw_unmatched += raw
            .iter()
            .filter(|&&q| out.iter().all(|&p| distance(p, q) > FAR_M))
            .count();
    }
    c
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let Some((config, takes)) = args.split_first() else {
        eprintln!("usage: reid_audit CONFIG.toml TAKE.csv[.gz]...");
        std::process::exit(2);
    };
    let config = ImportConfig::load(Path::new(config)).unwrap_or_else(|e| panic!("{e}"));
    println!(
        "| take | ids (sheet from) | joins | same sheet | across sheets | unknown | sheet-test refusals | genuine refused | other sheet | unknown | observed RMS to raw (mm) | observed > {} mm from raw | raw without output within {} mm |",
        1e3 * FAR_M,
        1e3 * FAR_M
    );
    println!("|---|---|---|---|---|---|---|---|---|---|---|---|---|");
    let mut total = Counts::default();
    for take in takes {
        let path = Path::new(take);
        let counts = audit(path, &config);
        let name = rlpkg_mocap::import::take_id(path);
        println!("{}", counts.row(&name));
        total.add(&counts);
    }
    println!("{}", total.row(&format!("**all {}**", takes.len())));
}
