//! Voxel-by-voxel agreement of depth fusion between a GPU and the CPU, apart from the
//! pixel-rounding ties where two correct implementations may pick different pixels (the
//! tolerance stated in `compare.rs`).

use denser::gpu::GpuContext;
use denser::grid::{BlockIndex, GridParams, Layer, VOXELS_PER_BLOCK};
use nalgebra::Point3;
use std::collections::HashSet;

/// Pixel-rounding ties of depth fusion: voxels that some frame projects within this distance
/// of a pixel's rounding boundary (`⌊x + ½⌋` steps at x = k + ½), pixels. The f32 projection
/// differs from the f64 one by ~1e-4 px at VGA size (a few ULPs of |u| < 640).
const TIE_PX: f64 = 5e-4;
/// The same for the band's end: voxels whose signed distance to some frame's depth sample lies
/// within this of −μ, metres (f32 depths of a few metres are within ~1e-6 m).
const TIE_M: f64 = 1e-4;

/// Voxel `i` of a block.
type VoxelKey = (BlockIndex, usize);

/// The voxels of `blocks` at a pixel-rounding tie in some frame (computed in f64, independently
/// of both twins). There a last-bit difference of the f32 projection (FMA contraction, a division
/// within 2.5 ULP: WGSL allows both) picks the neighbouring pixel, and with it another depth
/// sample, or drops the update: such a voxel may differ by any amount between two correct
/// implementations.
pub fn rounding_ties(
    grid: GridParams,
    frames: &[denser::frame::DepthFrame],
    blocks: &[BlockIndex],
) -> HashSet<VoxelKey> {
    let vs = grid.voxel_size_m as f64;
    let mu = grid.truncation_m as f64;
    let mut ties = HashSet::new();
    for f in frames {
        let camera_from_world = f.world_from_camera.inverse();
        let k = f.intrinsics;
        let (w, h) = (f.depth_m.width as f64, f.depth_m.height as f64);
        for &b in blocks {
            let o = grid.block_origin(b);
            for i in 0..VOXELS_PER_BLOCK {
                let c = [i % 8, (i / 8) % 8, i / 64].map(|c| c as f64 + 0.5);
                let p = camera_from_world
                    * Point3::new(o[0] + c[0] * vs, o[1] + c[1] * vs, o[2] + c[2] * vs);
                if p.z <= 0.0 {
                    continue;
                }
                let (u, v) = (k.fx * p.x / p.z + k.cx, k.fy * p.y / p.z + k.cy);
                if !(u > -1.0 && v > -1.0 && u < w && v < h) {
                    continue;
                }
                // The pixels a last-bit change of (u, v) can pick (both ends of ±TIE_PX round
                // to one pixel unless it is near a boundary): a tie matters where one of them
                // would update the voxel (a depth, and the voxel in front of −μ).
                let picks = |x: f64| [-TIE_PX, TIE_PX].map(|e| (x + e + 0.5).floor());
                let (us, vs_) = (picks(u), picks(v));
                let ambiguous_pixel = us[0] != us[1] || vs_[0] != vs_[1];
                let mut updates = false;
                let mut band_end = false;
                for &ur in &us {
                    for &vr in &vs_ {
                        if ur < 0.0 || vr < 0.0 || ur >= w || vr >= h {
                            continue;
                        }
                        let d = f.depth_m.at(ur as u32, vr as u32) as f64;
                        if d.is_finite() && d - p.z >= -mu - TIE_M {
                            updates = true;
                            band_end |= (d - p.z + mu).abs() < TIE_M;
                        }
                    }
                }
                let tie = updates && (ambiguous_pixel || band_end);
                if tie {
                    ties.insert((b, i));
                }
            }
        }
    }
    ties
}

/// Voxel-by-voxel agreement of two layers over the same blocks, apart from `ties`.
#[derive(Debug)]
pub struct FusionAgreement {
    /// Voxels compared (all, ties included).
    voxels: usize,
    /// Voxels at a rounding tie ([`rounding_ties`]), and those of them that differ at all.
    ties: usize,
    ties_differ: usize,
    /// Outside the ties: weight or Ω differs, TSDF beyond one step, colour beyond one level.
    weight_mismatch: usize,
    tsdf_beyond_one_step: usize,
    color_beyond_one: usize,
    worst_tsdf_steps: i32,
    /// Outside the ties: TSDF differs by one step.
    tsdf_one_step: usize,
}

pub fn compare_layers(a: &Layer, b: &Layer, ties: &HashSet<VoxelKey>) -> FusionAgreement {
    assert_eq!(a.indices_sorted(), b.indices_sorted(), "block sets differ");
    let mut r = FusionAgreement {
        voxels: 0,
        ties: 0,
        ties_differ: 0,
        weight_mismatch: 0,
        tsdf_beyond_one_step: 0,
        color_beyond_one: 0,
        worst_tsdf_steps: 0,
        tsdf_one_step: 0,
    };
    for idx in a.indices_sorted() {
        let (x, y) = (a.get(&idx).expect("a"), b.get(&idx).expect("b"));
        for i in 0..VOXELS_PER_BLOCK {
            r.voxels += 1;
            let same = x.weight_omega[i] == y.weight_omega[i]
                && x.tsdf[i] == y.tsdf[i]
                && x.color[i] == y.color[i];
            if ties.contains(&(idx, i)) {
                r.ties += 1;
                r.ties_differ += usize::from(!same);
                continue;
            }
            if x.weight_omega[i] != y.weight_omega[i] {
                r.weight_mismatch += 1;
                continue;
            }
            let d = (x.tsdf[i] as i32 - y.tsdf[i] as i32).abs();
            r.worst_tsdf_steps = r.worst_tsdf_steps.max(d);
            r.tsdf_one_step += usize::from(d == 1);
            r.tsdf_beyond_one_step += usize::from(d > 1);
            if (0..3).any(|k| (x.color[i][k] as i32 - y.color[i][k] as i32).abs() > 1) {
                r.color_beyond_one += 1;
            }
        }
    }
    r
}

/// The fusion tolerance of the module doc: bit for bit on a software adapter; elsewhere the
/// same weights and Ω, the TSDF within one step and colours within one level on every voxel
/// outside the rounding ties, which must be a small part of the map.
pub fn assert_fusion_agrees(what: &str, ctx: &GpuContext, r: &FusionAgreement) {
    eprintln!("{what}: {r:?}");
    let n = r.voxels as f64;
    assert!(r.voxels > 0, "{what}: nothing compared");
    assert!(r.ties as f64 <= 0.02 * n, "{what}: too many ties");
    assert_eq!(r.weight_mismatch, 0, "{what}: weights");
    assert!(r.worst_tsdf_steps <= 1, "{what}: TSDF");
    assert_eq!(r.color_beyond_one, 0, "{what}: colour");
    if ctx.is_software() {
        assert_eq!(r.ties_differ + r.tsdf_one_step, 0, "{what}: bit for bit");
    }
}
