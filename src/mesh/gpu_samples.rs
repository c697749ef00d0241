//! The GPU mesher's samples made where the blocks already are: when every block a batch reads
//! is resident in the GPU tier ([`ResidentMap`]), `shaders/mc_samples.wgsl` makes the batch's
//! samples from their pool slots, and only each place's slot (4 bytes) goes up, with the
//! regularized field's values (2 bytes per voxel) when that is the field meshed. The samples
//! are those the host packs from the layer, bit for bit (`tests/gpu/mesh.rs`), provided the
//! layer and the pool agree, as they do after [`ResidentMap::sync`].

use super::marching_cubes::Field;
use crate::gpu::kept::Kept;
use crate::gpu::layout::McSampleUniforms;
use crate::gpu::{shaders, GpuContext, ResidentMap};
use crate::grid::{BlockIndex, Layer, VOXELS_PER_BLOCK};
use crate::Result;

/// Where the GPU mesher reads the blocks' samples from.
#[derive(Clone, Copy, Debug, Default)]
pub enum SampleSource<'a> {
    /// Packed on the host from the layer (8 bytes per voxel up).
    #[default]
    Layer,
    /// Made on the device from the pool of a GPU tier over the layer, synced with it, for the
    /// batches whose blocks it all holds (the others packed from the layer).
    Resident(&'a ResidentMap),
}

impl<'a> SampleSource<'a> {
    /// The pool and each place's slot, when every place is resident there.
    pub(super) fn slots(&self, places: &[BlockIndex]) -> Option<(&'a wgpu::Buffer, Vec<u32>)> {
        let SampleSource::Resident(map) = *self else {
            return None;
        };
        let slots = places
            .iter()
            .map(|b| map.slot_of(*b))
            .collect::<Option<_>>()?;
        Some((map.pool_buffer(), slots))
    }
}

/// The samples of `places` (resident at `slots` of `pool`) made on the device: one dispatch,
/// recorded into `encoder` before the passes that read them, over buffers kept in `kept`.
pub(super) fn device_samples(
    ctx: &GpuContext,
    (kept, encoder): (&mut Kept, &mut wgpu::CommandEncoder),
    layer: &Layer,
    field: Field,
    places: &[BlockIndex],
    (pool, slots): (&wgpu::Buffer, &[u32]),
) -> Result<wgpu::Buffer> {
    let voxels = (places.len() * VOXELS_PER_BLOCK) as u64;
    ctx.check_binding("marching-cubes samples", voxels * 8)?;
    let kernel = ctx.kernel(&shaders::MC_SAMPLES)?;
    let uniforms = McSampleUniforms {
        places: places.len() as u32,
        regularized: (field == Field::Regularized) as u32,
        pad: [0; 2],
    };
    let values = match field {
        // The stored i16 of each voxel, packed straight into the kept staging memory.
        Field::Regularized => kept.storage_by_piece::<{ 2 * VOXELS_PER_BLOCK }>(
            ctx,
            "mc_values",
            places.len(),
            |k, dst| {
                let block = layer.get(&places[k]).expect("a place is allocated");
                let q = block.regularized.as_deref().unwrap_or(&block.tsdf);
                for (d, v) in dst.chunks_exact_mut(2).zip(q) {
                    d.copy_from_slice(&v.to_le_bytes());
                }
            },
        )?,
        Field::Raw => kept.scratch(ctx, "mc_values", 4),
    };
    let samples = kept.scratch(ctx, "mc_samples", voxels * 8);
    let buffers = [
        &kept.uniform_with(ctx, "mc_sample_uniforms", bytemuck::bytes_of(&uniforms)),
        &kept.storage_with(ctx, "mc_place_slot", bytemuck::cast_slice(slots)),
        pool,
        &values,
        &samples,
    ];
    // Not kept: the pool is the GPU tier's, which a grow replaces, and a kept bind group would
    // hold the old one until the next mesh.
    let bind = ctx.bind_group("mc_samples", &kernel.layout, &buffers);
    ctx.record_dispatch(encoder, &kernel, &bind, voxels)?;
    Ok(samples)
}
