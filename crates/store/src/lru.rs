//! A size-accounted least-recently-used index: keys with a byte size and a value, ordered by last
//! access. Used by the cache twice: for files on disk (value = write generation) and for file bytes
//! held in memory (value = the bytes).

use std::collections::{BTreeMap, HashMap};

struct Entry<V> {
    tick: u64,
    size_bytes: u64,
    value: V,
}

/// LRU index; `touch`, `insert`, `remove` and eviction are O(log n).
pub(crate) struct LruIndex<V> {
    entries: HashMap<String, Entry<V>>,
    by_age: BTreeMap<u64, String>,
    next_tick: u64,
    total_bytes: u64,
}

impl<V> LruIndex<V> {
    pub(crate) fn new() -> Self {
        Self {
            entries: HashMap::new(),
            by_age: BTreeMap::new(),
            next_tick: 0,
            total_bytes: 0,
        }
    }

    fn tick(&mut self) -> u64 {
        self.next_tick += 1;
        self.next_tick
    }

    /// The value for `key`, marking it most recently used.
    pub(crate) fn get(&mut self, key: &str) -> Option<&V> {
        let tick = self.tick();
        let entry = self.entries.get_mut(key)?;
        self.by_age.remove(&entry.tick);
        entry.tick = tick;
        self.by_age.insert(tick, key.to_string());
        Some(&entry.value)
    }

    /// The value for `key` without changing its age.
    pub(crate) fn peek(&self, key: &str) -> Option<&V> {
        self.entries.get(key).map(|e| &e.value)
    }

    /// Inserts or replaces `key` as the most recently used entry.
    pub(crate) fn insert(&mut self, key: &str, size_bytes: u64, value: V) {
        self.remove(key);
        let tick = self.tick();
        self.by_age.insert(tick, key.to_string());
        self.entries.insert(
            key.to_string(),
            Entry {
                tick,
                size_bytes,
                value,
            },
        );
        self.total_bytes += size_bytes;
    }

    /// Removes `key`, returning its size and value.
    pub(crate) fn remove(&mut self, key: &str) -> Option<(u64, V)> {
        let entry = self.entries.remove(key)?;
        self.by_age.remove(&entry.tick);
        self.total_bytes -= entry.size_bytes;
        Some((entry.size_bytes, entry.value))
    }

    /// Removes and returns the least recently used key for which `pinned` is false.
    pub(crate) fn pop_oldest_unpinned(
        &mut self,
        pinned: impl Fn(&str) -> bool,
    ) -> Option<(String, u64, V)> {
        let key = self
            .by_age
            .values()
            .find(|key| !pinned(key.as_str()))?
            .clone();
        let (size_bytes, value) = self.remove(&key)?;
        Some((key, size_bytes, value))
    }

    pub(crate) fn total_bytes(&self) -> u64 {
        self.total_bytes
    }

    pub(crate) fn len(&self) -> usize {
        self.entries.len()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn evicts_in_access_order_and_accounts_bytes() {
        let mut lru = LruIndex::new();
        lru.insert("a", 10, 1);
        lru.insert("b", 20, 2);
        lru.insert("c", 30, 3);
        assert_eq!(lru.total_bytes(), 60);
        assert_eq!(lru.get("a"), Some(&1));
        lru.insert("b", 5, 22);
        assert_eq!(lru.total_bytes(), 45);
        assert_eq!(lru.peek("b"), Some(&22));
        // Order of use is now c, a, b.
        assert_eq!(
            lru.pop_oldest_unpinned(|k| k == "c"),
            Some(("a".into(), 10, 1))
        );
        assert_eq!(
            lru.pop_oldest_unpinned(|_| false),
            Some(("c".into(), 30, 3))
        );
        assert_eq!(lru.len(), 1);
        assert_eq!(lru.remove("b"), Some((5, 22)));
        assert_eq!(lru.pop_oldest_unpinned(|_| false), None);
        assert_eq!(lru.total_bytes(), 0);
    }
}
