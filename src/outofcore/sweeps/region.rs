//! One region of a sweep: its blocks' state gathered from the state files of the step before and
//! decoded into a problem; after the solve, the state of its own blocks written (steps before the
//! last), or its chunk files with `u` (the last step).

use super::super::region_plan::MapRegularizeStats;
use super::super::sweep_state::{
    decode_block_into, decode_state_index, encode_dense_record, encode_state, encode_state_with,
    BlockState, DenseBlock, StateHeader, STATE_BYTES_PER_OMEGA_VOXEL, STATE_MASK_BYTES,
};
use super::{state_name, write_state_file};
use crate::error::{Error, Result};
use crate::grid::{decode_tsdf, Block, BlockIndex, Layer, VOXELS_PER_BLOCK};
use crate::map::codec::PreviousFrames;
use crate::map::files::{MapFiles, ObjectBytes};
use crate::map::layout::SWEEPS_AREA;
use crate::map::store::{MapStore, WrittenChunk};
use crate::map::ChunkIndex;
use crate::regularize::TvProblem;
use rayon::prelude::*;
use std::collections::BTreeMap;

/// The stored blocks one region of a sweep gathers (its own and its halo's), sorted by index,
/// with the state files their records are in.
pub(super) struct Gathered {
    files: Vec<(std::path::PathBuf, ObjectBytes)>,
    pub blocks: Vec<GatheredBlock>,
}

/// One gathered block: where its record is, and whether it is the region's own.
pub(super) struct GatheredBlock {
    index: BlockIndex,
    file: usize,
    record: std::ops::Range<usize>,
    crc: u32,
    pub core: bool,
}

impl GatheredBlock {
    /// Its Ω voxels, as its record's length says (checked when it is decoded).
    pub fn omega_voxels(&self) -> u64 {
        (self.record.len().saturating_sub(STATE_MASK_BYTES) / STATE_BYTES_PER_OMEGA_VOXEL) as u64
    }
}

/// The problem over the gathered blocks, each record decoded straight into the solver's arrays,
/// for `iterations` iterations keeping the blocks in `core` (lowest and highest block index):
/// halo blocks are updated only while they can still reach the core
/// ([`TvProblem::limit_updates_to_reach`]).
pub(super) fn problem_from_gathered(
    g: &Gathered,
    core: ([i32; 3], [i32; 3]),
    iterations: u32,
) -> Result<TvProblem> {
    let vb = VOXELS_PER_BLOCK;
    let n = g.blocks.len() * vb;
    let [mut f, mut w, mut u, mut ubar] = [(); 4].map(|_| vec![0.0f32; n]);
    let mut omega = vec![false; n];
    let mut p = vec![0.0f32; 3 * n];
    let (px, rest) = p.split_at_mut(n);
    let (py, pz) = rest.split_at_mut(n);
    // Decoded on a worker of the pool, so that the loop's tasks start there rather than with a
    // wake-up from outside (the arrays stay allocated by the calling thread).
    rayon::scope(|_| {
        f.par_chunks_mut(vb)
            .zip(w.par_chunks_mut(vb))
            .zip(omega.par_chunks_mut(vb))
            .zip(u.par_chunks_mut(vb))
            .zip(ubar.par_chunks_mut(vb))
            .zip(px.par_chunks_mut(vb))
            .zip(py.par_chunks_mut(vb))
            .zip(pz.par_chunks_mut(vb))
            .zip(g.blocks.par_iter())
            .try_for_each(|((((((((f, w), omega), u), ubar), px), py), pz), b)| {
                let (path, bytes) = &g.files[b.file];
                let out = DenseBlock {
                    f,
                    w,
                    omega,
                    u,
                    ubar,
                    p: [px, py, pz],
                };
                decode_block_into(path, bytes, (&b.index, &b.record, b.crc), out)
            })
    })?;
    let blocks = g.blocks.iter().map(|b| b.index).collect();
    let mut problem = TvProblem::from_state(blocks, [f, w, u, ubar], omega, p);
    problem.limit_updates_to_reach(core, iterations);
    Ok(problem)
}

/// Appends to `out` the state record of the problem's block slot `slot`.
fn encode_slot(problem: &TvProblem, slot: usize, out: &mut Vec<u8>) {
    let vb = VOXELS_PER_BLOCK;
    let (u, ubar, p) = problem.state();
    let n = u.len();
    let r = slot * vb..(slot + 1) * vb;
    let mask = &problem.masks()[r.clone()];
    encode_dense_record(
        out,
        |i| mask[i] & TvProblem::OMEGA_BIT != 0,
        [
            &problem.f[r.clone()],
            &problem.w[r.clone()],
            &u[r.clone()],
            &ubar[r.clone()],
        ],
        [0, 1, 2].map(|d| &p[d * n + r.start..d * n + r.end]),
    );
}

/// Indexes the state of step `step − 1` of every stored block in `bounds` (blocks) from the
/// chunks `c_lo ..= c_hi`, marking the blocks of chunks `is_core` says are the region's; the
/// records are decoded by [`problem_from_gathered`].
pub(super) fn gather_states(
    store: &MapStore,
    key: u64,
    step: u32,
    c_lo: [i32; 3],
    c_hi: [i32; 3],
    bounds: ([i32; 3], [i32; 3]),
    is_core: impl Fn(ChunkIndex) -> bool,
) -> Result<Gathered> {
    let files = store.files();
    let (lo, hi) = bounds;
    let mut out = Gathered {
        files: Vec::new(),
        blocks: Vec::new(),
    };
    for cz in c_lo[2]..=c_hi[2] {
        for cy in c_lo[1]..=c_hi[1] {
            for cx in c_lo[0]..=c_hi[0] {
                let c = ChunkIndex([cx, cy, cz]);
                if !store.contains(c) {
                    continue;
                }
                let name = state_name((step - 1) % 2, c);
                let path = files.path(&name);
                let Some(bytes) = files.read(&name)? else {
                    return Err(Error::bad_input(
                        &path,
                        format!(
                            "the state of step {} is missing (a map changed under a swept pass?); delete {SWEEPS_AREA}/ to restart the pass",
                            step - 1
                        ),
                    ));
                };
                let index = decode_state_index(&path, &bytes)?;
                let h = index.header;
                // Name only what differs (issue 36: a swapped file read "another pass (key K),
                // expected key K").
                let mut differs = Vec::new();
                if h.key != key {
                    differs.push(format!(
                        "it belongs to another pass (key {:016x}, this pass {key:016x})",
                        h.key
                    ));
                }
                if h.chunk != c.0 {
                    differs.push(format!(
                        "it holds chunk {:?}, not {:?} (a file copied from another chunk?)",
                        h.chunk, c.0
                    ));
                }
                if h.step != step - 1 {
                    differs.push(format!(
                        "it is the state after step {}, not {}",
                        h.step,
                        step - 1
                    ));
                }
                if !differs.is_empty() {
                    return Err(Error::bad_input(
                        &path,
                        format!(
                            "not the state this sweep needs: {}; delete {SWEEPS_AREA}/ to restart the pass",
                            differs.join("; ")
                        ),
                    ));
                }
                let core = is_core(c);
                let file = out.files.len();
                out.blocks.extend(
                    index
                        .entries
                        .into_iter()
                        .filter(|(b, _, _)| (0..3).all(|a| b.0[a] >= lo[a] && b.0[a] <= hi[a]))
                        .map(|(index, record, crc)| GatheredBlock {
                            index,
                            file,
                            record,
                            crc,
                            core,
                        }),
                );
                out.files.push((path, bytes));
            }
        }
    }
    out.blocks.sort_unstable_by_key(|b| b.index);
    Ok(out)
}

/// Writes the state of the region's own blocks after step `step`, one file per chunk; the
/// problem's slots are the positions in `blocks`.
pub(super) fn write_states(
    files: &dyn MapFiles,
    problem: &TvProblem,
    blocks: &[GatheredBlock],
    key: u64,
    step: u32,
    store: &MapStore,
) -> Result<()> {
    let cb = store.chunk_blocks();
    let mut by_chunk: BTreeMap<ChunkIndex, Vec<(BlockIndex, usize, u64)>> = BTreeMap::new();
    for (slot, b) in blocks.iter().enumerate().filter(|(_, b)| b.core) {
        by_chunk
            .entry(ChunkIndex::of_block(b.index, cb))
            .or_default()
            .push((b.index, slot, b.omega_voxels()));
    }
    let encoded: Vec<(ChunkIndex, Vec<u8>)> = by_chunk
        .into_par_iter()
        .map(|(c, list)| {
            let h = StateHeader {
                key,
                chunk: c.0,
                step,
                block_count: list.len() as u32,
            };
            let index: Vec<BlockIndex> = list.iter().map(|(b, _, _)| *b).collect();
            let bytes: u64 = list
                .iter()
                .map(|(_, _, o)| (STATE_MASK_BYTES as u64) + o * STATE_BYTES_PER_OMEGA_VOXEL as u64)
                .sum();
            let file = encode_state_with(&h, &index, bytes as usize, |k, out| {
                encode_slot(problem, list[k].1, out)
            });
            (c, file)
        })
        .collect();
    for (c, bytes) in encoded {
        write_state_file(files, &state_name(step % 2, c), &bytes)?;
    }
    Ok(())
}

/// The last step: the region's chunk files with `u`, written (the caller commits). Chunks are
/// read, filled and encoded on every thread (the plan counts every core block decoded at once)
/// and written one by one in chunk order, their file numbers allocated in that order: the map's
/// operations are those of one thread.
pub(super) fn write_chunks(
    store: &mut MapStore,
    problem: &TvProblem,
    blocks: &[GatheredBlock],
    pass: u32,
    stats: &mut MapRegularizeStats,
) -> Result<()> {
    let cb = store.chunk_blocks();
    let mut chunks: Vec<ChunkIndex> = blocks
        .iter()
        .filter(|b| b.core)
        .map(|b| ChunkIndex::of_block(b.index, cb))
        .filter(|c| store.contains(*c))
        .collect();
    chunks.sort_unstable();
    chunks.dedup();
    let seqs: Vec<u64> = chunks.iter().map(|_| store.allocate_seq()).collect();
    let writer = store.writer();
    let st: &MapStore = store;
    let encoded: Vec<Result<Option<EncodedChunk>>> = chunks
        .par_iter()
        .zip(&seqs)
        .map(|(c, seq)| {
            let Some((d, previous)) = st.read_chunk_bytes(*c)? else {
                return Ok(None);
            };
            let mut layer = Layer::new(st.grid());
            let list: Vec<BlockIndex> = d.blocks.iter().map(|(b, _)| *b).collect();
            layer.put_blocks(d.blocks);
            problem.scatter(&mut layer, &list);
            let refs: Vec<(BlockIndex, &Block)> = list
                .iter()
                .filter_map(|b| layer.get(b).map(|x| (*b, x)))
                .collect();
            // Only `u` and the block flags change: the other parts keep their compressed frames.
            let (bytes, written) =
                writer.encode_reusing(*c, *seq, &refs, pass, &PreviousFrames::of(&previous));
            Ok(Some(EncodedChunk {
                omega_voxels: refs.iter().map(|(_, b)| b.observed_count() as u64).sum(),
                blocks: refs.len(),
                bytes,
                written,
            }))
        })
        .collect();
    for e in encoded {
        let Some(e) = e? else { continue };
        store.write_encoded_chunk(e.written, &e.bytes)?;
        stats.core_omega_voxels += e.omega_voxels;
        stats.core_blocks += e.blocks;
    }
    Ok(())
}

/// One chunk file of the last step, encoded and not yet written.
struct EncodedChunk {
    omega_voxels: u64,
    blocks: usize,
    bytes: Vec<u8>,
    written: WrittenChunk,
}

/// One block's initial state: u = ū = f on Ω, p = 0.
fn initial_state(block: &Block) -> BlockState {
    let mut s = BlockState::default();
    for i in 0..VOXELS_PER_BLOCK {
        if block.omega(i) {
            s.omega[i / 64] |= 1 << (i % 64);
            s.tsdf.push(block.tsdf[i]);
            s.weight.push(block.weight(i));
            let f = decode_tsdf(block.tsdf[i]);
            s.u.push(f);
            s.ubar.push(f);
        }
    }
    let n = s.tsdf.len();
    s.p = [vec![0.0; n], vec![0.0; n], vec![0.0; n]];
    s
}

/// Step 0 of a pass for one region: the initial state of each of its chunks (`core`), decoded and
/// encoded on every thread (the plan counts every core block decoded and its state encoded at
/// once), written one by one in chunk order.
pub(super) fn write_initial_states(store: &MapStore, key: u64, core: &[ChunkIndex]) -> Result<()> {
    let encoded: Vec<Result<Option<StateFile>>> = core
        .par_iter()
        .map(|c| {
            let Some(d) = store.read_chunk(*c)? else {
                return Ok(None);
            };
            let states: Vec<(BlockIndex, BlockState)> = d
                .blocks
                .par_iter()
                .map(|(b, block)| (*b, initial_state(block)))
                .collect();
            let h = StateHeader {
                key,
                chunk: c.0,
                step: 0,
                block_count: states.len() as u32,
            };
            Ok(Some((*c, encode_state(&h, &states))))
        })
        .collect();
    for e in encoded {
        if let Some((c, bytes)) = e? {
            write_state_file(&**store.files(), &state_name(0, c), &bytes)?;
        }
    }
    Ok(())
}

/// A chunk's state file, encoded.
type StateFile = (ChunkIndex, Vec<u8>);
