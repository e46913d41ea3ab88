//! Identifiers and time stamps shared by the coordinator, the workers and the CLI (a design
//! point is core's `DesignPoint`, converted from its message in `lib.rs`).

use std::fmt;
use std::str::FromStr;

use serde::{Deserialize, Serialize};

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
