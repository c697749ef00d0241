//! Marching cubes on the GPU: the twin of the CPU mesher (`marching_cubes.rs`), giving the same
//! triangles over the same vertices in the same order, the vertices' positions and colours
//! within [`POSITION_TOLERANCE_VOXELS`] and one colour step.
//!
//! The layer's samples go up once per batch of blocks: each meshed block and the +x/+y/+z
//! neighbours it reads corners from, 8 bytes per voxel (the field's value; colour and the
//! valid bit, Ω with weight > 0), with each block's voxel centres as f32 (96 bytes). Then five
//! passes (`shaders/mc_*.wgsl`):
//!
//! 1. `mc_count`: the triangles of each block (read back: 4 bytes per block, to size the rest);
//! 2. `mc_emit`: every triangle corner in the CPU mesher's order (block, cube, triangle,
//!    corner), its vertex computed as the CPU computes it, and its edge's entry in a hash table
//!    (insert by compare-and-swap on 32-bit words) where the smallest corner number naming the
//!    edge is kept;
//! 3. `mc_first`: per block, the corners that are their edge's first (these create vertices);
//! 4. `mc_scan`, `mc_assign`: the blocks' first vertex numbers, then each vertex written by its
//!    first corner, so vertices are numbered in order of first use, the CPU's order;
//! 5. `mc_link`: each corner's vertex number.
//!
//! A [`GpuMesher`] keeps its buffers and bind groups from mesh to mesh (`src/gpu/kept.rs`), so
//! a mesh of no more blocks and triangles than an earlier one creates none (but the bind group
//! over a GPU tier's pool, which a grow replaces). A batch costs a submit and a wait for its
//! count (the samples made from the pool in the same submit), and each of its parts two more:
//! the mesh, then its vertices. [`extract_mesh_gpu`] is one mesh with a mesher of its own.
//!
//! Nothing depends on the order the invocations run in, so the result is deterministic. Where a
//! layer does not fit one storage binding, it goes in batches of blocks (and a batch's
//! triangles in parts); the parts' vertices are merged on the host in order (`gpu_merge.rs`),
//! as the CPU merges its blocks', looking up only the vertices two blocks can share (those on
//! an edge whose lower corner lies on a block's low face).

use super::gpu_merge::Merge;
use super::gpu_samples::{device_samples, SampleSource};
use super::marching_cubes::{EdgeKey, Field};
use super::tables::triangle_table;
use super::Mesh;
use crate::gpu::kept::Kept;
use crate::gpu::layout::{pack_rgb, McUniforms};
use crate::gpu::{shaders, ErrorScopes, GpuContext, Kernel};
use crate::grid::{decode_tsdf, BlockIndex, Layer, VOXELS_PER_BLOCK, VOXELS_PER_SIDE};
use crate::Result;
use rayon::prelude::*;
use std::collections::HashMap;
use std::ops::Range;
use std::sync::{Arc, Mutex};

/// How far a GPU vertex may lie from the CPU's, in voxels, on top of one unit in the last place
/// of the coordinate: the edge parameter `fa / (fa − fb)` is a division, which WGSL allows to
/// be 2.5 units in the last place off, and a device may fuse the multiply-add that places the
/// vertex. On lavapipe the two agree exactly (`tests/gpu/mesh.rs`).
pub const POSITION_TOLERANCE_VOXELS: f32 = 1e-5;

/// Bytes uploaded per block: 8 per voxel (value; colour and valid bit).
const SAMPLE_BYTES: u64 = 8 * VOXELS_PER_BLOCK as u64;
/// Bytes per triangle corner on the device (position, colour, hash entry).
const CORNER_BYTES: u64 = 20;
/// Bytes per hash-table entry (key, first corner, vertex number).
const ENTRY_BYTES: u64 = 12;
/// Bit of a sample's second word saying the voxel is in Ω with weight > 0.
const VALID_BIT: u32 = 1 << 24;
/// "No block" in the neighbour table.
const NO_BLOCK: u32 = u32::MAX;

/// [`super::extract_mesh_keyed`] on the GPU: the same mesh (see the module documentation for
/// what "same" means) and the same edge keys.
pub fn extract_mesh_gpu(
    ctx: &GpuContext,
    layer: &Layer,
    field: Field,
    blocks: Option<&[BlockIndex]>,
) -> Result<(Mesh, Vec<EdgeKey>)> {
    extract_mesh_gpu_from(ctx, layer, field, blocks, SampleSource::Layer)
}

/// [`extract_mesh_gpu`] with the samples taken from `source`: where the blocks are resident on
/// the GPU, made there from the pool (`gpu_samples.rs`) instead of packed and uploaded. The
/// same mesh either way.
pub fn extract_mesh_gpu_from(
    ctx: &GpuContext,
    layer: &Layer,
    field: Field,
    blocks: Option<&[BlockIndex]>,
    source: SampleSource,
) -> Result<(Mesh, Vec<EdgeKey>)> {
    mesh_with(ctx, &mut Scratch::default(), (layer, source), field, blocks)
}

/// The GPU mesher ([`extract_mesh_gpu_from`]) with the buffers and bind groups it keeps from
/// mesh to mesh: after the first, a mesh of no more blocks and triangles creates none, and the
/// triangle table stays on the device. Clones share what is kept; meshes made at once (an
/// export's chunks, on every core) each take a set of their own, so as many sets are kept as
/// meshes ran at once, each as large as the largest mesh it made.
#[derive(Clone)]
pub struct GpuMesher {
    ctx: Arc<GpuContext>,
    sets: Arc<Mutex<Vec<Scratch>>>,
}

impl std::fmt::Debug for GpuMesher {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("GpuMesher")
            .field("device", &self.ctx.name())
            .finish()
    }
}

impl GpuMesher {
    /// A mesher on `ctx`, keeping nothing yet.
    pub fn new(ctx: Arc<GpuContext>) -> Self {
        GpuMesher {
            ctx,
            sets: Default::default(),
        }
    }

    /// The GPU it meshes on.
    pub fn context(&self) -> &Arc<GpuContext> {
        &self.ctx
    }

    /// [`extract_mesh_gpu_from`] over the kept buffers (a set of its own where other meshes are
    /// being made at once). After an error the set it used is dropped.
    pub fn mesh(
        &self,
        layer: &Layer,
        field: Field,
        blocks: Option<&[BlockIndex]>,
        source: SampleSource,
    ) -> Result<(Mesh, Vec<EdgeKey>)> {
        let sets = || self.sets.lock().unwrap_or_else(|e| e.into_inner());
        let mut set = sets().pop().unwrap_or_default();
        let mesh = mesh_with(&self.ctx, &mut set, (layer, source), field, blocks)?;
        sets().push(set);
        Ok(mesh)
    }

    /// Gives back every kept buffer (the device memory they hold).
    pub fn release(&self) {
        self.sets.lock().unwrap_or_else(|e| e.into_inner()).clear();
    }
}

/// What a [`GpuMesher`] keeps for one mesh at a time: the buffers and bind groups of its
/// batches and parts, and the triangle table on the device.
#[derive(Default)]
struct Scratch {
    kept: Kept,
    table: Option<wgpu::Buffer>,
}

fn mesh_with(
    ctx: &GpuContext,
    scratch: &mut Scratch,
    (layer, source): (&Layer, SampleSource),
    field: Field,
    blocks: Option<&[BlockIndex]>,
) -> Result<(Mesh, Vec<EdgeKey>)> {
    let mut list: Vec<BlockIndex> = match blocks {
        Some(b) => {
            let mut v = b.to_vec();
            v.sort_unstable();
            v.dedup();
            v
        }
        None => layer.indices_sorted(),
    };
    // A block that is not allocated has no valid corner 0 in any cube: no triangles.
    list.retain(|b| layer.get(b).is_some());
    let mut phases = Phases::default();
    let (words, stride) = table_words();
    let table = (scratch.table)
        .get_or_insert_with(|| ctx.storage("mc_table", bytemuck::cast_slice(&words)))
        .clone();
    let kept = &mut scratch.kept;
    let mut merge = Merge::default();
    let cap = ctx.max_binding_bytes();
    let mut start = 0;
    while start < list.len() {
        let upload = timed(&mut phases.plan_s, || plan_batch(layer, &list, start, cap));
        let end = start + upload.meshed;
        merge.more_to_come |= end < list.len();
        // The samples made on the device go in the count's submit.
        let mut encoder = ctx.encoder("mc_count");
        let batch = timed(&mut phases.upload_s, || {
            let to = (&mut *kept, &mut encoder);
            Batch::upload(ctx, to, (layer, source), field, &upload, (&table, stride))
        })?;
        let counts = timed(&mut phases.count_s, || batch.count(ctx, kept, encoder))?;
        let parts = plan_parts(&counts, cap);
        merge.more_to_come |= parts.len() > 1;
        for part in parts {
            let (vertices, triangles) = timed(&mut phases.mesh_s, || {
                batch.mesh_part(ctx, kept, part, &counts)
            })?;
            timed(&mut phases.merge_s, || {
                merge.add(&upload.places, &vertices, &triangles)
            });
        }
        start = end;
    }
    tracing::debug!(
        "marching cubes on the GPU, {} blocks: plan {:.1} ms, pack and upload {:.1} ms, count {:.1} ms, mesh {:.1} ms, merge {:.1} ms",
        list.len(),
        1e3 * phases.plan_s,
        1e3 * phases.upload_s,
        1e3 * phases.count_s,
        1e3 * phases.mesh_s,
        1e3 * phases.merge_s
    );
    Ok((merge.mesh, merge.keys))
}

/// Host time per phase of one [`extract_mesh_gpu`] (logged at debug level).
#[derive(Default)]
struct Phases {
    plan_s: f64,
    upload_s: f64,
    count_s: f64,
    mesh_s: f64,
    merge_s: f64,
}

/// `f()`, its wall time added to `seconds`.
fn timed<T>(seconds: &mut f64, f: impl FnOnce() -> T) -> T {
    let t = std::time::Instant::now();
    let out = f();
    *seconds += t.elapsed().as_secs_f64();
    out
}

/// The triangle table as the kernels read it: per sign case, its triangle count, then three
/// edge ids per triangle, padded to the largest case (`stride` words per case).
fn table_words() -> (Vec<u32>, u32) {
    let table = triangle_table();
    let most = table.iter().map(Vec::len).max().unwrap_or(0);
    let stride = 1 + 3 * most;
    let mut words = vec![0u32; 256 * stride];
    for (case, tris) in table.iter().enumerate() {
        let w = &mut words[case * stride..(case + 1) * stride];
        w[0] = tris.len() as u32;
        for (j, t) in tris.iter().enumerate() {
            for k in 0..3 {
                w[1 + 3 * j + k] = t[k] as u32;
            }
        }
    }
    (words, stride as u32)
}

/// One batch's blocks: the meshed ones first (a run of the sorted list), then the neighbours
/// they read corners from, each once.
struct Upload {
    places: Vec<BlockIndex>,
    meshed: usize,
    /// Eight upload places per meshed block (its corner-offset neighbours), [`NO_BLOCK`] where
    /// none is allocated.
    neighbours: Vec<u32>,
}

/// The blocks of `list[start..]` one batch meshes: as many as fit one binding with their
/// neighbours (at least one).
fn plan_batch(layer: &Layer, list: &[BlockIndex], start: usize, cap_bytes: u64) -> Upload {
    let cap_blocks = (cap_bytes / SAMPLE_BYTES).max(1) as usize;
    let mut take = (list.len() - start).min(cap_blocks.div_ceil(2)).max(1);
    loop {
        let upload = upload_of(layer, &list[start..start + take]);
        if upload.places.len() <= cap_blocks || take == 1 {
            return upload;
        }
        take = take.div_ceil(2);
    }
}

fn upload_of(layer: &Layer, meshed: &[BlockIndex]) -> Upload {
    let mut places: Vec<BlockIndex> = meshed.to_vec();
    let mut place_of: HashMap<BlockIndex, u32> = meshed
        .iter()
        .enumerate()
        .map(|(k, &b)| (b, k as u32))
        .collect();
    let mut neighbours = Vec::with_capacity(8 * meshed.len());
    for &b in meshed {
        for c in 0..8i32 {
            let n = b.offset([c & 1, (c >> 1) & 1, (c >> 2) & 1]);
            let place = match place_of.get(&n) {
                Some(&p) => p,
                None if layer.get(&n).is_some() => {
                    let p = places.len() as u32;
                    places.push(n);
                    place_of.insert(n, p);
                    p
                }
                None => NO_BLOCK,
            };
            neighbours.push(place);
        }
    }
    Upload {
        places,
        meshed: meshed.len(),
        neighbours,
    }
}

/// Consecutive runs of a batch's meshed blocks whose corners, vertices and hash table each fit
/// one binding (a block alone always does: at most 512 cubes of a few triangles).
fn plan_parts(counts: &[u32], cap_bytes: u64) -> Vec<Range<usize>> {
    let fits = |triangles: u64| {
        let corners = 3 * triangles;
        corners * CORNER_BYTES <= cap_bytes && ENTRY_BYTES * table_entries(corners) <= cap_bytes
    };
    let mut parts = Vec::new();
    let mut start = 0;
    while start < counts.len() {
        let (mut end, mut triangles) = (start, 0u64);
        while end < counts.len() && (end == start || fits(triangles + counts[end] as u64)) {
            triangles += counts[end] as u64;
            end += 1;
        }
        parts.push(start..end);
        start = end;
    }
    parts
}

/// Hash-table entries for `corners` corners: a power of two above the corner count, so the
/// table never fills (at most one edge per corner) and stays at most half full in practice
/// (an edge is named by 2 to 6 corners).
fn table_entries(corners: u64) -> u64 {
    (corners + 1).next_power_of_two()
}

/// The samples of `places` packed on the host from `layer` straight into the kept staging
/// memory, a block per task: 8 bytes per voxel, the field's value, then the colour with
/// [`VALID_BIT`].
fn host_samples(
    ctx: &GpuContext,
    kept: &mut Kept,
    (layer, field): (&Layer, Field),
    places: &[BlockIndex],
) -> Result<wgpu::Buffer> {
    ctx.check_binding("marching-cubes samples", places.len() as u64 * SAMPLE_BYTES)?;
    let pieces = places.len();
    kept.storage_by_piece::<{ SAMPLE_BYTES as usize }>(ctx, "mc_samples", pieces, |k, dst| {
        let block = layer
            .get(&places[k])
            .expect("an uploaded block is allocated");
        // Two little-endian words per voxel (the piece has no word alignment).
        for (i, w) in dst.chunks_exact_mut(8).enumerate() {
            let value = match field {
                Field::Raw => decode_tsdf(block.tsdf[i]),
                Field::Regularized => block.regularized_or_raw(i),
            };
            let valid = block.omega(i) && block.weight(i) > 0;
            let color = pack_rgb(block.color[i]) | if valid { VALID_BIT } else { 0 };
            w[..4].copy_from_slice(&value.to_bits().to_le_bytes());
            w[4..].copy_from_slice(&color.to_le_bytes());
        }
    })
}

/// A batch's blocks on the device, in kept buffers.
struct Batch {
    uniforms: McUniforms,
    samples: wgpu::Buffer,
    neighbours: wgpu::Buffer,
    table: wgpu::Buffer,
    centres: wgpu::Buffer,
}

impl Batch {
    /// The batch's inputs written into kept buffers (reaching the device with the next
    /// submit), the samples made on the device recorded into `encoder` where `source` holds
    /// every place.
    fn upload(
        ctx: &GpuContext,
        (kept, encoder): (&mut Kept, &mut wgpu::CommandEncoder),
        (layer, source): (&Layer, SampleSource),
        field: Field,
        upload: &Upload,
        (table, stride): (&wgpu::Buffer, u32),
    ) -> Result<Batch> {
        let grid = layer.params();
        let samples = match source.slots(&upload.places) {
            Some((pool, slots)) => device_samples(
                ctx,
                (&mut *kept, encoder),
                layer,
                field,
                &upload.places,
                (pool, &slots),
            )?,
            None => host_samples(ctx, kept, (layer, field), &upload.places)?,
        };
        let centres: Vec<[f32; 24]> = upload
            .places
            .par_iter()
            .map(|index| {
                let mut centres = [0f32; 24];
                for l in 0..VOXELS_PER_SIDE {
                    let c = grid.voxel_center(index.voxel(l, l, l));
                    for axis in 0..3 {
                        centres[8 * axis + l] = c[axis] as f32;
                    }
                }
                centres
            })
            .collect();
        let neighbours = bytemuck::cast_slice(&upload.neighbours);
        Ok(Batch {
            uniforms: McUniforms {
                blocks: upload.meshed as u32,
                first_block: 0,
                corner_count: 0,
                table_mask: 0,
                table_stride: stride,
                voxel_size_m: grid.voxel_size_m,
                pad: [0; 2],
            },
            samples,
            neighbours: kept.storage_with(ctx, "mc_neighbours", neighbours),
            table: table.clone(),
            centres: kept.storage_with(ctx, "mc_centres", bytemuck::cast_slice(&centres)),
        })
    }

    /// Pass 1 (after what `encoder` holds): the triangles of each meshed block.
    fn count(
        &self,
        ctx: &GpuContext,
        kept: &mut Kept,
        mut encoder: wgpu::CommandEncoder,
    ) -> Result<Vec<u32>> {
        let blocks = self.uniforms.blocks as usize;
        let kernel = ctx.kernel(&shaders::MC_COUNT)?;
        let scope = ErrorScopes::push(&ctx.device);
        let uniforms =
            kept.uniform_with(ctx, "mc_count_uniforms", bytemuck::bytes_of(&self.uniforms));
        let counts = kept.scratch(ctx, "mc_block_counts", 4 * blocks as u64);
        encoder.clear_buffer(&counts, 0, Some(4 * blocks as u64));
        let buffers = [
            &uniforms,
            &self.samples,
            &self.neighbours,
            &self.table,
            &counts,
        ];
        let bind = kept.bind_group(ctx, "mc_count", &kernel.layout, &buffers);
        ctx.record_dispatch(&mut encoder, &kernel, &bind, 64 * blocks as u64)?;
        let mut out = vec![0u32; blocks];
        let results = &mut [(&counts, bytemuck::cast_slice_mut(&mut out))];
        ctx.submit_and_read_back(encoder, kept, results)?;
        scope.pop("counting marching-cubes triangles")?;
        Ok(out)
    }

    /// Passes 2–5 over the meshed blocks `part`: the part's vertices (five words each: x, y,
    /// z, colour, edge key) and its triangles' vertex numbers (three per triangle).
    fn mesh_part(
        &self,
        ctx: &GpuContext,
        kept: &mut Kept,
        part: Range<usize>,
        counts: &[u32],
    ) -> Result<(Vec<[u32; 5]>, Vec<u32>)> {
        let blocks = part.len();
        let mut tri_base = Vec::with_capacity(blocks + 1);
        let mut triangles = 0u32;
        for &c in &counts[part.clone()] {
            tri_base.push(triangles);
            triangles += c;
        }
        tri_base.push(triangles);
        let corners = 3 * triangles as u64;
        if corners == 0 {
            return Ok((Vec::new(), Vec::new()));
        }
        let entries = table_entries(corners);
        let uniforms = McUniforms {
            blocks: blocks as u32,
            first_block: part.start as u32,
            corner_count: corners as u32,
            table_mask: (entries - 1) as u32,
            ..self.uniforms
        };
        let k = |s| ctx.kernel(s);
        let (emit, first, scan, assign, link) = (
            k(&shaders::MC_EMIT)?,
            k(&shaders::MC_FIRST)?,
            k(&shaders::MC_SCAN)?,
            k(&shaders::MC_ASSIGN)?,
            k(&shaders::MC_LINK)?,
        );
        let scope = ErrorScopes::push(&ctx.device);
        let mut encoder = ctx.encoder("marching_cubes");
        let u = kept.uniform_with(ctx, "mc_uniforms", bytemuck::bytes_of(&uniforms));
        let base = kept.storage_with(ctx, "mc_tri_base", bytemuck::cast_slice(&tri_base));
        // The hash table's and the blocks' vertex counts start at zero (the kernels add to
        // them); the rest is written whole before it is read.
        let mut zeroed = |name, bytes| {
            let b = kept.scratch(ctx, name, bytes);
            encoder.clear_buffer(&b, 0, Some(bytes));
            b
        };
        let hash = zeroed("mc_hash", ENTRY_BYTES * entries);
        let block_vertices = zeroed("mc_block_vertices", 4 * blocks as u64);
        let corner_buf = kept.scratch(ctx, "mc_corners", CORNER_BYTES * corners);
        let vertex_base = kept.scratch(ctx, "mc_vertex_base", 4 * (blocks as u64 + 1));
        // At most one vertex per corner.
        let vertices = kept.scratch(ctx, "mc_vertices", CORNER_BYTES * corners);
        let tris = kept.scratch(ctx, "mc_triangles", 4 * corners);
        let (s, n, t, c) = (&self.samples, &self.neighbours, &self.table, &self.centres);
        let groups = 64 * blocks as u64;
        let assigned = [&u, &base, &vertex_base, &hash, &corner_buf, &vertices];
        let passes: [(&'static str, &Kernel, &[&wgpu::Buffer], u64); 5] = [
            (
                "mc_emit",
                &emit,
                &[&u, s, n, t, c, &base, &hash, &corner_buf],
                groups,
            ),
            (
                "mc_first",
                &first,
                &[&u, &base, &hash, &corner_buf, &block_vertices],
                groups,
            ),
            ("mc_scan", &scan, &[&u, &block_vertices, &vertex_base], 64),
            ("mc_assign", &assign, &assigned, groups),
            ("mc_link", &link, &[&u, &hash, &corner_buf, &tris], corners),
        ];
        for (name, kernel, buffers, invocations) in passes {
            let bind = kept.bind_group(ctx, name, &kernel.layout, buffers);
            ctx.record_dispatch(&mut encoder, kernel, &bind, invocations)?;
        }
        let mut triangle_words = vec![0u32; corners as usize];
        let mut bases = vec![0u32; blocks + 1];
        ctx.submit_and_read_back(
            encoder,
            kept,
            &mut [
                (&tris, bytemuck::cast_slice_mut(&mut triangle_words)),
                (&vertex_base, bytemuck::cast_slice_mut(&mut bases)),
            ],
        )?;
        let mut out: Vec<[u32; 5]> = bytemuck::zeroed_vec(bases[blocks] as usize);
        let results = &mut [(&vertices, bytemuck::cast_slice_mut(&mut out))];
        ctx.submit_and_read_back(ctx.encoder("mc_vertices"), kept, results)?;
        scope.pop("meshing on the GPU")?;
        Ok((out, triangle_words))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parts_fit_the_binding_and_cover_the_blocks_in_order() {
        let counts = [5u32, 0, 700, 3, 3, 0, 1200, 2];
        // 3 corners × 20 bytes per triangle, and the hash table's power of two.
        for cap in [1u64 << 10, 1 << 14, 1 << 16, 1 << 30] {
            let parts = plan_parts(&counts, cap);
            assert_eq!(parts.first().map(|p| p.start), Some(0));
            assert_eq!(parts.last().map(|p| p.end), Some(counts.len()));
            for w in parts.windows(2) {
                assert_eq!(w[0].end, w[1].start);
            }
            for p in &parts {
                let t: u64 = counts[p.clone()].iter().map(|&c| c as u64).sum();
                assert!(
                    p.len() == 1 || 3 * t * CORNER_BYTES <= cap,
                    "{p:?} at {cap}"
                );
            }
        }
        let whole = plan_parts(&counts, 1 << 30);
        assert_eq!((whole.len(), whole[0].clone()), (1, 0..counts.len()));
        // 1 KiB: at most 17 triangles a part; the blocks of 700 and 1200 alone.
        let small: Vec<Range<usize>> = vec![0..2, 2..3, 3..6, 6..7, 7..8];
        assert_eq!(plan_parts(&counts, 1 << 10), small);
    }

    #[test]
    fn the_table_words_hold_every_case() {
        let (words, stride) = table_words();
        let table = triangle_table();
        for (case, tris) in table.iter().enumerate() {
            let w = &words[case * stride as usize..];
            assert_eq!(w[0] as usize, tris.len());
            for (j, t) in tris.iter().enumerate() {
                assert_eq!(&w[1 + 3 * j..4 + 3 * j], &t.map(|e| e as u32));
            }
        }
    }
}
