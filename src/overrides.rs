//! `--set KEY=VALUE`: one value of a TOML configuration replaced (or added) on the command line,
//! so that a sweep needs no rewritten files.
//!
//! The override edits the file's parsed document ([`toml_edit`], which keeps comments, key order
//! and the formatting of everything it does not touch), and the edited text is then checked like
//! any file: a run folder keeps it as its `config.toml`, readable and with exactly what was run.

use std::fmt;
use std::str::FromStr;

use toml_edit::{DocumentMut, InlineTable, Item, Key, Table, TableLike, Value};

/// One `--set KEY=VALUE`: a dotted key path and the TOML value to put there.
#[derive(Debug, Clone, PartialEq)]
pub struct Override {
    /// The option as given, e.g. `ppo.learning_rate=1e-4` (named in messages).
    given: String,
    /// The key path, e.g. `["ppo", "learning_rate"]`.
    path: Vec<Key>,
    /// The value, e.g. `1e-4`.
    value: Value,
}

impl Override {
    /// The option as given (`KEY=VALUE`).
    pub fn given(&self) -> &str {
        &self.given
    }
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
        if key.trim().is_empty() {
            return Err(format!("`{given}`: no key before `=`; {expected}"));
        }
        let path = Key::parse(key.trim()).map_err(|e| {
            let reason = e.message().trim_end();
            format!("`{given}`: `{key}` is not a TOML key ({reason}); {expected}")
        })?;
        let value = value.trim();
        let value = Value::from_str(value).unwrap_or_else(|_| Value::from(value));
        Ok(Self {
            given: given.to_string(),
            path,
            value,
        })
    }
}

/// `text` (the file named `source`) with every override applied in order (a key set twice keeps
/// the last value). A key may be new (its table decides whether it is known); a table that does
/// not exist yet is added. Replacing a table by a value, or a path through a value, is refused,
/// naming the option.
pub fn apply(text: &str, source: &str, overrides: &[Override]) -> Result<String, String> {
    let mut doc: DocumentMut = text
        .parse()
        .map_err(|e: toml_edit::TomlError| format!("{source}: {}", e.to_string().trim_end()))?;
    for one in overrides {
        set(doc.as_table_mut(), one).map_err(|reason| format!("{one}: {reason}"))?;
    }
    Ok(doc.to_string())
}

/// Puts `one.value` at `one.path` under `root`.
fn set(root: &mut Table, one: &Override) -> Result<(), String> {
    let (last, parents) = one
        .path
        .split_last()
        .expect("Key::parse gives one key or more");
    let mut table: &mut dyn TableLike = root;
    let mut inline = false;
    for (depth, key) in parents.iter().enumerate() {
        // A missing table is added as the kind its parent holds: a `[header]` table under a
        // standard one, an inline table under an inline one.
        let item = table.entry(key.get()).or_insert_with(Item::None);
        if item.is_none() {
            *item = if inline {
                Item::Value(Value::InlineTable(InlineTable::new()))
            } else {
                Item::Table(Table::new())
            };
        }
        if item.is_inline_table() {
            inline = true;
            table = item.as_inline_table_mut().expect("an inline table");
            continue;
        }
        let type_name = item.type_name();
        table = match item.as_table_mut() {
            Some(inner) => inner,
            None => {
                return Err(format!(
                    "`{}` is a value ({type_name}), not a table: no key under it can be set",
                    full_key(&one.path[..=depth])
                ))
            }
        };
    }
    match table.get_mut(last.get()) {
        Some(item) if item.is_table_like() || item.is_array_of_tables() => Err(format!(
            "`{0}` is a table; set one of its keys, e.g. --set {0}.<key>=VALUE",
            full_key(&one.path)
        )),
        Some(Item::Value(old)) => {
            // The new value keeps the old one's spacing and trailing comment.
            let decor = old.decor().clone();
            *old = one.value.clone();
            *old.decor_mut() = decor;
            Ok(())
        }
        _ => {
            let mut value = one.value.clone();
            value.decor_mut().set_prefix(" ");
            table.insert(last.get(), Item::Value(value));
            Ok(())
        }
    }
}

/// The dotted form of a key path, e.g. `ppo.learning_rate`.
fn full_key(path: &[Key]) -> String {
    path.iter()
        .map(|k| k.display_repr().to_string())
        .collect::<Vec<_>>()
        .join(".")
}

#[cfg(test)]
mod tests {
    use super::*;

    const CONFIG: &str =
        "# A training file.\n[run]\nseed = 3  # the seed\nenv = \"CartPole-v1\"\n\n\
                          [ppo]\nlearning_rate = 1e-3\n\n[policy]\nactor_hidden = [16, 16]\n\
                          activation = \"tanh\"\n";

    fn applied(sets: &[&str]) -> Result<String, String> {
        let overrides: Vec<Override> = sets.iter().map(|s| s.parse()).collect::<Result<_, _>>()?;
        apply(CONFIG, "train.toml", &overrides)
    }

    #[test]
    fn an_existing_value_is_replaced_in_place_with_its_comment() {
        let text = applied(&["run.seed=5", "ppo.learning_rate=5e-4"]).unwrap();
        assert_eq!(
            text,
            CONFIG
                .replace("seed = 3  #", "seed = 5  #")
                .replace("learning_rate = 1e-3", "learning_rate = 5e-4")
        );
    }

    #[test]
    fn the_last_of_two_sets_of_one_key_wins() {
        let text = applied(&["run.seed=5", "run.seed = 7"]).unwrap();
        assert!(text.contains("seed = 7  # the seed\n"), "{text}");
    }

    #[test]
    fn a_new_key_is_added_to_its_table() {
        let text = applied(&["ppo.epochs=4"]).unwrap();
        let doc: toml::Table = toml::from_str(&text).unwrap();
        assert_eq!(doc["ppo"]["epochs"].as_integer(), Some(4));
        assert_eq!(doc["ppo"]["learning_rate"].as_float(), Some(1e-3));
        assert!(
            text.contains("learning_rate = 1e-3\nepochs = 4\n"),
            "{text}"
        );
    }

    #[test]
    fn a_missing_table_is_added() {
        let text = applied(&["transport.reward.scale=2.5"]).unwrap();
        let doc: toml::Table = toml::from_str(&text).unwrap();
        assert_eq!(doc["transport"]["reward"]["scale"].as_float(), Some(2.5));
    }

    #[test]
    fn arrays_strings_and_bare_words() {
        let text = applied(&[
            "policy.actor_hidden=[64, 64]",
            "policy.activation=relu",
            "run.env=\"Pendulum-v1\"",
        ])
        .unwrap();
        let doc: toml::Table = toml::from_str(&text).unwrap();
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
        let text = applied(&["run.seed=abc"]).unwrap();
        assert!(text.contains("seed = \"abc\""), "{text}");
    }

    #[test]
    fn quoted_keys_and_inline_tables() {
        let config = "[scene]\nsize = { x = 1.0, y = 2.0 }\n";
        let set: Vec<Override> = vec![
            "scene.size.y=3.0".parse().unwrap(),
            "scene.\"a.b\"=1".parse().unwrap(),
        ];
        let text = apply(config, "s.toml", &set).unwrap();
        let doc: toml::Table = toml::from_str(&text).unwrap();
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

    #[test]
    fn no_override_keeps_the_text() {
        assert_eq!(apply(CONFIG, "train.toml", &[]).unwrap(), CONFIG);
    }
}
