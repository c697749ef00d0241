//! Regions planned to a memory budget: what one region's working memory is made of
//! ([`RegionCosts`], for swept passes and for the exact halo), the largest region edge whose every
//! region of a map fits ([`plan_region_chunks`], from the manifest's per-chunk block and Ω
//! counts), and the data-independent bound `reconstruct --map` checks before fusing
//! ([`check_budget_up_front`]).

use super::sweep_state::{STATE_BYTES_PER_OMEGA_VOXEL, STATE_ENTRY_BYTES, STATE_MASK_BYTES};
use crate::error::{Error, Result};
use crate::grid::{BLOCK_RESIDENT_BYTES, VOXELS_PER_BLOCK};
use crate::map::manifest::ChunkEntry;
use crate::map::store::MapStore;
use crate::map::ChunkIndex;
use crate::regularize::RegionPlan;
use std::collections::BTreeMap;

/// Bytes per voxel the solver's arrays take while a region is solved (`f`, `w`, `u`, `ū`: 4 each,
/// `p`: 12, mask 1, the gather's Ω flags 1, neighbour links 0.05), used for the budget check.
pub const SOLVER_BYTES_PER_VOXEL: u64 = 30;

/// Working memory of one gathered block in a sweep besides its Ω voxels: the solver's arrays
/// and its state record's mask and index entry, bytes.
pub const SWEEP_BYTES_PER_BLOCK: u64 = VOXELS_PER_BLOCK as u64 * SOLVER_BYTES_PER_VOXEL
    + (STATE_MASK_BYTES + STATE_ENTRY_BYTES) as u64;
/// Working memory of one gathered Ω voxel: its state record as read, bytes.
pub const SWEEP_BYTES_PER_OMEGA_VOXEL: u64 = STATE_BYTES_PER_OMEGA_VOXEL as u64;
/// What a region's own block adds besides its Ω voxels: the block decoded for the last step and
/// its state record's mask and index entry encoded for writing, bytes.
pub const SWEEP_BYTES_PER_CORE_BLOCK: u64 =
    BLOCK_RESIDENT_BYTES + (STATE_MASK_BYTES + STATE_ENTRY_BYTES) as u64;
/// What a region's own Ω voxel adds: its state record encoded for writing, bytes.
pub const SWEEP_BYTES_PER_CORE_OMEGA_VOXEL: u64 = STATE_BYTES_PER_OMEGA_VOXEL as u64;

/// Counters of an offline regularization run.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct MapRegularizeStats {
    /// Pass number written into the manifest.
    pub pass: u32,
    /// Regions solved in this run.
    pub regions: usize,
    /// Regions found already done (resumed run).
    pub regions_skipped: usize,
    /// Blocks written.
    pub core_blocks: usize,
    /// Blocks solved, halos included.
    pub solved_blocks: usize,
    /// Ω voxels written.
    pub core_omega_voxels: u64,
    /// Largest estimated working memory of one region, bytes.
    pub peak_region_bytes: u64,
    /// Halo thickness used, blocks.
    pub halo_blocks: i32,
    /// Wall time, seconds.
    pub seconds: f64,
    /// The caller stopped the run early (progress returned false); what was done is committed.
    pub interrupted: bool,
    /// Regions adopted from shards' records (a committing run after `--shard` runs).
    pub regions_adopted: usize,
    /// Regions left to other shards (a `--shard` run).
    pub regions_other_shards: usize,
    /// Sweeps the iterations were split into (1: all at once with the exact halo).
    pub sweeps: u32,
    /// Region edge used, chunks (planned to the budget when not given).
    pub region_chunks: u32,
    /// Scratch state a swept pass keeps under `sweeps/` at its fullest, bytes (computed from the
    /// manifest: [`super::sweeps::scratch_bytes`]; 0 for a pass with exact halos).
    pub scratch_bytes: u64,
}

/// How a stored map's regularization ([`super::regional::regularize_map`]) tiles and bounds its
/// work.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RegionalOptions {
    /// Region edge, chunks; 0: the largest that fits the budget ([`plan_region_chunks`]).
    pub region_chunks: u32,
    /// Working-memory bound of one region, bytes.
    pub budget_bytes: u64,
    /// Halo thickness, blocks; `None` for the exact halo of the iteration count. A thinner halo
    /// leaves seams (kept for the test that shows it).
    pub halo_blocks: Option<i32>,
    /// Iterations per sweep ([`super::sweeps`]: every region this many iterations at a time, the
    /// solver state kept in the store between sweeps, a halo of `K + 1` voxels); `None` solves
    /// each region with all iterations at once and the exact halo of `iterations + 1` voxels
    /// (also what `--shard` runs always do, and a committing run that adopted shards' regions).
    pub sweep_iterations: Option<u32>,
}

/// The region of `r`³ chunks holding chunk `c`.
pub(super) fn region_of(c: ChunkIndex, r: i32) -> [i32; 3] {
    [0, 1, 2].map(|a| c.0[a].div_euclid(r))
}

/// What a region's working memory is made of, for planning regions to a budget.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct RegionCosts {
    /// Bytes per gathered block (region and halo).
    pub per_block: u64,
    /// Bytes per gathered Ω voxel.
    pub per_omega_voxel: u64,
    /// Bytes added per block of the region itself.
    pub per_core_block: u64,
    /// Bytes added per Ω voxel of the region itself.
    pub per_core_omega_voxel: u64,
}

impl RegionCosts {
    /// The costs of a swept pass (`swept`) or of one solve with the exact halo.
    pub fn of(swept: bool) -> Self {
        if swept {
            RegionCosts {
                per_block: SWEEP_BYTES_PER_BLOCK,
                per_omega_voxel: SWEEP_BYTES_PER_OMEGA_VOXEL,
                per_core_block: SWEEP_BYTES_PER_CORE_BLOCK,
                per_core_omega_voxel: SWEEP_BYTES_PER_CORE_OMEGA_VOXEL,
            }
        } else {
            RegionCosts {
                per_block: BLOCK_RESIDENT_BYTES + SOLVER_BYTES_PER_VOXEL * VOXELS_PER_BLOCK as u64,
                per_omega_voxel: 0,
                per_core_block: 0,
                per_core_omega_voxel: 0,
            }
        }
    }

    /// Bytes of `blocks` gathered blocks with `omega` Ω voxels, of which `core_blocks` blocks and
    /// `core_omega` Ω voxels are the region's own.
    pub fn bytes(&self, blocks: u64, omega: u64, core_blocks: u64, core_omega: u64) -> u64 {
        blocks * self.per_block
            + omega * self.per_omega_voxel
            + core_blocks * self.per_core_block
            + core_omega * self.per_core_omega_voxel
    }

    /// The most a region of `region_chunks`³ full chunks of `chunk_blocks`³ blocks (every voxel
    /// in Ω) with a halo of `halo_blocks` can need, bytes: the bound that holds before anything
    /// is fused.
    pub fn full_region_bytes(
        &self,
        chunk_blocks: u32,
        region_chunks: u32,
        halo_blocks: i32,
    ) -> u64 {
        let core = ((chunk_blocks * region_chunks) as u64).pow(3);
        let with_halo =
            ((chunk_blocks * region_chunks) as u64 + 2 * halo_blocks.max(0) as u64).pow(3);
        let v = VOXELS_PER_BLOCK as u64;
        self.bytes(with_halo, with_halo * v, core, core * v)
    }
}

/// The largest region edge (chunks) whose every region of the map, with a halo of `halo_blocks`,
/// stays within `budget_bytes` by the bound of `costs` (the chunks' block counts from the
/// manifest; a neighbour chunk counts with at most its blocks inside the halo), and that bound.
/// An error when not even one chunk fits.
pub fn plan_region_chunks(
    chunks: &BTreeMap<ChunkIndex, ChunkEntry>,
    chunk_blocks: u32,
    halo_blocks: i32,
    costs: RegionCosts,
    budget_bytes: u64,
) -> Result<(u32, u64)> {
    let cb = chunk_blocks as i32;
    let halo = halo_blocks.max(0);
    let reach = (halo + cb - 1) / cb;
    let bound = |r: i32| -> u64 {
        let mut regions: BTreeMap<[i32; 3], Vec<ChunkIndex>> = BTreeMap::new();
        for c in chunks.keys() {
            regions.entry(region_of(*c, r)).or_default().push(*c);
        }
        let mut worst = 0u64;
        for key in regions.keys() {
            let lo = [0, 1, 2].map(|a| key[a] * r * cb - halo);
            let hi = [0, 1, 2].map(|a| (key[a] + 1) * r * cb - 1 + halo);
            let (mut core, mut gathered) = ([0u64; 2], [0u64; 2]); // blocks, Ω voxels
            for cz in key[2] * r - reach..=key[2] * r + r - 1 + reach {
                for cy in key[1] * r - reach..=key[1] * r + r - 1 + reach {
                    for cx in key[0] * r - reach..=key[0] * r + r - 1 + reach {
                        let c = ChunkIndex([cx, cy, cz]);
                        let Some(e) = chunks.get(&c) else { continue };
                        let (blocks, omega) = (e.block_count as u64, e.observed_voxels as u64);
                        if region_of(c, r) == *key {
                            core = [core[0] + blocks, core[1] + omega];
                            gathered = [gathered[0] + blocks, gathered[1] + omega];
                        } else {
                            let inside: i64 = (0..3)
                                .map(|a| {
                                    let (c0, c1) = (c.0[a] * cb, c.0[a] * cb + cb - 1);
                                    (c1.min(hi[a]) - c0.max(lo[a]) + 1).max(0) as i64
                                })
                                .product();
                            let b = blocks.min(inside as u64);
                            gathered[0] += b;
                            gathered[1] += omega.min(b * VOXELS_PER_BLOCK as u64);
                        }
                    }
                }
            }
            worst = worst.max(costs.bytes(gathered[0], gathered[1], core[0], core[1]));
        }
        worst
    };
    let extent = (0..3)
        .map(|a| {
            let lo = chunks.keys().map(|c| c.0[a]).min().unwrap_or(0);
            let hi = chunks.keys().map(|c| c.0[a]).max().unwrap_or(0);
            hi - lo + 1
        })
        .max()
        .unwrap_or(1);
    let first = bound(1);
    if first > budget_bytes {
        return Err(Error::InvalidArgument(format!(
            "regularizing this map needs about {} MiB for its fullest chunk with a {halo}-block halo, over the {} MiB a region may use: use a --memory-budget of at least {} MiB",
            first.div_ceil(1 << 20),
            budget_bytes >> 20,
            crate::memory::budget_for_data_bytes(first).div_ceil(1 << 20)
        )));
    }
    let (mut best, mut best_bytes) = (1, first);
    // Regions of up to the map's extent (one region then holds every chunk).
    for r in 2..=extent.max(1) {
        let b = bound(r);
        if b > budget_bytes {
            break;
        }
        (best, best_bytes) = (r, b);
    }
    Ok((best as u32, best_bytes))
}

/// Checks, before anything is fused, that regularizing a map of `chunk_blocks`-block chunks with
/// `options` for `iterations` iterations fits `options.budget_bytes` whatever the map holds: the
/// bound of one region of full chunks (the given `region_chunks`, else one chunk) with its halo.
/// Returns that bound; the error names it and what would fit.
pub fn check_budget_up_front(
    chunk_blocks: u32,
    options: &RegionalOptions,
    iterations: u32,
) -> Result<u64> {
    let swept = options.sweep_iterations.filter(|k| *k < iterations);
    let halo = match swept {
        Some(k) => RegionPlan::exact_halo_blocks(k),
        None => options
            .halo_blocks
            .unwrap_or_else(|| RegionPlan::exact_halo_blocks(iterations)),
    };
    let costs = RegionCosts::of(swept.is_some());
    let r = options.region_chunks.max(1);
    let bytes = costs.full_region_bytes(chunk_blocks, r, halo);
    if bytes <= options.budget_bytes {
        return Ok(bytes);
    }
    let mut smaller = String::new();
    if chunk_blocks > 4 {
        let half = chunk_blocks / 2;
        smaller = format!(
            ", smaller chunks (--chunk-blocks {half}: up to {} MiB)",
            costs.full_region_bytes(half, r, halo).div_ceil(1 << 20)
        );
    }
    Err(Error::InvalidArgument(format!(
        "regularizing a region of {r}³ chunks of {chunk_blocks}³ blocks with its {halo}-block halo may need up to {} MiB, over the {} MiB a region may use: give a --memory-budget of at least {} MiB{smaller}{}, or --skip-regularize and then `denser regularize MAP`, which plans regions to the map's real block counts",
        bytes.div_ceil(1 << 20),
        options.budget_bytes >> 20,
        crate::memory::budget_for_data_bytes(bytes).div_ceil(1 << 20),
        if options.region_chunks > 1 { ", a smaller --region-chunks" } else { "" }
    )))
}

/// `options` with the region edge decided: as given, or planned to the budget (0). The plan is
/// logged as the run's (`announce`), or only at debug level (a plan consulted, not run: the
/// shards' exact-halo plan a swept pass adopts from).
pub(super) fn resolve(
    store: &MapStore,
    options: &RegionalOptions,
    halo_blocks: i32,
    swept: bool,
    announce: bool,
) -> Result<RegionalOptions> {
    if options.region_chunks > 0 {
        return Ok(*options);
    }
    let (r, bytes) = plan_region_chunks(
        &store.manifest().chunks,
        store.chunk_blocks(),
        halo_blocks,
        RegionCosts::of(swept),
        options.budget_bytes,
    )?;
    let line = format!(
        "regions of {r}³ chunks (the largest within the {} MiB a region may use: at most {} MiB each with a {halo_blocks}-block halo)",
        options.budget_bytes >> 20,
        bytes.div_ceil(1 << 20)
    );
    if announce {
        tracing::info!("{line}");
    } else {
        tracing::debug!("the shards' plan, for adopting their regions: {line}");
    }
    Ok(RegionalOptions {
        region_chunks: r,
        ..*options
    })
}

/// The error of a region whose gathered blocks (`bytes` of working memory, its halo `halo`
/// blocks) do not fit the `budget_bytes` a region may use, naming what would.
pub(super) fn region_over_budget(
    region: [i32; 3],
    halo: i32,
    bytes: u64,
    budget_bytes: u64,
) -> Error {
    Error::InvalidArgument(format!(
        "region {region:?} with its {halo}-block halo needs about {} MiB, over the {} MiB a region may use; use a smaller --region-chunks or a --memory-budget of at least {} MiB",
        bytes >> 20,
        budget_bytes >> 20,
        crate::memory::budget_for_data_bytes(bytes).div_ceil(1 << 20)
    ))
}
