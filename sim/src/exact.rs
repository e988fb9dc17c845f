//! Fixed-length arrays of configuration files, read so that a wrong number of values is an error:
//! serde fills `[T; N]` from the first N values of a longer TOML array and drops the rest, so
//! `grid = [16, 19, 3]` would silently run as 16 x 19. Use through
//! `#[serde(deserialize_with = "rlpkg_sim::exact::array")]` (or `option`, `map`); the parser's
//! message then says `invalid length 3, expected an array of length 2` at the key's line.

use std::collections::BTreeMap;

use serde::{Deserialize, Deserializer};

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

/// A table of `[T; N]` with exactly `N` values each.
pub fn map<'de, D, T, const N: usize>(deserializer: D) -> Result<BTreeMap<String, [T; N]>, D::Error>
where
    D: Deserializer<'de>,
    T: Deserialize<'de>,
{
    BTreeMap::<String, Exact<T, N>>::deserialize(deserializer)
        .map(|table| table.into_iter().map(|(k, v)| (k, v.0)).collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[derive(Debug, Deserialize)]
    struct Fixed {
        #[serde(deserialize_with = "array")]
        pair: [u32; 2],
        #[serde(default, deserialize_with = "option")]
        range: Option<[f32; 2]>,
        #[serde(default, deserialize_with = "map")]
        scales: BTreeMap<String, [f32; 2]>,
    }

    fn parse(text: &str) -> Result<Fixed, String> {
        toml::from_str(text).map_err(|e| e.to_string())
    }

    #[test]
    fn exactly_n_values_are_accepted_and_any_other_count_is_an_error() {
        let ok = parse("pair = [1, 2]\nrange = [0.5, 1.5]\nscales = { a = [1.0, 2.0] }").unwrap();
        assert_eq!(ok.pair, [1, 2]);
        assert_eq!(ok.range, Some([0.5, 1.5]));
        assert_eq!(ok.scales["a"], [1.0, 2.0]);
        assert_eq!(parse("pair = [1, 2]").unwrap().range, None);
        for (text, line) in [
            ("pair = [1, 2, 3]", "pair = [1, 2, 3]"),
            ("pair = [1]", "pair = [1]"),
            (
                "pair = [1, 2]\nrange = [0.5, 1.5, 9.0]",
                "range = [0.5, 1.5, 9.0]",
            ),
            (
                "pair = [1, 2]\nscales = { a = [1.0] }",
                "scales = { a = [1.0] }",
            ),
        ] {
            let err = parse(text).unwrap_err();
            assert!(
                err.contains(line) && err.contains("expected an array of length 2"),
                "{text}: {err}"
            );
        }
    }
}
