//! What the GPU costs: [`GpuTraffic`], the counts of bytes moved and of the calls that cost
//! the host time or a round trip, and the live counters a context keeps them in.

use std::sync::atomic::{AtomicU64, Ordering};

/// What a [`GpuContext`](super::GpuContext) has cost since it was opened: the bytes it moved across the bus and the
/// calls that cost the host time or a round trip. Every upload, readback, submit, blocking wait,
/// buffer and bind-group creation and dispatch of the crate goes through the context's methods,
/// which count them here (`tests/gpu/traffic.rs` fails on a raw wgpu call elsewhere); a stage's
/// figures are the difference of two snapshots ([`GpuTraffic::since`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct GpuTraffic {
    /// Bytes written from the host into device buffers (initial contents included).
    pub upload_bytes: u64,
    /// Bytes copied from the device into host memory.
    pub readback_bytes: u64,
    /// Command buffers submitted to the queue.
    pub submits: u64,
    /// Times the host blocked until the device finished its work.
    pub waits: u64,
    /// Buffers created (staging buffers included).
    pub buffers_created: u64,
    /// Bind groups created.
    pub bind_groups_created: u64,
    /// Compute dispatches recorded.
    pub dispatches: u64,
}

impl GpuTraffic {
    /// What happened between `earlier` (a snapshot of the same context) and `self`.
    pub fn since(self, earlier: GpuTraffic) -> GpuTraffic {
        GpuTraffic {
            upload_bytes: self.upload_bytes - earlier.upload_bytes,
            readback_bytes: self.readback_bytes - earlier.readback_bytes,
            submits: self.submits - earlier.submits,
            waits: self.waits - earlier.waits,
            buffers_created: self.buffers_created - earlier.buffers_created,
            bind_groups_created: self.bind_groups_created - earlier.bind_groups_created,
            dispatches: self.dispatches - earlier.dispatches,
        }
    }

    /// The sum of two counts.
    pub fn plus(self, other: GpuTraffic) -> GpuTraffic {
        GpuTraffic {
            upload_bytes: self.upload_bytes + other.upload_bytes,
            readback_bytes: self.readback_bytes + other.readback_bytes,
            submits: self.submits + other.submits,
            waits: self.waits + other.waits,
            buffers_created: self.buffers_created + other.buffers_created,
            bind_groups_created: self.bind_groups_created + other.bind_groups_created,
            dispatches: self.dispatches + other.dispatches,
        }
    }

    /// One line for summaries, each count divided by `per` (frames, scans, solves): "4.1 MiB up,
    /// 12.0 KiB down, 3.0 submits, 1.0 waits, 14.0 buffers, 2.0 bind groups, 2.0 dispatches".
    pub fn describe_per(&self, per: u64) -> String {
        let n = per.max(1) as f64;
        format!(
            "{} up, {} down, {:.1} submits, {:.1} waits, {:.1} buffers and {:.1} bind groups \
             created, {:.1} dispatches",
            human_bytes(self.upload_bytes as f64 / n),
            human_bytes(self.readback_bytes as f64 / n),
            self.submits as f64 / n,
            self.waits as f64 / n,
            self.buffers_created as f64 / n,
            self.bind_groups_created as f64 / n,
            self.dispatches as f64 / n,
        )
    }
}

/// Bytes in B, KiB, MiB or GiB with one decimal.
fn human_bytes(bytes: f64) -> String {
    const UNITS: [&str; 4] = ["B", "KiB", "MiB", "GiB"];
    let mut v = bytes;
    let mut u = 0;
    while v >= 1024.0 && u + 1 < UNITS.len() {
        v /= 1024.0;
        u += 1;
    }
    if u == 0 {
        format!("{v:.0} B")
    } else {
        format!("{v:.1} {}", UNITS[u])
    }
}

/// The traffic of a stage that runs outside the backend's calls, summed over its calls and
/// shared with whoever reports it: stereo, whose matcher belongs to the input sequence while
/// the backend reports the run. A call's figure is the difference of the context's counters
/// around it, exact while no other GPU work is recorded at the same time (the host's calls take
/// turns: a pair is matched, a frame fused, the pair's band collected).
#[derive(Clone, Debug, Default)]
pub struct StageTally(std::sync::Arc<std::sync::Mutex<(u64, GpuTraffic)>>);

impl StageTally {
    /// Runs `work`, adding its traffic on `ctx` and one call to the tally.
    pub fn count<T>(&self, ctx: &super::GpuContext, work: impl FnOnce() -> T) -> T {
        let out = self.add(ctx, work);
        self.0.lock().unwrap_or_else(|e| e.into_inner()).0 += 1;
        out
    }

    /// Runs `work`, adding its traffic on `ctx` to the tally's, as part of calls counted
    /// before (a pair's results collected later).
    pub fn add<T>(&self, ctx: &super::GpuContext, work: impl FnOnce() -> T) -> T {
        let before = ctx.traffic();
        let out = work();
        let spent = ctx.traffic().since(before);
        let mut tally = self.0.lock().unwrap_or_else(|e| e.into_inner());
        tally.1 = tally.1.plus(spent);
        out
    }

    /// The calls counted and their traffic.
    pub fn get(&self) -> (u64, GpuTraffic) {
        *self.0.lock().unwrap_or_else(|e| e.into_inner())
    }
}

/// The live counters behind [`GpuTraffic`] (the context is shared between threads).
#[derive(Debug, Default)]
pub(crate) struct TrafficCounters {
    pub(crate) upload_bytes: AtomicU64,
    pub(crate) readback_bytes: AtomicU64,
    pub(crate) submits: AtomicU64,
    pub(crate) waits: AtomicU64,
    pub(crate) buffers_created: AtomicU64,
    pub(crate) bind_groups_created: AtomicU64,
    pub(crate) dispatches: AtomicU64,
}

pub(crate) fn bump(counter: &AtomicU64, by: u64) {
    counter.fetch_add(by, Ordering::Relaxed);
}

impl TrafficCounters {
    /// The counts so far.
    pub(crate) fn snapshot(&self) -> GpuTraffic {
        let get = |a: &AtomicU64| a.load(Ordering::Relaxed);
        GpuTraffic {
            upload_bytes: get(&self.upload_bytes),
            readback_bytes: get(&self.readback_bytes),
            submits: get(&self.submits),
            waits: get(&self.waits),
            buffers_created: get(&self.buffers_created),
            bind_groups_created: get(&self.bind_groups_created),
            dispatches: get(&self.dispatches),
        }
    }
}
