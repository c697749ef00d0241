//! PLY (Stanford polygon format) meshes and point clouds.
//!
//! What it does: writes [`Mesh`]es and [`PointCloud`]s as binary little-endian PLY that
//! MeshLab, CloudCompare, Open3D and Blender open; reads PLY files written by such tools in any
//! of the three encodings (`ascii`, `binary_little_endian`, `binary_big_endian`), with any
//! property types and extra properties or elements (normals, alpha, quality, edges, materials…),
//! keeping positions, colours and faces. Polygons are fan-triangulated.
//!
//! What it does not do: keep normals, texture coordinates or other extra properties, read
//! `obj_info` metadata, or stream files larger than memory.
//!
//! # Files written here (byte layout)
//! ```text
//! ply\n
//! format binary_little_endian 1.0\n
//! comment written by denser\n
//! element vertex N\n
//! property float x\n  property float y\n  property float z\n      (double for *_f64 writers)
//! property uchar red\n property uchar green\n property uchar blue\n (only with colours)
//! element face M\n                                                 (meshes only)
//! property list uchar int vertex_indices\n
//! end_header\n
//! N vertex records: x, y, z as f32 LE (or f64 LE) then r, g, b as u8 → 15 bytes (27 with f64)
//!                   per vertex, 12 (24) without colour
//! M face records:   u8 3, then three i32 LE vertex indices → 13 bytes per triangle
//! ```
//! Precision: f32 coordinates have a 24-bit mantissa, i.e. a step of about 0.06 mm at 1 km
//! from the origin and 0.5 m at 5 000 km (raw UTM northings). Use [`write_points_ply_f64`] or
//! shift the cloud to a local origin when coordinates are large; viewers read `double` too.
//!
//! # Reading
//! * Vertex element `vertex` with properties `x`, `y`, `z` (any numeric type, required) and
//!   optionally `red`/`green`/`blue` (also `r`/`g`/`b`, `diffuse_red`…): `uchar` taken as is,
//!   16-bit integers scaled by 1/257, floating point taken as [0, 1] and scaled by 255.
//! * Face element `face` with a list property `vertex_indices` (or `vertex_index`); polygons
//!   with n ≥ 3 vertices give n − 2 triangles `(v0, vk, vk+1)`; an index outside the vertex
//!   range is an error.

use crate::error::{Error, Result};
use crate::frame::PointCloud;
use crate::mesh::Mesh;
use std::path::Path;

/// How the body of a PLY file is encoded.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Encoding {
    Ascii,
    BinaryLe,
    BinaryBe,
}

/// A PLY scalar type.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Scalar {
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
    F32,
    F64,
}

impl Scalar {
    fn parse(s: &str) -> Option<Scalar> {
        Some(match s {
            "char" | "int8" => Scalar::I8,
            "uchar" | "uint8" => Scalar::U8,
            "short" | "int16" => Scalar::I16,
            "ushort" | "uint16" => Scalar::U16,
            "int" | "int32" => Scalar::I32,
            "uint" | "uint32" => Scalar::U32,
            "float" | "float32" => Scalar::F32,
            "double" | "float64" => Scalar::F64,
            _ => return None,
        })
    }

    fn size(self) -> usize {
        match self {
            Scalar::I8 | Scalar::U8 => 1,
            Scalar::I16 | Scalar::U16 => 2,
            Scalar::I32 | Scalar::U32 | Scalar::F32 => 4,
            Scalar::F64 => 8,
        }
    }
}

#[derive(Clone, Debug)]
enum Kind {
    Scalar(Scalar),
    List { count: Scalar, item: Scalar },
}

#[derive(Clone, Debug)]
struct Property {
    name: String,
    kind: Kind,
}

#[derive(Clone, Debug)]
struct Element {
    name: String,
    count: usize,
    props: Vec<Property>,
}

#[derive(Clone, Debug)]
struct Header {
    encoding: Encoding,
    elements: Vec<Element>,
    body_start: usize,
}

fn parse_header(bytes: &[u8]) -> std::result::Result<Header, String> {
    if !bytes.starts_with(b"ply") {
        return Err("not a PLY file (magic 'ply' missing)".into());
    }
    let mut pos = 0;
    let mut encoding = None;
    let mut elements: Vec<Element> = Vec::new();
    let mut line_no = 0;
    loop {
        let Some(len) = bytes[pos..].iter().position(|&b| b == b'\n') else {
            return Err("truncated header: 'end_header' not found".into());
        };
        line_no += 1;
        let line = std::str::from_utf8(&bytes[pos..pos + len])
            .map_err(|_| format!("header line {line_no} is not text"))?
            .trim();
        pos += len + 1;
        let words: Vec<&str> = line.split_whitespace().collect();
        let bad = || format!("header line {line_no}: cannot parse '{line}'");
        match words.first().copied() {
            None | Some("ply") | Some("comment") | Some("obj_info") => {}
            Some("format") => {
                encoding = Some(match words.get(1).copied() {
                    Some("ascii") => Encoding::Ascii,
                    Some("binary_little_endian") => Encoding::BinaryLe,
                    Some("binary_big_endian") => Encoding::BinaryBe,
                    _ => {
                        return Err(format!(
                            "header line {line_no}: unsupported format '{line}'"
                        ))
                    }
                });
            }
            Some("element") => {
                let (Some(name), Some(count), None) = (words.get(1), words.get(2), words.get(3))
                else {
                    return Err(bad());
                };
                let count = count.parse().map_err(|_| bad())?;
                elements.push(Element {
                    name: name.to_string(),
                    count,
                    props: Vec::new(),
                });
            }
            Some("property") => {
                let element = elements
                    .last_mut()
                    .ok_or_else(|| format!("header line {line_no}: property before any element"))?;
                let ty = |s: &str| {
                    Scalar::parse(s)
                        .ok_or_else(|| format!("header line {line_no}: unknown type '{s}'"))
                };
                let (kind, name) = match words.as_slice() {
                    ["property", "list", c, i, name] => (
                        Kind::List {
                            count: ty(c)?,
                            item: ty(i)?,
                        },
                        name,
                    ),
                    ["property", t, name] => (Kind::Scalar(ty(t)?), name),
                    _ => return Err(bad()),
                };
                element.props.push(Property {
                    name: name.to_string(),
                    kind,
                });
            }
            Some("end_header") => break,
            Some(_) => return Err(bad()),
        }
    }
    let encoding = encoding.ok_or("header has no 'format' line")?;
    Ok(Header {
        encoding,
        elements,
        body_start: pos,
    })
}

/// Sequential reader of body values.
enum Body<'a> {
    Binary {
        bytes: &'a [u8],
        pos: usize,
        big_endian: bool,
    },
    Ascii {
        tokens: std::str::SplitAsciiWhitespace<'a>,
    },
}

impl Body<'_> {
    /// Next value as f64; `Err(None)` at end of data, `Err(Some(token))` on a bad ASCII token.
    fn next(&mut self, ty: Scalar) -> std::result::Result<f64, Option<String>> {
        match self {
            Body::Ascii { tokens } => {
                let t = tokens.next().ok_or(None)?;
                t.parse::<f64>().map_err(|_| Some(t.to_string()))
            }
            Body::Binary {
                bytes,
                pos,
                big_endian,
            } => {
                let n = ty.size();
                let b = bytes.get(*pos..*pos + n).ok_or(None)?;
                *pos += n;
                let mut a = [0u8; 8];
                a[..n].copy_from_slice(b);
                if *big_endian {
                    a[..n].reverse();
                }
                Ok(match ty {
                    Scalar::I8 => a[0] as i8 as f64,
                    Scalar::U8 => a[0] as f64,
                    Scalar::I16 => i16::from_le_bytes([a[0], a[1]]) as f64,
                    Scalar::U16 => u16::from_le_bytes([a[0], a[1]]) as f64,
                    Scalar::I32 => i32::from_le_bytes([a[0], a[1], a[2], a[3]]) as f64,
                    Scalar::U32 => u32::from_le_bytes([a[0], a[1], a[2], a[3]]) as f64,
                    Scalar::F32 => f32::from_le_bytes([a[0], a[1], a[2], a[3]]) as f64,
                    Scalar::F64 => f64::from_le_bytes(a),
                })
            }
        }
    }
}

fn color_to_u8(v: f64, ty: Scalar) -> u8 {
    let scaled = match ty {
        Scalar::U8 | Scalar::I8 => v,
        Scalar::U16 | Scalar::I16 => v / 257.0,
        Scalar::F32 | Scalar::F64 => v * 255.0,
        Scalar::U32 | Scalar::I32 => v,
    };
    scaled.round().clamp(0.0, 255.0) as u8
}

/// Reads a PLY file: its vertices (with colours when all of red, green, blue exist) and, when
/// it has a `face` element, its triangles (polygons fan-triangulated). Errors name the file.
pub fn read_ply(path: impl AsRef<Path>) -> Result<(PointCloud, Option<Vec<[u32; 3]>>)> {
    let path = path.as_ref();
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    decode_ply(&bytes).map_err(|msg| Error::bad_input(path, msg))
}

/// A decoded PLY file: its vertices and, for a mesh, its triangles.
pub type PlyContents = (PointCloud, Option<Vec<[u32; 3]>>);

/// Decodes a PLY file held in memory (see [`read_ply`]).
pub fn decode_ply(bytes: &[u8]) -> std::result::Result<PlyContents, String> {
    let header = parse_header(bytes)?;
    let body_bytes = &bytes[header.body_start..];
    let mut body = match header.encoding {
        Encoding::Ascii => Body::Ascii {
            tokens: std::str::from_utf8(body_bytes)
                .map_err(|_| "ASCII PLY body is not text".to_string())?
                .split_ascii_whitespace(),
        },
        e => Body::Binary {
            bytes: body_bytes,
            pos: 0,
            big_endian: e == Encoding::BinaryBe,
        },
    };
    let mut points: Option<Vec<[f64; 3]>> = None;
    let mut colors: Option<Vec<[u8; 3]>> = None;
    let mut faces: Option<Vec<[u32; 3]>> = None;
    let mut polygon: Vec<u32> = Vec::new();
    let mut skipped_polygons = 0usize;
    for el in &header.elements {
        let find = |names: &[&str]| {
            el.props
                .iter()
                .position(|p| names.contains(&p.name.as_str()) && matches!(p.kind, Kind::Scalar(_)))
        };
        let is_vertex = el.name == "vertex" && points.is_none();
        let is_face = el.name == "face" && faces.is_none();
        let xyz = [find(&["x"]), find(&["y"]), find(&["z"])];
        let rgb = [
            find(&["red", "r", "diffuse_red"]),
            find(&["green", "g", "diffuse_green"]),
            find(&["blue", "b", "diffuse_blue"]),
        ];
        let face_list = el.props.iter().position(|p| {
            matches!(p.kind, Kind::List { .. })
                && (p.name == "vertex_indices" || p.name == "vertex_index")
        });
        if is_vertex && xyz.iter().any(|k| k.is_none()) {
            return Err("element 'vertex' lacks one of the properties x, y, z".into());
        }
        if is_face && face_list.is_none() {
            return Err("element 'face' has no list property 'vertex_indices'".into());
        }
        let has_rgb = is_vertex && rgb.iter().all(|k| k.is_some());
        let mut pts = Vec::with_capacity(if is_vertex { el.count } else { 0 });
        let mut cols = Vec::with_capacity(if has_rgb { el.count } else { 0 });
        let mut tris = Vec::new();
        let mut values = vec![0.0f64; el.props.len()];
        for rec in 0..el.count {
            let fail = |e: Option<String>, prop: &str| {
                match e {
                None => format!(
                    "truncated: element '{}' record {rec} of {} (property '{prop}') runs past the end of the file",
                    el.name, el.count
                ),
                Some(t) => format!(
                    "element '{}' record {rec} property '{prop}': '{t}' is not a number",
                    el.name
                ),
            }
            };
            for (k, prop) in el.props.iter().enumerate() {
                match prop.kind {
                    Kind::Scalar(ty) => {
                        values[k] = body.next(ty).map_err(|e| fail(e, &prop.name))?
                    }
                    Kind::List { count, item } => {
                        let n = body.next(count).map_err(|e| fail(e, &prop.name))?;
                        if !(n >= 0.0 && n.fract() == 0.0) {
                            return Err(format!(
                                "element '{}' record {rec}: bad list length {n}",
                                el.name
                            ));
                        }
                        let keep = is_face && face_list == Some(k);
                        polygon.clear();
                        for _ in 0..n as usize {
                            let v = body.next(item).map_err(|e| fail(e, &prop.name))?;
                            if keep {
                                if !(v >= 0.0 && v.fract() == 0.0 && v <= u32::MAX as f64) {
                                    return Err(format!("face {rec}: bad vertex index {v}"));
                                }
                                polygon.push(v as u32);
                            }
                        }
                        if keep {
                            if polygon.len() < 3 {
                                skipped_polygons += 1;
                            }
                            for j in 1..polygon.len().saturating_sub(1) {
                                tris.push([polygon[0], polygon[j], polygon[j + 1]]);
                            }
                        }
                    }
                }
            }
            if is_vertex {
                let g = |k: Option<usize>| k.map_or(0.0, |k| values[k]);
                pts.push([g(xyz[0]), g(xyz[1]), g(xyz[2])]);
                if has_rgb {
                    let c = |k: Option<usize>| {
                        let k = k.unwrap_or(0);
                        let ty = match el.props[k].kind {
                            Kind::Scalar(t) => t,
                            Kind::List { item, .. } => item,
                        };
                        color_to_u8(values[k], ty)
                    };
                    cols.push([c(rgb[0]), c(rgb[1]), c(rgb[2])]);
                }
            }
        }
        if is_vertex {
            points = Some(pts);
            if has_rgb {
                colors = Some(cols);
            }
        }
        if is_face {
            faces = Some(tris);
        }
    }
    let points = points.ok_or("no 'vertex' element")?;
    if let Some(tris) = &faces {
        if let Some(t) = tris
            .iter()
            .find(|t| t.iter().any(|&i| i as usize >= points.len()))
        {
            return Err(format!(
                "face {t:?} refers to a vertex beyond the {} vertices",
                points.len()
            ));
        }
    }
    if skipped_polygons > 0 {
        tracing::debug!("PLY: skipped {skipped_polygons} faces with fewer than 3 vertices");
    }
    Ok((
        PointCloud {
            points_m: points,
            colors,
        },
        faces,
    ))
}

/// Reads a PLY mesh (vertices, colours, faces). Vertices without colour are white; a file
/// without a `face` element gives a mesh with no triangles.
pub fn read_mesh_ply(path: impl AsRef<Path>) -> Result<Mesh> {
    let (cloud, faces) = read_ply(path)?;
    let n = cloud.points_m.len();
    Ok(Mesh {
        positions_m: cloud
            .points_m
            .iter()
            .map(|p| [p[0] as f32, p[1] as f32, p[2] as f32])
            .collect(),
        colors: cloud.colors.unwrap_or_else(|| vec![[255, 255, 255]; n]),
        triangles: faces.unwrap_or_default(),
    })
}

/// Where the fields of a binary little-endian PLY mesh lie, for readers that stream it
/// ([`crate::io::ply_stream`]): fixed-size vertex records, then (when present) faces.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct BinaryMeshLayout {
    /// Bytes of the header (the vertex records start here).
    pub body_start: u64,
    /// Vertex records.
    pub vertices: u64,
    /// Bytes per vertex record.
    pub vertex_stride: usize,
    /// Byte offsets of x, y, z in a record, and whether they are `double` (else `float`).
    pub xyz: [usize; 3],
    /// Whether the coordinates are `double`.
    pub f64_coordinates: bool,
    /// Byte offsets of red, green, blue (`uchar`), when present.
    pub rgb: Option<[usize; 3]>,
    /// Face records (0 without a face element); each `uchar` 3 then three `int`/`uint`.
    pub faces: u64,
}

/// The [`BinaryMeshLayout`] of the PLY whose first bytes are `head` (at least its header), or
/// why it cannot be streamed: not binary little endian, coordinates neither `float` nor
/// `double`, a vertex property of variable size, colours not `uchar`, elements other than
/// `vertex` then `face`, or faces other than `list uchar int|uint`.
pub(crate) fn binary_mesh_layout(head: &[u8]) -> std::result::Result<BinaryMeshLayout, String> {
    let h = parse_header(head)?;
    if h.encoding != Encoding::BinaryLe {
        return Err("not binary little endian".into());
    }
    let (vertex, face) = match h.elements.as_slice() {
        [v] if v.name == "vertex" => (v, None),
        [v, f] if v.name == "vertex" && f.name == "face" => (v, Some(f)),
        _ => return Err("elements other than `vertex` then `face`".into()),
    };
    let (mut offset, mut xyz, mut rgb) = (0usize, [None; 3], [None; 3]);
    let mut coordinate_type = None;
    for p in &vertex.props {
        let Kind::Scalar(s) = p.kind else {
            return Err(format!("vertex property `{}` is a list", p.name));
        };
        let axis = ["x", "y", "z"].iter().position(|n| *n == p.name);
        let colour = ["red", "green", "blue"].iter().position(|n| *n == p.name);
        if let Some(a) = axis {
            if !matches!(s, Scalar::F32 | Scalar::F64) || coordinate_type.is_some_and(|t| t != s) {
                return Err("coordinates neither all `float` nor all `double`".into());
            }
            coordinate_type = Some(s);
            xyz[a] = Some(offset);
        } else if let Some(c) = colour {
            if s != Scalar::U8 {
                return Err("colours not `uchar`".into());
            }
            rgb[c] = Some(offset);
        }
        offset += s.size();
    }
    let [Some(x), Some(y), Some(z)] = xyz else {
        return Err("vertex without x, y and z".into());
    };
    if let Some(f) = face {
        match f.props.as_slice() {
            [Property {
                kind:
                    Kind::List {
                        count: Scalar::U8,
                        item: Scalar::I32 | Scalar::U32,
                    },
                ..
            }] => {}
            _ => return Err("faces not `list uchar int`".into()),
        }
    }
    Ok(BinaryMeshLayout {
        body_start: h.body_start as u64,
        vertices: vertex.count as u64,
        vertex_stride: offset,
        xyz: [x, y, z],
        f64_coordinates: coordinate_type == Some(Scalar::F64),
        rgb: match rgb {
            [Some(r), Some(g), Some(b)] => Some([r, g, b]),
            _ => None,
        },
        faces: face.map_or(0, |f| f.count as u64),
    })
}

fn vertex_header(out: &mut String, n: usize, coord: &str, color: bool) {
    out.push_str("ply\nformat binary_little_endian 1.0\ncomment written by denser\n");
    out.push_str(&format!("element vertex {n}\n"));
    for axis in ["x", "y", "z"] {
        out.push_str(&format!("property {coord} {axis}\n"));
    }
    if color {
        out.push_str("property uchar red\nproperty uchar green\nproperty uchar blue\n");
    }
}

fn write_bytes(path: &Path, bytes: &[u8]) -> Result<()> {
    crate::io::atomic::write_file(path, bytes)
}

/// Encodes a mesh as binary little-endian PLY (layout in the module doc). Vertex colours are
/// written when `mesh.colors` is not empty; then it must match the vertex count.
pub fn encode_mesh_ply(mesh: &Mesh) -> Result<Vec<u8>> {
    let n = mesh.positions_m.len();
    let color = !mesh.colors.is_empty();
    if color && mesh.colors.len() != n {
        return Err(Error::InvalidArgument(format!(
            "mesh has {n} vertices but {} colours",
            mesh.colors.len()
        )));
    }
    if n > i32::MAX as usize {
        return Err(Error::InvalidArgument(format!(
            "{n} vertices exceed PLY int indices"
        )));
    }
    if let Some(t) = mesh
        .triangles
        .iter()
        .find(|t| t.iter().any(|&i| i as usize >= n))
    {
        return Err(Error::InvalidArgument(format!(
            "triangle {t:?} refers to a vertex beyond {n}"
        )));
    }
    let mut header = String::new();
    vertex_header(&mut header, n, "float", color);
    header.push_str(&format!(
        "element face {}\nproperty list uchar int vertex_indices\nend_header\n",
        mesh.triangles.len()
    ));
    let mut out = header.into_bytes();
    out.reserve(n * 15 + mesh.triangles.len() * 13);
    for (i, p) in mesh.positions_m.iter().enumerate() {
        for v in p {
            out.extend_from_slice(&v.to_le_bytes());
        }
        if color {
            out.extend_from_slice(&mesh.colors[i]);
        }
    }
    for t in &mesh.triangles {
        out.push(3);
        for &i in t {
            out.extend_from_slice(&(i as i32).to_le_bytes());
        }
    }
    Ok(out)
}

/// Writes a mesh as binary little-endian PLY (see [`encode_mesh_ply`]).
pub fn write_mesh_ply(path: impl AsRef<Path>, mesh: &Mesh) -> Result<()> {
    let path = path.as_ref();
    let bytes = encode_mesh_ply(mesh).map_err(|e| match e {
        Error::InvalidArgument(m) => Error::InvalidArgument(format!("{}: {m}", path.display())),
        other => other,
    })?;
    write_bytes(path, &bytes)
}

/// Encodes a point cloud as binary little-endian PLY, coordinates as `float` (f32) or, with
/// `double`, as f64; colours when present.
pub fn encode_points_ply(cloud: &PointCloud, double: bool) -> Result<Vec<u8>> {
    let n = cloud.points_m.len();
    if let Some(c) = &cloud.colors {
        if c.len() != n {
            return Err(Error::InvalidArgument(format!(
                "point cloud has {n} points but {} colours",
                c.len()
            )));
        }
    }
    let mut header = String::new();
    vertex_header(
        &mut header,
        n,
        if double { "double" } else { "float" },
        cloud.colors.is_some(),
    );
    header.push_str("end_header\n");
    let mut out = header.into_bytes();
    out.reserve(n * if double { 27 } else { 15 });
    for (i, p) in cloud.points_m.iter().enumerate() {
        for &v in p {
            if double {
                out.extend_from_slice(&v.to_le_bytes());
            } else {
                out.extend_from_slice(&(v as f32).to_le_bytes());
            }
        }
        if let Some(c) = &cloud.colors {
            out.extend_from_slice(&c[i]);
        }
    }
    Ok(out)
}

/// Writes a point cloud as binary little-endian PLY with `float` coordinates (see the module
/// doc for the precision this keeps).
pub fn write_points_ply(path: impl AsRef<Path>, cloud: &PointCloud) -> Result<()> {
    let path = path.as_ref();
    write_bytes(path, &encode_points_ply(cloud, false)?)
}

/// Writes a point cloud as binary little-endian PLY with `double` coordinates (exact).
pub fn write_points_ply_f64(path: impl AsRef<Path>, cloud: &PointCloud) -> Result<()> {
    let path = path.as_ref();
    write_bytes(path, &encode_points_ply(cloud, true)?)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mesh_golden_bytes() {
        let mesh = Mesh {
            positions_m: vec![[1.0, 2.0, 3.0], [0.0, 0.0, 0.0], [0.5, 0.0, -1.0]],
            colors: vec![[10, 20, 30], [0, 0, 0], [255, 255, 255]],
            triangles: vec![[0, 1, 2]],
        };
        let bytes = encode_mesh_ply(&mesh).unwrap();
        let h = parse_header(&bytes).unwrap();
        assert_eq!(h.encoding, Encoding::BinaryLe);
        let body = &bytes[h.body_start..];
        assert_eq!(body.len(), 3 * 15 + 13);
        assert_eq!(&body[0..4], &1.0f32.to_le_bytes());
        assert_eq!(&body[12..15], &[10, 20, 30]);
        assert_eq!(&body[45..], &[3, 0, 0, 0, 0, 1, 0, 0, 0, 2, 0, 0, 0]);
    }

    #[test]
    fn big_endian_with_extra_properties() {
        let mut bytes = b"ply\nformat binary_big_endian 1.0\nelement vertex 2\nproperty double x\nproperty double y\nproperty double z\nproperty float nx\nproperty ushort red\nproperty ushort green\nproperty ushort blue\nelement face 1\nproperty list uint short vertex_index\nend_header\n".to_vec();
        for (p, c) in [([1.5f64, -2.0, 3.25], 65535u16), ([0.0, 0.0, 7.0], 257)] {
            for v in p {
                bytes.extend_from_slice(&v.to_be_bytes());
            }
            bytes.extend_from_slice(&0.5f32.to_be_bytes());
            for _ in 0..3 {
                bytes.extend_from_slice(&c.to_be_bytes());
            }
        }
        // A degenerate 2-vertex "face" yields no triangle.
        bytes.extend_from_slice(&2u32.to_be_bytes());
        bytes.extend_from_slice(&0i16.to_be_bytes());
        bytes.extend_from_slice(&1i16.to_be_bytes());
        let (cloud, faces) = decode_ply(&bytes).unwrap();
        assert_eq!(cloud.points_m, vec![[1.5, -2.0, 3.25], [0.0, 0.0, 7.0]]);
        assert_eq!(cloud.colors, Some(vec![[255, 255, 255], [1, 1, 1]]));
        assert_eq!(faces, Some(vec![]));
    }
}
