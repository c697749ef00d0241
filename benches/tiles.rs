//! Criterion benchmarks of the out-of-core path on the analytic scene (sphere above a floor, 8
//! views at 640×480, 5 cm voxels): chunk encode/decode throughput, and fusion through the pager
//! (budget 0: every chunk evicted after every frame, the worst case) vs. in memory. Settings are
//! fixed: do not modify, or results are not comparable.

#[path = "../tests/common/mod.rs"]
mod common;

use common::{orbit, vga, Rng, SphereScene};
use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use denser::backend::Backend;
use denser::fusion::{integrate_depth, DepthFusionParams};
use denser::grid::{Block, BlockIndex, GridParams, Layer};
use denser::map::codec::{decode_chunk, encode_chunk, ChunkHeader};
use denser::map::store::MapStore;
use denser::map::{group_by_chunk, ChunkIndex};
use denser::outofcore::pager::{OverrunPolicy, PagerConfig};
use denser::outofcore::regional::RegionalOptions;
use denser::outofcore::PagedStore;
use denser::reconstruct::{ReconstructionConfig, Reconstructor};

const GRID: GridParams = GridParams {
    voxel_size_m: 0.05,
    truncation_m: 0.2,
};

fn frames() -> Vec<denser::frame::DepthFrame> {
    let scene = SphereScene::standard();
    let mut rng = Rng(1);
    orbit(8, 3.0, -1.2, scene.center)
        .into_iter()
        .map(|p| scene.render(&vga(), p, 0.005, 8.0, &mut rng))
        .collect()
}

fn codec(c: &mut Criterion) {
    let mut layer = Layer::new(GRID);
    for f in &frames() {
        integrate_depth(&mut layer, f, &DepthFusionParams::default());
    }
    // The fullest 16³-block chunk of the scene.
    let (chunk, blocks) = group_by_chunk(layer.indices_sorted(), 16)
        .into_iter()
        .max_by_key(|(_, v)| v.len())
        .expect("a chunk");
    let refs: Vec<(BlockIndex, &Block)> = blocks
        .iter()
        .map(|b| (*b, layer.get(b).expect("b")))
        .collect();
    let header = ChunkHeader {
        voxel_size_m: GRID.voxel_size_m,
        truncation_m: GRID.truncation_m,
        chunk: ChunkIndex(chunk.0),
        chunk_blocks: 16,
        block_count: 0,
        flags: 0,
        payload_raw_bytes: 0,
        payload_zstd_bytes: 0,
        payload_crc32: 0,
    };
    let bytes = encode_chunk(&header, &refs, 3);
    println!(
        "chunk of {} blocks: {} bytes, {:.3} bytes per voxel",
        refs.len(),
        bytes.len(),
        bytes.len() as f64 / (refs.len() * 512) as f64
    );
    let mut g = c.benchmark_group("chunk_codec");
    g.throughput(Throughput::Elements((refs.len() * 512) as u64)); // voxels
    g.bench_function("encode_zstd3", |b| {
        b.iter(|| encode_chunk(&header, &refs, 3))
    });
    g.bench_function("decode", |b| {
        b.iter(|| decode_chunk(&bytes).expect("decode"))
    });
    g.finish();
}

fn paging(c: &mut Criterion) {
    let frames = frames();
    let mut g = c.benchmark_group("fuse_8_frames_5cm");
    g.sample_size(10);
    g.bench_function("in_memory", |b| {
        b.iter(|| {
            let mut layer = Layer::new(GRID);
            for f in &frames {
                integrate_depth(&mut layer, f, &DepthFusionParams::default());
            }
            layer.block_count()
        })
    });
    for chunk_blocks in [16u32, 4] {
        g.bench_function(format!("paged_budget0_chunk{chunk_blocks}"), |b| {
            b.iter(|| {
                let dir = tempfile::tempdir().expect("tempdir");
                let store =
                    MapStore::create(&dir.path().join("m"), GRID, chunk_blocks).expect("create");
                let store = PagedStore::new(
                    store,
                    PagerConfig {
                        budget_bytes: 0,
                        overrun: OverrunPolicy::Warn,
                        writer_threads: 2,
                    },
                    RegionalOptions {
                        region_chunks: 2,
                        budget_bytes: 1 << 30,
                        halo_blocks: None,
                        sweep_iterations: Some(denser::outofcore::sweeps::DEFAULT_SWEEP_ITERATIONS),
                    },
                    denser::export::write_map_surface,
                );
                let config = ReconstructionConfig {
                    grid: GRID,
                    ..ReconstructionConfig::paper(GRID.voxel_size_m)
                };
                let mut rec = Reconstructor::with_store(config, Box::new(store), Backend::cpu(), 0)
                    .expect("reconstructor");
                for f in &frames {
                    rec.fuse_depth(f).expect("fuse");
                }
                rec.sync().expect("commit");
                rec.summary().blocks
            })
        });
    }
    g.finish();
}

criterion_group!(benches, codec, paging);
criterion_main!(benches);
