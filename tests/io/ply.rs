//! PLY: round trips of the writers, files in the styles other tools write (ASCII with extra
//! properties, quads, float colours, big endian), and errors.

use denser::frame::PointCloud;
use denser::io::ply::{
    read_mesh_ply, read_ply, write_mesh_ply, write_points_ply, write_points_ply_f64,
};
use denser::mesh::Mesh;

fn test_mesh() -> Mesh {
    // A unit cube's 8 corners and 12 CCW-outward triangles.
    let positions_m: Vec<[f32; 3]> = (0..8)
        .map(|i| {
            [
                (i & 1) as f32,
                ((i >> 1) & 1) as f32 + 0.25,
                ((i >> 2) & 1) as f32 - 1e-3,
            ]
        })
        .collect();
    let colors = (0..8).map(|i| [i as u8 * 30, 255 - i as u8, 7]).collect();
    let triangles = vec![
        [0, 2, 1],
        [1, 2, 3],
        [4, 5, 6],
        [5, 7, 6],
        [0, 1, 4],
        [1, 5, 4],
        [2, 6, 3],
        [3, 6, 7],
        [0, 4, 2],
        [2, 4, 6],
        [1, 3, 5],
        [3, 7, 5],
    ];
    Mesh {
        positions_m,
        colors,
        triangles,
    }
}

#[test]
fn mesh_round_trip() {
    let tmp = tempfile::tempdir().unwrap();
    let path = tmp.path().join("cube.ply");
    let mesh = test_mesh();
    write_mesh_ply(&path, &mesh).unwrap();
    let back = read_mesh_ply(&path).unwrap();
    assert_eq!(back, mesh);
    assert!((back.surface_area_m2() - 6.0).abs() < 1e-6);
    // Documented size: header + 15 bytes per vertex + 13 per triangle.
    let bytes = std::fs::read(&path).unwrap();
    let header_len = bytes
        .windows(11)
        .position(|w| w == b"end_header\n")
        .unwrap()
        + 11;
    assert_eq!(bytes.len() - header_len, 8 * 15 + 12 * 13);
    // Without colours: no colour properties, read back as white.
    let plain = Mesh {
        colors: vec![],
        ..mesh.clone()
    };
    write_mesh_ply(&path, &plain).unwrap();
    let text = String::from_utf8_lossy(&std::fs::read(&path).unwrap()[..200]).to_string();
    assert!(!text.contains("red"));
    let back = read_mesh_ply(&path).unwrap();
    assert_eq!(back.positions_m, mesh.positions_m);
    assert!(back.colors.iter().all(|c| *c == [255, 255, 255]));
    // Bad meshes are refused before writing.
    let bad = Mesh {
        triangles: vec![[0, 1, 8]],
        ..mesh
    };
    let e = write_mesh_ply(tmp.path().join("bad.ply"), &bad)
        .unwrap_err()
        .to_string();
    assert!(e.contains("bad.ply") && e.contains("[0, 1, 8]"), "{e}");
}

#[test]
fn points_round_trip_float_and_double() {
    let tmp = tempfile::tempdir().unwrap();
    let cloud = PointCloud {
        points_m: (0..1000)
            .map(|i| [i as f64 * 0.001 - 0.3, 12.345 + i as f64, -7.0])
            .collect(),
        colors: Some((0..1000).map(|i| [i as u8, (i / 4) as u8, 99]).collect()),
    };
    let f32_path = tmp.path().join("p32.ply");
    write_points_ply(&f32_path, &cloud).unwrap();
    let (back, faces) = read_ply(&f32_path).unwrap();
    assert!(faces.is_none());
    assert_eq!(back.colors, cloud.colors);
    for (a, b) in back.points_m.iter().zip(&cloud.points_m) {
        for k in 0..3 {
            // f32 rounding: relative 2^-24.
            assert!(
                (a[k] - b[k]).abs() <= b[k].abs() * 6e-8 + 1e-12,
                "{a:?} {b:?}"
            );
        }
    }
    let f64_path = tmp.path().join("p64.ply");
    let far = PointCloud {
        points_m: cloud
            .points_m
            .iter()
            .map(|p| [p[0] + 500_000.0, p[1] + 5_400_000.0, p[2]])
            .collect(),
        colors: None,
    };
    write_points_ply_f64(&f64_path, &far).unwrap();
    let (back, _) = read_ply(&f64_path).unwrap();
    assert_eq!(back, far);
}

#[test]
fn ascii_file_with_extras_quads_and_float_colours() {
    // As MeshLab/CloudCompare write them: comments, normals, alpha, a quad, an edge element.
    let text = "ply\r\nformat ascii 1.0\r\ncomment made by hand\r\nobj_info nothing\r\n\
element vertex 5\r\nproperty float x\r\nproperty float y\r\nproperty float z\r\n\
property float nx\r\nproperty float ny\r\nproperty float nz\r\n\
property float red\r\nproperty float green\r\nproperty float blue\r\nproperty float alpha\r\n\
element face 2\r\nproperty uchar flags\r\nproperty list uchar int vertex_indices\r\n\
element edge 1\r\nproperty int vertex1\r\nproperty int vertex2\r\nend_header\r\n\
0 0 0  0 0 1  1 0 0 1\r\n1 0 0  0 0 1  0 1 0 1\r\n1 1 0  0 0 1  0 0 1 1\r\n\
0 1 0  0 0 1  0.5 0.5 0.5 1\r\n2.5 -1e-3 3e2  0 0 1  0 0 0 1\r\n\
0 4 0 1 2 3\r\n0 3 0 1 4\r\n0 1\r\n";
    let tmp = tempfile::tempdir().unwrap();
    let path = tmp.path().join("ascii.ply");
    std::fs::write(&path, text).unwrap();
    let (cloud, faces) = read_ply(&path).unwrap();
    assert_eq!(cloud.points_m[4], [2.5, -1e-3, 300.0]);
    assert_eq!(
        cloud.colors.unwrap(),
        vec![
            [255, 0, 0],
            [0, 255, 0],
            [0, 0, 255],
            [128, 128, 128],
            [0, 0, 0]
        ]
    );
    assert_eq!(faces.unwrap(), vec![[0, 1, 2], [0, 2, 3], [0, 1, 4]]);
    let mesh = read_mesh_ply(&path).unwrap();
    assert!((mesh.surface_area_m2() - (1.0 + 0.5 * 300.0)).abs() < 1e-3);
}

#[test]
fn errors_name_the_file() {
    let tmp = tempfile::tempdir().unwrap();
    let path = tmp.path().join("cube.ply");
    write_mesh_ply(&path, &test_mesh()).unwrap();
    let bytes = std::fs::read(&path).unwrap();
    let cut = tmp.path().join("cut.ply");
    std::fs::write(&cut, &bytes[..bytes.len() - 20]).unwrap();
    let e = read_ply(&cut).unwrap_err().to_string();
    assert!(
        e.contains("cut.ply") && e.contains("truncated") && e.contains("face"),
        "{e}"
    );
    std::fs::write(&cut, &bytes[..100]).unwrap();
    let e = read_ply(&cut).unwrap_err().to_string();
    assert!(e.contains("cut.ply") && e.contains("end_header"), "{e}");

    let bad = tmp.path().join("bad.ply");
    std::fs::write(&bad, "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nproperty float z\nend_header\n1 2 zz\n").unwrap();
    let e = read_ply(&bad).unwrap_err().to_string();
    assert!(e.contains("bad.ply") && e.contains("'zz'"), "{e}");
    std::fs::write(&bad, "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nproperty float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n1 2 3\n3 0 0 1\n").unwrap();
    let e = read_ply(&bad).unwrap_err().to_string();
    assert!(e.contains("bad.ply") && e.contains("beyond"), "{e}");
    std::fs::write(&bad, "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nend_header\n1 2\n").unwrap();
    let e = read_ply(&bad).unwrap_err().to_string();
    assert!(e.contains("bad.ply") && e.contains("x, y, z"), "{e}");
    std::fs::write(&bad, "PLY?").unwrap();
    assert!(read_ply(&bad).unwrap_err().to_string().contains("magic"));
    let e = read_ply(tmp.path().join("none.ply"))
        .unwrap_err()
        .to_string();
    assert!(e.contains("none.ply"), "{e}");
}
