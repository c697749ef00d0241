//! Re-encodes the chunks of a map at several zstd levels: bytes per allocated voxel and encode
//! time per level (to choose the writers' level). Usage: `chunk_levels MAP_DIR [MAX_CHUNKS]`.

use denser::grid::{Block, BlockIndex};
use denser::tiles::codec::{encode_chunk, ChunkHeader};
use denser::tiles::store::MapStore;

fn main() -> denser::Result<()> {
    let dir = std::env::args()
        .nth(1)
        .expect("usage: chunk_levels MAP_DIR [MAX_CHUNKS]");
    let max: usize = std::env::args()
        .nth(2)
        .and_then(|s| s.parse().ok())
        .unwrap_or(50);
    let store = MapStore::open_read_only(std::path::Path::new(&dir))?;
    let chunks: Vec<_> = store.chunk_indices().into_iter().take(max).collect();
    let decoded: Vec<_> = chunks
        .iter()
        .map(|c| store.read_chunk(*c).map(|d| d.expect("chunk")))
        .collect::<Result<_, _>>()?;
    let voxels: usize = decoded.iter().map(|d| d.blocks.len() * 512).sum();
    for level in [1, 3, 6, 9, 12, 15, 19] {
        let t = std::time::Instant::now();
        let mut bytes = 0;
        for d in &decoded {
            let refs: Vec<(BlockIndex, &Block)> =
                d.blocks.iter().map(|(i, b)| (*i, &**b)).collect();
            let h = ChunkHeader { ..d.header };
            bytes += encode_chunk(&h, &refs, level).len();
        }
        let s = t.elapsed().as_secs_f64();
        println!(
            "level {level:2}: {:.3} bytes/voxel, {:.1} M voxels/s encode",
            bytes as f64 / voxels as f64,
            voxels as f64 / s / 1e6
        );
    }
    Ok(())
}
