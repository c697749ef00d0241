//! Exact traversal of the cells of a regular grid along a ray segment (Amanatides & Woo 1987).

use crate::grid::floor_i64;

/// Visits, in order along the ray `origin + t·dir`, every cell of a grid of edge `cell_size`
/// (cell `c` covers `[c·s, (c+1)·s)`) that the segment `t ∈ [t0, t1]` passes through. `visit`
/// receives the cell and returns `false` to stop early. `dir` need not be normalised; `t` is in
/// units of `dir`.
pub fn traverse_cells(
    origin: [f64; 3],
    dir: [f64; 3],
    t0: f64,
    t1: f64,
    cell_size: f64,
    mut visit: impl FnMut([i64; 3]) -> bool,
) {
    if !(t1 >= t0) {
        return;
    }
    let start = [
        origin[0] + t0 * dir[0],
        origin[1] + t0 * dir[1],
        origin[2] + t0 * dir[2],
    ];
    let mut cell = [0i64; 3];
    let mut step = [0i64; 3];
    let mut t_max = [f64::INFINITY; 3];
    let mut t_delta = [f64::INFINITY; 3];
    let mut last = [0i64; 3];
    let inv_cell = 1.0 / cell_size;
    for a in 0..3 {
        cell[a] = floor_i64(start[a] * inv_cell);
        let end = origin[a] + t1 * dir[a];
        last[a] = floor_i64(end * inv_cell);
        if dir[a] != 0.0 {
            let inv_dir = 1.0 / dir[a];
            if dir[a] > 0.0 {
                step[a] = 1;
                t_max[a] = t0 + (((cell[a] + 1) as f64) * cell_size - start[a]) * inv_dir;
                t_delta[a] = cell_size * inv_dir;
            } else {
                step[a] = -1;
                t_max[a] = t0 + ((cell[a] as f64) * cell_size - start[a]) * inv_dir;
                t_delta[a] = -cell_size * inv_dir;
            }
        }
    }
    // Bound the walk by the number of cell boundaries between the two end cells.
    let mut remaining: i64 = (0..3).map(|a| (last[a] - cell[a]).abs()).sum::<i64>() + 1;
    while remaining > 0 {
        if !visit(cell) {
            return;
        }
        remaining -= 1;
        let a = if t_max[0] < t_max[1] {
            if t_max[0] < t_max[2] {
                0
            } else {
                2
            }
        } else if t_max[1] < t_max[2] {
            1
        } else {
            2
        };
        if t_max[a] > t1 {
            return;
        }
        cell[a] += step[a];
        t_max[a] += t_delta[a];
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn brute_force(origin: [f64; 3], dir: [f64; 3], t0: f64, t1: f64, s: f64) -> Vec<[i64; 3]> {
        // Dense sampling finds every cell the segment crosses (except corner grazes).
        let n = 20_000;
        let mut out: Vec<[i64; 3]> = Vec::new();
        for k in 0..=n {
            let t = t0 + (t1 - t0) * k as f64 / n as f64;
            let c = [0, 1, 2].map(|a| ((origin[a] + t * dir[a]) / s).floor() as i64);
            if out.last() != Some(&c) {
                out.push(c);
            }
        }
        out
    }

    proptest! {
        #[test]
        fn matches_dense_sampling(
            o in prop::array::uniform3(-5.0f64..5.0),
            d in prop::array::uniform3(-1.0f64..1.0),
            t0 in 0.0f64..1.0, len in 0.0f64..4.0,
        ) {
            prop_assume!(d.iter().map(|x| x * x).sum::<f64>() > 0.01);
            let mut got = Vec::new();
            traverse_cells(o, d, t0, t0 + len, 0.37, |c| { got.push(c); true });
            let want = brute_force(o, d, t0, t0 + len, 0.37);
            // Sampling can miss a cell the ray only grazes; every sampled cell must be visited in order.
            let mut it = got.iter();
            for c in &want {
                prop_assert!(it.any(|g| g == c), "cell {:?} missing from {:?}", c, got);
            }
            prop_assert!(got.len() <= want.len() + 2);
            // Consecutive cells are face neighbours.
            for w in got.windows(2) {
                let dist: i64 = (0..3).map(|a| (w[0][a] - w[1][a]).abs()).sum();
                prop_assert_eq!(dist, 1);
            }
        }
    }
}
