//! Each QoI's value at one point, as a record keeps it: a vector sorted by name, not a map. The
//! coordinator keeps four of them for every design point it ever solved (a point's result and its
//! stored solution, the finals and the histories' largest magnitudes), and a `BTreeMap` of three
//! entries takes a node of eleven, about 370 bytes against 96 (as `DesignPoint` does;
//! docs/performance.md, "Memory per design point"). Stored and sent as the JSON map
//! `{"slip_A": 1.2e-6}`, as the maps were. The names are shared (`records::shared`): a study's
//! points hold one copy of each.

use std::collections::BTreeMap;
use std::fmt;
use std::sync::Arc;

use serde::{Deserialize, Serialize};

#[derive(Clone, Default, PartialEq, Deserialize)]
#[serde(from = "BTreeMap<String, f64>")]
pub struct QoiMap(Vec<(Arc<str>, f64)>);

impl QoiMap {
    fn find(&self, name: &str) -> Result<usize, usize> {
        self.0.binary_search_by(|(n, _)| (**n).cmp(name))
    }

    pub fn get(&self, name: &str) -> Option<&f64> {
        self.find(name).ok().map(|i| &self.0[i].1)
    }

    pub fn contains_key(&self, name: &str) -> bool {
        self.find(name).is_ok()
    }

    /// Sets `name`'s value; the one it replaces, if any.
    pub fn insert(&mut self, name: String, value: f64) -> Option<f64> {
        match self.find(&name) {
            Ok(i) => Some(std::mem::replace(&mut self.0[i].1, value)),
            Err(i) => {
                self.0.insert(i, (crate::records::shared(&name), value));
                None
            }
        }
    }

    /// In name order.
    pub fn iter(&self) -> impl Iterator<Item = (&str, &f64)> {
        self.0.iter().map(|(n, v)| (&**n, v))
    }

    pub fn keys(&self) -> impl Iterator<Item = &str> {
        self.0.iter().map(|(n, _)| &**n)
    }

    pub fn values(&self) -> impl Iterator<Item = &f64> {
        self.0.iter().map(|(_, v)| v)
    }

    pub fn len(&self) -> usize {
        self.0.len()
    }

    pub fn is_empty(&self) -> bool {
        self.0.is_empty()
    }
}

impl From<BTreeMap<String, f64>> for QoiMap {
    fn from(map: BTreeMap<String, f64>) -> Self {
        // (one copy of each name for every record that holds it: a study's points share theirs)
        QoiMap(map.into_iter().map(|(n, v)| (crate::records::shared(&n), v)).collect())
    }
}

impl From<QoiMap> for BTreeMap<String, f64> {
    fn from(map: QoiMap) -> Self {
        map.0.into_iter().map(|(n, v)| (n.to_string(), v)).collect()
    }
}

impl FromIterator<(String, f64)> for QoiMap {
    fn from_iter<I: IntoIterator<Item = (String, f64)>>(items: I) -> Self {
        // (a later value for a name replaces an earlier one, as in a map)
        QoiMap::from(items.into_iter().collect::<BTreeMap<_, _>>())
    }
}

impl<const N: usize> From<[(String, f64); N]> for QoiMap {
    fn from(items: [(String, f64); N]) -> Self {
        items.into_iter().collect()
    }
}

impl<'a> IntoIterator for &'a QoiMap {
    type Item = (&'a str, &'a f64);
    type IntoIter =
        std::iter::Map<std::slice::Iter<'a, (Arc<str>, f64)>, fn(&'a (Arc<str>, f64)) -> (&'a str, &'a f64)>;

    fn into_iter(self) -> Self::IntoIter {
        self.0.iter().map(|(n, v)| (&**n, v))
    }
}

impl IntoIterator for QoiMap {
    type Item = (String, f64);
    type IntoIter = std::iter::Map<std::vec::IntoIter<(Arc<str>, f64)>, fn((Arc<str>, f64)) -> (String, f64)>;

    fn into_iter(self) -> Self::IntoIter {
        self.0.into_iter().map(|(n, v)| (n.to_string(), v))
    }
}

impl std::ops::Index<&str> for QoiMap {
    type Output = f64;

    fn index(&self, name: &str) -> &f64 {
        self.get(name).unwrap_or_else(|| panic!("no QoI named {name:?}"))
    }
}

impl Serialize for QoiMap {
    fn serialize<S: serde::Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        serializer.collect_map(self.iter())
    }
}

impl fmt::Debug for QoiMap {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_map().entries(self.iter()).finish()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn it_reads_and_writes_as_the_map_it_replaces() {
        let map: BTreeMap<String, f64> = [("slip_B".to_string(), 2.0), ("middle_ux".to_string(), 1.0)].into();
        let q = QoiMap::from(map.clone());
        assert_eq!(serde_json::to_string(&q).unwrap(), serde_json::to_string(&map).unwrap());
        let back: QoiMap = serde_json::from_str(r#"{"slip_B": 2.0, "middle_ux": 1.0}"#).unwrap();
        assert_eq!(back, q);
        assert_eq!((q["middle_ux"], q.get("slip_B"), q.get("slip_A")), (1.0, Some(&2.0), None));
        assert_eq!(q.keys().collect::<Vec<_>>(), ["middle_ux", "slip_B"]);
        let mut r = q.clone();
        assert_eq!((r.insert("slip_A".into(), 3.0), r.insert("slip_B".into(), 4.0)), (None, Some(2.0)));
        assert_eq!(
            BTreeMap::from(r),
            BTreeMap::from([("middle_ux".into(), 1.0), ("slip_A".into(), 3.0), ("slip_B".into(), 4.0)])
        );
        assert_eq!(format!("{q:?}"), format!("{map:?}"));
    }
}
