//! `--set KEY=VALUE`: one value of a TOML configuration replaced (or added) on the command line,
//! so that a sweep needs no rewritten files.
//!
//! The overrides edit the file's parsed table ([`toml::Table`], the workspace's TOML crate: keys
//! come back sorted and comments are dropped), and the merged table is written back as text that
//! is then checked like any file. A run folder keeps that text as its `config.toml`,
//! headed by a comment naming the file and the overrides, so it says exactly what was run.

use std::fmt;
use std::str::FromStr;

use toml::{Table, Value};

/// One `--set KEY=VALUE`: a dotted key path and the TOML value to put there.
#[derive(Debug, Clone, PartialEq)]
pub struct Override {
    /// The option as given, e.g. `ppo.learning_rate=1e-4` (named in messages).
    given: String,
    /// The key path, e.g. `["ppo", "learning_rate"]`.
    path: Vec<String>,
    /// The value, e.g. `1e-4`.
    value: Value,
}

impl fmt::Display for Override {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "--set {}", self.given)
    }
}

impl FromStr for Override {
    type Err = String;

    /// Parses `KEY=VALUE`: KEY a dotted TOML key (`ppo.learning_rate`, `transport."a.b"`), VALUE a
    /// TOML value (`1e-4`, `true`, `"tanh"`, `[64, 64]`) or, when it is not one, a bare word taken
    /// as a string (`tanh`).
    fn from_str(given: &str) -> Result<Self, Self::Err> {
        let expected = "expected KEY=VALUE with a dotted key, e.g. ppo.learning_rate=1e-4";
        let (key, value) = given
            .split_once('=')
            .ok_or_else(|| format!("`{given}`: no `=`; {expected}"))?;
        let key = key.trim();
        if key.is_empty() {
            return Err(format!("`{given}`: no key before `=`; {expected}"));
        }
        let path = parse_key(key).ok_or_else(|| {
            format!("`{given}`: `{key}` is not a TOML key (dotted bare or quoted keys); {expected}")
        })?;
        let value = value.trim();
        // A line `v = VALUE` parses exactly the values a file may hold.
        let value = format!("v = {value}")
            .parse::<Table>()
            .ok()
            .and_then(|mut t| t.remove("v"))
            .unwrap_or_else(|| Value::String(value.to_string()));
        Ok(Self {
            given: given.to_string(),
            path,
            value,
        })
    }
}

/// The parts of a dotted TOML key (`a."b.c"` gives `a`, `b.c`), or `None` when `key` is not one.
/// The key is parsed by the TOML parser itself, as the key of a one-line document.
fn parse_key(key: &str) -> Option<Vec<String>> {
    let mut table = format!("{key} = 0").parse::<Table>().ok()?;
    let mut path = Vec::new();
    loop {
        if table.len() != 1 {
            return None;
        }
        let (name, value) = table.into_iter().next()?;
        path.push(name);
        match value {
            Value::Table(inner) => table = inner,
            Value::Integer(0) => return Some(path),
            _ => return None,
        }
    }
}

/// `text` (the file named `source`) with every override applied in order (a key set twice is
/// refused, naming both options: on a command line it is a slip, not a choice), written back as TOML text headed by a comment naming `source` and the
/// overrides. A key may be new (its table decides whether it is known); a table that does not
/// exist yet is added. Replacing a table by a value, or a path through a value, is refused,
/// naming the option.
pub fn apply(text: &str, source: &str, overrides: &[Override]) -> Result<String, String> {
    let mut table: Table = text
        .parse()
        .map_err(|e: toml::de::Error| format!("{source}: {}", e.to_string().trim_end()))?;
    for (i, one) in overrides.iter().enumerate() {
        if let Some(first) = overrides[..i].iter().find(|o| o.path == one.path) {
            return Err(format!(
                "{one}: `{}` is already set by {first}; expected each key once",
                one.path.join(".")
            ));
        }
        set(&mut table, one).map_err(|reason| format!("{one}: {reason}"))?;
    }
    let body = toml::to_string(&table).map_err(|e| format!("{source}: {e}"))?;
    let sets: Vec<String> = overrides.iter().map(ToString::to_string).collect();
    Ok(format!("# {source} {}\n{body}", sets.join(" ")))
}

/// Puts `one.value` at `one.path` under `root`.
fn set(root: &mut Table, one: &Override) -> Result<(), String> {
    let (last, parents) = one
        .path
        .split_last()
        .expect("parse_key gives one key or more");
    let mut table = root;
    for (depth, key) in parents.iter().enumerate() {
        let item = table
            .entry(key.clone())
            .or_insert_with(|| Value::Table(Table::new()));
        let type_name = item.type_str();
        table = match item {
            Value::Table(inner) => inner,
            _ => {
                return Err(format!(
                    "`{}` is a value ({type_name}), not a table: no key under it can be set",
                    parents[..=depth].join(".")
                ))
            }
        };
    }
    match table.get(last) {
        Some(Value::Table(_)) => Err(format!(
            "`{0}` is a table; set one of its keys, e.g. --set {0}.<key>=VALUE",
            one.path.join(".")
        )),
        Some(Value::Array(items)) if items.iter().any(Value::is_table) => Err(format!(
            "`{}` is an array of tables; it cannot be set from the command line",
            one.path.join(".")
        )),
        _ => {
            table.insert(last.clone(), one.value.clone());
            Ok(())
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const CONFIG: &str =
        "# A training file.\n[run]\nseed = 3  # the seed\nenv = \"CartPole-v1\"\n\n\
                          [ppo]\nlearning_rate = 1e-3\n\n[policy]\nactor_hidden = [16, 16]\n\
                          activation = \"tanh\"\n";

    fn applied(sets: &[&str]) -> Result<Table, String> {
        let overrides: Vec<Override> = sets.iter().map(|s| s.parse()).collect::<Result<_, _>>()?;
        let text = apply(CONFIG, "train.toml", &overrides)?;
        Ok(text.parse().unwrap())
    }

    #[test]
    fn values_are_replaced_and_the_rest_kept() {
        let doc = applied(&["run.seed=5", "ppo.learning_rate=5e-4"]).unwrap();
        let mut expected: Table = CONFIG.parse().unwrap();
        expected["run"]["seed"] = Value::Integer(5);
        expected["ppo"]["learning_rate"] = Value::Float(5e-4);
        assert_eq!(doc, expected);
    }

    #[test]
    fn the_text_names_the_file_and_the_overrides() {
        let set: Vec<Override> = vec!["run.seed=5".parse().unwrap()];
        let text = apply(CONFIG, "train.toml", &set).unwrap();
        assert!(
            text.starts_with("# train.toml --set run.seed=5\n"),
            "{text}"
        );
        assert!(text.contains("\nseed = 5\n"), "{text}");
    }

    #[test]
    fn a_key_set_twice_is_refused_naming_both_options() {
        let err = applied(&["run.seed=5", "ppo.epochs=4", "run . seed = 7"]).unwrap_err();
        assert!(
            err.contains("--set run . seed = 7") && err.contains("already set by --set run.seed=5"),
            "{err}"
        );
        assert!(applied(&["run.seed=5", "run.env=x"]).is_ok());
    }

    #[test]
    fn a_new_key_is_added_to_its_table_and_a_missing_table_is_added() {
        let doc = applied(&["ppo.epochs=4", "transport.reward.scale=2.5"]).unwrap();
        assert_eq!(doc["ppo"]["epochs"].as_integer(), Some(4));
        assert_eq!(doc["ppo"]["learning_rate"].as_float(), Some(1e-3));
        assert_eq!(doc["transport"]["reward"]["scale"].as_float(), Some(2.5));
    }

    #[test]
    fn arrays_strings_and_bare_words() {
        let doc = applied(&[
            "policy.actor_hidden=[64, 64]",
            "policy.activation=relu",
            "run.env=\"Pendulum-v1\"",
        ])
        .unwrap();
        let widths: Vec<i64> = doc["policy"]["actor_hidden"]
            .as_array()
            .unwrap()
            .iter()
            .map(|w| w.as_integer().unwrap())
            .collect();
        assert_eq!(widths, [64, 64]);
        assert_eq!(doc["policy"]["activation"].as_str(), Some("relu"));
        assert_eq!(doc["run"]["env"].as_str(), Some("Pendulum-v1"));
        // A bare word that is not TOML is a string, which the configuration's types then check.
        let doc = applied(&["run.seed=abc"]).unwrap();
        assert_eq!(doc["run"]["seed"].as_str(), Some("abc"));
    }

    #[test]
    fn quoted_keys_and_inline_tables() {
        let config = "[scene]\nsize = { x = 1.0, y = 2.0 }\n";
        let set: Vec<Override> = vec![
            "scene.size.y=3.0".parse().unwrap(),
            "scene.\"a.b\"=1".parse().unwrap(),
        ];
        let doc: Table = apply(config, "s.toml", &set).unwrap().parse().unwrap();
        assert_eq!(doc["scene"]["size"]["y"].as_float(), Some(3.0));
        assert_eq!(doc["scene"]["size"]["x"].as_float(), Some(1.0));
        assert_eq!(doc["scene"]["a.b"].as_integer(), Some(1));
    }

    #[test]
    fn malformed_options_are_refused() {
        for (given, reason) in [
            ("ppo.learning_rate", "no `=`"),
            ("=3", "no key"),
            (" =3", "no key"),
            ("ppo..x=3", "not a TOML key"),
            ("ppo x=3", "not a TOML key"),
        ] {
            let err = given.parse::<Override>().unwrap_err();
            assert!(err.contains(given) && err.contains(reason), "{err}");
        }
    }

    #[test]
    fn a_table_is_not_replaced_and_a_value_has_no_keys() {
        let err = applied(&["ppo=3"]).unwrap_err();
        assert!(err.starts_with("--set ppo=3: `ppo` is a table"), "{err}");
        let err = applied(&["run.seed.x=1"]).unwrap_err();
        assert!(
            err.starts_with("--set run.seed.x=1: `run.seed` is a value (integer)"),
            "{err}"
        );
        let err = applied(&["run.seed=1", "policy.actor_hidden.0=1"]).unwrap_err();
        assert!(err.contains("--set policy.actor_hidden.0=1"), "{err}");
    }
}
