//! Regional solves of a layer in RAM: the map tiled into regions of blocks, each solved with a
//! halo of context and only its own blocks written ([`regularize_regions`]); with the exact halo
//! of [`RegionPlan::exact_halo_blocks`] the result equals the global solve.

use super::{TvParams, TvProblem};
use crate::grid::{BlockIndex, Layer, TouchedBlocks, VOXELS_PER_SIDE};

/// How [`regularize_regions`] tiles the map.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct RegionPlan {
    /// Edge of a region, blocks (a region is the unit that is solved and written at once).
    pub region_blocks: i32,
    /// Blocks of context gathered around each region and solved with it, but not written.
    pub halo_blocks: i32,
}

impl RegionPlan {
    /// The smallest halo that makes every region's result equal the global solve of `iterations`
    /// iterations: information travels at most one voxel per iteration along each axis (the dual
    /// step reads `ū(x + e_d)`, the primal step reads `p(x − e_d)`, so `u(x)` depends on
    /// `ū(x − e_d + e_d')`: an L∞ step of one), and the gathered set's outer layer is wrong from
    /// the start (its links to ungathered neighbours are cut), so core voxels are exact when the
    /// halo is at least `iterations + 1` voxels thick.
    pub fn exact_halo_blocks(iterations: u32) -> i32 {
        (iterations as i32 + 1 + VOXELS_PER_SIDE as i32 - 1) / VOXELS_PER_SIDE as i32
    }

    /// Regions of `region_blocks` with the exact halo for `iterations`.
    pub fn exact(region_blocks: i32, iterations: u32) -> Self {
        RegionPlan {
            region_blocks,
            halo_blocks: Self::exact_halo_blocks(iterations),
        }
    }
}

/// Work counters of a regional run.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct RegionStats {
    /// Regions solved.
    pub regions: usize,
    /// Blocks written (each once).
    pub core_blocks: usize,
    /// Blocks solved, halos included (≥ `core_blocks`; the ratio is the halo's cost).
    pub solved_blocks: usize,
    /// The largest number of blocks gathered for one region (bounds the working memory:
    /// about 28 bytes per voxel, 14 KiB per block).
    pub max_region_blocks: usize,
}

fn region_of(b: BlockIndex, r: i32) -> [i32; 3] {
    [
        b.0[0].div_euclid(r),
        b.0[1].div_euclid(r),
        b.0[2].div_euclid(r),
    ]
}

impl TvProblem {
    /// [`TvProblem::limit_updates`] for a region solve of `iterations` iterations keeping the
    /// blocks from `core.0` to `core.1` (block indices, inclusive): a halo block `k` blocks from
    /// the core (Chebyshev) has every voxel at least `8 (k − 1) + 1` voxels away, so it is
    /// updated during the first `iterations − 8 (k − 1)` iterations only; the core and the
    /// first ring always. The kept blocks' result is the same bit for bit (tested).
    pub fn limit_updates_to_reach(&mut self, core: ([i32; 3], [i32; 3]), iterations: u32) {
        let side = VOXELS_PER_SIDE as u32;
        let horizon = self
            .blocks()
            .iter()
            .map(|b| {
                let ring = (0..3)
                    .map(|a| (core.0[a] - b.0[a]).max(b.0[a] - core.1[a]).max(0))
                    .max()
                    .unwrap_or(0) as u32;
                match ring {
                    0 | 1 => u32::MAX,
                    k => iterations.saturating_sub(side * (k - 1)),
                }
            })
            .collect();
        self.limit_updates(horizon);
    }
}

/// Regularizes `layer` region by region: each region of `plan.region_blocks`³ blocks is solved
/// together with every allocated block within `plan.halo_blocks` of it, and only the region's
/// own blocks are written. With [`RegionPlan::exact`] the result equals [`super::regularize_layer`]'s
/// global solve (the same arithmetic on the same inputs); with a thinner halo, voxels near region
/// borders differ (seams). Regions are visited in sorted order; memory is bounded by the largest
/// gathered region, not by the map. Returns the written blocks (sorted) and counters.
pub fn regularize_regions(
    layer: &mut Layer,
    params: &TvParams,
    plan: &RegionPlan,
) -> crate::Result<(TouchedBlocks, RegionStats)> {
    regularize_regions_with(layer, params, plan, |problem| {
        problem.solve(params);
        Ok(())
    })
}

/// [`regularize_regions`] with another solver for each region's problem (the GPU twin,
/// `crate::gpu::regularize_regions_gpu`, passes its own). `solve` must run `params.iterations`
/// iterations; an error stops the run (regions already written keep their result).
pub fn regularize_regions_with(
    layer: &mut Layer,
    params: &TvParams,
    plan: &RegionPlan,
    mut solve: impl FnMut(&mut TvProblem) -> crate::Result<()>,
) -> crate::Result<(TouchedBlocks, RegionStats)> {
    params.validate()?;
    if plan.region_blocks < 1 || plan.halo_blocks < 0 {
        return Err(crate::Error::InvalidArgument(format!(
            "region plan needs region ≥ 1 and halo ≥ 0 blocks, got {plan:?}"
        )));
    }
    let r = plan.region_blocks;
    let h = plan.halo_blocks;
    let mut buckets: std::collections::BTreeMap<[i32; 3], Vec<BlockIndex>> = Default::default();
    for b in layer.indices_sorted() {
        buckets.entry(region_of(b, r)).or_default().push(b);
    }
    let reach = (h + r - 1) / r; // regions of halo around a region
    let mut stats = RegionStats::default();
    let mut written = Vec::new();
    let keys: Vec<[i32; 3]> = buckets.keys().copied().collect();
    for key in keys {
        let core = buckets[&key].clone();
        let lo = [key[0] * r - h, key[1] * r - h, key[2] * r - h];
        let hi = [
            key[0] * r + r - 1 + h,
            key[1] * r + r - 1 + h,
            key[2] * r + r - 1 + h,
        ];
        let mut gathered = Vec::new();
        for dz in -reach..=reach {
            for dy in -reach..=reach {
                for dx in -reach..=reach {
                    if let Some(list) = buckets.get(&[key[0] + dx, key[1] + dy, key[2] + dz]) {
                        gathered.extend(
                            list.iter()
                                .copied()
                                .filter(|b| (0..3).all(|a| b.0[a] >= lo[a] && b.0[a] <= hi[a])),
                        );
                    }
                }
            }
        }
        let mut problem = TvProblem::gather(layer, &gathered);
        let (core_lo, core_hi) = (key.map(|k| k * r), key.map(|k| k * r + r - 1));
        problem.limit_updates_to_reach((core_lo, core_hi), params.iterations);
        solve(&mut problem)?;
        problem.scatter(layer, &core);
        stats.regions += 1;
        stats.core_blocks += core.len();
        stats.solved_blocks += problem.blocks().len();
        stats.max_region_blocks = stats.max_region_blocks.max(problem.blocks().len());
        written.extend(core);
    }
    written.sort_unstable();
    Ok((written, stats))
}
