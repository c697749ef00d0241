//! Surface extraction: marching cubes over the raw (`f`) or regularized (`u`) field, and the
//! mesh and point types that exporters write.

mod gpu;
mod gpu_merge;
mod gpu_samples;
mod marching_cubes;
pub mod tables;

pub use gpu::{extract_mesh_gpu, extract_mesh_gpu_from, GpuMesher, POSITION_TOLERANCE_VOXELS};
pub use gpu_samples::SampleSource;
pub use marching_cubes::{extract_mesh, extract_mesh_keyed, EdgeKey, Field};

/// An indexed triangle mesh with per-vertex colour, world coordinates in metres.
/// Triangles wind counter-clockwise seen from the free-space (positive TSDF) side.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Mesh {
    /// Vertex positions, metres.
    pub positions_m: Vec<[f32; 3]>,
    /// Vertex colours (sRGB), same length as `positions_m`.
    pub colors: Vec<[u8; 3]>,
    /// Triangles as vertex indices.
    pub triangles: Vec<[u32; 3]>,
}

/// Area of the triangle with corners `p`, m² (f64 arithmetic).
pub fn triangle_area_m2(p: [[f32; 3]; 3]) -> f64 {
    let v = |i: usize| nalgebra::Vector3::new(p[i][0] as f64, p[i][1] as f64, p[i][2] as f64);
    0.5 * (v(1) - v(0)).cross(&(v(2) - v(0))).norm()
}

impl Mesh {
    /// Total triangle area, m².
    pub fn surface_area_m2(&self) -> f64 {
        self.triangles
            .iter()
            .map(|t| triangle_area_m2(t.map(|i| self.positions_m[i as usize])))
            .sum()
    }
}

impl Mesh {
    /// The vertices as a point cloud (the "surface points" the paper evaluates).
    pub fn to_point_cloud(&self) -> crate::frame::PointCloud {
        crate::frame::PointCloud {
            points_m: self
                .positions_m
                .iter()
                .map(|p| [p[0] as f64, p[1] as f64, p[2] as f64])
                .collect(),
            colors: Some(self.colors.clone()),
        }
    }
}
