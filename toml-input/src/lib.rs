//! Reading the TOML files of rlpkg (scene presets, configurations, `configs/import/motive.toml`,
//! `manifest.toml`, `meta.toml`): fixed-length arrays that must have exactly their length, and
//! parse errors that name the line and the key. Shared by the simulator and the motion-capture
//! crate, which do not depend on each other.
//!
//! serde fills `[T; N]` from the first N values of a longer TOML array and drops the rest, so
//! `grid = [16, 19, 3]` would silently run as 16 x 19. Read such fields through
//! `#[serde(deserialize_with = "rlpkg_toml_input::array")]` (or `option`, `list`, `map`); the
//! parser's message then says `invalid length 3, expected an array of length 2` at the key's line.
//!
//! Configurations compose: `extends = "base.toml"` starts a file from another ([`read_composed`]).

#![warn(missing_docs)]

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Deserializer};

mod compose;

pub use compose::{
    merge, read_composed, ComposeError, Composed, EXTENDS, MAX_DEPTH, MAX_FILE_BYTES,
};

/// An array read through a `Vec`, so that its length is checked.
struct Exact<T, const N: usize>([T; N]);

impl<'de, T: Deserialize<'de>, const N: usize> Deserialize<'de> for Exact<T, N> {
    fn deserialize<D: Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
        let values = Vec::<T>::deserialize(deserializer)?;
        let len = values.len();
        values.try_into().map(Exact).map_err(|_| {
            serde::de::Error::invalid_length(len, &format!("an array of length {N}").as_str())
        })
    }
}

/// `[T; N]` with exactly `N` values.
pub fn array<'de, D, T, const N: usize>(deserializer: D) -> Result<[T; N], D::Error>
where
    D: Deserializer<'de>,
    T: Deserialize<'de>,
{
    Exact::deserialize(deserializer).map(|exact| exact.0)
}

/// An optional `[T; N]` with exactly `N` values (pair with `#[serde(default)]`).
pub fn option<'de, D, T, const N: usize>(deserializer: D) -> Result<Option<[T; N]>, D::Error>
where
    D: Deserializer<'de>,
    T: Deserialize<'de>,
{
    Option::<Exact<T, N>>::deserialize(deserializer).map(|exact| exact.map(|e| e.0))
}

/// A list of `[T; N]` with exactly `N` values each.
pub fn list<'de, D, T, const N: usize>(deserializer: D) -> Result<Vec<[T; N]>, D::Error>
where
    D: Deserializer<'de>,
    T: Deserialize<'de>,
{
    Vec::<Exact<T, N>>::deserialize(deserializer)
        .map(|list| list.into_iter().map(|e| e.0).collect())
}

/// A table of `[T; N]` with exactly `N` values each.
pub fn map<'de, D, T, const N: usize>(deserializer: D) -> Result<BTreeMap<String, [T; N]>, D::Error>
where
    D: Deserializer<'de>,
    T: Deserialize<'de>,
{
    BTreeMap::<String, Exact<T, N>>::deserialize(deserializer)
        .map(|table| table.into_iter().map(|(k, v)| (k, v.0)).collect())
}

/// Where a relative path named by the file `file` is found: as given when it is absolute or
/// exists from the working folder, else from the file's folder or the first of its parents where
/// it exists (a configuration in the repository's `configs/train/` names paths relative to the
/// repository), else as given (so that the error names the path the user wrote).
pub fn find_relative(path: &Path, file: &Path) -> PathBuf {
    if path.is_absolute() || path.exists() {
        return path.to_path_buf();
    }
    let Some(folder) = file.parent().and_then(|f| {
        let f = if f.as_os_str().is_empty() {
            Path::new(".")
        } else {
            f
        };
        f.canonicalize().ok()
    }) else {
        return path.to_path_buf();
    };
    folder
        .ancestors()
        .map(|dir| dir.join(path))
        .find(|candidate| candidate.exists())
        .unwrap_or_else(|| path.to_path_buf())
}

/// The 1-based line of a parse error of `text` and its message, which names the key when the
/// error points into a value: `` key `package.size_m`: invalid length 1, ... ``.
pub fn error_at(text: &str, err: &toml::de::Error) -> (usize, String) {
    let Some(at) = err.span().map(|span| span.start.min(text.len())) else {
        return (1, err.message().to_string());
    };
    let line = text[..at].matches('\n').count() + 1;
    let message = match key_before(text, at) {
        Some(key) => format!("key `{key}`: {}", err.message()),
        None => err.message().to_string(),
    };
    (line, message)
}

/// The dotted key whose value holds byte `at` of `text` (with its `[table]`), if `at` lies in a
/// value: found by walking back over the arrays that close before `at` to the `=`, on the same
/// line unless an array that holds `at` spans lines.
fn key_before(text: &str, at: usize) -> Option<String> {
    let (mut closed, mut enclosing) = (0usize, 0usize);
    let mut equals = None;
    for (i, c) in text[..at].char_indices().rev() {
        match c {
            ']' => closed += 1,
            '[' if closed > 0 => closed -= 1,
            '[' => enclosing += 1,
            '\n' if enclosing == 0 => return None,
            '=' if closed == 0 => {
                equals = Some(i);
                break;
            }
            _ => {}
        }
    }
    let equals = equals?;
    let line_start = text[..equals].rfind('\n').map_or(0, |i| i + 1);
    let key = text[line_start..equals]
        .rsplit([',', '{'])
        .next()?
        .trim()
        .trim_matches('"');
    if key.is_empty() {
        return None;
    }
    // The innermost `[table]` header above the key's line.
    let table = text[..line_start].lines().rev().find_map(|l| {
        let l = l.trim();
        (l.starts_with('[') && !l.starts_with("[[") && l.ends_with(']'))
            .then(|| l.trim_matches(['[', ']']).trim())
    });
    Some(match table {
        Some(table) => format!("{table}.{key}"),
        None => key.to_string(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_relative_path_is_found_from_the_working_folder_then_the_files_folder_upwards() {
        let root = std::env::temp_dir().join(format!("rlpkg-find-relative-{}", std::process::id()));
        let configs = root.join("configs/train");
        std::fs::create_dir_all(&configs).unwrap();
        std::fs::create_dir_all(root.join("data/x")).unwrap();
        let file = configs.join("job.toml");
        std::fs::write(&file, "").unwrap();
        let found = find_relative(Path::new("data/x"), &file);
        assert_eq!(found, root.canonicalize().unwrap().join("data/x"));
        // Not found anywhere: as written.
        assert_eq!(
            find_relative(Path::new("data/none"), &file),
            PathBuf::from("data/none")
        );
        // Found from the working folder first (this crate's own manifest).
        assert_eq!(
            find_relative(Path::new("Cargo.toml"), &file),
            PathBuf::from("Cargo.toml")
        );
        std::fs::remove_dir_all(&root).unwrap();
    }

    #[derive(Debug, Deserialize)]
    #[serde(deny_unknown_fields)]
    struct Fixed {
        #[serde(deserialize_with = "array")]
        size: [f64; 2],
        #[serde(default, deserialize_with = "option")]
        rotation: Option<[f64; 4]>,
        #[serde(default, deserialize_with = "list")]
        points: Vec<[f64; 3]>,
        #[serde(default, deserialize_with = "map")]
        scales: BTreeMap<String, [f32; 2]>,
        #[serde(default)]
        table: Option<Inner>,
    }

    #[derive(Debug, Deserialize)]
    struct Inner {
        #[serde(deserialize_with = "array")]
        offset: [f64; 3],
    }

    #[test]
    fn exactly_n_values_are_read() {
        let text = "size = [1.0, 2.0]\nrotation = [0.0, 0.0, 0.0, 1.0]\npoints = [[1.0, 2.0, 3.0]]\nscales = { a = [1.0, 2.0] }\n[table]\noffset = [0.0, 0.5, 0.0]\n";
        let fixed: Fixed = toml::from_str(text).unwrap();
        assert_eq!(fixed.size, [1.0, 2.0]);
        assert_eq!(fixed.rotation, Some([0.0, 0.0, 0.0, 1.0]));
        assert_eq!(fixed.points, [[1.0, 2.0, 3.0]]);
        assert_eq!(fixed.scales["a"], [1.0, 2.0]);
        assert_eq!(fixed.table.unwrap().offset, [0.0, 0.5, 0.0]);
        let bare: Fixed = toml::from_str("size = [1.0, 2.0]").unwrap();
        assert_eq!(
            (bare.rotation, bare.points.len(), bare.scales.len()),
            (None, 0, 0)
        );
        let err = toml::from_str::<Fixed>("size = [1.0, 2.0]\nscales = { a = [1.0] }")
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("scales = { a = [1.0] }") && err.contains("expected an array of length 2"),
            "{err}"
        );
    }

    fn error(text: &str) -> (usize, String) {
        let err = toml::from_str::<Fixed>(text).unwrap_err();
        error_at(text, &err)
    }

    #[test]
    fn wrong_lengths_name_line_key_and_expected_length() {
        for (text, line, expected) in [
            (
                "size = [1.0, 2.0, 3.0]\n",
                1,
                "key `size`: invalid length 3, expected an array of length 2",
            ),
            (
                "size = [1.0, 2.0]\nrotation = [0.0, 0.0, 1.0]\n",
                2,
                "key `rotation`: invalid length 3, expected an array of length 4",
            ),
            (
                "size = [1.0, 2.0]\npoints = [[1.0, 2.0, 3.0], [1.0, 2.0, 3.0, 4.0]]\n",
                2,
                "key `points`: invalid length 4, expected an array of length 3",
            ),
            // A value over several lines: the line of its key.
            (
                "size = [1.0, 2.0]\npoints = [\n  [1.0, 2.0, 3.0],\n  [1.0, 2.0],\n]\n",
                2,
                "key `points`: invalid length 2, expected an array of length 3",
            ),
            (
                "size = [1.0, 2.0]\n\n[table]\noffset = [0.0, 0.0]\n",
                4,
                "key `table.offset`: invalid length 2, expected an array of length 3",
            ),
            // An unknown key is named by the parser; no value holds the error.
            (
                "size = [1.0, 2.0]\nbogus = 1\n",
                2,
                "unknown field `bogus`, expected one of `size`, `rotation`, `points`, `scales`, `table`",
            ),
        ] {
            assert_eq!(error(text), (line, expected.to_string()), "{text}");
        }
    }
}
