//! GPU marching cubes against the CPU mesher (`denser::mesh::extract_mesh_gpu` against
//! `extract_mesh_keyed`): the same triangles over the same vertices in the same order, positions
//! within the stated tolerance and colours within one step, on the sphere scene's raw and
//! regularized fields, with Ω holes, on listed blocks, and split into batches and parts.

use crate::common::{gpu, Rng};
use crate::compare::sphere_layer;
use denser::export::{export_with, ExportOptions, ExportTarget, Mesher};
use denser::gpu::GpuContext;
use denser::grid::{BlockIndex, GridParams, Layer, OMEGA_BIT, VOXELS_PER_BLOCK};
use denser::io::ply::read_mesh_ply;
use denser::map::store::MapStore;
use denser::mesh::SampleSource;
use denser::mesh::POSITION_TOLERANCE_VOXELS;
use denser::mesh::{extract_mesh_gpu, extract_mesh_keyed, EdgeKey, Field, GpuMesher, Mesh};
use denser::regularize::{regularize_layer, TvParams};

const GRID: GridParams = GridParams {
    voxel_size_m: 0.05,
    truncation_m: 0.4,
};

/// The sphere scene from six views, regularized, with Ω holes punched in (so cubes with a
/// corner outside Ω are left out).
fn scene() -> Layer {
    let mut layer = sphere_layer(GRID, 6, 0.01, None);
    regularize_layer(&mut layer, &TvParams::paper(0.1)).expect("TV");
    let mut rng = Rng(11);
    for b in layer.indices_sorted() {
        let block = layer.get_mut(&b).expect("block");
        for i in 0..VOXELS_PER_BLOCK {
            if rng.uniform() < 0.02 {
                block.weight_omega[i] &= !OMEGA_BIT;
            }
        }
    }
    layer
}

/// Asserts `gpu` is `cpu` within the stated tolerances; returns the vertices whose position
/// differs at all.
fn assert_same_mesh(cpu: &(Mesh, Vec<EdgeKey>), gpu: &(Mesh, Vec<EdgeKey>)) -> usize {
    let ((c, ck), (g, gk)) = (cpu, gpu);
    assert!(!c.triangles.is_empty());
    assert_eq!(c.positions_m.len(), g.positions_m.len(), "vertex count");
    assert_eq!(ck, gk, "edge keys, in order");
    assert_eq!(c.triangles, g.triangles, "triangles");
    let mut moved = 0;
    for (k, (p, q)) in c.positions_m.iter().zip(&g.positions_m).enumerate() {
        for a in 0..3 {
            let ulp = f32::from_bits(p[a].abs().to_bits() + 1) - p[a].abs();
            let tol = POSITION_TOLERANCE_VOXELS * GRID.voxel_size_m + ulp;
            assert!((p[a] - q[a]).abs() <= tol, "vertex {k}: {p:?} vs {q:?}");
        }
        moved += (p != q) as usize;
        let (x, y) = (c.colors[k], g.colors[k]);
        for i in 0..3 {
            assert!(
                x[i].abs_diff(y[i]) <= 1,
                "vertex {k}: colour {x:?} vs {y:?}"
            );
        }
    }
    moved
}

#[test]
fn gpu_marching_cubes_equals_the_cpu_mesher() {
    let Some(ctx) = gpu() else { return };
    let layer = scene();
    for field in [Field::Raw, Field::Regularized] {
        let cpu = extract_mesh_keyed(&layer, field, None);
        let gpu = extract_mesh_gpu(&ctx, &layer, field, None).expect("GPU mesh");
        let moved = assert_same_mesh(&cpu, &gpu);
        eprintln!(
            "{field:?}: {} vertices, {} triangles; {moved} vertices not bit-identical",
            cpu.0.positions_m.len(),
            cpu.0.triangles.len()
        );
    }
    // The raw and regularized meshes differ: the field reached the kernel.
    let raw = extract_mesh_gpu(&ctx, &layer, Field::Raw, None).expect("raw");
    let reg = extract_mesh_gpu(&ctx, &layer, Field::Regularized, None).expect("regularized");
    assert_ne!(raw.0, reg.0);
}

#[test]
fn gpu_marching_cubes_of_listed_blocks_equals_the_cpu_mesher() {
    let Some(ctx) = gpu() else { return };
    let layer = scene();
    let all = layer.indices_sorted();
    // Every third block, in reverse and with repeats, and a block that is not allocated.
    let mut list: Vec<BlockIndex> = all.iter().rev().step_by(3).copied().collect();
    list.extend_from_slice(&all[..4]);
    list.push(BlockIndex([1000, 1000, 1000]));
    let cpu = extract_mesh_keyed(&layer, Field::Regularized, Some(&list));
    let gpu = extract_mesh_gpu(&ctx, &layer, Field::Regularized, Some(&list)).expect("GPU");
    assert_same_mesh(&cpu, &gpu);
    // No blocks, or none allocated: an empty mesh.
    let none = extract_mesh_gpu(&ctx, &layer, Field::Raw, Some(&[BlockIndex([1000, 0, 0])]));
    assert_eq!(none.expect("empty").0, Mesh::default());
}

#[test]
fn gpu_marching_cubes_in_batches_and_parts_gives_the_same_mesh() {
    let Some(whole) = gpu() else { return };
    let layer = scene();
    let cpu = extract_mesh_keyed(&layer, Field::Regularized, None);
    let one = extract_mesh_gpu(&whole, &layer, Field::Regularized, None).expect("GPU");
    // 64 KiB bindings: 16 blocks' samples per batch (with their neighbours), and a few
    // hundred triangles per part.
    let small: GpuContext = gpu()
        .expect("the same adapter")
        .with_max_binding_bytes(64 << 10);
    let before = small.traffic();
    let split = extract_mesh_gpu(&small, &layer, Field::Regularized, None).expect("GPU, split");
    let t = small.traffic().since(before);
    let blocks = layer.block_count() as u64;
    eprintln!("{blocks} blocks in 64 KiB bindings: {t:?}");
    assert!(
        t.waits > 2 * blocks / 16,
        "{t:?}: several batches and parts"
    );
    assert_eq!(split, one, "split into batches and parts");
    assert_same_mesh(&cpu, &split);
}

#[test]
fn gpu_marching_cubes_traffic_is_the_samples_up_and_the_mesh_down() {
    let Some(ctx) = gpu() else { return };
    let layer = scene();
    let before = ctx.traffic();
    let (mesh, _) = extract_mesh_gpu(&ctx, &layer, Field::Raw, None).expect("GPU");
    let t = ctx.traffic().since(before);
    let blocks = layer.block_count() as u64;
    let (v, tri) = (mesh.positions_m.len() as u64, mesh.triangles.len() as u64);
    eprintln!("{blocks} blocks, {v} vertices, {tri} triangles: {t:?}");
    // One batch, one part: a count (submit, wait), the mesh (submit, wait) and its vertices
    // (submit, wait).
    assert_eq!((t.submits, t.waits), (3, 3), "{t:?}");
    assert_eq!(t.dispatches, 6, "{t:?}");
    // Up: 8 bytes per voxel and 96 per block of samples (every block is meshed, so none is
    // uploaded twice), 32 bytes of neighbours per block, 4 of triangle bases, the table and
    // the uniforms.
    let up = blocks * (8 * VOXELS_PER_BLOCK as u64 + 96 + 32 + 4);
    assert!(
        t.upload_bytes >= up && t.upload_bytes <= up + (32 << 10),
        "{t:?} vs {up}"
    );
    // Down: 4 bytes per block (count) and per block + 1 (vertex bases), 12 per triangle and 20
    // per vertex.
    let down = 4 * blocks + 4 * (blocks + 1) + 12 * tri + 20 * v;
    assert_eq!(t.readback_bytes, down, "{t:?}");
}

#[test]
fn a_kept_mesher_creates_no_buffer_after_its_first_mesh() {
    // Issue 34's kept buffers: a `GpuMesher`'s meshes after its first, of no more blocks and
    // triangles (the raw field's mesh is the larger here), create no buffer and no bind group
    // (the triangle table stays on the device), in three submits and three waits, and are the
    // meshes a mesher of their own makes.
    let Some(ctx) = gpu() else { return };
    let ctx = std::sync::Arc::new(ctx);
    let layer = scene();
    let mesher = GpuMesher::new(ctx.clone());
    let before = ctx.traffic();
    let first = mesher.mesh(&layer, Field::Raw, None, SampleSource::Layer);
    let warm_up = ctx.traffic().since(before);
    assert!(warm_up.buffers_created >= 12, "{warm_up:?}");
    let all = layer.indices_sorted();
    let some = &all[..all.len() / 3];
    for (field, blocks) in [
        (Field::Raw, None),
        (Field::Regularized, None),
        (Field::Raw, Some(some)),
    ] {
        let before = ctx.traffic();
        let kept = mesher
            .mesh(&layer, field, blocks, SampleSource::Layer)
            .expect("kept");
        let t = ctx.traffic().since(before);
        eprintln!(
            "{field:?}, {} blocks: {t:?}",
            blocks.map_or(all.len(), <[_]>::len)
        );
        assert_eq!((t.buffers_created, t.bind_groups_created), (0, 0), "{t:?}");
        assert_eq!((t.submits, t.waits), (3, 3), "{t:?}");
        let own = extract_mesh_gpu(&ctx, &layer, field, blocks).expect("own");
        assert!(!own.0.triangles.is_empty());
        assert_eq!(kept, own, "{field:?}");
    }
    assert_eq!(
        first.expect("first"),
        extract_mesh_gpu(&ctx, &layer, Field::Raw, None).unwrap()
    );
    // Given back: the next mesh makes its buffers again.
    mesher.release();
    let before = ctx.traffic();
    mesher
        .mesh(&layer, Field::Raw, None, SampleSource::Layer)
        .expect("after release");
    assert!(ctx.traffic().since(before).buffers_created >= 12);
}

#[test]
fn export_meshes_the_chunks_on_the_gpu_as_on_the_cpu() {
    // `export --device gpu`: every chunk meshed by the GPU twin, then stitched as the CPU's
    // chunks are. The same vertices (positions within the tolerance) and the same triangles;
    // on llvmpipe, where the twins agree exactly, the same PLY bytes.
    let Some(ctx) = gpu() else { return };
    let ctx = std::sync::Arc::new(ctx);
    let tmp = tempfile::tempdir().expect("tempdir");
    let layer = scene();
    // Chunks of 2³ blocks: many chunk borders to stitch across.
    let chunk_blocks = 2;
    let mut store = MapStore::create(&tmp.path().join("map"), GRID, chunk_blocks).expect("map");
    for (c, blocks) in denser::map::group_by_chunk(layer.indices_sorted(), chunk_blocks) {
        let refs: Vec<_> = blocks
            .iter()
            .map(|b| (*b, layer.get(b).expect("block")))
            .collect();
        store.write_chunk(c, &refs, 0).expect("write chunk");
    }
    store.commit().expect("commit");
    let mut options = ExportOptions::new(Field::Raw);
    let cpu_path = tmp.path().join("cpu.ply");
    let cpu = export_with(&store, &options, &ExportTarget::Mesh(cpu_path.clone())).expect("CPU");
    options.mesher = Mesher::gpu(ctx.clone());
    let gpu_path = tmp.path().join("gpu.ply");
    let before = ctx.traffic();
    let on_gpu = export_with(&store, &options, &ExportTarget::Mesh(gpu_path.clone())).expect("GPU");
    let t = ctx.traffic().since(before);
    assert!(cpu.chunks > 20, "{cpu:?}");
    assert!(
        t.dispatches >= cpu.chunks as u64 && t.waits >= cpu.chunks as u64,
        "the chunks were meshed on the GPU: {t:?}"
    );
    assert_eq!(
        (cpu.vertices, cpu.triangles),
        (on_gpu.vertices, on_gpu.triangles)
    );
    let (c, g) = (
        read_mesh_ply(&cpu_path).unwrap(),
        read_mesh_ply(&gpu_path).unwrap(),
    );
    assert_eq!(c.triangles, g.triangles);
    let tolerance_m = 2.0 * POSITION_TOLERANCE_VOXELS * GRID.voxel_size_m;
    for (a, b) in c.positions_m.iter().zip(&g.positions_m) {
        let d = (0..3).map(|k| (a[k] - b[k]).abs()).fold(0f32, f32::max);
        assert!(
            d <= tolerance_m + 1e-6 * a.iter().fold(0f32, |m, v| m.max(v.abs())),
            "{a:?} {b:?}"
        );
    }
    if ctx.describe().contains("llvmpipe") {
        assert!(std::fs::read(&cpu_path).unwrap() == std::fs::read(&gpu_path).unwrap());
    }
}
