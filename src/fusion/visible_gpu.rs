//! The resident blocks in view, found on the device (`shaders/table_visible.wgsl`): every live
//! entry of the GPU hash table is tested as [`ViewFrustum::meets_block`] tests a block, in f32
//! relative to the camera's block, with a margin wider than the f32 arithmetic's error. The
//! kernel decides every block that clears or misses the frustum by the margin and lists the few
//! in between apart; the host decides those in f64 ([`ResidentInView::blocks`]), so the set is
//! exactly the host's. It is the piece of a frame's listing that the host no longer needs to
//! walk its layer for; the frame path does not use it yet.
//!
//! **The margin.** A block's least clearance past the planes is a few dot products of
//! quantities bounded by `m = |w|₁ + far + r` (w: the block's centre minus the camera's
//! position, far: the far plane, r: the block's bounding radius), each term rounded a few times
//! in f32 (unit roundoff 2⁻²⁴ ≈ 6·10⁻⁸), the inputs rounded once from f64. Twenty roundings of
//! `m` bound it by about 1.2·10⁻⁶·m; the kernel's margin is 10⁻⁵·m, eight times that.

use super::depth::ViewFrustum;
use crate::gpu::resident::{BlockTable, SLOT_TOMBSTONE};
use crate::gpu::shaders;
use crate::gpu::{ErrorScopes, GpuContext};
use crate::grid::{BlockIndex, GridParams};
use crate::Result;

/// The kernel's margin per metre of the magnitudes involved (see the module documentation).
pub const MARGIN_PER_M: f32 = 1e-5;

/// The words of `table_visible.wgsl`'s `params` for `frustum` over a table of `entries`
/// entries.
pub fn visible_words(frustum: &ViewFrustum, grid: &GridParams, entries: u32) -> [u32; 32] {
    let s = grid.block_size_m();
    let camera = frustum.camera_from_world.inverse().translation.vector;
    let camera_block = grid.block_of_point([camera.x, camera.y, camera.z]);
    let corner = grid.block_origin(camera_block);
    let r = 0.5 * s * 3f64.sqrt();
    let rotation = frustum.camera_from_world.rotation.to_rotation_matrix();
    let mut w = [0u32; 32];
    for k in 0..3 {
        w[k] = camera_block.0[k] as u32;
        w[4 + k] = ((corner[k] + 0.5 * s - camera[k]) as f32).to_bits();
        for j in 0..3 {
            w[7 + 3 * k + j] = (rotation[(k, j)] as f32).to_bits();
        }
    }
    w[3] = entries;
    w[16] = (s as f32).to_bits();
    w[17] = (r as f32).to_bits();
    w[18] = (frustum.far_m as f32).to_bits();
    w[19] = MARGIN_PER_M.to_bits();
    for (k, n) in frustum.sides.iter().enumerate() {
        for j in 0..3 {
            w[20 + 3 * k + j] = (n[j] as f32).to_bits();
        }
    }
    w
}

/// What `table_visible.wgsl` found: table entries (positions), each list in no defined order.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct ResidentInView {
    /// Entries whose blocks are in view.
    pub in_view: Vec<u32>,
    /// Entries whose blocks lie within the margin of a plane: the host decides them.
    pub undecided: Vec<u32>,
}

impl ResidentInView {
    /// The blocks in view, sorted: those the kernel found and those of the undecided entries
    /// that [`ViewFrustum::meets_block`] passes; `table` is the table the kernel read.
    pub fn blocks(
        &self,
        table: &BlockTable,
        frustum: &ViewFrustum,
        grid: &GridParams,
    ) -> Vec<BlockIndex> {
        let key = |&pos: &u32| {
            let e = table.entries()[pos as usize];
            debug_assert!(e[3] < SLOT_TOMBSTONE, "entry {pos} is not live");
            BlockIndex([e[0] as i32, e[1] as i32, e[2] as i32])
        };
        let decided = (self.undecided.iter().map(key)).filter(|b| frustum.meets_block(grid, *b));
        let mut v: Vec<BlockIndex> = self.in_view.iter().map(key).chain(decided).collect();
        v.sort_unstable();
        v
    }
}

/// Runs `table_visible.wgsl` over a copy of `table` uploaded whole, with the margin
/// `margin_per_m` ([`MARGIN_PER_M`], or wider to send more blocks to the host). For tests of
/// the kernel against [`ViewFrustum::meets_block`].
pub fn resident_in_view_on_gpu(
    ctx: &GpuContext,
    table: &BlockTable,
    (frustum, grid): (&ViewFrustum, &GridParams),
    margin_per_m: f32,
) -> Result<ResidentInView> {
    let entries = table.capacity() as u64;
    let kernel = ctx.kernel(&shaders::TABLE_VISIBLE)?;
    let scope = ErrorScopes::push(&ctx.device);
    let mut words = visible_words(frustum, grid, entries as u32);
    words[19] = margin_per_m.to_bits();
    let buf_params = ctx.storage("visible_params", bytemuck::cast_slice(&words));
    let buf_table = ctx.storage("block_table", bytemuck::cast_slice(table.entries()));
    let buf_counts = ctx.storage_zeroed("visible_counts", 8);
    let buf_in_view = ctx.storage_zeroed("visible_in_view", entries * 4);
    let buf_undecided = ctx.storage_zeroed("visible_undecided", entries * 4);
    let bind = ctx.bind_group(
        "table_visible",
        &kernel.layout,
        &[
            &buf_params,
            &buf_table,
            &buf_counts,
            &buf_in_view,
            &buf_undecided,
        ],
    );
    let mut encoder = ctx.encoder("table_visible");
    ctx.record_dispatch(&mut encoder, &kernel, &bind, entries)?;
    ctx.submit(encoder);
    scope.pop("finding the resident blocks in view on the GPU")?;
    let counts: Vec<u32> = ctx.read_back_as(&buf_counts, 2)?;
    let list = |buffer: &wgpu::Buffer, count: u32| -> Result<Vec<u32>> {
        match count {
            0 => Ok(Vec::new()),
            n => ctx.read_back_as(buffer, n as usize),
        }
    };
    let mut in_view = list(&buf_in_view, counts[0])?;
    let mut undecided = list(&buf_undecided, counts[1])?;
    in_view.sort_unstable();
    undecided.sort_unstable();
    Ok(ResidentInView { in_view, undecided })
}
