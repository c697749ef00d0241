//! Chunk format 3 (`formats/chunk.md`): golden bytes of the header and of a hand-computed
//! payload (prediction residuals, one zstd frame per part), bit-identical round trips of random,
//! dense, empty and extreme blocks, rejection of every truncation and flipped byte, and files of
//! formats 1 and 2 still read.

use denser::grid::{Block, BlockIndex, OMEGA_BIT, VOXELS_PER_BLOCK};
use denser::map::codec::{
    decode_chunk, decode_header_with_origin, encode_chunk, encode_chunk_v3,
    encode_chunk_v3_reusing, encode_chunk_v4_reusing, encode_chunk_with, encode_header_v2,
    encode_header_v3, ChunkHeader, ChunkOrigin, PreviousFrames, CHUNK_HEADER_V2_BYTES,
};
use denser::map::ChunkIndex;
use denser::regularize::TvParams;
use proptest::prelude::*;

fn header(chunk: ChunkIndex) -> ChunkHeader {
    ChunkHeader {
        voxel_size_m: 0.1,
        truncation_m: 1.0,
        chunk,
        chunk_blocks: 4,
        block_count: 0,
        flags: 0,
        payload_raw_bytes: 0,
        payload_zstd_bytes: 0,
        payload_crc32: 0,
    }
}

fn origin() -> ChunkOrigin {
    ChunkOrigin {
        map_id: 0x1122_3344_5566_7788,
        file_seq: 42,
        reg_pass: 1,
        reg_params: TvParams::paper(0.1),
        commit_gen: 0,
    }
}

fn v3(h: &ChunkHeader, blocks: &[(BlockIndex, Box<Block>)]) -> Vec<u8> {
    let refs: Vec<(BlockIndex, &Block)> = blocks.iter().map(|(i, b)| (*i, &**b)).collect();
    encode_chunk_v3(h, &origin(), &refs, 3)
}

/// Decodes `bytes` and asserts the blocks equal `blocks` bit for bit (sorted by index).
fn assert_round_trip(bytes: &[u8], blocks: &[(BlockIndex, Box<Block>)]) {
    assert_eq!(&bytes[8..10], &[3, 0], "format 3");
    let d = decode_chunk(bytes).expect("decode");
    assert_eq!(d.origin, Some(origin()));
    let mut want: Vec<&(BlockIndex, Box<Block>)> = blocks.iter().collect();
    want.sort_by_key(|(i, _)| *i);
    assert_eq!(d.blocks.len(), want.len());
    for ((a, ba), (b, bb)) in d.blocks.iter().zip(want) {
        assert_eq!(a, b);
        assert_eq!(ba.tsdf, bb.tsdf, "TSDF of block {a:?}");
        assert_eq!(ba.weight_omega, bb.weight_omega, "weights of block {a:?}");
        assert_eq!(ba.color, bb.color, "colour of block {a:?}");
        assert_eq!(ba.regularized, bb.regularized, "u of block {a:?}");
    }
}

/// A block with pseudo-random fields from `seed`: voxels observed with probability `fill`/8,
/// TSDF a noisy slope (or anything at all when `wild`), `u` when `with_u`.
fn random_block(seed: u64, fill: u64, with_u: bool, wild: bool) -> Box<Block> {
    let mut s = seed | 1;
    let mut next = move || {
        s ^= s << 13;
        s ^= s >> 7;
        s ^= s << 17;
        s
    };
    let mut b = Block::new_boxed();
    let mut u = Box::new(b.tsdf);
    for i in 0..VOXELS_PER_BLOCK {
        let r = next();
        if r % 8 >= fill {
            continue;
        }
        let slope = 3000 * (i / 64) as i64 - 12000 + (r >> 40) as i64 % 1500;
        b.tsdf[i] = if wild {
            (r >> 16) as i16
        } else {
            slope.clamp(-32767, 32767) as i16
        };
        b.weight_omega[i] = (r >> 8) as u8 | 1;
        b.color[i] = [(r >> 24) as u8, (r >> 32) as u8, (r >> 48) as u8];
        u[i] = if wild {
            (r >> 32) as i16
        } else {
            b.tsdf[i].saturating_add((r >> 56) as i16 - 128)
        };
    }
    if with_u {
        b.regularized = Some(u);
    }
    b
}

#[test]
fn chunk_v3_golden_bytes() {
    // Header: the version-2 table with version 3.
    let h = ChunkHeader {
        block_count: 5,
        flags: 1,
        payload_raw_bytes: 0x4414,
        payload_zstd_bytes: 0x6789,
        payload_crc32: 0xDEAD_BEEF,
        ..header(ChunkIndex([-1, 2, 3]))
    };
    let b3 = encode_header_v3(&h, &origin());
    let b2 = encode_header_v2(&h, &origin());
    assert_eq!(&b3[0..8], b"DNSRCHNK");
    assert_eq!(&b3[8..10], &[3, 0], "version 3");
    assert_eq!(&b3[10..124], &b2[10..124], "the rest as version 2");
    assert_eq!(&b3[124..128], &crc32fast::hash(&b3[0..124]).to_le_bytes());
    assert_eq!(
        decode_header_with_origin(&b3).expect("decode"),
        (h, Some(origin()))
    );

    // Payload: one block at local (1, 2, 3) with coded voxels 1 (x 1), 2 (x 2) and 9 (x 1, y 1).
    let mut b = Block::new_boxed();
    for (i, t, c) in [
        (1, 90, [10, 20, 30]),
        (2, 95, [11, 21, 31]),
        (9, 100, [12, 22, 32]),
    ] {
        b.tsdf[i] = t;
        b.weight_omega[i] = OMEGA_BIT | i as u8;
        b.color[i] = c;
    }
    let mut u = Box::new(b.tsdf);
    (u[1], u[2], u[9]) = (80, 97, 60);
    b.regularized = Some(u);
    let blocks = vec![(BlockIndex([1, 2, 3]), b)];
    let file = v3(&header(ChunkIndex([0, 0, 0])), &blocks);
    // TSDF: voxel 1 has no coded neighbour: prediction 0 (the block's first), residual 90;
    // voxel 2 its x neighbour 90 (no second one), residual 5; voxel 9 its y neighbour 90, 10.
    let tsdf_lo = [180, 10, 20];
    // Colour: the same predictions per channel (red 10, 1, 2; green 20, 1, 2; blue 30, 1, 2),
    // green stored less red's residual, blue less green's.
    let (red, green, blue) = ([10, 1, 2], [10, 0, 0], [10, 0, 0]);
    // u: prediction of u (0, then 80 and 80) + floor(3/4 · TSDF residual (90, 5, 10)):
    // 67, 83, 87; residuals 13, 14, −27; zigzag 26, 28, 53.
    let u_lo = [26, 28, 53];
    let mut weights = vec![0u8; 512];
    for i in [1, 2, 9] {
        weights[i] = OMEGA_BIT | i as u8;
    }
    let parts: Vec<Vec<u8>> = vec![
        vec![1, 2, 3],
        vec![1],
        weights,
        tsdf_lo.to_vec(),
        vec![0; 3],
        red.to_vec(),
        green.to_vec(),
        blue.to_vec(),
        u_lo.to_vec(),
        vec![0; 3],
    ];
    let raw: Vec<u8> = parts.concat();
    assert_eq!(raw.len(), 516 + 5 * 3 + 2 * 3);
    let h = decode_header_with_origin(&file).expect("header").0;
    assert_eq!(h.payload_raw_bytes as usize, raw.len());
    // The payload is one zstd frame per part, in order: the low bytes of the TSDF and of u at the
    // level asked for (3), the other parts at level 15.
    let frames: Vec<u8> = parts
        .iter()
        .enumerate()
        .flat_map(|(k, p)| {
            let level = if k == 3 || k == 8 { 3 } else { 15 };
            zstd::bulk::compress(p, level).expect("zstd")
        })
        .collect();
    assert_eq!(&file[CHUNK_HEADER_V2_BYTES..], &frames[..]);
    let back = zstd::bulk::decompress(&file[CHUNK_HEADER_V2_BYTES..], raw.len()).expect("zstd");
    assert_eq!(back, raw);
    assert_round_trip(&file, &blocks);
}

#[test]
fn v3_round_trips_edge_cases_bit_for_bit() {
    let c = ChunkIndex([3, -1, 0]);
    let o = c.origin_block(4);
    let at = |x: i32, y: i32, z: i32| BlockIndex([o[0] + x, o[1] + y, o[2] + z]);
    // An empty chunk.
    let empty = v3(&header(c), &[]);
    assert_round_trip(&empty, &[]);
    // Every voxel observed, with and without u; extreme and wrapping values; a dense block
    // (empty voxels off their defaults); a block with one voxel; saturated colours.
    let mut extreme = Block::new_boxed();
    let mut u = Box::new(extreme.tsdf);
    for i in 0..VOXELS_PER_BLOCK {
        extreme.tsdf[i] = if i % 2 == 0 { i16::MIN } else { i16::MAX };
        extreme.weight_omega[i] = 0xFF;
        extreme.color[i] = if i % 3 == 0 {
            [255, 0, 255]
        } else {
            [0, 255, 0]
        };
        u[i] = if i % 5 == 0 { i16::MAX } else { i16::MIN };
    }
    extreme.regularized = Some(u);
    let mut dense = random_block(5, 3, true, false);
    dense.tsdf[0] = -7;
    dense.color[511] = [1, 2, 3];
    let mut one = Block::new_boxed();
    one.tsdf[511] = -32768;
    one.weight_omega[511] = 1;
    one.color[511] = [255, 255, 255];
    let blocks = vec![
        (at(0, 0, 0), random_block(1, 8, true, false)),
        (at(3, 3, 3), random_block(2, 8, false, false)),
        (at(1, 0, 2), extreme),
        (at(2, 2, 2), dense),
        (at(0, 3, 1), one),
        (at(1, 1, 1), random_block(3, 8, true, true)),
        (at(2, 1, 0), Block::new_boxed()),
    ];
    let file = v3(&header(c), &blocks);
    assert_round_trip(&file, &blocks);
    // Format 2 of the same blocks decodes to the same blocks; formats 1 and 2 are still read.
    let refs: Vec<(BlockIndex, &Block)> = blocks.iter().map(|(i, b)| (*i, &**b)).collect();
    let d2 = decode_chunk(&encode_chunk_with(&header(c), Some(&origin()), &refs, 3)).expect("v2");
    let d1 = decode_chunk(&encode_chunk(&header(c), &refs, 3)).expect("v1");
    let d3 = decode_chunk(&file).expect("v3");
    assert!(d2.blocks == d3.blocks && d1.blocks == d3.blocks);
}

/// A surface crossing the chunk along z: a TSDF slope (continuous across blocks; `at` is the
/// block's place in the chunk) with noise of ±16, grey colour varying slowly, `u` the noise-free
/// slope; voxels observed with probability 3/4.
fn smooth_block(seed: u64, at: [i16; 3]) -> Box<Block> {
    let mut b = Block::new_boxed();
    let mut u = Box::new(b.tsdf);
    let mut s = seed | 1;
    for i in 0..VOXELS_PER_BLOCK {
        s = s
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        if (s >> 60).is_multiple_of(4) {
            continue;
        }
        let (x, y, z) = (
            8 * at[0] + (i % 8) as i16,
            8 * at[1] + ((i / 8) % 8) as i16,
            8 * at[2] + (i / 64) as i16,
        );
        u[i] = 1000 * z - 300 * y + 150 * x - 9000;
        b.tsdf[i] = u[i] + ((s >> 20) % 32) as i16 - 16;
        b.weight_omega[i] = OMEGA_BIT | 20;
        let grey = (60 + 3 * x + 2 * y) as u8;
        b.color[i] = [grey; 3];
    }
    b.regularized = Some(u);
    b
}

#[test]
fn v3_is_smaller_than_v2_on_smooth_fields() {
    let c = ChunkIndex([0, 0, 0]);
    let blocks: Vec<(BlockIndex, Box<Block>)> = (0..32)
        .map(|k| {
            let at = [k % 4, k / 4 % 4, k / 16];
            let b = smooth_block(10 + k as u64, at.map(|c| c as i16));
            (BlockIndex(at), b)
        })
        .collect();
    let refs: Vec<(BlockIndex, &Block)> = blocks.iter().map(|(i, b)| (*i, &**b)).collect();
    let v2 = encode_chunk_with(&header(c), Some(&origin()), &refs, 3);
    let v3 = v3(&header(c), &blocks);
    assert!(
        (v3.len() as f64) < 0.9 * v2.len() as f64,
        "format 3 {} bytes, format 2 {}",
        v3.len(),
        v2.len()
    );
    assert_round_trip(&v3, &blocks);
}

#[test]
fn v3_every_truncation_and_flipped_byte_is_rejected() {
    let c = ChunkIndex([0, 1, 0]);
    let blocks = vec![
        (BlockIndex([0, 4, 0]), random_block(7, 4, true, false)),
        (BlockIndex([1, 5, 2]), random_block(8, 2, false, false)),
    ];
    let file = v3(&header(c), &blocks);
    for len in 0..file.len() {
        assert!(decode_chunk(&file[..len]).is_err(), "truncated to {len}");
    }
    for at in 0..file.len() {
        let mut b = file.clone();
        b[at] ^= 0x04;
        assert!(decode_chunk(&b).is_err(), "flipped byte {at} accepted");
    }
    // A raw length that disagrees with the weights (CRCs recomputed) is named, not a panic.
    let (mut h, o) = decode_header_with_origin(&file).expect("header");
    h.payload_raw_bytes -= 1;
    let mut b = encode_header_v3(&h, &o.expect("origin")).to_vec();
    b.extend_from_slice(&file[CHUNK_HEADER_V2_BYTES..]);
    let e = decode_chunk(&b)
        .err()
        .expect("short raw length")
        .to_string();
    assert!(e.contains("malformed"), "{e}");
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]

    /// Arbitrary payloads behind a valid format-3 header (as a zstd frame, and raw) never panic
    /// the decoder: they are refused or decoded.
    #[test]
    fn v3_decoder_never_panics(data in proptest::collection::vec(any::<u8>(), 0..3000), blocks in 0u32..5) {
        let z = zstd::bulk::compress(&data, 1).expect("zstd");
        for body in [&z[..], &data[..]] {
            let h = ChunkHeader { block_count: blocks, payload_raw_bytes: data.len() as u32,
                payload_zstd_bytes: body.len() as u32, payload_crc32: crc32fast::hash(body),
                ..header(ChunkIndex([0, 0, 0])) };
            let mut b = encode_header_v3(&h, &origin()).to_vec();
            b.extend_from_slice(body);
            let _ = decode_chunk(&b);
        }
    }

    /// A well-formed format-3 payload of one block with arbitrary weights, flags and residuals
    /// decodes without panicking, to a block with those weights.
    #[test]
    fn v3_arbitrary_residuals_decode(weights in proptest::collection::vec(any::<u8>(), 512), flag in 0u8..4,
                                     seed in any::<u64>()) {
        let k = if flag & 2 != 0 { 512 } else { weights.iter().filter(|w| **w != 0).count() };
        let k_u = if flag & 1 != 0 { k } else { 0 };
        let mut raw = vec![1, 2, 3, flag];
        raw.extend_from_slice(&weights);
        let mut s = seed;
        raw.extend((0..5 * k + 2 * k_u).map(|_| {
            s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            (s >> 56) as u8
        }));
        let z = zstd::bulk::compress(&raw, 1).expect("zstd");
        let h = ChunkHeader { block_count: 1, flags: (flag & 1) as u16, payload_raw_bytes: raw.len() as u32,
            payload_zstd_bytes: z.len() as u32, payload_crc32: crc32fast::hash(&z), ..header(ChunkIndex([0, 0, 0])) };
        let mut b = encode_header_v3(&h, &origin()).to_vec();
        b.extend_from_slice(&z);
        let d = decode_chunk(&b).expect("a well-formed payload decodes");
        prop_assert_eq!(&d.blocks[0].1.weight_omega[..], &weights[..]);
        prop_assert_eq!(d.blocks[0].1.regularized.is_some(), flag & 1 != 0);
    }

    /// Random blocks (any fill, with or without u, smooth or arbitrary values) round-trip bit
    /// for bit in format 3.
    #[test]
    fn v3_random_chunks_round_trip(places in proptest::collection::btree_set((0i32..4, 0i32..4, 0i32..4), 0..5),
                                   seed in any::<u64>(), fill in 0u64..9, wild in any::<bool>()) {
        let c = ChunkIndex([-2, 0, 1]);
        let o = c.origin_block(4);
        let blocks: Vec<(BlockIndex, Box<Block>)> = places.iter().enumerate()
            .map(|(k, (x, y, z))| (BlockIndex([o[0] + x, o[1] + y, o[2] + z]),
                                   random_block(seed ^ (k as u64 * 0x9E37_79B9), fill, k % 2 == 0, wild)))
            .collect();
        assert_round_trip(&v3(&header(c), &blocks), &blocks);
    }
}

#[test]
fn v3_predicts_across_blocks() {
    // Block A at local (0, 0, 0) codes voxels 6 and 7 of its first row, block B at (1, 0, 0) its
    // voxel 0: B's prediction is the linear extrapolation 2 · A7 − A6 along x.
    let (mut a, mut b) = (Block::new_boxed(), Block::new_boxed());
    (a.tsdf[6], a.tsdf[7], b.tsdf[0]) = (100, 200, 310);
    (a.weight_omega[6], a.weight_omega[7], b.weight_omega[0]) = (1, 1, 1);
    let blocks = vec![(BlockIndex([1, 0, 0]), b), (BlockIndex([0, 0, 0]), a)];
    let file = v3(&header(ChunkIndex([0, 0, 0])), &blocks);
    let h = decode_header_with_origin(&file).expect("header").0;
    let raw = zstd::bulk::decompress(&file[CHUNK_HEADER_V2_BYTES..], h.payload_raw_bytes as usize)
        .expect("zstd");
    let t = 6 + 2 + 1024;
    // A6: nothing before it, residual 100; A7: its x neighbour, 200 − 100; B0: 310 − (2·200 − 100).
    assert_eq!(&raw[t..t + 6], &[200, 200, 20, 0, 0, 0]);
    assert_round_trip(&file, &blocks);
}

/// A chunk rewritten with `u` added (what a regularization pass writes) copies the unchanged
/// parts' frames from the file it replaces: the result is byte for byte the fresh encoding, and
/// frames of another chunk's file, or of a format-2 file, are never taken for parts they do not
/// hold.
#[test]
fn rewrite_reuses_the_frames_of_unchanged_parts() {
    let h = header(ChunkIndex([1, -2, 0]));
    let first = h.chunk.origin_block(h.chunk_blocks);
    let at = |k: i32| BlockIndex([first[0] + k % 4, first[1] + k / 4 % 4, first[2] + k / 16]);
    let fused: Vec<(BlockIndex, Box<Block>)> = (0..40)
        .map(|k| (at(k), random_block(k as u64 * 7 + 1, 5, false, false)))
        .collect();
    let regularized: Vec<(BlockIndex, Box<Block>)> = fused
        .iter()
        .enumerate()
        .map(|(k, (i, b))| {
            let mut b = b.clone();
            let with_u = random_block(k as u64 * 7 + 1, 5, true, false);
            b.regularized = with_u.regularized.clone();
            (*i, b)
        })
        .collect();
    let refs: Vec<(BlockIndex, &Block)> = regularized.iter().map(|(i, b)| (*i, &**b)).collect();
    let old = v3(&h, &fused);
    let fresh = encode_chunk_v3(&h, &origin(), &refs, 3);
    let frames = PreviousFrames::of(&old);
    // Coordinates, flags, weights, TSDF low/high, red, green, blue.
    assert_eq!(frames.len(), 8, "one frame per non-empty part");
    let reused = encode_chunk_v3_reusing(&h, &origin(), &refs, 3, &frames);
    assert_eq!(reused, fresh, "byte-identical to the fresh encoding");
    assert_round_trip(&reused, &regularized);

    // Another chunk's file: only parts that are equal byte for byte could be taken.
    let other: Vec<(BlockIndex, Box<Block>)> = (0..40)
        .map(|k| (at(k), random_block(k as u64 * 11 + 5, 3, false, false)))
        .collect();
    let other_file = v3(&h, &other);
    let r = encode_chunk_v3_reusing(&h, &origin(), &refs, 3, &PreviousFrames::of(&other_file));
    assert_round_trip(&r, &regularized);
    // A format-2 file, truncated bytes, garbage: nothing to reuse.
    let f2 = encode_chunk_with(&h, Some(&origin()), &refs, 3);
    assert!(PreviousFrames::of(&f2).is_empty());
    assert!(PreviousFrames::of(&old[..old.len() - 5]).is_empty());
    assert!(PreviousFrames::of(b"not a chunk").is_empty());
}

/// Format 4 (issue 36): format 3 with the commit generation at bytes 96..104. Same payload bytes
/// as format 3, the header differs only in the version and those eight bytes; decoding returns
/// the generation; a non-zero byte in the rest of the reserved range is refused; a format-3 file
/// reads as generation 0; a format-4 file's frames are reused like a format-3 file's.
#[test]
fn format_4_carries_the_commit_generation() {
    let h = header(ChunkIndex([1, -2, 3]));
    let first = h.chunk.origin_block(h.chunk_blocks);
    let at = |k: i32| BlockIndex([first[0] + k % 4, first[1] + k / 4 % 4, first[2] + k / 16]);
    let blocks: Vec<(BlockIndex, Box<Block>)> = (0..12)
        .map(|k| (at(k), random_block(k as u64 * 3 + 2, 4, k % 2 == 0, false)))
        .collect();
    let refs: Vec<(BlockIndex, &Block)> = blocks.iter().map(|(i, b)| (*i, &**b)).collect();
    let o4 = ChunkOrigin {
        commit_gen: 0x0102_0304_0506_0708,
        ..origin()
    };
    let f4 = encode_chunk_v4_reusing(&h, &o4, &refs, 3, &PreviousFrames::default());
    let f3 = encode_chunk_v3(&h, &origin(), &refs, 3);
    assert_eq!(&f4[8..10], &[4, 0]);
    assert_eq!(&f4[96..104], &0x0102_0304_0506_0708u64.to_le_bytes());
    assert!(f4[104..124].iter().all(|b| *b == 0));
    assert_eq!(
        f4[CHUNK_HEADER_V2_BYTES..],
        f3[CHUNK_HEADER_V2_BYTES..],
        "same payload"
    );
    for k in (0..124).filter(|k| !(8..10).contains(k) && !(96..104).contains(k)) {
        assert_eq!(f4[k], f3[k], "header byte {k}");
    }
    let d = decode_chunk(&f4).expect("decode");
    assert_eq!(d.origin, Some(o4));
    assert!(
        d.blocks == decode_chunk(&f3).expect("v3").blocks,
        "same blocks"
    );
    assert_round_trip(&f3, &blocks);
    assert_eq!(
        decode_chunk(&f3)
            .expect("v3")
            .origin
            .expect("origin")
            .commit_gen,
        0
    );
    let mut bad = f4.clone();
    bad[110] = 1;
    let crc = crc32fast::hash(&bad[0..124]);
    bad[124..128].copy_from_slice(&crc.to_le_bytes());
    let e = decode_header_with_origin(&bad).unwrap_err().to_string();
    assert!(e.contains("reserved") && e.contains("104..124"), "{e}");
    assert_eq!(PreviousFrames::of(&f4).len(), PreviousFrames::of(&f3).len());
}
