//! The blocks a depth frame's truncation band reaches: listed per image tile
//! ([`depth_frame_blocks`], what fusion and the pager use) and exactly, per pixel
//! ([`depth_frame_blocks_exact`], the lower bound the tests compare with).

use super::depth::{usable, DepthFusionParams};
use super::traverse::traverse_cells;
use crate::camera::PinholeIntrinsics;
use crate::frame::DepthFrame;
use crate::grid::{BlockIndex, GridParams, TouchedBlocks};
use nalgebra::{Isometry3, Vector3};
use rayon::prelude::*;
use std::collections::HashSet;

mod slices;
pub use slices::{
    band_slices, blocks_of_band_slices, BandSlice, BandSlices, BAND_SLICE_MAX_SIDE_PX,
};

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
    list_band(grid, frame, params, true).blocks
}

/// [`depth_frame_blocks`], with the number of usable pixels (counted on the way). `skip_listed`:
/// whether a slice whose blocks are all listed already is skipped (always, but for the test
/// that checks the skip changes nothing).
pub(super) fn list_band(
    grid: &GridParams,
    frame: &DepthFrame,
    params: &DepthFusionParams,
    skip_listed: bool,
) -> BandListing {
    let (w, h) = (frame.depth_m.width as usize, frame.depth_m.height as usize);
    let (k, pose) = (&frame.intrinsics, &frame.world_from_camera);
    let tiles = TileLister::new(grid, k, pose, params).over(&frame.depth_m.data, w);
    let tiles_x = w.div_ceil(BAND_TILE_PX);
    let (keys, usable_pixels, skipped_slices) = (0..h.div_ceil(BAND_TILE_PX))
        .into_par_iter()
        .fold(
            || Listed::new(skip_listed),
            |mut out, ty| {
                let v0 = ty * BAND_TILE_PX;
                let v1 = (v0 + BAND_TILE_PX).min(h) - 1;
                for tx in 0..tiles_x {
                    let u0 = tx * BAND_TILE_PX;
                    let u1 = (u0 + BAND_TILE_PX).min(w) - 1;
                    let tile = Tile {
                        u: [u0, u1],
                        v: [v0, v1],
                    };
                    let range = tiles.range(tile);
                    out.usable_pixels += range.count;
                    tile_blocks(tile, range, &tiles, &mut out);
                }
                out
            },
        )
        .map(|listed| (listed.keys, listed.usable_pixels, listed.skipped))
        .reduce(
            || (Vec::new(), 0, 0),
            |(mut x, nx, sx), (mut y, ny, sy)| {
                x.append(&mut y);
                (x, nx + ny, sx + sy)
            },
        );
    BandListing {
        blocks: sorted_blocks(keys),
        usable_pixels,
        skipped_slices,
    }
}

/// The blocks of the sort keys `keys` (with repeats, in any order), sorted.
pub(super) fn sorted_blocks(mut keys: Vec<u64>) -> TouchedBlocks {
    // Sort keys are in the blocks' order: one sort of integers.
    keys.par_sort_unstable();
    keys.dedup();
    keys.into_iter().map(BlockIndex::from_sort_key).collect()
}

/// What [`list_band`] found.
pub(super) struct BandListing {
    pub(super) blocks: TouchedBlocks,
    pub(super) usable_pixels: usize,
    /// Slices skipped because their blocks were all listed already.
    pub(super) skipped_slices: usize,
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

/// A tile's usable depths: how many, the least and the greatest.
#[derive(Clone, Copy)]
struct TileRange {
    count: usize,
    lo: f32,
    hi: f32,
}

impl<'a> TileLister<'a> {
    /// The lister of a frame of `grid` taken with the camera `k` from the pose
    /// `world_from_camera`, with no depths (only slices can be listed; see [`Self::over`]).
    fn new(
        grid: &GridParams,
        k: &PinholeIntrinsics,
        world_from_camera: &Isometry3<f64>,
        params: &'a DepthFusionParams,
    ) -> Self {
        let rot = world_from_camera.rotation.to_rotation_matrix().into_inner();
        TileLister {
            data: &[],
            width: 0,
            fx: k.fx,
            fy: k.fy,
            cx: k.cx,
            cy: k.cy,
            mu: grid.truncation_m as f64,
            params,
            slices: SliceGeometry {
                columns: [rot.column(0), rot.column(1), rot.column(2)].map(|c| c.into_owned()),
                origin: world_from_camera.translation.vector,
                block_m: grid.block_size_m(),
            },
        }
    }

    /// This lister over the depths `data`, rows `width` pixels long.
    fn over(self, data: &'a [f32], width: usize) -> Self {
        TileLister {
            data,
            width,
            ..self
        }
    }

    /// The usable depths of `tile`.
    #[inline]
    fn range(&self, tile: Tile) -> TileRange {
        tile_range(self.data, self.width, tile, self.params)
    }

    /// The usable depths of `tile`, sorted, into `depths`.
    fn sorted_depths(&self, tile: Tile, depths: &mut Vec<f32>) {
        depths.clear();
        for v in tile.v[0]..=tile.v[1] {
            let row = v * self.width;
            depths.extend(
                self.data[row + tile.u[0]..=row + tile.u[1]]
                    .iter()
                    .filter(|&&d| usable(d, self.params)),
            );
        }
        depths.sort_unstable_by(f32::total_cmp);
    }
}

/// The usable depths of `tile` in the image `data` of rows `width` pixels long. Compiled for
/// AVX-512, AVX2 and the baseline, picked at run time (a full tile's row is one vector).
#[multiversion::multiversion(targets(
    "x86_64+avx512f+avx512bw+avx512vl+avx2+avx+sse4.1",
    "x86_64+avx2+avx+sse4.1",
    "x86_64+sse4.1"
))]
fn tile_range(data: &[f32], width: usize, tile: Tile, params: &DepthFusionParams) -> TileRange {
    let mut r = TileRange {
        count: 0,
        lo: f32::INFINITY,
        hi: f32::NEG_INFINITY,
    };
    let usable = |d: f32| usable(d, params);
    for v in tile.v[0]..=tile.v[1] {
        let row = v * width;
        let row = &data[row + tile.u[0]..=row + tile.u[1]];
        if let Ok(full) = <&[f32; BAND_TILE_PX]>::try_from(row) {
            // A full tile's row, lane-wise as one vector (usable depths are finite, so
            // the selects are the minimum and maximum).
            let ok = full.map(usable);
            r.count += ok.iter().filter(|&&k| k).count();
            let lo = std::array::from_fn::<f32, BAND_TILE_PX, _>(|i| {
                if ok[i] {
                    full[i]
                } else {
                    f32::INFINITY
                }
            });
            let hi = std::array::from_fn::<f32, BAND_TILE_PX, _>(|i| {
                if ok[i] {
                    full[i]
                } else {
                    f32::NEG_INFINITY
                }
            });
            r.lo = lo.iter().fold(r.lo, |a, &b| if b < a { b } else { a });
            r.hi = hi.iter().fold(r.hi, |a, &b| if b > a { b } else { a });
        } else {
            for &d in row {
                if usable(d) {
                    r.count += 1;
                    r.lo = r.lo.min(d);
                    r.hi = r.hi.max(d);
                }
            }
        }
    }
    r
}

/// Lists the blocks of one tile (whose usable depths are `range`) into `out`: its usable
/// depths, split into ranges at gaps of more than 2μ; a tile whose depths (within one range)
/// spread over more than μ/2 (a surface seen at a grazing angle) is split into quadrants, down
/// to 2×2 pixels, so that the slice stays close to the union of its pixels' band segments.
fn tile_blocks<S: BandSink>(tile: Tile, range: TileRange, l: &TileLister, out: &mut S) {
    if range.count == 0 {
        return;
    }
    let smallest = tile.u[1] - tile.u[0] < 2 && tile.v[1] - tile.v[0] < 2;
    let split_spread = SPLIT_SPREAD * l.mu;
    let split = |out: &mut S| {
        let um = (tile.u[0] + tile.u[1]) / 2;
        let vm = (tile.v[0] + tile.v[1]) / 2;
        for u in [[tile.u[0], um], [um + 1, tile.u[1]]] {
            for v in [[tile.v[0], vm], [vm + 1, tile.v[1]]] {
                if u[0] <= u[1] && v[0] <= v[1] {
                    let quadrant = Tile { u, v };
                    tile_blocks(quadrant, l.range(quadrant), l, out);
                }
            }
        }
    };
    let (lo, hi) = (range.lo, range.hi);
    if (hi - lo) as f64 <= 2.0 * l.mu {
        // No gap of more than 2μ can fit: one range, no sort.
        if !smallest && hi as f64 - lo as f64 > split_spread {
            split(out);
        } else {
            out.slice(tile, l, lo as f64, hi as f64);
        }
        return;
    }
    // Ranges of the sorted depths, split at gaps of more than 2μ.
    let mut depths = std::mem::take(out.depths());
    l.sorted_depths(tile, &mut depths);
    let ranges = || {
        let gaps = depths
            .windows(2)
            .enumerate()
            .filter(|(_, p)| (p[1] - p[0]) as f64 > 2.0 * l.mu)
            .map(|(i, _)| i + 1);
        std::iter::once(0)
            .chain(gaps.clone())
            .zip(gaps.chain(std::iter::once(depths.len())))
            .map(|(start, end)| (depths[start] as f64, depths[end - 1] as f64))
    };
    if !smallest && ranges().any(|(lo, hi)| hi - lo > split_spread) {
        *out.depths() = depths;
        split(out);
        return;
    }
    for (lo, hi) in ranges() {
        out.slice(tile, l, lo, hi);
    }
    *out.depths() = depths;
}

/// Where [`tile_blocks`] puts a tile's slices: [`Listed`] lists their blocks at once;
/// `slices.rs` keeps the slices themselves.
trait BandSink {
    /// A buffer for a tile's sorted depths (kept between tiles).
    fn depths(&mut self) -> &mut Vec<f32>;
    /// The band of `tile` whose depths span `[lo, hi]` (metres, each an `f32`).
    fn slice(&mut self, tile: Tile, l: &TileLister, lo: f64, hi: f64);
}

impl BandSink for Listed {
    fn depths(&mut self) -> &mut Vec<f32> {
        &mut self.depths
    }

    #[inline]
    fn slice(&mut self, tile: Tile, l: &TileLister, lo: f64, hi: f64) {
        l.slices.tile_slice(tile, l, lo, hi, self);
    }
}

/// A frame's pose as [`depth_frame_blocks`] uses it.
struct SliceGeometry {
    /// Columns of the world from camera rotation: the camera's x, y and z axes, world frame.
    columns: [Vector3<f64>; 3],
    /// Camera centre, world frame, metres.
    origin: Vector3<f64>,
    block_m: f64,
}

/// Slots of [`Listed::seen`] (a power of two).
const SEEN_SLOTS: usize = 1024;

/// A slice whose corners' box holds more blocks than this is not checked for being listed
/// already (the check would cost more than it saves).
const SKIP_BOX_BLOCKS: i64 = 64;

/// What one worker listed: blocks (as [`BlockIndex::sort_key`]s, unsorted, with some repeats),
/// a direct-mapped cache of listed keys (neighbouring tiles meet mostly the same blocks, and a
/// candidate found in the cache is skipped before its geometric test), the usable pixels of
/// its tiles, and a buffer for a tile's sorted depths.
struct Listed {
    keys: Vec<u64>,
    /// `u64::MAX` (which no key equals) or a key in `keys`.
    seen: Box<[u64; SEEN_SLOTS]>,
    usable_pixels: usize,
    depths: Vec<f32>,
    /// Whether slices whose blocks are all listed already are skipped.
    skip_listed: bool,
    /// Slices skipped so.
    skipped: usize,
}

impl Listed {
    fn new(skip_listed: bool) -> Self {
        Listed {
            keys: Vec::new(),
            seen: Box::new([u64::MAX; SEEN_SLOTS]),
            usable_pixels: 0,
            depths: Vec::with_capacity(BAND_TILE_PX * BAND_TILE_PX),
            skip_listed,
            skipped: 0,
        }
    }

    fn slot(key: u64) -> usize {
        (key.wrapping_mul(0x9E37_79B9_7F4A_7C15) >> (64 - SEEN_SLOTS.trailing_zeros())) as usize
    }
}

impl SliceGeometry {
    /// Lists the blocks of the band of `tile` whose depths span `[lo, hi]`: the frustum slice
    /// through its pixel centres between `max(lo − μ, 0)` and `hi + μ`.
    fn tile_slice(&self, tile: Tile, l: &TileLister, lo: f64, hi: f64, out: &mut Listed) {
        // Lateral bounds: the rays through the tile's pixel centres (z = 1).
        let a = [
            (tile.u[0] as f64 - l.cx) / l.fx,
            (tile.u[1] as f64 - l.cx) / l.fx,
        ];
        let b = [
            (tile.v[0] as f64 - l.cy) / l.fy,
            (tile.v[1] as f64 - l.cy) / l.fy,
        ];
        self.blocks_of_slice(a, b, (lo - l.mu).max(0.0), hi + l.mu, out);
    }

    /// The blocks `first .. end` (per axis) of the box around the slice's corners at depths `za`
    /// and `zb` (both ≥ 0, in either order), widened by `margin_m`; `rays` bounds its edge rays
    /// per axis.
    ///
    /// The same box as the eight corners `origin + z·ray` give one by one: for `z ≥ 0`, the
    /// rounded `z·r` and `origin + z·r` do not decrease with `r`, so the least (greatest) corner
    /// coordinate at a depth is the one of the least (greatest) ray component.
    #[inline]
    fn corner_box(
        &self,
        rays: &RayBounds,
        za: f64,
        zb: f64,
        margin_m: f64,
        inv_block: f64,
    ) -> ([i64; 3], [i64; 3]) {
        let (mut first, mut end) = ([0i64; 3], [0i64; 3]);
        for k in 0..3 {
            let o = self.origin[k];
            let (lo_a, lo_b) = (o + za * rays.lo[k], o + zb * rays.lo[k]);
            let (hi_a, hi_b) = (o + za * rays.hi[k], o + zb * rays.hi[k]);
            let lo = if lo_b < lo_a { lo_b } else { lo_a };
            let hi = if hi_b > hi_a { hi_b } else { hi_a };
            first[k] = floor_div(lo - margin_m, self.block_m, inv_block);
            end[k] = floor_div(hi + margin_m, self.block_m, inv_block) + 1;
        }
        (first, end)
    }

    /// Whether [`Listed::seen`] holds every block of the box `first .. end`.
    fn all_listed(first: [i64; 3], end: [i64; 3], out: &Listed) -> bool {
        (first[0]..end[0]).all(|bx| {
            (first[1]..end[1]).all(|by| {
                (first[2]..end[2]).all(|bz| {
                    let key = BlockIndex([bx as i32, by as i32, bz as i32]).sort_key();
                    out.seen[Listed::slot(key)] == key
                })
            })
        })
    }

    /// Pushes (unsorted, with repeats) the blocks meeting the frustum slice
    /// `{x/z ∈ [a0, a1], y/z ∈ [b0, b1], z ∈ [z0, z1]}` (camera frame).
    fn blocks_of_slice(&self, a: [f64; 2], b: [f64; 2], z0: f64, z1: f64, out: &mut Listed) {
        const MARGIN_M: f64 = 1e-6;
        // Camera-frame vectors rotated to the world as sums of the rotation's columns, in the
        // order of the matrix product (c₀·v₀ + c₁·v₁) + c₂·v₂, without its products by 0 and 1.
        let [cx, cy, cz] = &self.columns;
        // Side planes through the camera centre, inward normals (camera: x − a0·z ≥ 0, …).
        let sides = [
            cx + cz * -a[0],
            -cx + cz * a[1],
            cy + cz * -b[0],
            -cy + cz * b[1],
        ];
        let view = *cz;
        let half = 0.5 * self.block_m;
        let reach = |n: &Vector3<f64>| half * (n.x.abs() + n.y.abs() + n.z.abs());
        // Written out: `array::map` with a closure is not inlined here.
        let side_reach = [
            reach(&sides[0]),
            reach(&sides[1]),
            reach(&sides[2]),
            reach(&sides[3]),
        ];
        let view_reach = reach(&view);
        // The slice's four edge rays (z = 1), world frame: a corner at depth z is origin + z·ray.
        let ray = |i: usize, j: usize| (cx * a[i] + cy * b[j]) + cz;
        let rays = RayBounds::of(&[ray(0, 0), ray(0, 1), ray(1, 0), ray(1, 1)]);
        let inv_block = 1.0 / self.block_m;
        let pieces = ((z1 - z0) / self.block_m).ceil().max(1.0) as usize;
        // Every block a piece can list lies in the box of the slice's eight corners (widened
        // by two margins more, against the rounding of the pieces' corners). When the cache
        // holds all of that box's blocks, they are listed already: nothing to do. (With one
        // piece, the check would cost as much as the piece.)
        if pieces > 1 && out.skip_listed {
            let (first, end) = self.corner_box(&rays, z0, z1, 3.0 * MARGIN_M, inv_block);
            let count = (0..3).map(|k| (end[k] - first[k]).max(0)).product::<i64>();
            if count <= SKIP_BOX_BLOCKS && Self::all_listed(first, end, out) {
                out.skipped += 1;
                return;
            }
        }
        let dz = (z1 - z0) / pieces as f64;
        for p in 0..pieces {
            let za = z0 + dz * p as f64;
            let zb = if p + 1 == pieces { z1 } else { za + dz };
            let (first, end) = self.corner_box(&rays, za, zb, MARGIN_M, inv_block);
            // Exclusive ranges: an inclusive one tests for its last step on every iteration.
            for bx in first[0]..end[0] {
                for by in first[1]..end[1] {
                    for bz in first[2]..end[2] {
                        let key = BlockIndex([bx as i32, by as i32, bz as i32]).sort_key();
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

/// The least and greatest components, per axis, of a slice's four edge rays (world frame).
struct RayBounds {
    lo: [f64; 3],
    hi: [f64; 3],
}

impl RayBounds {
    #[inline]
    fn of(rays: &[Vector3<f64>; 4]) -> Self {
        let mut b = RayBounds {
            lo: [f64::INFINITY; 3],
            hi: [f64::NEG_INFINITY; 3],
        };
        for ray in rays {
            for k in 0..3 {
                b.lo[k] = b.lo[k].min(ray[k]);
                b.hi[k] = b.hi[k].max(ray[k]);
            }
        }
        b
    }
}

/// `⌊x / b⌋` (of the rounded quotient, as `floor_i64(x / b)`) for `b > 0` and `inv_b = 1/b`: a
/// multiplication, and the division only where the product lies so close to an integer (within
/// 10⁻¹⁵·(|q| + 1), more than its error against the quotient) that the two could floor apart.
#[inline(always)]
fn floor_div(x: f64, b: f64, inv_b: f64) -> i64 {
    let q = x * inv_b;
    let f = crate::grid::floor_i64(q);
    // Exact: q and its floor are within one of each other.
    let frac = q - f as f64;
    let tolerance = 1e-15 * (q.abs() + 1.0);
    if frac > tolerance && frac < 1.0 - tolerance {
        f
    } else {
        crate::grid::floor_i64(x / b)
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

#[cfg(test)]
mod tests;
