//! Kernel device times from timestamp queries, where the adapter has them
//! (`wgpu::Features::TIMESTAMP_QUERY`): while timing is on, every compute pass
//! `GpuContext::record_dispatch` records writes a timestamp at its start and end, and each
//! submit resolves its passes' timestamps and reads them back after it (`GpuContext::submit`).
//! The GPU's time per kernel is the difference, in the queue's timestamp period. Timing adds a
//! wait per submit, so a timed run is for attributing device time to kernels, not for
//! wall-clock figures (`denser bench --device gpu` times one extra pass for it). The host's
//! side: [`thread_cpu_s`], the calling thread's own CPU time.

use super::GpuContext;
use std::collections::BTreeMap;

/// Seconds of CPU time the calling thread has used (`CLOCK_THREAD_CPUTIME_ID`): the host's own
/// work, to which waiting (for the device, or for the cores a software device's threads hold)
/// adds nothing. 0 where the platform has no such clock.
pub fn thread_cpu_s() -> f64 {
    #[cfg(unix)]
    {
        let mut ts = libc::timespec {
            tv_sec: 0,
            tv_nsec: 0,
        };
        // SAFETY: clock_gettime writes only the timespec it is given.
        if unsafe { libc::clock_gettime(libc::CLOCK_THREAD_CPUTIME_ID, &mut ts) } == 0 {
            return ts.tv_sec as f64 + 1e-9 * ts.tv_nsec as f64;
        }
    }
    0.0
}

/// Passes timed per submit; passes beyond it in one submit are counted as untimed.
pub(crate) const MAX_TIMED_PASSES: u32 = 1024;

/// Bytes of one pass's two resolved timestamps.
pub(crate) const PASS_BYTES: u64 = 16;

/// One kernel's device time over the passes timed so far.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct KernelTime {
    /// The kernel (its file under `shaders/` without `.wgsl`).
    pub kernel: &'static str,
    /// Passes (dispatches) timed.
    pub passes: usize,
    /// Median device time of one pass, µs.
    pub median_us: f64,
    /// Device time of all its passes, ms.
    pub total_ms: f64,
}

/// The query set, its buffers and the times collected (see the module documentation).
#[derive(Debug)]
pub(crate) struct KernelTimer {
    pub(crate) set: wgpu::QuerySet,
    /// Where the set resolves (`QUERY_RESOLVE | COPY_SRC`), `MAX_TIMED_PASSES` × 16 bytes.
    pub(crate) resolve: wgpu::Buffer,
    /// Where the resolved timestamps are copied for mapping.
    pub(crate) staging: wgpu::Buffer,
    /// Nanoseconds per timestamp tick.
    period_ns: f64,
    /// The kernels of the passes recorded since the last submit, in query order.
    pending: Vec<&'static str>,
    /// Device time of each pass, µs, per kernel.
    samples: BTreeMap<&'static str, Vec<f64>>,
    /// Passes that could not be timed (beyond `MAX_TIMED_PASSES` in one submit).
    pub(crate) untimed: u64,
}

impl KernelTimer {
    pub(crate) fn new(
        set: wgpu::QuerySet,
        resolve: wgpu::Buffer,
        staging: wgpu::Buffer,
        period_ns: f32,
    ) -> Self {
        KernelTimer {
            set,
            resolve,
            staging,
            period_ns: period_ns as f64,
            pending: Vec::new(),
            samples: BTreeMap::new(),
            untimed: 0,
        }
    }

    /// The timestamp writes of the next pass, a pass of `kernel`; `None` (counted untimed)
    /// when this submit already has `MAX_TIMED_PASSES` passes.
    pub(crate) fn pass_writes(
        &mut self,
        kernel: &'static str,
    ) -> Option<wgpu::ComputePassTimestampWrites<'_>> {
        let k = self.pending.len() as u32;
        if k >= MAX_TIMED_PASSES {
            self.untimed += 1;
            return None;
        }
        self.pending.push(kernel);
        Some(wgpu::ComputePassTimestampWrites {
            query_set: &self.set,
            beginning_of_pass_write_index: Some(2 * k),
            end_of_pass_write_index: Some(2 * k + 1),
        })
    }

    /// Appends to `encoder` the resolution of the pending passes' timestamps and their copy to
    /// the staging buffer; returns how many passes (0: nothing appended).
    pub(crate) fn resolve_into(&mut self, encoder: &mut wgpu::CommandEncoder) -> u32 {
        let n = self.pending.len() as u32;
        if n > 0 {
            encoder.resolve_query_set(&self.set, 0..2 * n, &self.resolve, 0);
            encoder.copy_buffer_to_buffer(
                &self.resolve,
                0,
                &self.staging,
                0,
                n as u64 * PASS_BYTES,
            );
        }
        n
    }

    /// Records the pending passes' times from their resolved timestamps (two `u64` per pass,
    /// start then end) and clears them.
    pub(crate) fn record(&mut self, timestamps: &[u64]) {
        for (kernel, pair) in self.pending.drain(..).zip(timestamps.chunks_exact(2)) {
            // A device may leave a pass's timestamps unordered (e.g. across a power-state
            // change); such a pass is not timed.
            if pair[1] >= pair[0] {
                let us = (pair[1] - pair[0]) as f64 * self.period_ns / 1e3;
                self.samples.entry(kernel).or_default().push(us);
            } else {
                self.untimed += 1;
            }
        }
    }

    /// Forgets the pending passes (their submit's timestamps could not be read).
    pub(crate) fn drop_pending(&mut self) {
        self.untimed += self.pending.len() as u64;
        self.pending.clear();
    }

    /// The time of each kernel timed so far, by kernel name.
    pub(crate) fn times(&self) -> Vec<KernelTime> {
        self.samples
            .iter()
            .map(|(&kernel, us)| {
                let mut sorted = us.clone();
                sorted.sort_by(f64::total_cmp);
                KernelTime {
                    kernel,
                    passes: us.len(),
                    median_us: sorted[sorted.len() / 2],
                    total_ms: us.iter().sum::<f64>() / 1e3,
                }
            })
            .collect()
    }
}

impl GpuContext {
    /// Whether the adapter has timestamp queries, so kernels can be timed on the device.
    pub fn has_kernel_timing(&self) -> bool {
        self.device
            .features()
            .contains(wgpu::Features::TIMESTAMP_QUERY)
    }

    /// Starts timing every kernel pass on the device ([`super::timing`]); `false` where the
    /// adapter has no timestamp queries. Timing assumes one thread records and submits at a
    /// time, and adds a wait to every submit.
    pub fn start_kernel_timing(&self) -> bool {
        if !self.has_kernel_timing() {
            return false;
        }
        let mut timer = self.timer.lock().unwrap_or_else(|e| e.into_inner());
        if timer.is_none() {
            let set = self.device.create_query_set(&wgpu::QuerySetDescriptor {
                label: Some("kernel_timing"),
                ty: wgpu::QueryType::Timestamp,
                count: 2 * MAX_TIMED_PASSES,
            });
            let bytes = MAX_TIMED_PASSES as u64 * PASS_BYTES;
            let buffer = |label, usage| {
                self.create_buffer(&wgpu::BufferDescriptor {
                    label: Some(label),
                    size: bytes,
                    usage,
                    mapped_at_creation: false,
                })
            };
            let resolve = buffer(
                "kernel_timing_resolve",
                wgpu::BufferUsages::QUERY_RESOLVE | wgpu::BufferUsages::COPY_SRC,
            );
            let staging = buffer(
                "kernel_timing_staging",
                wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            );
            let period = self.queue.get_timestamp_period();
            *timer = Some(KernelTimer::new(set, resolve, staging, period));
        }
        true
    }

    /// The device time of each kernel timed since [`GpuContext::start_kernel_timing`], by
    /// kernel name, and the passes that could not be timed.
    pub fn kernel_times(&self) -> (Vec<KernelTime>, u64) {
        let timer = self.timer.lock().unwrap_or_else(|e| e.into_inner());
        timer
            .as_ref()
            .map_or((Vec::new(), 0), |t| (t.times(), t.untimed))
    }

    /// Stops timing kernels and forgets the times.
    pub fn stop_kernel_timing(&self) {
        *self.timer.lock().unwrap_or_else(|e| e.into_inner()) = None;
    }
}

#[cfg(all(test, unix))]
mod thread_cpu_tests {
    use super::thread_cpu_s;
    use std::time::{Duration, Instant};

    #[test]
    fn the_threads_cpu_time_counts_its_work_not_its_sleep() {
        let before = thread_cpu_s();
        std::thread::sleep(Duration::from_millis(200));
        let slept_s = thread_cpu_s() - before;
        let (before, started) = (thread_cpu_s(), Instant::now());
        let mut x = 1u64;
        while started.elapsed() < Duration::from_millis(200) {
            x = std::hint::black_box(x.wrapping_mul(6364136223846793005).wrapping_add(1));
        }
        let worked_s = thread_cpu_s() - before;
        assert!(slept_s < 0.02, "200 ms asleep took {slept_s} s of CPU time");
        // A busy thread gets at least a quarter of a core on a loaded 2-core machine.
        assert!(
            (0.05..0.25).contains(&worked_s),
            "200 ms busy took {worked_s} s"
        );
    }
}
