//! Configurations that compose: a file may start from another with `extends = "base.toml"` (a
//! path relative to the file's own folder) and then give only what it changes. Tables merge key
//! by key, the file's values over its base's; any other value, arrays and arrays of tables
//! included, replaces the base's whole. A base may extend another, up to [`MAX_DEPTH`] files.
//!
//! The merged configuration is self-contained text ([`Composed::text`]): a run folder keeps it,
//! so that what was run never depends on the base files staying as they were. A file that
//! extends nothing is kept exactly as written, comments and line numbers included.

use std::fmt;
use std::path::{Path, PathBuf};

use toml::{Table, Value};

/// The key that names a configuration's base.
pub const EXTENDS: &str = "extends";

/// The longest chain of files one configuration may be composed of.
pub const MAX_DEPTH: usize = 8;

/// The largest configuration file read: far beyond any configuration, and a bound on what a
/// file named by mistake can make this allocate.
pub const MAX_FILE_BYTES: u64 = 16 << 20;

/// A configuration with its bases merged in.
#[derive(Debug, Clone, PartialEq)]
pub struct Composed {
    /// The merged table, without the `extends` keys.
    pub table: Table,
    /// The files read: the one named first, then its base, its base's base, ...
    pub files: Vec<PathBuf>,
    /// The configuration as text: the file's own when it extends nothing, else the merged table
    /// headed by a comment naming the files.
    pub text: String,
}

impl Composed {
    /// Whether the configuration came from more than one file (then [`Composed::text`] is the
    /// merged table, whose line numbers are none of the files').
    pub fn is_merged(&self) -> bool {
        self.files.len() > 1
    }

    /// Why the merged text does not parse as `T`, naming the key and the chain of files (the
    /// merged text's line numbers are none of the files'); `None` when it parses.
    pub fn merged_error<T: serde::de::DeserializeOwned>(&self) -> Option<String> {
        let e = toml::from_str::<T>(&self.text).err()?;
        let (_, message) = crate::error_at(&self.text, &e);
        Some(format!("{message} (in {}, merged)", self.chain()))
    }

    /// "`a.toml` extending `b.toml`, `c.toml`": the chain, for messages.
    pub fn chain(&self) -> String {
        let mut names = self.files.iter().map(|f| f.display().to_string());
        let first = names.next().unwrap_or_default();
        let rest: Vec<String> = names.collect();
        if rest.is_empty() {
            first
        } else {
            format!("{first} extending {}", rest.join(", "))
        }
    }
}

/// Why a configuration could not be composed. Each names the file at fault.
#[derive(Debug, Clone, PartialEq)]
pub enum ComposeError {
    /// The file could not be read, or is not UTF-8 text.
    Read {
        /// The file.
        file: PathBuf,
        /// What went wrong.
        message: String,
    },
    /// The file is not TOML (the parser's message names the line).
    Parse {
        /// The file.
        file: PathBuf,
        /// The parser's message.
        message: String,
    },
    /// The file's `extends` key is not a readable base.
    Extends {
        /// The file holding the key.
        file: PathBuf,
        /// The value found.
        value: String,
        /// What the key should hold.
        expected: String,
    },
}

impl ComposeError {
    /// The file at fault.
    pub fn file(&self) -> &Path {
        match self {
            ComposeError::Read { file, .. }
            | ComposeError::Parse { file, .. }
            | ComposeError::Extends { file, .. } => file,
        }
    }

    /// The message without the file's name.
    pub fn message(&self) -> String {
        match self {
            ComposeError::Read { message, .. } | ComposeError::Parse { message, .. } => {
                message.clone()
            }
            ComposeError::Extends {
                value, expected, ..
            } => format!("key `{EXTENDS}` = {value}: expected {expected}"),
        }
    }
}

impl fmt::Display for ComposeError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}: {}", self.file().display(), self.message())
    }
}

impl std::error::Error for ComposeError {}

/// Reads the configuration at `path` with its bases merged in.
pub fn read_composed(path: &Path) -> Result<Composed, ComposeError> {
    let own_text = read_text(path)?;
    let mut files = vec![path.to_path_buf()];
    let mut layers = vec![parse(&own_text, path)?];
    // Canonical paths of the files read so far, to refuse a chain that comes back.
    let mut seen = vec![path.canonicalize().unwrap_or_else(|_| path.to_path_buf())];
    while let Some(value) = layers.last_mut().and_then(|t| t.remove(EXTENDS)) {
        let holder = files.last().cloned().unwrap_or_default();
        let fail = |value: String, expected: String| ComposeError::Extends {
            file: holder.clone(),
            value,
            expected,
        };
        let Value::String(name) = value else {
            return Err(fail(
                value.to_string(),
                "the path of the configuration this one starts from, as a string".into(),
            ));
        };
        if files.len() == MAX_DEPTH {
            return Err(fail(
                format!("{name:?}"),
                format!("a chain of at most {MAX_DEPTH} files"),
            ));
        }
        let base = holder.parent().unwrap_or(Path::new("")).join(&name);
        let canonical = base.canonicalize().map_err(|e| {
            fail(
                format!("{name:?}"),
                format!(
                    "a configuration file, relative to {}'s folder ({}: {e})",
                    holder.display(),
                    base.display()
                ),
            )
        })?;
        if seen.contains(&canonical) {
            return Err(fail(
                format!("{name:?}"),
                "a file not already in the chain (it extends itself through its bases)".into(),
            ));
        }
        seen.push(canonical);
        layers.push(parse(&read_text(&base)?, &base)?);
        files.push(base);
    }
    let mut layers = layers.into_iter().rev();
    let mut table = layers.next().unwrap_or_default();
    for layer in layers {
        merge(&mut table, layer);
    }
    let text = if files.len() == 1 {
        own_text
    } else {
        let chain: Vec<String> = files.iter().map(|f| f.display().to_string()).collect();
        format!(
            "# {}, merged with its bases ({}).\n{}",
            chain[0],
            chain[1..].join(", "),
            toml::to_string(&table).map_err(|e| ComposeError::Parse {
                file: path.to_path_buf(),
                message: e.to_string(),
            })?
        )
    };
    Ok(Composed { table, files, text })
}

/// `over`'s keys merged into `base`: tables key by key, any other value replacing the base's.
pub fn merge(base: &mut Table, over: Table) {
    for (key, value) in over {
        match (base.get_mut(&key), value) {
            (Some(Value::Table(inner)), Value::Table(value)) => merge(inner, value),
            (_, value) => {
                base.insert(key, value);
            }
        }
    }
}

fn read_text(path: &Path) -> Result<String, ComposeError> {
    let fail = |message: String| ComposeError::Read {
        file: path.to_path_buf(),
        message,
    };
    let size = std::fs::metadata(path)
        .map_err(|e| fail(e.to_string()))?
        .len();
    if size > MAX_FILE_BYTES {
        return Err(fail(format!(
            "{size} bytes; expected a TOML configuration of at most {MAX_FILE_BYTES} bytes"
        )));
    }
    let bytes = std::fs::read(path).map_err(|e| fail(e.to_string()))?;
    String::from_utf8(bytes).map_err(|e| {
        fail(format!(
            "not UTF-8 text (byte {}); expected a TOML configuration",
            e.utf8_error().valid_up_to()
        ))
    })
}

fn parse(text: &str, path: &Path) -> Result<Table, ComposeError> {
    text.parse::<Table>().map_err(|e| ComposeError::Parse {
        file: path.to_path_buf(),
        message: e.to_string().trim_end().to_string(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A fresh folder holding `files` (name, text).
    fn folder(name: &str, files: &[(&str, &str)]) -> PathBuf {
        let dir = std::env::temp_dir().join(format!("rlpkg-compose-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        for (file, text) in files {
            let path = dir.join(file);
            std::fs::create_dir_all(path.parent().unwrap()).unwrap();
            std::fs::write(path, text).unwrap();
        }
        dir
    }

    #[test]
    fn a_file_overrides_its_bases_key_by_key_and_replaces_arrays_whole() {
        let dir = folder(
            "merge",
            &[
                (
                    "base/root.toml",
                    "[run]\nseed = 1\nnum_envs = 8\n[ppo]\nlr = 1e-3\nhidden = [64, 64]\n[[param]]\nname = \"a\"\n[[param]]\nname = \"b\"\n",
                ),
                (
                    "base/mid.toml",
                    "extends = \"root.toml\"\n[run]\nseed = 2\n[ppo.schedule]\nkind = \"linear\"\n",
                ),
                (
                    "job.toml",
                    "# a job\nextends = \"base/mid.toml\"\n[ppo]\nhidden = [32]\n[[param]]\nname = \"c\"\n",
                ),
            ],
        );
        let composed = read_composed(&dir.join("job.toml")).unwrap();
        let expected: Table = "[run]\nseed = 2\nnum_envs = 8\n[ppo]\nlr = 1e-3\nhidden = [32]\n[ppo.schedule]\nkind = \"linear\"\n[[param]]\nname = \"c\"\n"
            .parse()
            .unwrap();
        assert_eq!(composed.table, expected);
        assert_eq!(
            composed.files,
            [
                dir.join("job.toml"),
                dir.join("base/mid.toml"),
                dir.join("base/root.toml")
            ]
        );
        assert!(composed.is_merged());
        // The text is self-contained: it parses back to the same table and names no base.
        assert_eq!(composed.text.parse::<Table>().unwrap(), expected);
        assert!(composed.text.starts_with('#'), "{}", composed.text);
        // A file without `extends` is its own text, comments and all.
        let root = read_composed(&dir.join("base/root.toml")).unwrap();
        assert_eq!(
            root.text,
            std::fs::read_to_string(dir.join("base/root.toml")).unwrap()
        );
        assert!(!root.is_merged());
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn a_bad_chain_names_the_file_and_the_key() {
        let dir = folder(
            "bad",
            &[
                ("loop-a.toml", "extends = \"loop-b.toml\"\n"),
                ("loop-b.toml", "extends = \"loop-a.toml\"\n"),
                ("self.toml", "extends = \"./self.toml\"\n"),
                ("missing.toml", "extends = \"nowhere.toml\"\n"),
                ("number.toml", "extends = 3\n"),
                ("broken-base.toml", "extends = \"broken.toml\"\n"),
                ("broken.toml", "[run\n"),
                ("binary.toml", ""),
            ],
        );
        let err = |name: &str| read_composed(&dir.join(name)).unwrap_err();
        let e = err("loop-a.toml");
        assert_eq!(e.file(), dir.join("loop-b.toml"));
        assert!(e.to_string().contains("already in the chain"), "{e}");
        assert!(err("self.toml")
            .to_string()
            .contains("already in the chain"));
        let e = err("missing.toml").to_string();
        assert!(
            e.contains("missing.toml: key `extends` = \"nowhere.toml\"") && e.contains("folder"),
            "{e}"
        );
        let e = err("number.toml").to_string();
        assert!(e.contains("key `extends` = 3: expected the path"), "{e}");
        let e = err("broken-base.toml");
        assert!(
            matches!(e, ComposeError::Parse { .. }) && e.file() == dir.join("broken.toml"),
            "{e}"
        );
        assert!(e.to_string().contains("line 1"), "{e}");
        std::fs::write(dir.join("binary.toml"), [b'a', 0xff, 0xfe]).unwrap();
        assert!(err("binary.toml").to_string().contains("not UTF-8"));
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn a_chain_longer_than_the_limit_is_refused() {
        let files: Vec<(String, String)> = (0..=MAX_DEPTH)
            .map(|i| {
                (
                    format!("c{i}.toml"),
                    format!("extends = \"c{}.toml\"\n", i + 1),
                )
            })
            .collect();
        let refs: Vec<(&str, &str)> = files
            .iter()
            .map(|(n, t)| (n.as_str(), t.as_str()))
            .collect();
        let dir = folder("deep", &refs);
        let e = read_composed(&dir.join("c0.toml")).unwrap_err().to_string();
        assert!(e.contains(&format!("at most {MAX_DEPTH} files")), "{e}");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
