//! The files of a posterior folder, read and written here only:
//!
//! * `samples.csv`: a header of parameter names (`k_tri_e`, ..., as the simulator names them),
//!   then one row per draw, SI values. Written by `rlpkg posterior` and by `rlpkg calibrate` with
//!   `[smc]`; read by `rlpkg eval --params`, `rlpkg posterior --validate` and the transport task's
//!   `randomization.package.posterior`.
//! * `summary.json`: the calibration config and folder the draws came from (what a reader needs to
//!   rebuild the scene they are parameters of), then the posterior's own summary.
//!
//! A reader is given the folder or either file ([`locate`]); every value is checked against the
//! simulator's range of its parameter when read, and a bad cell is named by file, line and column.

use std::path::{Path, PathBuf};

use serde::Serialize;

use rlpkg_sim::config::PARAM_NAMES;
use rlpkg_sim::{Params, PosteriorDraws, SceneConfig};

use crate::config::CalibrateConfig;
use crate::space::ParamSpace;

/// The draws' file of a posterior folder.
pub const SAMPLES_FILE: &str = "samples.csv";
/// The file of a posterior folder naming the calibration it came from.
pub const SUMMARY_FILE: &str = "summary.json";
/// Largest `samples.csv` read (bytes): checked before the file is read.
pub const MAX_SAMPLES_BYTES: u64 = 64 << 20;
/// Largest `summary.json` read (bytes).
const MAX_SUMMARY_BYTES: u64 = 1 << 20;

/// What is wrong with a posterior folder's file.
#[derive(Debug, thiserror::Error)]
pub enum PosteriorFileError {
    /// The file is missing, unreadable, too large or not of the expected kind.
    #[error("{path}: {expected}")]
    File {
        /// The file.
        path: PathBuf,
        /// What was expected of it.
        expected: String,
    },
    /// A cell of `samples.csv`.
    #[error("{file} line {line} column {column}: key `{key}` = {value}: expected {expected}")]
    Cell {
        /// The file as named to the reader.
        file: String,
        /// 1-based line.
        line: usize,
        /// 1-based column.
        column: usize,
        /// The header name (`header`, `row` or `rows` for the table's shape).
        key: String,
        /// The cell as written.
        value: String,
        /// What was expected.
        expected: String,
    },
}

fn file_error(path: &Path, expected: impl Into<String>) -> PosteriorFileError {
    PosteriorFileError::File {
        path: path.to_path_buf(),
        expected: expected.into(),
    }
}

/// The files of the posterior `given` names: its folder, its `summary.json` or its `samples.csv`
/// (any other file is taken as the samples). The summary is `None` when there is none beside
/// the samples.
#[derive(Debug, Clone, PartialEq)]
pub struct PosteriorFiles {
    /// The draws.
    pub samples: PathBuf,
    /// The summary naming the calibration.
    pub summary: Option<PathBuf>,
}

/// The files of the posterior `given` names ([`PosteriorFiles`]).
pub fn locate(given: &Path) -> Result<PosteriorFiles, PosteriorFileError> {
    let folder = if given.is_dir() {
        given.to_path_buf()
    } else if given.is_file() {
        given.parent().unwrap_or(Path::new(".")).to_path_buf()
    } else {
        return Err(file_error(
            given,
            format!(
                "an `rlpkg posterior` output folder, its {SUMMARY_FILE} or its {SAMPLES_FILE} \
                 (not found)"
            ),
        ));
    };
    let named = |name: &str| given.file_name().is_some_and(|f| f == name);
    let samples = if given.is_file() && !named(SUMMARY_FILE) {
        given.to_path_buf()
    } else {
        folder.join(SAMPLES_FILE)
    };
    let summary = folder.join(SUMMARY_FILE);
    let summary = (named(SUMMARY_FILE) || summary.is_file()).then_some(summary);
    Ok(PosteriorFiles { samples, summary })
}

/// The text of `path`, refused unread when larger than `limit` bytes.
fn read_limited(path: &Path, limit: u64, kind: &str) -> Result<String, PosteriorFileError> {
    let size = std::fs::metadata(path)
        .map_err(|e| file_error(path, format!("a readable {kind} ({e})")))?
        .len();
    if size > limit {
        return Err(file_error(
            path,
            format!("a {kind} of at most {} MiB ({size} bytes)", limit >> 20),
        ));
    }
    std::fs::read_to_string(path)
        .map_err(|e| file_error(path, format!("a readable UTF-8 {kind} ({e})")))
}

/// The draws of a `samples.csv`: named columns, SI values.
#[derive(Debug, Clone, PartialEq)]
pub struct Samples {
    /// Parameter names of the columns.
    pub names: Vec<String>,
    /// One row per draw, `names.len()` values each.
    pub rows: Vec<Vec<f64>>,
}

impl Samples {
    /// Parses a `samples.csv`: a header of distinct parameter names, then one row per draw, each
    /// value finite and within its parameter's range ([`Params::range`]; > 0 but for `mu_con`,
    /// which may be 0). `file` names it in messages. A leading byte-order mark is skipped.
    pub fn parse(text: &str, file: &str) -> Result<Self, PosteriorFileError> {
        let bad = |line: usize, column: usize, key: &str, value: &str, expected: &str| {
            PosteriorFileError::Cell {
                file: file.to_string(),
                line,
                column,
                key: key.to_string(),
                value: value.to_string(),
                expected: expected.to_string(),
            }
        };
        // A spreadsheet's UTF-8 export starts with a byte-order mark, which is not part of a name.
        let mut lines = text.strip_prefix('\u{feff}').unwrap_or(text).lines();
        let header = lines.next().unwrap_or("");
        let mut names: Vec<String> = Vec::new();
        for (c, name) in header.split(',').map(str::trim).enumerate() {
            if !PARAM_NAMES.contains(&name) {
                return Err(bad(
                    1,
                    c + 1,
                    "header",
                    &format!("{name:?}"),
                    "a parameter name such as k_tri_e or mu_con",
                ));
            }
            if names.iter().any(|n| n == name) {
                return Err(bad(
                    1,
                    c + 1,
                    "header",
                    &format!("{name:?}"),
                    "each parameter named once",
                ));
            }
            names.push(name.to_string());
        }
        let mut rows = Vec::new();
        for (i, line) in lines.enumerate() {
            let number = i + 2;
            if line.trim().is_empty() {
                continue;
            }
            let cells: Vec<&str> = line.split(',').map(str::trim).collect();
            if cells.len() != names.len() {
                return Err(bad(
                    number,
                    cells.len().min(names.len()) + 1,
                    "row",
                    &format!("{} values", cells.len()),
                    &format!("{} values, one per header name", names.len()),
                ));
            }
            let mut row = Vec::with_capacity(names.len());
            for (c, (cell, name)) in cells.iter().zip(&names).enumerate() {
                let (lo32, hi32) = Params::range(name).expect("a header name is a parameter");
                let (lo, hi) = (f64::from(lo32), f64::from(hi32));
                // A draw is a material: zero stiffness is no film (mu_con = 0 is frictionless).
                let low_ok = |v: f64| if name == "mu_con" { v >= lo } else { v > lo };
                match cell.parse::<f64>().ok() {
                    Some(v) if v.is_finite() && low_ok(v) && v <= hi => row.push(v),
                    _ => {
                        let bound = if name == "mu_con" { "[" } else { "(" };
                        let low = if lo32 == 0.0 {
                            "0".to_string()
                        } else {
                            format!("{lo32:e}")
                        };
                        let expected = format!("a number in {bound}{low}, {hi32:e}]");
                        return Err(bad(number, c + 1, name, cell, &expected));
                    }
                }
            }
            rows.push(row);
        }
        if rows.is_empty() {
            return Err(bad(
                2,
                1,
                "rows",
                "none",
                "at least one draw below the header",
            ));
        }
        Ok(Self { names, rows })
    }

    /// Reads and parses the `samples.csv` at `path` ([`Samples::parse`]), refused unread when
    /// larger than [`MAX_SAMPLES_BYTES`].
    pub fn read(path: &Path) -> Result<Self, PosteriorFileError> {
        let text = read_limited(path, MAX_SAMPLES_BYTES, "posterior file")?;
        Self::parse(&text, &path.display().to_string())
    }

    /// Refuses draws whose columns are not `names` in that order (a posterior of another
    /// calibration).
    pub fn expect_columns(&self, path: &Path, names: &[String]) -> Result<(), PosteriorFileError> {
        if self.names != names {
            return Err(file_error(
                path,
                format!(
                    "the calibration's parameters `{}` as its header (has `{}`)",
                    names.join(","),
                    self.names.join(",")
                ),
            ));
        }
        Ok(())
    }

    /// Reads the `samples.csv` at `path` ([`Samples::read`]) and refuses it unless its columns
    /// are `names` in that order ([`Samples::expect_columns`]).
    pub fn read_columns(path: &Path, names: &[String]) -> Result<Self, PosteriorFileError> {
        let samples = Self::read(path)?;
        samples.expect_columns(path, names)?;
        Ok(samples)
    }

    /// `draws` row indices evenly spaced through the draws (the first one first), refused when
    /// there are fewer; `path` names the file and `option` the count asked for (e.g. `--draws`)
    /// in the message.
    pub fn evenly_spaced_rows(
        &self,
        path: &Path,
        draws: usize,
        option: &str,
    ) -> Result<Vec<usize>, PosteriorFileError> {
        let available = self.rows.len();
        if available < draws {
            return Err(file_error(
                path,
                format!("{available} draws; expected at least {option} {draws}"),
            ));
        }
        Ok((0..draws).map(|i| i * available / draws).collect())
    }

    /// The draws as the simulator's randomisation takes them (single precision).
    pub fn to_draws(&self) -> PosteriorDraws {
        PosteriorDraws {
            names: self.names.clone(),
            rows: self
                .rows
                .iter()
                .map(|r| r.iter().map(|&v| v as f32).collect())
                .collect(),
        }
    }
}

/// `samples.csv` of `draws` (SI values, in `space`'s order).
pub fn samples_csv(space: &ParamSpace, draws: &[Vec<f64>]) -> String {
    let mut text = space.names().join(",");
    text.push('\n');
    for draw in draws {
        let cells: Vec<String> = draw.iter().map(f64::to_string).collect();
        text.push_str(&cells.join(","));
        text.push('\n');
    }
    text
}

/// `summary.json`: the calibration config and folder the posterior came from, the `replayed.csv`
/// files fitted beside its evaluations, then `summary`'s own fields.
pub fn summary_json(
    config: &Path,
    calibration: &Path,
    replays: &[PathBuf],
    summary: &impl Serialize,
) -> Result<String, serde_json::Error> {
    #[derive(Serialize)]
    struct SummaryFile<'a, S: Serialize> {
        config: &'a Path,
        calibration: &'a Path,
        replays: &'a [PathBuf],
        #[serde(flatten)]
        summary: &'a S,
    }
    serde_json::to_string_pretty(&SummaryFile {
        config,
        calibration,
        replays,
        summary,
    })
}

/// The `summary.json` at `path` as JSON.
pub fn read_summary(path: &Path) -> Result<serde_json::Value, PosteriorFileError> {
    let text = read_limited(path, MAX_SUMMARY_BYTES, SUMMARY_FILE)?;
    serde_json::from_str(&text).map_err(|e| {
        file_error(
            path,
            format!("a {SUMMARY_FILE} of `rlpkg posterior` (not JSON: {e})"),
        )
    })
}

/// The calibration a `summary.json` records: its config's path (found from the working folder,
/// else from the summary's folder upwards, [`rlpkg_toml_input::find_relative`]) and the config.
pub fn recorded_calibration(
    summary: &Path,
) -> Result<(PathBuf, CalibrateConfig), PosteriorFileError> {
    let value = read_summary(summary)?;
    let path = value["config"]
        .as_str()
        .map(|c| rlpkg_toml_input::find_relative(Path::new(c), summary))
        .ok_or_else(|| {
            file_error(
                summary,
                format!(
                    "a {SUMMARY_FILE} naming its calibration config (`config`), as `rlpkg \
                     posterior` writes"
                ),
            )
        })?;
    let mut config = CalibrateConfig::load(&path).map_err(|e| {
        file_error(
            summary,
            format!("a calibration config named by `config` that loads: {e}"),
        )
    })?;
    // The preset is named relative to the repository too.
    let preset = rlpkg_toml_input::find_relative(Path::new(&config.sim.preset), &path);
    if preset.exists() {
        config.sim.preset = preset.to_string_lossy().into_owned();
    }
    Ok((path, config))
}

/// The scene the calibration recorded in `summary` simulated: its draws are parameters of that
/// film on that grid at that step ([`CalibrateConfig::scene`]).
pub fn calibrated_scene(summary: &Path) -> Result<SceneConfig, PosteriorFileError> {
    let (path, config) = recorded_calibration(summary)?;
    config.scene(&path).map_err(|e| {
        file_error(
            summary,
            format!("a calibration config whose scene loads: {e}"),
        )
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn samples_are_parsed_with_their_names_and_bad_cells_are_located() {
        let samples = Samples::parse("k_tri_e, mu_con\n1000,0.5\n\n2000,0\n", "s.csv").unwrap();
        assert_eq!(samples.names, ["k_tri_e", "mu_con"]);
        assert_eq!(samples.rows, [vec![1000.0, 0.5], vec![2000.0, 0.0]]);
        assert_eq!(
            samples.to_draws().rows,
            [vec![1000.0, 0.5], vec![2000.0, 0.0]]
        );
        let marked = Samples::parse("\u{feff}k_tri_e,mu_con\n1,0\n", "s.csv").unwrap();
        assert_eq!(marked.names, ["k_tri_e", "mu_con"]);
        for (text, at, value) in [
            ("k_tri_e,k_bogus\n1,2\n", "s.csv line 1 column 2", "k_bogus"),
            (
                "k_tri_e,k_tri_e\n1,2\n",
                "s.csv line 1 column 2",
                "each parameter named once",
            ),
            (
                "k_tri_e,mu_con\n1,0.5\n1\n",
                "s.csv line 3 column 2",
                "1 values",
            ),
            ("k_tri_e,mu_con\n1,0.5\n1,x\n", "s.csv line 3 column 2", "x"),
            (
                "k_tri_e,mu_con\n0,0.5\n",
                "s.csv line 2 column 1",
                "(0, 1e10]",
            ),
            (
                "k_tri_e,mu_con\n1,-0.1\n",
                "s.csv line 2 column 2",
                "[0, 1e2]",
            ),
            ("k_tri_e,mu_con\n1,1e6\n", "s.csv line 2 column 2", "1e6"),
            ("k_tri_e,mu_con\nnan,1\n", "s.csv line 2 column 1", "nan"),
            (
                "k_tri_e,mu_con\n",
                "s.csv line 2 column 1",
                "at least one draw",
            ),
        ] {
            let err = Samples::parse(text, "s.csv").unwrap_err().to_string();
            assert!(err.contains(at) && err.contains(value), "{text:?}: {err}");
        }
    }

    #[test]
    fn a_folder_or_either_file_locates_the_same_posterior() {
        let dir = tempfile::tempdir().unwrap();
        let (samples, summary) = (dir.path().join(SAMPLES_FILE), dir.path().join(SUMMARY_FILE));
        std::fs::write(&samples, "k_tri_e\n1\n").unwrap();
        assert_eq!(
            locate(dir.path()).unwrap(),
            PosteriorFiles {
                samples: samples.clone(),
                summary: None
            }
        );
        std::fs::write(&summary, "{}").unwrap();
        for given in [dir.path(), samples.as_path(), summary.as_path()] {
            let files = locate(given).unwrap();
            assert_eq!(files.samples, samples);
            assert_eq!(files.summary.as_deref(), Some(summary.as_path()));
        }
        let missing = locate(&dir.path().join("none")).unwrap_err().to_string();
        assert!(
            missing.contains("none") && missing.contains("not found"),
            "{missing}"
        );
        let err = recorded_calibration(&summary).unwrap_err().to_string();
        assert!(err.contains("`config`"), "{err}");
    }

    #[test]
    fn written_samples_read_back_with_their_columns() {
        let space = ParamSpace::new(vec![
            crate::space::ParamSpec {
                name: "k_tri_e".into(),
                lower: 1e3,
                upper: 1e5,
                log: true,
            },
            crate::space::ParamSpec {
                name: "mu_con".into(),
                lower: 0.1,
                upper: 2.0,
                log: false,
            },
        ])
        .unwrap();
        let draws = vec![vec![1234.5, 0.25], vec![5.0e4, 1.5]];
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join(SAMPLES_FILE);
        std::fs::write(&path, samples_csv(&space, &draws)).unwrap();
        let back = Samples::read(&path).unwrap();
        assert_eq!(back.rows, draws);
        let names: Vec<String> = space.names().iter().map(|n| n.to_string()).collect();
        back.expect_columns(&path, &names).unwrap();
        let other = back
            .expect_columns(&path, &names[..1])
            .unwrap_err()
            .to_string();
        assert!(other.contains("k_tri_e,mu_con"), "{other}");
        assert!(Samples::read_columns(&path, &names).is_ok());
        let err = Samples::read_columns(&path, &names[1..])
            .unwrap_err()
            .to_string();
        assert!(err.contains("has `k_tri_e,mu_con`"), "{err}");
    }

    #[test]
    fn rows_are_spread_evenly_and_too_many_are_refused() {
        let samples = Samples {
            names: vec!["k_tri_e".into()],
            rows: (1..=10).map(|v| vec![f64::from(v)]).collect(),
        };
        let path = Path::new("s.csv");
        assert_eq!(
            samples.evenly_spaced_rows(path, 4, "--draws").unwrap(),
            [0, 2, 5, 7]
        );
        assert_eq!(
            samples.evenly_spaced_rows(path, 10, "--draws").unwrap(),
            (0..10).collect::<Vec<_>>()
        );
        let err = samples
            .evenly_spaced_rows(path, 11, "--validate")
            .unwrap_err()
            .to_string();
        assert_eq!(err, "s.csv: 10 draws; expected at least --validate 11");
    }
}
