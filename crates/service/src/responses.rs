//! Rendered response bodies (JSON, PNG, EXR) kept in memory with a byte budget, least recently used
//! evicted first, so a hot request is answered without decoding the EXR artifact again.

use bytes::Bytes;
use skybake_product::Format;
use std::collections::{BTreeMap, HashMap};

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

    /// Stores a body; bodies larger than the whole budget are not kept.
    pub fn put(&mut self, key: &str, format: Format, body: Bytes) {
        let len = body.len() as u64;
        if len > self.budget_bytes {
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
        let mut c = ResponseCache::new(10);
        c.put("a", Format::Json, Bytes::from_static(b"1234"));
        c.put("b", Format::Json, Bytes::from_static(b"1234"));
        assert!(c.get("a", Format::Json).is_some()); // a is now newer than b
        c.put("c", Format::Json, Bytes::from_static(b"1234"));
        assert!(c.get("b", Format::Json).is_none());
        assert!(c.get("a", Format::Json).is_some());
        assert!(c.get("c", Format::Json).is_some());
        assert!(c.get("a", Format::Png).is_none());
        c.put("d", Format::Json, Bytes::from_static(b"01234567890"));
        assert!(c.get("d", Format::Json).is_none());
        assert!(c.bytes <= 10);
    }
}
