//! The rlpkg dataset format: a folder with `manifest.toml` and one folder per trajectory holding
//! `tool.csv`, `object.csv`, `markers.csv` and `meta.toml` (see `data/deformable-sim-real/README.md`).
//!
//! Every reader validates what it reads and names the file, the line and what was expected when
//! something is off; every writer writes a temporary file beside the target and renames it, so a
//! failed write never leaves a half-written file.

use std::fs;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

/// Header of `tool.csv`.
pub const TOOL_HEADER: [&str; 20] = [
    "t", "px", "py", "pz", "qx", "qy", "qz", "qw", "vx", "vy", "vz", "wx", "wy", "wz", "ax", "ay",
    "az", "alpha_x", "alpha_y", "alpha_z",
];
/// Header of `object.csv`.
pub const OBJECT_HEADER: [&str; 10] = ["t", "px", "py", "pz", "vx", "vy", "vz", "ax", "ay", "az"];
/// Header of `markers.csv` without marker identities (the study's recordings).
pub const MARKERS_HEADER: [&str; 5] = ["frame", "t", "x", "y", "z"];
/// Header of `markers.csv` with each row's physical marker id.
pub const LABELLED_MARKERS_HEADER: [&str; 6] = ["frame", "t", "x", "y", "z", "marker"];
/// Largest marker id a `markers.csv` may carry (a take has tens of markers; the bound keeps a
/// corrupted id from sizing tables).
pub const MAX_MARKER_ID: u32 = 100_000;

/// Largest difference (s) allowed between a marker row's time and its frame's tool time.
const TIME_TOLERANCE_S: f64 = 1e-5;
/// Largest difference (s) allowed between the manifest's `duration_s` (rounded when it was
/// written, 4 decimals in the shipped data) and the last tool time.
const DURATION_TOLERANCE_S: f64 = 1e-3;
/// Largest magnitude a recorded value may have (metres, seconds, m/s, m/s², rad/s²): far beyond
/// any capture volume or motion, so only a corrupted or mis-scaled value exceeds it.
const PLAUSIBLE_MAGNITUDE: f64 = 1e6;

/// What went wrong while reading or writing a dataset; every variant names the file.
#[derive(Debug, thiserror::Error)]
pub enum DataError {
    /// The file could not be read or written.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The operating system's error.
        source: std::io::Error,
    },
    /// A line of the file is malformed.
    #[error("{path}:{line}: {message}")]
    Malformed {
        /// The file.
        path: PathBuf,
        /// 1-based line number.
        line: usize,
        /// What is wrong and what was expected.
        message: String,
    },
    /// The file is well formed but its content is not acceptable.
    #[error("{path}: {message}")]
    Invalid {
        /// The file.
        path: PathBuf,
        /// What is wrong and what was expected.
        message: String,
    },
}

fn io_error(path: &Path) -> impl FnOnce(std::io::Error) -> DataError + '_ {
    move |source| DataError::Io {
        path: path.to_path_buf(),
        source,
    }
}

fn invalid(path: &Path, message: impl Into<String>) -> DataError {
    DataError::Invalid {
        path: path.to_path_buf(),
        message: message.into(),
    }
}

/// Which part of the dataset a trajectory belongs to.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Split {
    /// Used for calibration.
    Train,
    /// Held out for evaluation.
    Test,
    /// Kept in the dataset but in neither train nor test (a failure take, see
    /// [`ManifestEntry::failure`]).
    Excluded,
}

impl Split {
    /// The split as the manifest names it: `train`, `test` or `excluded`.
    pub fn name(self) -> &'static str {
        match self {
            Split::Train => "train",
            Split::Test => "test",
            Split::Excluded => "excluded",
        }
    }
}

impl std::str::FromStr for Split {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s {
            "train" => Ok(Split::Train),
            "test" => Ok(Split::Test),
            other => Err(format!("expected \"train\" or \"test\", got {other:?}")),
        }
    }
}

/// One `[[trajectory]]` entry of `manifest.toml`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ManifestEntry {
    /// Folder name of the trajectory.
    pub id: String,
    /// Train or test.
    pub split: Split,
    /// Mass class of the internal object (low / medium / high), when known.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mass: Option<String>,
    /// Added weight in pounds, when known.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mass_lb: Option<f64>,
    /// Velocity level, when known.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub velocity: Option<String>,
    /// Orientation level, when known.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub orientation: Option<String>,
    /// Number of frames.
    pub frames: usize,
    /// Time of the last frame (s).
    pub duration_s: f64,
    /// Mass of the internal object with its added weight (kg).
    pub object_total_mass_kg: f64,
    /// Fewest markers seen in a frame.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub markers_per_frame_min: Option<usize>,
    /// Most markers seen in a frame.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub markers_per_frame_max: Option<usize>,
    /// Data rows of `markers.csv` (markers seen, summed over the frames), so that a file cut at a
    /// line boundary is noticed.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub marker_rows: Option<usize>,
    /// The take failed (e.g. the suction seal let go); such a take is in split `excluded`.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub failure: bool,
}

impl ManifestEntry {
    /// Checks a loaded trajectory against what this entry promises (frame count, duration, marker
    /// rows and markers per frame); the error names the file that disagrees, the manifest and both
    /// values.
    pub fn check(
        &self,
        dir: &Path,
        trajectory: &Trajectory,
        manifest: &Path,
    ) -> Result<(), DataError> {
        let disagree = |file: &str, what: String| {
            invalid(
                &dir.join(file),
                format!(
                    "{what} (manifest {} promises it for {:?}; truncated or edited file?)",
                    manifest.display(),
                    self.id
                ),
            )
        };
        let frames = trajectory.tool.t.len();
        if frames != self.frames {
            return Err(disagree(
                "tool.csv",
                format!("expected {} frames, found {frames}", self.frames),
            ));
        }
        let duration = trajectory.tool.t.last().copied().unwrap_or(0.0);
        if (duration - self.duration_s).abs() > DURATION_TOLERANCE_S {
            return Err(disagree(
                "tool.csv",
                format!(
                    "expected the last frame at t = {} s, found t = {duration} s",
                    self.duration_s
                ),
            ));
        }
        let markers = &trajectory.markers;
        if let Some(rows) = self.marker_rows {
            let found = markers.points.len();
            if found != rows {
                return Err(disagree(
                    "markers.csv",
                    format!("expected {rows} data rows, found {found}"),
                ));
            }
        }
        let counts = (0..markers.len()).map(|k| (k, markers.frame(k).len()));
        if let Some(min) = self.markers_per_frame_min {
            if let Some((k, n)) = counts.clone().find(|&(_, n)| n < min) {
                return Err(disagree(
                    "markers.csv",
                    format!("expected at least {min} markers in every frame, frame {k} has {n}"),
                ));
            }
        }
        if let Some(max) = self.markers_per_frame_max {
            if let Some((k, n)) = counts.clone().find(|&(_, n)| n > max) {
                return Err(disagree(
                    "markers.csv",
                    format!("expected at most {max} markers in every frame, frame {k} has {n}"),
                ));
            }
        }
        Ok(())
    }
}

#[derive(Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct Manifest {
    trajectory: Vec<ManifestEntry>,
}

/// A dataset folder: its manifest, with trajectories loaded on demand.
#[derive(Debug, Clone)]
pub struct Dataset {
    /// The dataset folder.
    pub root: PathBuf,
    /// The manifest's entries, in file order.
    pub entries: Vec<ManifestEntry>,
}

impl Dataset {
    /// Reads `dir/manifest.toml` and checks that every listed trajectory folder exists.
    pub fn open(dir: &Path) -> Result<Dataset, DataError> {
        let path = dir.join("manifest.toml");
        let manifest = read_manifest(&path)?;
        for entry in &manifest.trajectory {
            if !dir.join(&entry.id).is_dir() {
                return Err(invalid(
                    &path,
                    format!(
                        "trajectory {:?} has no folder {}",
                        entry.id,
                        dir.join(&entry.id).display()
                    ),
                ));
            }
        }
        Ok(Dataset {
            root: dir.to_path_buf(),
            entries: manifest.trajectory,
        })
    }

    /// Ids of the trajectories in `split` (all of them for `None`), in manifest order.
    pub fn ids(&self, split: Option<Split>) -> Vec<String> {
        self.entries
            .iter()
            .filter(|entry| split.is_none_or(|s| entry.split == s))
            .map(|entry| entry.id.clone())
            .collect()
    }

    /// Loads trajectory `id`, which must be listed in the manifest, and checks it against its
    /// manifest entry.
    pub fn load(&self, id: &str) -> Result<Trajectory, DataError> {
        let manifest = self.root.join("manifest.toml");
        let Some(entry) = self.entries.iter().find(|entry| entry.id == id) else {
            return Err(invalid(
                &manifest,
                format!(
                    "no trajectory {id:?}; known ids: {}",
                    self.ids(None).join(", ")
                ),
            ));
        };
        let dir = self.root.join(id);
        let trajectory = read_trajectory(&dir)?;
        entry.check(&dir, &trajectory, &manifest)?;
        Ok(trajectory)
    }
}

/// Parses a `manifest.toml`, naming the line of the first error, and checks its entries: ids
/// listed once, a finite duration >= 0, a positive mass, at least one frame.
fn read_manifest(path: &Path) -> Result<Manifest, DataError> {
    let text = fs::read_to_string(path).map_err(io_error(path))?;
    let manifest: Manifest = toml::from_str(&text).map_err(|err| {
        let (line, message) = rlpkg_toml_input::error_at(&text, &err);
        DataError::Malformed {
            path: path.to_path_buf(),
            line,
            message,
        }
    })?;
    let mut seen = std::collections::HashSet::new();
    for entry in &manifest.trajectory {
        let wrong = |key: &str, value: String, expected: &str| {
            invalid(
                path,
                format!(
                    "trajectory {:?}: `{key}` = {value}: expected {expected}",
                    entry.id
                ),
            )
        };
        if !seen.insert(entry.id.as_str()) {
            return Err(invalid(
                path,
                format!("trajectory id {:?} is listed twice", entry.id),
            ));
        }
        if entry.frames == 0 {
            return Err(wrong("frames", "0".into(), "at least 1"));
        }
        if !(entry.duration_s.is_finite() && entry.duration_s >= 0.0) {
            return Err(wrong(
                "duration_s",
                entry.duration_s.to_string(),
                "a finite time >= 0 s (the last frame's)",
            ));
        }
        if !(entry.object_total_mass_kg.is_finite() && entry.object_total_mass_kg > 0.0) {
            return Err(wrong(
                "object_total_mass_kg",
                entry.object_total_mass_kg.to_string(),
                "a mass > 0 kg",
            ));
        }
        if let Some(lb) = entry.mass_lb {
            if !(lb.is_finite() && lb >= 0.0) {
                return Err(wrong("mass_lb", lb.to_string(), "a weight >= 0 lb"));
            }
        }
    }
    Ok(manifest)
}

/// Writes `dir/manifest.toml` atomically.
pub fn write_manifest(dir: &Path, entries: &[ManifestEntry]) -> Result<(), DataError> {
    let path = dir.join("manifest.toml");
    let manifest = Manifest {
        trajectory: entries.to_vec(),
    };
    let text = toml::to_string(&manifest).map_err(|err| invalid(&path, err.to_string()))?;
    write_atomic(&path, text.as_bytes())
}

/// `meta.toml` of one trajectory.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Meta {
    /// Trajectory id (the folder name).
    pub id: String,
    /// Short side and long side of the package (m).
    #[serde(deserialize_with = "rlpkg_toml_input::array")]
    pub package_size_m: [f64; 2],
    /// Film mass of the package (kg).
    pub package_mass_kg: f64,
    /// Diameter of the internal disc (m).
    pub object_diameter_m: f64,
    /// Mass of the printed body alone (kg).
    pub object_body_mass_kg: f64,
    /// Mass of the body with its added weight (kg).
    pub object_total_mass_kg: f64,
    /// Package plus object (kg).
    pub total_mass_kg: f64,
    /// Centre of the suction cups at the start of the recording (m, world frame).
    #[serde(deserialize_with = "rlpkg_toml_input::array")]
    pub initial_suction_cup_position_m: [f64; 3],
    /// Package markers seen in the first recorded frame (m, world frame), used to place the package.
    #[serde(deserialize_with = "rlpkg_toml_input::list")]
    pub initial_marker_positions_m: Vec<[f64; 3]>,
    /// How far the outermost markers sit inside the package's edges at the smallest world x and z
    /// (m); a replay places the package's corner that far beyond the outermost initial markers.
    /// Absent: the markers lie on the edges (the study's dataset).
    #[serde(
        default,
        deserialize_with = "rlpkg_toml_input::option",
        skip_serializing_if = "Option::is_none"
    )]
    pub marker_inset_m: Option<[f64; 2]>,
    /// Markers of the lower film layer at the start of the recording (m, world frame), where the
    /// package's marker layout puts them: the surface the package lies on hides them, so the first
    /// frame cannot give them. A replay embeds them in the lower sheet as marker sites of their own.
    /// Empty: no marker on the lower layer (the study's dataset).
    #[serde(
        default,
        deserialize_with = "rlpkg_toml_input::list",
        skip_serializing_if = "Vec::is_empty"
    )]
    pub initial_lower_marker_positions_m: Vec<[f64; 3]>,
}

/// Recorded end-effector (suction tool) motion, one row per frame.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ToolTrack {
    /// Time (s).
    pub t: Vec<f64>,
    /// Position (m).
    pub position: Vec<[f64; 3]>,
    /// Orientation as a quaternion (x, y, z, w), unit to within 1e-3 as recorded (6 decimals).
    pub orientation: Vec<[f64; 4]>,
    /// Linear velocity (m/s).
    pub velocity: Vec<[f64; 3]>,
    /// Angular velocity (rad/s).
    pub angular_velocity: Vec<[f64; 3]>,
    /// Linear acceleration (m/s²).
    pub acceleration: Vec<[f64; 3]>,
    /// Angular acceleration (rad/s²).
    pub angular_acceleration: Vec<[f64; 3]>,
}

/// Recorded motion of the internal object's centre, one row per frame.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ObjectTrack {
    /// Time (s).
    pub t: Vec<f64>,
    /// Position (m).
    pub position: Vec<[f64; 3]>,
    /// Velocity (m/s).
    pub velocity: Vec<[f64; 3]>,
    /// Acceleration (m/s²).
    pub acceleration: Vec<[f64; 3]>,
}

/// Package markers seen in each frame, with the physical marker each point is when the recording
/// knows it (`markers.csv`'s optional `marker` column; [`crate::tracking`] recovers identities for
/// recordings without one). Without ids the order within a frame carries no identity.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct MarkerFrames {
    t: Vec<f64>,
    /// `offsets[k]..offsets[k + 1]` indexes `points` for frame k.
    offsets: Vec<usize>,
    points: Vec<[f64; 3]>,
    /// Physical marker id of each point, parallel to `points`; `None` for unlabelled recordings.
    ids: Option<Vec<u32>>,
}

impl MarkerFrames {
    /// Builds from per-frame point lists and their times (unlabelled).
    pub fn from_frames(t: Vec<f64>, frames: Vec<Vec<[f64; 3]>>) -> Self {
        assert_eq!(t.len(), frames.len(), "one time per marker frame");
        let mut offsets = Vec::with_capacity(frames.len() + 1);
        offsets.push(0);
        let mut points = Vec::new();
        for frame in frames {
            points.extend(frame);
            offsets.push(points.len());
        }
        MarkerFrames {
            t,
            offsets,
            points,
            ids: None,
        }
    }

    /// Builds from per-frame `(marker id, point)` lists and their times. An id names one physical
    /// marker through the whole recording and appears at most once per frame.
    pub fn from_labelled_frames(t: Vec<f64>, frames: Vec<Vec<(u32, [f64; 3])>>) -> Self {
        let ids = frames
            .iter()
            .flat_map(|frame| frame.iter().map(|(id, _)| *id))
            .collect();
        let points = frames
            .into_iter()
            .map(|frame| frame.into_iter().map(|(_, p)| p).collect())
            .collect();
        MarkerFrames {
            ids: Some(ids),
            ..Self::from_frames(t, points)
        }
    }

    /// True when every point carries the id of its physical marker.
    pub fn is_labelled(&self) -> bool {
        self.ids.is_some()
    }

    /// The marker ids of frame `k`, parallel to [`MarkerFrames::frame`]; `None` when unlabelled.
    pub fn frame_ids(&self, k: usize) -> Option<&[u32]> {
        self.ids
            .as_ref()
            .map(|ids| &ids[self.offsets[k]..self.offsets[k + 1]])
    }

    /// Number of frames.
    pub fn len(&self) -> usize {
        self.t.len()
    }

    /// True when there are no frames.
    pub fn is_empty(&self) -> bool {
        self.t.is_empty()
    }

    /// Markers seen in frame `k` (m).
    pub fn frame(&self, k: usize) -> &[[f64; 3]] {
        &self.points[self.offsets[k]..self.offsets[k + 1]]
    }

    /// Time of frame `k` (s).
    pub fn t(&self, k: usize) -> f64 {
        self.t[k]
    }
}

/// One recorded trajectory: the tool drives the package, the markers and the object are the targets.
#[derive(Debug, Clone, PartialEq)]
pub struct Trajectory {
    /// Folder name.
    pub id: String,
    /// `meta.toml`.
    pub meta: Meta,
    /// `tool.csv`.
    pub tool: ToolTrack,
    /// `object.csv`.
    pub object: ObjectTrack,
    /// `markers.csv`.
    pub markers: MarkerFrames,
}

/// Reads the rows of a CSV file with exactly `header`, giving each row's 1-based line and values.
pub(crate) fn read_rows(path: &Path, header: &[&str]) -> Result<Vec<(usize, Vec<f64>)>, DataError> {
    let mut reader = csv::ReaderBuilder::new()
        .flexible(true)
        .from_path(path)
        .map_err(|err| csv_error(path, err))?;
    let found = reader
        .headers()
        .map_err(|err| csv_error(path, err))?
        .clone();
    if found.iter().map(str::trim).ne(header.iter().copied()) {
        return Err(DataError::Malformed {
            path: path.to_path_buf(),
            line: 1,
            message: format!(
                "expected the header {:?}, found {:?}",
                header.join(","),
                found.iter().collect::<Vec<_>>().join(",")
            ),
        });
    }
    let mut rows = Vec::new();
    for record in reader.records() {
        let record = record.map_err(|err| csv_error(path, err))?;
        let line = record.position().map_or(0, |p| p.line() as usize);
        if record.len() != header.len() {
            return Err(DataError::Malformed {
                path: path.to_path_buf(),
                line,
                message: format!("expected {} values, found {}", header.len(), record.len()),
            });
        }
        let mut values = Vec::with_capacity(header.len());
        for (column, cell) in header.iter().zip(record.iter()) {
            let value: f64 = cell.trim().parse().map_err(|_| DataError::Malformed {
                path: path.to_path_buf(),
                line,
                message: format!("column {column}: expected a number, found {cell:?}"),
            })?;
            if !value.is_finite() {
                return Err(DataError::Malformed {
                    path: path.to_path_buf(),
                    line,
                    message: format!("column {column}: expected a finite number, found {cell:?}"),
                });
            }
            if *column != "frame" && value.abs() > PLAUSIBLE_MAGNITUDE {
                return Err(DataError::Malformed {
                    path: path.to_path_buf(),
                    line,
                    message: format!(
                        "column {column}: {cell:?} is beyond any plausible size; expected a \
                         magnitude <= {PLAUSIBLE_MAGNITUDE:e} (SI units)"
                    ),
                });
            }
            values.push(value);
        }
        rows.push((line, values));
    }
    Ok(rows)
}

fn csv_error(path: &Path, err: csv::Error) -> DataError {
    match err.kind() {
        csv::ErrorKind::Io(_) => {
            let message = err.to_string();
            match err.into_kind() {
                csv::ErrorKind::Io(source) => DataError::Io {
                    path: path.to_path_buf(),
                    source,
                },
                _ => invalid(path, message),
            }
        }
        _ => DataError::Malformed {
            path: path.to_path_buf(),
            line: err.position().map_or(0, |p| p.line() as usize),
            message: err.to_string(),
        },
    }
}

/// Checks that there is a row and that times strictly increase, naming the first bad line.
pub(crate) fn check_increasing(path: &Path, rows: &[(usize, Vec<f64>)]) -> Result<(), DataError> {
    for pair in rows.windows(2) {
        if pair[1].1[0] <= pair[0].1[0] {
            return Err(DataError::Malformed {
                path: path.to_path_buf(),
                line: pair[1].0,
                message: format!(
                    "time must increase: t = {} follows t = {}",
                    pair[1].1[0], pair[0].1[0]
                ),
            });
        }
    }
    if rows.is_empty() {
        return Err(invalid(path, "expected at least one data row"));
    }
    Ok(())
}

fn vec3(values: &[f64], start: usize) -> [f64; 3] {
    [values[start], values[start + 1], values[start + 2]]
}

fn read_tool(path: &Path) -> Result<ToolTrack, DataError> {
    let rows = read_rows(path, &TOOL_HEADER)?;
    check_increasing(path, &rows)?;
    let mut tool = ToolTrack::default();
    for (line, v) in &rows {
        let q = [v[4], v[5], v[6], v[7]];
        let norm = q.iter().map(|c| c * c).sum::<f64>().sqrt();
        if (norm - 1.0).abs() > 1e-3 {
            return Err(DataError::Malformed {
                path: path.to_path_buf(),
                line: *line,
                message: format!("qx,qy,qz,qw must be a unit quaternion, its norm is {norm}"),
            });
        }
        tool.t.push(v[0]);
        tool.position.push(vec3(v, 1));
        tool.orientation.push(q);
        tool.velocity.push(vec3(v, 8));
        tool.angular_velocity.push(vec3(v, 11));
        tool.acceleration.push(vec3(v, 14));
        tool.angular_acceleration.push(vec3(v, 17));
    }
    Ok(tool)
}

fn read_object(path: &Path) -> Result<ObjectTrack, DataError> {
    let rows = read_rows(path, &OBJECT_HEADER)?;
    check_increasing(path, &rows)?;
    let mut object = ObjectTrack::default();
    for (_, v) in &rows {
        object.t.push(v[0]);
        object.position.push(vec3(v, 1));
        object.velocity.push(vec3(v, 4));
        object.acceleration.push(vec3(v, 7));
    }
    Ok(object)
}

/// Reads `markers.csv`, whose `frame` column indexes the frames of `times` (the tool's time base).
/// With a `marker` column every row names its physical marker, at most once per frame.
fn read_markers(path: &Path, times: &[f64]) -> Result<MarkerFrames, DataError> {
    let labelled = first_line(path)?.trim() == LABELLED_MARKERS_HEADER.join(",");
    let header: &[&str] = if labelled {
        &LABELLED_MARKERS_HEADER
    } else {
        &MARKERS_HEADER
    };
    let rows = read_rows(path, header)?;
    let mut frames: Vec<Vec<(u32, [f64; 3])>> = vec![Vec::new(); times.len()];
    let mut last_frame = 0usize;
    for (line, v) in &rows {
        let malformed = |message: String| DataError::Malformed {
            path: path.to_path_buf(),
            line: *line,
            message,
        };
        if v[0] < 0.0 || v[0].fract() != 0.0 {
            return Err(malformed(format!(
                "frame must be a whole number >= 0, found {}",
                v[0]
            )));
        }
        let frame = v[0] as usize;
        if frame >= times.len() {
            return Err(malformed(format!(
                "frame {frame} is past the last tool frame {}",
                times.len() - 1
            )));
        }
        if frame < last_frame {
            return Err(malformed(format!(
                "frames must not decrease: frame {frame} follows frame {last_frame}"
            )));
        }
        if (v[1] - times[frame]).abs() > TIME_TOLERANCE_S {
            return Err(malformed(format!(
                "t = {} does not match frame {frame}'s time {} in tool.csv",
                v[1], times[frame]
            )));
        }
        last_frame = frame;
        let id = if labelled {
            let id = v[5];
            if id < 0.0 || id.fract() != 0.0 || id > f64::from(MAX_MARKER_ID) {
                return Err(malformed(format!(
                    "marker must be a whole number in 0..={MAX_MARKER_ID}, found {id}"
                )));
            }
            let id = id as u32;
            if frames[frame].iter().any(|(seen, _)| *seen == id) {
                return Err(malformed(format!(
                    "marker {id} appears twice in frame {frame}; expected each marker once per frame"
                )));
            }
            id
        } else {
            0
        };
        frames[frame].push((id, vec3(v, 2)));
    }
    if labelled {
        Ok(MarkerFrames::from_labelled_frames(times.to_vec(), frames))
    } else {
        let frames = frames
            .into_iter()
            .map(|f| f.into_iter().map(|(_, p)| p).collect())
            .collect();
        Ok(MarkerFrames::from_frames(times.to_vec(), frames))
    }
}

/// The first line of a text file (empty for an empty file).
fn first_line(path: &Path) -> Result<String, DataError> {
    use std::io::BufRead;
    let file = fs::File::open(path).map_err(io_error(path))?;
    let mut line = String::new();
    std::io::BufReader::new(file)
        .read_line(&mut line)
        .map_err(io_error(path))?;
    Ok(line)
}

fn read_meta(path: &Path) -> Result<Meta, DataError> {
    let text = fs::read_to_string(path).map_err(io_error(path))?;
    let meta: Meta = toml::from_str(&text).map_err(|err| {
        let (line, message) = rlpkg_toml_input::error_at(&text, &err);
        DataError::Malformed {
            path: path.to_path_buf(),
            line,
            message,
        }
    })?;
    let positive = [
        ("package_size_m[0]", meta.package_size_m[0]),
        ("package_size_m[1]", meta.package_size_m[1]),
        ("package_mass_kg", meta.package_mass_kg),
        ("object_diameter_m", meta.object_diameter_m),
        ("object_body_mass_kg", meta.object_body_mass_kg),
        ("object_total_mass_kg", meta.object_total_mass_kg),
        ("total_mass_kg", meta.total_mass_kg),
    ];
    for (key, value) in positive {
        if !(value.is_finite() && value > 0.0 && value <= PLAUSIBLE_MAGNITUDE) {
            return Err(invalid(
                path,
                format!("{key} must be a positive number, found {value}"),
            ));
        }
    }
    let positions = std::iter::once((
        "initial_suction_cup_position_m",
        0,
        &meta.initial_suction_cup_position_m,
    ))
    .chain(
        meta.initial_marker_positions_m
            .iter()
            .enumerate()
            .map(|(i, p)| ("initial_marker_positions_m", i, p)),
    )
    .chain(
        meta.initial_lower_marker_positions_m
            .iter()
            .enumerate()
            .map(|(i, p)| ("initial_lower_marker_positions_m", i, p)),
    );
    for (key, index, position) in positions {
        if position
            .iter()
            .any(|v| !(v.is_finite() && v.abs() <= PLAUSIBLE_MAGNITUDE))
        {
            let at = if key == "initial_suction_cup_position_m" {
                key.to_string()
            } else {
                format!("{key}[{index}]")
            };
            return Err(invalid(
                path,
                format!(
                    "{at} = {position:?}: expected finite coordinates of magnitude <= \
                     {PLAUSIBLE_MAGNITUDE:e} m"
                ),
            ));
        }
    }
    if meta.initial_marker_positions_m.len() < 3 {
        return Err(invalid(
            path,
            "initial_marker_positions_m must list at least 3 markers to place the package",
        ));
    }
    Ok(meta)
}

/// Loads and validates one trajectory folder (`tool.csv`, `object.csv`, `markers.csv`,
/// `meta.toml`). When the folder sits in a dataset whose `manifest.toml` lists it, the trajectory is
/// also checked against that entry (frame count, duration, marker rows), as [`Dataset::load`] does.
pub fn load_trajectory(dir: &Path) -> Result<Trajectory, DataError> {
    let trajectory = read_trajectory(dir)?;
    let (Some(parent), Some(name)) = (dir.parent(), dir.file_name()) else {
        return Ok(trajectory);
    };
    let manifest = parent.join("manifest.toml");
    if manifest.is_file() {
        let entries = read_manifest(&manifest)?.trajectory;
        if let Some(entry) = entries.iter().find(|e| name == e.id.as_str()) {
            entry.check(dir, &trajectory, &manifest)?;
            return Ok(trajectory);
        }
    }
    check_markers_cover_frames(dir, &trajectory)?;
    Ok(trajectory)
}

/// A folder no manifest vouches for is checked from its own files: every frame of `tool.csv` must
/// have markers in `markers.csv` (a file cut short leaves the last frames without any, and their
/// errors would be NaN).
fn check_markers_cover_frames(dir: &Path, trajectory: &Trajectory) -> Result<(), DataError> {
    let markers = &trajectory.markers;
    match (0..markers.len()).find(|&k| markers.frame(k).is_empty()) {
        Some(k) => Err(invalid(
            &dir.join("markers.csv"),
            format!(
                "frame {k} of {} (t = {} s) has no marker; expected markers in every frame \
                 (file cut short?)",
                markers.len(),
                markers.t(k)
            ),
        )),
        None => Ok(()),
    }
}

/// Loads and validates one trajectory folder on its own (no manifest).
fn read_trajectory(dir: &Path) -> Result<Trajectory, DataError> {
    if !dir.is_dir() {
        return Err(invalid(
            dir,
            "expected a trajectory folder (tool.csv, object.csv, markers.csv, meta.toml)",
        ));
    }
    let meta = read_meta(&dir.join("meta.toml"))?;
    let tool_path = dir.join("tool.csv");
    let tool = read_tool(&tool_path)?;
    let object_path = dir.join("object.csv");
    let object = read_object(&object_path)?;
    if object.t.len() != tool.t.len() {
        return Err(invalid(
            &object_path,
            format!(
                "expected one row per tool.csv frame ({}), found {}",
                tool.t.len(),
                object.t.len()
            ),
        ));
    }
    if let Some(k) = (0..tool.t.len()).find(|&k| (object.t[k] - tool.t[k]).abs() > TIME_TOLERANCE_S)
    {
        return Err(invalid(
            &object_path,
            format!(
                "row {} has t = {} but tool.csv has t = {} for that frame",
                k + 1,
                object.t[k],
                tool.t[k]
            ),
        ));
    }
    let markers = read_markers(&dir.join("markers.csv"), &tool.t)?;
    let folder = dir.file_name().and_then(|name| name.to_str());
    if folder.is_some_and(|folder| folder != meta.id) {
        return Err(invalid(
            &dir.join("meta.toml"),
            format!(
                "id = {:?} but the folder is {:?}; expected the folder's name (renamed or copied \
                 folder?)",
                meta.id,
                folder.unwrap_or_default()
            ),
        ));
    }
    Ok(Trajectory {
        id: meta.id.clone(),
        meta,
        tool,
        object,
        markers,
    })
}

impl Trajectory {
    /// Writes the four files of this trajectory into `dir` (created if needed), each atomically.
    pub fn save(&self, dir: &Path) -> Result<(), DataError> {
        fs::create_dir_all(dir).map_err(io_error(dir))?;
        let meta_path = dir.join("meta.toml");
        let meta =
            toml::to_string(&self.meta).map_err(|err| invalid(&meta_path, err.to_string()))?;
        write_atomic(&meta_path, meta.as_bytes())?;

        let tool = &self.tool;
        let mut text = TOOL_HEADER.join(",") + "\n";
        for k in 0..tool.t.len() {
            let mut row = vec![tool.t[k]];
            row.extend(tool.position[k]);
            row.extend(tool.orientation[k]);
            row.extend(tool.velocity[k]);
            row.extend(tool.angular_velocity[k]);
            row.extend(tool.acceleration[k]);
            row.extend(tool.angular_acceleration[k]);
            push_row(&mut text, &row);
        }
        write_atomic(&dir.join("tool.csv"), text.as_bytes())?;

        let object = &self.object;
        let mut text = OBJECT_HEADER.join(",") + "\n";
        for k in 0..object.t.len() {
            let mut row = vec![object.t[k]];
            row.extend(object.position[k]);
            row.extend(object.velocity[k]);
            row.extend(object.acceleration[k]);
            push_row(&mut text, &row);
        }
        write_atomic(&dir.join("object.csv"), text.as_bytes())?;

        let header = if self.markers.is_labelled() {
            &LABELLED_MARKERS_HEADER[..]
        } else {
            &MARKERS_HEADER[..]
        };
        let mut text = header.join(",") + "\n";
        for k in 0..self.markers.len() {
            let ids = self.markers.frame_ids(k);
            for (i, point) in self.markers.frame(k).iter().enumerate() {
                text.push_str(&format!("{k},"));
                push_row(
                    &mut text,
                    &[self.markers.t(k), point[0], point[1], point[2]],
                );
                if let Some(ids) = ids {
                    text.pop(); // the row's newline: the id follows as a whole number
                    text.push_str(&format!(",{}\n", ids[i]));
                }
            }
        }
        write_atomic(&dir.join("markers.csv"), text.as_bytes())
    }
}

/// Prefix of the temporary folder a trajectory is written into before it is renamed into place.
pub const TEMP_FOLDER_PREFIX: &str = ".rlpkg-tmp-";
/// Prefix of a trajectory folder moved aside while its replacement is renamed into place.
pub const REPLACED_FOLDER_PREFIX: &str = ".rlpkg-old-";

impl Trajectory {
    /// Writes this trajectory as the folder `root/<id>` all at once: the files go into a temporary
    /// folder beside it, which is renamed into place (an existing folder is moved aside first and
    /// removed after). On error the temporary folder is removed and an existing folder is kept.
    pub fn save_folder(&self, root: &Path) -> Result<PathBuf, DataError> {
        let target = root.join(&self.id);
        let temp = root.join(format!("{TEMP_FOLDER_PREFIX}{}", self.id));
        let replaced = root.join(format!("{REPLACED_FOLDER_PREFIX}{}", self.id));
        if let Ok(meta) = fs::symlink_metadata(&target) {
            if !meta.is_dir() {
                return Err(invalid(
                    &target,
                    "exists and is not a folder; expected a trajectory folder or nothing",
                ));
            }
        }
        remove_if_present(&temp)?;
        let result = self
            .save(&temp)
            .and_then(|()| replace_folder(&temp, &target, &replaced));
        if result.is_err() {
            // Best effort: the error being returned matters more than this one.
            let _ = fs::remove_dir_all(&temp);
        }
        result.map(|()| target)
    }
}

fn remove_if_present(dir: &Path) -> Result<(), DataError> {
    match fs::remove_dir_all(dir) {
        Err(err) if err.kind() != std::io::ErrorKind::NotFound => Err(DataError::Io {
            path: dir.to_path_buf(),
            source: err,
        }),
        _ => Ok(()),
    }
}

/// Renames the complete folder `temp` to `target`, moving an existing `target` aside to
/// `replaced` first and removing it once the new one is in place.
fn replace_folder(temp: &Path, target: &Path, replaced: &Path) -> Result<(), DataError> {
    if target.exists() {
        remove_if_present(replaced)?;
        fs::rename(target, replaced).map_err(io_error(target))?;
        if let Err(err) = fs::rename(temp, target) {
            // Put the old folder back so the dataset stays as it was.
            let _ = fs::rename(replaced, target);
            return Err(io_error(target)(err));
        }
        remove_if_present(replaced)?;
    } else {
        fs::rename(temp, target).map_err(io_error(target))?;
    }
    // Make the rename durable; not every file system can sync a folder, and the data is complete
    // either way.
    if let Some(parent) = target.parent() {
        let _ = fs::File::open(parent).and_then(|dir| dir.sync_all());
    }
    Ok(())
}

/// Removes what an interrupted import left in the dataset folder `root`: temporary trajectory
/// folders, folders moved aside (put back if their replacement never arrived) and temporary files
/// of an interrupted manifest write. Returns one line per folder or file it handled.
pub fn clean_leftovers(root: &Path) -> Result<Vec<String>, DataError> {
    let mut done = Vec::new();
    let entries = match fs::read_dir(root) {
        Ok(entries) => entries,
        Err(err) if err.kind() == std::io::ErrorKind::NotFound => return Ok(done),
        Err(err) => return Err(io_error(root)(err)),
    };
    let mut names: Vec<String> = Vec::new();
    for entry in entries {
        let entry = entry.map_err(io_error(root))?;
        names.push(entry.file_name().to_string_lossy().into_owned());
    }
    names.sort();
    for name in names {
        let path = root.join(&name);
        if name.starts_with(TEMP_FOLDER_PREFIX) {
            remove_if_present(&path)?;
            done.push(format!("removed the unfinished folder {}", path.display()));
        } else if let Some(id) = name.strip_prefix(REPLACED_FOLDER_PREFIX) {
            let target = root.join(id);
            if target.exists() {
                remove_if_present(&path)?;
                done.push(format!("removed the replaced folder {}", path.display()));
            } else {
                fs::rename(&path, &target).map_err(io_error(&target))?;
                done.push(format!(
                    "restored {} (its replacement was never written)",
                    target.display()
                ));
            }
        } else if rlpkg_files::is_temporary_of(&name, "manifest.toml") {
            fs::remove_file(&path).map_err(io_error(&path))?;
            done.push(format!("removed the unfinished file {}", path.display()));
        }
    }
    Ok(done)
}

/// Appends one CSV row with 6 decimals (micrometres, microseconds), as the shipped data.
fn push_row(text: &mut String, values: &[f64]) {
    let cells: Vec<String> = values.iter().map(|v| format!("{v:.6}")).collect();
    text.push_str(&cells.join(","));
    text.push('\n');
}

/// Writes `bytes` to `path` atomically ([`rlpkg_files::write_atomic`]).
fn write_atomic(path: &Path, bytes: &[u8]) -> Result<(), DataError> {
    rlpkg_files::write_atomic(path, bytes).map_err(io_error(path))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn shipped() -> PathBuf {
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../data/deformable-sim-real")
    }

    #[test]
    fn split_names_are_the_manifests() {
        for split in [Split::Train, Split::Test, Split::Excluded] {
            let written = serde_json::to_string(&split).unwrap();
            assert_eq!(written, format!("\"{}\"", split.name()));
        }
    }

    #[test]
    fn shipped_dataset_has_the_papers_split() {
        let dataset = Dataset::open(&shipped()).unwrap();
        assert_eq!(dataset.entries.len(), 18);
        let mut test = dataset.ids(Some(Split::Test));
        test.sort();
        assert_eq!(test, ["HHHMM", "HHLMM", "HHMMM"]);
        assert_eq!(dataset.ids(Some(Split::Train)).len(), 15);
    }

    #[test]
    fn every_shipped_trajectory_keeps_its_manifests_promises() {
        let dataset = Dataset::open(&shipped()).unwrap();
        for id in dataset.ids(None) {
            let entry = dataset.entries.iter().find(|e| e.id == id).unwrap();
            assert!(entry.marker_rows.is_some(), "{id}: no marker_rows");
            if let Err(err) = dataset.load(&id) {
                panic!("{id}: {err}");
            }
        }
    }

    #[test]
    fn loads_a_trajectory_consistently_with_its_manifest() {
        let dataset = Dataset::open(&shipped()).unwrap();
        let traj = dataset.load("HHLHL").unwrap();
        let entry = dataset.entries.iter().find(|e| e.id == "HHLHL").unwrap();
        assert_eq!(traj.tool.t.len(), entry.frames);
        assert_eq!(traj.markers.len(), entry.frames);
        assert!((traj.tool.t.last().unwrap() - entry.duration_s).abs() < 1e-3);
        let counts: Vec<usize> = (0..traj.markers.len())
            .map(|k| traj.markers.frame(k).len())
            .collect();
        assert_eq!(counts.iter().min().copied(), entry.markers_per_frame_min);
        assert_eq!(counts.iter().max().copied(), entry.markers_per_frame_max);
        assert_eq!(traj.meta.initial_marker_positions_m.len(), 37);
    }

    #[test]
    fn save_then_load_round_trips() {
        let dataset = Dataset::open(&shipped()).unwrap();
        let traj = dataset.load("HHLHL").unwrap();
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("HHLHL");
        traj.save(&out).unwrap();
        let again = load_trajectory(&out).unwrap();
        assert_eq!(again, traj);
    }

    #[test]
    fn tracked_marker_ids_survive_save_and_load() {
        let dataset = Dataset::open(&shipped()).unwrap();
        let mut traj = dataset.load("HHLHL").unwrap();
        assert!(!traj.markers.is_labelled());
        let (labelled, report) =
            crate::track_markers(&traj.markers, &crate::TrackingSettings::default());
        assert_eq!(report.initial_tracks, traj.markers.frame(0).len());
        traj.markers = labelled;
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("HHLHL");
        traj.save(&out).unwrap();
        let header = fs::read_to_string(out.join("markers.csv")).unwrap();
        assert!(
            header.starts_with("frame,t,x,y,z,marker\n"),
            "{}",
            &header[..40]
        );
        let again = load_trajectory(&out).unwrap();
        assert!(again.markers.is_labelled());
        assert_eq!(again.markers.frame_ids(7), traj.markers.frame_ids(7));
        assert_eq!(again, traj);
    }

    #[test]
    fn a_bad_marker_id_names_the_line() {
        let dataset = Dataset::open(&shipped()).unwrap();
        let mut traj = dataset.load("HHLHL").unwrap();
        traj.markers = crate::track_markers(&traj.markers, &crate::TrackingSettings::default()).0;
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("HHLHL");
        traj.save(&out).unwrap();
        let path = out.join("markers.csv");
        let text = fs::read_to_string(&path).unwrap();
        let second = text.lines().nth(2).unwrap();
        let (head, _) = second.rsplit_once(',').unwrap();
        let first_id = text.lines().nth(1).unwrap().rsplit_once(',').unwrap().1;
        for (bad, words) in [
            (format!("{head},-1"), "whole number"),
            (format!("{head},2.5"), "whole number"),
            (format!("{head},{first_id}"), "appears twice"),
        ] {
            fs::write(&path, replace_line(&text, 3, &bad)).unwrap();
            let message = load_trajectory(&out).unwrap_err().to_string();
            assert!(
                message.contains("markers.csv:3") && message.contains(words),
                "{message}"
            );
        }
    }

    fn broken_copy(file: &str, edit: impl Fn(&str) -> String) -> (tempfile::TempDir, PathBuf) {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("T");
        fs::create_dir(&out).unwrap();
        for name in ["tool.csv", "object.csv", "markers.csv", "meta.toml"] {
            let text = fs::read_to_string(shipped().join("HHLHL").join(name)).unwrap();
            let text = if name == file { edit(&text) } else { text };
            fs::write(out.join(name), text).unwrap();
        }
        (dir, out)
    }

    fn replace_line(text: &str, line: usize, new: &str) -> String {
        let mut lines: Vec<&str> = text.lines().collect();
        lines[line - 1] = new;
        lines.join("\n") + "\n"
    }

    #[test]
    fn a_non_numeric_cell_names_file_line_and_column() {
        let (_dir, out) = broken_copy("object.csv", |t| {
            replace_line(t, 5, "0.016666,abc,0,0,0,0,0,0,0,0")
        });
        let message = load_trajectory(&out).unwrap_err().to_string();
        assert!(message.contains("object.csv:5:"), "{message}");
        assert!(message.contains("column px"), "{message}");
    }

    #[test]
    fn a_short_row_is_reported() {
        let (_dir, out) = broken_copy("tool.csv", |t| replace_line(t, 3, "0.1,1,2"));
        let message = load_trajectory(&out).unwrap_err().to_string();
        assert!(
            message.contains("tool.csv:3:") && message.contains("expected 20 values"),
            "{message}"
        );
    }

    #[test]
    fn time_going_backwards_is_reported() {
        let (_dir, out) = broken_copy("object.csv", |t| {
            let fields: Vec<String> = t
                .lines()
                .nth(3)
                .unwrap()
                .split(',')
                .map(String::from)
                .collect();
            let row = format!("0.000001,{}", fields[1..].join(","));
            replace_line(t, 4, &row)
        });
        let message = load_trajectory(&out).unwrap_err().to_string();
        assert!(
            message.contains("object.csv:4:") && message.contains("time must increase"),
            "{message}"
        );
    }

    #[test]
    fn a_missing_file_is_named() {
        let (_dir, out) = broken_copy("markers.csv", |t| t.to_string());
        fs::remove_file(out.join("markers.csv")).unwrap();
        let message = load_trajectory(&out).unwrap_err().to_string();
        assert!(message.contains("markers.csv"), "{message}");
    }

    /// A dataset holding a copy of HHLHL (with its shipped manifest entry) where `edit` changes the
    /// files; returns the folder that holds the dataset.
    fn edited_dataset(edit: impl Fn(&Path)) -> tempfile::TempDir {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("HHLHL");
        fs::create_dir(&out).unwrap();
        for name in ["tool.csv", "object.csv", "markers.csv", "meta.toml"] {
            fs::copy(shipped().join("HHLHL").join(name), out.join(name)).unwrap();
        }
        let entry = Dataset::open(&shipped())
            .unwrap()
            .entries
            .into_iter()
            .find(|e| e.id == "HHLHL")
            .unwrap();
        write_manifest(dir.path(), &[entry]).unwrap();
        edit(&out);
        dir
    }

    /// Drops the last `lines` lines of a file (a cut at a line boundary).
    fn drop_last_lines(path: &Path, lines: usize) {
        let text = fs::read_to_string(path).unwrap();
        let kept: Vec<&str> = text.lines().collect();
        fs::write(path, kept[..kept.len() - lines].join("\n") + "\n").unwrap();
    }

    #[test]
    fn markers_cut_at_a_line_boundary_break_the_manifests_promise() {
        let rows = fs::read_to_string(shipped().join("HHLHL/markers.csv"))
            .unwrap()
            .lines()
            .count()
            - 1;
        // One line: the last frame keeps most of its markers, so only the row count can tell.
        let dir = edited_dataset(|t| drop_last_lines(&t.join("markers.csv"), 1));
        let message = Dataset::open(dir.path())
            .unwrap()
            .load("HHLHL")
            .unwrap_err()
            .to_string();
        assert!(
            message.contains("HHLHL/markers.csv")
                && message.contains(&format!("expected {rows} data rows, found {}", rows - 1))
                && message.contains("manifest.toml"),
            "{message}"
        );
        // The same check when the folder is loaded on its own (as `rlpkg simulate` does).
        let direct = load_trajectory(&dir.path().join("HHLHL"))
            .unwrap_err()
            .to_string();
        assert_eq!(direct, message);
        // Without the row count, whole frames cut off fall below the promised minimum.
        let dir = edited_dataset(|t| drop_last_lines(&t.join("markers.csv"), 200));
        let mut entries = Dataset::open(dir.path()).unwrap().entries;
        entries[0].marker_rows = None;
        write_manifest(dir.path(), &entries).unwrap();
        let message = load_trajectory(&dir.path().join("HHLHL"))
            .unwrap_err()
            .to_string();
        assert!(
            message.contains("markers.csv: expected at least"),
            "{message}"
        );
    }

    #[test]
    fn tool_and_object_cut_alike_break_the_frame_count() {
        // The three CSVs cut consistently: the last 10 frames are gone from all of them.
        let dir = edited_dataset(|t| {
            drop_last_lines(&t.join("tool.csv"), 10);
            drop_last_lines(&t.join("object.csv"), 10);
            let frames = fs::read_to_string(t.join("tool.csv"))
                .unwrap()
                .lines()
                .count()
                - 1;
            let markers = fs::read_to_string(t.join("markers.csv")).unwrap();
            let kept: Vec<&str> = markers
                .lines()
                .filter(|line| {
                    line.split(',')
                        .next()
                        .unwrap()
                        .parse::<usize>()
                        .map_or(true, |k| k < frames)
                })
                .collect();
            fs::write(t.join("markers.csv"), kept.join("\n") + "\n").unwrap();
        });
        let frames = Dataset::open(dir.path()).unwrap().entries[0].frames;
        let message = Dataset::open(dir.path())
            .unwrap()
            .load("HHLHL")
            .unwrap_err()
            .to_string();
        assert!(
            message.contains("HHLHL/tool.csv")
                && message.contains(&format!("expected {frames} frames, found {}", frames - 10)),
            "{message}"
        );
    }

    #[test]
    fn a_folder_is_saved_whole_and_leftovers_are_cleaned() {
        let traj = Dataset::open(&shipped()).unwrap().load("HHLHL").unwrap();
        let dir = tempfile::tempdir().unwrap();
        let root = dir.path();
        // An interrupted earlier run: an unfinished folder, a folder moved aside whose replacement
        // never arrived, and a temporary manifest file.
        fs::create_dir(root.join(".rlpkg-tmp-HHLHL")).unwrap();
        fs::write(root.join(".rlpkg-tmp-HHLHL/tool.csv"), "t\n").unwrap();
        fs::create_dir(root.join(".rlpkg-old-X")).unwrap();
        fs::write(root.join(".rlpkg-old-X/meta.toml"), "").unwrap();
        fs::write(root.join(".manifest.toml.a1B2c3"), "").unwrap();
        fs::write(root.join("notes.txt"), "kept").unwrap();
        let done = clean_leftovers(root).unwrap();
        assert_eq!(done.len(), 3, "{done:?}");
        let mut left: Vec<String> = fs::read_dir(root)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        left.sort();
        assert_eq!(left, ["X", "notes.txt"]);
        assert!(root.join("X/meta.toml").is_file());

        let target = traj.save_folder(root).unwrap();
        assert_eq!(load_trajectory(&target).unwrap(), traj);
        // Saving again replaces the folder and leaves nothing beside it.
        fs::write(target.join("stale.txt"), "").unwrap();
        traj.save_folder(root).unwrap();
        assert!(!target.join("stale.txt").exists());
        assert!(!root.join(".rlpkg-old-HHLHL").exists() && !root.join(".rlpkg-tmp-HHLHL").exists());
        // A file where the folder should go is refused and left alone.
        fs::remove_dir_all(&target).unwrap();
        fs::write(&target, "not a folder").unwrap();
        let message = traj.save_folder(root).unwrap_err().to_string();
        assert!(
            message.contains("HHLHL: exists and is not a folder"),
            "{message}"
        );
        assert!(!root.join(".rlpkg-tmp-HHLHL").exists());
    }

    #[test]
    fn an_unknown_meta_key_is_rejected_with_its_line() {
        let (_dir, out) = broken_copy("meta.toml", |t| format!("{t}\nbogus_key = 1\n"));
        let original = fs::read_to_string(shipped().join("HHLHL/meta.toml")).unwrap();
        let bogus_line = original.lines().count() + 2;
        let message = load_trajectory(&out).unwrap_err().to_string();
        assert!(
            message.contains(&format!("meta.toml:{bogus_line}:")),
            "{message}"
        );
        assert!(message.contains("bogus_key"), "{message}");
    }
}
