//! A design point (docs/method.md 4): values of named parameters, the one form a friction value
//! takes from a study's grid to the local stage (docs/design.md 1).
//!
//! Checked where it is made: every name plain and short, every value finite, at most
//! [`MAX_PARAMETERS`] of them. Each edge converts by `TryFrom` (a `BTreeMap` read from sled or a
//! solution file, `glissade_proto`'s `v1::ParameterVector`), and nothing after it checks again.

use std::collections::BTreeMap;
use std::fmt;

use serde::{Deserialize, Serialize};

use crate::text::{MAX_NAME_CHARS, excerpt, is_plain_name};

/// Most parameters of one design point (and of a scene, `Scene::parse`): a bound before any
/// map of a message or a record is kept.
pub const MAX_PARAMETERS: usize = 256;

/// Why a design point was refused; each variant names the offending parameter.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ParameterError {
    /// A blank, long or unprintable name matches no scene's parameter and would be echoed back.
    #[error("parameter name `{name}` must be 1 to {MAX_NAME_CHARS} printable characters")]
    BadName {
        /// the name, escaped and cut to [`MAX_NAME_CHARS`]
        name: String,
    },
    /// NaN or an infinity would silently poison a solve; refused before any work is queued.
    #[error("parameter `{name}` is not finite: {value}")]
    NonFinite { name: String, value: f64 },
    /// Two values for one name: the caller's intent is ambiguous.
    #[error("parameter `{name}` is given twice")]
    Duplicate { name: String },
    #[error("{count} parameters, more than the {MAX_PARAMETERS} accepted")]
    TooMany { count: usize },
}

/// Values of named parameters at one design point, ordered by name (so that one point always
/// serialises, hashes and prints the same way).
///
/// Stored (sled, solution files) and sent as JSON as the map `{"f1": 0.1}`: `Deserialize`
/// checks it like every other constructor.
///
/// Held as a vector sorted by name, not a map: the coordinator keeps several points per design
/// point it ever stored, and a `BTreeMap` of two entries takes a node of eleven (about 450 bytes
/// against 150; docs/performance.md, "Memory per design point").
#[derive(Clone, Default, PartialEq, Deserialize)]
#[serde(try_from = "BTreeMap<String, f64>")]
pub struct DesignPoint(Vec<(Box<str>, f64)>);

/// The one rule a name and a value are judged by.
fn check(name: &str, value: f64) -> Result<(), ParameterError> {
    if !is_plain_name(name) {
        return Err(ParameterError::BadName { name: excerpt(&name.escape_debug().to_string(), MAX_NAME_CHARS) });
    }
    if !value.is_finite() {
        return Err(ParameterError::NonFinite { name: name.to_owned(), value });
    }
    Ok(())
}

impl DesignPoint {
    /// No parameter (a study with no parameters has exactly this one point).
    pub fn new() -> Self {
        Self::default()
    }

    /// From `(name, value)` pairs, refusing invalid and repeated entries.
    pub fn from_pairs<S: Into<String>>(pairs: impl IntoIterator<Item = (S, f64)>) -> Result<Self, ParameterError> {
        let mut point = Self::new();
        for (name, value) in pairs {
            let name = name.into();
            if point.find(&name).is_ok() {
                return Err(ParameterError::Duplicate { name });
            }
            point.insert(name, value)?;
        }
        point.0.shrink_to_fit();
        Ok(point)
    }

    /// Where `name` is, or would go.
    fn find(&self, name: &str) -> Result<usize, usize> {
        self.0.binary_search_by(|(k, _)| (**k).cmp(name))
    }

    /// Sets `name` to `value` (replacing an earlier value), after checking both and the count.
    pub fn insert(&mut self, name: impl Into<String>, value: f64) -> Result<(), ParameterError> {
        let name = name.into();
        check(&name, value)?;
        match self.find(&name) {
            Ok(at) => self.0[at].1 = value,
            Err(_) if self.0.len() >= MAX_PARAMETERS => {
                return Err(ParameterError::TooMany { count: self.0.len() + 1 });
            }
            Err(at) => self.0.insert(at, (name.into_boxed_str(), value)),
        }
        Ok(())
    }

    /// This point with `other`'s values over its own (a point's swept values over the defaults).
    pub fn overlaid(mut self, other: &DesignPoint) -> Result<Self, ParameterError> {
        for (name, value) in other.iter() {
            self.insert(name, value)?;
        }
        Ok(self)
    }

    pub fn get(&self, name: &str) -> Option<f64> {
        self.find(name).ok().map(|at| self.0[at].1)
    }

    /// `(name, value)` pairs in name order.
    pub fn iter(&self) -> impl Iterator<Item = (&str, f64)> {
        self.0.iter().map(|(k, v)| (&**k, *v))
    }

    pub fn names(&self) -> impl Iterator<Item = &str> {
        self.0.iter().map(|(k, _)| &**k)
    }

    pub fn len(&self) -> usize {
        self.0.len()
    }

    pub fn is_empty(&self) -> bool {
        self.0.is_empty()
    }
}

impl TryFrom<BTreeMap<String, f64>> for DesignPoint {
    type Error = ParameterError;

    fn try_from(map: BTreeMap<String, f64>) -> Result<Self, Self::Error> {
        if map.len() > MAX_PARAMETERS {
            return Err(ParameterError::TooMany { count: map.len() });
        }
        for (name, value) in &map {
            check(name, *value)?;
        }
        // (a map's order is the name order)
        Ok(Self(map.into_iter().map(|(k, v)| (k.into_boxed_str(), v)).collect()))
    }
}

impl From<DesignPoint> for BTreeMap<String, f64> {
    fn from(point: DesignPoint) -> Self {
        point.0.into_iter().map(|(k, v)| (k.into_string(), v)).collect()
    }
}

impl Serialize for DesignPoint {
    /// The map `{"f1": 0.1}`, in name order (as the `BTreeMap` it was wrote it).
    fn serialize<S: serde::Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        serializer.collect_map(self.iter())
    }
}

impl fmt::Debug for DesignPoint {
    /// `DesignPoint({"f1": 0.1})`, as a map prints.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_tuple("DesignPoint").field(&DebugMap(self)).finish()
    }
}

struct DebugMap<'a>(&'a DesignPoint);

impl fmt::Debug for DebugMap<'_> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_map().entries(self.0.iter()).finish()
    }
}

impl fmt::Display for DesignPoint {
    /// `f1=0.1 f2=0.15`
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        for (i, (k, v)) in self.iter().enumerate() {
            if i > 0 {
                f.write_str(" ")?;
            }
            write!(f, "{k}={}", crate::text::parameter(v))?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn accepts_finite_values_in_name_order() {
        let p = DesignPoint::from_pairs([("mu", 0.3), ("e", 210e9), ("v0", -1.0)]).unwrap();
        assert_eq!(p.len(), 3);
        assert_eq!(p.get("mu"), Some(0.3));
        assert_eq!(p.names().collect::<Vec<_>>(), ["e", "mu", "v0"]);
        assert_eq!(p.to_string(), "e=210000000000 mu=0.3 v0=-1");
    }

    #[test]
    fn refuses_what_no_scene_could_name_or_solve() {
        let err = DesignPoint::from_pairs([("mu", 0.3), ("v0", f64::NAN)]).unwrap_err();
        assert_eq!(err.to_string(), "parameter `v0` is not finite: NaN");
        for value in [f64::INFINITY, f64::NEG_INFINITY] {
            let mut p = DesignPoint::new();
            assert_eq!(p.insert("e", value).unwrap_err(), ParameterError::NonFinite { name: "e".into(), value });
            assert!(p.is_empty(), "a refused value is not stored");
        }
        for name in ["", "  ", "a\nb", &"n".repeat(MAX_NAME_CHARS + 1)] {
            let err = DesignPoint::from_pairs([(name, 1.0)]).unwrap_err();
            assert!(matches!(err, ParameterError::BadName { .. }), "{name:?}: {err}");
        }
        // a long name is echoed cut short
        let err = DesignPoint::from_pairs([("n".repeat(10_000), 1.0)]).unwrap_err().to_string();
        assert!(err.len() < 200 && err.contains("more characters"), "{err}");
        let dup = DesignPoint::from_pairs([("mu", 0.1), ("mu", 0.2)]).unwrap_err();
        assert_eq!(dup, ParameterError::Duplicate { name: "mu".into() });
        assert!(DesignPoint::from_pairs([("n", 1.0)]).unwrap().names().eq(["n"]));
    }

    #[test]
    fn the_count_is_bounded_whichever_way_a_point_is_made() {
        let names: Vec<String> = (0..=MAX_PARAMETERS).map(|i| format!("p{i}")).collect();
        let many = || names.iter().map(|n| (n.clone(), 1.0));
        assert_eq!(DesignPoint::from_pairs(many()).unwrap_err(), ParameterError::TooMany { count: MAX_PARAMETERS + 1 });
        let map: BTreeMap<String, f64> = many().collect();
        assert_eq!(DesignPoint::try_from(map).unwrap_err(), ParameterError::TooMany { count: MAX_PARAMETERS + 1 });
        let full = DesignPoint::from_pairs(many().take(MAX_PARAMETERS)).unwrap();
        assert!(full.clone().overlaid(&DesignPoint::from_pairs([("p0", 2.0)]).unwrap()).is_ok(), "a replaced value");
        assert!(full.overlaid(&DesignPoint::from_pairs([("q", 2.0)]).unwrap()).is_err(), "one more name");
    }

    /// A point record as main wrote it to sled before this type (`ParameterVector`'s JSON map),
    /// and a solution file's `parameters`: both read back, and write the same bytes again.
    #[test]
    fn the_stored_json_map_reads_and_writes_unchanged() {
        let stored = r#"{"f1":0.11000000000000001,"f2":0.2,"pressure":50000000.0}"#;
        let p: DesignPoint = serde_json::from_str(stored).unwrap();
        assert_eq!(p.get("f1"), Some(0.11000000000000001));
        assert_eq!(p.get("pressure"), Some(5e7));
        assert_eq!(serde_json::to_string(&p).unwrap(), stored);
        let err = serde_json::from_str::<DesignPoint>(r#"{"":0.3}"#).unwrap_err();
        assert!(err.to_string().contains("printable characters"), "{err}");
        // (JSON has no NaN: a stored non-finite value cannot come back; a blank one is refused above)
        assert!(serde_json::from_str::<DesignPoint>(r#"{"f1":null}"#).is_err());
    }
}
