//! Parser for OptiTrack Motive CSV exports (format version 1.2x).
//!
//! Layout: line 1 holds `key,value` pairs (format version, take name, frame rates, rotation type,
//! length units, ...), line 2 is empty, lines 3-7 are the `Type`, `Name`, `ID`, property
//! (`Rotation` / `Position` / ...) and axis (`X Y Z W`) rows, and every following line is one frame:
//! frame index, time in seconds, then one value per column. An empty cell means "not seen".
//! Gzip-compressed exports (`.csv.gz`) are recognised by their magic bytes.

use std::collections::HashMap;
use std::io::Read;
use std::path::{Path, PathBuf};

use thiserror::Error;

/// Largest coordinate (m) a take may hold: far beyond any capture volume, far below a corrupted value.
const MAX_COORDINATE_M: f64 = 1000.0;

/// An error while reading a Motive export; the message names the file, line (and column) and what
/// was expected.
#[derive(Debug, Error)]
pub enum MotiveError {
    /// The file could not be read (or decompressed).
    #[error("{path}: cannot read file: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The underlying error.
        source: std::io::Error,
    },
    /// The take is larger than an import handles (checked before allocating for it).
    #[error("{}: {message}", path.display())]
    TooLarge {
        /// The file.
        path: PathBuf,
        /// How large it is, the limit, and what to do.
        message: String,
    },
    /// The file does not follow the Motive CSV layout.
    #[error("{}: line {line}{}: {message}", path.display(), column.map(|c| format!(", column {c}")).unwrap_or_default())]
    Format {
        /// The file.
        path: PathBuf,
        /// 1-based line number.
        line: usize,
        /// 1-based column (cell) number, when one cell is at fault.
        column: Option<usize>,
        /// What was found and what was expected.
        message: String,
    },
}

/// Length unit of the positions in the export.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum LengthUnit {
    /// Millimetres.
    Millimeters,
    /// Centimetres.
    Centimeters,
    /// Metres.
    Meters,
}

impl LengthUnit {
    /// The factor that converts a value in this unit to metres.
    pub fn to_meters(self) -> f64 {
        match self {
            LengthUnit::Millimeters => 1e-3,
            LengthUnit::Centimeters => 1e-2,
            LengthUnit::Meters => 1.0,
        }
    }
}

/// The header block of a take (line 1).
#[derive(Debug, Clone)]
pub struct TakeHeader {
    /// `Format Version`, e.g. "1.23".
    pub format_version: String,
    /// `Take Name`.
    pub take_name: String,
    /// `Capture Frame Rate` in Hz.
    pub capture_frame_rate_hz: f64,
    /// `Export Frame Rate` in Hz: the sampling rate of the data rows.
    pub export_frame_rate_hz: f64,
    /// `Length Units` of the file (positions are converted to metres on load).
    pub length_unit: LengthUnit,
    /// `Total Exported Frames`, when present.
    pub total_exported_frames: Option<usize>,
}

/// A rigid body: its pose per frame (`None` where it was not tracked).
#[derive(Debug, Clone)]
pub struct RigidBodyTrack {
    /// Name from the `Name` row.
    pub name: String,
    /// ID from the `ID` row.
    pub id: String,
    /// Orientation quaternion (x, y, z, w) per frame.
    pub rotation: Vec<Option<[f64; 4]>>,
    /// Pivot position in metres per frame.
    pub position: Vec<Option<[f64; 3]>>,
}

/// What kind of marker a column holds.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MarkerKind {
    /// A labelled marker (`Marker` type with a name other than `Unlabeled ...`).
    Labeled,
    /// An unlabelled marker (`Unlabeled <id>`): a new id after every dropout.
    Unlabeled,
    /// A marker of a rigid body's marker set (`Rigid Body Marker`).
    RigidBodyMarker,
}

/// One marker column triple: position in metres per frame.
#[derive(Debug, Clone)]
pub struct MarkerTrack {
    /// Name from the `Name` row (e.g. `Unlabeled 1003`).
    pub name: String,
    /// ID from the `ID` row.
    pub id: String,
    /// Labelled, unlabelled or rigid-body marker.
    pub kind: MarkerKind,
    /// Position per frame (`None` = not seen).
    pub position: Vec<Option<[f64; 3]>>,
}

/// A parsed take: header, time base, rigid bodies and markers, positions in metres.
#[derive(Debug, Clone)]
pub struct MotiveTake {
    /// The file it was read from.
    pub path: PathBuf,
    /// Header block.
    pub header: TakeHeader,
    /// Time of each frame in seconds (from the `Time (Seconds)` column).
    pub time: Vec<f64>,
    /// Rigid bodies in column order.
    pub rigid_bodies: Vec<RigidBodyTrack>,
    /// Markers in column order.
    pub markers: Vec<MarkerTrack>,
}

impl MotiveTake {
    /// Number of frames.
    pub fn len(&self) -> usize {
        self.time.len()
    }

    /// True if the take has no frames.
    pub fn is_empty(&self) -> bool {
        self.time.is_empty()
    }
}

/// Largest take text (decompressed) an import reads: 4 GiB.
pub const MAX_TAKE_TEXT_BYTES: u64 = 4 << 30;
/// Largest memory the parsed tracks of a take may need: 4 GiB (cleaning needs a few times this).
pub const MAX_TRACK_BYTES: u64 = 4 << 30;

fn gib(bytes: u64) -> f64 {
    bytes as f64 / (1u64 << 30) as f64
}

/// Reads a Motive CSV export (plain or gzip-compressed), refusing files whose text exceeds
/// [`MAX_TAKE_TEXT_BYTES`] before reading them whole.
pub fn read_take(path: &Path) -> Result<MotiveTake, MotiveError> {
    let io_err = |source| MotiveError::Io {
        path: path.to_path_buf(),
        source,
    };
    let too_large = |what: &str| {
        MotiveError::TooLarge {
        path: path.to_path_buf(),
        message: format!(
            "{what} more than the {:.0} GiB an import reads; expected a shorter export (fewer frames or markers)",
            gib(MAX_TAKE_TEXT_BYTES)
        ),
    }
    };
    let size = std::fs::metadata(path).map_err(io_err)?.len();
    if size > MAX_TAKE_TEXT_BYTES {
        return Err(too_large(&format!("the file has {:.1} GiB,", gib(size))));
    }
    let bytes = std::fs::read(path).map_err(io_err)?;
    let text = if bytes.starts_with(&[0x1f, 0x8b]) {
        let mut out = String::new();
        flate2::read::MultiGzDecoder::new(bytes.as_slice())
            .take(MAX_TAKE_TEXT_BYTES + 1)
            .read_to_string(&mut out)
            .map_err(io_err)?;
        if out.len() as u64 > MAX_TAKE_TEXT_BYTES {
            return Err(too_large("the file decompresses to"));
        }
        out
    } else {
        String::from_utf8(bytes).map_err(|e| {
            io_err(std::io::Error::new(
                std::io::ErrorKind::InvalidData,
                format!("not UTF-8 text: {e}"),
            ))
        })?
    };
    parse_take(&text, path)
}

/// What a data column holds.
#[derive(Clone, Copy)]
enum Slot {
    Ignored,
    RigidRotation(usize, usize),
    RigidPosition(usize, usize),
    MarkerPosition(usize, usize),
}

/// Parses the text of a Motive CSV export; `path` is only used in error messages.
pub fn parse_take(text: &str, path: &Path) -> Result<MotiveTake, MotiveError> {
    let err = |line: usize, column: Option<usize>, message: String| MotiveError::Format {
        path: path.to_path_buf(),
        line,
        column,
        message,
    };
    // Some editors save with a byte-order mark; it is not part of the first key.
    let text = text.strip_prefix('\u{feff}').unwrap_or(text);
    let lines: Vec<&str> = text
        .split('\n')
        .map(|l| l.strip_suffix('\r').unwrap_or(l))
        .collect();
    let line_cells =
        |i: usize| -> Vec<&str> { lines.get(i).map_or(vec![], |l| l.split(',').collect()) };

    let header = parse_header(&line_cells(0), &err)?;
    if lines.get(1).is_some_and(|l| !l.trim().is_empty()) {
        return Err(err(
            2,
            None,
            "expected an empty line after the header block".into(),
        ));
    }
    // Lines 3-7: Type, Name, ID, property, axis.
    let rows: Vec<Vec<&str>> = (2..7).map(line_cells).collect();
    let expected_label = ["Type", "Name", "ID", "", "Time (Seconds)"];
    for (r, row) in rows.iter().enumerate() {
        if lines.get(2 + r).is_none() {
            return Err(err(
                3 + r,
                None,
                "file ends inside the column header rows (lines 3-7)".into(),
            ));
        }
        let label = row.get(1).copied().unwrap_or("");
        if label.trim() != expected_label[r] {
            return Err(err(
                3 + r,
                Some(2),
                format!(
                    "expected '{}' in the second cell, found '{label}'",
                    expected_label[r]
                ),
            ));
        }
    }
    if rows[4][0].trim() != "Frame" {
        return Err(err(
            7,
            Some(1),
            format!("expected 'Frame', found '{}'", rows[4][0]),
        ));
    }
    let n_cols = rows[4].len();
    for (r, row) in rows.iter().enumerate().take(4) {
        if row.len() != n_cols {
            return Err(err(
                3 + r,
                None,
                format!(
                    "expected {n_cols} cells (as in line 7), found {}",
                    row.len()
                ),
            ));
        }
    }

    let (slots, mut rigid_bodies, mut markers) = build_slots(&rows, &err)?;
    // The parsed tracks: per data row, a time, a rotation and a position per rigid body and a
    // position per marker, each an `Option` of floats.
    let data_rows = lines
        .iter()
        .skip(7)
        .rposition(|line| !line.trim().is_empty())
        .map_or(0, |last| last as u64 + 1);
    let per_row = 8
        + rigid_bodies.len() * (size_of::<Option<[f64; 4]>>() + size_of::<Option<[f64; 3]>>())
        + markers.len() * size_of::<Option<[f64; 3]>>();
    let needed = data_rows.saturating_mul(per_row as u64);
    if needed > MAX_TRACK_BYTES {
        return Err(MotiveError::TooLarge {
            path: path.to_path_buf(),
            message: format!(
                "{data_rows} data rows of {} rigid bodies and {} marker columns would need {:.1} GiB once parsed, more than the {:.0} GiB an import allows; expected a shorter export (fewer frames or markers)",
                rigid_bodies.len(),
                markers.len(),
                gib(needed),
                gib(MAX_TRACK_BYTES)
            ),
        });
    }

    let unit = header.length_unit.to_meters();
    let mut time = Vec::new();
    // Values of the current frame, per slot, before they are grouped into vectors.
    let mut rigid_rot: Vec<[Option<f64>; 4]> = vec![[None; 4]; rigid_bodies.len()];
    let mut rigid_pos: Vec<[Option<f64>; 3]> = vec![[None; 3]; rigid_bodies.len()];
    let mut marker_pos: Vec<[Option<f64>; 3]> = vec![[None; 3]; markers.len()];
    for (index, line) in lines.iter().enumerate().skip(7) {
        let line_no = index + 1;
        if line.trim().is_empty() {
            if lines[index..].iter().all(|l| l.trim().is_empty()) {
                break;
            }
            return Err(err(line_no, None, "empty line inside the data rows".into()));
        }
        let cells: Vec<&str> = line.split(',').collect();
        if cells.len() != n_cols {
            return Err(err(
                line_no,
                None,
                format!(
                    "expected {n_cols} cells (as in the header rows), found {}",
                    cells.len()
                ),
            ));
        }
        let number = |c: usize| -> Result<Option<f64>, MotiveError> {
            let cell = cells[c].trim();
            if cell.is_empty() {
                return Ok(None);
            }
            match cell.parse::<f64>() {
                Ok(v) if v.is_finite() => Ok(Some(v)),
                _ => Err(err(
                    line_no,
                    Some(c + 1),
                    format!("expected a number, found '{cell}'"),
                )),
            }
        };
        let t = number(1)?.ok_or_else(|| err(line_no, Some(2), "missing time".into()))?;
        if let Some(&prev) = time.last() {
            if t <= prev {
                return Err(err(
                    line_no,
                    Some(2),
                    format!("time {t} s is not after the previous frame's {prev} s"),
                ));
            }
        }
        time.push(t);
        // A value no capture can hold (a corrupted export) is refused here, before the low-pass
        // filter would spread it over its neighbours.
        let bounded = |c: usize, limit: f64, what: &str| -> Result<Option<f64>, MotiveError> {
            match number(c)? {
                Some(v) if v.abs() > limit => {
                    Err(err(line_no, Some(c + 1), format!("{v} is not {what}")))
                }
                value => Ok(value),
            }
        };
        let coordinate_limit = MAX_COORDINATE_M / unit;
        let coordinate = "a coordinate of a capture volume (within 1000 m)";
        for (c, slot) in slots.iter().enumerate() {
            match *slot {
                // Unused columns (e.g. Mean Marker Error) must still hold numbers: anything else is
                // a corrupted export.
                Slot::Ignored => {
                    number(c)?;
                }
                Slot::RigidRotation(b, axis) => {
                    rigid_rot[b][axis] =
                        bounded(c, 1.0 + 1e-3, "a quaternion component within [-1, 1]")?
                }
                Slot::RigidPosition(b, axis) => {
                    rigid_pos[b][axis] = bounded(c, coordinate_limit, coordinate)?
                }
                Slot::MarkerPosition(m, axis) => {
                    marker_pos[m][axis] = bounded(c, coordinate_limit, coordinate)?
                }
            }
        }
        let partial = |line_no: usize, what: &str| {
            err(
                line_no,
                None,
                format!("{what} has some coordinates empty and others not; expected all or none"),
            )
        };
        for (b, body) in rigid_bodies.iter_mut().enumerate() {
            body.rotation.push(match rigid_rot[b] {
                [Some(x), Some(y), Some(z), Some(w)] => Some([x, y, z, w]),
                [None, None, None, None] => None,
                _ => {
                    return Err(partial(
                        line_no,
                        &format!("rotation of rigid body '{}'", body.name),
                    ))
                }
            });
            body.position.push(match rigid_pos[b] {
                [Some(x), Some(y), Some(z)] => Some([x * unit, y * unit, z * unit]),
                [None, None, None] => None,
                _ => {
                    return Err(partial(
                        line_no,
                        &format!("position of rigid body '{}'", body.name),
                    ))
                }
            });
        }
        for (m, marker) in markers.iter_mut().enumerate() {
            marker.position.push(match marker_pos[m] {
                [Some(x), Some(y), Some(z)] => Some([x * unit, y * unit, z * unit]),
                [None, None, None] => None,
                _ => {
                    return Err(partial(
                        line_no,
                        &format!("position of marker '{}'", marker.name),
                    ))
                }
            });
        }
    }
    if time.is_empty() {
        return Err(err(
            8,
            None,
            "expected at least one data row after the header rows".into(),
        ));
    }
    check_export_rate(&header, &time, &err)?;
    if let Some(total) = header.total_exported_frames {
        if total != time.len() {
            return Err(err(
                1,
                None,
                format!("'Total Exported Frames' says {total} but the file has {} data rows (truncated file?)", time.len()),
            ));
        }
    }
    Ok(MotiveTake {
        path: path.to_path_buf(),
        header,
        time,
        rigid_bodies,
        markers,
    })
}

/// The `Time` column must step by one period of the header's `Export Frame Rate` (the median
/// step, so that a few dropped frames do not count): a header that contradicts its rows would
/// give every derived velocity and acceleration the wrong scale.
fn check_export_rate(header: &TakeHeader, time: &[f64], err: &ErrFn) -> Result<(), MotiveError> {
    let mut steps: Vec<f64> = time.windows(2).map(|pair| pair[1] - pair[0]).collect();
    if steps.is_empty() {
        return Ok(());
    }
    steps.sort_by(f64::total_cmp);
    let step = steps[steps.len() / 2];
    let period = 1.0 / header.export_frame_rate_hz;
    if (step - period).abs() > 0.01 * period {
        return Err(err(
            1,
            None,
            format!(
                "'Export Frame Rate' says {} Hz but the Time column steps by {step:.6} s ({:.1} Hz); \
                 expected the two to agree within 1 %",
                header.export_frame_rate_hz,
                1.0 / step
            ),
        ));
    }
    Ok(())
}

/// Column slots with the rigid bodies and markers they fill.
type ColumnLayout = (Vec<Slot>, Vec<RigidBodyTrack>, Vec<MarkerTrack>);

type ErrFn<'a> = dyn Fn(usize, Option<usize>, String) -> MotiveError + 'a;

fn parse_header(cells: &[&str], err: &ErrFn) -> Result<TakeHeader, MotiveError> {
    let mut map: HashMap<&str, (usize, &str)> = HashMap::new();
    for (i, pair) in cells.chunks(2).enumerate() {
        if let [key, value] = pair {
            map.insert(key.trim(), (2 * i + 2, value.trim()));
        }
    }
    let get = |key: &str| -> Result<(usize, &str), MotiveError> {
        map.get(key).copied().ok_or_else(|| {
            err(1, None, format!("header key '{key}' is missing (expected a Motive CSV export: 'Format Version,1.23,...')"))
        })
    };
    let rate = |key: &str| -> Result<f64, MotiveError> {
        let (col, value) = get(key)?;
        match value.parse::<f64>() {
            Ok(v) if v.is_finite() && v > 0.0 => Ok(v),
            _ => Err(err(
                1,
                Some(col),
                format!("'{key}' must be a positive number of Hz, found '{value}'"),
            )),
        }
    };
    let format_version = get("Format Version")?.1.to_string();
    let take_name = map.get("Take Name").map_or("", |v| v.1).to_string();
    let capture_frame_rate_hz = rate("Capture Frame Rate")?;
    let export_frame_rate_hz = rate("Export Frame Rate")?;
    let (col, rotation) = get("Rotation Type")?;
    if rotation != "Quaternion" {
        return Err(err(
            1,
            Some(col),
            format!("'Rotation Type' is '{rotation}'; expected 'Quaternion' (re-export the take with quaternions)"),
        ));
    }
    let (col, units) = get("Length Units")?;
    let length_unit = match units {
        "Millimeters" => LengthUnit::Millimeters,
        "Centimeters" => LengthUnit::Centimeters,
        "Meters" => LengthUnit::Meters,
        other => {
            return Err(err(
                1,
                Some(col),
                format!("'Length Units' is '{other}'; expected Millimeters, Centimeters or Meters"),
            ))
        }
    };
    let total_exported_frames = match map.get("Total Exported Frames") {
        None => None,
        Some(&(col, value)) => Some(value.parse::<usize>().map_err(|_| {
            err(
                1,
                Some(col),
                format!("'Total Exported Frames' must be a whole number, found '{value}'"),
            )
        })?),
    };
    Ok(TakeHeader {
        format_version,
        take_name,
        capture_frame_rate_hz,
        export_frame_rate_hz,
        length_unit,
        total_exported_frames,
    })
}

/// Maps every data column to a rigid-body or marker coordinate, from the five header rows.
fn build_slots(rows: &[Vec<&str>], err: &ErrFn) -> Result<ColumnLayout, MotiveError> {
    let n_cols = rows[4].len();
    let mut slots = vec![Slot::Ignored; n_cols];
    let mut rigid_bodies: Vec<RigidBodyTrack> = Vec::new();
    let mut markers: Vec<MarkerTrack> = Vec::new();
    // (type, name, id) -> index into rigid_bodies / markers.
    let mut rigid_index: HashMap<(String, String), usize> = HashMap::new();
    let mut marker_index: HashMap<(String, String, String), usize> = HashMap::new();
    let mut seen: HashMap<(usize, bool, usize), usize> = HashMap::new();
    for c in 2..n_cols {
        let (kind, name, id, property, axis) = (
            rows[0][c].trim(),
            rows[1][c].trim(),
            rows[2][c].trim(),
            rows[3][c].trim(),
            rows[4][c].trim(),
        );
        let axis_index = |names: &[&str]| -> Result<usize, MotiveError> {
            names.iter().position(|a| *a == axis).ok_or_else(|| {
                err(7, Some(c + 1), format!("expected one of {names:?} as the axis of '{name}' {property}, found '{axis}'"))
            })
        };
        let slot = match (kind, property) {
            ("Rigid Body", "Rotation" | "Position") => {
                let key = (name.to_string(), id.to_string());
                let b = *rigid_index.entry(key).or_insert_with(|| {
                    rigid_bodies.push(RigidBodyTrack {
                        name: name.to_string(),
                        id: id.to_string(),
                        rotation: Vec::new(),
                        position: Vec::new(),
                    });
                    rigid_bodies.len() - 1
                });
                if property == "Rotation" {
                    Slot::RigidRotation(b, axis_index(&["X", "Y", "Z", "W"])?)
                } else {
                    Slot::RigidPosition(b, axis_index(&["X", "Y", "Z"])?)
                }
            }
            ("Marker" | "Rigid Body Marker", "Position") => {
                let marker_kind = if kind == "Rigid Body Marker" {
                    MarkerKind::RigidBodyMarker
                } else if name.starts_with("Unlabeled") {
                    MarkerKind::Unlabeled
                } else {
                    MarkerKind::Labeled
                };
                let key = (kind.to_string(), name.to_string(), id.to_string());
                let m = *marker_index.entry(key).or_insert_with(|| {
                    markers.push(MarkerTrack {
                        name: name.to_string(),
                        id: id.to_string(),
                        kind: marker_kind,
                        position: Vec::new(),
                    });
                    markers.len() - 1
                });
                Slot::MarkerPosition(m, axis_index(&["X", "Y", "Z"])?)
            }
            ("Rigid Body" | "Marker" | "Rigid Body Marker", "") => {
                return Err(err(
                    6,
                    Some(c + 1),
                    format!("missing property (Rotation/Position) for '{name}'"),
                ));
            }
            // Mean Marker Error, Marker Quality, bones, ...: not needed.
            _ => Slot::Ignored,
        };
        // A coordinate that appears twice would silently overwrite the first.
        let key = match slot {
            Slot::RigidRotation(b, a) => Some((b, true, a)),
            Slot::RigidPosition(b, a) => Some((b, false, a + 10)),
            Slot::MarkerPosition(m, a) => Some((m + 1_000_000, false, a)),
            Slot::Ignored => None,
        };
        if let Some(key) = key {
            if let Some(first) = seen.insert(key, c + 1) {
                return Err(err(
                    7,
                    Some(c + 1),
                    format!("'{name}' {property} {axis} already appears in column {first}; expected each coordinate once"),
                ));
            }
        }
        slots[c] = slot;
    }
    // Every item needs all its coordinates.
    for (b, body) in rigid_bodies.iter().enumerate() {
        let has_rot = (0..4).all(|a| seen.contains_key(&(b, true, a)));
        let has_pos = (0..3).all(|a| seen.contains_key(&(b, false, a + 10)));
        if !has_rot || !has_pos {
            return Err(err(
                6,
                None,
                format!(
                    "rigid body '{}' needs Rotation X,Y,Z,W and Position X,Y,Z columns",
                    body.name
                ),
            ));
        }
    }
    for (m, marker) in markers.iter().enumerate() {
        if !(0..3).all(|a| seen.contains_key(&(m + 1_000_000, false, a))) {
            return Err(err(
                6,
                None,
                format!("marker '{}' needs Position X,Y,Z columns", marker.name),
            ));
        }
    }
    Ok((slots, rigid_bodies, markers))
}

#[cfg(test)]
mod tests {
    use super::*;

    const SMALL: &str = "Format Version,1.23,Take Name,t1,Capture Frame Rate,100.000000,Export Frame Rate,100.000000,Rotation Type,Quaternion,Length Units,Millimeters,Total Exported Frames,3\n\
\n\
,Type,Rigid Body,Rigid Body,Rigid Body,Rigid Body,Rigid Body,Rigid Body,Rigid Body,Rigid Body,Marker,Marker,Marker,Marker,Marker,Marker\n\
,Name,Tool,Tool,Tool,Tool,Tool,Tool,Tool,Tool,Unlabeled 1000,Unlabeled 1000,Unlabeled 1000,Pkg:A,Pkg:A,Pkg:A\n\
,ID,1,1,1,1,1,1,1,1,1000,1000,1000,7,7,7\n\
,,Rotation,Rotation,Rotation,Rotation,Position,Position,Position,Mean Marker Error,Position,Position,Position,Position,Position,Position\n\
Frame,Time (Seconds),X,Y,Z,W,X,Y,Z,,X,Y,Z,X,Y,Z\n\
0,0.00,0,0,0,1,100,200,300,0.1,1,2,3,,,\n\
1,0.01,0,0,0,1,100,200,301,0.1,,,,4,5,6\n\
2,0.02,0,0,0,1,100,200,302,0.1,7,8,9,10,11,12\n";

    fn parse(text: &str) -> Result<MotiveTake, MotiveError> {
        parse_take(text, Path::new("take.csv"))
    }

    #[test]
    fn parses_header_bodies_markers_and_converts_millimetres() {
        let take = parse(SMALL).unwrap();
        assert_eq!(take.header.take_name, "t1");
        assert_eq!(take.header.export_frame_rate_hz, 100.0);
        assert_eq!(take.header.length_unit, LengthUnit::Millimeters);
        assert_eq!(take.time, vec![0.0, 0.01, 0.02]);
        assert_eq!(take.rigid_bodies.len(), 1);
        let tool = &take.rigid_bodies[0];
        assert_eq!(tool.rotation[1], Some([0.0, 0.0, 0.0, 1.0]));
        assert_eq!(tool.position[2], Some([0.1, 0.2, 0.302]));
        assert_eq!(take.markers.len(), 2);
        assert_eq!(take.markers[0].kind, MarkerKind::Unlabeled);
        assert_eq!(take.markers[0].position[1], None);
        let p = take.markers[0].position[2].unwrap();
        assert!((p[2] - 0.009).abs() < 1e-15 && (p[0] - 0.007).abs() < 1e-15);
        assert_eq!(take.markers[1].kind, MarkerKind::Labeled);
        assert_eq!(take.markers[1].position[0], None);
    }

    fn message(text: &str) -> String {
        parse(text).unwrap_err().to_string()
    }

    #[test]
    fn a_take_too_large_to_parse_is_refused_before_allocating() {
        // 100 000 marker columns x 1 400 rows would need 4.2 GiB of tracks: refused from the
        // header and the line count alone (the short data rows are never read).
        let markers = 100_000;
        let mut text = String::from(
            "Format Version,1.23,Capture Frame Rate,100,Export Frame Rate,100,Rotation Type,Quaternion,Length Units,Meters\n\n",
        );
        let mut rows = [
            String::from(",Type"),
            String::from(",Name"),
            String::from(",ID"),
            String::from(","),
            String::from("Frame,Time (Seconds)"),
        ];
        for m in 0..markers {
            for axis in ["X", "Y", "Z"] {
                for (row, cell) in rows.iter_mut().zip([
                    "Marker".to_string(),
                    format!("Unlabeled {m}"),
                    m.to_string(),
                    "Position".into(),
                    axis.into(),
                ]) {
                    row.push(',');
                    row.push_str(&cell);
                }
            }
        }
        for row in rows {
            text += &row;
            text.push('\n');
        }
        text += &"0,0\n".repeat(1400);
        let msg = message(&text);
        assert!(
            msg.contains("take.csv: 1400 data rows of 0 rigid bodies and 100000 marker columns would need 4.2 GiB"),
            "{msg}"
        );
    }

    #[test]
    fn values_no_capture_can_hold_name_line_and_column() {
        let far = SMALL.replace("1,0.01,0,0,0,1,100,200,301", "1,0.01,0,0,0,1,100,1e300,301");
        let msg = message(&far);
        assert!(msg.contains("take.csv: line 9, column 8"), "{msg}");
        assert!(msg.contains("within 1000 m"), "{msg}");
        let rotation = SMALL.replace("1,0.01,0,0,0,1,100,200,301", "1,0.01,0,0,0,7,100,200,301");
        let msg = message(&rotation);
        assert!(
            msg.contains("line 9, column 6: 7 is not a quaternion component"),
            "{msg}"
        );
    }

    #[test]
    fn malformed_cells_name_line_and_column() {
        let bad = SMALL.replace("1,0.01,0,0,0,1,100,200,301", "1,0.01,0,0,0,1,100,abc,301");
        let msg = message(&bad);
        assert!(msg.contains("take.csv: line 9, column 8"), "{msg}");
        assert!(msg.contains("expected a number, found 'abc'"), "{msg}");

        let short = SMALL.replace(
            "2,0.02,0,0,0,1,100,200,302,0.1,7,8,9,10,11,12",
            "2,0.02,0,0,0,1,100",
        );
        assert!(message(&short).contains("line 10: expected 16 cells"));

        let partial = SMALL.replace(",1,2,3,,,", ",1,,3,,,");
        assert!(message(&partial).contains("line 8: position of marker 'Unlabeled 1000'"));

        let backwards = SMALL.replace("2,0.02,", "2,0.005,");
        assert!(message(&backwards).contains("line 10, column 2: time 0.005 s is not after"));

        let units = SMALL.replace("Millimeters", "Inches");
        assert!(message(&units).contains("line 1, column 12: 'Length Units' is 'Inches'"));

        let euler = SMALL.replace("Quaternion", "XYZ");
        assert!(message(&euler).contains("expected 'Quaternion'"));

        let axis = SMALL.replace(
            "Frame,Time (Seconds),X,Y,Z,W",
            "Frame,Time (Seconds),X,Y,Q,W",
        );
        assert!(message(&axis).contains("line 7, column 5"));

        let truncated_count = SMALL.replace("Total Exported Frames,3", "Total Exported Frames,4");
        assert!(message(&truncated_count).contains("truncated file?"));
    }

    #[test]
    fn truncated_and_garbled_inputs_give_errors_not_panics() {
        // Every prefix of the file (cut anywhere) must either parse or return an error.
        for cut in 0..SMALL.len() {
            let prefix = &SMALL[..cut];
            if let Ok(take) = parse(prefix) {
                // Only cuts inside/after the last row can still be complete.
                assert_eq!(
                    take.len(),
                    3,
                    "prefix of {cut} bytes parsed as {} frames",
                    take.len()
                );
            }
        }
        // Deterministic garbling: replace single bytes with separators or letters.
        let bytes = SMALL.as_bytes();
        for (i, replacement) in (0..bytes.len()).flat_map(|i| [(i, b','), (i, b'x'), (i, b'\n')]) {
            let mut garbled = bytes.to_vec();
            garbled[i] = replacement;
            let text = String::from_utf8(garbled).unwrap();
            let _ = parse(&text);
        }
        assert!(message("").contains("line 1"));
        assert!(message("\u{feff}garbage").contains("header key"));
        assert_eq!(parse(&format!("\u{feff}{SMALL}")).unwrap().len(), 3);
    }

    #[test]
    fn reads_gzip_files() {
        use std::io::Write;
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("t.csv.gz");
        let mut encoder = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::fast());
        encoder.write_all(SMALL.as_bytes()).unwrap();
        std::fs::write(&path, encoder.finish().unwrap()).unwrap();
        let take = read_take(&path).unwrap();
        assert_eq!(take.len(), 3);
        let missing = read_take(&dir.path().join("nope.csv"))
            .unwrap_err()
            .to_string();
        assert!(missing.contains("nope.csv: cannot read file"), "{missing}");
    }
}
