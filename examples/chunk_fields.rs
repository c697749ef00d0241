//! Where the bytes of a stored map's chunk files go: re-encodes every chunk in format 2 and in
//! format 3 at one zstd level (format 3: its structured parts at `STRUCTURED_ZSTD_LEVEL` at
//! least, as the store writes them), checks that format 3 decodes to the same blocks bit for bit,
//! and prints bytes per allocated voxel of each payload part compressed alone, of the whole
//! files, and encode/decode milliseconds per chunk. Usage: `chunk_fields MAP_DIR [ZSTD_LEVEL]`.

use denser::grid::{Block, BlockIndex};
use denser::map::codec::{
    decode_chunk, encode_chunk_v3, encode_chunk_with, local_order, payload_planes,
    STRUCTURED_ZSTD_LEVEL,
};
use denser::map::store::MapStore;
use std::time::Instant;

fn main() -> denser::Result<()> {
    let args: Vec<String> = std::env::args().collect();
    let dir = args
        .get(1)
        .expect("usage: chunk_fields MAP_DIR [ZSTD_LEVEL]");
    let level: i32 = args.get(2).and_then(|s| s.parse().ok()).unwrap_or(3);
    let store = MapStore::open_read_only(std::path::Path::new(dir))?;
    let mut names: Vec<&str> = Vec::new();
    let mut parts = [Vec::new(), Vec::new()];
    let (mut files, mut enc_s, mut dec_s) = ([0usize; 2], [0f64; 2], [0f64; 2]);
    let (mut voxels, mut chunks) = (0usize, 0usize);
    for c in store.chunk_indices() {
        let d = store.read_chunk(c)?.expect("chunk named by the manifest");
        let origin = d.origin.expect("a format-2 or -3 file");
        let refs: Vec<(BlockIndex, &Block)> = d.blocks.iter().map(|(i, b)| (*i, &**b)).collect();
        voxels += refs.len() * 512;
        chunks += 1;
        for (v, predicted) in [false, true].into_iter().enumerate() {
            let t = Instant::now();
            let bytes = if predicted {
                encode_chunk_v3(&d.header, &origin, &refs, level)
            } else {
                encode_chunk_with(&d.header, Some(&origin), &refs, level)
            };
            enc_s[v] += t.elapsed().as_secs_f64();
            files[v] += bytes.len();
            let t = Instant::now();
            let back = decode_chunk(&bytes).expect("decode");
            dec_s[v] += t.elapsed().as_secs_f64();
            assert!(
                back.blocks.len() == d.blocks.len()
                    && back
                        .blocks
                        .iter()
                        .zip(&d.blocks)
                        .all(|(a, b)| a.0 == b.0 && *a.1 == *b.1),
                "chunk {c:?} does not round-trip in format {}",
                2 + v
            );
            let planes = payload_planes(&local_order(&d.header, &refs), predicted);
            names = planes.iter().map(|(n, _)| *n).collect();
            parts[v].resize(planes.len(), 0usize);
            for (k, (name, p)) in planes.iter().enumerate() {
                // Format 3 compresses its structured parts at STRUCTURED_ZSTD_LEVEL at least.
                let l = match (predicted, *name) {
                    (true, "tsdf low" | "u low") | (false, _) => level,
                    (true, _) => level.max(STRUCTURED_ZSTD_LEVEL),
                };
                if !p.is_empty() {
                    parts[v][k] += zstd::bulk::compress(p, l).expect("zstd").len();
                }
            }
        }
    }
    let v = voxels.max(1) as f64;
    println!(
        "{chunks} chunks, {voxels} allocated voxels, zstd level {level}, every chunk round-trips"
    );
    println!(
        "{:>16} {:>10} {:>10}",
        "bytes/voxel", "format 2", "format 3"
    );
    for (k, n) in names.iter().enumerate() {
        println!(
            "{n:>16} {:>10.4} {:>10.4}",
            parts[0][k] as f64 / v,
            parts[1][k] as f64 / v
        );
    }
    println!(
        "{:>16} {:>10.4} {:>10.4}",
        "whole files",
        files[0] as f64 / v,
        files[1] as f64 / v
    );
    let per = |s: f64| 1000.0 * s / chunks.max(1) as f64;
    println!(
        "{:>16} {:>10.2} {:>10.2}",
        "encode ms/chunk",
        per(enc_s[0]),
        per(enc_s[1])
    );
    println!(
        "{:>16} {:>10.2} {:>10.2}",
        "decode ms/chunk",
        per(dec_s[0]),
        per(dec_s[1])
    );
    Ok(())
}
