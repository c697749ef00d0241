//! Marching cubes over the hashed grid, block by block, in parallel.
//!
//! A cube joins the 8 voxel centres `v + {0,1}³`; it is meshed only when all 8 corners are in Ω
//! with weight > 0 (so no surface is invented in unobserved space). Cubes whose origin voxel lies
//! in block `b` belong to `b` and read their +x/+y/+z corners from the neighbouring blocks.
//! Vertices live on cube edges and are keyed by (global voxel index of the edge's lower corner,
//! axis), so a vertex shared by cubes of two blocks is emitted once: no duplicates or cracks at
//! block borders.

use super::tables::{edge_axis, triangle_table, EDGES};
use super::Mesh;
use crate::grid::{linear_index, BlockIndex, Layer, VoxelIndex, VOXELS_PER_SIDE};
use rayon::prelude::*;
use std::collections::HashMap;

/// Which field to mesh.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum Field {
    /// The raw fused TSDF `f`.
    Raw,
    /// The regularized TSDF `u` (falls back to `f` in blocks not regularized).
    Regularized,
}

const N: usize = VOXELS_PER_SIDE + 1;

/// A (VOXELS_PER_SIDE + 1)³ neighbourhood of samples: the block plus one voxel layer from its
/// +x, +y, +z neighbours.
struct Samples {
    value: Vec<f32>,
    valid: Vec<bool>,
    color: Vec<[u8; 3]>,
}

fn gather(layer: &Layer, index: BlockIndex, field: Field) -> Samples {
    let mut s = Samples {
        value: vec![0.0; N * N * N],
        valid: vec![false; N * N * N],
        color: vec![[0; 3]; N * N * N],
    };
    let side = VOXELS_PER_SIDE;
    for dz in 0..2 {
        for dy in 0..2 {
            for dx in 0..2 {
                let Some(block) = layer.get(&index.offset([dx, dy, dz])) else {
                    continue;
                };
                let xs = if dx == 0 { 0..side } else { 0..1 };
                for z in if dz == 0 { 0..side } else { 0..1 } {
                    for y in if dy == 0 { 0..side } else { 0..1 } {
                        for x in xs.clone() {
                            let i = linear_index(x, y, z);
                            let (gx, gy, gz) = (
                                x + dx as usize * side,
                                y + dy as usize * side,
                                z + dz as usize * side,
                            );
                            let j = gx + N * (gy + N * gz);
                            s.valid[j] = block.omega(i) && block.weight(i) > 0;
                            s.value[j] = match field {
                                Field::Raw => crate::grid::decode_tsdf(block.tsdf[i]),
                                Field::Regularized => block.regularized_or_raw(i),
                            };
                            s.color[j] = block.color[i];
                        }
                    }
                }
            }
        }
    }
    s
}

/// A vertex keyed by its edge: (lower corner voxel, axis).
/// A vertex's identity: the global voxel index of its cube edge's lower corner and the edge's axis.
pub type EdgeKey = (VoxelIndex, u8);

struct BlockMesh {
    vertices: Vec<(EdgeKey, [f32; 3], [u8; 3])>,
    /// Triangles as indices into `vertices`.
    triangles: Vec<[u32; 3]>,
}

fn mesh_block(layer: &Layer, index: BlockIndex, field: Field) -> BlockMesh {
    let grid = layer.params();
    let s = gather(layer, index, field);
    let table = triangle_table();
    let mut out = BlockMesh {
        vertices: Vec::new(),
        triangles: Vec::new(),
    };
    let mut local: HashMap<EdgeKey, u32> = HashMap::new();
    let side = VOXELS_PER_SIDE;
    for z in 0..side {
        for y in 0..side {
            for x in 0..side {
                let corner = |c: u8| {
                    (x + (c & 1) as usize)
                        + N * ((y + ((c >> 1) & 1) as usize) + N * (z + ((c >> 2) & 1) as usize))
                };
                let mut case = 0usize;
                let mut all_valid = true;
                for c in 0..8u8 {
                    let j = corner(c);
                    all_valid &= s.valid[j];
                    if s.value[j] < 0.0 {
                        case |= 1 << c;
                    }
                }
                if !all_valid || case == 0 || case == 255 {
                    continue;
                }
                for tri in &table[case] {
                    let mut ids = [0u32; 3];
                    for (k, &e) in tri.iter().enumerate() {
                        let [a, b] = EDGES[e as usize];
                        let lower = index.voxel(
                            x + (a & 1) as usize,
                            y + ((a >> 1) & 1) as usize,
                            z + ((a >> 2) & 1) as usize,
                        );
                        let key = (lower, edge_axis(e as usize) as u8);
                        ids[k] = *local.entry(key).or_insert_with(|| {
                            let (fa, fb) = (s.value[corner(a)], s.value[corner(b)]);
                            let t = (fa / (fa - fb)).clamp(0.0, 1.0);
                            let ca = grid.voxel_center(lower);
                            let axis = edge_axis(e as usize);
                            let mut p = [ca[0] as f32, ca[1] as f32, ca[2] as f32];
                            p[axis] += t * grid.voxel_size_m;
                            let (ka, kb) = (s.color[corner(a)], s.color[corner(b)]);
                            let col = [0, 1, 2].map(|q| {
                                (ka[q] as f32 + t * (kb[q] as f32 - ka[q] as f32)).round() as u8
                            });
                            out.vertices.push((key, p, col));
                            (out.vertices.len() - 1) as u32
                        });
                    }
                    if ids[0] != ids[1] && ids[1] != ids[2] && ids[0] != ids[2] {
                        out.triangles.push(ids);
                    }
                }
            }
        }
    }
    out
}

/// Extracts the zero level set of `field` over the given blocks (all allocated blocks when
/// `blocks` is `None`), with colours. Vertices and triangles come in block order, so the result is
/// deterministic.
pub fn extract_mesh(layer: &Layer, field: Field, blocks: Option<&[BlockIndex]>) -> Mesh {
    extract_mesh_keyed(layer, field, blocks).0
}

/// [`extract_mesh`], also returning each vertex's [`EdgeKey`] (same order as the vertices), so
/// meshes extracted tile by tile can be stitched without duplicate vertices.
pub fn extract_mesh_keyed(
    layer: &Layer,
    field: Field,
    blocks: Option<&[BlockIndex]>,
) -> (Mesh, Vec<EdgeKey>) {
    let list: Vec<BlockIndex> = match blocks {
        Some(b) => {
            let mut v = b.to_vec();
            v.sort_unstable();
            v.dedup();
            v
        }
        None => layer.indices_sorted(),
    };
    let parts: Vec<BlockMesh> = list
        .par_iter()
        .map(|&b| mesh_block(layer, b, field))
        .collect();
    let mut mesh = Mesh::default();
    let mut keys = Vec::new();
    let mut global: HashMap<EdgeKey, u32> = HashMap::new();
    for part in parts {
        let remap: Vec<u32> = part
            .vertices
            .iter()
            .map(|(key, p, c)| {
                *global.entry(*key).or_insert_with(|| {
                    mesh.positions_m.push(*p);
                    mesh.colors.push(*c);
                    keys.push(*key);
                    (mesh.positions_m.len() - 1) as u32
                })
            })
            .collect();
        mesh.triangles
            .extend(part.triangles.iter().map(|t| t.map(|i| remap[i as usize])));
    }
    (mesh, keys)
}
