//! Process-wide memos of values a camera's parameters fix (the sensor's
//! PRNU/DSNU maps, PSF kernels, distortion tables): built once per key and
//! shared, so a frame loop or a dataset pays for them once, not per frame.
//! Each memo keeps its few most recent keys, bounding the memory held.

use std::sync::{Arc, Mutex};

/// A small memo from keys compared by equality to shared values.
pub struct Memo<K, V> {
    capacity: usize,
    entries: Mutex<Vec<(K, Arc<V>)>>,
}

impl<K: PartialEq, V> Memo<K, V> {
    /// An empty memo keeping up to `capacity` values.
    pub const fn new(capacity: usize) -> Memo<K, V> {
        Memo {
            capacity,
            entries: Mutex::new(Vec::new()),
        }
    }

    /// The value of `key`, built by `build` if absent. The lock is not held
    /// while building (a kernel can take a second): two threads asking for
    /// the same new key may both build it; the values are equal.
    pub fn get_or_build<E>(
        &self,
        key: K,
        build: impl FnOnce() -> std::result::Result<V, E>,
    ) -> std::result::Result<Arc<V>, E> {
        if let Some(v) = self.find(&key) {
            return Ok(v);
        }
        let value = Arc::new(build()?);
        let mut entries = self.entries.lock().unwrap_or_else(|e| e.into_inner());
        entries.retain(|(k, _)| *k != key);
        if entries.len() >= self.capacity.max(1) {
            entries.remove(0);
        }
        entries.push((key, Arc::clone(&value)));
        Ok(value)
    }

    fn find(&self, key: &K) -> Option<Arc<V>> {
        let entries = self.entries.lock().unwrap_or_else(|e| e.into_inner());
        entries
            .iter()
            .find(|(k, _)| k == key)
            .map(|(_, v)| Arc::clone(v))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn builds_once_per_key_and_evicts_the_oldest() {
        let memo: Memo<u32, u32> = Memo::new(2);
        let builds = std::cell::Cell::new(0);
        let get = |k: u32| {
            *memo
                .get_or_build(k, || {
                    builds.set(builds.get() + 1);
                    Ok::<_, ()>(k * 10)
                })
                .unwrap()
        };
        assert_eq!(get(1), 10);
        assert_eq!(get(1), 10);
        assert_eq!(get(2), 20);
        assert_eq!(get(3), 30); // evicts 1
        assert_eq!(get(2), 20);
        assert_eq!(get(1), 10); // rebuilt
        assert_eq!(builds.get(), 4);
    }
}
