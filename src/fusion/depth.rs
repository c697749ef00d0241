//! Projective fusion of depth maps (the paper's update, with colour).

use super::depth_block::{fuse_block, FramePixels};
use super::traverse::traverse_cells;
use super::FusionStats;
use crate::frame::DepthFrame;
use crate::grid::{BlockIndex, GridParams, Layer, TouchedBlocks};
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

/// Edge of the image tiles [`depth_frame_blocks`] lists blocks for, pixels.
pub const BAND_TILE_PX: usize = 8;

/// The blocks a depth frame's truncation band reaches, sorted: for every tile of
/// [`BAND_TILE_PX`]² pixels, the blocks that meet the tile's viewing frustum between the
/// depths `d_min − μ` and `d_max + μ` of its usable pixels (depths split into separate ranges
/// where two consecutive ones differ by more than 2μ, so free space between a foreground and a
/// background surface is not listed; a tile whose range spreads over more than μ/2 is split
/// into quadrants, down to 2×2 pixels). A superset of [`depth_frame_blocks_exact`] (every pixel's
/// band segment lies in its tile's slice; `tests/core/analytic.rs` checks the superset and how
/// many blocks it adds), at a cost per tile instead of per pixel. Each slice is cut along the
/// view into pieces no deeper than a block; a block is listed when it lies in a piece's
/// bounding box and on the inner side of the piece's six planes (a box–plane test with a 1 µm
/// margin). Reads no layer.
pub fn depth_frame_blocks(
    grid: &GridParams,
    frame: &DepthFrame,
    params: &DepthFusionParams,
) -> TouchedBlocks {
    let k = &frame.intrinsics;
    let (w, h) = (frame.depth_m.width as usize, frame.depth_m.height as usize);
    let mu = grid.truncation_m as f64;
    let block = grid.block_size_m();
    let slices = SliceGeometry {
        rot: frame
            .world_from_camera
            .rotation
            .to_rotation_matrix()
            .into_inner(),
        origin: frame.world_from_camera.translation.vector,
        block_m: block,
    };
    let tiles = TileLister {
        data: &frame.depth_m.data,
        width: w,
        fx: k.fx,
        fy: k.fy,
        cx: k.cx,
        cy: k.cy,
        mu,
        params,
        slices,
    };
    let tiles_x = w.div_ceil(BAND_TILE_PX);
    let mut keys: Vec<u64> = (0..h.div_ceil(BAND_TILE_PX))
        .into_par_iter()
        .fold(Listed::new, |mut out, ty| {
            let mut depths: Vec<f32> = Vec::with_capacity(BAND_TILE_PX * BAND_TILE_PX);
            let v0 = ty * BAND_TILE_PX;
            let v1 = (v0 + BAND_TILE_PX).min(h) - 1;
            for tx in 0..tiles_x {
                let u0 = tx * BAND_TILE_PX;
                let u1 = (u0 + BAND_TILE_PX).min(w) - 1;
                let tile = Tile {
                    u: [u0, u1],
                    v: [v0, v1],
                };
                tile_blocks(tile, &tiles, &mut depths, &mut out);
            }
            out
        })
        .map(|listed| listed.keys)
        .reduce(Vec::new, |mut x, mut y| {
            x.append(&mut y);
            x
        });
    keys.par_sort_unstable();
    keys.dedup();
    let mut all: Vec<BlockIndex> = keys.into_iter().map(BlockIndex::unpack).collect();
    all.par_sort_unstable();
    all
}

/// A tile whose depths (within one range) spread over more than this many μ is split.
const SPLIT_SPREAD: f64 = 0.5;

/// A rectangle of pixels, inclusive bounds.
#[derive(Clone, Copy)]
struct Tile {
    u: [usize; 2],
    v: [usize; 2],
}

/// What [`tile_blocks`] reads.
struct TileLister<'a> {
    data: &'a [f32],
    width: usize,
    fx: f64,
    fy: f64,
    cx: f64,
    cy: f64,
    mu: f64,
    params: &'a DepthFusionParams,
    slices: SliceGeometry,
}

/// Lists the blocks of one tile into `out`: its usable depths, split into ranges at gaps of
/// more than 2μ; a tile whose depths (within one range) spread over more than μ/2 (a surface
/// seen at a grazing angle) is split into quadrants, down to 2×2 pixels, so that the slice
/// stays close to the union of its pixels' band segments.
fn tile_blocks(tile: Tile, l: &TileLister, depths: &mut Vec<f32>, out: &mut Listed) {
    depths.clear();
    for v in tile.v[0]..=tile.v[1] {
        let row = &l.data[v * l.width..];
        depths.extend(
            row[tile.u[0]..=tile.u[1]]
                .iter()
                .filter(|&&d| usable(d, l.params)),
        );
    }
    if depths.is_empty() {
        return;
    }
    let (lo, hi) = depths
        .iter()
        .fold((f32::INFINITY, f32::NEG_INFINITY), |(lo, hi), &d| {
            (lo.min(d), hi.max(d))
        });
    let mut ranges: Vec<(f64, f64)> = Vec::new();
    if (hi - lo) as f64 <= 2.0 * l.mu {
        // No gap of more than 2μ can fit: one range, no sort.
        ranges.push((lo as f64, hi as f64));
    } else {
        depths.sort_unstable_by(f32::total_cmp);
        let mut start = 0;
        for i in 1..=depths.len() {
            if i == depths.len() || (depths[i] - depths[i - 1]) as f64 > 2.0 * l.mu {
                ranges.push((depths[start] as f64, depths[i - 1] as f64));
                start = i;
            }
        }
    }
    let smallest = tile.u[1] - tile.u[0] < 2 && tile.v[1] - tile.v[0] < 2;
    if !smallest && ranges.iter().any(|(lo, hi)| hi - lo > SPLIT_SPREAD * l.mu) {
        let um = (tile.u[0] + tile.u[1]) / 2;
        let vm = (tile.v[0] + tile.v[1]) / 2;
        for u in [[tile.u[0], um], [um + 1, tile.u[1]]] {
            for v in [[tile.v[0], vm], [vm + 1, tile.v[1]]] {
                if u[0] <= u[1] && v[0] <= v[1] {
                    tile_blocks(Tile { u, v }, l, depths, out);
                }
            }
        }
        return;
    }
    // Lateral bounds: the rays through the tile's pixel centres (z = 1).
    let a = [
        (tile.u[0] as f64 - l.cx) / l.fx,
        (tile.u[1] as f64 - l.cx) / l.fx,
    ];
    let b = [
        (tile.v[0] as f64 - l.cy) / l.fy,
        (tile.v[1] as f64 - l.cy) / l.fy,
    ];
    for (lo, hi) in ranges {
        l.slices
            .blocks_of_slice(a, b, (lo - l.mu).max(0.0), hi + l.mu, out);
    }
}

/// A frame's pose as [`depth_frame_blocks`] uses it.
struct SliceGeometry {
    /// World from camera rotation.
    rot: nalgebra::Matrix3<f64>,
    /// Camera centre, world frame, metres.
    origin: Vector3<f64>,
    block_m: f64,
}

/// Slots of [`Listed::seen`] (a power of two).
const SEEN_SLOTS: usize = 1024;

/// The blocks one worker listed (packed, unsorted, with some repeats), and a direct-mapped
/// cache of listed keys: neighbouring tiles meet mostly the same blocks, and a candidate found
/// in the cache is skipped before its geometric test.
struct Listed {
    keys: Vec<u64>,
    /// `u64::MAX` (which no packed index equals) or a key in `keys`.
    seen: Box<[u64; SEEN_SLOTS]>,
}

impl Listed {
    fn new() -> Self {
        Listed {
            keys: Vec::new(),
            seen: Box::new([u64::MAX; SEEN_SLOTS]),
        }
    }

    fn slot(key: u64) -> usize {
        (key.wrapping_mul(0x9E37_79B9_7F4A_7C15) >> (64 - SEEN_SLOTS.trailing_zeros())) as usize
    }
}

impl SliceGeometry {
    /// Pushes (packed, unsorted, with repeats) the blocks meeting the frustum slice
    /// `{x/z ∈ [a0, a1], y/z ∈ [b0, b1], z ∈ [z0, z1]}` (camera frame).
    fn blocks_of_slice(&self, a: [f64; 2], b: [f64; 2], z0: f64, z1: f64, out: &mut Listed) {
        const MARGIN_M: f64 = 1e-6;
        let r = &self.rot;
        let to_world = |c: Vector3<f64>| r * c;
        // Side planes through the camera centre, inward normals (camera: x − a0·z ≥ 0, …).
        let sides = [
            Vector3::new(1.0, 0.0, -a[0]),
            Vector3::new(-1.0, 0.0, a[1]),
            Vector3::new(0.0, 1.0, -b[0]),
            Vector3::new(0.0, -1.0, b[1]),
        ]
        .map(to_world);
        let view = to_world(Vector3::z());
        let half = 0.5 * self.block_m;
        let reach = |n: &Vector3<f64>| half * (n.x.abs() + n.y.abs() + n.z.abs());
        let side_reach = sides.map(|n| reach(&n));
        let view_reach = reach(&view);
        // The slice's four edge rays (z = 1), world frame: a corner at depth z is origin + z·ray.
        let rays =
            [(0, 0), (0, 1), (1, 0), (1, 1)].map(|(i, j)| to_world(Vector3::new(a[i], b[j], 1.0)));
        let pieces = ((z1 - z0) / self.block_m).ceil().max(1.0) as usize;
        let dz = (z1 - z0) / pieces as f64;
        for p in 0..pieces {
            let za = z0 + dz * p as f64;
            let zb = if p + 1 == pieces { z1 } else { za + dz };
            let mut lo = [f64::INFINITY; 3];
            let mut hi = [f64::NEG_INFINITY; 3];
            for z in [za, zb] {
                for ray in &rays {
                    for k in 0..3 {
                        let c = self.origin[k] + z * ray[k];
                        lo[k] = lo[k].min(c);
                        hi[k] = hi[k].max(c);
                    }
                }
            }
            let first = lo.map(|v| crate::grid::floor_i64((v - MARGIN_M) / self.block_m));
            let last = hi.map(|v| crate::grid::floor_i64((v + MARGIN_M) / self.block_m));
            for bx in first[0]..=last[0] {
                for by in first[1]..=last[1] {
                    for bz in first[2]..=last[2] {
                        let key = BlockIndex([bx as i32, by as i32, bz as i32]).pack();
                        // Listed already (neighbouring tiles list mostly the same blocks).
                        let slot = Listed::slot(key);
                        if out.seen[slot] == key {
                            continue;
                        }
                        let centre = Vector3::new(
                            (bx as f64 + 0.5) * self.block_m,
                            (by as f64 + 0.5) * self.block_m,
                            (bz as f64 + 0.5) * self.block_m,
                        ) - self.origin;
                        let depth = view.dot(&centre);
                        let inside = depth + view_reach >= za - MARGIN_M
                            && depth - view_reach <= zb + MARGIN_M
                            && sides
                                .iter()
                                .zip(&side_reach)
                                .all(|(n, r)| n.dot(&centre) + r >= -MARGIN_M);
                        if inside {
                            out.seen[slot] = key;
                            out.keys.push(key);
                        }
                    }
                }
            }
        }
    }
}

/// The blocks crossed by the truncation band `[max(d − μ, 0), d + μ]` of every usable pixel,
/// exactly (one block-level ray walk per pixel), sorted: the definition before issue 14,
/// [`depth_frame_blocks`]'s lower bound (kept for the tests that measure the difference).
pub fn depth_frame_blocks_exact(
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
    let all: Vec<BlockIndex> = layer.iter_unsorted().map(|(i, _)| *i).collect();
    let mut v: Vec<BlockIndex> = all
        .into_par_iter()
        .filter(|i| {
            let o = grid.block_origin(*i);
            frustum.meets_sphere([o[0] + half, o[1] + half, o[2] + half], radius)
        })
        .collect();
    v.par_sort_unstable();
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
        // Both lists are sorted: merged in one pass.
        let visible = visible_blocks_in(layer, &self.frustum);
        let mut blocks = Vec::with_capacity(self.band.len() + visible.len());
        let (mut a, mut b) = (self.band.iter().peekable(), visible.iter().peekable());
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
            blocks.extend(next);
        }
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
    let updates: Vec<usize> = FramePixels::with(frame, params, |pixels| {
        taken
            .par_iter_mut()
            .map(|(index, block)| {
                let base = g.block_base(&grid, *index);
                fuse_block(g, [base.x, base.y, base.z], pixels, block)
            })
            .collect()
    });
    // A block with an update has a voxel in Ω: only the others are scanned.
    let touched = layer.put_blocks_observed_unless(taken, |k| updates[k] > 0);
    let stats = FusionStats {
        blocks: touched.len(),
        voxel_updates: updates.iter().sum(),
        measurements: plan.measurements,
    };
    (touched, stats)
}
