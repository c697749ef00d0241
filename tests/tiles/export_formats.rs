//! Exports of a stored map as a surveyor, a GIS user and a web viewer receive them (issue 13):
//! LAS/LAZ in a z-up world frame with complete LAS 1.4 headers and a WKT CRS, COPC read by
//! independent readers (the `las` crate, laspy's `CopcReader`), and a 3D Tiles tileset whose GLBs
//! pass the Khronos glTF validator and which a real browser draws.
//!
//! The map is analytic: a ground plane 1.55 m below the first camera (map y = +1.55, y down) and
//! a sphere of radius 2 m 15 m ahead, fused voxel by voxel from their exact signed distances, so
//! every exported point can be checked against the known surface. Tools that are absent (python
//! laspy, PDAL, node, Chromium) make their part print `skipped: …` instead of failing.

use denser::export::{self, ExportOptions, ExportTarget};
use denser::geo::WorldFrame;
use denser::grid::{linear_index, Block, BlockIndex, GridParams, Layer, VOXELS_PER_SIDE};
use denser::map::store::MapStore;
use denser::mesh::Field;
use std::path::{Path, PathBuf};
use std::process::Command;

const VOXEL_M: f32 = 0.2;
const MU_M: f32 = 0.6;
const GROUND_Y_MAP: f64 = 1.55;
const SPHERE_C_MAP: [f64; 3] = [0.0, 0.0, 15.0];
const SPHERE_R: f64 = 2.0;

/// Signed distance (metres, positive in free space) of the scene, map frame.
fn sdf_map(p: [f64; 3]) -> f64 {
    let ground = GROUND_Y_MAP - p[1];
    let d = ((p[0] - SPHERE_C_MAP[0]).powi(2)
        + (p[1] - SPHERE_C_MAP[1]).powi(2)
        + (p[2] - SPHERE_C_MAP[2]).powi(2))
    .sqrt();
    ground.min(d - SPHERE_R)
}

fn color_map(p: [f64; 3]) -> [u8; 3] {
    if GROUND_Y_MAP - p[1] < 0.5 {
        // A chequered road: 2 m squares.
        let c = ((p[0] / 2.0).floor() as i64 + (p[2] / 2.0).floor() as i64).rem_euclid(2);
        if c == 0 {
            [200, 60, 40]
        } else {
            [230, 200, 60]
        }
    } else {
        [40, 160, 220]
    }
}

/// Fuses the analytic scene over x ∈ [−8, 8], z ∈ [−2, 30] (map frame) into a stored map.
fn analytic_map(dir: &Path, chunk_blocks: u32) -> MapStore {
    let grid = GridParams {
        voxel_size_m: VOXEL_M,
        truncation_m: MU_M,
    };
    let mut layer = Layer::new(grid);
    let bs = grid.block_size_m();
    let range = |lo: f64, hi: f64| (lo / bs).floor() as i32..=(hi / bs).floor() as i32;
    for bz in range(-2.0, 30.0) {
        for by in range(-3.0, 2.6) {
            for bx in range(-8.0, 8.0) {
                let b = BlockIndex([bx, by, bz]);
                let mut block = Block::default();
                let mut any = false;
                for z in 0..VOXELS_PER_SIDE {
                    for y in 0..VOXELS_PER_SIDE {
                        for x in 0..VOXELS_PER_SIDE {
                            let p = grid.voxel_center(b.voxel(x, y, z));
                            if !(-8.0..=8.0).contains(&p[0]) || !(-2.0..=30.0).contains(&p[2]) {
                                continue;
                            }
                            let d = sdf_map(p);
                            if d.abs() < MU_M as f64 {
                                block.fuse(
                                    linear_index(x, y, z),
                                    (d / MU_M as f64) as f32,
                                    Some(color_map(p)),
                                );
                                any = true;
                            }
                        }
                    }
                }
                if any {
                    layer.insert(b, Box::new(block));
                }
            }
        }
    }
    let mut store = MapStore::create(dir, grid, chunk_blocks).expect("create map");
    for (c, blocks) in denser::map::group_by_chunk(layer.indices_sorted(), chunk_blocks) {
        let refs: Vec<(BlockIndex, &Block)> = blocks
            .iter()
            .map(|b| (*b, layer.get(b).expect("block")))
            .collect();
        store.write_chunk(c, &refs, 0).expect("write chunk");
    }
    store.commit().expect("commit");
    store
}

/// Map-frame point of a local z-up point (the inverse rotation).
fn map_of_local(p: [f64; 3]) -> [f64; 3] {
    [-p[1], -p[2], p[0]]
}

fn python_with(modules: &str) -> Option<()> {
    let ok = Command::new("python3")
        .args(["-c", &format!("import {modules}")])
        .output()
        .map(|o| o.status.success())
        .unwrap_or(false);
    if ok {
        Some(())
    } else {
        crate::common::skip(&format!(
            "python3 with {modules} is not installed (tools/setup.sh installs it)"
        ));
        None
    }
}

fn run_python(script: &str, args: &[&str]) -> String {
    let o = Command::new("python3")
        .arg("-c")
        .arg(script)
        .args(args)
        .output()
        .expect("python3");
    let text = format!(
        "{}{}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    );
    assert!(o.status.success(), "python failed:\n{text}");
    String::from_utf8_lossy(&o.stdout).into_owned()
}

fn u16_at(b: &[u8], o: usize) -> u16 {
    u16::from_le_bytes([b[o], b[o + 1]])
}
fn u32_at(b: &[u8], o: usize) -> u32 {
    u32::from_le_bytes(b[o..o + 4].try_into().unwrap())
}
fn u64_at(b: &[u8], o: usize) -> u64 {
    u64::from_le_bytes(b[o..o + 8].try_into().unwrap())
}
fn f64_at(b: &[u8], o: usize) -> f64 {
    f64::from_le_bytes(b[o..o + 8].try_into().unwrap())
}

/// Checks the LAS 1.4 header fields issue 13 names; returns the point count.
fn check_las14_header(bytes: &[u8], format: u8, name: &str) -> u64 {
    assert_eq!(&bytes[..4], b"LASF", "{name}");
    assert_eq!((bytes[24], bytes[25]), (1, 4), "{name}: version");
    assert_eq!(bytes[104] & 0x3f, format, "{name}: point format");
    assert_ne!(u16_at(bytes, 6) & 16, 0, "{name}: WKT bit");
    let text = |o: usize| {
        String::from_utf8_lossy(&bytes[o..o + 32])
            .trim_end_matches('\0')
            .to_string()
    };
    assert_eq!(text(26), "EXTRACTION", "{name}: system identifier");
    assert!(text(58).starts_with("denser "), "{name}: {}", text(58));
    let (day, year) = (u16_at(bytes, 90), u16_at(bytes, 92));
    let now_year = 1970
        + (std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .unwrap()
            .as_secs()
            / 31_556_952) as u16;
    assert!(
        (1..=366).contains(&day) && year.abs_diff(now_year) <= 1,
        "{name}: date {day}/{year}"
    );
    assert_eq!(
        u32_at(bytes, 107),
        0,
        "{name}: legacy count is 0 for format ≥ 6"
    );
    let n = u64_at(bytes, 247);
    assert_eq!(u64_at(bytes, 255), n, "{name}: all points are return 1");
    for r in 1..15 {
        assert_eq!(u64_at(bytes, 255 + 8 * r), 0, "{name}: returns > 1");
    }
    for k in 0..6 {
        assert!(f64_at(bytes, 179 + 8 * k).is_finite(), "{name}: bounds");
    }
    n
}

#[test]
fn las_and_laz_exports_are_z_up_with_complete_headers_and_a_crs() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let store = analytic_map(&tmp.path().join("map"), 4);
    let mut options = ExportOptions::new(Field::Raw);
    for name in ["p.las", "p.laz"] {
        let path = tmp.path().join(name);
        let st = export::export_with(&store, &options, &ExportTarget::Points(path.clone()))
            .expect("export");
        assert!(st.vertices > 5_000, "{st:?}");
        let bytes = std::fs::read(&path).unwrap();
        assert_eq!(check_las14_header(&bytes, 7, name), st.vertices);
        // Every point lies on the analytic surface, read back in the local z-up frame.
        let cloud = denser::io::las::read_point_cloud(&path).expect("read");
        let mut on_ground = 0;
        let mut top = f64::NEG_INFINITY;
        for p in &cloud.points_m {
            let d = sdf_map(map_of_local(*p));
            assert!(d.abs() < 0.06, "{name}: {p:?} is {d} m off the surface");
            if (p[2] + GROUND_Y_MAP).abs() < 0.01 {
                on_ground += 1;
            }
            if p[0] > 12.0 && p[0] < 18.0 {
                top = top.max(p[2]);
            }
        }
        // Up is up: the ground is at z = −1.55 and the sphere's top at z = +2.
        assert!(on_ground * 2 > cloud.points_m.len(), "{on_ground}");
        assert!((top - SPHERE_R).abs() < 0.1, "sphere top at z = {top}");
        // Return numbers: 1 of 1 on every point.
        let data = las::Reader::from_path(&path).unwrap().read_all().unwrap();
        assert!(data.return_number().all(|r| r == 1));
        assert!(data.number_of_returns().all(|r| r == 1));
    }

    // An empty export (a box that meets nothing) has zero bounds, not ±inf.
    options.bbox = Some(export::Bbox::parse("1000,1000,1000,1001,1001,1001").unwrap());
    let empty = tmp.path().join("empty.laz");
    let st = export::export_with(&store, &options, &ExportTarget::Points(empty.clone())).unwrap();
    assert_eq!(st.vertices, 0);
    let bytes = std::fs::read(&empty).unwrap();
    assert_eq!(check_las14_header(&bytes, 7, "empty.laz"), 0);
    for k in 0..6 {
        assert_eq!(f64_at(&bytes, 179 + 8 * k), 0.0);
    }
    assert!(denser::io::las::read_point_cloud(&empty)
        .unwrap()
        .is_empty());

    // Georeferenced: the map origin at UTM 32N (691000, 5335000, 500), forward heading 30°.
    options.bbox = None;
    options.frame = Some(WorldFrame::parse("EPSG:32632@691000,5335000,500,30").unwrap());
    let geo = tmp.path().join("geo.laz");
    let st = export::export_with(&store, &options, &ExportTarget::Points(geo.clone())).unwrap();
    let cloud = denser::io::las::read_point_cloud(&geo).unwrap();
    assert_eq!(cloud.points_m.len() as u64, st.vertices);
    let h = 30f64.to_radians();
    for p in cloud.points_m.iter().step_by(97) {
        // Undo the georeference by hand: forward = (sin h, cos h) east/north, left = (−cos h, sin h).
        let d = [p[0] - 691000.0, p[1] - 5335000.0, p[2] - 500.0];
        let fwd = d[0] * h.sin() + d[1] * h.cos();
        let left = -d[0] * h.cos() + d[1] * h.sin();
        let sdf = sdf_map(map_of_local([fwd, left, d[2]]));
        assert!(sdf.abs() < 0.06, "{p:?}: {sdf}");
    }
    let reader = las::Reader::from_path(&geo).unwrap();
    let wkt = reader.header().get_wkt_crs_bytes().expect("a WKT VLR");
    assert!(String::from_utf8_lossy(wkt).contains("UTM zone 32N"));

    // An independent reader: laspy sees the same points and pyproj the CRS.
    if python_with("laspy, lazrs, pyproj").is_some() {
        let out = run_python(
            "import sys, laspy\n\
             f = laspy.read(sys.argv[1])\n\
             h = f.header\n\
             print(h.version, h.point_format.id, h.point_count, h.parse_crs().to_epsg())\n\
             print(h.system_identifier, h.generating_software, h.creation_date.year)\n\
             print(int(f.return_number.min()), int(f.number_of_returns.max()))\n\
             print(repr(float(f.x[0])), repr(float(f.y[0])), repr(float(f.z[0])))",
            &[geo.to_str().unwrap()],
        );
        let lines: Vec<&str> = out.lines().collect();
        assert_eq!(lines[0], format!("1.4 7 {} 32632", st.vertices), "{out}");
        assert!(lines[1].starts_with("EXTRACTION denser"), "{out}");
        assert_eq!(lines[2], "1 1", "{out}");
        let first: Vec<f64> = lines[3].split(' ').map(|t| t.parse().unwrap()).collect();
        for (got, want) in first.iter().zip(cloud.points_m[0]) {
            assert!((got - want).abs() < 1e-6, "{out}");
        }
    }
    // PDAL, where the distribution ships it.
    if Command::new("pdal").arg("--version").output().is_ok() {
        let o = Command::new("pdal")
            .args(["info", "--summary", geo.to_str().unwrap()])
            .output()
            .unwrap();
        let t = String::from_utf8_lossy(&o.stdout);
        assert!(o.status.success(), "{t}");
        let j: serde_json::Value = serde_json::from_str(&t).unwrap();
        assert_eq!(
            j["summary"]["num_points"].as_u64(),
            Some(st.vertices),
            "{t}"
        );
        assert!(t.contains("32632"), "{t}");
    } else {
        crate::common::skip("pdal is not installed (Debian 12 does not ship it)");
    }
}

#[test]
fn bad_georef_names_the_file_and_the_problem() {
    let tmp = tempfile::tempdir().unwrap();
    let missing = tmp.path().join("nowhere.txt");
    let e = WorldFrame::parse(missing.to_str().unwrap())
        .unwrap_err()
        .to_string();
    assert!(e.contains("nowhere.txt"), "{e}");
    let bad = tmp.path().join("skewed.txt");
    std::fs::write(&bad, "1 0.5 0 0\n0 1 0 0\n0 0 1 0\n0 0 0 1\n").unwrap();
    let e = WorldFrame::parse(bad.to_str().unwrap())
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("skewed.txt") && e.contains("not a rotation"),
        "{e}"
    );
    let e = WorldFrame::parse("EPSG:32632@1,2").unwrap_err().to_string();
    assert!(e.contains("expected 3 coordinates"), "{e}");
}

/// All points of a LAS/LAZ/COPC file as sorted integer coordinates and colours.
fn sorted_points(path: &Path) -> Vec<([i64; 3], [u16; 3])> {
    let data = las::Reader::from_path(path)
        .expect("open")
        .read_all()
        .expect("points");
    let xyz = data.x().zip(data.y()).zip(data.z());
    let mut v: Vec<([i64; 3], [u16; 3])> = xyz
        .zip(data.rgb().expect("colour"))
        .map(|(((x, y), z), (r, g, b))| ([x, y, z].map(|c| (c * 1000.0).round() as i64), [r, g, b]))
        .collect();
    v.sort_unstable();
    v
}

#[test]
fn copc_is_an_octree_that_independent_readers_query() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let store = analytic_map(&tmp.path().join("map"), 4);
    let mut options = ExportOptions::new(Field::Raw);
    let laz = tmp.path().join("ref.laz");
    export::export_with(&store, &options, &ExportTarget::Points(laz.clone())).unwrap();
    // Built in RAM, then with a budget so small that the top levels stream from spill files.
    let copc = tmp.path().join("a.copc.laz");
    let st = export::export_with(&store, &options, &ExportTarget::Points(copc.clone())).unwrap();
    let c = st.copc.expect("copc stats");
    assert_eq!(c.streamed_nodes, 0);
    options.memory_budget_bytes = 0;
    let small = tmp.path().join("b.copc.laz");
    let st2 = export::export_with(&store, &options, &ExportTarget::Points(small.clone())).unwrap();
    let c2 = st2.copc.expect("copc stats");
    assert!(c2.streamed_nodes > 0, "{c2:?}");
    assert!(c.max_level >= 2 && c.nodes > 8, "{c:?}");
    assert!(
        !tmp.path().join("b.copc.laz.tmp").exists(),
        "spill folder left behind"
    );
    // The octree does not depend on where nodes were built: same bytes.
    assert!(
        std::fs::read(&copc).unwrap() == std::fs::read(&small).unwrap(),
        "COPC built out of core differs from the in-memory build"
    );
    let bytes = std::fs::read(&copc).unwrap();
    assert_eq!(check_las14_header(&bytes, 7, "a.copc.laz"), st.vertices);
    // The COPC info VLR is first, at byte 375.
    assert_eq!(&bytes[375 + 2..375 + 6], b"copc");
    assert_eq!(u16_at(&bytes, 375 + 18), 1);
    // Read as plain LAZ (chunk table) by the las crate: the same points as the LAZ export.
    assert_eq!(sorted_points(&copc), sorted_points(&laz));

    if python_with("laspy, lazrs").is_none() {
        return;
    }
    // laspy's CopcReader: the whole octree, the root level, and a spatial query, against the
    // point list computed here.
    let all = sorted_points(&laz);
    let (q_lo, q_hi) = ([5.0, -3.0, -2.0], [17.0, 3.0, 0.5]);
    let inside = all
        .iter()
        .filter(|(p, _)| {
            (0..3).all(|a| {
                let v = p[a] as f64 / 1000.0;
                v >= q_lo[a] && v <= q_hi[a]
            })
        })
        .count();
    let out = run_python(
        "import sys, numpy as np, laspy\n\
         from laspy.copc import Bounds\n\
         with laspy.CopcReader.open(sys.argv[1]) as r:\n\
         \x20   info = r.copc_info\n\
         \x20   print(r.header.point_count, len(r.query()))\n\
         \x20   root = r.query(level=0)\n\
         \x20   cell = 2 * info.halfsize / 128\n\
         \x20   lo = np.array(info.center) - info.halfsize\n\
         \x20   k = np.floor((np.stack([root.x, root.y, root.z], 1) - lo) / cell + 1e-6).astype(np.int64)\n\
         \x20   print(len(root), len(np.unique(k, axis=0)))\n\
         \x20   coarse = r.query(level=range(0, 2))\n\
         \x20   print(len(coarse))\n\
         \x20   b = Bounds(mins=np.array([5.0, -3.0, -2.0]), maxs=np.array([17.0, 3.0, 0.5]))\n\
         \x20   q = r.query(bounds=b)\n\
         \x20   print(len(q))",
        &[copc.to_str().unwrap()],
    );
    let v: Vec<Vec<u64>> = out
        .lines()
        .map(|l| l.split(' ').map(|t| t.parse().unwrap()).collect())
        .collect();
    assert_eq!(v[0], vec![st.vertices, st.vertices], "{out}");
    // The root holds one point per cell of its 128³ grid.
    assert_eq!(v[1], vec![c.root_points, c.root_points], "{out}");
    assert!(v[2][0] > c.root_points && v[2][0] < st.vertices, "{out}");
    assert_eq!(v[3][0] as usize, inside, "{out}");
}

fn walk_tiles(
    dir: &Path,
    tile: &serde_json::Value,
    parent: Option<(&[f64], f64)>,
    level_tris: &mut Vec<u64>,
    depth: usize,
    glbs: &mut Vec<PathBuf>,
) {
    let b: Vec<f64> = tile["boundingVolume"]["box"]
        .as_array()
        .expect("box")
        .iter()
        .map(|v| v.as_f64().unwrap())
        .collect();
    let err = tile["geometricError"].as_f64().expect("error");
    if let Some((pb, perr)) = parent {
        assert!(err < perr, "geometric error must shrink: {err} ≥ {perr}");
        for a in 0..3 {
            let h = b[3 + 4 * a];
            let ph = pb[3 + 4 * a];
            assert!(
                b[a] - h >= pb[a] - ph - 1e-6 && b[a] + h <= pb[a] + ph + 1e-6,
                "child box outside its parent"
            );
        }
    }
    if level_tris.len() <= depth {
        level_tris.resize(depth + 1, 0);
    }
    if let Some(uri) = tile["content"]["uri"].as_str() {
        let path = dir.join(uri);
        let bytes = std::fs::read(&path).expect("content exists");
        let (json, bin) = denser::io::glb::parse_glb(&bytes).expect("GLB");
        let prim = &json["meshes"][0]["primitives"][0];
        assert!(prim["attributes"]["COLOR_0"].is_u64(), "vertex colours");
        let acc = &json["accessors"][0];
        let n = acc["count"].as_u64().unwrap() as usize;
        level_tris[depth] += json["accessors"][2]["count"].as_u64().unwrap() / 3;
        // Every vertex (glTF y-up → tileset z-up: x, −z, y) inside the tile's box.
        for i in 0..n {
            let f = |k: usize| {
                f32::from_le_bytes(bin[12 * i + 4 * k..12 * i + 4 * k + 4].try_into().unwrap())
                    as f64
            };
            let p = [f(0), -f(2), f(1)];
            for a in 0..3 {
                assert!(
                    (p[a] - b[a]).abs() <= b[3 + 4 * a] + 1e-3,
                    "{uri}: vertex {p:?} outside"
                );
            }
        }
        glbs.push(path);
    }
    if let Some(children) = tile["children"].as_array() {
        for c in children {
            walk_tiles(dir, c, Some((&b, err)), level_tris, depth + 1, glbs);
        }
    } else {
        assert_eq!(err, 0.0, "leaves are full resolution");
    }
}

/// The absolute path of a program on PATH (puppeteer needs one).
fn chromium_path(name: &str) -> PathBuf {
    std::env::var_os("PATH")
        .and_then(|p| {
            std::env::split_paths(&p)
                .map(|d| d.join(name))
                .find(|f| f.is_file())
        })
        .unwrap_or_else(|| PathBuf::from(name))
}

/// A static file server on 127.0.0.1 for the browser test: `/data/…` from `data`, the rest from
/// `root`. Serves `requests` requests at most and stops when the test ends.
fn serve(root: PathBuf, data: PathBuf) -> u16 {
    use std::io::{BufRead, BufReader, Write};
    let listener = std::net::TcpListener::bind("127.0.0.1:0").expect("bind");
    let port = listener.local_addr().unwrap().port();
    std::thread::spawn(move || {
        for stream in listener.incoming().take(5000) {
            let Ok(mut s) = stream else { continue };
            let mut line = String::new();
            let mut r = BufReader::new(s.try_clone().unwrap());
            if r.read_line(&mut line).is_err() {
                continue;
            }
            loop {
                let mut h = String::new();
                if r.read_line(&mut h).map(|n| n <= 2).unwrap_or(true) {
                    break;
                }
            }
            let path = line
                .split(' ')
                .nth(1)
                .unwrap_or("/")
                .split('?')
                .next()
                .unwrap_or("/");
            let file = if let Some(rest) = path.strip_prefix("/data/") {
                data.join(rest)
            } else {
                root.join(path.trim_start_matches('/'))
            };
            let mime = match file.extension().and_then(|e| e.to_str()) {
                Some("html") => "text/html",
                Some("js") | Some("mjs") => "text/javascript",
                Some("json") => "application/json",
                Some("glb") => "model/gltf-binary",
                _ => "application/octet-stream",
            };
            let reply = match std::fs::read(&file) {
                Ok(body) if !path.contains("..") => {
                    let mut v = format!(
                        "HTTP/1.1 200 OK\r\nContent-Type: {mime}\r\nContent-Length: {}\r\nConnection: close\r\n\r\n",
                        body.len()
                    )
                    .into_bytes();
                    v.extend(body);
                    v
                }
                _ => b"HTTP/1.1 404 Not Found\r\nContent-Length: 0\r\nConnection: close\r\n\r\n"
                    .to_vec(),
            };
            let _ = s.write_all(&reply);
        }
    });
    port
}

#[test]
fn tileset_has_levels_valid_glbs_and_draws_in_a_browser() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let store = analytic_map(&tmp.path().join("map"), 4);
    let options = ExportOptions::new(Field::Raw);
    let ply = tmp.path().join("m.ply");
    let mesh_st = export::export_with(&store, &options, &ExportTarget::Mesh(ply)).unwrap();
    let dir = tmp.path().join("tiles");
    let st = export::export_with(&store, &options, &ExportTarget::Tiles(dir.clone())).unwrap();
    let t = st.tileset.expect("tileset stats");
    assert!(t.levels >= 3, "{t:?}");
    // The full-resolution tiles hold exactly the triangles of the stitched mesh export.
    assert_eq!(t.leaf_triangles, mesh_st.triangles);
    let ts: serde_json::Value =
        serde_json::from_slice(&std::fs::read(dir.join("tileset.json")).unwrap()).unwrap();
    assert_eq!(ts["asset"]["version"], "1.1");
    assert!(
        ts["root"]["transform"].is_null(),
        "no georeference, no transform"
    );
    let mut level_tris = Vec::new();
    let mut glbs = Vec::new();
    let top = ts["geometricError"].as_f64().unwrap();
    walk_tiles(&dir, &ts["root"], None, &mut level_tris, 0, &mut glbs);
    assert!(ts["root"]["geometricError"].as_f64().unwrap() < top);
    assert_eq!(glbs.len(), t.tiles);
    // Coarser levels have fewer triangles: the root far fewer than the full resolution.
    assert_eq!(*level_tris.last().unwrap(), t.leaf_triangles);
    assert!(level_tris[0] * 4 < t.leaf_triangles, "{level_tris:?}");

    // Georeferenced: the root transform is ECEF at the origin (pyproj: 32632 → 4978).
    let mut geo = options.clone();
    geo.frame = Some(WorldFrame::parse("EPSG:32632@691000,5335000,500").unwrap());
    let gdir = tmp.path().join("geo_tiles");
    export::export_with(&store, &geo, &ExportTarget::Tiles(gdir.clone())).unwrap();
    let gts: serde_json::Value =
        serde_json::from_slice(&std::fs::read(gdir.join("tileset.json")).unwrap()).unwrap();
    let m: Vec<f64> = gts["root"]["transform"]
        .as_array()
        .expect("transform")
        .iter()
        .map(|v| v.as_f64().unwrap())
        .collect();
    let expect = [4177891.130820783, 855128.5779302452, 4727618.047799967];
    for k in 0..3 {
        assert!((m[12 + k] - expect[k]).abs() < 1e-3, "{m:?}");
    }

    // The Khronos glTF validator on every GLB.
    let web = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tools/web");
    let have_node_modules = web.join("node_modules/gltf-validator").exists()
        && web.join("node_modules/3d-tiles-renderer").exists();
    if !have_node_modules {
        crate::common::skip("tools/web/node_modules is absent (tools/setup.sh runs npm ci there)");
        return;
    }
    let mut cmd = Command::new("node");
    cmd.arg(web.join("validate_glb.mjs"));
    for g in &glbs {
        cmd.arg(g);
    }
    let o = cmd.output().expect("node");
    let out = String::from_utf8_lossy(&o.stdout);
    assert!(
        o.status.success(),
        "{out}{}",
        String::from_utf8_lossy(&o.stderr)
    );
    assert!(
        out.contains(&format!("validated {} files: 0 errors", glbs.len())),
        "{out}"
    );

    // A real browser: headless Chromium draws the tileset with 3DTilesRendererJS.
    let chromium = ["chromium", "chromium-browser", "google-chrome"]
        .into_iter()
        .find(|c| Command::new(c).arg("--version").output().is_ok());
    let Some(chromium) = chromium else {
        crate::common::skip("chromium is not installed (tools/setup.sh installs it)");
        return;
    };
    let port = serve(web.clone(), dir.clone());
    let shot = tmp.path().join("shot.png");
    let o = Command::new("node")
        .arg(web.join("screenshot.mjs"))
        .arg(format!("http://127.0.0.1:{port}/viewer.html"))
        .arg(&shot)
        .arg(chromium_path(chromium))
        .arg("60000")
        .output()
        .expect("node");
    let log = format!(
        "{}{}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    );
    eprintln!("{log}");
    assert!(o.status.success() && shot.exists(), "no screenshot: {log}");
    let img = image::open(&shot).expect("png").into_rgb8();
    let lit = img.pixels().filter(|p| p.0.iter().any(|&c| c > 16)).count();
    let blue = img
        .pixels()
        .filter(|p| p.0[2] > 120 && p.0[2] > p.0[0] + 40)
        .count();
    let total = (img.width() * img.height()) as usize;
    if let Ok(keep) = std::env::var("DENSER_KEEP_SCREENSHOT") {
        std::fs::copy(&shot, keep).expect("keep screenshot");
    }
    // The road and the (blue) sphere are drawn.
    assert!(lit * 20 > total, "only {lit} of {total} pixels drawn");
    assert!(blue > 100, "no sphere pixels ({blue})");
}

/// Issue 40: chunks are meshed in parallel and stitched in their sorted order, so every format
/// is byte for byte the same on 1, 2 and 5 threads (the mesh, PLY, LAS and COPC points, a box,
/// and a small memory budget that narrows the meshing window to one chunk and makes COPC compress
/// its nodes in many batches).
#[test]
fn exports_are_byte_identical_on_any_number_of_threads() {
    let dir = tempfile::tempdir().expect("tempdir");
    let store = analytic_map(&dir.path().join("map"), 2);
    assert!(store.chunk_indices().len() > 50, "many chunks to share out");
    let mut small = ExportOptions::new(Field::Raw);
    small.memory_budget_bytes = 64 << 10;
    let mut boxed = ExportOptions::new(Field::Raw);
    boxed.bbox = Some(export::Bbox::parse("-3,-2,-1,3,3,20").expect("bbox"));
    type Target = fn(PathBuf) -> ExportTarget;
    let cases: Vec<(&str, ExportOptions, Target)> = vec![
        (
            "mesh.ply",
            ExportOptions::new(Field::Raw),
            ExportTarget::Mesh,
        ),
        (
            "points.ply",
            ExportOptions::new(Field::Raw),
            ExportTarget::Points,
        ),
        (
            "points.las",
            ExportOptions::new(Field::Raw),
            ExportTarget::Points,
        ),
        (
            "points.copc.laz",
            ExportOptions::new(Field::Raw),
            ExportTarget::Points,
        ),
        ("boxed.ply", boxed, ExportTarget::Mesh),
        ("small_budget.ply", small.clone(), ExportTarget::Mesh),
        // COPC's nodes compressed in many batches (an eighth of 1 024 points each).
        ("small_budget.copc.laz", small, ExportTarget::Points),
    ];
    for (name, options, target) in &cases {
        let mut outputs = Vec::new();
        for threads in [1, 2, 5] {
            let path = dir.path().join(format!("{threads}_{name}"));
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .expect("pool");
            let st = pool
                .install(|| export::export_with(&store, options, &target(path.clone())))
                .expect("export");
            assert!(st.vertices > 1000, "{name}: {st:?}");
            outputs.push(std::fs::read(&path).expect("read"));
        }
        assert!(outputs[0] == outputs[1], "{name}: 1 and 2 threads differ");
        assert!(outputs[0] == outputs[2], "{name}: 1 and 5 threads differ");
    }
    // A tileset: every file of the folder.
    let mut trees = Vec::new();
    for threads in [1, 2, 5] {
        let out = dir.path().join(format!("tiles_{threads}"));
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .expect("pool");
        pool.install(|| {
            export::export_with(
                &store,
                &ExportOptions::new(Field::Raw),
                &ExportTarget::Tiles(out.clone()),
            )
        })
        .expect("tileset");
        let mut files = Vec::new();
        let mut stack = vec![out.clone()];
        while let Some(d) = stack.pop() {
            for e in std::fs::read_dir(&d).expect("ls") {
                let p = e.expect("entry").path();
                if p.is_dir() {
                    stack.push(p);
                } else {
                    let rel = p.strip_prefix(&out).expect("under").to_path_buf();
                    files.push((rel, std::fs::read(&p).expect("read")));
                }
            }
        }
        files.sort();
        assert!(files.len() > 20, "{} tiles", files.len());
        trees.push(files);
    }
    assert!(trees[0] == trees[1], "tilesets of 1 and 2 threads differ");
    assert!(trees[0] == trees[2], "tilesets of 1 and 5 threads differ");
}
