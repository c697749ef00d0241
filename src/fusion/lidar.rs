//! Ray-wise fusion of LiDAR scans: only voxels that a ray traverses inside its truncation band.

use super::lidar_gpu::{block_local_ray, walk_block_ray};
use super::traverse::traverse_cells;
use super::FusionStats;
use crate::frame::LidarScan;
use crate::grid::{linear_index, BlockIndex, GridParams, Layer, TouchedBlocks, VOXELS_PER_SIDE};
use rayon::prelude::*;
use std::sync::OnceLock;

/// Options of LiDAR fusion.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LidarFusionParams {
    /// Returns farther than this are ignored, metres.
    pub max_range_m: f32,
    /// Returns nearer than this (the car itself) are ignored, metres.
    pub min_range_m: f32,
}

impl Default for LidarFusionParams {
    fn default() -> Self {
        LidarFusionParams {
            max_range_m: 80.0,
            min_range_m: 2.5,
        }
    }
}

/// A usable ray: direction (unit, world frame) and range.
pub(crate) struct Ray {
    /// Unit direction, world frame.
    pub(crate) dir: [f64; 3],
    /// Range of the return, metres.
    pub(crate) range_m: f64,
    /// Intensity as a grey level (the colour every voxel it updates is averaged towards).
    pub(crate) gray: u8,
}

/// The truncation band `[max(r − μ, 0), r + μ]` of a return at range `range_m`, metres along
/// the ray: the segment whose voxels a ray updates (shared by the CPU and GPU paths).
#[inline]
pub(crate) fn band_m(range_m: f64, truncation_m: f64) -> (f64, f64) {
    ((range_m - truncation_m).max(0.0), range_m + truncation_m)
}

/// A usable return as it goes up to a device (16 bytes: [`LidarPlan::sent_rays`]): its point
/// as scanned and its grey level, from which [`Ray`] follows ([`SentRay::ray`]).
#[derive(Clone, Copy, Debug, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
#[repr(C)]
pub(crate) struct SentRay {
    /// The return in the sensor's frame, metres, as scanned.
    pub(crate) point_sensor_m: [f32; 3],
    /// Its grey level (0–255).
    pub(crate) gray: u32,
}

impl SentRay {
    /// The return's point in f64, sensor frame, metres.
    #[inline]
    fn point_m(&self) -> nalgebra::Vector3<f64> {
        nalgebra::Vector3::from(self.point_sensor_m.map(|c| c as f64))
    }

    /// The ray of this return under `rotation` (world from sensor), with its range `range_m`
    /// (`|point|`, as [`usable`] measured it): the same f64 operations wherever it is made.
    fn ray(&self, rotation: &nalgebra::UnitQuaternion<f64>, range_m: f64) -> Ray {
        Ray {
            dir: rotation
                .transform_vector(&(self.point_m() / range_m))
                .into(),
            range_m,
            gray: self.gray as u8,
        }
    }
}

/// The return `p` with intensity `i` and its range, where usable (finite, within the limits).
#[inline]
fn usable(p: &[f32; 3], i: f32, params: &LidarFusionParams) -> Option<(SentRay, f64)> {
    let sent = SentRay {
        point_sensor_m: *p,
        gray: (i.clamp(0.0, 1.0) * 255.0).round() as u8 as u32,
    };
    let r = sent.point_m().norm();
    if !r.is_finite() || r < params.min_range_m as f64 || r > params.max_range_m as f64 {
        return None;
    }
    Some((sent, r))
}

/// The usable returns of `scan`, in scan order, as they go up; with their rays where `with_rays`
/// (what the host's walks need; a device makes its own from the returns).
fn sent_rays(
    scan: &LidarScan,
    params: &LidarFusionParams,
    with_rays: bool,
) -> (Vec<SentRay>, Option<Vec<Ray>>) {
    let rot = scan.world_from_sensor.rotation;
    let usable = scan
        .points_sensor_m
        .par_iter()
        .enumerate()
        .filter_map(|(k, p)| {
            let i = scan.intensity.get(k).copied().unwrap_or(0.0);
            usable(p, i, params)
        });
    if !with_rays {
        return (usable.map(|(sent, _)| sent).collect(), None);
    }
    let (sent, rays) = usable.map(|(sent, r)| (sent, sent.ray(&rot, r))).unzip();
    (sent, Some(rays))
}

/// (block, ray) pairs for every block a ray's band crosses, sorted by block then ray.
fn block_ray_pairs(grid: &GridParams, origin: [f64; 3], rays: &[Ray]) -> Vec<(BlockIndex, u32)> {
    let mu = grid.truncation_m as f64;
    let block = grid.block_size_m();
    // One u128 per pair, ordered as (BlockIndex, ray): each coordinate offset by 2²⁰ into 21
    // bits (the range `BlockIndex::pack` supports), then the ray in the low 32 bits; one integer
    // comparison per step of the sort, no allocation per ray.
    const OFFSET: i64 = 1 << 20;
    let mut keys: Vec<u128> = rays
        .par_iter()
        .enumerate()
        .fold(Vec::new, |mut out, (k, r)| {
            let (t0, t1) = band_m(r.range_m, mu);
            traverse_cells(origin, r.dir, t0, t1, block, |c| {
                let b = ((c[0] + OFFSET) as u128) << 42
                    | ((c[1] + OFFSET) as u128) << 21
                    | (c[2] + OFFSET) as u128;
                out.push(b << 32 | k as u128);
                true
            });
            out
        })
        .reduce(Vec::new, |mut a, mut b| {
            a.append(&mut b);
            a
        });
    keys.par_sort_unstable();
    const MASK: u128 = (1 << 21) - 1;
    keys.par_iter()
        .map(|&key| {
            let b = key >> 32;
            let coord = |shift: u32| (((b >> shift) & MASK) as i64 - OFFSET) as i32;
            (BlockIndex([coord(42), coord(21), coord(0)]), key as u32)
        })
        .collect()
}

/// The blocks crossed by the truncation band of every usable return, sorted. Reads no layer.
pub fn lidar_scan_blocks(
    grid: &GridParams,
    scan: &LidarScan,
    params: &LidarFusionParams,
) -> TouchedBlocks {
    LidarPlan::new(grid, scan, params).blocks()
}

/// Fuses one LiDAR scan into `layer`; returns the touched blocks (sorted) and work counters.
/// Within a block, rays are applied in scan order, so the result does not depend on threading.
pub fn integrate_lidar(
    layer: &mut Layer,
    scan: &LidarScan,
    params: &LidarFusionParams,
) -> (TouchedBlocks, FusionStats) {
    let plan = LidarPlan::new(&layer.params(), scan, params);
    integrate_lidar_plan(layer, &plan)
}

/// A scan's usable rays and the (block, ray) pairs of their truncation bands: what
/// [`integrate_lidar_plan`] applies. A pager builds it first to page in [`LidarPlan::blocks`].
/// The host lists the pairs ([`LidarPlan::new`]), or a GPU lists the blocks and counts their
/// pairs ([`crate::Backend::plan_lidar`], [`LidarPlan::with_listed_blocks`]); the pairs are
/// then listed on the host only where something asks for them ([`LidarPlan::pairs`]). The usable
/// returns are kept as they go up to a device (16 bytes each, [`LidarPlan::sent_rays`]); their
/// directions in the world frame are made by the host only where it walks them
/// ([`LidarPlan::rays`]: at once by [`LidarPlan::new`]).
pub struct LidarPlan {
    grid: GridParams,
    origin: [f64; 3],
    /// World from sensor.
    rotation: nalgebra::UnitQuaternion<f64>,
    /// The usable returns as they go up to a device.
    sent: Vec<SentRay>,
    /// Their rays: made at once by [`LidarPlan::new`], else on first use by the host.
    rays: OnceLock<Vec<Ray>>,
    /// Sorted by block then ray: made at once by [`LidarPlan::new`], else on first use.
    pairs: OnceLock<Vec<(BlockIndex, u32)>>,
    /// The blocks (sorted) and their pair counts, where a device listed them.
    listed: Option<Vec<(BlockIndex, u32)>>,
    /// The listing whose rays the device keeps ([`crate::Backend::plan_lidar`]).
    device_listing: Option<u64>,
}

impl LidarPlan {
    /// Lists the rays and band blocks of `scan` on `grid`.
    pub fn new(grid: &GridParams, scan: &LidarScan, params: &LidarFusionParams) -> Self {
        let plan = Self::with_returns(grid, scan, params, true);
        let pairs = block_ray_pairs(grid, plan.origin, plan.rays());
        plan.pairs.set(pairs).expect("a new plan has no pairs");
        plan
    }

    /// The usable returns of `scan` as they go up to a device, its blocks not listed yet and
    /// its rays made only where the host asks for them ([`LidarPlan::rays`]).
    pub(crate) fn rays_only(
        grid: &GridParams,
        scan: &LidarScan,
        params: &LidarFusionParams,
    ) -> Self {
        Self::with_returns(grid, scan, params, false)
    }

    /// The plan of `scan`'s usable returns, with their rays made at once where `with_rays`.
    fn with_returns(
        grid: &GridParams,
        scan: &LidarScan,
        params: &LidarFusionParams,
        with_rays: bool,
    ) -> Self {
        let (sent, rays) = sent_rays(scan, params, with_rays);
        LidarPlan {
            grid: *grid,
            origin: scan.world_from_sensor.translation.vector.into(),
            rotation: scan.world_from_sensor.rotation,
            sent,
            rays: rays.map(OnceLock::from).unwrap_or_default(),
            pairs: OnceLock::new(),
            listed: None,
            device_listing: None,
        }
    }

    /// This plan with its blocks and their pair counts as a device listed them (`blocks`: any
    /// order, each block once), the listing `device_listing` whose rays the device keeps.
    /// Exactly what [`LidarPlan::new`] lists (`tests/gpu/lidar_listing.rs`).
    pub(crate) fn with_listed_blocks(
        mut self,
        mut blocks: Vec<(BlockIndex, u32)>,
        device_listing: u64,
    ) -> Self {
        blocks.sort_unstable_by_key(|b| b.0);
        self.listed = Some(blocks);
        self.device_listing = Some(device_listing);
        self
    }

    /// The device listing whose rays the device keeps for this plan, if one listed it.
    pub(crate) fn device_listing(&self) -> Option<u64> {
        self.device_listing
    }

    /// Whether a device listed the blocks.
    pub fn listed_on_device(&self) -> bool {
        self.listed.is_some()
    }

    /// Whether the host has walked the rays and listed the pairs (never, for a plan a device
    /// listed and fused: [`LidarPlan::pairs`] is asked only where the device cannot fuse it).
    pub fn host_walked(&self) -> bool {
        self.pairs.get().is_some()
    }

    /// The blocks the scan will update, sorted.
    pub fn blocks(&self) -> TouchedBlocks {
        if let Some(listed) = &self.listed {
            return listed.iter().map(|b| b.0).collect();
        }
        let mut b: Vec<BlockIndex> = self.pairs().iter().map(|p| p.0).collect();
        b.dedup();
        b
    }

    /// The sensor's position, world frame, metres.
    pub fn origin_m(&self) -> [f64; 3] {
        self.origin
    }

    /// The sensor's rotation, world from sensor: a unit quaternion (i, j, k, w).
    pub fn rotation_ijkw(&self) -> [f64; 4] {
        let q = &self.rotation.coords;
        [q[0], q[1], q[2], q[3]]
    }

    /// Number of usable rays (returns within the range limits).
    pub fn ray_count(&self) -> usize {
        self.sent.len()
    }

    /// Number of (block, ray) pairs: the block-ray work items of an integration.
    pub fn pair_count(&self) -> usize {
        match &self.listed {
            Some(listed) => listed.iter().map(|b| b.1 as usize).sum(),
            None => self.pairs().len(),
        }
    }

    /// How many (block, ray) pairs each block has (blocks sorted).
    pub fn pairs_per_block(&self) -> Vec<usize> {
        self.groups().iter().map(|g| g.1.len()).collect()
    }

    /// The usable rays, in scan order (made from the returns on first use where a device
    /// lists and fuses the scan: the host never needs them then).
    pub(crate) fn rays(&self) -> &[Ray] {
        self.rays.get_or_init(|| {
            (self.sent.par_iter())
                .map(|s| s.ray(&self.rotation, s.point_m().norm()))
                .collect()
        })
    }

    /// The usable returns as they go up to a device (16 bytes each), in scan order.
    pub(crate) fn sent_rays(&self) -> &[SentRay] {
        &self.sent
    }

    /// Whether the host has made the rays' directions ([`LidarPlan::rays`]).
    pub fn host_made_rays(&self) -> bool {
        self.rays.get().is_some()
    }

    /// The (block, ray) pairs, sorted by block then ray (listed on the host on first use where
    /// a device listed the blocks).
    pub(crate) fn pairs(&self) -> &[(BlockIndex, u32)] {
        self.pairs
            .get_or_init(|| block_ray_pairs(&self.grid, self.origin, self.rays()))
    }

    /// The pairs grouped by block: each block (sorted) with its range in [`LidarPlan::pairs`]
    /// (rays in scan order).
    pub(crate) fn groups(&self) -> Vec<(BlockIndex, std::ops::Range<usize>)> {
        if let Some(listed) = &self.listed {
            let mut start = 0;
            return listed
                .iter()
                .map(|&(b, n)| {
                    start += n as usize;
                    (b, start - n as usize..start)
                })
                .collect();
        }
        let pairs = self.pairs();
        let mut groups = Vec::new();
        let mut start = 0;
        for i in 1..=pairs.len() {
            if i == pairs.len() || pairs[i].0 != pairs[start].0 {
                groups.push((pairs[start].0, start..i));
                start = i;
            }
        }
        groups
    }
}

/// Applies a [`LidarPlan`] to `layer` (see [`integrate_lidar`]) with the single LiDAR walk of
/// both devices: each (block, ray) pair is walked in f32 in the block's own voxel coordinates
/// ([`block_local_ray`], start cell and step count decided in f64; [`walk_block_ray`], the CPU
/// twin of `shaders/fuse_lidar.wgsl`), so the GPU kernel equals this function bit for bit on
/// lavapipe. Against the f64 world-frame walk ([`integrate_lidar_reference`]) it differs only at
/// exact cell-boundary ties and in the last quantisation step (`tests/gpu/lidar.rs` states the
/// tolerance). Rays are applied per block in scan order, so the result does not depend on
/// threading or on which blocks are resident.
pub fn integrate_lidar_plan(layer: &mut Layer, plan: &LidarPlan) -> (TouchedBlocks, FusionStats) {
    let grid = layer.params();
    let origin = plan.origin;
    let rays = plan.rays();
    let pairs = plan.pairs();
    let groups = plan.groups();
    let indices: Vec<BlockIndex> = groups.iter().map(|g| g.0).collect();
    let mut taken = layer.take_blocks(&indices);
    let (mu, vs) = (grid.truncation_m, grid.voxel_size_m);
    let updates: usize = taken
        .par_iter_mut()
        .zip(groups.par_iter())
        .map(|((index, block), (_, range))| {
            let mut n = 0usize;
            for &(_, k) in &pairs[range.clone()] {
                let r = &rays[k as usize];
                let ray = block_local_ray(&grid, origin, r.dir, r.range_m, r.gray, *index);
                let gray = Some([r.gray; 3]);
                n += walk_block_ray(&ray, mu, vs, |i, t| block.fuse(i, t, gray)) as usize;
            }
            n
        })
        .sum();
    let touched = layer.put_blocks_observed(taken);
    let stats = FusionStats {
        blocks: touched.len(),
        voxel_updates: updates,
        measurements: rays.len(),
    };
    (touched, stats)
}

/// The f64 reference of [`integrate_lidar_plan`]: every (block, ray) pair walks the ray's whole
/// band in world coordinates (Amanatides–Woo in f64) and updates the voxels inside the block.
/// Slower (each pair walks the whole band) and not what any device runs: kept as the oracle the
/// single f32 walk is measured against (`tests/gpu/lidar.rs`).
pub fn integrate_lidar_reference(
    layer: &mut Layer,
    plan: &LidarPlan,
) -> (TouchedBlocks, FusionStats) {
    let grid = layer.params();
    let origin = plan.origin;
    let rays = plan.rays();
    let pairs = plan.pairs();
    let groups = plan.groups();
    let indices: Vec<BlockIndex> = groups.iter().map(|g| g.0).collect();
    let mut taken = layer.take_blocks(&indices);
    let mu = grid.truncation_m as f64;
    let vs = grid.voxel_size_m as f64;
    let s = VOXELS_PER_SIDE as i64;
    let updates: usize = taken
        .par_iter_mut()
        .zip(groups.par_iter())
        .map(|((index, block), (_, range))| {
            let lo = [0, 1, 2].map(|a| index.0[a] as i64 * s);
            let mut n = 0;
            for &(_, k) in &pairs[range.clone()] {
                let r = &rays[k as usize];
                let (t0, t1) = band_m(r.range_m, mu);
                traverse_cells(origin, r.dir, t0, t1, vs, |c| {
                    let l = [c[0] - lo[0], c[1] - lo[1], c[2] - lo[2]];
                    if l.iter().all(|&x| (0..s).contains(&x)) {
                        // Signed distance along the ray from the voxel centre to the hit.
                        let t = (0..3)
                            .map(|a| ((c[a] as f64 + 0.5) * vs - origin[a]) * r.dir[a])
                            .sum::<f64>();
                        let sdf = r.range_m - t;
                        if sdf >= -mu {
                            let i = linear_index(l[0] as usize, l[1] as usize, l[2] as usize);
                            block.fuse(i, (sdf.min(mu) / mu) as f32, Some([r.gray; 3]));
                            n += 1;
                        }
                    }
                    true
                });
            }
            n
        })
        .sum();
    let touched = layer.put_blocks_observed(taken);
    let stats = FusionStats {
        blocks: touched.len(),
        voxel_updates: updates,
        measurements: rays.len(),
    };
    (touched, stats)
}
