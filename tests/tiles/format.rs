//! Chunk and manifest formats (`formats/chunk.md`, `formats/manifest.md`): round trips, golden
//! bytes from the spec tables, every truncation and every flipped byte rejected, arbitrary bytes
//! never panicking the decoders, and the store's crash-safety rules (orphans after a kill,
//! corrupted chunks reported by file name).

use denser::grid::{encode_tsdf, Block, BlockIndex, GridParams, OMEGA_BIT, VOXELS_PER_BLOCK};
use denser::map::codec::{
    decode_chunk, decode_header, decode_header_with_origin, encode_chunk, encode_chunk_with,
    encode_header, encode_header_v2, ChunkHeader, ChunkOrigin, CodecError, CHUNK_HEADER_BYTES,
    CHUNK_HEADER_V2_BYTES,
};
use denser::map::layout::CHUNKS_DIR;
use denser::map::manifest::{
    decode_manifest, encode_manifest, ChunkEntry, Manifest, ManifestHeader, MANIFEST_HEADER_BYTES,
};
use denser::map::store::MapStore;
use denser::map::ChunkIndex;
use denser::regularize::TvParams;
use proptest::prelude::*;

fn header(chunk: ChunkIndex, chunk_blocks: u32) -> ChunkHeader {
    ChunkHeader {
        voxel_size_m: 0.1,
        truncation_m: 1.0,
        chunk,
        chunk_blocks,
        block_count: 0,
        flags: 0,
        payload_raw_bytes: 0,
        payload_zstd_bytes: 0,
        payload_crc32: 0,
    }
}

/// A block like fusion makes: a plane at depth `z0` voxels, observed where `x < obs_x`.
fn plane_block(z0: f32, obs_x: usize, regularized: bool, seed: u64) -> Box<Block> {
    let mut b = Block::new_boxed();
    let mut s = seed;
    for i in 0..VOXELS_PER_BLOCK {
        let (x, z) = (i % 8, i / 64);
        if x < obs_x {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            let noise = ((s >> 40) as f32 / (1u64 << 24) as f32 - 0.5) * 0.05;
            b.tsdf[i] = encode_tsdf(((z as f32 - z0) / 10.0 + noise).clamp(-1.0, 1.0));
            b.weight_omega[i] = OMEGA_BIT | (1 + (s % 20) as u8);
            b.color[i] = [(s >> 8) as u8, (s >> 16) as u8, 200];
        }
    }
    if regularized {
        let mut u = Box::new(b.tsdf);
        for (i, v) in u.iter_mut().enumerate() {
            if i % 8 < obs_x {
                *v = v.saturating_add(((i * 7) % 31) as i16 - 15);
            }
        }
        b.regularized = Some(u);
    }
    b
}

fn sample_chunk() -> (ChunkHeader, Vec<(BlockIndex, Box<Block>)>) {
    let c = ChunkIndex([-1, 0, 2]);
    let h = header(c, 4);
    let o = c.origin_block(4);
    let blocks = vec![
        (
            BlockIndex([o[0] + 3, o[1], o[2] + 1]),
            plane_block(3.0, 8, true, 1),
        ),
        (
            BlockIndex([o[0], o[1] + 2, o[2]]),
            plane_block(5.5, 5, false, 2),
        ),
        (
            BlockIndex([o[0] + 1, o[1] + 3, o[2] + 3]),
            plane_block(0.5, 2, true, 3),
        ),
        (BlockIndex([o[0] + 2, o[1] + 1, o[2] + 1]), {
            // Dense: empty voxels off their defaults (kept exactly all the same).
            let mut b = plane_block(2.0, 4, true, 4);
            b.tsdf[7] = -5;
            b.color[63] = [1, 2, 3];
            b
        }),
    ];
    (h, blocks)
}

fn encode(h: &ChunkHeader, blocks: &[(BlockIndex, Box<Block>)]) -> Vec<u8> {
    let refs: Vec<(BlockIndex, &Block)> = blocks.iter().map(|(i, b)| (*i, &**b)).collect();
    encode_chunk(h, &refs, 3)
}

#[test]
fn chunk_round_trip_is_exact_and_sorted() {
    let (h, blocks) = sample_chunk();
    let bytes = encode(&h, &blocks);
    let d = decode_chunk(&bytes).expect("decode");
    assert_eq!(d.header.chunk, h.chunk);
    assert_eq!(d.header.block_count, 4);
    assert_eq!(d.header.flags, 1, "has regularized blocks");
    let mut want = blocks.clone();
    want.sort_by_key(|(i, _)| *i);
    assert_eq!(d.blocks.len(), 4);
    for ((a, ba), (b, bb)) in d.blocks.iter().zip(&want) {
        assert_eq!(a, b);
        assert!(**ba == **bb, "block {a:?} differs after the round trip");
    }
    // An empty chunk is valid too.
    let e = decode_chunk(&encode(&h, &[])).expect("empty");
    assert!(e.blocks.is_empty());
}

#[test]
fn chunk_header_golden_bytes() {
    // The table of formats/chunk.md, byte by byte.
    let h = ChunkHeader {
        voxel_size_m: 0.1,
        truncation_m: 1.0,
        chunk: ChunkIndex([-1, 2, 3]),
        chunk_blocks: 16,
        block_count: 5,
        flags: 1,
        payload_raw_bytes: 0x4414, // within 5·516 ..= 5·516 + 2560·7 for 5 blocks
        payload_zstd_bytes: 0x0000_6789,
        payload_crc32: 0xDEAD_BEEF,
    };
    let b = encode_header(&h);
    let mut want = Vec::new();
    want.extend_from_slice(b"DNSRCHNK"); // 0: magic
    want.extend_from_slice(&[1, 0]); // 8: version 1
    want.extend_from_slice(&[1, 0]); // 10: flags
    want.extend_from_slice(&[64, 0, 0, 0]); // 12: header length
    want.extend_from_slice(&[0xCD, 0xCC, 0xCC, 0x3D]); // 16: 0.1f32
    want.extend_from_slice(&[0x00, 0x00, 0x80, 0x3F]); // 20: 1.0f32
    want.extend_from_slice(&[0xFF, 0xFF, 0xFF, 0xFF]); // 24: chunk x = -1
    want.extend_from_slice(&[2, 0, 0, 0]); // 28: chunk y
    want.extend_from_slice(&[3, 0, 0, 0]); // 32: chunk z
    want.extend_from_slice(&[16, 0, 0, 0]); // 36: chunk edge
    want.extend_from_slice(&[5, 0, 0, 0]); // 40: blocks
    want.extend_from_slice(&[0x14, 0x44, 0x00, 0x00]); // 44: raw payload bytes
    want.extend_from_slice(&[0x89, 0x67, 0x00, 0x00]); // 48: zstd payload bytes
    want.extend_from_slice(&[0xEF, 0xBE, 0xAD, 0xDE]); // 52: payload CRC
    want.extend_from_slice(&[0, 0, 0, 0]); // 56: reserved
    assert_eq!(&b[..60], &want[..]);
    // 60: CRC-32 (IEEE) of bytes 0..60.
    assert_eq!(&b[60..64], &crc32fast::hash(&want).to_le_bytes());
    assert_eq!(decode_header(&b).expect("decode"), h);
}

#[test]
fn chunk_header_v2_golden_bytes() {
    // The version-2 table of formats/chunk.md: bytes 0..56 as in version 1, then the origin.
    let h = ChunkHeader {
        voxel_size_m: 0.1,
        truncation_m: 1.0,
        chunk: ChunkIndex([-1, 2, 3]),
        chunk_blocks: 16,
        block_count: 5,
        flags: 1,
        payload_raw_bytes: 0x4414,
        payload_zstd_bytes: 0x0000_6789,
        payload_crc32: 0xDEAD_BEEF,
    };
    let o = ChunkOrigin {
        map_id: 0x1122_3344_5566_7788,
        file_seq: 0x0102_0304_0506,
        reg_pass: 3,
        reg_params: TvParams {
            lambda: 0.7,
            ..TvParams::paper(0.1)
        },
        commit_gen: 0,
    };
    let b = encode_header_v2(&h, &o);
    assert_eq!(b.len(), CHUNK_HEADER_V2_BYTES);
    let v1 = encode_header(&h);
    assert_eq!(&b[0..8], &v1[0..8], "magic");
    assert_eq!(
        &b[8..16],
        &[2, 0, 1, 0, 128, 0, 0, 0],
        "version 2, flags, length"
    );
    assert_eq!(
        &b[16..56],
        &v1[16..56],
        "grid, chunk, counts, payload: as version 1"
    );
    assert_eq!(
        &b[56..64],
        &0x1122_3344_5566_7788u64.to_le_bytes(),
        "map id"
    );
    assert_eq!(
        &b[64..72],
        &0x0102_0304_0506u64.to_le_bytes(),
        "file number"
    );
    assert_eq!(
        &b[72..80],
        &[3, 0, 0, 0, 100, 0, 0, 0],
        "pass 3, 100 iterations"
    );
    assert_eq!(&b[80..84], &0.7f32.to_le_bytes(), "λ");
    assert_eq!(&b[84..88], &0.5f32.to_le_bytes(), "σ");
    assert_eq!(&b[88..92], &(1.0f32 / 6.0).to_le_bytes(), "τ");
    assert_eq!(&b[92..96], &1.0f32.to_le_bytes(), "θ");
    assert!(b[96..124].iter().all(|x| *x == 0), "reserved");
    assert_eq!(&b[124..128], &crc32fast::hash(&b[0..124]).to_le_bytes());
    assert_eq!(decode_header_with_origin(&b).expect("decode"), (h, Some(o)));
    assert_eq!(decode_header(&b).expect("decode"), h);
    // A whole version-2 file round-trips, origin included, and every flipped byte and every
    // truncation is rejected.
    let (h, blocks) = sample_chunk();
    let refs: Vec<(BlockIndex, &Block)> = blocks.iter().map(|(i, b)| (*i, &**b)).collect();
    let file = encode_chunk_with(&h, Some(&o), &refs, 3);
    let v1_file = encode_chunk(&h, &refs, 3);
    assert_eq!(
        file.len(),
        v1_file.len() + 64,
        "the same payload behind a longer header"
    );
    assert_eq!(&file[128..], &v1_file[64..]);
    let d = decode_chunk(&file).expect("decode");
    assert_eq!(d.origin, Some(o));
    assert_eq!(d.blocks.len(), blocks.len());
    for at in 0..CHUNK_HEADER_V2_BYTES {
        let mut c = file.clone();
        c[at] ^= 0x10;
        assert!(
            decode_chunk(&c).is_err(),
            "flipped header byte {at} accepted"
        );
    }
    for len in [0, 10, 64, 127, 128, file.len() - 1] {
        assert!(decode_chunk(&file[..len]).is_err(), "truncated to {len}");
    }
}

#[test]
fn chunk_payload_golden_layout() {
    // One block at local (1, 2, 3) of chunk (0,0,0), edge 4, with two observed voxels: only they
    // carry TSDF and colour (the columns of formats/chunk.md).
    let mut b = Block::new_boxed();
    b.tsdf[1] = 90;
    b.tsdf[2] = 95;
    b.weight_omega[1] = OMEGA_BIT | 3;
    b.weight_omega[2] = OMEGA_BIT | 5;
    b.color[1] = [10, 20, 30];
    b.color[2] = [11, 21, 31];
    let raw = payload_of(vec![(BlockIndex([1, 2, 3]), b.clone())]);
    assert_eq!(&raw[0..3], &[1, 2, 3], "local block coordinates");
    assert_eq!(raw[3], 0, "block flags: sparse, no u");
    let w = 4;
    assert_eq!(
        (raw[w], raw[w + 1], raw[w + 2]),
        (0, 0x83, 0x85),
        "weights with Ω"
    );
    let t = w + 512; // TSDF of the 2 coded voxels: low bytes, then high bytes
    assert_eq!(
        &raw[t..t + 4],
        &[180, 10, 0, 0],
        "zigzag(90) = 180, zigzag(95 − 90) = 10"
    );
    let c = t + 4; // colour planes R, G, B over the coded voxels
    assert_eq!(&raw[c..c + 6], &[10, 11, 20, 21, 30, 31]);
    assert_eq!(raw.len(), c + 6);

    // An empty voxel that is not at its defaults makes the block dense: all 512 voxels coded.
    b.tsdf[0] = 100;
    let raw = payload_of(vec![(BlockIndex([1, 2, 3]), b)]);
    assert_eq!(raw[3], 2, "block flags: dense");
    let t = 4 + 512;
    assert_eq!(
        (raw[t], raw[t + 1]),
        (200, 19),
        "zigzag(100), zigzag(90 − 100)"
    );
    assert_eq!(raw[t + 2], 10);
    assert_eq!(raw[t + 3], (zig(32767 - 95) & 0xff) as u8);
    assert_eq!(raw[t + 512 + 3], (zig(32767 - 95) >> 8) as u8);
    assert_eq!(raw.len(), 4 + 512 + 512 * 5);
}

fn payload_of(blocks: Vec<(BlockIndex, Box<Block>)>) -> Vec<u8> {
    let bytes = encode(&header(ChunkIndex([0, 0, 0]), 4), &blocks);
    let h = decode_header(&bytes).expect("header");
    zstd::bulk::decompress(&bytes[CHUNK_HEADER_BYTES..], h.payload_raw_bytes as usize)
        .expect("zstd")
}

fn zig(d: i32) -> u32 {
    let d = d as i16;
    ((d << 1) ^ (d >> 15)) as u16 as u32
}

#[test]
fn every_truncation_and_every_flipped_byte_is_rejected() {
    let (h, blocks) = sample_chunk();
    let bytes = encode(&h, &blocks);
    for len in 0..bytes.len() {
        assert!(
            decode_chunk(&bytes[..len]).is_err(),
            "truncated to {len} bytes was accepted"
        );
    }
    let mut extra = bytes.clone();
    extra.push(0);
    assert!(decode_chunk(&extra).is_err(), "trailing byte accepted");
    for at in 0..bytes.len() {
        for bit in [0u8, 3, 7] {
            let mut b = bytes.clone();
            b[at] ^= 1 << bit;
            assert!(
                decode_chunk(&b).is_err(),
                "flipping bit {bit} of byte {at} went unnoticed"
            );
        }
    }
}

#[test]
fn chunk_errors_are_specific() {
    let (h, blocks) = sample_chunk();
    let bytes = encode(&h, &blocks);
    let mut b = bytes.clone();
    b[0] = b'X';
    assert_eq!(decode_chunk(&b).err(), Some(CodecError::BadMagic));
    let mut b = bytes.clone();
    b[8] = 9; // version 9, header CRC recomputed so that the version is what fails
    let crc = crc32fast::hash(&b[..60]);
    b[60..64].copy_from_slice(&crc.to_le_bytes());
    assert_eq!(
        decode_chunk(&b).err(),
        Some(CodecError::UnsupportedVersion { found: 9 })
    );
    let mut b = bytes.clone();
    let last = b.len() - 1;
    b[last] ^= 0x40;
    assert!(matches!(
        decode_chunk(&b),
        Err(CodecError::PayloadChecksum { .. })
    ));
    assert!(matches!(
        decode_chunk(&bytes[..40]),
        Err(CodecError::Truncated(_))
    ));
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(300))]

    /// Arbitrary bytes, and arbitrary bytes behind a valid header, never panic the decoder.
    #[test]
    fn decoder_never_panics(data in proptest::collection::vec(any::<u8>(), 0..400), blocks in 0u32..5, raw in 0u32..4000) {
        let _ = decode_chunk(&data);
        let h = ChunkHeader { block_count: blocks, payload_raw_bytes: raw, payload_zstd_bytes: data.len() as u32,
            payload_crc32: crc32fast::hash(&data), ..header(ChunkIndex([0, 0, 0]), 2) };
        let mut b = encode_header(&h).to_vec();
        b.extend_from_slice(&data);
        let _ = decode_chunk(&b);
        // A valid zstd frame of arbitrary content behind a valid header.
        let z = zstd::bulk::compress(&data, 1).expect("zstd");
        let h = ChunkHeader { payload_raw_bytes: data.len() as u32, payload_zstd_bytes: z.len() as u32,
            payload_crc32: crc32fast::hash(&z), ..h };
        let mut b = encode_header(&h).to_vec();
        b.extend_from_slice(&z);
        let _ = decode_chunk(&b);
        let o = ChunkOrigin { map_id: 7, file_seq: 9, reg_pass: 1, reg_params: TvParams::paper(0.1), commit_gen: 0 };
        let mut b = encode_header_v2(&h, &o).to_vec();
        b.extend_from_slice(&z);
        let _ = decode_chunk(&b);
        let _ = decode_manifest(&data);
    }

    /// Random blocks at random places of a chunk round-trip exactly.
    #[test]
    fn random_chunks_round_trip(places in proptest::collection::btree_set((0i32..4, 0i32..4, 0i32..4), 0..6),
                                seed in any::<u64>(), obs in 0usize..9) {
        let c = ChunkIndex([2, -3, 0]);
        let o = c.origin_block(4);
        let blocks: Vec<(BlockIndex, Box<Block>)> = places.iter().enumerate()
            .map(|(k, (x, y, z))| (BlockIndex([o[0] + x, o[1] + y, o[2] + z]), plane_block(k as f32, obs, k % 2 == 0, seed ^ k as u64)))
            .collect();
        let d = decode_chunk(&encode(&header(c, 4), &blocks)).expect("decode");
        prop_assert_eq!(d.blocks.len(), blocks.len());
        for ((a, ba), (b, bb)) in d.blocks.iter().zip(blocks.iter()) {
            prop_assert_eq!(a, b);
            prop_assert!(**ba == **bb);
        }
    }
}

fn sample_manifest() -> Manifest {
    let mut chunks = std::collections::BTreeMap::new();
    chunks.insert(
        ChunkIndex([-2, 0, 1]),
        ChunkEntry {
            block_count: 7,
            observed_voxels: 1234,
            flags: 1,
            file_seq: 3,
            file_bytes: 999,
            payload_crc32: 0xABCD_0123,
            reg_pass: 2,
        },
    );
    chunks.insert(
        ChunkIndex([0, 0, 0]),
        ChunkEntry {
            block_count: 1,
            observed_voxels: 5,
            flags: 0,
            file_seq: 4,
            file_bytes: 100,
            payload_crc32: 7,
            reg_pass: 0,
        },
    );
    Manifest {
        header: ManifestHeader {
            voxel_size_m: 0.1,
            truncation_m: 1.0,
            chunk_blocks: 16,
            generation: 9,
            frames_committed: 250,
            next_file_seq: 5,
            reg_pass: 2,
            reg_params: TvParams::paper(0.1),
            complete_pass: 1,
            complete_params: TvParams {
                lambda: 0.5,
                ..TvParams::paper(0.1)
            },
            map_id: 0x0123_4567_89AB_CDEF,
        },
        chunks,
        kept: [(
            ChunkIndex([-2, 0, 1]),
            ChunkEntry {
                block_count: 7,
                observed_voxels: 1230,
                flags: 1,
                file_seq: 2,
                file_bytes: 990,
                payload_crc32: 0x1111_2222,
                reg_pass: 1,
            },
        )]
        .into(),
    }
}

#[test]
fn manifest_round_trip_and_golden_bytes() {
    let m = sample_manifest();
    let b = encode_manifest(&m);
    assert_eq!(b.len(), MANIFEST_HEADER_BYTES + (2 + 1) * 48 + 4);
    assert_eq!(&b[0..8], b"DNSRMANI");
    assert_eq!(&b[8..16], &[2, 0, 0, 0, 128, 0, 0, 0]);
    assert_eq!(
        &b[24..32],
        &[16, 0, 0, 0, 2, 0, 0, 0],
        "chunk edge, entry count"
    );
    assert_eq!(&b[32..40], &9u64.to_le_bytes(), "generation");
    assert_eq!(&b[40..48], &250u64.to_le_bytes(), "frames committed");
    assert_eq!(
        &b[56..64],
        &[2, 0, 0, 0, 100, 0, 0, 0],
        "pass 2, 100 iterations"
    );
    assert_eq!(&b[64..68], &0.8f32.to_le_bytes(), "λ");
    assert_eq!(
        &b[80..88],
        &[1, 0, 0, 0, 100, 0, 0, 0],
        "complete pass 1, 100 iterations"
    );
    assert_eq!(&b[88..92], &0.5f32.to_le_bytes(), "complete pass λ");
    assert_eq!(
        &b[104..112],
        &0x0123_4567_89AB_CDEFu64.to_le_bytes(),
        "map id"
    );
    assert_eq!(&b[112..116], &1u32.to_le_bytes(), "kept entries");
    assert!(b[116..124].iter().all(|x| *x == 0), "reserved");
    // First entry: chunk (-2, 0, 1), sorted before (0, 0, 0).
    let e = MANIFEST_HEADER_BYTES;
    assert_eq!(
        &b[e..e + 12],
        &[0xFE, 0xFF, 0xFF, 0xFF, 0, 0, 0, 0, 1, 0, 0, 0]
    );
    assert_eq!(
        &b[e + 24..e + 32],
        &3u64.to_le_bytes(),
        "file sequence number"
    );
    // The kept table follows the entries, in the same 48-byte layout.
    let k = MANIFEST_HEADER_BYTES + 2 * 48;
    assert_eq!(
        &b[k..k + 12],
        &b[e..e + 12],
        "kept file of chunk (-2, 0, 1)"
    );
    assert_eq!(&b[k + 24..k + 32], &2u64.to_le_bytes(), "its file number");
    assert_eq!(decode_manifest(&b).expect("decode"), m);
    for at in 0..b.len() {
        let mut c = b.clone();
        c[at] ^= 0x10;
        assert!(decode_manifest(&c).is_err(), "flipped byte {at} accepted");
    }
    for len in 0..b.len() {
        assert!(decode_manifest(&b[..len]).is_err());
    }
}

fn grid() -> GridParams {
    GridParams {
        voxel_size_m: 0.1,
        truncation_m: 1.0,
    }
}

#[test]
fn store_commits_atomically_and_cleans_orphans() {
    let dir = tempfile::tempdir().expect("tempdir");
    let root = dir.path().join("map");
    let (_, blocks) = sample_chunk();
    let c = ChunkIndex([-1, 0, 2]);
    let refs: Vec<(BlockIndex, &Block)> = blocks.iter().map(|(i, b)| (*i, &**b)).collect();
    {
        let mut s = MapStore::create(&root, grid(), 4).expect("create");
        assert!(
            MapStore::create(&root, grid(), 4).is_err(),
            "a second create must refuse"
        );
        s.write_chunk(c, &refs, 0).expect("write");
        s.commit().expect("commit");
        // A second version written but never committed (the run is killed here) plus a stray
        // temporary file: neither may survive reopening, and the committed version must.
        s.write_chunk(c, &refs[..1], 0).expect("write v2");
        std::fs::write(
            root.join(CHUNKS_DIR).join("c_9_9_9_000000000099.tmp"),
            b"partial",
        )
        .expect("tmp");
    }
    let n_files = std::fs::read_dir(root.join(CHUNKS_DIR))
        .expect("ls")
        .count();
    assert_eq!(
        n_files, 3,
        "v1, v2 and the temporary file are on disk before reopening"
    );
    let s = MapStore::open(&root).expect("open");
    let names: Vec<String> = std::fs::read_dir(root.join(CHUNKS_DIR))
        .expect("ls")
        .map(|e| e.expect("entry").file_name().to_string_lossy().into_owned())
        .collect();
    assert_eq!(names.len(), 1, "orphans removed: {names:?}");
    let d = s.read_chunk(c).expect("read").expect("present");
    assert_eq!(d.blocks.len(), 4, "the committed version is the one read");
    assert!(s.verify().is_empty());
    let sum = s.summary();
    assert_eq!((sum.chunks, sum.blocks), (1, 4));
}

#[test]
fn corrupted_chunk_is_reported_by_name() {
    let dir = tempfile::tempdir().expect("tempdir");
    let root = dir.path().join("map");
    let (_, blocks) = sample_chunk();
    let c = ChunkIndex([-1, 0, 2]);
    let refs: Vec<(BlockIndex, &Block)> = blocks.iter().map(|(i, b)| (*i, &**b)).collect();
    let mut s = MapStore::create(&root, grid(), 4).expect("create");
    s.write_chunk(c, &refs, 0).expect("write");
    s.commit().expect("commit");
    let path = s.chunk_path(c).expect("path");
    let mut bytes = std::fs::read(&path).expect("read");
    let mid = bytes.len() / 2 + 20;
    bytes[mid] ^= 0x01;
    std::fs::write(&path, &bytes).expect("write");
    drop(s); // the writer closes the map (one writer per map)
    let s = MapStore::open_read_only(&root).expect("open");
    let err = s
        .read_chunk(c)
        .err()
        .expect("corruption must be an error")
        .to_string();
    let name = path
        .file_name()
        .expect("name")
        .to_string_lossy()
        .into_owned();
    assert!(err.contains(&name) && err.contains("checksum"), "{err}");
    let problems = s.verify();
    assert_eq!(problems.len(), 1);
    assert!(problems[0].contains(&name), "{problems:?}");
    // A missing manifest is named too (with the repair command: chunk files are there).
    std::fs::remove_file(root.join("manifest.dmf")).expect("rm");
    let err = MapStore::open(&root).expect_err("no manifest").to_string();
    assert!(
        err.contains("manifest.dmf") && err.contains("denser repair"),
        "{err}"
    );
}
