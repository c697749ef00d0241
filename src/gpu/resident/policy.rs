//! What the resident map does when a frame needs more slots than are free: grow the pool
//! (doubling, up to its largest size), then spill the least recently used blocks outside the
//! frame, farthest from the camera first ([`crate::grid::eviction_order`], the order the RAM
//! pager evicts chunks in), plus an eighth of the pool so that spills come in batches.

use super::pool::BlockPool;
use crate::grid::{eviction_order, BlockIndex, EvictionCandidate, GridParams};
use std::collections::HashSet;

/// The capacity to grow to so that `need` slots are free, doubling from the current capacity and
/// capped at `max_blocks`; `None` when the pool is already at its largest.
pub(crate) fn grown_capacity(pool: &BlockPool, need: usize, max_blocks: u32) -> Option<u32> {
    if pool.capacity() >= max_blocks {
        return None;
    }
    let wanted = pool.capacity() as usize + need.saturating_sub(pool.free_count());
    let mut cap = pool.capacity().max(1) as usize;
    while cap < wanted {
        cap *= 2;
    }
    Some(cap.min(max_blocks as usize) as u32)
}

/// The slots to spill so that `need` slots become free: blocks outside `in_frame`, in eviction
/// order around `camera_m`, `need − free + capacity/8` of them (or all candidates).
pub(crate) fn spill_slots(
    pool: &BlockPool,
    grid: &GridParams,
    in_frame: &HashSet<BlockIndex>,
    camera_m: [f64; 3],
    need: usize,
) -> Vec<u32> {
    let half = 0.5 * grid.block_size_m();
    let origin = |k: BlockIndex| grid.block_origin(k);
    let candidates: Vec<EvictionCandidate<u32>> = pool
        .occupied()
        .filter(|(_, k, _)| !in_frame.contains(k))
        .map(|(slot, k, last_used)| {
            let o = origin(k);
            EvictionCandidate {
                key: slot,
                centre_m: [o[0] + half, o[1] + half, o[2] + half],
                last_used,
            }
        })
        .collect();
    let count = (need.saturating_sub(pool.free_count()) + pool.capacity() as usize / 8)
        .min(candidates.len());
    let mut order = eviction_order(candidates, camera_m);
    order.truncate(count);
    order
}
