//! Binary PLY meshes read as streams, in bounded memory: vertices in batches, then triangles with
//! their corners' positions and colours (looked up through a small cache of vertex pages, since
//! a triangle of a mesh written chunk by chunk names vertices written shortly before it).
//!
//! Reads what [`crate::io::ply`] and `denser export` write (binary little endian, `float` or
//! `double` coordinates, optional `uchar` colours, triangles as `list uchar int`); anything else
//! is refused with the reason ([`crate::io::ply::read_mesh_ply`] reads any PLY, whole).

use crate::error::{Error, Result};
use crate::io::ply::{binary_mesh_layout, BinaryMeshLayout};
use std::collections::HashMap;
use std::io::{BufReader, Read, Seek, SeekFrom};
use std::os::unix::fs::FileExt;
use std::path::{Path, PathBuf};

/// Vertices per cached page.
const PAGE_VERTICES: u64 = 4096;

/// Bytes of a face record: the count (3) and three 32-bit indices.
const FACE_BYTES: usize = 13;

/// A binary PLY mesh opened for streaming.
pub struct PlyMeshStream {
    path: PathBuf,
    file: std::fs::File,
    layout: BinaryMeshLayout,
}

/// One vertex: position (metres, as stored) and colour (white without colours).
pub type Vertex = ([f64; 3], [u8; 3]);

impl PlyMeshStream {
    /// Opens `path` and reads its header. Errors name the file: missing, not a PLY, not of the
    /// streamable layout (module doc), or shorter than its header says.
    pub fn open(path: &Path) -> Result<PlyMeshStream> {
        let file = std::fs::File::open(path).map_err(|e| Error::io(path, e))?;
        let mut head = Vec::with_capacity(4096);
        (&file)
            .take(1 << 16)
            .read_to_end(&mut head)
            .map_err(|e| Error::io(path, e))?;
        let layout = binary_mesh_layout(&head)
            .map_err(|why| Error::bad_input(path, format!("cannot stream this PLY: {why}")))?;
        let need = layout.body_start
            + layout.vertices * layout.vertex_stride as u64
            + layout.faces * FACE_BYTES as u64;
        let len = file.metadata().map_err(|e| Error::io(path, e))?.len();
        if len < need {
            return Err(Error::bad_input(
                path,
                format!("truncated: {len} bytes, its header describes {need}"),
            ));
        }
        Ok(PlyMeshStream {
            path: path.to_path_buf(),
            file,
            layout,
        })
    }

    /// Number of vertices.
    pub fn vertices(&self) -> u64 {
        self.layout.vertices
    }

    /// Number of triangles.
    pub fn triangles(&self) -> u64 {
        self.layout.faces
    }

    fn decode(&self, rec: &[u8]) -> Vertex {
        let l = &self.layout;
        let p = l.xyz.map(|o| {
            if l.f64_coordinates {
                f64::from_le_bytes(rec[o..o + 8].try_into().expect("8 bytes"))
            } else {
                f32::from_le_bytes(rec[o..o + 4].try_into().expect("4 bytes")) as f64
            }
        });
        let c = l.rgb.map_or([255; 3], |o| o.map(|o| rec[o]));
        (p, c)
    }

    /// Calls `f` with the vertices in file order, `batch` at a time (the last batch shorter).
    pub fn for_each_vertex_batch(
        &self,
        batch: usize,
        mut f: impl FnMut(&[Vertex]) -> Result<()>,
    ) -> Result<()> {
        let stride = self.layout.vertex_stride;
        let mut reader = BufReader::with_capacity(1 << 20, &self.file);
        reader
            .seek(SeekFrom::Start(self.layout.body_start))
            .map_err(|e| Error::io(&self.path, e))?;
        let mut left = self.layout.vertices;
        let mut rec = vec![0u8; stride];
        let mut out = Vec::with_capacity(batch.max(1));
        while left > 0 {
            out.clear();
            while left > 0 && out.len() < batch.max(1) {
                reader
                    .read_exact(&mut rec)
                    .map_err(|e| Error::io(&self.path, e))?;
                out.push(self.decode(&rec));
                left -= 1;
            }
            f(&out)?;
        }
        Ok(())
    }

    /// Calls `f` with each triangle's three corners, in file order. Vertices are read through a
    /// cache of at most `cache_pages` pages of 4096 vertices (least recently used evicted).
    /// Errors on a face that is not a triangle or names a vertex that does not exist.
    pub fn for_each_triangle(
        &self,
        cache_pages: usize,
        mut f: impl FnMut(&[Vertex; 3]) -> Result<()>,
    ) -> Result<()> {
        let l = self.layout;
        let stride = l.vertex_stride as u64;
        let mut reader = BufReader::with_capacity(1 << 20, &self.file);
        reader
            .seek(SeekFrom::Start(l.body_start + l.vertices * stride))
            .map_err(|e| Error::io(&self.path, e))?;
        let mut cache: HashMap<u64, (Vec<Vertex>, u64)> = HashMap::new();
        let mut clock = 0u64;
        let mut page_bytes = Vec::new();
        let mut rec = [0u8; FACE_BYTES];
        for face in 0..l.faces {
            reader
                .read_exact(&mut rec)
                .map_err(|e| Error::io(&self.path, e))?;
            if rec[0] != 3 {
                return Err(Error::bad_input(
                    &self.path,
                    format!("face {face} has {} corners; only triangles stream", rec[0]),
                ));
            }
            let mut corners = [([0.0; 3], [0u8; 3]); 3];
            for (j, corner) in corners.iter_mut().enumerate() {
                let i = u32::from_le_bytes(rec[1 + 4 * j..5 + 4 * j].try_into().expect("4"));
                let i = i as u64;
                if i >= l.vertices {
                    return Err(Error::bad_input(
                        &self.path,
                        format!("face {face} names vertex {i} of {}", l.vertices),
                    ));
                }
                let page = i / PAGE_VERTICES;
                clock += 1;
                if !cache.contains_key(&page) {
                    if cache.len() >= cache_pages.max(1) {
                        let oldest = *cache
                            .iter()
                            .min_by_key(|(_, (_, used))| *used)
                            .expect("a full cache")
                            .0;
                        cache.remove(&oldest);
                    }
                    let first = page * PAGE_VERTICES;
                    let n = PAGE_VERTICES.min(l.vertices - first);
                    page_bytes.resize((n * stride) as usize, 0);
                    self.file
                        .read_exact_at(&mut page_bytes, l.body_start + first * stride)
                        .map_err(|e| Error::io(&self.path, e))?;
                    let vertices = page_bytes
                        .chunks_exact(stride as usize)
                        .map(|r| self.decode(r))
                        .collect();
                    cache.insert(page, (vertices, clock));
                }
                let entry = cache.get_mut(&page).expect("just cached");
                entry.1 = clock;
                *corner = entry.0[(i - page * PAGE_VERTICES) as usize];
            }
            f(&corners)?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::Mesh;

    #[test]
    fn a_streamed_mesh_equals_the_mesh_read_whole() {
        // 10 000 vertices on a grid (three pages), triangles naming vertices across pages.
        let mut mesh = Mesh::default();
        let side = 100u32;
        for j in 0..side {
            for i in 0..side {
                mesh.positions_m
                    .push([i as f32 * 0.1, (i * j) as f32 * 1e-3, j as f32 * 0.1]);
                mesh.colors.push([(i % 256) as u8, (j % 256) as u8, 7]);
            }
        }
        for j in 0..side - 1 {
            for i in 0..side - 1 {
                let v = j * side + i;
                mesh.triangles.push([v, v + 1, v + side]);
                mesh.triangles.push([v + 1, v + side + 1, v + side]);
            }
        }
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("m.ply");
        crate::io::ply::write_mesh_ply(&path, &mesh).unwrap();
        let s = PlyMeshStream::open(&path).unwrap();
        assert_eq!((s.vertices(), s.triangles()), (10_000, 19_602));
        let mut seen = Vec::new();
        s.for_each_vertex_batch(3000, |b| {
            assert!(b.len() <= 3000);
            seen.extend_from_slice(b);
            Ok(())
        })
        .unwrap();
        assert_eq!(seen.len(), mesh.positions_m.len());
        for (k, (p, c)) in seen.iter().enumerate() {
            assert_eq!(p.map(|v| v as f32), mesh.positions_m[k]);
            assert_eq!(*c, mesh.colors[k]);
        }
        // A cache of one page: every page is read again as the triangles move on, same corners.
        let mut t = 0;
        s.for_each_triangle(1, |corners| {
            for (j, (p, c)) in corners.iter().enumerate() {
                let k = mesh.triangles[t][j] as usize;
                assert_eq!(
                    (p.map(|v| v as f32), *c),
                    (mesh.positions_m[k], mesh.colors[k])
                );
            }
            t += 1;
            Ok(())
        })
        .unwrap();
        assert_eq!(t, mesh.triangles.len());
        // Truncated by one byte: refused, naming the file.
        let bytes = std::fs::read(&path).unwrap();
        std::fs::write(&path, &bytes[..bytes.len() - 1]).unwrap();
        let e = PlyMeshStream::open(&path).err().unwrap().to_string();
        assert!(e.contains("m.ply") && e.contains("truncated"), "{e}");
        // An ASCII PLY is not streamed.
        std::fs::write(
            &path,
            "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nproperty float z\nend_header\n0 0 0\n",
        )
        .unwrap();
        let e = PlyMeshStream::open(&path).err().unwrap().to_string();
        assert!(e.contains("binary little endian"), "{e}");
    }
}
