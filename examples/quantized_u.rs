//! How far the regularized mesh moves when `u` is kept in fewer bits (a decision aid for issue
//! 14, item 7: at most 6 bytes per voxel in RAM with `u` needs a lossy field; not a format).
//!
//! `cargo run --release --example quantized_u -- SEQ`, SEQ a `denser synth` drive's
//! `sequences/00`: its ground-truth depth fused in memory at 10 and 5 cm (the paper's μ),
//! regularized, meshed; then `u` rounded to 127 and to 63 levels per sign (8 and 7 bits) and
//! meshed again. Prints the distance from each vertex of the rounded mesh to the nearest vertex
//! of the exact one (median, 90th, 99th percentile, maximum) and the vertex counts.

use denser::backend::Backend;
use denser::eval::GroundTruthIndex;
use denser::grid::{decode_tsdf, encode_tsdf};
use denser::io::sequence::{open_sequence, RangeSource};
use denser::mesh::{extract_mesh, Field, Mesh};
use denser::reconstruct::{ReconstructionConfig, Reconstructor};

fn main() -> anyhow::Result<()> {
    let Some(dir) = std::env::args().nth(1) else {
        anyhow::bail!("usage: quantized_u SEQ (a denser synth drive's sequences/00)");
    };
    let seq = open_sequence(
        std::path::Path::new(&dir),
        RangeSource::GroundTruthDepth,
        None,
        None,
    )?;
    let frames: Vec<usize> = (0..seq.len()).collect();
    let positions =
        |m: &Mesh| -> Vec<[f64; 3]> { m.positions_m.iter().map(|p| p.map(f64::from)).collect() };
    for voxel_m in [0.1f32, 0.05] {
        let config = ReconstructionConfig::paper(voxel_m);
        let mut rec = Reconstructor::in_memory(config, Backend::cpu())?;
        rec.fuse_sequence(&*seq, &frames)?;
        rec.regularize()?;
        let exact = extract_mesh(rec.layer(), Field::Regularized, None);
        let index = GroundTruthIndex::from_points(&positions(&exact))?;
        for levels in [127.0f32, 63.0] {
            let mut layer = rec.layer().clone();
            for i in layer.indices_sorted() {
                let block = layer.get_mut(&i).expect("listed");
                for u in block.regularized.iter_mut().flat_map(|u| u.iter_mut()) {
                    *u = encode_tsdf((decode_tsdf(*u) * levels).round() / levels);
                }
            }
            let rounded = extract_mesh(&layer, Field::Regularized, None);
            let mut d = index.nearest_distances_m(&positions(&rounded))?;
            d.sort_by(f32::total_cmp);
            let mm = |p: f64| 1e3 * d[((d.len() - 1) as f64 * p) as usize];
            println!(
                "voxel {voxel_m} m, μ {} m, u in {levels} levels per sign: vertices {} -> {}; \
                 shift mm: median {:.2}, p90 {:.2}, p99 {:.2}, max {:.1}",
                config.grid.truncation_m,
                exact.positions_m.len(),
                rounded.positions_m.len(),
                mm(0.5),
                mm(0.9),
                mm(0.99),
                mm(1.0)
            );
        }
    }
    Ok(())
}
