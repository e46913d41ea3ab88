//! What the web keeps between reads (a study's answers, its pictures): a map bounded in bytes
//! that drops the least recently read entries first. One rule for both caches
//! ([`crate::renderings`], [`crate::figures`]); each says what its entries are and when one is
//! still good.

use std::collections::HashMap;
use std::hash::Hash;

struct Slot<V> {
    value: V,
    /// 0 until counted
    bytes: usize,
    /// when it was last read (the map's clock)
    used: u64,
}

pub struct Kept<K, V> {
    max_bytes: usize,
    slots: HashMap<K, Slot<V>>,
    bytes: usize,
    clock: u64,
}

impl<K: Hash + Eq + Clone, V> Kept<K, V> {
    pub fn new(max_bytes: usize) -> Self {
        Kept { max_bytes, slots: HashMap::new(), bytes: 0, clock: 0 }
    }

    fn tick(&mut self) -> u64 {
        self.clock += 1;
        self.clock
    }

    /// The value under `key` if it is still `good`, marked as read now.
    pub fn read(&mut self, key: &K, good: impl FnOnce(&V) -> bool) -> Option<&mut V> {
        let now = self.tick();
        let slot = self.slots.get_mut(key).filter(|s| good(&s.value))?;
        slot.used = now;
        Some(&mut slot.value)
    }

    /// Puts `value` under `key` (the old one goes), its `bytes` counted at once, or later by
    /// [`Kept::count`] when 0 (a value still being built).
    pub fn insert(&mut self, key: K, value: V, bytes: usize) {
        let used = self.tick();
        if let Some(old) = self.slots.insert(key.clone(), Slot { value, bytes: 0, used }) {
            self.bytes -= old.bytes;
        }
        if bytes > 0 {
            self.count(&key, |_| true, bytes);
        }
    }

    /// Counts the bytes of the value under `key`, once and if it is the one meant (`is`), then
    /// drops the least recently read others until everything fits the bound. A value larger
    /// than the bound alone is not kept.
    pub fn count(&mut self, key: &K, is: impl FnOnce(&V) -> bool, bytes: usize) {
        let Some(slot) = self.slots.get_mut(key).filter(|s| s.bytes == 0 && is(&s.value)) else { return };
        if bytes > self.max_bytes {
            self.slots.remove(key);
            return;
        }
        slot.bytes = bytes;
        self.bytes += bytes;
        while self.bytes > self.max_bytes {
            let oldest =
                self.slots.iter().filter(|(k, _)| *k != key).min_by_key(|(_, s)| s.used).map(|(k, _)| k.clone());
            let Some(oldest) = oldest else { break };
            self.remove_if(&oldest, |_| true);
        }
    }

    /// Drops the value under `key` if `it` is the one meant.
    pub fn remove_if(&mut self, key: &K, it: impl FnOnce(&V) -> bool) {
        if self.slots.get(key).is_some_and(|s| it(&s.value))
            && let Some(s) = self.slots.remove(key)
        {
            self.bytes -= s.bytes;
        }
    }

    /// The bytes counted.
    #[cfg(test)]
    pub fn bytes(&self) -> usize {
        self.bytes
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_least_recently_read_go_first_and_a_value_over_the_bound_is_not_kept() {
        let mut kept: Kept<&str, u32> = Kept::new(100);
        kept.insert("a", 1, 40);
        kept.insert("b", 2, 40);
        assert_eq!(kept.read(&"a", |_| true).copied(), Some(1), "a read after b was put");
        kept.insert("c", 3, 40);
        assert!(kept.read(&"b", |_| true).is_none(), "b, the least recently read, went");
        assert_eq!((kept.read(&"a", |_| true).copied(), kept.bytes()), (Some(1), 80));
        // a value not good any more is not read, and stays until replaced or dropped
        assert!(kept.read(&"c", |&v| v == 4).is_none());
        kept.insert("c", 4, 10);
        assert_eq!((kept.read(&"c", |&v| v == 4).copied(), kept.bytes()), (Some(4), 50));
        // counted later, once, and only if it is the value meant
        kept.insert("d", 5, 0);
        kept.count(&"d", |&v| v == 6, 30);
        assert_eq!(kept.bytes(), 50);
        kept.count(&"d", |&v| v == 5, 30);
        kept.count(&"d", |&v| v == 5, 30);
        assert_eq!(kept.bytes(), 80);
        kept.insert("e", 7, 101);
        assert!(kept.read(&"e", |_| true).is_none(), "over the bound alone");
        kept.remove_if(&"d", |&v| v == 0);
        assert_eq!(kept.bytes(), 80, "not the value meant");
        kept.remove_if(&"d", |&v| v == 5);
        assert_eq!(kept.bytes(), 50);
    }
}
