//! Chunk files read from an object store, cached in RAM within a byte budget.

use std::sync::{Arc, Mutex};

/// Chunk files read from an object store, kept in RAM up to a byte budget (least recently used
/// first out). A chunk file never changes under its name, so a cached copy is never stale.
#[derive(Debug, Default)]
pub(super) struct ChunkCache {
    budget_bytes: u64,
    state: Mutex<CacheState>,
}

#[derive(Debug, Default)]
struct CacheState {
    files: std::collections::HashMap<String, (Arc<Vec<u8>>, u64)>,
    bytes: u64,
    tick: u64,
    hits: u64,
    misses: u64,
}

impl ChunkCache {
    /// An empty cache of at most `budget_bytes`.
    pub(super) fn new(budget_bytes: u64) -> Self {
        ChunkCache {
            budget_bytes,
            ..Default::default()
        }
    }

    /// Reads served from the cache and reads that missed it.
    pub(super) fn stats(&self) -> (u64, u64) {
        self.state.lock().map_or((0, 0), |s| (s.hits, s.misses))
    }

    pub(super) fn get(&self, name: &str) -> Option<Arc<Vec<u8>>> {
        let mut s = self.state.lock().ok()?;
        s.tick += 1;
        let tick = s.tick;
        let hit = s.files.get_mut(name).map(|e| {
            e.1 = tick;
            e.0.clone()
        });
        if hit.is_some() {
            s.hits += 1;
        } else {
            s.misses += 1;
        }
        hit
    }

    pub(super) fn put(&self, name: &str, bytes: Arc<Vec<u8>>) {
        let len = bytes.len() as u64;
        if len > self.budget_bytes {
            return;
        }
        let Ok(mut s) = self.state.lock() else { return };
        while s.bytes + len > self.budget_bytes {
            let Some(oldest) = s
                .files
                .iter()
                .min_by_key(|(_, (_, t))| *t)
                .map(|(k, _)| k.clone())
            else {
                break;
            };
            if let Some((b, _)) = s.files.remove(&oldest) {
                s.bytes -= b.len() as u64;
            }
        }
        s.tick += 1;
        let tick = s.tick;
        if s.files.insert(name.to_string(), (bytes, tick)).is_none() {
            s.bytes += len;
        }
    }
}

/// Default RAM for chunk files read from an object store (see [`MapStore::set_cache_budget`]).
pub const DEFAULT_OBJECT_CACHE_BYTES: u64 = 256 << 20;
