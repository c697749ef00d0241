//! The GPU mesher's parts joined into one mesh on the host (`gpu.rs`): in order, as the CPU
//! mesher joins its blocks, looking up only the vertices two blocks can share.

use super::marching_cubes::EdgeKey;
use super::Mesh;
use crate::grid::{BlockIndex, VoxelIndex, VOXELS_PER_BLOCK, VOXELS_PER_SIDE};
use rayon::prelude::*;
use std::collections::HashMap;

/// The parts' vertices and triangles joined in order, as the CPU joins its blocks'.
#[derive(Default)]
pub(super) struct Merge {
    pub mesh: Mesh,
    pub keys: Vec<EdgeKey>,
    /// Whether more than one part makes the mesh (known before the first part is added).
    pub more_to_come: bool,
    /// The vertices two blocks can share, by edge, once more than one part makes the mesh.
    shared: HashMap<EdgeKey, u32>,
}

impl Merge {
    pub(super) fn add(&mut self, places: &[BlockIndex], vertices: &[[u32; 5]], triangles: &[u32]) {
        let decoded: Vec<(EdgeKey, bool)> = vertices
            .par_iter()
            .map(|v| edge_key(places, v[4]))
            .collect();
        let position = |v: &[u32; 5]| [0, 1, 2].map(|i| f32::from_bits(v[i]));
        let color = |v: &[u32; 5]| [0, 8, 16].map(|s| (v[3] >> s) as u8);
        if !self.more_to_come {
            // One part makes the mesh: its vertices are the mesh's, in order.
            let base = self.mesh.positions_m.len() as u32;
            let positions: Vec<[f32; 3]> = vertices.par_iter().map(position).collect();
            let colors: Vec<[u8; 3]> = vertices.par_iter().map(color).collect();
            let keys: Vec<EdgeKey> = decoded.into_par_iter().map(|(key, _)| key).collect();
            let tris: Vec<[u32; 3]> = triangles
                .par_chunks_exact(3)
                .map(|t| [base + t[0], base + t[1], base + t[2]])
                .collect();
            append(&mut self.mesh.positions_m, positions);
            append(&mut self.mesh.colors, colors);
            append(&mut self.keys, keys);
            append(&mut self.mesh.triangles, tris);
            return;
        }
        let remap: Vec<u32> = vertices
            .iter()
            .zip(decoded)
            .map(|(v, (key, shareable))| {
                let mesh = &mut self.mesh;
                let keys = &mut self.keys;
                let mut push = || {
                    mesh.positions_m.push(position(v));
                    mesh.colors.push(color(v));
                    keys.push(key);
                    (mesh.positions_m.len() - 1) as u32
                };
                if shareable {
                    *self.shared.entry(key).or_insert_with(push)
                } else {
                    push()
                }
            })
            .collect();
        self.mesh
            .triangles
            .extend(triangles.chunks_exact(3).map(|t| {
                [
                    remap[t[0] as usize],
                    remap[t[1] as usize],
                    remap[t[2] as usize],
                ]
            }));
    }
}

/// `more` appended to `v` (moved in whole where `v` is empty).
fn append<T>(v: &mut Vec<T>, more: Vec<T>) {
    if v.is_empty() {
        *v = more;
    } else {
        v.extend(more);
    }
}

/// The edge key of a device key `(place · 512 + voxel) · 3 + axis`, and whether cubes of two
/// blocks can name the edge (its lower corner on a low face of its block).
pub(super) fn edge_key(places: &[BlockIndex], key: u32) -> (EdgeKey, bool) {
    let axis = (key % 3) as u8;
    let voxel = (key / 3) as usize % VOXELS_PER_BLOCK;
    let place = (key / 3) as usize / VOXELS_PER_BLOCK;
    let side = VOXELS_PER_SIDE;
    let (x, y, z) = (voxel % side, (voxel / side) % side, voxel / (side * side));
    let v: VoxelIndex = places[place].voxel(x, y, z);
    ((v, axis), x == 0 || y == 0 || z == 0)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn device_keys_decode_to_the_cpu_keys() {
        let places = [BlockIndex([3, -2, 7]), BlockIndex([-1, 0, 0])];
        for (place, (x, y, z), axis) in [
            (0usize, (0, 5, 7), 2u32),
            (1, (7, 7, 7), 0),
            (1, (3, 4, 5), 1),
        ] {
            let voxel = x + 8 * (y + 8 * z);
            let key = ((place * 512 + voxel) * 3) as u32 + axis;
            let (k, shareable) = edge_key(&places, key);
            assert_eq!(k, (places[place].voxel(x, y, z), axis as u8));
            assert_eq!(shareable, x == 0 || y == 0 || z == 0);
        }
    }
}
