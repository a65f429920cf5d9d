//! A setting whose default depends on the dataset: `"auto"` in a configuration file or `--set`,
//! a number once a run has resolved it against its dataset (`TrainConfig::resolve`, which writes
//! the number into the run's `config.toml`, so a resumed run and stage 2 read what stage 1 used).

use serde::{Deserialize, Serialize};

/// `"auto"` or a value. Untagged: a TOML number is a value, the string `"auto"` the other arm.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(untagged)]
pub enum Auto<T> {
    Value(T),
    Auto(AutoWord),
}

/// The word `auto`, the only string an [`Auto`] accepts.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum AutoWord {
    Auto,
}

impl<T: Copy> Auto<T> {
    pub const AUTO: Auto<T> = Auto::Auto(AutoWord::Auto);

    /// The value given, or `fallback` where the setting is still `auto`.
    pub fn or(self, fallback: T) -> T {
        match self {
            Auto::Value(v) => v,
            Auto::Auto(_) => fallback,
        }
    }

    /// Fills an `auto` with the value the dataset calls for; a given value stays.
    pub fn resolve(&mut self, value: T) {
        if let Auto::Auto(_) = self {
            *self = Auto::Value(value);
        }
    }

    pub fn value(self) -> Option<T> {
        match self {
            Auto::Value(v) => Some(v),
            Auto::Auto(_) => None,
        }
    }
}

impl<T> From<T> for Auto<T> {
    fn from(v: T) -> Self {
        Auto::Value(v)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[derive(Debug, PartialEq, Serialize, Deserialize)]
    struct S {
        n: Auto<u64>,
        x: Auto<f64>,
    }

    #[test]
    fn numbers_and_the_word_auto_round_trip_through_toml() {
        let s: S = toml::from_str("n = \"auto\"\nx = 1\n").unwrap();
        assert_eq!(
            s,
            S {
                n: Auto::AUTO,
                x: Auto::Value(1.0)
            }
        );
        let back: S = toml::from_str(&toml::to_string(&s).unwrap()).unwrap();
        assert_eq!(back, s);
        assert!(toml::to_string(&s).unwrap().contains("n = \"auto\""));
        assert!(toml::from_str::<S>("n = \"often\"\nx = 1\n").is_err());
        assert!(toml::from_str::<S>("n = -3\nx = 1\n").is_err());
    }

    #[test]
    fn resolving_fills_only_auto() {
        let mut a = Auto::<u64>::AUTO;
        assert_eq!(a.or(7), 7);
        a.resolve(5000);
        assert_eq!(a, Auto::Value(5000));
        a.resolve(1);
        assert_eq!(a.value(), Some(5000));
    }
}
