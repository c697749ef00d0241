//! Routes through the synthetic city: the procedural street route (a lattice walk with a closed
//! loop and rounded corners), routes that follow a given trajectory (e.g. KITTI's ground-truth
//! poses), camera poses sampled along them, and a small KITTI pose-file reader. Produces the road
//! centreline of the driven street and the cameras; does not place buildings.

use super::rng::Rng;
use crate::error::{Error, Result};
use nalgebra::{Isometry3, Matrix3, Rotation3, Translation3, UnitQuaternion, Vector3};
use std::collections::HashSet;

/// The driven street and the cameras on it.
#[derive(Clone, Debug)]
pub(crate) struct Route {
    /// Road centreline of the driven street, points (x, ground y, z), about 1–2 m apart.
    pub centreline: Vec<Vector3<f64>>,
    /// Camera poses (world_from_cam0), in driving order.
    pub poses: Vec<Isometry3<f64>>,
}

/// Parameters shared by both kinds of route.
#[derive(Clone, Copy, Debug)]
pub(crate) struct RouteParams {
    pub seed: u64,
    pub length_m: f64,
    pub frame_spacing_m: f64,
    pub camera_height_m: f64,
    pub lane_offset_m: f64,
    pub max_frames: Option<usize>,
}

/// Camera rotation looking along the horizontal unit direction (fx, fz), y down.
fn level_rotation(fx: f64, fz: f64) -> UnitQuaternion<f64> {
    let m = Matrix3::from_columns(&[
        Vector3::new(fz, 0.0, -fx),
        Vector3::new(0.0, 1.0, 0.0),
        Vector3::new(fx, 0.0, fz),
    ]);
    UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(m))
}

/// Per-vertex unit tangents (x, z) of a polyline (average of the adjacent segments).
fn tangents(pts: &[Vector3<f64>]) -> Vec<[f64; 2]> {
    let n = pts.len();
    (0..n)
        .map(|i| {
            let a = pts[i.saturating_sub(1)];
            let b = pts[(i + 1).min(n - 1)];
            let (dx, dz) = (b.x - a.x, b.z - a.z);
            let l = (dx * dx + dz * dz).sqrt().max(1e-12);
            [dx / l, dz / l]
        })
        .collect()
}

/// The polyline shifted sideways by `offset_m` (positive: to the right of travel) and by `dy` in y.
fn offset_polyline(pts: &[Vector3<f64>], offset_m: f64, dy: f64) -> Vec<Vector3<f64>> {
    let t = tangents(pts);
    pts.iter()
        .zip(&t)
        .map(|(p, d)| Vector3::new(p.x + d[1] * offset_m, p.y + dy, p.z - d[0] * offset_m))
        .collect()
}

/// Cumulative horizontal arc length of a polyline.
fn arc_lengths(pts: &[Vector3<f64>]) -> Vec<f64> {
    let mut s = vec![0.0; pts.len()];
    for i in 1..pts.len() {
        s[i] = s[i - 1]
            + ((pts[i].x - pts[i - 1].x).powi(2) + (pts[i].z - pts[i - 1].z).powi(2)).sqrt();
    }
    s
}

/// Level camera poses every `spacing` metres along `lane` (camera positions), from arc length
/// `s_start` for `length_m`.
fn poses_along(lane: &[Vector3<f64>], s_start: f64, p: &RouteParams) -> Vec<Isometry3<f64>> {
    let s = arc_lengths(lane);
    let t = tangents(lane);
    let spacing = p.frame_spacing_m.max(1e-3);
    let count = (p.length_m / spacing).floor() as usize + 1;
    let count = p.max_frames.map_or(count, |m| count.min(m));
    let mut out = Vec::with_capacity(count);
    let mut seg = 0;
    for k in 0..count {
        let sk = s_start + k as f64 * spacing;
        while seg + 2 < lane.len() && s[seg + 1] < sk {
            seg += 1;
        }
        let len = (s[seg + 1] - s[seg]).max(1e-12);
        let w = ((sk - s[seg]) / len).clamp(0.0, 1.0);
        let pos = lane[seg] + (lane[seg + 1] - lane[seg]) * w;
        let (fx, fz) = (
            t[seg][0] * (1.0 - w) + t[seg + 1][0] * w,
            t[seg][1] * (1.0 - w) + t[seg + 1][1] * w,
        );
        let l = (fx * fx + fz * fz).sqrt().max(1e-12);
        out.push(Isometry3::from_parts(
            Translation3::from(pos),
            level_rotation(fx / l, fz / l),
        ));
    }
    out
}

/// Dense points of a polyline of lattice nodes with corners rounded to radius `r`: straight parts
/// sampled every metre from their start, arcs every ~1 m.
fn rounded_polyline(nodes: &[[f64; 2]], r: f64) -> Vec<[f64; 2]> {
    let mut out: Vec<[f64; 2]> = Vec::new();
    let mut cur = nodes[0];
    for i in 1..nodes.len() {
        let b = nodes[i];
        let (dx, dz) = (b[0] - cur[0], b[1] - cur[1]);
        let len = (dx * dx + dz * dz).sqrt();
        let d = [dx / len, dz / len];
        // Where the straight part ends: before the fillet at b, if b turns.
        let turn = nodes.get(i + 1).map(|c| {
            let (ex, ez) = (c[0] - b[0], c[1] - b[1]);
            let el = (ex * ex + ez * ez).sqrt();
            [ex / el, ez / el]
        });
        let turning = turn.is_some_and(|e| (e[0] * d[0] + e[1] * d[1]) < 0.999);
        let straight = if turning { len - r } else { len };
        let steps = straight.floor() as usize;
        for k in 0..=steps {
            out.push([cur[0] + d[0] * k as f64, cur[1] + d[1] * k as f64]);
        }
        let end = [cur[0] + d[0] * straight, cur[1] + d[1] * straight];
        if straight - steps as f64 > 1e-9 {
            out.push(end);
        }
        if let (true, Some(e)) = (turning, turn) {
            // Quarter arc from `end` (heading d) to b + e·r (heading e).
            let cross = d[0] * e[1] - d[1] * e[0];
            let side = if cross > 0.0 { 1.0 } else { -1.0 };
            // Centre lies on the inside of the turn.
            let nrm = [-d[1] * side, d[0] * side];
            let c = [end[0] + nrm[0] * r, end[1] + nrm[1] * r];
            let a0 = (end[1] - c[1]).atan2(end[0] - c[0]);
            let sweep = (d[0] * e[0] + d[1] * e[1]).clamp(-1.0, 1.0).acos() * side;
            let n = ((sweep.abs() * r).ceil() as usize).max(2);
            for k in 1..n {
                let a = a0 + sweep * k as f64 / n as f64;
                out.push([c[0] + r * a.cos(), c[1] + r * a.sin()]);
            }
            cur = [b[0] + e[0] * r, b[1] + e[1] * r];
        } else {
            cur = b;
        }
    }
    out.dedup_by(|a, b| (a[0] - b[0]).abs() < 1e-9 && (a[1] - b[1]).abs() < 1e-9);
    out
}

/// A procedural route: a lead-in, a closed rectangular loop around city blocks that crosses the
/// start (a junction revisited), then a random lattice walk. The first camera is at the origin
/// looking along +z, 1.65 m (camera height) above the ground plane y = camera height.
pub(crate) fn procedural(p: &RouteParams) -> Route {
    let mut rng = Rng::new(p.seed, 0x4F07E);
    let lead_in = 30.0;
    let block = (0.7 * p.length_m / 6.0).clamp(30.0, 90.0) * rng.range(0.9, 1.1);
    let x0 = -p.lane_offset_m;
    let mut lattice: Vec<(i64, i64)> = vec![(0, 0), (0, 2), (1, 2), (1, 0), (0, 0), (-1, 0)];
    let mut visited: HashSet<(i64, i64)> = [
        (0, 0),
        (0, 1),
        (0, 2),
        (1, 2),
        (1, 1),
        (1, 0),
        (-1, 0),
        (0, -1),
    ]
    .into_iter()
    .collect();
    let mut heading = (-1i64, 0i64);
    let mut cur = (-1i64, 0i64);
    let mut total = 6.0 * block;
    while total < p.length_m + 60.0 {
        let left = (heading.1, -heading.0);
        let right = (-heading.1, heading.0);
        let mut options = vec![(heading, 0.5), (left, 0.25), (right, 0.25)];
        options.retain(|(d, _)| !visited.contains(&(cur.0 + d.0, cur.1 + d.1)));
        let d = if options.is_empty() {
            heading
        } else {
            let wsum: f64 = options.iter().map(|o| o.1).sum();
            let mut x = rng.f64() * wsum;
            let mut pick = options[0].0;
            for (d, w) in &options {
                if x < *w {
                    pick = *d;
                    break;
                }
                x -= w;
            }
            pick
        };
        cur = (cur.0 + d.0, cur.1 + d.1);
        visited.insert(cur);
        lattice.push(cur);
        heading = d;
        total += block;
    }
    // Lattice → metres, dropping collinear interior nodes.
    let mut nodes: Vec<[f64; 2]> = vec![[x0, -lead_in]];
    for (i, j) in lattice {
        nodes.push([x0 + i as f64 * block, j as f64 * block]);
    }
    let mut merged: Vec<[f64; 2]> = vec![nodes[0]];
    for i in 1..nodes.len() {
        if i + 1 < nodes.len() {
            let (a, b, c) = (merged[merged.len() - 1], nodes[i], nodes[i + 1]);
            let cross = (b[0] - a[0]) * (c[1] - b[1]) - (b[1] - a[1]) * (c[0] - b[0]);
            if cross.abs() < 1e-9 {
                continue;
            }
        }
        merged.push(nodes[i]);
    }
    let radius = (0.4 * block).min(12.0);
    let pts2 = rounded_polyline(&merged, radius);
    let ground_y = p.camera_height_m;
    let centreline: Vec<Vector3<f64>> = pts2
        .iter()
        .map(|q| Vector3::new(q[0], ground_y, q[1]))
        .collect();
    let lane = offset_polyline(&centreline, p.lane_offset_m, -p.camera_height_m);
    // The lead-in is sampled every metre, so vertex 30 is the origin and its arc length is 30.
    let s_start = arc_lengths(&lane)[lead_in as usize];
    let poses = poses_along(&lane, s_start, p);
    Route { centreline, poses }
}

/// A route along a given trajectory (camera poses at real scale, e.g. KITTI's). Frames are the
/// given poses thinned to at least `frame_spacing_m` apart, for the first `length_m` metres.
pub(crate) fn along_trajectory(traj: &[Isometry3<f64>], p: &RouteParams) -> Result<Route> {
    if traj.len() < 2 {
        return Err(Error::InvalidArgument(format!(
            "a trajectory needs at least 2 poses, got {}",
            traj.len()
        )));
    }
    let mut poses = vec![traj[0]];
    let mut travelled = 0.0;
    let mut since = 0.0;
    let mut last_used = 0;
    for i in 1..traj.len() {
        let d = (traj[i].translation.vector - traj[i - 1].translation.vector).norm();
        travelled += d;
        since += d;
        if travelled > p.length_m + 1e-9 {
            break;
        }
        last_used = i;
        if since >= p.frame_spacing_m - 1e-9 {
            if p.max_frames.is_some_and(|m| poses.len() >= m) {
                break;
            }
            poses.push(traj[i]);
            since = 0.0;
        }
    }
    // Centreline: positions 2 m apart up to 40 m past the last frame, smoothed.
    let mut pts: Vec<Vector3<f64>> = Vec::new();
    let mut past = 0.0;
    for i in 0..traj.len() {
        let q = traj[i].translation.vector;
        if i > last_used {
            past += (q - traj[i - 1].translation.vector).norm();
            if past > 40.0 {
                break;
            }
        }
        if pts.last().is_none_or(|l: &Vector3<f64>| {
            ((q.x - l.x).powi(2) + (q.z - l.z).powi(2)).sqrt() >= 2.0
        }) {
            pts.push(q);
        }
    }
    if pts.len() < 2 {
        return Err(Error::InvalidArgument(
            "the trajectory does not move (all poses within 2 m)".into(),
        ));
    }
    let smoothed: Vec<Vector3<f64>> = (0..pts.len())
        .map(|i| {
            let (a, b) = (i.saturating_sub(2), (i + 2).min(pts.len() - 1));
            let k = b - a + 1;
            pts[a..=b].iter().sum::<Vector3<f64>>() / k as f64
        })
        .collect();
    let t = tangents(&smoothed);
    let n = smoothed.len();
    let mut ext = Vec::with_capacity(n + 30);
    for k in (1..=15).rev() {
        let d = 2.0 * k as f64;
        ext.push(smoothed[0] - Vector3::new(t[0][0] * d, 0.0, t[0][1] * d));
    }
    ext.extend_from_slice(&smoothed);
    for k in 1..=15 {
        let d = 2.0 * k as f64;
        ext.push(smoothed[n - 1] + Vector3::new(t[n - 1][0] * d, 0.0, t[n - 1][1] * d));
    }
    let centreline = offset_polyline(&ext, -p.lane_offset_m, p.camera_height_m);
    Ok(Route { centreline, poses })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn params(length_m: f64) -> RouteParams {
        RouteParams {
            seed: 1,
            length_m,
            frame_spacing_m: 0.9,
            camera_height_m: 1.65,
            lane_offset_m: 1.75,
            max_frames: None,
        }
    }

    #[test]
    fn procedural_route_starts_at_origin_and_closes_a_loop() {
        let r = procedural(&params(400.0));
        let p0 = r.poses[0];
        assert!(p0.translation.vector.norm() < 1e-12, "{p0}");
        assert!(p0.rotation.angle() < 1e-12);
        assert_eq!(r.poses.len(), (400.0f64 / 0.9).floor() as usize + 1);
        // Consecutive frames are one spacing apart (less in turns, where the chord is shorter).
        for w in r.poses.windows(2) {
            let d = (w[1].translation.vector - w[0].translation.vector).norm();
            assert!(d <= 0.9 + 1e-9 && d > 0.85, "{d}");
        }
        // The loop brings the car back within a lane width of the start, later in the drive.
        let back = r.poses[100..]
            .iter()
            .map(|p| p.translation.vector.norm())
            .fold(f64::INFINITY, f64::min);
        assert!(back < 4.0, "closest return to start {back}");
        // Cameras stay 1.65 m above the ground and level.
        for p in &r.poses {
            assert!(p.translation.y.abs() < 1e-12);
            let down = p.rotation * Vector3::y();
            assert!((down - Vector3::y()).norm() < 1e-9);
        }
    }
}
