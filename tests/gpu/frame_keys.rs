//! A depth frame's listed blocks as the GPU tier sends them (`src/fusion/depth_keys.rs`): 4-byte
//! offsets from the frame's origin block, from which `shaders/frame_keys.wgsl` resolves slots
//! through the GPU hash table and computes bases in double-f32. Against the CPU twin
//! (`FrameKeys::base`, `BlockTable::lookup`) and the CPU's own f64 bases.

use crate::common::{gpu, Rng};
use crate::street::street_frame;
use denser::fusion::{frame_keys_on_gpu, DepthGeometry, FrameKeys};
use denser::gpu::resident::BlockTable;
use denser::grid::{BlockIndex, GridParams};

/// ULPs between two f32 of one sign.
fn ulps(a: f32, b: f32) -> i64 {
    (a.to_bits() as i64 - b.to_bits() as i64).abs()
}

#[test]
fn frame_keys_give_the_twins_slots_and_bases() {
    let Some(ctx) = gpu() else { return };
    let grid = GridParams::paper(0.1);
    // A street frame 2 km down the road: world coordinates far larger than camera ones.
    let frame = street_frame(2000.0, 0);
    let g = DepthGeometry::new(&grid, &frame);
    let origin = grid.block_of_point(frame.world_from_camera.translation.vector.into());
    let mut rng = Rng(4);
    let mut blocks: Vec<BlockIndex> = (0..6000)
        .map(|_| {
            let d = [0, 1, 2].map(|k| ((rng.uniform() - 0.5) * [1800.0, 900.0, 1800.0][k]) as i32);
            origin.offset(d)
        })
        .collect();
    blocks.sort_unstable();
    blocks.dedup();
    let mut table = BlockTable::for_blocks(blocks.len() as u32);
    for (k, b) in blocks.iter().enumerate().filter(|(k, _)| k % 3 != 0) {
        table.insert(*b, k as u32);
    }
    for (wide, first_unsettled) in [(false, blocks.len() - 100), (true, 7)] {
        let mut listed = blocks.clone();
        if wide {
            listed.push(origin.offset([0, 3000, 0]));
        }
        let keys = FrameKeys::new(&grid, &g, &listed, first_unsettled).expect("keys");
        assert_eq!(keys.is_wide(), wide);
        let (slots, bases) = frame_keys_on_gpu(&ctx, &keys, &table).expect("kernel");
        let host: Vec<Option<u32>> = listed.iter().map(|b| table.lookup(*b)).collect();
        assert_eq!(slots, host, "slots");
        let (mut from_twin, mut from_cpu) = (0usize, 0usize);
        for (k, (b, base)) in listed.iter().zip(&bases).enumerate() {
            assert_eq!(
                base[3],
                (k >= first_unsettled) as u32 as f32,
                "block {k}: w"
            );
            let (twin, cpu) = (keys.base(*b), g.block_base(&grid, *b));
            for c in 0..3 {
                assert!(ulps(base[c], cpu[c]) <= 1, "{b:?}: {base:?} vs CPU {cpu:?}");
                from_twin += (base[c] != twin[c]) as usize;
                from_cpu += (base[c] != cpu[c]) as usize;
            }
        }
        eprintln!(
            "{} blocks (wide keys: {wide}): {from_twin} coordinates differ from the twin, \
             {from_cpu} from the CPU's f64 bases",
            listed.len()
        );
        // Integer arithmetic: the same bits on any adapter.
        assert_eq!(from_twin, 0, "the kernel differs from its twin");
        assert!(from_cpu * 10_000 <= 3 * listed.len(), "{from_cpu}");
    }
}
