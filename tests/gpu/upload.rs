//! Uploads through kept staging memory (`src/gpu/upload.rs`): what a drive's writes put in a
//! buffer equals the same writes applied in order on the host (overlapping writes between two
//! submits, writes padded with zeros, a write larger than every chunk kept), and a drive of
//! frame-sized writes makes its chunks at the first write and none after.

use crate::common::{gpu, Rng};
use denser::gpu::upload::{kept_chunks, written_through_ring, TestWrite, FIRST_CHUNKS};

/// The writes applied in order to `size` zero bytes (the twin).
fn applied(size: u64, rounds: &[Vec<TestWrite>]) -> Vec<u8> {
    let mut out = vec![0u8; size as usize];
    for w in rounds.iter().flatten() {
        match w {
            TestWrite::At(at, bytes) => {
                let at = *at as usize;
                out[at..at + bytes.len()].copy_from_slice(bytes);
                out[at + bytes.len()..at + bytes.len().next_multiple_of(4)].fill(0);
            }
            TestWrite::Filled(bytes) => {
                out[..bytes.len()].copy_from_slice(bytes);
                let padded = bytes.len().max(4).next_multiple_of(4);
                out[bytes.len()..padded].fill(0);
            }
        }
    }
    out
}

fn random_bytes(rng: &mut Rng, n: usize) -> Vec<u8> {
    (0..n).map(|_| rng.next_u64() as u8).collect()
}

#[test]
fn writes_through_kept_staging_memory_land_in_the_order_written() {
    let Some(ctx) = gpu() else { return };
    let mut rng = Rng(34);
    let size: u64 = 3 << 20;
    // Rounds of one to six writes, overlapping within and across rounds: words of up to
    // 256 KiB at random offsets, and writes at the start of any length (padded with zeros).
    let mut rounds = Vec::new();
    for _ in 0..24 {
        let mut round = Vec::new();
        for _ in 0..1 + rng.next_u64() % 6 {
            let len = 4 * (1 + rng.next_u64() % (1 << 16)) as usize;
            if rng.next_u64().is_multiple_of(4) {
                let odd = len - (rng.next_u64() % 4) as usize;
                round.push(TestWrite::Filled(random_bytes(&mut rng, odd)));
            } else {
                let at = 4 * (rng.next_u64() % ((size - len as u64) / 4));
                round.push(TestWrite::At(at, random_bytes(&mut rng, len)));
            }
        }
        rounds.push(round);
    }
    // Nothing, and a write not a multiple of 4 bytes (padded with zeros, counted padded).
    rounds[5].push(TestWrite::At(8, Vec::new()));
    rounds[7].push(TestWrite::At(4096, random_bytes(&mut rng, 5)));
    let before = ctx.traffic();
    let got = written_through_ring(&ctx, size, &rounds, 3).expect("written");
    let t = ctx.traffic().since(before);
    let want = applied(size, &rounds);
    let differ = got.iter().zip(&want).filter(|(a, b)| a != b).count();
    assert_eq!(
        differ, 0,
        "{differ} bytes differ from the writes applied in order"
    );
    let sent: u64 = (rounds.iter().flatten())
        .map(|w| match w {
            TestWrite::At(_, b) => b.len().next_multiple_of(4) as u64,
            TestWrite::Filled(b) => b.len().max(4).next_multiple_of(4) as u64,
        })
        .sum();
    assert_eq!(t.upload_bytes, sent, "{t:?}");
    // The test's buffer, the chunks made at the first write, and the readback's staging.
    assert_eq!(t.buffers_created, 1 + FIRST_CHUNKS as u64 + 1, "{t:?}");

    // A write larger than all the chunks kept may be: a chunk of its own, not kept.
    let big: u64 = 80 << 20;
    let (chunks, kept) = kept_chunks(&ctx);
    let rounds = vec![
        vec![TestWrite::At(0, random_bytes(&mut rng, 1 << 20))],
        vec![
            TestWrite::At(4, random_bytes(&mut rng, big as usize - 8)),
            TestWrite::At(1 << 10, random_bytes(&mut rng, 4096)),
        ],
    ];
    let got = written_through_ring(&ctx, big, &rounds, 1).expect("written");
    assert!(got == applied(big, &rounds), "a write past the kept chunks");
    assert_eq!(
        kept_chunks(&ctx),
        (chunks, kept),
        "the large write's chunk not kept"
    );
}

#[test]
fn a_drive_of_frame_sized_writes_makes_its_chunks_at_the_first_write_only() {
    let Some(ctx) = gpu() else { return };
    let mut rng = Rng(35);
    // A 1241×376 frame's depths (f32) and colours (RGB, padded): 1.78 + 1.34 MiB, then a
    // small uniform; one submit a frame, collected three frames later (a counted wait every
    // third frame, as the readback ring makes a drive do).
    let (depth, colour) = (1241 * 376 * 4, (1241 * 376 * 3usize).next_multiple_of(4));
    let size = (depth + colour + 256) as u64;
    let frame = |rng: &mut Rng| {
        vec![
            TestWrite::At(0, random_bytes(rng, depth)),
            TestWrite::At(depth as u64, random_bytes(rng, colour)),
            TestWrite::At((depth + colour) as u64, random_bytes(rng, 64)),
        ]
    };
    let first: Vec<_> = (0..1).map(|_| frame(&mut rng)).collect();
    let before = ctx.traffic();
    written_through_ring(&ctx, size, &first, 3).expect("written");
    let warm = ctx.traffic().since(before);
    let (chunks, kept) = kept_chunks(&ctx);
    let rounds: Vec<_> = (0..30).map(|_| frame(&mut rng)).collect();
    let before = ctx.traffic();
    let got = written_through_ring(&ctx, size, &rounds, 3).expect("written");
    let t = ctx.traffic().since(before);
    eprintln!("first frame {warm:?}; 30 frames {t:?}; {chunks} chunks kept, {kept} bytes");
    assert!(got == applied(size, &rounds), "the last frame's bytes");
    // The chunks came with the first frame, the first write of this test's context.
    assert_eq!(chunks, FIRST_CHUNKS, "{warm:?}");
    assert_eq!(
        kept_chunks(&ctx),
        (chunks, kept),
        "no chunk made after the first frame"
    );
    // 30 frames: the test's buffer and the readback's staging, no chunk; their bytes, once.
    assert_eq!(t.buffers_created, 2, "{t:?}");
    assert_eq!(t.upload_bytes, 30 * (depth + colour + 64) as u64, "{t:?}");
    assert_eq!((t.submits, t.waits), (30 + 1, 10 + 1), "{t:?}");
}
