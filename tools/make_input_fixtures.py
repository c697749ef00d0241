#!/usr/bin/env python3
"""Write denser's input fixtures (folders of scans with a trajectory, ROS 2 bags) from a KITTI drive.

Tests compare denser's readers of these files against the same data in the KITTI layout, so
everything here is written by independent libraries (pypcd4, plyfile, laspy + lazrs, numpy,
rosbags), never by denser itself.

    python3 tools/make_input_fixtures.py KITTI_SEQ_DIR OUT_DIR [--frames N] [--poses POSES_FILE]

KITTI_SEQ_DIR holds calib.txt (P0..P3 and Tr or Tr_velo_to_cam, 3x4 row-major), times.txt,
velodyne/NNNNNN.bin and maybe image_0/ and image_1/. Poses (3x4 world_from_cam0 per line) come
from POSES_FILE or SEQ_DIR/../../poses/<NN>.txt. Rotations of the poses and of Tr (cam0_from_velo)
are snapped to the nearest rotation (SVD, U.V^T with det fixed), as denser's readers do.

Under OUT_DIR (existing outputs are replaced) it writes, for frames [0, N):
  scans_<form>/       form in pcd_ascii pcd_binary pcd_binary_compressed ply las laz bin:
                      scans/NNNNNN.<ext> (velodyne-frame x,y,z + intensity = reflectance),
                      trajectory.tum (t tx ty tz qx qy qz qw of world_from_cam0, %.17g),
                      poses_kitti.txt (snapped 3x4), extrinsic.txt (4x4 cam0_from_velo), times.txt
  scans_stamped/      scans/<times[i]+1000 as %.6f>.pcd (binary), trajectory.tum at those
                      stamps, extrinsic.txt (no times.txt: the stamps come from the names)
  bag_mcap/           MCAP, zstd chunks: /tf_static, /tf, /points (PointCloud2 float32)
  bag_sqlite/         SQLite3: /tf_static, /odom (nav_msgs/Odometry), /points
  bag_pose_stamped/   MCAP: /tf_static, /pose (geometry_msgs/PoseStamped), /points
  bag_double/         MCAP: /tf_static, /tf, /points with float64 x,y,z, height 2 (organised)
  bag_unordered/      faulty: /points of frames 1 and 2 written in swapped order
  bag_no_tf_static/   faulty: no /tf_static
  bag_cut/            faulty: bag_mcap with its .mcap truncated to 70 % (inside a record)
  bag_no_metadata/    faulty: bag_mcap without metadata.yaml
  bag_stereo/, bag_stereo_compressed/, bag_stereo_raw/ (image_raw with a distortion: to refuse)
                      (only with image_0 and image_1 for every frame)
  manifest.json       files, frames, topics, faults and library versions

Bag stamps: header.stamp = log time = times[i] + 1000 s (exact, in ns). Frames: map (fixed),
base_link (= cam0), velodyne, cam_left (= cam0), cam_right.

Exit status: 0 done, 3 a Python package is missing (the message names it), 1 other errors.
"""
from __future__ import annotations

import argparse
import importlib
import importlib.metadata
import json
import shutil
import sys
import time
from decimal import Decimal
from pathlib import Path

PACKAGES = {"numpy": "numpy", "rosbags": "rosbags", "pypcd4": "pypcd4", "plyfile": "plyfile",
            "laspy": "laspy", "lazrs": "lazrs", "PIL": "pillow"}
for _module, _dist in PACKAGES.items():
    try:
        importlib.import_module(_module)
    except ImportError:
        print(f"make_input_fixtures: missing Python package {_dist} (bash tools/setup.sh installs it)",
              file=sys.stderr)
        sys.exit(3)

import laspy  # noqa: E402
import numpy as np  # noqa: E402
import plyfile  # noqa: E402
import pypcd4  # noqa: E402
from PIL import Image  # noqa: E402
from rosbags.rosbag2 import CompressionFormat, CompressionMode, StoragePlugin, Writer  # noqa: E402
from rosbags.typesys import Stores, get_typestore  # noqa: E402

TS = get_typestore(Stores.ROS2_HUMBLE)
T = TS.types
STAMP_OFFSET_S = 1000  # stamps are times[i] + 1000 s, so they are not frame indices
FORMS = {"pcd_ascii": "pcd", "pcd_binary": "pcd", "pcd_binary_compressed": "pcd",
         "ply": "ply", "las": "las", "laz": "laz", "bin": "bin"}


# ----------------------------------------------------------------------------- input
def snap_rotation(m: np.ndarray) -> np.ndarray:
    """The 3x4 (or 4x4) transform with its rotation replaced by the nearest rotation."""
    u, _, vt = np.linalg.svd(m[:3, :3])
    if np.linalg.det(u @ vt) < 0:
        u[:, 2] = -u[:, 2]
    out = m.copy()
    out[:3, :3] = u @ vt
    return out


def quaternion(r: np.ndarray) -> tuple[float, float, float, float]:
    """(x, y, z, w) of a rotation matrix, w >= 0 (Shepperd's method)."""
    tr = r[0, 0] + r[1, 1] + r[2, 2]
    if tr > 0:
        s = 2.0 * np.sqrt(tr + 1.0)
        q = ((r[2, 1] - r[1, 2]) / s, (r[0, 2] - r[2, 0]) / s, (r[1, 0] - r[0, 1]) / s, 0.25 * s)
    elif r[0, 0] > r[1, 1] and r[0, 0] > r[2, 2]:
        s = 2.0 * np.sqrt(1.0 + r[0, 0] - r[1, 1] - r[2, 2])
        q = (0.25 * s, (r[0, 1] + r[1, 0]) / s, (r[0, 2] + r[2, 0]) / s, (r[2, 1] - r[1, 2]) / s)
    elif r[1, 1] > r[2, 2]:
        s = 2.0 * np.sqrt(1.0 + r[1, 1] - r[0, 0] - r[2, 2])
        q = ((r[0, 1] + r[1, 0]) / s, 0.25 * s, (r[1, 2] + r[2, 1]) / s, (r[0, 2] - r[2, 0]) / s)
    else:
        s = 2.0 * np.sqrt(1.0 + r[2, 2] - r[0, 0] - r[1, 1])
        q = ((r[0, 2] + r[2, 0]) / s, (r[1, 2] + r[2, 1]) / s, 0.25 * s, (r[1, 0] - r[0, 1]) / s)
    q = np.array(q, dtype=np.float64)
    q /= np.linalg.norm(q)
    if q[3] < 0:
        q = -q
    return tuple(float(v) for v in q)


class Drive:
    """The selected frames of a KITTI sequence."""

    def __init__(self, seq: Path, frames: int | None, poses_file: Path | None):
        self.seq = seq
        calib = {}
        for line in (seq / "calib.txt").read_text().splitlines():
            if ":" in line:
                key, vals = line.split(":", 1)
                calib[key.strip()] = np.array([float(v) for v in vals.split()], dtype=np.float64)
        tr = calib.get("Tr", calib.get("Tr_velo_to_cam"))
        if tr is None:
            raise SystemExit(f"make_input_fixtures: no Tr in {seq / 'calib.txt'}")
        self.p = {k: calib[k].reshape(3, 4) for k in ("P0", "P1", "P2", "P3") if k in calib}
        self.cam0_from_velo = snap_rotation(np.vstack([tr.reshape(3, 4), [0, 0, 0, 1]]))
        self.time_text = [t.strip() for t in (seq / "times.txt").read_text().split()]
        poses_file = poses_file or seq.parent.parent / "poses" / f"{seq.name}.txt"
        rows = [np.array([float(v) for v in ln.split()]).reshape(3, 4)
                for ln in poses_file.read_text().splitlines() if ln.strip()]
        available = 0
        while (seq / "velodyne" / f"{available:06d}.bin").exists():
            available += 1
        n = available if frames is None else frames
        if n < 1 or n > min(available, len(self.time_text), len(rows)):
            raise SystemExit(f"make_input_fixtures: asked for {n} frames; {seq} has {available} scans, "
                             f"{len(self.time_text)} times, {len(rows)} poses")
        self.n = n
        self.poses = [snap_rotation(np.vstack([r, [0, 0, 0, 1]])) for r in rows[:n]]  # world_from_cam0
        self.times = [float(t) for t in self.time_text[:n]]
        # Exact stamps in ns: times.txt's decimal text + 1000 s, rounded to the nanosecond.
        self.stamps_ns = [int((Decimal(t) * 10**9).to_integral_value()) + STAMP_OFFSET_S * 10**9
                          for t in self.time_text[:n]]
        self.scans = [np.fromfile(seq / "velodyne" / f"{i:06d}.bin", dtype="<f4").reshape(-1, 4)
                      for i in range(n)]
        self.stereo = all((seq / f"image_{c}" / f"{i:06d}.png").exists()
                          for c in (0, 1) for i in range(n)) and "P0" in self.p and "P1" in self.p


# ----------------------------------------------------------------------------- text files
def g(x: float) -> str:
    return "%.17g" % x


def write_tum(path: Path, times: list[float], poses: list[np.ndarray]) -> None:
    with path.open("w") as f:
        for t, m in zip(times, poses):
            f.write(" ".join(g(v) for v in (t, *m[:3, 3], *quaternion(m[:3, :3]))) + "\n")


def write_pose_files(folder: Path, d: Drive, times: list[float], with_times: bool) -> None:
    write_tum(folder / "trajectory.tum", times, d.poses)
    (folder / "extrinsic.txt").write_text(
        "".join(" ".join(g(v) for v in row) + "\n" for row in d.cam0_from_velo))
    if with_times:
        (folder / "poses_kitti.txt").write_text(
            "".join(" ".join(g(v) for v in m[:3].ravel()) + "\n" for m in d.poses))
        # The selected frames' lines of times.txt, as they are written there.
        (folder / "times.txt").write_text("".join(t + "\n" for t in d.time_text[:len(d.poses)]))


# ----------------------------------------------------------------------------- scan files
def write_pcd(path: Path, pts: np.ndarray, encoding: "pypcd4.Encoding") -> None:
    pypcd4.PointCloud.from_xyzi_points(pts).save(path, encoding=encoding)


def write_ply(path: Path, pts: np.ndarray) -> None:
    v = np.empty(len(pts), dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("intensity", "<f4")])
    for k, name in enumerate(("x", "y", "z", "intensity")):
        v[name] = pts[:, k]
    plyfile.PlyData([plyfile.PlyElement.describe(v, "vertex")], text=False, byte_order="<").write(path)


def las_intensity(pts: np.ndarray) -> np.ndarray:
    return np.clip(np.rint(pts[:, 3].astype(np.float64) * 65535.0), 0, 65535).astype(np.uint16)


def write_las(path: Path, pts: np.ndarray, point_format: int) -> None:
    header = laspy.LasHeader(point_format=point_format, version="1.2" if point_format == 0 else "1.4")
    header.scales = np.array([1e-5, 1e-5, 1e-5])
    header.offsets = np.zeros(3)
    las = laspy.LasData(header)
    las.x, las.y, las.z = (pts[:, k].astype(np.float64) for k in range(3))
    las.intensity = las_intensity(pts)
    las.write(path, laz_backend=laspy.LazBackend.Lazrs if path.suffix == ".laz" else None)


def write_scan(path: Path, form: str, pts: np.ndarray) -> None:
    if form.startswith("pcd_"):
        write_pcd(path, pts, pypcd4.Encoding(form[4:]))
    elif form == "ply":
        write_ply(path, pts)
    elif form == "las":
        write_las(path, pts, 0)  # LAS 1.2, point format 0
    elif form == "laz":
        write_las(path, pts, 6)  # LAS 1.4, point format 6, LAZ by lazrs
    else:
        np.ascontiguousarray(pts, dtype="<f4").tofile(path)


def scan_folders(out: Path, d: Drive, want) -> dict:
    made = {}
    for form, ext in FORMS.items():
        if not want(f"scans_{form}"):
            continue
        folder = fresh(out / f"scans_{form}")
        (folder / "scans").mkdir()
        for i, pts in enumerate(d.scans):
            write_scan(folder / "scans" / f"{i:06d}.{ext}", form, pts)
        write_pose_files(folder, d, d.times, with_times=True)
        made[folder.name] = {"frames": d.n, "form": form}
    notes = {
        "scans_pcd_ascii": "pypcd4 writes ASCII floats as %.10f (not always float32-exact near 0)",
        "scans_las": "LAS 1.2 point format 0, scale 1e-5, offset 0, intensity rint(r*65535)",
        "scans_laz": "LAS 1.4 point format 6 (LAZ, lazrs), scale 1e-5, offset 0, intensity rint(r*65535)",
    }
    for name, note in notes.items():
        if name in made:
            made[name]["note"] = note
    if not want("scans_stamped"):
        return made
    folder = fresh(out / "scans_stamped")
    (folder / "scans").mkdir()
    stamped = [t + STAMP_OFFSET_S for t in d.times]
    names = ["%.6f.pcd" % t for t in stamped]
    for name, pts in zip(names, d.scans):
        write_pcd(folder / "scans" / name, pts, pypcd4.Encoding.BINARY)
    write_pose_files(folder, d, stamped, with_times=False)
    made[folder.name] = {"frames": d.n, "form": "pcd_binary", "scan_names": names,
                         "note": "scan names and trajectory times are times.txt + 1000 s"}
    return made


# ----------------------------------------------------------------------------- ROS messages
def header(stamp_ns: int, frame: str):
    stamp = T["builtin_interfaces/msg/Time"](sec=stamp_ns // 10**9, nanosec=stamp_ns % 10**9)
    return T["std_msgs/msg/Header"](stamp=stamp, frame_id=frame)


def ros_quat(m: np.ndarray):
    x, y, z, w = quaternion(m[:3, :3])
    return T["geometry_msgs/msg/Quaternion"](x=x, y=y, z=z, w=w)


def transform(stamp_ns: int, parent: str, child: str, m: np.ndarray):
    tr = T["geometry_msgs/msg/Vector3"](*(float(v) for v in m[:3, 3]))
    return T["geometry_msgs/msg/TransformStamped"](
        header=header(stamp_ns, parent), child_frame_id=child,
        transform=T["geometry_msgs/msg/Transform"](translation=tr, rotation=ros_quat(m)))


def ros_pose(m: np.ndarray):
    pos = T["geometry_msgs/msg/Point"](*(float(v) for v in m[:3, 3]))
    return T["geometry_msgs/msg/Pose"](position=pos, orientation=ros_quat(m))


def tf_message(*transforms):
    return T["tf2_msgs/msg/TFMessage"](transforms=list(transforms))


def pose_message(kind: str, stamp_ns: int, m: np.ndarray):
    """(topic, message) of one world_from_cam0 pose as /tf, /odom or /pose."""
    if kind == "tf":
        return "/tf", tf_message(transform(stamp_ns, "map", "base_link", m))
    if kind == "odom":
        zero = np.zeros(36)
        twist = T["geometry_msgs/msg/Twist"](T["geometry_msgs/msg/Vector3"](0.0, 0.0, 0.0),
                                             T["geometry_msgs/msg/Vector3"](0.0, 0.0, 0.0))
        return "/odom", T["nav_msgs/msg/Odometry"](
            header=header(stamp_ns, "map"), child_frame_id="base_link",
            pose=T["geometry_msgs/msg/PoseWithCovariance"](pose=ros_pose(m), covariance=zero),
            twist=T["geometry_msgs/msg/TwistWithCovariance"](twist=twist, covariance=zero.copy()))
    return "/pose", T["geometry_msgs/msg/PoseStamped"](header=header(stamp_ns, "map"), pose=ros_pose(m))


def cloud_message(stamp_ns: int, pts: np.ndarray, double: bool):
    field = T["sensor_msgs/msg/PointField"]
    if double:  # float64 x,y,z + float32 intensity, organised as 2 rows
        width = len(pts) // 2
        pts = pts[:2 * width]
        dt = np.dtype({"names": ["x", "y", "z", "i"], "formats": ["<f8", "<f8", "<f8", "<f4"],
                       "offsets": [0, 8, 16, 24], "itemsize": 28})
        height, offsets, types, step = 2, (0, 8, 16, 24), (8, 8, 8, 7), 28
    else:
        width = len(pts)
        dt = np.dtype({"names": ["x", "y", "z", "i"], "formats": ["<f4"] * 4,
                       "offsets": [0, 4, 8, 12], "itemsize": 16})
        height, offsets, types, step = 1, (0, 4, 8, 12), (7, 7, 7, 7), 16
    rec = np.zeros(len(pts), dtype=dt)
    for k, name in enumerate("xyzi"):
        rec[name] = pts[:, k]
    fields = [field(name=n, offset=o, datatype=t, count=1)
              for n, o, t in zip(("x", "y", "z", "intensity"), offsets, types)]
    return T["sensor_msgs/msg/PointCloud2"](
        header=header(stamp_ns, "velodyne"), height=height, width=width, fields=fields,
        is_bigendian=False, point_step=step, row_step=step * width,
        data=np.frombuffer(rec.tobytes(), dtype=np.uint8), is_dense=True)


def camera_info(stamp_ns: int, frame: str, p: np.ndarray, width: int, height: int,
                d=(0.0,) * 5):
    return T["sensor_msgs/msg/CameraInfo"](
        header=header(stamp_ns, frame), height=height, width=width, distortion_model="plumb_bob",
        d=np.array(d, dtype=np.float64), k=p[:, :3].ravel().copy(), r=np.eye(3).ravel(), p=p.ravel().copy(),
        binning_x=0, binning_y=0,
        roi=T["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0, width=0,
                                                  do_rectify=False))


# ----------------------------------------------------------------------------- bags
def fresh(folder: Path) -> Path:
    if folder.exists():
        shutil.rmtree(folder)
    folder.mkdir(parents=True)
    return folder


def write_bag(folder: Path, events: list, plugin=StoragePlugin.MCAP, zstd_chunks=False) -> dict:
    """Writes events [(topic, message), stamp_ns] in order; returns {topic: {type, count}}."""
    if folder.exists():
        shutil.rmtree(folder)  # rosbags' Writer refuses an existing folder
    writer = Writer(folder, version=9, storage_plugin=plugin)
    if zstd_chunks:
        writer.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
    writer.open()
    connections, topics = {}, {}
    for (topic, msg), _ in events:
        if topic not in connections:
            connections[topic] = writer.add_connection(topic, msg.__msgtype__, typestore=TS)
            topics[topic] = {"type": msg.__msgtype__, "count": 0}
    for (topic, msg), stamp in events:
        writer.write(connections[topic], stamp, bytes(TS.serialize_cdr(msg, msg.__msgtype__)))
        topics[topic]["count"] += 1
    writer.close()
    return topics


def lidar_events(d: Drive, pose_kind="tf", double=False, tf_static=True) -> list:
    events = []
    if tf_static:
        events.append((("/tf_static", tf_message(
            transform(d.stamps_ns[0], "base_link", "velodyne", d.cam0_from_velo))), d.stamps_ns[0]))
    for stamp, m, pts in zip(d.stamps_ns, d.poses, d.scans):
        events.append((pose_message(pose_kind, stamp, m), stamp))
        events.append((("/points", cloud_message(stamp, pts, double)), stamp))
    return events


def stereo_events(d: Drive, compressed: bool, raw: bool = False) -> list:
    """Stereo topics; `raw` names them image_raw and gives the cameras a distortion (the
    unrectified input a reader must refuse)."""
    s0 = d.stamps_ns[0]
    events = [(("/tf_static", tf_message(transform(s0, "base_link", "cam_left", np.eye(4)),
                                          transform(s0, "base_link", "velodyne", d.cam0_from_velo))), s0)]
    for i, (stamp, m) in enumerate(zip(d.stamps_ns, d.poses)):
        events.append((pose_message("tf", stamp, m), stamp))
        for cam, side in ((0, "left"), (1, "right")):
            path = d.seq / f"image_{cam}" / f"{i:06d}.png"
            with Image.open(path) as im:
                gray = np.asarray(im if im.mode == "L" else im.convert("L"), dtype=np.uint8)
            h, w = gray.shape
            frame = f"cam_{side}"
            if compressed:
                msg = T["sensor_msgs/msg/CompressedImage"](
                    header=header(stamp, frame), format="png",
                    data=np.frombuffer(path.read_bytes(), dtype=np.uint8))
                topic = f"/stereo/{side}/image_rect/compressed"
            else:
                msg = T["sensor_msgs/msg/Image"](
                    header=header(stamp, frame), height=h, width=w, encoding="mono8",
                    is_bigendian=0, step=w, data=gray.ravel().copy())
                topic = f"/stereo/{side}/image_raw" if raw else f"/stereo/{side}/image_rect"
            events.append(((topic, msg), stamp))
            dist = (-0.37, 0.2, 0.0, 0.0, 0.0) if raw else (0.0,) * 5
            events.append(((f"/stereo/{side}/camera_info",
                            camera_info(stamp, frame, d.p[f"P{cam}"], w, h, dist)), stamp))
    return events


def mcap_records(path: Path) -> list[tuple[int, int, int]]:
    """(opcode, start, end) of the top-level records of an MCAP file."""
    data, pos, out = path.read_bytes(), 8, []
    while pos + 9 <= len(data):
        op, length = data[pos], int.from_bytes(data[pos + 1:pos + 9], "little")
        out.append((op, pos, pos + 9 + length))
        pos += 9 + length
    return out


def cut_bag(src: Path, dst: Path) -> str:
    shutil.copytree(src, fresh(dst), dirs_exist_ok=True)
    mcap = dst / f"{src.name}.mcap"
    size = mcap.stat().st_size
    cut = int(size * 0.7)
    records = mcap_records(mcap)
    if any(start == cut for _, start, _ in records):
        cut -= 1  # keep the cut inside a record
    op, start, end = next(r for r in records if r[1] < cut < r[2])
    with mcap.open("r+b") as f:
        f.truncate(cut)
    whole = sum(1 for o, _, e in records if o == 0x06 and e <= cut)
    return (f"{mcap.name} truncated from {size} to {cut} bytes, inside a record of opcode 0x{op:02x} "
            f"(bytes {start}..{end}) after {whole} whole chunk records; no footer or summary; "
            "metadata.yaml kept")


def bags(out: Path, d: Drive, want) -> dict:
    made = {}

    def bag(name, events, fault=None, **kw):
        if not want(name):
            return
        entry = {"frames": d.n, "storage": "sqlite3" if kw.get("plugin") == StoragePlugin.SQLITE3
                 else "mcap", "zstd_chunks": kw.get("zstd_chunks", False),
                 "topics": write_bag(out / name, events, **kw)}
        if fault:
            entry["fault"] = fault
        made[name] = entry

    bag("bag_mcap", lidar_events(d), zstd_chunks=True)
    bag("bag_sqlite", lidar_events(d, pose_kind="odom"), plugin=StoragePlugin.SQLITE3)
    bag("bag_pose_stamped", lidar_events(d, pose_kind="pose"))
    bag("bag_double", lidar_events(d, double=True))
    if "bag_double" in made:
        made["bag_double"]["note"] = "x,y,z FLOAT64, intensity FLOAT32, point_step 28, height 2, width n//2"
    if not want("bag_unordered"):
        pass
    elif d.n >= 3:
        events = lidar_events(d)
        # events: [tf_static, tf0, pts0, tf1, pts1, tf2, pts2, ...]; swap pts1 and pts2.
        events[4], events[6] = events[6], events[4]
        bag("bag_unordered", events, fault="the /points messages of frames 1 and 2 are written in "
            "swapped order (each keeps its own stamp and log time), so log times go backwards")
    else:
        shutil.rmtree(out / "bag_unordered", ignore_errors=True)  # no stale one from an earlier run
        print("make_input_fixtures: bag_unordered skipped (needs 3 frames)")
    bag("bag_no_tf_static", lidar_events(d, tf_static=False), fault="no /tf_static topic")
    if "bag_mcap" in made and want("bag_cut"):
        made["bag_cut"] = dict(made["bag_mcap"], fault=cut_bag(out / "bag_mcap", out / "bag_cut"))
    if "bag_mcap" in made and want("bag_no_metadata"):
        nometa = out / "bag_no_metadata"
        shutil.copytree(out / "bag_mcap", fresh(nometa), dirs_exist_ok=True)
        (nometa / "metadata.yaml").unlink()
        made["bag_no_metadata"] = dict(made["bag_mcap"], fault="no metadata.yaml (bag_mcap.mcap alone)")
    if not (want("bag_stereo") or want("bag_stereo_compressed") or want("bag_stereo_raw")):
        pass
    elif d.stereo:
        bag("bag_stereo", stereo_events(d, compressed=False))
        bag("bag_stereo_compressed", stereo_events(d, compressed=True))
        bag("bag_stereo_raw", stereo_events(d, compressed=False, raw=True),
            fault="image_raw topics whose CameraInfo has a distortion: unrectified")
    else:
        for name in ("bag_stereo", "bag_stereo_compressed", "bag_stereo_raw"):
            shutil.rmtree(out / name, ignore_errors=True)
        print(f"make_input_fixtures: stereo bags skipped ({d.seq} lacks image_0/image_1 PNGs or P0/P1 "
              "for some selected frame)")
    return made


# ----------------------------------------------------------------------------- main
def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("seq", type=Path, help="KITTI odometry sequence folder (calib.txt, times.txt, velodyne/)")
    ap.add_argument("out", type=Path, help="output folder (created; existing outputs replaced)")
    ap.add_argument("--frames", type=int, help="use frames [0, N) (default: all with a velodyne scan)")
    ap.add_argument("--poses", type=Path, help="3x4 world_from_cam0 per line (default: SEQ/../../poses/NN.txt)")
    ap.add_argument("--only", help="comma-separated output folders to write (default: all), "
                    "e.g. bag_mcap,scans_bin for a benchmark")
    args = ap.parse_args()
    only = set(args.only.split(",")) if args.only else None

    def want(name: str) -> bool:
        return only is None or name in only

    started = time.monotonic()
    d = Drive(args.seq, args.frames, args.poses)
    args.out.mkdir(parents=True, exist_ok=True)
    outputs = scan_folders(args.out, d, want)
    outputs.update(bags(args.out, d, want))
    for name, entry in outputs.items():
        folder = args.out / name
        entry["files"] = sorted(str(p.relative_to(folder)) for p in folder.rglob("*") if p.is_file())
    manifest = {
        "source": str(args.seq.resolve()), "frames": d.n, "stamp_offset_s": STAMP_OFFSET_S,
        "stamps_ns": d.stamps_ns, "points_per_frame": [len(s) for s in d.scans],
        "frames_ids": {"fixed": "map", "body": "base_link (= cam0)", "lidar": "velodyne"},
        "outputs": outputs,
        "versions": {dist: importlib.metadata.version(dist) for dist in
                     ("rosbags", "pypcd4", "plyfile", "laspy", "lazrs", "numpy", "pillow")},
    }
    (args.out / "manifest.json").write_text(json.dumps(manifest, indent=1) + "\n")
    print(f"make_input_fixtures: {d.n} frames, {len(outputs)} folders in {args.out} "
          f"({time.monotonic() - started:.1f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
