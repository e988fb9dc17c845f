//! Parsing the `[transport]` table, from a parsed table or a whole configuration file's text, and
//! the wording of its parse errors.

use super::table::TransportConfig;
use super::validation::bad;
use crate::EnvError;

/// The message of an error in the `[transport]` table, naming the key: a table parsed apart from
/// its file has no line, but the parser keeps the key path (its text ends with `` in `a.b` ``).
fn table_error(err: &toml::de::Error) -> String {
    let text = err.to_string();
    match text.trim_end().rsplit_once("\nin `") {
        Some((message, key)) => format!("key `transport.{}: {message}", key),
        None => format!("[transport]: {}", err.message()),
    }
}

impl TransportConfig {
    /// Parses the `[transport]` table; `source` names the file in messages.
    pub fn from_table(table: &toml::Table, source: &str) -> Result<Self, EnvError> {
        let mut config: TransportConfig =
            table
                .clone()
                .try_into()
                .map_err(|e: toml::de::Error| EnvError::ConfigParse {
                    file: source.to_string(),
                    message: table_error(&e),
                })?;
        config.validate(source)?;
        config.load_posterior(source)?;
        Ok(config)
    }

    /// Parses the `[transport]` table of a whole configuration file's text.
    pub fn from_toml_str(text: &str, source: &str) -> Result<Self, EnvError> {
        let table: toml::Table = toml::from_str(text).map_err(|e| EnvError::ConfigParse {
            file: source.to_string(),
            message: e.to_string(),
        })?;
        match table.get("transport") {
            Some(toml::Value::Table(t)) => Self::from_table(t, source),
            _ => Err(bad(source, "", "missing", "a [transport] table")),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::transport::test_support::test_table;

    #[test]
    fn fixed_length_arrays_with_a_wrong_length_name_the_key() {
        let text = test_table();
        for (from, to, key, found) in [
            ("grid = [11, 13]", "grid = [11, 13, 2]", "grid", 3),
            (
                "target_tilt_deg = [30.0, 60.0]",
                "target_tilt_deg = [30.0, 45.0, 60.0]",
                "randomization.target_tilt_deg",
                3,
            ),
            (
                "object_mass_kg = [0.287, 0.595]",
                "object_mass_kg = [0.287]",
                "randomization.package.object_mass_kg",
                1,
            ),
            (
                "package_yaw_deg = [-10.0, 10.0]",
                "package_yaw_deg = [-10.0, 0.0, 10.0]",
                "randomization.package.package_yaw_deg",
                3,
            ),
            (
                "k_tri_e = [0.8, 1.25]",
                "k_tri_e = [0.8, 1.0, 1.25]",
                "randomization.package.param_scale.k_tri_e",
                3,
            ),
        ] {
            assert!(text.contains(from), "{from}");
            let table: toml::Table = toml::from_str(&text.replace(from, to)).unwrap();
            let err = TransportConfig::from_table(table["transport"].as_table().unwrap(), "t.toml")
                .unwrap_err()
                .to_string();
            let expected = format!(
                "t.toml: key `transport.{key}`: invalid length {found}, expected an array of length 2"
            );
            assert!(err.starts_with(&expected), "{to}: {err}");
        }
    }
}
