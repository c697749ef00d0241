//! Compares codings of the regularized field on a stored map: compressed bytes of the `u` planes
//! as `u − f` (chunk format 1) vs. as deltas of `u` along the coded voxels. Usage:
//! `chunk_levels MAP_DIR [MAX_CHUNKS]`.

use denser::map::store::MapStore;

fn zz(d: i16) -> u16 {
    ((d << 1) ^ (d >> 15)) as u16
}

fn planes(z: &[u16]) -> Vec<u8> {
    let mut v: Vec<u8> = z.iter().map(|x| (*x & 0xff) as u8).collect();
    v.extend(z.iter().map(|x| (*x >> 8) as u8));
    v
}

fn main() -> denser::Result<()> {
    let dir = std::env::args()
        .nth(1)
        .expect("usage: chunk_levels MAP_DIR [MAX_CHUNKS]");
    let max: usize = std::env::args()
        .nth(2)
        .and_then(|s| s.parse().ok())
        .unwrap_or(50);
    let store = MapStore::open_read_only(std::path::Path::new(&dir))?;
    let (mut a, mut b, mut files, mut voxels) = (0usize, 0usize, 0u64, 0usize);
    for c in store.chunk_indices().into_iter().take(max) {
        let d = store.read_chunk(c)?.expect("chunk");
        if d.header.flags & 1 == 0 {
            continue;
        }
        files += store.manifest().chunks[&c].file_bytes;
        voxels += d.blocks.len() * 512;
        let (mut za, mut zb) = (Vec::new(), Vec::new());
        for (_, blk) in &d.blocks {
            let Some(u) = &blk.regularized else { continue };
            let mut prev = 0i16;
            for i in 0..512 {
                if blk.weight_omega[i] != 0 {
                    za.push(zz(u[i].wrapping_sub(blk.tsdf[i])));
                    zb.push(zz(u[i].wrapping_sub(prev)));
                    prev = u[i];
                }
            }
        }
        a += zstd::bulk::compress(&planes(&za), 3).expect("zstd").len();
        b += zstd::bulk::compress(&planes(&zb), 3).expect("zstd").len();
    }
    let v = voxels.max(1) as f64;
    println!(
        "chunks with u: {:.3} bytes/voxel in all; u planes as u−f {:.3}, as u deltas {:.3} bytes/voxel",
        files as f64 / v,
        a as f64 / v,
        b as f64 / v
    );
    Ok(())
}
