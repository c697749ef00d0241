//! Projective fusion of depth maps (the paper's update, with colour).

use super::traverse::traverse_cells;
use super::FusionStats;
use crate::frame::DepthFrame;
use crate::grid::{
    round_i64, BlockIndex, GridParams, Layer, TouchedBlocks, VOXELS_PER_BLOCK, VOXELS_PER_SIDE,
};
use nalgebra::{Isometry3, Point3, Vector3};
use rayon::prelude::*;
use std::collections::HashSet;

/// Options of depth-map fusion.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DepthFusionParams {
    /// Depths beyond this are ignored (stereo depth error grows with z²), metres.
    pub max_depth_m: f32,
    /// Depths below this are ignored, metres.
    pub min_depth_m: f32,
    /// Fuse colour when the frame has it.
    pub use_color: bool,
}

impl Default for DepthFusionParams {
    fn default() -> Self {
        DepthFusionParams {
            max_depth_m: 40.0,
            min_depth_m: 0.1,
            use_color: true,
        }
    }
}

/// Whether a depth is used: finite and within `[min_depth_m, max_depth_m]` (shared with the GPU
/// twin, `src/gpu/fuse.rs`).
#[inline]
pub(crate) fn usable(d: f32, p: &DepthFusionParams) -> bool {
    d.is_finite() && d >= p.min_depth_m && d <= p.max_depth_m
}

/// The blocks crossed by the truncation band of every usable pixel, sorted. Reads no layer.
pub fn depth_frame_blocks(
    grid: &GridParams,
    frame: &DepthFrame,
    params: &DepthFusionParams,
) -> TouchedBlocks {
    let k = &frame.intrinsics;
    let w = frame.depth_m.width as usize;
    let mu = grid.truncation_m as f64;
    let pose = frame.world_from_camera;
    let origin = pose.translation.vector;
    let block = grid.block_size_m();
    let sets: Vec<HashSet<u64, std::hash::BuildHasherDefault<crate::grid::BlockHasher>>> = frame
        .depth_m
        .data
        .par_chunks(w)
        .enumerate()
        .fold(HashSet::default, |mut set, (v, row)| {
            // Neighbouring pixels cross the same blocks: only blocks the previous ray did not
            // report reach the hash set.
            let mut previous: Vec<u64> = Vec::with_capacity(16);
            let mut current: Vec<u64> = Vec::with_capacity(16);
            // World ray directions are affine in u: dir(u) = dir(0) + u·step (z = 1 in the camera).
            let dir0 = pose.rotation * k.ray(0.0, v as f64);
            let step = pose.rotation * nalgebra::Vector3::new(1.0 / k.fx, 0.0, 0.0);
            for (u, &d) in row.iter().enumerate() {
                if !usable(d, params) {
                    continue;
                }
                // The ray through the pixel, scaled so that t is the depth (z) along it.
                let dir = dir0 + step * u as f64;
                let (t0, t1) = ((d as f64 - mu).max(0.0), d as f64 + mu);
                current.clear();
                traverse_cells(origin.into(), dir.into(), t0, t1, block, |c| {
                    current.push(BlockIndex([c[0] as i32, c[1] as i32, c[2] as i32]).pack());
                    true
                });
                for b in &current {
                    if !previous.contains(b) {
                        set.insert(*b);
                    }
                }
                std::mem::swap(&mut previous, &mut current);
            }
            set
        })
        .collect();
    let mut all: Vec<BlockIndex> = sets.into_iter().flatten().map(BlockIndex::unpack).collect();
    all.par_sort_unstable();
    all.dedup();
    all
}

/// The view volume of a depth frame as half-spaces (camera frame: near `z > 0`, far
/// `z < max_depth + μ`, and the four planes through the optical centre and the image borders
/// widened by one pixel). [`ViewFrustum::meets_sphere`] is conservative and monotone: a sphere
/// that contains a passing sphere passes too, so a pager can select chunks with the same test that
/// selects blocks and page in every block fusion could update.
#[derive(Clone, Copy, Debug)]
pub struct ViewFrustum {
    camera_from_world: nalgebra::Isometry3<f64>,
    /// Unit inward normals of the side planes (through the camera centre), camera frame.
    sides: [Vector3<f64>; 4],
    far_m: f64,
}

impl ViewFrustum {
    /// The frustum of `frame` for fusion with `params` and truncation `truncation_m`.
    pub fn new(frame: &DepthFrame, params: &DepthFusionParams, truncation_m: f64) -> Self {
        let k = &frame.intrinsics;
        let (w, h) = (k.width as f64, k.height as f64);
        // Rays through the widened image corners (z = 1).
        let x0 = (-1.0 - k.cx) / k.fx;
        let x1 = (w + 1.0 - k.cx) / k.fx;
        let y0 = (-1.0 - k.cy) / k.fy;
        let y1 = (h + 1.0 - k.cy) / k.fy;
        // Inward normals: x - x0·z ≥ 0, x1·z - x ≥ 0, same for y.
        let sides = [
            Vector3::new(1.0, 0.0, -x0).normalize(),
            Vector3::new(-1.0, 0.0, x1).normalize(),
            Vector3::new(0.0, 1.0, -y0).normalize(),
            Vector3::new(0.0, -1.0, y1).normalize(),
        ];
        ViewFrustum {
            camera_from_world: frame.world_from_camera.inverse(),
            sides,
            far_m: params.max_depth_m as f64 + truncation_m,
        }
    }

    /// Whether the sphere of `radius_m` around world point `centre` meets every half-space.
    pub fn meets_sphere(&self, centre: [f64; 3], radius_m: f64) -> bool {
        let c = self.camera_from_world * Point3::new(centre[0], centre[1], centre[2]);
        if c.z < -radius_m || c.z > self.far_m + radius_m {
            return false;
        }
        self.sides.iter().all(|n| n.dot(&c.coords) > -radius_m)
    }
}

/// Allocated blocks of `layer` whose bounding sphere meets the camera frustum up to
/// `max_depth_m + μ` ([`ViewFrustum`]), sorted. These receive the update too (free space carves
/// stale surfaces).
pub fn visible_blocks(
    layer: &Layer,
    frame: &DepthFrame,
    params: &DepthFusionParams,
) -> TouchedBlocks {
    let frustum = ViewFrustum::new(frame, params, layer.params().truncation_m as f64);
    visible_blocks_in(layer, &frustum)
}

/// [`visible_blocks`] for a frustum already built.
pub fn visible_blocks_in(layer: &Layer, frustum: &ViewFrustum) -> TouchedBlocks {
    let grid = layer.params();
    let half = 0.5 * grid.block_size_m();
    let radius = half * 3f64.sqrt();
    let mut v: Vec<BlockIndex> = layer
        .iter_unsorted()
        .map(|(i, _)| *i)
        .filter(|i| {
            let o = grid.block_origin(*i);
            frustum.meets_sphere([o[0] + half, o[1] + half, o[2] + half], radius)
        })
        .collect();
    v.sort_unstable();
    v
}

/// A depth frame's geometry in the grid, as the f32 quantities the CPU loop and the GPU kernels
/// both use (the kernels' `FuseUniforms` are built from it): so all three depth paths project
/// voxels with the same numbers.
#[derive(Clone, Copy, Debug)]
pub struct DepthGeometry {
    /// The inverse of the frame's pose.
    pub camera_from_world: Isometry3<f64>,
    /// Camera-frame step of one voxel along world x, y and z, metres.
    pub axis_m: [Vector3<f32>; 3],
    /// Focal lengths and principal point, pixels.
    pub fx: f32,
    /// Focal length y, pixels.
    pub fy: f32,
    /// Principal point x, pixels.
    pub cx: f32,
    /// Principal point y, pixels.
    pub cy: f32,
    /// Image width, pixels.
    pub width: u32,
    /// Image height, pixels.
    pub height: u32,
    /// Truncation μ, metres.
    pub truncation_m: f32,
    voxel_size_m: f64,
}

impl DepthGeometry {
    /// The geometry of `frame` on `grid`.
    pub fn new(grid: &GridParams, frame: &DepthFrame) -> Self {
        let camera_from_world = frame.world_from_camera.inverse();
        let rot = camera_from_world.rotation.to_rotation_matrix();
        let vs = grid.voxel_size_m as f64;
        let k = frame.intrinsics;
        DepthGeometry {
            camera_from_world,
            axis_m: [Vector3::x(), Vector3::y(), Vector3::z()].map(|a| (rot * a * vs).cast()),
            fx: k.fx as f32,
            fy: k.fy as f32,
            cx: k.cx as f32,
            cy: k.cy as f32,
            width: frame.depth_m.width,
            height: frame.depth_m.height,
            truncation_m: grid.truncation_m,
            voxel_size_m: vs,
        }
    }

    /// Camera-frame centre of voxel (0, 0, 0) of `block`, metres (computed in f64, then f32).
    pub fn block_base(&self, grid: &GridParams, block: BlockIndex) -> Vector3<f32> {
        let vs = self.voxel_size_m;
        let o = grid.block_origin(block);
        let centre0 = Point3::new(o[0] + 0.5 * vs, o[1] + 0.5 * vs, o[2] + 0.5 * vs);
        (self.camera_from_world * centre0).coords.cast()
    }
}

/// Everything fusion needs to know about one depth frame besides the layer: the blocks its
/// truncation band crosses (listed once; reads no layer), its view frustum, its geometry and its
/// usable pixel count. The CPU ([`integrate_depth_plan`]) and both GPU depth paths fuse from the
/// same plan, as [`super::LidarPlan`] serves both LiDAR paths; a pager builds it first to page
/// in the chunks of the band and of the frustum.
#[derive(Clone, Debug)]
pub struct DepthPlan {
    /// Blocks crossed by the band of some usable pixel, sorted.
    pub band: TouchedBlocks,
    /// The view volume (the allocated blocks it meets are updated too).
    pub frustum: ViewFrustum,
    /// Projection quantities.
    pub geometry: DepthGeometry,
    /// Usable pixels ([`DepthFusionParams`] depth range, finite).
    pub measurements: usize,
    /// The camera centre, world frame, metres.
    pub camera_m: [f64; 3],
    /// Seconds spent listing the band.
    pub listing_s: f64,
}

impl DepthPlan {
    /// Lists the band of `frame` on `grid` and its geometry.
    pub fn new(grid: &GridParams, frame: &DepthFrame, params: &DepthFusionParams) -> Self {
        let t = std::time::Instant::now();
        let band = depth_frame_blocks(grid, frame, params);
        let listing_s = t.elapsed().as_secs_f64();
        DepthPlan {
            band,
            frustum: ViewFrustum::new(frame, params, grid.truncation_m as f64),
            geometry: DepthGeometry::new(grid, frame),
            measurements: frame
                .depth_m
                .data
                .iter()
                .filter(|&&d| usable(d, params))
                .count(),
            camera_m: frame.world_from_camera.translation.vector.into(),
            listing_s,
        }
    }

    /// The blocks fusion updates: the band plus the allocated blocks of `layer` in view, sorted.
    pub fn blocks(&self, layer: &Layer) -> TouchedBlocks {
        let mut blocks = self.band.clone();
        blocks.extend(visible_blocks_in(layer, &self.frustum));
        blocks.sort_unstable();
        blocks.dedup();
        blocks
    }
}

/// Fuses one depth frame into `layer`: the blocks crossed by this frame's truncation band plus the
/// allocated blocks in view. Returns the touched blocks (sorted) and work counters.
pub fn integrate_depth(
    layer: &mut Layer,
    frame: &DepthFrame,
    params: &DepthFusionParams,
) -> (TouchedBlocks, FusionStats) {
    let plan = DepthPlan::new(&layer.params(), frame, params);
    integrate_depth_plan(layer, frame, params, &plan)
}

/// [`integrate_depth`] from a plan already made ([`DepthPlan::new`] on this layer's grid).
pub fn integrate_depth_plan(
    layer: &mut Layer,
    frame: &DepthFrame,
    params: &DepthFusionParams,
    plan: &DepthPlan,
) -> (TouchedBlocks, FusionStats) {
    let grid = layer.params();
    let blocks = plan.blocks(layer);
    let mut taken = layer.take_blocks(&blocks);
    let g = &plan.geometry;
    let mu = g.truncation_m;
    let inv_mu = 1.0 / mu;
    let (wid, hei) = (g.width as i64, g.height as i64);
    let (fx, fy, cx, cy) = (g.fx, g.fy, g.cx, g.cy);
    let depth = &frame.depth_m.data;
    let color = if params.use_color {
        frame.color.as_ref()
    } else {
        None
    };
    let [ax, ay, az] = g.axis_m;
    let updates: usize = taken
        .par_iter_mut()
        .map(|(index, block)| {
            let base = g.block_base(&grid, *index);
            let mut n = 0usize;
            let mut i = 0usize;
            for z in 0..VOXELS_PER_SIDE {
                for y in 0..VOXELS_PER_SIDE {
                    let row = base + ay * y as f32 + az * z as f32;
                    for x in 0..VOXELS_PER_SIDE {
                        let p = row + ax * x as f32;
                        let vi = i;
                        i += 1;
                        if p.z <= 0.0 {
                            continue;
                        }
                        let inv_z = 1.0 / p.z;
                        let u = round_i64((fx * p.x * inv_z + cx) as f64);
                        let v = round_i64((fy * p.y * inv_z + cy) as f64);
                        if u < 0 || v < 0 || u >= wid || v >= hei {
                            continue;
                        }
                        let pix = (v * wid + u) as usize;
                        let d = depth[pix];
                        if !usable(d, params) {
                            continue;
                        }
                        let sdf = d - p.z;
                        if sdf < -mu {
                            continue;
                        }
                        block.fuse(vi, sdf.min(mu) * inv_mu, color.map(|c| c.data[pix]));
                        n += 1;
                    }
                }
            }
            debug_assert_eq!(i, VOXELS_PER_BLOCK);
            n
        })
        .sum();
    let touched = layer.put_blocks_observed(taken);
    let stats = FusionStats {
        blocks: touched.len(),
        voxel_updates: updates,
        measurements: plan.measurements,
    };
    (touched, stats)
}
