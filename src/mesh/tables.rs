//! Marching-cubes case tables, generated from first principles at first use.
//!
//! Corner `c` of a cube sits at offset `(c & 1, (c >> 1) & 1, (c >> 2) & 1)`; a corner is
//! *negative* when its value is `< 0` (behind the surface). For each of the 256 sign cases:
//! on every face, walking the face's corners counter-clockwise about its outward normal, each edge
//! where the walk goes from a non-negative to a negative corner is joined by a segment to the next
//! sign-changing edge. On faces with two diagonal negative corners (the ambiguous case) this cuts
//! each negative corner off on its own. Since the rule depends only on the face's four corners, two
//! cubes sharing a face always cut it the same way, so meshes have no cracks. Each crossed edge
//! starts exactly one segment and ends exactly one, so segments chain into closed loops, which are
//! fan-triangulated. Loops run with the negative corners on their right seen from outside the
//! cube, so triangles wind counter-clockwise seen from the non-negative (free-space) side.

use std::sync::OnceLock;

/// The two corners of each of the 12 cube edges (lower corner first).
pub const EDGES: [[u8; 2]; 12] = build_edges();

const fn build_edges() -> [[u8; 2]; 12] {
    let mut e = [[0u8; 2]; 12];
    let mut k = 0;
    let mut axis = 0;
    while axis < 3 {
        let mut c = 0u8;
        while c < 8 {
            if c & (1 << axis) == 0 {
                e[k] = [c, c | (1 << axis)];
                k += 1;
            }
            c += 1;
        }
        axis += 1;
    }
    e
}

/// Axis (0 = x, 1 = y, 2 = z) of edge `e`.
pub fn edge_axis(e: usize) -> usize {
    e / 4
}

/// Triangles (as triples of edge ids) per sign case; case bit `c` set = corner `c` negative.
pub fn triangle_table() -> &'static [Vec<[u8; 3]>; 256] {
    static TABLE: OnceLock<[Vec<[u8; 3]>; 256]> = OnceLock::new();
    TABLE.get_or_init(|| std::array::from_fn(|case| triangulate(case as u8)))
}

fn corner_pos(c: u8) -> [f64; 3] {
    [(c & 1) as f64, ((c >> 1) & 1) as f64, ((c >> 2) & 1) as f64]
}

fn edge_of(a: u8, b: u8) -> u8 {
    EDGES
        .iter()
        .position(|e| (e[0] == a && e[1] == b) || (e[0] == b && e[1] == a))
        .expect("corners share an edge") as u8
}

/// The four corners of face (axis, side) ordered counter-clockwise about the outward normal.
fn face_corners(axis: usize, side: u8) -> [u8; 4] {
    let (ua, va) = ((axis + 1) % 3, (axis + 2) % 3);
    let mut corners: Vec<u8> = (0..8u8).filter(|c| (c >> axis) & 1 == side).collect();
    let angle = |c: &u8| {
        let p = corner_pos(*c);
        (p[va] - 0.5).atan2(p[ua] - 0.5)
    };
    corners.sort_by(|a, b| angle(a).total_cmp(&angle(b)));
    if side == 0 {
        // Outward normal is −e_axis: counter-clockwise about it is clockwise about +e_axis.
        corners.reverse();
    }
    [corners[0], corners[1], corners[2], corners[3]]
}

fn triangulate(case: u8) -> Vec<[u8; 3]> {
    let negative = |c: u8| case & (1 << c) != 0;
    let mut next = [u8::MAX; 12];
    for axis in 0..3 {
        for side in 0..2u8 {
            let q = face_corners(axis, side);
            let crossings: Vec<(u8, bool)> = (0..4)
                .filter(|&k| negative(q[k]) != negative(q[(k + 1) % 4]))
                .map(|k| (edge_of(q[k], q[(k + 1) % 4]), !negative(q[k])))
                .collect();
            for (j, &(edge, enters_negative)) in crossings.iter().enumerate() {
                if enters_negative {
                    let (to, _) = crossings[(j + 1) % crossings.len()];
                    next[edge as usize] = to;
                }
            }
        }
    }
    let mut seen = [false; 12];
    let mut triangles = Vec::new();
    for start in 0..12u8 {
        if next[start as usize] == u8::MAX || seen[start as usize] {
            continue;
        }
        let mut poly = Vec::new();
        let mut e = start;
        while !seen[e as usize] {
            seen[e as usize] = true;
            poly.push(e);
            e = next[e as usize];
        }
        for k in 1..poly.len().saturating_sub(1) {
            triangles.push([poly[0], poly[k], poly[k + 1]]);
        }
    }
    triangles
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn classic_counts() {
        let t = triangle_table();
        assert!(t[0].is_empty() && t[255].is_empty());
        for c in 0..8 {
            assert_eq!(t[1 << c].len(), 1, "a single corner gives one triangle");
            assert_eq!(t[255 ^ (1 << c)].len(), 1);
        }
        // One face of four negative corners: a quad, two triangles.
        assert_eq!(t[0b0000_1111].len(), 2);
        // Two opposite corners: two separate triangles.
        assert_eq!(t[0b1000_0001].len(), 2);
        // Every case has at most 5 triangles as in Lorensen & Cline's table.
        assert!(
            t.iter().all(|v| v.len() <= 5),
            "max {}",
            t.iter().map(|v| v.len()).max().unwrap_or(0)
        );
        // Every crossed edge is used, and no uncrossed one.
        for (case, tris) in t.iter().enumerate() {
            let mut used = [false; 12];
            for tri in tris {
                for &e in tri {
                    used[e as usize] = true;
                }
            }
            for (e, corners) in EDGES.iter().enumerate() {
                let crossed = ((case >> corners[0]) & 1) != ((case >> corners[1]) & 1);
                assert_eq!(used[e], crossed, "case {case} edge {e}");
            }
        }
    }
}
