//! The two passes of the streamed aggregation (see [`super`]): their buffers, the row claims
//! they share, and the loop over rows and pixels of one pass.

#[allow(unused_imports)]
use super::*;

/// Rows of a buffer that two threads share, each row used by one thread at a time (the claim
/// protocol of the module docs decides which).
pub(super) struct SharedRows<T> {
    pub(super) ptr: *mut T,
    pub(super) row_len: usize,
    pub(super) rows: usize,
}

// SAFETY: the buffer outlives the passes (it is borrowed for the whole `rayon::join`), and the
// claim protocol gives every row to one thread at a time; `row` documents the rule.
unsafe impl<T: Send> Send for SharedRows<T> {}
unsafe impl<T: Send> Sync for SharedRows<T> {}

impl<T> SharedRows<T> {
    pub(super) fn new(buf: &mut [T], row_len: usize, rows: usize) -> Self {
        assert!(
            buf.len() >= row_len * rows,
            "shared rows need {rows}×{row_len} values"
        );
        SharedRows {
            ptr: buf.as_mut_ptr(),
            row_len,
            rows,
        }
    }

    /// Row `y`.
    ///
    /// # Safety
    /// No other reference to row `y` may be alive: a row is written by the pass that claimed it
    /// until it publishes `STORED` (release), and afterwards used by the other pass only (after
    /// an acquire load of `STORED`).
    #[allow(clippy::mut_from_ref)]
    unsafe fn row(&self, y: usize) -> &mut [T] {
        assert!(y < self.rows);
        // SAFETY: in bounds (asserted above and in `new`); exclusive by the caller's contract.
        unsafe { std::slice::from_raw_parts_mut(self.ptr.add(y * self.row_len), self.row_len) }
    }

    /// Row `y`, to read.
    ///
    /// # Safety
    /// No mutable reference to row `y` may be alive (the claim protocol, as for
    /// [`SharedRows::row`]).
    unsafe fn row_ref(&self, y: usize) -> &[T] {
        assert!(y < self.rows);
        // SAFETY: in bounds (asserted above and in `new`); no writer by the caller's contract.
        unsafe { std::slice::from_raw_parts(self.ptr.add(y * self.row_len), self.row_len) }
    }
}

/// Buffers of one pass.
#[derive(Default, Debug)]
pub(super) struct PassScratch {
    /// Path costs in `u8` or `u16` ([`Cell`]).
    pub(super) narrow: PathRows<u8>,
    pub(super) wide: PathRows<u16>,
    /// The pass's path sum at one pixel (when it comes second to the row).
    pub(super) acc: Vec<u16>,
    pub(super) select: RowSelect,
}

/// A pass's rows of path costs: the previous row's, read, and the current row's, written.
#[derive(Default, Debug)]
pub(super) struct PathRows<T> {
    /// `L_r` of two rows, the previous and the current one (they swap roles every row), each
    /// `[x][dir][D + 2]`, padded with [`Cell::PAD`].
    pub(super) slots: Vec<T>,
    /// Their minima, two rows of `[x][dir]`.
    pub(super) slot_min: Vec<u16>,
    /// The horizontal path at the previous and current pixel: `[2][D + 2]`.
    pub(super) horiz: Vec<T>,
}

impl<T: Cell> PathRows<T> {
    pub(super) fn prepare(&mut self, w: usize, nd: usize, nr: usize) {
        let stride = nd + 2;
        fn fill<V: Copy>(v: &mut Vec<V>, n: usize, value: V) {
            v.clear();
            v.resize(n, value);
        }
        fill(&mut self.slots, 2 * w * nr * stride, T::PAD);
        fill(&mut self.slot_min, 2 * w * nr, 0);
        fill(&mut self.horiz, 2 * stride, T::PAD);
    }
}

/// Reusable buffers of the aggregation (kept by the matchers between pairs, so that the large
/// ones are not mapped in again for every frame).
#[derive(Default, Debug)]
pub(crate) struct AggregateScratch {
    /// The first pass's four-path sums, row by row (`w·h·D`, each row written by one pass).
    partial: Vec<u16>,
    /// With 5 paths, the raw costs' window sums of the sub-pixel fit, stored by the forward
    /// pass beside its sums (same rows, same places).
    window: Vec<u16>,
    passes: [PassScratch; 2],
}

/// Rows of the 5-path ring ([`super`]): 8 rows of `w·D` sums (2.5 MB at 1241 × 128), in the
/// last-level cache while the second pass reads them.
pub(crate) const RING_ROWS: usize = 8;

/// Where the stored rows live: a ring of [`RING_ROWS`] slots for rows before `full_from`, the
/// row's own place in the buffer from there on (always, without a ring).
pub(super) struct RowPlaces<'a> {
    /// Whether rows before `full_from` share the ring's slots.
    pub(super) ring: bool,
    /// First row stored in place; set (once, by the forward pass, before it publishes that row
    /// `STORED`) when the second pass had not started at the first full ring.
    pub(super) full_from: &'a AtomicUsize,
    /// Set by the second pass when it starts.
    pub(super) started: &'a AtomicBool,
}

impl RowPlaces<'_> {
    /// The buffer row of image row `y` (read after an acquire load of `y`'s `STORED`, which
    /// orders it after the `full_from` store that concerns `y`).
    fn slot(&self, y: usize) -> usize {
        if self.ring && y < self.full_from.load(Ordering::Relaxed) {
            y % RING_ROWS
        } else {
            y
        }
    }

    /// The forward pass, before it stores row `y`: waits until the row that last used `y`'s ring
    /// slot is consumed, or, when the second pass has not started (within [`START_WAIT`], and at
    /// once without a second worker), stores from `y` on in place.
    fn make_room(&self, claims: &[AtomicU8], y: usize) {
        if !self.ring || y < RING_ROWS || y >= self.full_from.load(Ordering::Relaxed) {
            return;
        }
        let before = &claims[y - RING_ROWS];
        if before.load(Ordering::Acquire) == CONSUMED {
            return;
        }
        let started = self.started.load(Ordering::Acquire)
            || rayon::current_num_threads() > 1 && wait_until(self.started, START_WAIT);
        if !started {
            // Published to the second pass by the release store of row y's STORED.
            self.full_from.store(y, Ordering::Relaxed);
            return;
        }
        // The second pass is running and needs no row after y − 1: it gets there.
        wait_for(before, CONSUMED);
    }
}

/// How long the forward pass waits at the first full ring for a second pass that has not
/// started. A worker that wakes late (a loaded machine: 1.5 ms was seen) would otherwise send
/// every later row through memory instead of the ring: 28 → 50–130 ms for a KITTI pair. When
/// no other worker takes the second pass in this time, it runs after the forward pass, on the
/// same thread, and the rows go in place.
const START_WAIT: std::time::Duration = std::time::Duration::from_millis(4);

/// Waits until `flag` is set (acquire) or `timeout` has passed; whether it was set.
fn wait_until(flag: &AtomicBool, timeout: std::time::Duration) -> bool {
    let t0 = std::time::Instant::now();
    let mut spins = 0u32;
    while !flag.load(Ordering::Acquire) {
        if t0.elapsed() > timeout {
            return false;
        }
        if spins < 256 {
            std::hint::spin_loop();
            spins += 1;
        } else {
            std::thread::yield_now();
        }
    }
    true
}

/// Inputs of both passes.
pub(super) struct Job<'a> {
    pub(super) volume: &'a CostVolume,
    pub(super) image: &'a [u8],
    pub(super) params: &'a SgmParams,
    pub(super) pen: Penalties,
    /// Column offsets of the previous-row predecessors (0 vertical, ±1 diagonal) of the
    /// forward and the backward pass; none: the pass carries the horizontal path only.
    pub(super) dxs: [&'a [isize]; 2],
    pub(super) finish: Finish,
    pub(super) claims: &'a [AtomicU8],
    pub(super) partial: SharedRows<u16>,
    /// The sub-pixel window sums of the stored rows, when the forward pass computes them
    /// (`window_radius > 0`).
    pub(super) window: SharedRows<u16>,
    pub(super) window_radius: usize,
    pub(super) places: RowPlaces<'a>,
    pub(super) disparity: SharedRows<f32>,
    pub(super) confidence: SharedRows<f32>,
}

/// Waits until `claim` reaches `state` (acquire).
pub(super) fn wait_for(claim: &AtomicU8, state: u8) {
    let mut spins = 0u32;
    while claim.load(Ordering::Acquire) != state {
        if spins < 256 {
            std::hint::spin_loop();
            spins += 1;
        } else {
            std::thread::yield_now();
        }
    }
}

/// One pass over every row (module docs).
#[inline(always)]
pub(super) fn run_pass_impl<I: Isa>(job: &Job, forward: bool, ps: &mut PassScratch) {
    let narrow = job.volume.max_cost as u16 + job.pen.p2 <= 254;
    match (job.dxs[usize::from(!forward)].len(), narrow) {
        (3, true) => run_pass_n::<3, 4, u8, I>(job, forward, ps),
        (3, false) => run_pass_n::<3, 4, u16, I>(job, forward, ps),
        (1, true) => run_pass_n::<1, 2, u8, I>(job, forward, ps),
        (1, false) => run_pass_n::<1, 2, u16, I>(job, forward, ps),
        (_, true) => run_pass_n::<0, 1, u8, I>(job, forward, ps),
        (_, false) => run_pass_n::<0, 1, u16, I>(job, forward, ps),
    }
}

/// The path rows of type `T` in `ps`.
pub(super) trait RowsOf<T> {
    fn rows_and_rest(&mut self) -> (&mut PathRows<T>, &mut Vec<u16>, &mut RowSelect);
}

impl RowsOf<u8> for PassScratch {
    fn rows_and_rest(&mut self) -> (&mut PathRows<u8>, &mut Vec<u16>, &mut RowSelect) {
        (&mut self.narrow, &mut self.acc, &mut self.select)
    }
}

impl RowsOf<u16> for PassScratch {
    fn rows_and_rest(&mut self) -> (&mut PathRows<u16>, &mut Vec<u16>, &mut RowSelect) {
        (&mut self.wide, &mut self.acc, &mut self.select)
    }
}

/// [`run_pass_impl`] with `NR` previous-row directions (`N = NR + 1` with the horizontal one)
/// and path costs stored as `T`. A pass with the horizontal path only (`NR = 0`: the right→left
/// path of 5 paths) needs no previous row: it visits the rows top to bottom right behind the
/// forward pass, which claims them all, and selects every row (the lighter pass takes the
/// selection, so that the two threads carry similar loads).
#[inline(always)]
pub(super) fn run_pass_n<const NR: usize, const N: usize, T: Cell, I: Isa>(
    job: &Job,
    forward: bool,
    ps: &mut PassScratch,
) where
    PassScratch: RowsOf<T>,
{
    let vol = job.volume;
    let (w, h, nd) = (vol.width as usize, vol.height as usize, vol.num_disparities);
    let stride = nd + 2;
    let dxs: [isize; NR] = std::array::from_fn(|r| job.dxs[usize::from(!forward)][r]);
    // Rows in the forward pass's order when this pass needs no previous row.
    let rows_down = forward || NR == 0;
    let (p1, pen) = (job.pen.p1, job.pen);
    let (rows, own, select) = ps.rows_and_rest();
    rows.prepare(w, nd, NR);
    // A new volume: no window sums to continue from.
    select.colsum_row = None;
    own.clear();
    own.resize(nd, 0);
    let PathRows {
        slots,
        slot_min,
        horiz,
    } = rows;
    let (row_len, min_len) = (w * NR * stride, w * NR);
    let mut hmin = 0u16;
    for step in 0..h {
        let y = if rows_down { step } else { h - 1 - step };
        let has_prev = step > 0;
        let y_prev = if !has_prev {
            y
        } else if rows_down {
            y - 1
        } else {
            y + 1
        };
        let img = &job.image[y * w..(y + 1) * w];
        let img_prev = &job.image[y_prev * w..(y_prev + 1) * w];
        let cost_row = &vol.cost[y * w * nd..(y + 1) * w * nd];
        let first = NR > 0
            && job.claims[y]
                .compare_exchange(FREE, CLAIMED, Ordering::AcqRel, Ordering::Acquire)
                .is_ok();
        // Second to the row, with a fused kernel: S of each pixel and its winner at once.
        let fused = !first && job.finish == Finish::Select && (N == 4 || N == 1);
        if first {
            job.places.make_room(job.claims, y);
        } else {
            wait_for(&job.claims[y], STORED);
            select.reset(w);
        }
        // SAFETY: the claim protocol (module docs): the claimer writes the row until it
        // publishes STORED; the other pass uses it only after seeing STORED, and a ring slot is
        // written again only after the row it held was published CONSUMED.
        let stored = unsafe { job.partial.row(job.places.slot(y)) };
        // This row's path costs and the previous row's: the two halves swap roles every row.
        let (lo, hi) = slots.split_at_mut(row_len);
        let (lo_min, hi_min) = slot_min.split_at_mut(min_len);
        let (prev, cur_row, prev_min, cur_min) = if step % 2 == 0 {
            (&*hi, lo, &*hi_min, lo_min)
        } else {
            (&*lo, hi, &*lo_min, hi_min)
        };
        // Whether the pixel at step `i` continues every path (the usual case).
        let inside_at = |i: usize| {
            if i == 0 || i >= w {
                return false;
            }
            let x = if forward { i } else { w - 1 - i } as isize;
            NR == 0 || has_prev && dxs.iter().all(|&dx| (0..w as isize).contains(&(x + dx)))
        };
        // The interior steps run in one call when the pass reaches the first of them: the first
        // pass to a row with four paths ([`path_row4`]), the second with its fused selection
        // ([`path_row_select`]).
        let interior = if (first && NR == 3 && N == 4 || fused) && inside_at(1) {
            1..(1..w).find(|&i| !inside_at(i)).unwrap_or(w)
        } else {
            0..0
        };
        for i in 0..w {
            if i == interior.start && !interior.is_empty() {
                let (h0, h1) = horiz.split_at_mut(stride);
                let a = RowSteps {
                    i0: interior.start,
                    i1: interior.end,
                    forward,
                    w,
                    nd,
                    dxs: std::array::from_fn(|r| dxs.get(r).copied().unwrap_or(0)),
                    img,
                    img_prev,
                    pen: &job.pen,
                    hmin,
                    dmin: job.params.min_disparity_px,
                    cost_row,
                    prev: (prev, prev, prev),
                    prev_min,
                };
                let h = (h0, h1);
                hmin = if first {
                    I::row4(&a, cur_row, cur_min, h, stored)
                } else {
                    let own = &mut own[..nd];
                    I::row_select::<NR, T>(&a, cur_row, cur_min, h, stored, own, select)
                };
            }
            if interior.contains(&i) {
                continue;
            }
            let x = if forward { i } else { w - 1 - i };
            let c = &cost_row[x * nd..(x + 1) * nd];
            if !first {
                // The other pass's sums were written long ago (they are in memory, not in the
                // cache): ask for those of a pixel a few steps ahead.
                let ahead = if forward {
                    x + PREFETCH_PX
                } else {
                    x.wrapping_sub(PREFETCH_PX)
                };
                if ahead < w {
                    prefetch(&stored[ahead * nd..(ahead + 1) * nd]);
                }
            }
            // Where the pass's sum goes: the stored row when first, else its own.
            let acc: &mut [u16] = if first {
                &mut stored[x * nd..(x + 1) * nd]
            } else {
                &mut own[..nd]
            };
            let (h0, h1) = horiz.split_at_mut(stride);
            let (hprev, hout) = if i % 2 == 0 { (&*h1, h0) } else { (&*h0, h1) };
            let sx = x * NR * stride;
            // Predecessors in the previous row, when every path continues (the usual case).
            let xps: [isize; NR] = std::array::from_fn(|r| x as isize + dxs[r]);
            let inside = inside_at(i);
            let outs = &mut cur_row[sx..sx + NR * stride];
            // Direction r's predecessor in the previous row (inside the image).
            let pred = |r: usize| -> (&[T], u16) {
                let xp = xps[r] as usize;
                let s0 = (xp * NR + r) * stride;
                (&prev[s0..s0 + stride], prev_min[xp * NR + r])
            };
            if inside {
                let xn = if forward { x - 1 } else { x + 1 };
                let mut p2 = [0u16; N];
                let mut pmin = [0u16; N];
                p2[0] = pen.p2_for(img[x], img[xn]);
                pmin[0] = hmin;
                let mut prevs: [&[T]; N] = [hprev; N];
                for r in 0..NR {
                    let xp = xps[r] as usize;
                    p2[r + 1] = pen.p2_for(img[x], img_prev[xp]);
                    let (pv, pm) = pred(r);
                    prevs[r + 1] = pv;
                    pmin[r + 1] = pm;
                }
                // (The fused steps of the second pass run in `path_row_select`.)
                let m: [u16; N] = if N == 1 {
                    let m = path_step::<true, T>(c, hprev, pmin[0], p1, p2[0], hout, acc);
                    std::array::from_fn(|_| m)
                } else if N == 4 {
                    let (o1, rest) = outs.split_at_mut(stride);
                    let (o2, o3) = rest.split_at_mut(stride);
                    let prevs = (prevs[0], prevs[1], prevs[2], prevs[3]);
                    let (pm, p2) = (
                        [pmin[0], pmin[1], pmin[2], pmin[3]],
                        [p2[0], p2[1], p2[2], p2[3]],
                    );
                    let m = I::steps4(c, (prevs, pm, p1, p2, [hout, o1, o2, o3], acc));
                    std::array::from_fn(|r| m[r])
                } else {
                    let prevs = (prevs[0], prevs[1]);
                    let m = I::steps2(
                        c,
                        prevs,
                        [pmin[0], pmin[1]],
                        p1,
                        [p2[0], p2[1]],
                        hout,
                        outs,
                        acc,
                    );
                    std::array::from_fn(|r| m[r])
                };
                hmin = m[0];
                cur_min[x * NR..(x + 1) * NR].copy_from_slice(&m[1..]);
            } else {
                // Path starts: the first row, the first pixel of the row, the image's sides.
                hmin = if i == 0 {
                    path_start::<true, T>(c, hout, acc)
                } else {
                    let xn = if forward { x - 1 } else { x + 1 };
                    let p2 = pen.p2_for(img[x], img[xn]);
                    path_step::<true, T>(c, hprev, hmin, p1, p2, hout, acc)
                };
                let mut m = [0u16; NR];
                for (r, out) in outs.chunks_exact_mut(stride).take(NR).enumerate() {
                    let xp = xps[r];
                    m[r] = if !has_prev || xp < 0 || xp >= w as isize {
                        path_start::<false, T>(c, out, acc)
                    } else {
                        let p2 = pen.p2_for(img[x], img_prev[xp as usize]);
                        let (pv, pm) = pred(r);
                        path_step::<false, T>(c, pv, pm, p1, p2, out, acc)
                    };
                }
                cur_min[x * NR..(x + 1) * NR].copy_from_slice(&m);
            }
            if !first {
                let theirs = &mut stored[x * nd..(x + 1) * nd];
                match job.finish {
                    Finish::Sum => {
                        for (t, &a) in theirs.iter_mut().zip(own.iter()) {
                            *t += a;
                        }
                    }
                    Finish::Select => {
                        for (a, &t) in own.iter_mut().zip(theirs.iter()) {
                            *a += t;
                        }
                        select.pixel::<I>(&own[..nd], x, w, job.params.min_disparity_px);
                    }
                }
            }
        }
        if first {
            if job.window_radius > 0 {
                // SAFETY: as for `stored`: row y's place is this pass's until it publishes
                // STORED, and row y − 1's (another place: the ring has more than one slot) is
                // only read, here and by the second pass.
                let (prev, out) = unsafe {
                    let prev = (step > 0).then(|| job.window.row_ref(job.places.slot(y - 1)));
                    (prev, job.window.row(job.places.slot(y)))
                };
                window_sums_into(vol, y, job.window_radius, prev, out);
            }
            job.claims[y].store(STORED, Ordering::Release);
        } else if job.finish == Finish::Select {
            // SAFETY: only the second pass to reach row y writes its output row; the window
            // sums of row y are read only, after STORED.
            let (disp, conf) = unsafe { (job.disparity.row(y), job.confidence.row(y)) };
            let window =
                (job.window_radius > 0).then(|| unsafe { job.window.row_ref(job.places.slot(y)) });
            select.finish(y, Some(vol), window, w, nd, job.params, disp, conf);
            if job.places.ring {
                job.claims[y].store(CONSUMED, Ordering::Release);
            }
        }
    }
}

/// [`run_pass_impl`], dispatched at run time to a copy compiled for AVX-512BW, AVX2 or the
/// baseline.
pub(super) fn run_pass(job: &Job, forward: bool, ps: &mut PassScratch) {
    #[cfg(target_arch = "x86_64")]
    {
        #[target_feature(enable = "avx512f,avx512bw,avx512vl,avx2,popcnt")]
        fn avx512(job: &Job, forward: bool, ps: &mut PassScratch) {
            run_pass_impl::<Avx512>(job, forward, ps)
        }
        #[target_feature(enable = "avx2,popcnt")]
        fn avx2(job: &Job, forward: bool, ps: &mut PassScratch) {
            run_pass_impl::<Avx2>(job, forward, ps)
        }
        if std::is_x86_feature_detected!("avx512bw")
            && std::is_x86_feature_detected!("avx512vl")
            && std::is_x86_feature_detected!("popcnt")
        {
            // SAFETY: the CPU supports the features the copy was compiled for (checked above).
            unsafe { avx512(job, forward, ps) };
            return;
        }
        if std::is_x86_feature_detected!("avx2") && std::is_x86_feature_detected!("popcnt") {
            // SAFETY: as above.
            unsafe { avx2(job, forward, ps) };
            return;
        }
    }
    run_pass_impl::<Baseline>(job, forward, ps)
}

/// Column offsets of the previous-row predecessors of the forward and the backward pass for
/// `paths`.
pub(super) fn predecessors(paths: SgmPaths) -> [&'static [isize]; 2] {
    match paths {
        SgmPaths::Four => [&[0], &[0]],
        SgmPaths::Five => [&[0, -1, 1], &[]],
        SgmPaths::Eight => [&[0, -1, 1], &[0, -1, 1]],
    }
}

/// Runs both passes (module docs) with `finish`; `partial` receives the stored rows.
#[allow(clippy::too_many_arguments)]
pub(super) fn run_passes(
    volume: &CostVolume,
    image: &[u8],
    params: &SgmParams,
    finish: Finish,
    scratch: &mut AggregateScratch,
    partial_out: Option<&mut Vec<u16>>,
    disparity: &mut [f32],
    confidence: &mut [f32],
) {
    let (w, h, nd) = (
        volume.width as usize,
        volume.height as usize,
        volume.num_disparities,
    );
    let n = w * h * nd;
    let partial = match partial_out {
        Some(p) => p,
        None => &mut scratch.partial,
    };
    if partial.len() != n {
        // calloc'd: rows no pass stores are never touched.
        *partial = vec![0u16; n];
    }
    let claims: Vec<AtomicU8> = (0..h).map(|_| AtomicU8::new(FREE)).collect();
    let dxs = predecessors(params.paths);
    let ring = finish == Finish::Select && dxs[1].is_empty();
    // With the ring, the forward pass computes the sub-pixel fit's window sums: the second
    // pass, one path and the whole selection, was the longer one.
    let window_radius = if ring {
        (params.subpixel_cost_window / 2) as usize
    } else {
        0
    };
    let window = &mut scratch.window;
    if window_radius > 0 && window.len() != n {
        *window = vec![0u16; n];
    }
    // The ring when the second pass selects right behind the forward pass (5 paths).
    let (full_from, started) = (AtomicUsize::new(h), AtomicBool::new(false));
    let job = Job {
        volume,
        image,
        params,
        pen: Penalties::of(params),
        dxs,
        finish,
        claims: &claims,
        partial: SharedRows::new(partial, w * nd, h),
        window: SharedRows::new(window, w * nd, if window_radius > 0 { h } else { 0 }),
        window_radius,
        places: RowPlaces {
            ring,
            full_from: &full_from,
            started: &started,
        },
        // Empty outputs when summing (no row is selected).
        disparity: SharedRows::new(disparity, w, if finish == Finish::Select { h } else { 0 }),
        confidence: SharedRows::new(confidence, w, if finish == Finish::Select { h } else { 0 }),
    };
    let [fwd, bwd] = &mut scratch.passes;
    rayon::join(
        || run_pass(&job, true, fwd),
        || {
            started.store(true, Ordering::Release);
            run_pass(&job, false, bwd)
        },
    );
}

/// Semi-global matching on `volume` (left image `image`): aggregation and selection streamed
/// together (module docs). Returns disparities (NaN invalid) and confidences, as
/// [`select_disparities`] of [`aggregate_paths`] would, bit for bit. `params` must be valid and
/// match the volume's disparity range; `image` must have the volume's size.
pub(crate) fn aggregate_and_select(
    volume: &CostVolume,
    image: &[u8],
    params: &SgmParams,
    scratch: &mut AggregateScratch,
) -> (Image<f32>, Image<f32>) {
    let (width, height) = (volume.width, volume.height);
    let mut disp = Image::filled(width, height, f32::NAN);
    let mut conf = Image::filled(width, height, 0.0f32);
    run_passes(
        volume,
        image,
        params,
        Finish::Select,
        scratch,
        None,
        &mut disp.data,
        &mut conf.data,
    );
    (disp, conf)
}

/// The aggregated costs `S(p, d)` summed over the configured directions, `u16`, layout of the
/// cost volume (the same passes, keeping every row).
pub(crate) fn aggregate_all(
    volume: &CostVolume,
    image: &[u8],
    params: &SgmParams,
    scratch: &mut AggregateScratch,
) -> Vec<u16> {
    let mut sum = Vec::new();
    run_passes(
        volume,
        image,
        params,
        Finish::Sum,
        scratch,
        Some(&mut sum),
        &mut [],
        &mut [],
    );
    sum
}
