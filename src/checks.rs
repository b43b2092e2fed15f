//! The range checks of settings: a value that has no meaning where it stands is a
//! [`BadValue`], which names the key that holds it and what is wrong with it.
//!
//! Every section of the config (`[orb]`, `[dop]`, `[dense]`, …) and of a synth scene
//! checks its own values with these; the section that holds another one adds its name
//! with [`BadValue::within`], so the message names the key as the user writes it
//! (`depth_camera.camera.fx`).

use std::fmt::Display;

/// A setting out of its range: `key` (dotted, as in the TOML file) and `problem`, a
/// predicate that completes the sentence (`must be in [0, 1], got 1.5`).
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{key} {problem}")]
pub struct BadValue {
    /// The dotted key, e.g. `dop.p_init`.
    pub key: String,
    /// What is wrong, as the rest of the sentence.
    pub problem: String,
}

impl BadValue {
    /// `key` has `problem`.
    pub fn new(key: impl Into<String>, problem: impl Into<String>) -> Self {
        Self {
            key: key.into(),
            problem: problem.into(),
        }
    }

    /// The same value seen from the section `section` that holds the checked one
    /// (`camera.fx` within `depth_camera` is `depth_camera.camera.fx`).
    pub fn within(self, section: &str) -> Self {
        Self {
            key: format!("{section}.{}", self.key),
            ..self
        }
    }
}

/// `check` on each `(name, value)` of `section`, in order: the first that fails
/// names `section.name` (`dop` and `p_init`: `dop.p_init`).
pub fn each<T: Copy>(
    section: &str,
    check: fn(&str, T) -> Result<(), BadValue>,
    values: &[(&str, T)],
) -> Result<(), BadValue> {
    values
        .iter()
        .try_for_each(|&(name, value)| check(&format!("{section}.{name}"), value))
}

/// `Ok` when `value` is in `[0, 1]` (NaN is not).
pub fn unit_interval<T: Into<f64> + Copy>(key: &str, value: T) -> Result<(), BadValue> {
    let v = value.into();
    if (0.0..=1.0).contains(&v) {
        Ok(())
    } else {
        Err(BadValue::new(key, format!("must be in [0, 1], got {v}")))
    }
}

/// `Ok` when `value` is a finite number above 0.
pub fn positive<T: Into<f64> + Copy>(key: &str, value: T) -> Result<(), BadValue> {
    let v = value.into();
    if v.is_finite() && v > 0.0 {
        Ok(())
    } else {
        Err(BadValue::new(
            key,
            format!("must be a positive number, got {v}"),
        ))
    }
}

/// `Ok` when `value` is a finite number, 0 or more.
pub fn non_negative<T: Into<f64> + Copy>(key: &str, value: T) -> Result<(), BadValue> {
    let v = value.into();
    if v.is_finite() && v >= 0.0 {
        Ok(())
    } else {
        Err(BadValue::new(key, format!("must be 0 or more, got {v}")))
    }
}

/// `Ok` when the count `value` is at least 1.
pub fn at_least_one<T: Into<u64> + Copy + Display>(key: &str, value: T) -> Result<(), BadValue> {
    if value.into() >= 1 {
        Ok(())
    } else {
        Err(BadValue::new(
            key,
            format!("must be at least 1, got {value}"),
        ))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_bad_value_names_its_key_from_the_outermost_section() {
        let bad = positive("fx", -1.0)
            .unwrap_err()
            .within("camera")
            .within("depth_camera");
        assert_eq!(bad.key, "depth_camera.camera.fx");
        assert_eq!(
            bad.to_string(),
            "depth_camera.camera.fx must be a positive number, got -1"
        );
    }

    #[test]
    fn the_checks_refuse_nan_and_the_edges_outside_their_range() {
        assert!(unit_interval("k", f64::NAN).is_err() && unit_interval("k", 1.0).is_ok());
        assert!(positive("k", 0.0).is_err() && positive("k", f64::INFINITY).is_err());
        assert!(non_negative("k", 0.0).is_ok() && non_negative("k", -1e-9).is_err());
        assert!(at_least_one("k", 0u32).is_err() && at_least_one("k", 1u32).is_ok());
    }
}
