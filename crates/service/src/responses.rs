//! Rendered response bodies (JSON, PNG, EXR) kept in memory with a byte budget, least recently used
//! evicted first, so a hot request is answered without decoding the EXR artifact again. A body
//! over [`MAX_ENTRY_FRACTION`] of the budget is not kept, so one large product cannot flush the
//! cache.

use bytes::Bytes;
use skybake_product::Format;
use std::collections::{BTreeMap, HashMap};

/// Largest share of the budget one body may take (larger ones are served, not kept).
pub const MAX_ENTRY_FRACTION: u64 = 8;

/// A byte-bounded LRU of response bodies keyed by (cache key, format).
pub struct ResponseCache {
    budget_bytes: u64,
    bytes: u64,
    tick: u64,
    entries: HashMap<(String, Format), (Bytes, u64)>,
    order: BTreeMap<u64, (String, Format)>,
}

impl ResponseCache {
    pub fn new(budget_bytes: u64) -> Self {
        Self {
            budget_bytes,
            bytes: 0,
            tick: 0,
            entries: HashMap::new(),
            order: BTreeMap::new(),
        }
    }

    /// The body stored for (`key`, `format`), refreshing its recency.
    pub fn get(&mut self, key: &str, format: Format) -> Option<Bytes> {
        let id = (key.to_string(), format);
        let (body, tick) = self.entries.get_mut(&id)?;
        self.order.remove(tick);
        self.tick += 1;
        *tick = self.tick;
        self.order.insert(self.tick, id);
        Some(body.clone())
    }

    /// Stores a body; bodies larger than 1/[`MAX_ENTRY_FRACTION`] of the budget are not kept.
    pub fn put(&mut self, key: &str, format: Format, body: Bytes) {
        let len = body.len() as u64;
        if len > self.budget_bytes / MAX_ENTRY_FRACTION {
            return;
        }
        let id = (key.to_string(), format);
        if let Some((old, tick)) = self.entries.remove(&id) {
            self.order.remove(&tick);
            self.bytes -= old.len() as u64;
        }
        while self.bytes + len > self.budget_bytes {
            let Some((_, victim)) = self.order.pop_first() else {
                break;
            };
            if let Some((old, _)) = self.entries.remove(&victim) {
                self.bytes -= old.len() as u64;
            }
        }
        self.tick += 1;
        self.order.insert(self.tick, id.clone());
        self.entries.insert(id, (body, self.tick));
        self.bytes += len;
    }

    pub fn clear(&mut self) {
        self.entries.clear();
        self.order.clear();
        self.bytes = 0;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn keeps_to_budget_evicting_least_recent() {
        let mut c = ResponseCache::new(10 * MAX_ENTRY_FRACTION);
        let body = |n: u64| Bytes::from(vec![b'x'; n as usize]);
        let quarter = 10 * MAX_ENTRY_FRACTION / 4;
        let entry = quarter.min(10);
        for k in ["a", "b", "e", "f"] {
            c.put(k, Format::Json, body(entry));
        }
        c.put("b", Format::Json, body(entry));
        assert!(c.get("a", Format::Json).is_some()); // a is now newer than the others
        let full = 10 * MAX_ENTRY_FRACTION / entry;
        for i in 0..full - 1 {
            c.put(&format!("n{i}"), Format::Json, body(entry));
        }
        assert!(c.bytes <= 10 * MAX_ENTRY_FRACTION);
        assert!(
            c.get("a", Format::Json).is_some(),
            "the most recent survives"
        );
        assert!(
            c.get("e", Format::Json).is_none(),
            "the least recent went first"
        );
        assert!(c.get("a", Format::Png).is_none());
        // A body over the per-entry ceiling is not kept and evicts nothing.
        let before = c.entries.len();
        c.put("big", Format::Json, body(10 + 1));
        assert!(c.get("big", Format::Json).is_none());
        assert_eq!(c.entries.len(), before);
        assert!(c.get("a", Format::Json).is_some());
    }
}
