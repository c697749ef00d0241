//! Ω-aware TV over the blocks resident on the GPU ([`ResidentMap`]): the problem is made where
//! the blocks are, iterated there, and only the stored result comes back.
//!
//! One submit, one wait:
//! 1. `shaders/tv_resident_slots.wgsl` places the hash table's live entries at their slots and
//!    `tv_resident_list.wgsl` numbers the occupied slots in order as the problem's blocks (any
//!    numbering gives the same voxels, since each voxel's arithmetic reads only its own and
//!    its neighbours' values; slot order keeps the blocks of one frame near each other);
//! 2. `tv_resident_links.wgsl` builds the neighbour table through the hash table;
//! 3. `tv_resident_gather.wgsl` reads f, w and the Ω and link bits from the pool's voxels, the
//!    CPU's `TvProblem::gather` bit for bit (f decoded by exact division);
//! 4. `u` and `ū` start as copies of `f` and `p` as zeros, on the device;
//! 5. the iterations: the same `tv_dual.wgsl` and `tv_primal.wgsl` as [`super::solve_gpu`];
//! 6. `tv_resident_encode.wgsl` stores the result as the blocks keep it, `encode_tsdf(u)` in Ω
//!    and the raw value elsewhere ([`TvProblem::scatter`]), 2 bytes per voxel, and that comes
//!    back with the blocks' keys (16 bytes per block) and two counters.
//!
//! Uploaded: the layer's blocks that are not resident (made resident first), and 48 bytes of
//! uniforms. The problem's arrays (32 bytes per voxel on the device) are made for the solve and
//! freed after it. The energies are not computed (that would gather the problem on the
//! host, which is what this avoids); the agreement with the CPU is that of [`super::solve_gpu`]
//! (`tests/gpu/compare.rs`).
//!
//! [`TvProblem::scatter`]: super::TvProblem::scatter

use super::gpu::{record_iterations, TvBuffers};
use super::{RegularizeStats, TvParams};
use crate::gpu::kept::Kept;
use crate::gpu::layout::{TvResidentUniforms, TvUniforms};
use crate::gpu::resident::FrameParts;
use crate::gpu::{shaders, ErrorScopes, ResidentMap};
use crate::grid::{BlockIndex, Layer, TouchedBlocks, VOXELS_PER_BLOCK};
use crate::{Error, Result};

/// Regularizes every block of `layer` on the GPU where `map` holds them: the layer's blocks are
/// made resident (those not yet on the device uploaded), the problem made and solved there, and
/// `u` stored in each block's `regularized` field, as [`super::regularize_layer`] does.
///
/// `Ok(None)`, with nothing done, when the layer's blocks do not fit the pool or one binding of
/// the problem's arrays, or the pool holds blocks the layer does not: the caller then gathers
/// the problem on the host. On error the layer's `regularized` fields are as before.
pub fn regularize_resident(
    map: &mut ResidentMap,
    layer: &mut Layer,
    params: &TvParams,
) -> Result<Option<(TouchedBlocks, RegularizeStats)>> {
    params.validate()?;
    if layer.params() != map.grid() {
        return Err(Error::InvalidArgument(
            "resident GPU map and layer have different grids".into(),
        ));
    }
    let blocks = layer.indices_sorted();
    let n = blocks.len() as u64;
    let voxels = n * VOXELS_PER_BLOCK as u64;
    let fits = n > 0
        && n <= map.max_blocks() as u64
        && voxels * 12 <= map.context().max_binding_bytes()
        && voxels <= u32::MAX as u64;
    // A clean pool: a later write-back stores raw values (and the regularized ones following
    // them, `Block::store_fused`) only where a later frame updates a voxel. Syncing also
    // collects the depth frames in flight, so the layer knows every resident block.
    map.sync(layer)?;
    if !fits || !map.resident_blocks().iter().all(|b| layer.contains(b)) {
        return Ok(None);
    }
    // The table's changes (blocks brought back up, slots released by the sync) go up with
    // the solve's submit.
    let mut encoder = map.context().encoder("tv_resident");
    map.make_resident(layer, &blocks, [0.0; 3], Some(&mut encoder))?;
    let (listed, stored, omega_voxels) = solve_on_device(map, n as u32, params, encoder)?;
    for (entry, values) in listed.iter().zip(stored.chunks_exact(VOXELS_PER_BLOCK)) {
        let key = BlockIndex([entry[0] as i32, entry[1] as i32, entry[2] as i32]);
        let block = layer
            .get_mut(&key)
            .ok_or_else(|| Error::Gpu(format!("the GPU solved block {key:?}, not in the map")))?;
        let mut out = Box::new([0i16; VOXELS_PER_BLOCK]);
        out.copy_from_slice(values);
        block.regularized = Some(out);
    }
    let stats = RegularizeStats {
        blocks: blocks.len(),
        omega_voxels,
        iterations: params.iterations,
        energy: None,
    };
    Ok(Some((blocks, stats)))
}

/// Records the solve over the map's `n` resident blocks into `encoder` (after what it holds)
/// and runs it (see the module documentation). Returns each block's table entry (key, slot),
/// the stored values (512 per block, in the same order) and the number of Ω voxels.
fn solve_on_device(
    map: &mut ResidentMap,
    n: u32,
    params: &TvParams,
    mut encoder: wgpu::CommandEncoder,
) -> Result<(Vec<[u32; 4]>, Vec<i16>, usize)> {
    let capacity = map.stats().capacity_blocks as u64;
    let FrameParts {
        ctx,
        pool,
        table: (table, table_mask),
        ..
    } = map.frame_parts();
    // The problem's buffers live for this solve only: a run solves once, at its end, and the
    // device memory (32 bytes per voxel) goes back to the pool and the meshes after it.
    let kept = &mut Kept::default();
    let voxels = n as u64 * VOXELS_PER_BLOCK as u64;
    let slots = ctx.kernel(&shaders::TV_RESIDENT_SLOTS)?;
    let list = ctx.kernel(&shaders::TV_RESIDENT_LIST)?;
    let links = ctx.kernel(&shaders::TV_RESIDENT_LINKS)?;
    let gather = ctx.kernel(&shaders::TV_RESIDENT_GATHER)?;
    let encode = ctx.kernel(&shaders::TV_RESIDENT_ENCODE)?;
    let dual = ctx.kernel(&shaders::TV_DUAL)?;
    let primal = ctx.kernel(&shaders::TV_PRIMAL)?;
    let resident_uniforms = TvResidentUniforms {
        table_mask,
        block_count: n,
        voxel_count: voxels as u32,
        slot_count: capacity as u32,
    };
    let tv_uniforms = TvUniforms {
        sigma: params.sigma,
        tau: params.tau,
        lambda: params.lambda,
        theta: params.theta,
        voxel_count: voxels as u32,
        pad: [0; 3],
    };
    let scope = ErrorScopes::push(&ctx.device);
    let buf_resident = kept.uniform_with(
        ctx,
        "tv_resident_uniforms",
        bytemuck::bytes_of(&resident_uniforms),
    );
    let buf_tv = kept.uniform_with(ctx, "tv_uniforms", bytemuck::bytes_of(&tv_uniforms));
    let buf_slot_entry = kept.scratch(ctx, "tv_slot_entry", capacity * 16);
    let buf_listed = kept.scratch(ctx, "tv_listed", n as u64 * 16);
    let buf_block_of_slot = kept.scratch(ctx, "tv_block_of_slot", capacity * 4);
    let buf_counters = kept.scratch(ctx, "tv_counters", 8);
    let buf_neighbors = kept.scratch(ctx, "tv_neighbors", n as u64 * 24);
    let [buf_f, buf_w, buf_mask, buf_u, buf_ubar] = ["tv_f", "tv_w", "tv_mask", "tv_u", "tv_ubar"]
        .map(|name| kept.scratch(ctx, name, voxels * 4));
    let buf_p = kept.scratch(ctx, "tv_p", voxels * 12);
    let buf_stored = kept.scratch(ctx, "tv_stored", voxels * 2);
    let bind_slots = kept.bind_group(
        ctx,
        "tv_resident_slots",
        &slots.layout,
        &[&buf_resident, table, &buf_slot_entry],
    );
    let bind_list = kept.bind_group(
        ctx,
        "tv_resident_list",
        &list.layout,
        &[
            &buf_resident,
            &buf_slot_entry,
            &buf_listed,
            &buf_block_of_slot,
            &buf_counters,
        ],
    );
    let bind_links = kept.bind_group(
        ctx,
        "tv_resident_links",
        &links.layout,
        &[
            &buf_resident,
            table,
            &buf_listed,
            &buf_block_of_slot,
            &buf_neighbors,
        ],
    );
    let bind_gather = kept.bind_group(
        ctx,
        "tv_resident_gather",
        &gather.layout,
        &[
            &buf_resident,
            &buf_listed,
            &buf_neighbors,
            pool,
            &buf_f,
            &buf_w,
            &buf_mask,
            &buf_counters,
        ],
    );
    let tv_buffers = TvBuffers {
        uniforms: &buf_tv,
        neighbors: &buf_neighbors,
        mask: &buf_mask,
        f: &buf_f,
        w: &buf_w,
        u: &buf_u,
        ubar: &buf_ubar,
        p: &buf_p,
    }
    .bindings();
    let bind_dual = kept.bind_group(ctx, "tv_resident_dual", &dual.layout, &tv_buffers);
    let bind_primal = kept.bind_group(ctx, "tv_resident_primal", &primal.layout, &tv_buffers);
    let bind_encode = kept.bind_group(
        ctx,
        "tv_resident_encode",
        &encode.layout,
        &[
            &buf_resident,
            &buf_listed,
            pool,
            &buf_mask,
            &buf_u,
            &buf_stored,
        ],
    );
    encoder.clear_buffer(&buf_counters, 0, Some(8));
    encoder.clear_buffer(&buf_slot_entry, 0, Some(capacity * 16));
    ctx.record_dispatch(&mut encoder, &slots, &bind_slots, table_mask as u64 + 1)?;
    // One workgroup: each invocation numbers a run of slots.
    ctx.record_dispatch(&mut encoder, &list, &bind_list, 64)?;
    ctx.record_dispatch(&mut encoder, &links, &bind_links, n as u64)?;
    ctx.record_dispatch(&mut encoder, &gather, &bind_gather, voxels)?;
    // u = ū = f and p = 0, made where they are used.
    encoder.copy_buffer_to_buffer(&buf_f, 0, &buf_u, 0, voxels * 4);
    encoder.copy_buffer_to_buffer(&buf_f, 0, &buf_ubar, 0, voxels * 4);
    encoder.clear_buffer(&buf_p, 0, Some(voxels * 12));
    let steps = [(&*dual, &bind_dual), (&*primal, &bind_primal)];
    record_iterations(ctx, &mut encoder, steps, voxels, params.iterations)?;
    ctx.record_dispatch(&mut encoder, &encode, &bind_encode, voxels / 2)?;
    let mut counters = [0u32; 2];
    let mut listed: Vec<[u32; 4]> = vec![[0; 4]; n as usize];
    let mut stored: Vec<i16> = vec![0; voxels as usize];
    ctx.submit_and_read_back(
        encoder,
        kept,
        &mut [
            (&buf_counters, bytemuck::cast_slice_mut(&mut counters)),
            (&buf_listed, bytemuck::cast_slice_mut(&mut listed)),
            (&buf_stored, bytemuck::cast_slice_mut(&mut stored)),
        ],
    )?;
    scope.pop("running TV over the resident blocks")?;
    if counters[0] != n {
        return Err(Error::Gpu(format!(
            "the GPU hash table lists {} resident blocks, the host {n}",
            counters[0]
        )));
    }
    Ok((listed, stored, counters[1] as usize))
}
