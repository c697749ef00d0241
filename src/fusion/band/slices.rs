//! A depth frame's band as the slices of its tiles, apart from the blocks they reach: what
//! [`super::depth_frame_blocks`] decides from the depths (which tiles, quadrants and depth
//! ranges make a slice; comparisons and exact differences only) is [`band_slices`] here and
//! `shaders/band_slices.wgsl` on the GPU, so that a depth map made on the device can be
//! summarised there; what it decides from the pose (which blocks a slice meets, in f64) is
//! [`blocks_of_band_slices`], on the host. The two together list exactly
//! [`super::depth_frame_blocks`]'s blocks (`tests/gpu/band_slices.rs`).

use super::{tile_blocks, BandSink, Listed, Tile, TileLister, BAND_TILE_PX};
use crate::camera::PinholeIntrinsics;
use crate::frame::DepthFrame;
use crate::fusion::DepthFusionParams;
use crate::grid::{GridParams, TouchedBlocks};
use nalgebra::Isometry3;
use rayon::prelude::*;

/// One slice of a depth frame's band: the pixels `u[0] ..= u[1]` × `v[0] ..= v[1]` (a tile or
/// one of its quadrants) and the depths `lo_m ..= hi_m` of a range of its usable pixels; its
/// blocks are those meeting the frustum through the pixels' centres between `lo_m − μ` (not
/// below 0) and `hi_m + μ`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BandSlice {
    /// First and last column.
    pub u: [u32; 2],
    /// First and last row.
    pub v: [u32; 2],
    /// Least depth, metres.
    pub lo_m: f32,
    /// Greatest depth, metres.
    pub hi_m: f32,
}

/// Largest image side a packed [`BandSlice`] holds (13 bits per coordinate).
pub const BAND_SLICE_MAX_SIDE_PX: u32 = 1 << 13;

impl BandSlice {
    /// The three words the GPU writes (`shaders/band_slices.wgsl`): the first column and row
    /// (13 bits each, from bit 0 and bit 13), the width − 1 and the height − 1 (3 bits each,
    /// from bits 26 and 29); the bits of `lo_m`; the bits of `hi_m`.
    pub fn pack(&self) -> [u32; 3] {
        let rect = self.u[0]
            | self.v[0] << 13
            | (self.u[1] - self.u[0]) << 26
            | (self.v[1] - self.v[0]) << 29;
        [rect, self.lo_m.to_bits(), self.hi_m.to_bits()]
    }

    /// The slice [`Self::pack`] wrote as `words`.
    pub fn unpack(words: [u32; 3]) -> Self {
        let (u0, v0) = (words[0] & 0x1fff, (words[0] >> 13) & 0x1fff);
        BandSlice {
            u: [u0, u0 + ((words[0] >> 26) & 7)],
            v: [v0, v0 + ((words[0] >> 29) & 7)],
            lo_m: f32::from_bits(words[1]),
            hi_m: f32::from_bits(words[2]),
        }
    }

    /// Row-major order of the first pixel, then the rest of the packed words.
    fn order_key(&self) -> (u32, u32, [u32; 3]) {
        (self.v[0], self.u[0], self.pack())
    }

    fn tile(&self) -> Tile {
        Tile {
            u: self.u.map(|c| c as usize),
            v: self.v.map(|c| c as usize),
        }
    }
}

/// A depth frame's band slices, in row-major order of their first pixels (ties by their
/// packed words), and its usable pixels.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct BandSlices {
    /// The slices.
    pub slices: Vec<BandSlice>,
    /// Usable depths in the frame.
    pub usable_pixels: usize,
}

impl BandSlices {
    /// `slices` (in any order) in the order [`BandSlices`] keeps.
    pub fn new(mut slices: Vec<BandSlice>, usable_pixels: usize) -> Self {
        slices.sort_unstable_by_key(BandSlice::order_key);
        BandSlices {
            slices,
            usable_pixels,
        }
    }
}

/// Keeps a tile's slices (the other [`BandSink`] is [`Listed`], which lists their blocks).
struct SliceList {
    slices: Vec<BandSlice>,
    depths: Vec<f32>,
}

impl BandSink for SliceList {
    fn depths(&mut self) -> &mut Vec<f32> {
        &mut self.depths
    }

    fn slice(&mut self, tile: Tile, _: &TileLister, lo: f64, hi: f64) {
        // `lo` and `hi` are depths of the frame, f32 widened: exact back.
        self.slices.push(BandSlice {
            u: tile.u.map(|c| c as u32),
            v: tile.v.map(|c| c as u32),
            lo_m: lo as f32,
            hi_m: hi as f32,
        });
    }
}

/// The slices whose blocks [`super::depth_frame_blocks`] lists for `frame` (the CPU twin of
/// `shaders/band_slices.wgsl`).
pub fn band_slices(
    grid: &GridParams,
    frame: &DepthFrame,
    params: &DepthFusionParams,
) -> BandSlices {
    let (w, h) = (frame.depth_m.width as usize, frame.depth_m.height as usize);
    let (k, pose) = (&frame.intrinsics, &frame.world_from_camera);
    let tiles = TileLister::new(grid, k, pose, params).over(&frame.depth_m.data, w);
    let rows: Vec<(Vec<BandSlice>, usize)> = (0..h.div_ceil(BAND_TILE_PX))
        .into_par_iter()
        .map(|ty| {
            let mut out = SliceList {
                slices: Vec::new(),
                depths: Vec::with_capacity(BAND_TILE_PX * BAND_TILE_PX),
            };
            let v0 = ty * BAND_TILE_PX;
            let v1 = (v0 + BAND_TILE_PX).min(h) - 1;
            let mut usable = 0;
            for u0 in (0..w).step_by(BAND_TILE_PX) {
                let tile = Tile {
                    u: [u0, (u0 + BAND_TILE_PX).min(w) - 1],
                    v: [v0, v1],
                };
                let range = tiles.range(tile);
                usable += range.count;
                tile_blocks(tile, range, &tiles, &mut out);
            }
            (out.slices, usable)
        })
        .collect();
    let usable = rows.iter().map(|r| r.1).sum();
    BandSlices::new(rows.into_iter().flat_map(|r| r.0).collect(), usable)
}

/// The blocks, sorted, that the band `slices` of a frame of `grid` taken with the camera `k`
/// from the pose `world_from_camera` reaches: for the frame's [`band_slices`] (or their GPU
/// twin's), exactly [`super::depth_frame_blocks`]. Reads no depth.
pub fn blocks_of_band_slices(
    grid: &GridParams,
    k: &PinholeIntrinsics,
    world_from_camera: &Isometry3<f64>,
    params: &DepthFusionParams,
    slices: &BandSlices,
) -> TouchedBlocks {
    let l = TileLister::new(grid, k, world_from_camera, params);
    // Neighbouring slices meet mostly the same blocks: in row-major order, a worker's cache
    // of listed blocks catches them, as it does for the tiles of one row.
    let keys = slices
        .slices
        .par_chunks(BAND_TILE_PX * 32)
        .fold(
            || Listed::new(true),
            |mut out, chunk| {
                for s in chunk {
                    l.slices
                        .tile_slice(s.tile(), &l, s.lo_m as f64, s.hi_m as f64, &mut out);
                }
                out
            },
        )
        .map(|listed| listed.keys)
        .reduce(Vec::new, |mut x, mut y| {
            x.append(&mut y);
            x
        });
    super::sorted_blocks(keys)
}
