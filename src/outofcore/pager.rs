//! Residency: which chunks live in RAM while the camera moves, within a byte budget.
//!
//! Before each frame the caller names the chunks the frame needs ([`Pager::page_in`]); chunks on
//! disk are read back (a revisit), new ones start empty. After the frame, [`Pager::evict_to_budget`]
//! moves the chunks farthest from the camera out of the layer and hands them to background writer
//! threads (crossbeam channel), which encode and write them (crash-safely, see [`crate::map::store`]).
//! Chunks still being written count against the budget. The chunks the current frame needs are
//! never evicted; if they alone exceed the budget the overrun is reported (an error, or a counted
//! warning with [`OverrunPolicy::Warn`]), never ignored.
//!
//! [`Pager::checkpoint`] writes every dirty resident chunk, waits for the writers and commits the
//! manifest with the number of frames fused, which is where a killed run resumes.
//!
//! The pager never changes voxel values: fusing through it gives the same bits as fusing into one
//! in-memory layer, provided the caller pages in every chunk the frame can update (tested).

use crate::error::{Error, Result};
use crate::grid::{
    eviction_order, Block, BlockIndex, EvictionCandidate, Layer, BLOCK_RESIDENT_BYTES,
};
use crate::map::store::{ChunkWriter, MapStore, WrittenChunk};
use crate::map::{group_by_chunk, ChunkIndex};
use crossbeam::channel::{bounded, unbounded, Receiver, Sender};
use std::collections::{HashMap, HashSet, VecDeque};

/// What to do when the chunks one frame needs do not fit in the budget.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum OverrunPolicy {
    /// Stop with an error that says how much was needed.
    Error,
    /// Go on over budget, log a warning and count it in [`PagerStats::budget_overruns`].
    Warn,
}

/// Pager settings.
#[derive(Clone, Copy, Debug)]
pub struct PagerConfig {
    /// Bytes of voxel blocks (resident plus being written) the pager evicts down to after each
    /// frame: the blocks' share of the memory budget ([`crate::memory::data_share_bytes`]). One
    /// frame's own chunks may use the process's reserve beyond it; past the whole budget
    /// ([`crate::memory::budget_for_data_bytes`] of this) the frame is an overrun.
    pub budget_bytes: u64,
    /// Reaction to a frame whose working set exceeds the budget.
    pub overrun: OverrunPolicy,
    /// Background writer threads.
    pub writer_threads: usize,
}

impl PagerConfig {
    /// A budget with the default policy (error on overrun) and two writer threads.
    pub fn with_budget(budget_bytes: u64) -> Self {
        PagerConfig {
            budget_bytes,
            overrun: OverrunPolicy::Error,
            writer_threads: 2,
        }
    }
}

/// Counters of a paging run.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct PagerStats {
    /// Chunks read back from disk (revisits, loops, resumes).
    pub chunks_read: u64,
    /// Chunk files written (evictions and checkpoints).
    pub chunks_written: u64,
    /// Chunks evicted from RAM.
    pub chunks_evicted: u64,
    /// Bytes of chunk files written.
    pub bytes_written: u64,
    /// Largest resident + in-flight block bytes seen after a frame's eviction.
    pub peak_bytes: u64,
    /// Frames whose working set alone exceeded the whole budget.
    pub budget_overruns: u64,
    /// Seconds the caller's thread spent reading chunks.
    pub read_s: f64,
    /// Seconds the caller's thread waited for writers (back-pressure and checkpoints).
    pub wait_s: f64,
}

struct WriteJob {
    chunk: ChunkIndex,
    seq: u64,
    blocks: Vec<(BlockIndex, Box<Block>)>,
    bytes: u64,
}

struct WriteDone {
    chunk: ChunkIndex,
    bytes: u64,
    result: Result<WrittenChunk>,
}

#[derive(Clone, Copy, Debug)]
struct Resident {
    dirty: bool,
}

/// The hook [`Pager::evict_to_budget_with`] calls with the resident layer, the held layer and
/// the blocks about to leave RAM; true where their newer copies come later.
pub type BeforeEvict<'a> = dyn FnMut(&mut Layer, &mut Layer, &[BlockIndex]) -> Result<bool> + 'a;

/// Evicted dirty chunks whose blocks wait for a tier's copies before they go to the writers.
struct Held {
    layer: Layer,
    chunks: HashMap<ChunkIndex, u64>,
    bytes: u64,
    releases: VecDeque<Vec<ChunkIndex>>,
}

/// The paging state around one layer of resident blocks.
pub struct Pager {
    store: MapStore,
    layer: Layer,
    config: PagerConfig,
    resident: HashMap<ChunkIndex, Resident>,
    in_flight: HashMap<ChunkIndex, u64>,
    in_flight_bytes: u64,
    /// Evicted chunks waiting for the tier above to send its copies of their blocks
    /// ([`Pager::evict_to_budget_with`]): their blocks, their bytes, and per release begun,
    /// oldest first, the chunks it holds back.
    held: Held,
    jobs: Option<Sender<WriteJob>>,
    done: Receiver<WriteDone>,
    workers: Vec<std::thread::JoinHandle<()>>,
    stats: PagerStats,
    first_error: Option<Error>,
    /// Evicted blocks' memory back to the kernel when the process passes the budget.
    trim: crate::memory::TrimAbove,
}

impl Pager {
    /// A pager over `store` (its committed chunks stay on disk until needed).
    pub fn new(store: MapStore, config: PagerConfig) -> Self {
        let grid = store.grid();
        let layer = Layer::new(grid);
        let (jobs_tx, jobs_rx) = bounded::<WriteJob>(config.writer_threads.max(1) * 2);
        let (done_tx, done_rx) = unbounded::<WriteDone>();
        let workers = (0..config.writer_threads.max(1))
            .map(|k| {
                let rx = jobs_rx.clone();
                let tx = done_tx.clone();
                let writer: ChunkWriter = store.writer();
                std::thread::Builder::new()
                    .name(format!("denser-chunk-writer-{k}"))
                    .spawn(move || {
                        for job in rx {
                            let refs: Vec<(BlockIndex, &Block)> =
                                job.blocks.iter().map(|(i, b)| (*i, &**b)).collect();
                            let result = writer.write(job.chunk, job.seq, &refs, 0);
                            drop(refs);
                            drop(job.blocks);
                            if tx
                                .send(WriteDone {
                                    chunk: job.chunk,
                                    bytes: job.bytes,
                                    result,
                                })
                                .is_err()
                            {
                                break;
                            }
                        }
                    })
                    .expect("spawning a chunk writer thread")
            })
            .collect();
        Pager {
            store,
            layer,
            config,
            resident: HashMap::new(),
            in_flight: HashMap::new(),
            in_flight_bytes: 0,
            held: Held {
                layer: Layer::new(grid),
                chunks: HashMap::new(),
                bytes: 0,
                releases: VecDeque::new(),
            },
            jobs: Some(jobs_tx),
            done: done_rx,
            workers,
            stats: PagerStats::default(),
            first_error: None,
            trim: crate::memory::TrimAbove::new(crate::memory::budget_for_data_bytes(
                config.budget_bytes,
            )),
        }
    }

    /// The resident blocks (fusion runs on this layer).
    pub fn layer(&self) -> &Layer {
        &self.layer
    }

    /// Mutable access to the resident blocks. Call [`Pager::mark_dirty`] with what was touched.
    pub fn layer_mut(&mut self) -> &mut Layer {
        &mut self.layer
    }

    /// The store behind the pager.
    pub fn store(&self) -> &MapStore {
        &self.store
    }

    /// Mutable access to the store (progress fields of the manifest).
    pub fn store_mut(&mut self) -> &mut MapStore {
        &mut self.store
    }

    /// Counters so far.
    pub fn stats(&self) -> PagerStats {
        self.stats
    }

    /// Chunk edge, blocks.
    pub fn chunk_blocks(&self) -> u32 {
        self.store.chunk_blocks()
    }

    /// Whether chunk `c` exists anywhere (resident, held, being written, or on disk).
    pub fn knows(&self, c: ChunkIndex) -> bool {
        self.resident.contains_key(&c)
            || self.held.chunks.contains_key(&c)
            || self.in_flight.contains_key(&c)
            || self.store.contains(c)
    }

    /// Every chunk that exists (resident, held, in flight or on disk), unsorted.
    pub fn known_chunks(&self) -> HashSet<ChunkIndex> {
        let mut s: HashSet<ChunkIndex> = self.store.chunk_indices().into_iter().collect();
        s.extend(self.resident.keys().copied());
        s.extend(self.held.chunks.keys().copied());
        s.extend(self.in_flight.keys().copied());
        s
    }

    /// Bytes of blocks resident, held for a tier's copies, or being written.
    pub fn used_bytes(&self) -> u64 {
        self.layer.block_count() as u64 * BLOCK_RESIDENT_BYTES
            + self.held.bytes
            + self.in_flight_bytes
    }

    /// The blocks of evicted chunks that wait for the copies of the tier above (where a tier's
    /// [`crate::store::UpperTier::collect_released`] writes them).
    pub fn held_layer_mut(&mut self) -> &mut Layer {
        &mut self.held.layer
    }

    /// Whether a chunk among `chunks` waits for the tier's copies of its blocks.
    pub fn holds_any<'a>(&self, chunks: impl IntoIterator<Item = &'a ChunkIndex>) -> bool {
        !self.held.chunks.is_empty() && chunks.into_iter().any(|c| self.held.chunks.contains_key(c))
    }

    /// Releases begun by the tier whose copies have not come: see [`Pager::complete_held`].
    pub fn held_releases(&self) -> usize {
        self.held.releases.len()
    }

    /// Sends to the writers the chunks of the `releases` oldest releases, whose copies the
    /// tier has written into [`Pager::held_layer_mut`].
    pub fn complete_held(&mut self, releases: usize) -> Result<()> {
        for _ in 0..releases {
            let chunks = self.held.releases.pop_front().ok_or_else(|| {
                Error::InvalidArgument("a tier completed a release the pager did not begin".into())
            })?;
            for c in chunks {
                let bytes = self.held.chunks.remove(&c).expect("a held chunk");
                self.held.bytes -= bytes;
                let cb = self.chunk_blocks();
                let mut indices: Vec<BlockIndex> = (self.held.layer.iter_unsorted())
                    .map(|(i, _)| *i)
                    .filter(|i| c.contains(*i, cb))
                    .collect();
                indices.sort_unstable();
                let blocks = self.held.layer.take_blocks(&indices);
                self.write_behind(c, blocks)?;
            }
        }
        Ok(())
    }

    fn absorb(&mut self, d: WriteDone) {
        self.in_flight_bytes -= d.bytes;
        self.in_flight.remove(&d.chunk);
        match d.result {
            Ok(w) => {
                self.stats.chunks_written += 1;
                self.stats.bytes_written += w.entry.file_bytes;
                self.store.record(w);
            }
            Err(e) => {
                if self.first_error.is_none() {
                    self.first_error = Some(e);
                }
            }
        }
    }

    fn drain_done(&mut self) -> Result<()> {
        while let Ok(d) = self.done.try_recv() {
            self.absorb(d);
        }
        self.take_error()
    }

    fn take_error(&mut self) -> Result<()> {
        match self.first_error.take() {
            Some(e) => Err(e),
            None => Ok(()),
        }
    }

    fn wait_for(&mut self, pred: impl Fn(&Self) -> bool) -> Result<()> {
        let t = std::time::Instant::now();
        while !pred(self) {
            match self.done.recv() {
                Ok(d) => self.absorb(d),
                Err(_) => break,
            }
        }
        self.stats.wait_s += t.elapsed().as_secs_f64();
        self.take_error()
    }

    /// Makes every chunk in `chunks` resident: read back from disk when the map holds it (after
    /// its pending write, if it is being written), empty otherwise.
    pub fn page_in(&mut self, chunks: &[ChunkIndex]) -> Result<()> {
        self.drain_done()?;
        for &c in chunks {
            if self.resident.contains_key(&c) {
                continue;
            }
            if self.held.chunks.contains_key(&c) {
                return Err(Error::InvalidArgument(format!(
                    "chunk {:?} was paged in while it waits for the GPU's copies of its blocks",
                    c.0
                )));
            }
            if self.in_flight.contains_key(&c) {
                self.wait_for(|p| !p.in_flight.contains_key(&c))?;
            }
            let t = std::time::Instant::now();
            if let Some(d) = self.store.read_chunk(c)? {
                self.layer.put_blocks(d.blocks);
                self.stats.chunks_read += 1;
            }
            self.stats.read_s += t.elapsed().as_secs_f64();
            self.resident.insert(c, Resident { dirty: false });
        }
        Ok(())
    }

    /// Marks the chunks of `touched` blocks as modified (they will be written before eviction and
    /// at checkpoints), and counts their blocks.
    pub fn mark_dirty(&mut self, touched: &[BlockIndex]) {
        let cb = self.chunk_blocks();
        for (c, _) in group_by_chunk(touched.iter().copied(), cb) {
            self.resident
                .entry(c)
                .or_insert(Resident { dirty: true })
                .dirty = true;
        }
    }

    fn blocks_of(&self, c: ChunkIndex) -> Vec<BlockIndex> {
        let cb = self.chunk_blocks();
        let o = c.origin_block(cb);
        let n = cb as i32;
        let mut v = Vec::new();
        // Walk the layer's blocks when the chunk is large relative to what is resident.
        if (n as usize).pow(3) > self.layer.block_count() {
            v.extend(
                self.layer
                    .iter_unsorted()
                    .map(|(i, _)| *i)
                    .filter(|i| c.contains(*i, cb)),
            );
        } else {
            for z in 0..n {
                for y in 0..n {
                    for x in 0..n {
                        let b = BlockIndex([o[0] + x, o[1] + y, o[2] + z]);
                        if self.layer.contains(&b) {
                            v.push(b);
                        }
                    }
                }
            }
        }
        v.sort_unstable();
        v
    }

    /// Whether [`Pager::evict_to_budget`] with `keep` would evict a chunk now: the used bytes
    /// exceed the budget and a chunk outside `keep` is resident.
    pub fn needs_eviction(&mut self, keep: &HashSet<ChunkIndex>) -> Result<bool> {
        self.drain_done()?;
        Ok(self.used_bytes() > self.config.budget_bytes
            && self.resident.keys().any(|c| !keep.contains(c)))
    }

    /// Evicts chunks, farthest from `camera_world_m` first, until the used bytes fit the budget;
    /// chunks in `keep` (the current frame's working set) stay. Dirty chunks go to the writers;
    /// clean ones are dropped (their file is current).
    pub fn evict_to_budget(
        &mut self,
        camera_world_m: [f64; 3],
        keep: &HashSet<ChunkIndex>,
    ) -> Result<()> {
        self.evict_to_budget_with(camera_world_m, keep, &mut |_, _, _| Ok(false))
    }

    /// [`Pager::evict_to_budget`] calling `before_evict(layer, held, blocks)` once, with the
    /// blocks of every chunk about to leave RAM, just before they leave: the hook of a tier
    /// above RAM (the GPU's resident blocks, through
    /// [`crate::store::UpperTier::release_later`]) to write its newer copies back, in one
    /// readback. Where the hook says the copies come later (true), the dirty chunks wait in
    /// the held layer (counted as used) until [`Pager::complete_held`] sends them to the
    /// writers, and neither [`Pager::page_in`] nor [`Pager::checkpoint`] accepts them before.
    /// Chunks leave in [`eviction_order`], the order every tier uses.
    pub fn evict_to_budget_with(
        &mut self,
        camera_world_m: [f64; 3],
        keep: &HashSet<ChunkIndex>,
        before_evict: &mut BeforeEvict<'_>,
    ) -> Result<()> {
        self.drain_done()?;
        if self.used_bytes() > self.config.budget_bytes {
            let grid = self.store.grid();
            let chunk_m = grid.block_size_m() * self.chunk_blocks() as f64;
            // The RAM tier does not track use: farthest first (then by chunk).
            let candidates: Vec<EvictionCandidate<ChunkIndex>> = self
                .resident
                .keys()
                .filter(|c| !keep.contains(c))
                .map(|c| EvictionCandidate {
                    key: *c,
                    centre_m: [0, 1, 2].map(|a| (c.0[a] as f64 + 0.5) * chunk_m),
                    last_used: 0,
                })
                .collect();
            // The chunks to evict, chosen first so that the tier above writes their blocks
            // back at once (one readback, not one per chunk): a clean chunk's bytes leave at
            // once, a dirty one's count until its writer is done (as in `evict`).
            let mut used = self.used_bytes();
            let mut chosen: Vec<(ChunkIndex, Vec<BlockIndex>)> = Vec::new();
            for c in eviction_order(candidates, camera_world_m) {
                if used <= self.config.budget_bytes {
                    break;
                }
                let indices = self.blocks_of(c);
                if !self.resident[&c].dirty || indices.is_empty() {
                    used -= indices.len() as u64 * BLOCK_RESIDENT_BYTES;
                }
                chosen.push((c, indices));
            }
            let mut later = false;
            if !chosen.is_empty() {
                let all: Vec<BlockIndex> = chosen.iter().flat_map(|(_, b)| b).copied().collect();
                later = before_evict(&mut self.layer, &mut self.held.layer, &all)?;
            }
            let mut held = Vec::new();
            for (c, indices) in chosen {
                if later && self.resident[&c].dirty && !indices.is_empty() {
                    self.hold(c, &indices);
                    held.push(c);
                } else {
                    self.evict(c, &indices)?;
                }
            }
            if later {
                self.held.releases.push_back(held);
            }
        }
        self.trim.check();
        let used = self.used_bytes();
        self.stats.peak_bytes = self.stats.peak_bytes.max(used);
        // A frame whose chunks alone pass the blocks' share may borrow the process's reserve:
        // only beyond the whole budget is it an overrun.
        let limit = crate::memory::budget_for_data_bytes(self.config.budget_bytes);
        if used > limit {
            self.stats.budget_overruns += 1;
            let msg = format!(
                "memory budget of {} MiB exceeded: the current frame's {} chunks need {:.1} MiB resident; use a --memory-budget of at least {} MiB (this frame's need and half again: frames ahead may need more, and larger budgets plan larger chunks)",
                limit.div_ceil(1 << 20),
                keep.len(),
                used as f64 / (1u64 << 20) as f64,
                suggested_budget_mib(used)
            );
            match self.config.overrun {
                OverrunPolicy::Error => return Err(Error::InvalidArgument(msg)),
                OverrunPolicy::Warn => tracing::warn!("{msg}"),
            }
        }
        Ok(())
    }

    /// Evicts resident chunk `c` of blocks `indices` (the tier above has written them back).
    fn evict(&mut self, c: ChunkIndex, indices: &[BlockIndex]) -> Result<()> {
        let r = self.resident.remove(&c).expect("a resident chunk");
        let blocks = self.layer.take_blocks(indices);
        self.stats.chunks_evicted += 1;
        if !r.dirty || blocks.is_empty() {
            return Ok(());
        }
        self.write_behind(c, blocks)
    }

    /// Evicts dirty resident chunk `c` of blocks `indices` into the held layer, where the tier
    /// above writes its copies ([`Pager::evict_to_budget_with`]).
    fn hold(&mut self, c: ChunkIndex, indices: &[BlockIndex]) {
        self.resident.remove(&c).expect("a resident chunk");
        let blocks = self.layer.take_blocks(indices);
        self.stats.chunks_evicted += 1;
        let bytes = blocks.len() as u64 * BLOCK_RESIDENT_BYTES;
        self.held.layer.put_blocks(blocks);
        self.held.chunks.insert(c, bytes);
        self.held.bytes += bytes;
    }

    /// Hands an evicted chunk's `blocks` to the writers.
    fn write_behind(&mut self, c: ChunkIndex, blocks: Vec<(BlockIndex, Box<Block>)>) -> Result<()> {
        let bytes = blocks.len() as u64 * BLOCK_RESIDENT_BYTES;
        let seq = self.store.allocate_seq();
        self.in_flight.insert(c, bytes);
        self.in_flight_bytes += bytes;
        self.send(WriteJob {
            chunk: c,
            seq,
            blocks,
            bytes,
        })
    }

    fn send(&mut self, job: WriteJob) -> Result<()> {
        let t = std::time::Instant::now();
        let tx = self.jobs.clone().expect("writers alive until finish");
        let mut job = job;
        loop {
            match tx.try_send(job) {
                Ok(()) => break,
                Err(crossbeam::channel::TrySendError::Full(j)) => {
                    job = j;
                    // Back-pressure: absorb a finished write while the queue is full.
                    if let Ok(d) = self.done.recv_timeout(std::time::Duration::from_millis(50)) {
                        self.absorb(d);
                    }
                }
                Err(crossbeam::channel::TrySendError::Disconnected(_)) => {
                    return Err(Error::InvalidArgument(
                        "chunk writer threads stopped".into(),
                    ));
                }
            }
        }
        self.stats.wait_s += t.elapsed().as_secs_f64();
        Ok(())
    }

    /// Writes every dirty resident chunk (blocks stay resident), waits for all writes and commits
    /// the manifest with `frames_committed`. Resident chunks are encoded in parallel straight from
    /// the layer (no copies), so a checkpoint needs no memory beyond the encoded bytes.
    pub fn checkpoint(&mut self, frames_committed: u64) -> Result<()> {
        use rayon::prelude::*;
        if !self.held.releases.is_empty() || self.held.layer.block_count() > 0 {
            return Err(Error::InvalidArgument(format!(
                "a checkpoint before the GPU's copies of {} evicted blocks came back",
                self.held.layer.block_count()
            )));
        }
        let t = std::time::Instant::now();
        self.wait_for(|p| p.in_flight.is_empty())?;
        let mut dirty: Vec<ChunkIndex> = self
            .resident
            .iter()
            .filter(|(_, r)| r.dirty)
            .map(|(c, _)| *c)
            .collect();
        dirty.sort_unstable();
        let lists: Vec<(ChunkIndex, Vec<BlockIndex>)> = dirty
            .iter()
            .map(|&c| (c, self.blocks_of(c)))
            .filter(|(_, b)| !b.is_empty())
            .collect();
        let jobs: Vec<(ChunkIndex, u64, Vec<BlockIndex>)> = lists
            .into_iter()
            .map(|(c, b)| (c, self.store.allocate_seq(), b))
            .collect();
        let writer = self.store.writer();
        let layer = &self.layer;
        let written: Vec<Result<WrittenChunk>> = jobs
            .par_iter()
            .map(|(c, seq, indices)| {
                let refs: Vec<(BlockIndex, &Block)> = indices
                    .iter()
                    .map(|i| (*i, layer.get(i).expect("listed block")))
                    .collect();
                writer.write(*c, *seq, &refs, 0)
            })
            .collect();
        for w in written {
            let w = w?;
            self.stats.chunks_written += 1;
            self.stats.bytes_written += w.entry.file_bytes;
            self.store.record(w);
        }
        for c in dirty {
            if let Some(r) = self.resident.get_mut(&c) {
                r.dirty = false;
            }
        }
        self.store.header_mut().frames_committed = frames_committed;
        self.store.commit()?;
        self.stats.wait_s += t.elapsed().as_secs_f64();
        Ok(())
    }

    /// Final checkpoint; stops the writers and returns the store and the counters.
    pub fn finish(mut self, frames_committed: u64) -> Result<(MapStore, PagerStats)> {
        self.checkpoint(frames_committed)?;
        // Dropping the sender ends the writers' loops; they are idle after the checkpoint.
        self.jobs = None;
        for w in self.workers.drain(..) {
            let _ = w.join();
        }
        Ok((self.store, self.stats))
    }
}

/// The budget, MiB, suggested when a frame's chunks need `used_bytes`: half again as much,
/// rounded up to 16 MiB. Not the frame's need alone: the frames ahead of it may need more, and a
/// larger budget plans larger chunks, which hold more blocks beyond the frame's (measured on the
/// 60 m drive: 19 MiB refused for 37.7 MiB, 38 for 41.1, 56 for 56.5; 64 ran with a 56.9 MiB
/// peak; `tests/cli/map.rs`).
pub(crate) fn suggested_budget_mib(used_bytes: u64) -> u64 {
    (used_bytes + used_bytes / 2).div_ceil(16 << 20) * 16
}
