//! The process's own memory: its resident set (now and at its peak, from `/proc/self/status`)
//! and the one place that sets how glibc's allocator hands freed memory back to the kernel.
//!
//! Why the allocator needs a policy here: the map's working sets (a frame's chunks, a region's
//! solver arrays) are large, short-lived and of varying size. glibc keeps freed memory in its
//! arenas for reuse, so a process that fused a drive and then regularizes it can hold hundreds
//! of MiB that are free but resident (measured: 560 MiB free of a 561 MiB arena between two
//! regions of a 1200 m drive at a 512 MiB budget, `docs/bench/memory.md`). [`TrimAbove`] hands
//! free pages back whenever the resident set passes the budget, at region and frame boundaries,
//! so `--memory-budget` bounds the process and not only the data it counts.

use std::time::{Duration, Instant};

/// The most of `--memory-budget` kept for the process itself, bytes (see [`data_share_bytes`]).
pub const PROCESS_RESERVE_MAX_BYTES: u64 = 64 << 20;

/// The part of a memory budget of `budget_bytes` that the map's data may use: resident blocks
/// during fusion, one region's arrays during regularization. The rest, a quarter of the budget up
/// to [`PROCESS_RESERVE_MAX_BYTES`], is the process's own: code and libraries, thread stacks,
/// the manifest, the frame being fused, the chunk writers' buffers and the allocator's slack
/// between two trims ([`TrimAbove`]). Measured (`docs/bench/memory.md`): about 80 MiB beside the
/// data, so the process stays within `budget + 64 MiB`.
pub fn data_share_bytes(budget_bytes: u64) -> u64 {
    budget_bytes - (budget_bytes / 4).min(PROCESS_RESERVE_MAX_BYTES)
}

/// The smallest budget whose [`data_share_bytes`] holds `data_bytes`.
pub fn budget_for_data_bytes(data_bytes: u64) -> u64 {
    // The share grows with the budget: the smallest budget by bisection over [data, data + R].
    let (mut lo, mut hi) = (data_bytes, data_bytes + PROCESS_RESERVE_MAX_BYTES);
    while lo < hi {
        let mid = lo + (hi - lo) / 2;
        if data_share_bytes(mid) >= data_bytes {
            hi = mid;
        } else {
            lo = mid + 1;
        }
    }
    lo
}

fn status_kib(field: &str) -> Option<u64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with(field))?;
    line.split_whitespace().nth(1)?.parse().ok()
}

/// Resident memory of this process now (Linux `VmRSS`), bytes; `None` elsewhere.
pub fn rss_bytes() -> Option<u64> {
    status_kib("VmRSS:").map(|kib| kib * 1024)
}

/// Peak resident memory of this process (Linux `VmHWM`), bytes; `None` elsewhere.
pub fn peak_rss_bytes() -> Option<u64> {
    status_kib("VmHWM:").map(|kib| kib * 1024)
}

/// Hands the allocator's free pages back to the kernel (all arenas, also pages in the middle of
/// a heap). Nothing happens off glibc.
pub fn release_free_memory() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: malloc_trim only returns free memory of glibc's heaps to the kernel.
    unsafe {
        libc::malloc_trim(0);
    }
}

/// Keeps freed large arrays in the heap for the next use instead of unmapping them: a solver
/// that allocates each region's arrays anew would otherwise take a page fault per 4 KiB of
/// every region (measured: half of a swept pass's CPU time was the kernel's,
/// `docs/bench/regularize.md`). What this keeps is bounded by [`TrimAbove`]. Call before the
/// work's threads start.
pub fn keep_freed_memory() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: mallopt only sets allocator parameters.
    unsafe {
        libc::mallopt(libc::M_MMAP_THRESHOLD, 1 << 30);
        libc::mallopt(libc::M_TRIM_THRESHOLD, 1 << 30);
    }
}

/// Maps every allocation of 128 KiB or more on its own and unmaps it when freed, with glibc's
/// adaptive threshold turned off (it otherwise rises to 32 MiB after the first large free, and
/// chunk buffers, scans and compressor windows then fragment the heap between the pager's
/// blocks). For fusion through the pager: measured on the 1200 m drive at 512 MiB, fusion's peak
/// went from 599 to 549 MiB (`docs/bench/memory.md`).
pub fn map_large_allocations() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: mallopt only sets allocator parameters.
    unsafe {
        libc::mallopt(libc::M_MMAP_THRESHOLD, 128 << 10);
    }
}

/// Hands free memory back to the kernel whenever the resident set is above a limit (at most
/// once per `min_interval`): called at the boundaries of a budgeted loop (after each region,
/// after each frame's eviction), it keeps allocator slack from adding to the budget.
#[derive(Debug)]
pub struct TrimAbove {
    limit_bytes: u64,
    min_interval: Duration,
    last: Option<Instant>,
    trims: u64,
}

impl TrimAbove {
    /// Trims when the resident set exceeds `limit_bytes`.
    pub fn new(limit_bytes: u64) -> Self {
        TrimAbove {
            limit_bytes,
            min_interval: Duration::from_millis(500),
            last: None,
            trims: 0,
        }
    }

    /// Checks the resident set, trimming when it is above the limit; true when it trimmed.
    pub fn check(&mut self) -> bool {
        if self.last.is_some_and(|t| t.elapsed() < self.min_interval) {
            return false;
        }
        match rss_bytes() {
            Some(rss) if rss > self.limit_bytes => {
                release_free_memory();
                self.last = Some(Instant::now());
                self.trims += 1;
                true
            }
            _ => false,
        }
    }

    /// Before allocating about `bytes`: trims (whatever the interval) when the resident set plus
    /// `bytes` would pass the limit, so that fresh arrays do not land on top of free memory the
    /// allocator could not reuse for them. True when it trimmed.
    pub fn make_room(&mut self, bytes: u64) -> bool {
        match rss_bytes() {
            Some(rss) if rss.saturating_add(bytes) > self.limit_bytes => {
                release_free_memory();
                self.last = Some(Instant::now());
                self.trims += 1;
                true
            }
            _ => false,
        }
    }

    /// How many times [`TrimAbove::check`] or [`TrimAbove::make_room`] trimmed.
    pub fn trims(&self) -> u64 {
        self.trims
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn data_share_and_its_inverse() {
        const MIB: u64 = 1 << 20;
        assert_eq!(data_share_bytes(128 * MIB), 96 * MIB);
        assert_eq!(data_share_bytes(256 * MIB), 192 * MIB);
        assert_eq!(data_share_bytes(512 * MIB), 448 * MIB);
        for data in [
            2,
            1000,
            95 * MIB + 7,
            96 * MIB,
            191 * MIB,
            192 * MIB,
            448 * MIB + 1,
        ] {
            let b = budget_for_data_bytes(data);
            assert!(data_share_bytes(b) >= data, "{data}: {b}");
            assert!(
                data_share_bytes(b - 1) < data,
                "{data}: {b} is not the smallest"
            );
        }
    }

    #[test]
    #[cfg(target_os = "linux")]
    fn resident_set_is_read_and_peak_is_at_least_current() {
        let now = rss_bytes().expect("VmRSS on Linux");
        let peak = peak_rss_bytes().expect("VmHWM on Linux");
        assert!(
            now > 1 << 20,
            "a running test binary holds more than 1 MiB: {now}"
        );
        assert!(peak >= now, "peak {peak} below current {now}");
    }

    #[test]
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    fn trim_above_a_limit_returns_freed_memory() {
        // 256 MiB touched in many small blocks (below the mmap threshold, so they stay in the
        // heap when freed), then freed: resident until trimmed.
        let blocks: Vec<Vec<u8>> = (0..4096).map(|_| vec![1u8; 64 << 10]).collect();
        let held = rss_bytes().unwrap();
        drop(blocks);
        let mut never = TrimAbove::new(u64::MAX);
        assert!(!never.check());
        let mut always = TrimAbove::new(0);
        assert!(always.check());
        assert_eq!(always.trims(), 1);
        assert!(!always.check(), "a second check within the interval waits");
        assert!(always.make_room(0), "making room does not wait");
        assert!(!never.make_room(1 << 40));
        let after = rss_bytes().unwrap();
        assert!(
            after + (128 << 20) < held,
            "less than 128 MiB of 256 went back: {held} → {after} bytes"
        );
    }
}
