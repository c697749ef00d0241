//! Projective fusion of depth maps (the paper's update, with colour).

use super::band::{list_band, BandListing};
use super::depth_block::{fuse_block, FramePixels};
use super::FusionStats;
use crate::frame::DepthFrame;
use crate::gpu::thread_cpu_s;
use crate::grid::{
    tile_bit, tile_block, tile_blocks, tile_of, BlockIndex, GridParams, Layer, TouchedBlocks,
    TILE_EDGE,
};
use nalgebra::{Isometry3, Point3, Vector3};
use rayon::prelude::*;

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
/// twin, `src/gpu/fuse.rs`). Always inlined, also into the kernels compiled for wider vectors.
#[inline(always)]
pub(crate) fn usable(d: f32, p: &DepthFusionParams) -> bool {
    d.is_finite() && d >= p.min_depth_m && d <= p.max_depth_m
}

/// The view volume of a depth frame as half-spaces (camera frame: near `z > 0`, far
/// `z < max_depth + μ`, and the four planes through the optical centre and the image borders
/// widened by one pixel). [`ViewFrustum::meets_sphere`] is conservative and monotone: a sphere
/// that contains a passing sphere passes too, so a pager can select chunks with the same test that
/// selects blocks and page in every block fusion could update.
#[derive(Clone, Copy, Debug)]
pub struct ViewFrustum {
    pub(crate) camera_from_world: nalgebra::Isometry3<f64>,
    /// Unit inward normals of the side planes (through the camera centre), camera frame.
    pub(crate) sides: [Vector3<f64>; 4],
    /// The widened image borders on the plane z = 1: x0, x1, y0, y1.
    borders: [f64; 4],
    pub(crate) far_m: f64,
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
            borders: [x0, x1, y0, y1],
            far_m: params.max_depth_m as f64 + truncation_m,
        }
    }

    /// The box of block indices (first and last, inclusive) holding every block that
    /// [`ViewFrustum::meets_block`] passes: the world bounding box of the frustum with each
    /// side moved out by a block's bounding radius (the set of centres that pass), whose cross
    /// sections are rectangles linear in z, so its eight corners at the two ends bound it.
    pub fn block_box(&self, grid: &GridParams) -> ([i64; 3], [i64; 3]) {
        let s = grid.block_size_m();
        let r = 0.5 * s * 3f64.sqrt();
        let [x0, x1, y0, y1] = self.borders;
        // Out-moved sides: x ≥ x0·z − r·|(1, −x0)|, and so on.
        let grow = |a: f64| r * (1.0 + a * a).sqrt();
        let world_from_camera = self.camera_from_world.inverse();
        let (mut lo, mut hi) = ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]);
        for z in [-r, self.far_m + r] {
            for x in [x0 * z - grow(x0), x1 * z + grow(x1)] {
                for y in [y0 * z - grow(y0), y1 * z + grow(y1)] {
                    let w = world_from_camera * Point3::new(x, y, z);
                    for k in 0..3 {
                        lo[k] = lo[k].min(w[k]);
                        hi[k] = hi[k].max(w[k]);
                    }
                }
            }
        }
        // Centres (i + ½)·s within [lo, hi], one block of margin for rounding.
        (
            lo.map(|v| (v / s - 0.5).floor() as i64 - 1),
            hi.map(|v| (v / s - 0.5).ceil() as i64 + 1),
        )
    }

    /// Whether the sphere of `radius_m` around world point `centre` meets every half-space.
    pub fn meets_sphere(&self, centre: [f64; 3], radius_m: f64) -> bool {
        let c = self.camera_from_world * Point3::new(centre[0], centre[1], centre[2]);
        if c.z < -radius_m || c.z > self.far_m + radius_m {
            return false;
        }
        self.sides.iter().all(|n| n.dot(&c.coords) > -radius_m)
    }

    /// Whether block `i`'s bounding sphere passes [`ViewFrustum::meets_sphere`]: the test that
    /// puts an allocated block in view.
    #[inline]
    pub fn meets_block(&self, grid: &GridParams, i: BlockIndex) -> bool {
        let half = 0.5 * grid.block_size_m();
        let o = grid.block_origin(i);
        self.meets_sphere([o[0] + half, o[1] + half, o[2] + half], half * 3f64.sqrt())
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

/// [`visible_blocks`] for a frustum already built. It searches the layer's occupancy tiles
/// ([`Layer::occupied_tiles`], a mask of 4³ block positions each) rather than the blocks:
/// where the frustum's box of blocks ([`ViewFrustum::block_box`]) covers fewer tiles than the
/// layer holds (a long drive in RAM), it looks the box's tiles up; otherwise it takes the
/// layer's every tile. Either way a tile whose bounding sphere misses the frustum is skipped
/// whole, a tile deep inside it is taken whole, and the blocks of the others are tested one by
/// one, as [`visible_blocks_by_scan`] tests them: both give the same blocks.
pub fn visible_blocks_in(layer: &Layer, frustum: &ViewFrustum) -> TouchedBlocks {
    let (first, last) = frustum.block_box(&layer.params());
    let tiles = box_tiles(first, last);
    let tile_count = tiles.1.iter().map(|&n| n as u128).product::<u128>();
    let from = if tile_count < layer.tile_count() as u128 {
        TilesFrom::Box(tiles)
    } else {
        TilesFrom::Layer
    };
    visible_blocks_in_tiles(layer, frustum, from)
}

/// [`visible_blocks_in`], testing every block of the layer: the oracle of the tiled search.
pub fn visible_blocks_by_scan(layer: &Layer, frustum: &ViewFrustum) -> TouchedBlocks {
    let grid = layer.params();
    let all: Vec<BlockIndex> = layer.iter_unsorted().map(|(i, _)| *i).collect();
    let mut v: Vec<BlockIndex> = all
        .into_par_iter()
        .filter(|i| frustum.meets_block(&grid, *i))
        .collect();
    v.par_sort_unstable();
    v
}

/// The tiles that cover the block positions `first..=last`: the first tile and the number of
/// tiles along each axis (0 where the box is empty).
fn box_tiles(first: [i64; 3], last: [i64; 3]) -> ([i32; 3], [i64; 3]) {
    let clamp = |v: i64| v.clamp(i32::MIN as i64 / 2, i32::MAX as i64 / 2) as i32;
    let tile = |v: i64| clamp(v).div_euclid(TILE_EDGE);
    let (first, last) = (first.map(tile), last.map(tile));
    let n = [0, 1, 2].map(|k| (last[k] as i64 - first[k] as i64 + 1).max(0));
    (first, n)
}

/// Where [`visible_blocks_in_tiles`] takes its candidate tiles from.
#[derive(Clone, Copy, Debug)]
enum TilesFrom {
    /// The tiles of a box (the first, and how many along each axis), looked up in the layer.
    Box(([i32; 3], [i64; 3])),
    /// Every tile of the layer.
    Layer,
}

/// The blocks of `layer` that meet `frustum`, sorted, searched tile by tile ([`TilesFrom`]).
fn visible_blocks_in_tiles(layer: &Layer, frustum: &ViewFrustum, from: TilesFrom) -> TouchedBlocks {
    let grid = layer.params();
    let s = grid.block_size_m();
    // A tile's sphere holds its blocks' spheres (a corner block's touches it from inside);
    // widened a little, so that rounding can never drop a tile a block of which meets the
    // frustum: the blocks' own test decides.
    let edge_m = TILE_EDGE as f64 * s;
    let radius_m = 0.5 * edge_m * 3f64.sqrt() * (1.0 + 1e-9) + 1e-9;
    // A tile whose centre lies this deep inside every plane holds only blocks whose centres
    // lie inside (they are at most 1.5·√3 blocks from it), far from where a block's test
    // (whose sphere reaches √3/2 of a block beyond its centre) could round either way.
    let inside_m = -(1.5 * s * 3f64.sqrt() * (1.0 + 1e-9) + 1e-9);
    // The tile's blocks in view, as a mask.
    let in_view = |(tile, mask): (BlockIndex, u64)| {
        let centre = tile.0.map(|t| (t as f64 + 0.5) * edge_m);
        if mask == 0 || !frustum.meets_sphere(centre, radius_m) {
            return (tile, 0);
        }
        if frustum.meets_sphere(centre, inside_m) {
            return (tile, mask);
        }
        let kept = tile_blocks(tile, mask)
            .filter(|b| frustum.meets_block(&grid, *b))
            .fold(0, |kept, b| kept | tile_of(b).1);
        (tile, kept)
    };
    // Fewer tiles than this are searched on the calling thread: waking the pool costs more.
    const ON_ONE_THREAD: usize = 1 << 13;
    let mut tiles: Vec<(BlockIndex, u64)> = match from {
        TilesFrom::Layer if layer.tile_count() < ON_ONE_THREAD => {
            layer.occupied_tiles().map(in_view).collect()
        }
        TilesFrom::Layer => {
            let tiles: Vec<(BlockIndex, u64)> = layer.occupied_tiles().collect();
            tiles.into_par_iter().map(in_view).collect()
        }
        TilesFrom::Box((first, n)) => {
            let tile = |t: i64| {
                let at = [t % n[0], (t / n[0]) % n[1], t / (n[0] * n[1])];
                let tile = BlockIndex([0, 1, 2].map(|k| first[k] + at[k] as i32));
                in_view((tile, layer.tile_mask(tile)))
            };
            let count = n[0] * n[1] * n[2];
            if count < ON_ONE_THREAD as i64 {
                (0..count).map(tile).collect()
            } else {
                (0..count).into_par_iter().map(tile).collect()
            }
        }
    };
    tiles.retain(|(_, mask)| *mask != 0);
    tiles.sort_unstable();
    blocks_of_sorted_tiles(&tiles)
}

/// The blocks that sorted tiles' masks hold, in the blocks' order (x, then y, then z), without
/// sorting them: for each x-column of tiles, each x; for each of its y-rows of tiles, each y;
/// then each tile of the row, z by z.
fn blocks_of_sorted_tiles(tiles: &[(BlockIndex, u64)]) -> TouchedBlocks {
    let e = TILE_EDGE;
    let count = tiles.iter().map(|(_, m)| m.count_ones() as usize).sum();
    let mut out = Vec::with_capacity(count);
    for column in tiles.chunk_by(|a, b| a.0 .0[0] == b.0 .0[0]) {
        for rx in 0..e {
            for row in column.chunk_by(|a, b| a.0 .0[1] == b.0 .0[1]) {
                for ry in 0..e {
                    for (tile, mask) in row {
                        for rz in 0..e {
                            if mask & tile_bit([rx, ry, rz]) != 0 {
                                out.push(tile_block(*tile, [rx, ry, rz]));
                            }
                        }
                    }
                }
            }
        }
    }
    out
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
        self.block_base_f64(grid, block).cast()
    }

    /// [`DepthGeometry::block_base`] before its rounding to f32.
    pub fn block_base_f64(&self, grid: &GridParams, block: BlockIndex) -> Vector3<f64> {
        let vs = self.voxel_size_m;
        let o = grid.block_origin(block);
        let centre0 = Point3::new(o[0] + 0.5 * vs, o[1] + 0.5 * vs, o[2] + 0.5 * vs);
        (self.camera_from_world * centre0).coords
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
    /// Of the calling thread's CPU time, seconds spent listing the band
    /// ([`crate::gpu::thread_cpu_s`]).
    pub listing_cpu_s: f64,
}

impl DepthPlan {
    /// Lists the band of `frame` on `grid` and its geometry.
    pub fn new(grid: &GridParams, frame: &DepthFrame, params: &DepthFusionParams) -> Self {
        let (t, cpu) = (std::time::Instant::now(), thread_cpu_s());
        let BandListing {
            blocks: band,
            usable_pixels: measurements,
            skipped_slices,
        } = list_band(grid, frame, params, true);
        tracing::trace!(blocks = band.len(), skipped_slices, "band listed");
        let listing_s = t.elapsed().as_secs_f64();
        DepthPlan {
            band,
            frustum: ViewFrustum::new(frame, params, grid.truncation_m as f64),
            geometry: DepthGeometry::new(grid, frame),
            measurements,
            camera_m: frame.world_from_camera.translation.vector.into(),
            listing_s,
            listing_cpu_s: thread_cpu_s() - cpu,
        }
    }

    /// The plan of a frame whose depths are elsewhere (on the device), from its band slices
    /// ([`super::band_slices`] or their GPU twin): the same plan as [`DepthPlan::new`] gives
    /// the frame with its depths. `frame` gives the camera, the pose and the image size.
    pub fn from_slices(
        grid: &GridParams,
        frame: &DepthFrame,
        params: &DepthFusionParams,
        slices: &super::BandSlices,
    ) -> Self {
        let t = (std::time::Instant::now(), thread_cpu_s());
        let (k, pose) = (&frame.intrinsics, &frame.world_from_camera);
        let band = super::blocks_of_band_slices(grid, k, pose, params, slices);
        Self::of_band(grid, frame, params, (band, slices.usable_pixels), t)
    }

    /// [`DepthPlan::from_slices`] from the band as the device listed it
    /// ([`super::DeviceBand`]: its blocks, and the slices it left to the host).
    pub fn from_device_band(
        grid: &GridParams,
        frame: &DepthFrame,
        params: &DepthFusionParams,
        band: &super::DeviceBand,
    ) -> Self {
        let t = (std::time::Instant::now(), thread_cpu_s());
        let (k, pose) = (&frame.intrinsics, &frame.world_from_camera);
        let blocks = band.blocks(grid, k, pose, params);
        Self::of_band(grid, frame, params, (blocks, band.usable_pixels), t)
    }

    /// The plan of `frame` with its band and usable pixels listed already (since `started`,
    /// and the thread's CPU time then).
    fn of_band(
        grid: &GridParams,
        frame: &DepthFrame,
        params: &DepthFusionParams,
        (band, measurements): (TouchedBlocks, usize),
        (started, started_cpu_s): (std::time::Instant, f64),
    ) -> Self {
        DepthPlan {
            band,
            frustum: ViewFrustum::new(frame, params, grid.truncation_m as f64),
            geometry: DepthGeometry::new(grid, frame),
            measurements,
            camera_m: frame.world_from_camera.translation.vector.into(),
            listing_s: started.elapsed().as_secs_f64(),
            listing_cpu_s: thread_cpu_s() - started_cpu_s,
        }
    }

    /// The blocks fusion updates: the band plus the allocated blocks of `layer` in view, sorted.
    pub fn blocks(&self, layer: &Layer) -> TouchedBlocks {
        merge_sorted(&self.band, &visible_blocks_in(layer, &self.frustum))
    }

    /// [`DepthPlan::blocks`], with the blocks of `unsettled` (sorted) in view listed as if
    /// `layer` had them: blocks a GPU frame still in flight may have created
    /// (`src/gpu/resident/late.rs`; its kernel skips those no frame did create).
    pub fn blocks_with(&self, layer: &Layer, unsettled: &[BlockIndex]) -> TouchedBlocks {
        let (listed, unsettled) = self.blocks_and_unsettled(layer, unsettled);
        merge_sorted(&listed, &unsettled)
    }

    /// [`DepthPlan::blocks_with`] in two sorted lists: [`DepthPlan::blocks`], and the blocks
    /// of `unsettled` (sorted; blocks `layer` lacks) in view that the band does not hold.
    pub fn blocks_and_unsettled(
        &self,
        layer: &Layer,
        unsettled: &[BlockIndex],
    ) -> (TouchedBlocks, TouchedBlocks) {
        let grid = layer.params();
        let in_view: Vec<BlockIndex> = (unsettled.iter().copied())
            .filter(|b| self.frustum.meets_block(&grid, *b) && self.band.binary_search(b).is_err())
            .collect();
        (self.blocks(layer), in_view)
    }
}

/// The union of two sorted lists without repeats, sorted (one pass).
pub(crate) fn merge_sorted(a: &[BlockIndex], b: &[BlockIndex]) -> TouchedBlocks {
    let mut out = Vec::with_capacity(a.len() + b.len());
    let (mut a, mut b) = (a.iter().peekable(), b.iter().peekable());
    loop {
        let next = match (a.peek(), b.peek()) {
            (Some(&&x), Some(&&y)) if x < y => a.next(),
            (Some(&&x), Some(&&y)) if y < x => b.next(),
            (Some(_), Some(_)) => {
                b.next();
                a.next()
            }
            (Some(_), None) => a.next(),
            (None, Some(_)) => b.next(),
            (None, None) => break,
        };
        out.extend(next.copied());
    }
    out
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
///
/// Fuses the blocks of [`DepthPlan::blocks`] (the band, allocated where missing, and the
/// allocated blocks in view) where they lie, in one parallel pass ([`Layer::update_in_place`]);
/// a block left with no voxel in Ω (allocated for a band whose voxels all fell outside the
/// image, say) is dropped.
pub fn integrate_depth_plan(
    layer: &mut Layer,
    frame: &DepthFrame,
    params: &DepthFusionParams,
    plan: &DepthPlan,
) -> (TouchedBlocks, FusionStats) {
    let grid = layer.params();
    let in_view = |i: &BlockIndex| plan.frustum.meets_block(&grid, *i);
    let g = &plan.geometry;
    let fused = FramePixels::with(frame, params, |pixels| {
        layer.update_in_place(&plan.band, in_view, |index, block| {
            let base = g.block_base(&grid, *index);
            let n = fuse_block(g, [base.x, base.y, base.z], pixels, block);
            // An updated block has a voxel in Ω.
            (n, n > 0 || block.observed())
        })
    });
    let voxel_updates = fused.iter().map(|(_, n, _)| n).sum();
    let touched: TouchedBlocks = fused
        .into_iter()
        .filter(|(_, _, kept)| *kept)
        .map(|(i, _, _)| i)
        .collect();
    let stats = FusionStats {
        blocks: touched.len(),
        voxel_updates,
        measurements: plan.measurements,
    };
    (touched, stats)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::PinholeIntrinsics;
    use crate::frame::Image;
    use nalgebra::{Translation3, UnitQuaternion};

    #[test]
    fn the_frustums_box_holds_every_block_in_view() {
        // Blocks scattered around cameras in many poses: the tiles' search, of the box's tiles
        // or of the layer's, finds exactly the blocks the scan of the layer finds; on the finer
        // grid many tiles lie wholly inside the view, on the coarser few.
        for voxel_m in [0.2, 0.05] {
            let seen = blocks_in_view_of_random_poses(GridParams::paper(voxel_m));
            assert!(seen > 3_000, "{seen} blocks in view at {voxel_m} m");
        }
    }

    fn blocks_in_view_of_random_poses(grid: GridParams) -> usize {
        let params = DepthFusionParams {
            max_depth_m: 12.0,
            ..Default::default()
        };
        let mut rng = 0x1234_5678_9abc_def0u64;
        let mut next = move || {
            rng ^= rng << 13;
            rng ^= rng >> 7;
            rng ^= rng << 17;
            (rng >> 11) as f64 / (1u64 << 53) as f64
        };
        let mut layer = Layer::new(grid);
        for _ in 0..20_000 {
            let b = [0; 3].map(|_| (next() * 40.0) as i32 - 20);
            layer.get_or_allocate(BlockIndex(b));
        }
        let mut seen = 0;
        for k in 0..40 {
            let rot = UnitQuaternion::from_euler_angles(
                next() * 6.3 - 3.15,
                next() * 6.3 - 3.15,
                next() * 6.3 - 3.15,
            );
            let t = [0; 3].map(|_| next() * 20.0 - 10.0);
            let (w, h) = if k % 2 == 0 { (1241, 376) } else { (64, 480) };
            let frame = DepthFrame {
                intrinsics: PinholeIntrinsics {
                    fx: 300.0 + next() * 500.0,
                    fy: 300.0 + next() * 500.0,
                    cx: w as f64 * next(),
                    cy: h as f64 * next(),
                    width: w,
                    height: h,
                },
                world_from_camera: Isometry3::from_parts(Translation3::new(t[0], t[1], t[2]), rot),
                depth_m: Image::filled(w, h, 1.0),
                color: None,
            };
            let frustum = ViewFrustum::new(&frame, &params, grid.truncation_m as f64);
            let by_scan = visible_blocks_by_scan(&layer, &frustum);
            let (first, last) = frustum.block_box(&grid);
            let from_box = TilesFrom::Box(box_tiles(first, last));
            let boxed = visible_blocks_in_tiles(&layer, &frustum, from_box);
            assert_eq!(by_scan, boxed, "pose {k}");
            let tiled = visible_blocks_in_tiles(&layer, &frustum, TilesFrom::Layer);
            assert_eq!(by_scan, tiled, "pose {k}");
            assert_eq!(visible_blocks_in(&layer, &frustum), by_scan);
            seen += by_scan.len();
        }
        seen
    }
}
