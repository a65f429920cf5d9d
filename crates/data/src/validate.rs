//! One set of value checks for every configuration-like input: the training and model
//! configuration (TOML files and `--set`), edit specs and synthetic scene descriptions. A rule
//! (`int_in`, `real_in`, `positive_up_to`, …) returns the requirement a value breaks
//! (`must be …`); the reader of each input names the key and the value its own way: the
//! configuration through the keyed checks [`int`], [`real`] and [`positive`]
//! (`KEY = VALUE: must be …`), edit specs and scenes as `FILE: KEY: must be …, found VALUE`.
//! Non-finite numbers never pass a real-valued rule.

use std::fmt::Display;

/// `lo ≤ v ≤ hi`, for a count or size.
pub fn int_in<T: PartialOrd + Display>(v: T, lo: T, hi: T) -> Result<(), String> {
    match v >= lo && v <= hi {
        true => Ok(()),
        false => Err(format!("must be in {lo}..={hi}")),
    }
}

/// `lo ≤ x ≤ hi` and finite (compared in the value's own precision).
pub fn real_in<T: PartialOrd + Display + Copy + Into<f64>>(x: T, lo: T, hi: T) -> Result<(), String> {
    match x.into().is_finite() && x >= lo && x <= hi {
        true => Ok(()),
        false => Err(format!("must be a finite number in [{lo}, {hi}]")),
    }
}

/// `0 < x ≤ hi` and finite (`hi` infinite: any finite `x > 0`).
pub fn positive_up_to(x: f64, hi: f64) -> Result<(), String> {
    match (x.is_finite() && x > 0.0 && x <= hi, hi.is_finite()) {
        (true, _) => Ok(()),
        (false, true) => Err(format!("must be a finite number in (0, {hi}]")),
        (false, false) => Err("must be a finite number > 0".into()),
    }
}

/// `x ≥ 0` and finite.
pub fn non_negative(x: f64) -> Result<(), String> {
    match x.is_finite() && x >= 0.0 {
        true => Ok(()),
        false => Err("must be a finite number ≥ 0".into()),
    }
}

/// Every component finite.
pub fn each_finite(v: &[f32]) -> Result<(), String> {
    match v.iter().all(|x| x.is_finite()) {
        true => Ok(()),
        false => Err("must be finite".into()),
    }
}

/// Every component finite and in `[lo, hi]`.
pub fn each_in(v: &[f32], lo: f32, hi: f32) -> Result<(), String> {
    match v.iter().all(|x| x.is_finite() && *x >= lo && *x <= hi) {
        true => Ok(()),
        false => Err(format!("each component must be in [{lo}, {hi}]")),
    }
}

/// Every component finite and ≥ 0.
pub fn each_non_negative(v: &[f32]) -> Result<(), String> {
    match v.iter().all(|x| x.is_finite() && *x >= 0.0) {
        true => Ok(()),
        false => Err("each component must be finite and ≥ 0".into()),
    }
}

/// A rule's failure as a configuration key's message: `KEY = VALUE: must be …` (the value as the
/// user wrote it; an f32 printed through f64 would show its rounding).
fn keyed(key: &str, v: impl Display, rule: Result<(), String>) -> Result<(), String> {
    rule.map_err(|m| format!("{key} = {v}: {m}"))
}

/// [`int_in`] for the configuration key `key`.
pub fn int<T: PartialOrd + Display + Copy>(key: &str, v: T, lo: T, hi: T) -> Result<(), String> {
    keyed(key, v, int_in(v, lo, hi))
}

/// [`real_in`] for the configuration key `key`.
pub fn real<T: Into<f64> + Copy + Display>(key: &str, v: T, lo: f64, hi: f64) -> Result<(), String> {
    keyed(key, v, real_in(v.into(), lo, hi))
}

/// [`positive_up_to`] for the configuration key `key`.
pub fn positive<T: Into<f64> + Copy + Display>(key: &str, v: T, hi: f64) -> Result<(), String> {
    keyed(key, v, positive_up_to(v.into(), hi))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn messages() {
        assert_eq!(int("a.b", 0, 1, 8).unwrap_err(), "a.b = 0: must be in 1..=8");
        assert_eq!(
            real("a.b", f32::NAN, 0.0, 1.0).unwrap_err(),
            "a.b = NaN: must be a finite number in [0, 1]"
        );
        assert_eq!(
            positive("a.b", 0.0f32, 2.0).unwrap_err(),
            "a.b = 0: must be a finite number in (0, 2]"
        );
        assert_eq!(
            positive_up_to(-1.0, f64::INFINITY).unwrap_err(),
            "must be a finite number > 0"
        );
        assert!(int("a.b", 8, 1, 8).is_ok() && real("a.b", 1.0f32, 0.0, 1.0).is_ok());
        assert!(positive_up_to(f64::INFINITY, f64::INFINITY).is_err() && non_negative(f64::NAN).is_err());
        assert!(each_in(&[0.0, 1.0, 0.5], 0.0, 1.0).is_ok() && each_in(&[0.0, 1.5, 0.5], 0.0, 1.0).is_err());
        assert!(each_finite(&[0.0, f32::INFINITY]).is_err() && each_non_negative(&[-0.0, 1.0]).is_ok());
    }
}
