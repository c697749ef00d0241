//! Which resident units (GPU block slots, RAM chunks) leave first when a tier is full: one
//! ordering for every tier, so that the GPU pool and the RAM pager agree on what "far and old"
//! means.

/// A unit that may be evicted: its key, the centre of the space it covers (world frame, metres)
/// and when it was last used (a frame counter; tiers that do not track use pass 0).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EvictionCandidate<K> {
    /// The unit (a block index, a chunk index, a slot).
    pub key: K,
    /// Centre of the unit, world frame, metres.
    pub centre_m: [f64; 3],
    /// Frame counter of the last use (higher is more recent).
    pub last_used: u64,
}

/// Sorts `candidates` into eviction order: least recently used first, then farthest from
/// `camera_m`, then by key (so the order is deterministic).
pub fn eviction_order<K: Ord + Copy>(
    mut candidates: Vec<EvictionCandidate<K>>,
    camera_m: [f64; 3],
) -> Vec<K> {
    let d2 = |c: &EvictionCandidate<K>| -> f64 {
        (0..3).map(|a| (c.centre_m[a] - camera_m[a]).powi(2)).sum()
    };
    candidates.sort_by(|a, b| {
        a.last_used
            .cmp(&b.last_used)
            .then_with(|| d2(b).total_cmp(&d2(a)))
            .then_with(|| a.key.cmp(&b.key))
    });
    candidates.into_iter().map(|c| c.key).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn old_then_far_then_key() {
        let c = |key: u32, x: f64, last_used: u64| EvictionCandidate {
            key,
            centre_m: [x, 0.0, 0.0],
            last_used,
        };
        let order = eviction_order(
            vec![
                c(1, 1.0, 5),
                c(2, 9.0, 5),
                c(3, 2.0, 1),
                c(4, 9.0, 5),
                c(5, -20.0, 7),
            ],
            [0.0; 3],
        );
        // Frame 1 first; among frame 5 the farthest (keys 2 and 4 tie: key order), then key 1;
        // the most recent last however far.
        assert_eq!(order, vec![3, 2, 4, 1, 5]);
    }
}
