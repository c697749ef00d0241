//! Index maths: world point ↔ global voxel ↔ (block, voxel within block).

use serde::{Deserialize, Serialize};

/// Voxels along each edge of a block (defined once; everything else derives from it).
pub const VOXELS_PER_SIDE: usize = 8;
/// Voxels in one block.
pub const VOXELS_PER_BLOCK: usize = VOXELS_PER_SIDE * VOXELS_PER_SIDE * VOXELS_PER_SIDE;

/// Integer coordinates of a block: block `b` covers global voxels `8·b .. 8·b + 7` on each axis.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Serialize, Deserialize)]
pub struct BlockIndex(pub [i32; 3]);

impl std::hash::Hash for BlockIndex {
    /// Packs the three coordinates into 63 bits (21 bits each, injective for |coordinate| < 2²⁰
    /// blocks, i.e. ±838 km at 10 cm voxels) and writes one `u64`; [`crate::grid::Layer`]'s hasher
    /// mixes it. The HVG paper's `x·p1 ⊕ y·p2 ⊕ z·p3` (Teschner et al. 2003) maps a 16³
    /// neighbourhood of blocks to only 2518 distinct values out of 4096, so it is not used.
    #[inline]
    fn hash<H: std::hash::Hasher>(&self, state: &mut H) {
        state.write_u64(self.pack());
    }
}

/// Integer coordinates of a voxel in the unbounded global grid: voxel `v` covers
/// `[v·s, (v+1)·s)` on each axis for voxel size `s`, and its centre is `(v + ½)·s`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
pub struct VoxelIndex(pub [i64; 3]);

impl BlockIndex {
    /// The coordinates packed into 63 bits (21 bits each, two's complement), injective for
    /// |coordinate| < 2²⁰; see [`BlockIndex::unpack`].
    #[inline]
    pub fn pack(&self) -> u64 {
        const MASK: u64 = (1 << 21) - 1;
        let [x, y, z] = self.0;
        (x as u64 & MASK) | ((y as u64 & MASK) << 21) | ((z as u64 & MASK) << 42)
    }

    /// Inverse of [`BlockIndex::pack`].
    #[inline]
    pub fn unpack(key: u64) -> BlockIndex {
        let field = |shift: u32| (((key >> shift) << 43) as i64 >> 43) as i32;
        BlockIndex([field(0), field(21), field(42)])
    }

    /// The coordinates packed into 63 bits in the order of `BlockIndex`'s `Ord` (x, then y,
    /// then z; 21 bits each, offset binary): sorting these keys sorts the blocks, with one
    /// integer comparison instead of three. Injective for |coordinate| < 2²⁰; see
    /// [`BlockIndex::from_sort_key`].
    #[inline]
    pub fn sort_key(&self) -> u64 {
        const MASK: u64 = (1 << 21) - 1;
        let field = |c: i32| (c as u64).wrapping_add(1 << 20) & MASK;
        let [x, y, z] = self.0;
        (field(x) << 42) | (field(y) << 21) | field(z)
    }

    /// Inverse of [`BlockIndex::sort_key`].
    #[inline]
    pub fn from_sort_key(key: u64) -> BlockIndex {
        const MASK: u64 = (1 << 21) - 1;
        let field = |shift: u32| ((key >> shift) & MASK) as i32 - (1 << 20);
        BlockIndex([field(42), field(21), field(0)])
    }

    /// The block holding global voxel `v`, and the voxel's linear index inside that block.
    #[inline]
    pub fn of_voxel(v: VoxelIndex) -> (BlockIndex, usize) {
        let s = VOXELS_PER_SIDE as i64;
        let b = [
            v.0[0].div_euclid(s),
            v.0[1].div_euclid(s),
            v.0[2].div_euclid(s),
        ];
        let l = [
            v.0[0].rem_euclid(s),
            v.0[1].rem_euclid(s),
            v.0[2].rem_euclid(s),
        ];
        (
            BlockIndex([b[0] as i32, b[1] as i32, b[2] as i32]),
            linear_index(l[0] as usize, l[1] as usize, l[2] as usize),
        )
    }

    /// Global index of the voxel at local coordinates (x, y, z) of this block.
    #[inline]
    pub fn voxel(&self, x: usize, y: usize, z: usize) -> VoxelIndex {
        let s = VOXELS_PER_SIDE as i64;
        VoxelIndex([
            self.0[0] as i64 * s + x as i64,
            self.0[1] as i64 * s + y as i64,
            self.0[2] as i64 * s + z as i64,
        ])
    }

    /// The neighbouring block offset by `d` blocks.
    #[inline]
    pub fn offset(&self, d: [i32; 3]) -> BlockIndex {
        BlockIndex([self.0[0] + d[0], self.0[1] + d[1], self.0[2] + d[2]])
    }
}

/// `⌊x⌋` as an integer, inline (baseline x86-64 has no SSE4.1 `roundsd`, so `f64::floor` becomes a
/// library call). Exact for |x| < 2⁶³.
#[inline(always)]
pub fn floor_i64(x: f64) -> i64 {
    let i = x as i64;
    i - ((i as f64 > x) as i64)
}

/// Nearest integer to `x` (halves round up), inline.
#[inline(always)]
pub fn round_i64(x: f64) -> i64 {
    floor_i64(x + 0.5)
}

/// Linear index of local voxel (x, y, z) in a block: x fastest, then y, then z.
#[inline]
pub const fn linear_index(x: usize, y: usize, z: usize) -> usize {
    x + VOXELS_PER_SIDE * (y + VOXELS_PER_SIDE * z)
}

/// Local (x, y, z) of a linear voxel index in a block.
#[inline]
pub const fn local_coords(i: usize) -> [usize; 3] {
    [
        i % VOXELS_PER_SIDE,
        (i / VOXELS_PER_SIDE) % VOXELS_PER_SIDE,
        i / (VOXELS_PER_SIDE * VOXELS_PER_SIDE),
    ]
}

/// Geometry of a grid: voxel size and TSDF truncation.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct GridParams {
    /// Edge length of a voxel, metres (paper: 0.10 or 0.20).
    pub voxel_size_m: f32,
    /// Truncation distance μ, metres (paper: 1.0 at 10 cm voxels, 1.6 at 20 cm).
    pub truncation_m: f32,
}

impl GridParams {
    /// The paper's pairing of voxel size and truncation: 10 cm → μ = 1.0 m, 20 cm → μ = 1.6 m,
    /// otherwise μ = 10 voxels.
    pub fn paper(voxel_size_m: f32) -> Self {
        let truncation_m = if (voxel_size_m - 0.2).abs() < 1e-6 {
            1.6
        } else {
            10.0 * voxel_size_m
        };
        GridParams {
            voxel_size_m,
            truncation_m,
        }
    }

    /// Edge length of a block, metres.
    #[inline]
    pub fn block_size_m(&self) -> f64 {
        self.voxel_size_m as f64 * VOXELS_PER_SIDE as f64
    }

    /// The voxel containing world point `p` (metres).
    #[inline]
    pub fn voxel_of_point(&self, p: [f64; 3]) -> VoxelIndex {
        let s = self.voxel_size_m as f64;
        VoxelIndex([
            (p[0] / s).floor() as i64,
            (p[1] / s).floor() as i64,
            (p[2] / s).floor() as i64,
        ])
    }

    /// The block containing world point `p` (metres).
    #[inline]
    pub fn block_of_point(&self, p: [f64; 3]) -> BlockIndex {
        let s = self.block_size_m();
        BlockIndex([
            (p[0] / s).floor() as i32,
            (p[1] / s).floor() as i32,
            (p[2] / s).floor() as i32,
        ])
    }

    /// World position of the centre of voxel `v`, metres.
    #[inline]
    pub fn voxel_center(&self, v: VoxelIndex) -> [f64; 3] {
        let s = self.voxel_size_m as f64;
        [
            (v.0[0] as f64 + 0.5) * s,
            (v.0[1] as f64 + 0.5) * s,
            (v.0[2] as f64 + 0.5) * s,
        ]
    }

    /// World position of the minimum corner of block `b`, metres.
    #[inline]
    pub fn block_origin(&self, b: BlockIndex) -> [f64; 3] {
        let s = self.block_size_m();
        [b.0[0] as f64 * s, b.0[1] as f64 * s, b.0[2] as f64 * s]
    }

    /// Checks that the parameters are usable.
    pub fn validate(&self) -> crate::Result<()> {
        if !(self.voxel_size_m.is_finite() && self.voxel_size_m > 0.0) {
            return Err(crate::Error::InvalidArgument(format!(
                "voxel size must be positive, got {} m",
                self.voxel_size_m
            )));
        }
        if !(self.truncation_m.is_finite() && self.truncation_m >= self.voxel_size_m) {
            return Err(crate::Error::InvalidArgument(format!(
                "truncation must be at least one voxel ({} m), got {} m",
                self.voxel_size_m, self.truncation_m
            )));
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    proptest! {
        #[test]
        fn voxel_block_round_trip(x in -100_000i64..100_000, y in -100_000i64..100_000, z in -100_000i64..100_000) {
            let v = VoxelIndex([x, y, z]);
            let (b, i) = BlockIndex::of_voxel(v);
            let [lx, ly, lz] = local_coords(i);
            prop_assert_eq!(b.voxel(lx, ly, lz), v);
            prop_assert_eq!(linear_index(lx, ly, lz), i);
        }

        #[test]
        fn point_lies_in_its_voxel(x in -1000.0f64..1000.0, y in -1000.0f64..1000.0, z in -1000.0f64..1000.0) {
            let g = GridParams { voxel_size_m: 0.1, truncation_m: 1.0 };
            let v = g.voxel_of_point([x, y, z]);
            let c = g.voxel_center(v);
            for a in 0..3 {
                prop_assert!((c[a] - [x, y, z][a]).abs() <= 0.05 + 1e-9);
            }
            let (b, _) = BlockIndex::of_voxel(v);
            prop_assert_eq!(b, g.block_of_point(c));
        }
    }

    proptest! {
        #[test]
        fn fast_floor_matches_std(x in -1e12f64..1e12) {
            prop_assert_eq!(floor_i64(x), x.floor() as i64);
            prop_assert_eq!(floor_i64(x.floor()), x.floor() as i64);
        }
    }

    proptest! {
        #[test]
        fn pack_round_trips(x in -(1i32 << 20)..(1 << 20), y in -(1i32 << 20)..(1 << 20), z in -(1i32 << 20)..(1 << 20)) {
            let b = BlockIndex([x, y, z]);
            prop_assert_eq!(BlockIndex::unpack(b.pack()), b);
        }
    }

    proptest! {
        #[test]
        fn sort_key_round_trips_and_orders(
            a in proptest::array::uniform3(-(1i32 << 20)..(1 << 20)),
            b in proptest::array::uniform3(-(1i32 << 20)..(1 << 20)),
            same_x in proptest::bool::ANY,
        ) {
            // Equal leading coordinates half the time, so y and z decide the order too.
            let b = if same_x { [a[0], b[1], b[2]] } else { b };
            let (a, b) = (BlockIndex(a), BlockIndex(b));
            prop_assert_eq!(BlockIndex::from_sort_key(a.sort_key()), a);
            prop_assert_eq!(a.sort_key().cmp(&b.sort_key()), a.cmp(&b));
        }
    }

    #[test]
    fn negative_coordinates_floor() {
        let (b, i) = BlockIndex::of_voxel(VoxelIndex([-1, -8, -9]));
        assert_eq!(b, BlockIndex([-1, -1, -2]));
        assert_eq!(local_coords(i), [7, 0, 7]);
    }
}
