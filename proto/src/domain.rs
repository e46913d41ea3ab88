//! Domain types shared by the coordinator, the workers and the CLI.
//!
//! Generated proto messages convert into these at the edge, so validation happens once, here.

use std::collections::BTreeMap;
use std::fmt;
use std::str::FromStr;

use serde::{Deserialize, Serialize};

/// Why a parameter vector was rejected; each variant names the offending parameter.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ParameterError {
    /// A name that is empty or only whitespace cannot be matched against a scene's parameters.
    #[error("parameter name is empty (value {value})")]
    EmptyName {
        /// The value given with the empty name.
        value: f64,
    },
    /// NaN or an infinity would silently poison a solve; reject it before any work is queued.
    #[error("parameter `{name}` is not finite: {value}")]
    NonFinite {
        /// The parameter's name.
        name: String,
        /// The rejected value.
        value: f64,
    },
    /// Two values for one name: the caller's intent is ambiguous.
    #[error("parameter `{name}` is given twice")]
    Duplicate {
        /// The repeated name.
        name: String,
    },
}

/// Values of a study's parameters at one design point, ordered by name.
///
/// Ordered (a `BTreeMap`) so that the same point always serialises, hashes and prints the same way.
/// Every value is finite and every name non-empty: the constructors and `Deserialize` check it.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(try_from = "BTreeMap<String, f64>", into = "BTreeMap<String, f64>")]
pub struct ParameterVector(BTreeMap<String, f64>);

impl ParameterVector {
    /// An empty vector (a study with no parameters has exactly one point).
    pub fn new() -> Self {
        Self::default()
    }

    /// Builds a vector from `(name, value)` pairs, rejecting invalid and repeated entries.
    pub fn from_pairs<I, S>(pairs: I) -> Result<Self, ParameterError>
    where
        I: IntoIterator<Item = (S, f64)>,
        S: Into<String>,
    {
        let mut vector = Self::new();
        for (name, value) in pairs {
            let name = name.into();
            if vector.0.contains_key(&name) {
                return Err(ParameterError::Duplicate { name });
            }
            vector.insert(name, value)?;
        }
        Ok(vector)
    }

    /// Sets `name` to `value` (replacing an earlier value), after checking both.
    pub fn insert(&mut self, name: impl Into<String>, value: f64) -> Result<(), ParameterError> {
        let name = name.into();
        check(&name, value)?;
        self.0.insert(name, value);
        Ok(())
    }

    /// The value of `name`, if present.
    pub fn get(&self, name: &str) -> Option<f64> {
        self.0.get(name).copied()
    }

    /// Number of parameters.
    pub fn len(&self) -> usize {
        self.0.len()
    }

    /// True when there are no parameters.
    pub fn is_empty(&self) -> bool {
        self.0.is_empty()
    }

    /// `(name, value)` pairs in name order.
    pub fn iter(&self) -> impl Iterator<Item = (&str, f64)> {
        self.0.iter().map(|(k, v)| (k.as_str(), *v))
    }
}

/// The single place where a name/value pair is judged.
fn check(name: &str, value: f64) -> Result<(), ParameterError> {
    if name.trim().is_empty() {
        return Err(ParameterError::EmptyName { value });
    }
    if !value.is_finite() {
        return Err(ParameterError::NonFinite { name: name.to_owned(), value });
    }
    Ok(())
}

impl TryFrom<BTreeMap<String, f64>> for ParameterVector {
    type Error = ParameterError;

    fn try_from(map: BTreeMap<String, f64>) -> Result<Self, Self::Error> {
        for (name, value) in &map {
            check(name, *value)?;
        }
        Ok(Self(map))
    }
}

impl From<ParameterVector> for BTreeMap<String, f64> {
    fn from(vector: ParameterVector) -> Self {
        vector.0
    }
}

impl fmt::Display for ParameterVector {
    /// `{a=1, b=2.5}`: compact enough for log lines.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str("{")?;
        for (i, (name, value)) in self.0.iter().enumerate() {
            if i > 0 {
                f.write_str(", ")?;
            }
            write!(f, "{name}={value}")?;
        }
        f.write_str("}")
    }
}

/// An identifier string that did not parse.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("invalid {kind} id `{input}`: expected a non-negative integer")]
pub struct IdParseError {
    /// Which kind of id was expected ("study", "point").
    pub kind: &'static str,
    /// The rejected text.
    pub input: String,
}

macro_rules! id_newtype {
    ($(#[$doc:meta])* $name:ident, $kind:literal) => {
        $(#[$doc])*
        #[derive(
            Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize,
        )]
        #[serde(transparent)]
        pub struct $name(pub u64);

        impl fmt::Display for $name {
            fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
                write!(f, "{}", self.0)
            }
        }

        impl FromStr for $name {
            type Err = IdParseError;

            fn from_str(s: &str) -> Result<Self, Self::Err> {
                s.trim().parse().map(Self).map_err(|_| IdParseError {
                    kind: $kind,
                    input: s.to_owned(),
                })
            }
        }
    };
}

id_newtype!(
    /// Identifies a parametric study; distinct type so it cannot be confused with a point.
    StudyId,
    "study"
);
id_newtype!(
    /// Identifies one design point of a study.
    PointId,
    "point"
);

/// Milliseconds since the Unix epoch (0 if the clock is before it): the time stamps of events
/// and leases on both ends.
pub fn now_unix_ms() -> i64 {
    std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map_or(0, |d| d.as_millis() as i64)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn accepts_finite_values_in_name_order() {
        let v = ParameterVector::from_pairs([("mu", 0.3), ("e", 210e9), ("v0", -1.0)]).unwrap();
        assert_eq!(v.len(), 3);
        assert_eq!(v.get("mu"), Some(0.3));
        let names: Vec<_> = v.iter().map(|(n, _)| n).collect();
        assert_eq!(names, ["e", "mu", "v0"]);
        assert_eq!(v.to_string(), "{e=210000000000, mu=0.3, v0=-1}");
    }

    #[test]
    fn rejects_nan_naming_the_parameter() {
        let err = ParameterVector::from_pairs([("mu", 0.3), ("v0", f64::NAN)]).unwrap_err();
        assert!(matches!(&err, ParameterError::NonFinite { name, .. } if name == "v0"));
        assert_eq!(err.to_string(), "parameter `v0` is not finite: NaN");
    }

    #[test]
    fn rejects_infinities() {
        for value in [f64::INFINITY, f64::NEG_INFINITY] {
            let mut v = ParameterVector::new();
            let err = v.insert("e", value).unwrap_err();
            assert_eq!(err, ParameterError::NonFinite { name: "e".into(), value });
            assert!(v.is_empty(), "a rejected value must not be stored");
        }
    }

    #[test]
    fn rejects_empty_and_blank_names() {
        for name in ["", "  "] {
            let err = ParameterVector::from_pairs([(name, 1.0)]).unwrap_err();
            assert_eq!(err, ParameterError::EmptyName { value: 1.0 });
        }
    }

    #[test]
    fn rejects_duplicates() {
        let err = ParameterVector::from_pairs([("mu", 0.1), ("mu", 0.2)]).unwrap_err();
        assert_eq!(err, ParameterError::Duplicate { name: "mu".into() });
    }

    #[test]
    fn deserialising_validates() {
        let v: ParameterVector = serde_json::from_str(r#"{"mu":0.3,"e":1.5}"#).unwrap();
        assert_eq!(serde_json::to_string(&v).unwrap(), r#"{"e":1.5,"mu":0.3}"#);
        let err = serde_json::from_str::<ParameterVector>(r#"{"":0.3}"#).unwrap_err();
        assert!(err.to_string().contains("parameter name is empty"), "{err}");
    }

    #[test]
    fn ids_round_trip_through_text() {
        let s: StudyId = "42".parse().unwrap();
        assert_eq!(s, StudyId(42));
        assert_eq!(s.to_string(), "42");
        assert_eq!(PointId(7).to_string().parse::<PointId>(), Ok(PointId(7)));
        let err = "x1".parse::<PointId>().unwrap_err();
        assert_eq!(err.to_string(), "invalid point id `x1`: expected a non-negative integer");
        assert!("-1".parse::<StudyId>().is_err());
    }
}
