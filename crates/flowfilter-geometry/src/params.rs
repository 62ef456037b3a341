//! Checks of configuration values (finite, in range), shared by every stage's configuration.
//!
//! Each check names the key, the rule and the value found, so that a configuration error reads
//! as `key 'registration.cpd.w' must be in [0, 1), found NaN`. A table prefixes its keys with
//! [`ParamError::within`].
//!
//! ```
//! use flowfilter_geometry::params::{self, ParamError};
//! fn check(threshold: f64) -> Result<(), ParamError> {
//!     params::positive("inlier_threshold_m", threshold)
//! }
//! let e = check(f64::NAN).unwrap_err().within("registration.flowfilter");
//! assert_eq!(e.to_string(), "key 'registration.flowfilter.inlier_threshold_m' must be a finite number > 0, found NaN");
//! ```

use std::fmt::Display;

/// A configuration value that breaks its rule.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("key '{key}' must be {rule}, found {found}")]
pub struct ParamError {
    /// The key, dotted from the file's root when known (`registration.cpd.w`).
    pub key: String,
    /// What the value must be (`a finite number > 0`).
    pub rule: String,
    /// The value found.
    pub found: String,
}

impl ParamError {
    /// An error for `key`, which must be `rule` and is `found`.
    pub fn new(key: &str, rule: impl Into<String>, found: impl Display) -> Self {
        Self { key: key.into(), rule: rule.into(), found: found.to_string() }
    }

    /// The same error with the key prefixed by its table (`table.key`).
    pub fn within(mut self, table: &str) -> Self {
        if !table.is_empty() {
            self.key = format!("{table}.{}", self.key);
        }
        self
    }
}

/// `Ok` when `ok`, else the error for `key`.
///
/// # Errors
/// [`ParamError`] when `ok` is false.
pub fn require(ok: bool, key: &str, rule: &str, found: impl Display) -> Result<(), ParamError> {
    if ok { Ok(()) } else { Err(ParamError::new(key, rule, found)) }
}

/// Finite (not NaN, not infinite).
///
/// # Errors
/// [`ParamError`] otherwise.
pub fn finite(key: &str, v: f64) -> Result<(), ParamError> {
    require(v.is_finite(), key, "a finite number", v)
}

/// Finite and > 0.
///
/// # Errors
/// [`ParamError`] otherwise.
pub fn positive(key: &str, v: f64) -> Result<(), ParamError> {
    require(v.is_finite() && v > 0.0, key, "a finite number > 0", v)
}

/// Finite and >= 0.
///
/// # Errors
/// [`ParamError`] otherwise.
pub fn non_negative(key: &str, v: f64) -> Result<(), ParamError> {
    require(v.is_finite() && v >= 0.0, key, "a finite number >= 0", v)
}

/// Finite and >= `min`.
///
/// # Errors
/// [`ParamError`] otherwise.
pub fn at_least(key: &str, v: f64, min: f64) -> Result<(), ParamError> {
    require(v.is_finite() && v >= min, key, &format!("a finite number >= {min}"), v)
}

/// In the closed interval [`lo`, `hi`].
///
/// # Errors
/// [`ParamError`] otherwise (NaN included).
pub fn in_closed(key: &str, v: f64, lo: f64, hi: f64) -> Result<(), ParamError> {
    require((lo..=hi).contains(&v), key, &format!("in [{lo}, {hi}]"), v)
}

/// In the half-open interval [`lo`, `hi`).
///
/// # Errors
/// [`ParamError`] otherwise (NaN included).
pub fn in_half_open(key: &str, v: f64, lo: f64, hi: f64) -> Result<(), ParamError> {
    require((lo..hi).contains(&v), key, &format!("in [{lo}, {hi})"), v)
}

/// In the open interval (`lo`, `hi`).
///
/// # Errors
/// [`ParamError`] otherwise (NaN included).
pub fn in_open(key: &str, v: f64, lo: f64, hi: f64) -> Result<(), ParamError> {
    require(v > lo && v < hi, key, &format!("in ({lo}, {hi})"), v)
}

/// A count of at least one.
///
/// # Errors
/// [`ParamError`] when `n` is 0.
pub fn count_positive(key: &str, n: usize) -> Result<(), ParamError> {
    require(n > 0, key, "at least 1", n)
}

/// Every float of a TOML table, with its dotted key, must be finite: TOML spells NaN and
/// infinity (`nan`, `inf`) and no setting of this project means either.
///
/// # Errors
/// `key 'a.b' must be a finite number, found nan` for the first one that is not.
pub fn reject_non_finite(table: &toml::Table) -> Result<(), ParamError> {
    fn walk(key: &str, value: &toml::Value) -> Result<(), ParamError> {
        match value {
            toml::Value::Float(f) => finite(key, *f),
            toml::Value::Table(t) => t.iter().try_for_each(|(k, v)| walk(&format!("{key}.{k}"), v)),
            toml::Value::Array(a) => a.iter().enumerate().try_for_each(|(i, v)| walk(&format!("{key}[{i}]"), v)),
            _ => Ok(()),
        }
    }
    table.iter().try_for_each(|(k, v)| walk(k, v))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_check_rejects_nan_and_infinity() {
        for v in [f64::NAN, f64::INFINITY, f64::NEG_INFINITY] {
            assert!(finite("k", v).is_err());
            assert!(positive("k", v).is_err());
            assert!(non_negative("k", v).is_err());
            assert!(at_least("k", v, 1.0).is_err());
            assert!(in_closed("k", v, 0.0, 1.0).is_err());
            assert!(in_half_open("k", v, 0.0, 1.0).is_err());
            assert!(in_open("k", v, 0.0, 1.0).is_err());
        }
    }

    #[test]
    fn toml_nan_and_infinity_are_named_by_their_dotted_key() {
        let t: toml::Table = toml::from_str("a = 1.0\n[b.c]\nd = [1.0, nan]\n").unwrap();
        assert_eq!(reject_non_finite(&t).unwrap_err().key, "b.c.d[1]");
        let t: toml::Table = toml::from_str("[x]\ny = -inf\n").unwrap();
        assert_eq!(reject_non_finite(&t).unwrap_err().to_string(), "key 'x.y' must be a finite number, found -inf");
        assert!(reject_non_finite(&toml::from_str("a = 1e300\nb = 'nan'").unwrap()).is_ok());
    }

    #[test]
    fn bounds_are_as_named() {
        assert!(positive("k", 0.0).is_err() && positive("k", 1e-9).is_ok());
        assert!(non_negative("k", 0.0).is_ok() && non_negative("k", -1e-9).is_err());
        assert!(in_closed("k", 1.0, 0.0, 1.0).is_ok() && in_half_open("k", 1.0, 0.0, 1.0).is_err());
        assert!(in_open("k", 0.0, 0.0, 1.0).is_err() && in_open("k", 0.5, 0.0, 1.0).is_ok());
        assert!(count_positive("k", 0).is_err() && count_positive("k", 1).is_ok());
        assert_eq!(
            at_least("ratio", 0.5, 1.0).unwrap_err().within("a.b").to_string(),
            "key 'a.b.ratio' must be a finite number >= 1, found 0.5"
        );
    }
}
