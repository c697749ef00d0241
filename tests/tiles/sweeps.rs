//! Swept regional regularization (issue 14 item 5): every region K iterations at a time with a
//! (K+1)-voxel halo, the solver state (u, ū, p) kept in the map between sweeps. Checked against
//! the global in-memory solve bit for bit: the stored state after each sweep, and the final `u`;
//! through kills at any point (a reopened map resumes from the progress record); regions planned
//! to a memory budget, and a budget too small for one chunk refused before anything is written.

use crate::paging::{fused_store, max_u_difference, store_layer};
use denser::map::layout::SWEEPS_AREA;
use denser::map::store::MapStore;
use denser::outofcore::regional::{
    plan_region_chunks, regularize_map, RegionCosts, RegionalOptions,
};
use denser::outofcore::sweep_state::{decode_block_state, decode_state_index};
use denser::regularize::{TvParams, TvProblem};
use std::path::Path;

fn params() -> TvParams {
    TvParams {
        iterations: 20,
        ..TvParams::paper(0.05)
    }
}

fn swept(region_chunks: u32) -> RegionalOptions {
    RegionalOptions {
        region_chunks,
        budget_bytes: 1 << 30,
        halo_blocks: None,
        sweep_iterations: Some(7),
    }
}

/// Every state file of parity `parity` checked bit for bit against `global`'s state.
fn assert_state_equals(map: &Path, parity: u32, step: u32, global: &TvProblem) -> usize {
    let (u, ubar, p) = global.state();
    let n = u.len();
    let mut blocks = 0;
    let folder = map.join(SWEEPS_AREA).join(format!("s{parity}"));
    for e in std::fs::read_dir(&folder).expect("state folder") {
        let path = e.expect("entry").path();
        let bytes = std::fs::read(&path).expect("read state");
        let index = decode_state_index(&path, &bytes).expect("index");
        assert_eq!(index.header.step, step, "{}", path.display());
        for entry in &index.entries {
            let s = decode_block_state(&path, &bytes, entry).expect("block");
            let slot = global
                .blocks()
                .binary_search(&entry.0)
                .expect("block in the map");
            let mut k = 0;
            for i in 0..512 {
                let g = slot * 512 + i;
                assert_eq!(s.in_omega(i), global.in_omega(g), "Ω of {:?}", entry.0);
                if !s.in_omega(i) {
                    continue;
                }
                let pairs = [
                    (s.u[k], u[g]),
                    (s.ubar[k], ubar[g]),
                    (s.p[0][k], p[g]),
                    (s.p[1][k], p[n + g]),
                    (s.p[2][k], p[2 * n + g]),
                ];
                for (a, b) in pairs {
                    assert_eq!(
                        a.to_bits(),
                        b.to_bits(),
                        "block {:?} voxel {i} after step {step}: {a} vs {b}",
                        entry.0
                    );
                }
                k += 1;
            }
            blocks += 1;
        }
    }
    blocks
}

#[test]
fn sweeps_equal_the_global_solve_bit_for_bit_through_kills() {
    let dir = tempfile::tempdir().expect("tempdir");
    let map = dir.path().join("map");
    let (mem, mut store) = fused_store(&map);
    let params = params();
    let all = mem.indices_sorted();
    let mut global = TvProblem::gather(&mem, &all);

    // Stop after step 1 (initial state, then the first sweep of 7 iterations): the stored state
    // is the global solve's after 7 iterations, bit for bit.
    let mut regions = 0;
    let first = regularize_map(&mut store, &params, &swept(1), |done, total| {
        regions = total / 4; // steps: initial state + 3 sweeps (7, 7, 6 iterations)
        done < 2 * regions
    })
    .expect("first sweep");
    assert!(first.interrupted && regions > 100, "{first:?}");
    assert_eq!(first.halo_blocks, 1, "7 iterations need 8 voxels of halo");
    for _ in 0..7 {
        global.iterate(&params);
    }
    let checked = assert_state_equals(&map, 1, 1, &global);
    assert_eq!(checked, all.len(), "every block has its state");
    // Both parities are whole now: the scratch the pass announced (and checks against free disk)
    // is what lies under sweeps/, to the progress record.
    let on_disk: u64 = ["s0", "s1"]
        .iter()
        .flat_map(|p| std::fs::read_dir(map.join(SWEEPS_AREA).join(p)).expect("parity"))
        .map(|e| e.expect("entry").metadata().expect("size").len())
        .sum();
    assert_eq!(
        on_disk + 4096,
        first.scratch_bytes,
        "state files against the announced scratch"
    );

    // Killed in the middle of the second sweep; a reopened map resumes from its record.
    drop(store);
    let mut store = MapStore::open(&map).expect("reopen");
    let second = regularize_map(&mut store, &params, &swept(1), |done, _| {
        done < 2 * regions + regions / 2
    })
    .expect("part of the second sweep");
    assert!(second.interrupted, "{second:?}");
    drop(store);
    // A state file torn as by a power loss (state is not fsynced): the resumed run finds it by
    // its checksums and starts the sweeps again. The last region's chunk (regions of one chunk
    // go in chunk order), which the rest of the second sweep reads.
    let chunk_of = |p: &std::path::PathBuf| -> [i32; 3] {
        let name = p.file_stem().expect("stem").to_string_lossy().into_owned();
        let v: Vec<i32> = name[2..]
            .split('_')
            .map(|x| x.parse().expect("int"))
            .collect();
        [v[0], v[1], v[2]]
    };
    let torn = std::fs::read_dir(map.join(SWEEPS_AREA).join("s1"))
        .expect("s1")
        .map(|e| e.expect("entry").path())
        .max_by_key(chunk_of)
        .expect("a state file");
    let bytes = std::fs::read(&torn).expect("read");
    std::fs::write(&torn, &bytes[..bytes.len() / 2]).expect("tear");
    let mut store = MapStore::open(&map).expect("reopen");
    regularize_map(&mut store, &params, &swept(1), |done, _| done < 3 * regions)
        .expect("rest of the second sweep");
    for _ in 0..7 {
        global.iterate(&params);
    }
    assert_state_equals(&map, 0, 2, &global);
    assert_eq!(
        store.manifest().header.complete_pass,
        0,
        "nothing is committed before the last sweep"
    );

    // Killed during the last sweep, which commits region by region; then finished.
    drop(store);
    let mut store = MapStore::open(&map).expect("reopen");
    let third = regularize_map(&mut store, &params, &swept(1), |done, _| {
        done < 3 * regions + 7
    })
    .expect("part of the last sweep");
    assert_eq!(third.regions, 7, "{third:?}");
    drop(store);
    let mut store = MapStore::open(&map).expect("reopen");
    let last = regularize_map(&mut store, &params, &swept(1), |_, _| true).expect("finish");
    assert!(
        !last.interrupted && last.regions + 7 == regions,
        "the last run writes the regions the killed one did not: {last:?}"
    );
    assert_eq!(last.pass, first.pass);
    assert!(store.manifest().latest_pass_complete());
    assert!(
        !map.join(SWEEPS_AREA).join("s0").exists() && !map.join(SWEEPS_AREA).join("s1").exists(),
        "the state is removed when the pass completes"
    );

    // The stored u is the global solve's u after 20 iterations, quantised: identical.
    for _ in 0..6 {
        global.iterate(&params);
    }
    let mut want = mem.clone();
    global.scatter(&mut want, &all);
    let got = store_layer(&store);
    let mut voxels = 0;
    for b in &all {
        let (w, g) = (want.get(b).expect("want"), got.get(b).expect("got"));
        assert_eq!(w.regularized, g.regularized, "u of block {b:?}");
        assert!(w.tsdf == g.tsdf && w.weight_omega == g.weight_omega && w.color == g.color);
        voxels += g.observed_count();
    }
    let (worst, _) = max_u_difference(&want, &got);
    println!(
        "{} blocks, {voxels} Ω voxels: max |u_swept − u_global| = {worst:e}",
        all.len()
    );
    assert_eq!(worst, 0.0);
    // And the same as all iterations at once with the exact halo, file for file.
    let dir2 = tempfile::tempdir().expect("tempdir");
    let (_, mut exact) = fused_store(&dir2.path().join("map"));
    let opts = RegionalOptions {
        sweep_iterations: None,
        ..swept(1)
    };
    regularize_map(&mut exact, &params, &opts, |_, _| true).expect("exact halo");
    let exact_layer = store_layer(&exact);
    for b in &all {
        assert_eq!(
            exact_layer.get(b).expect("e").regularized,
            got.get(b).expect("g").regularized
        );
    }
}

#[test]
fn regions_are_planned_to_the_budget_and_a_budget_too_small_is_refused_first() {
    let dir = tempfile::tempdir().expect("tempdir");
    let map = dir.path().join("map");
    let (mem, mut store) = fused_store(&map);
    let cb = store.chunk_blocks();
    let costs = RegionCosts::of(true);
    let chunks = store.manifest().chunks.clone();
    let (r1, one) = plan_region_chunks(&chunks, cb, 1, costs, 1 << 40).expect("unbounded");
    assert!(r1 > 1, "an unbounded budget takes the largest region");
    // A budget just below one chunk's bound is refused before anything is read or written.
    let smallest = least_budget(&chunks, cb);
    let err = plan_region_chunks(&chunks, cb, 1, costs, smallest - 1).expect_err("too small");
    assert!(err.to_string().contains("budget"), "{err}");
    let before = store.manifest().clone();
    let opts = RegionalOptions {
        budget_bytes: smallest - 1,
        ..swept(0)
    };
    let e = regularize_map(&mut store, &params(), &opts, |_, _| true).expect_err("refused");
    assert!(e.to_string().contains("MiB"), "{e}");
    assert_eq!(store.manifest().chunks, before.chunks, "nothing written");
    assert!(!map.join(SWEEPS_AREA).join("s0").exists());
    // A budget between: the planned regions' real peak stays under it, the result is exact.
    let budget = (smallest + one) / 2;
    let (r, bound) = plan_region_chunks(&chunks, cb, 1, costs, budget).expect("plan");
    assert!(
        bound <= budget && r < r1,
        "r {r}, bound {bound}, budget {budget}"
    );
    let opts = RegionalOptions {
        budget_bytes: budget,
        ..swept(0)
    };
    let stats = regularize_map(&mut store, &params(), &opts, |_, _| true).expect("planned");
    println!(
        "budget {budget} B: regions of {r}³ chunks, peak {} B",
        stats.peak_region_bytes
    );
    assert_eq!(stats.region_chunks, r);
    assert!(stats.peak_region_bytes <= bound, "{stats:?}");
    let mut want = mem.clone();
    denser::regularize::regularize_layer(&mut want, &params()).expect("global");
    let (worst, _) = max_u_difference(&want, &store_layer(&store));
    assert!(worst <= 1e-5, "{worst}");
}

/// The least budget the plan accepts (one chunk per region), found by bisection.
fn least_budget(
    chunks: &std::collections::BTreeMap<denser::map::ChunkIndex, denser::map::manifest::ChunkEntry>,
    cb: u32,
) -> u64 {
    let costs = RegionCosts::of(true);
    let (mut lo, mut hi) = (0u64, 1u64 << 40);
    while lo + 1 < hi {
        let mid = lo + (hi - lo) / 2;
        match plan_region_chunks(chunks, cb, 1, costs, mid) {
            Ok(_) => hi = mid,
            Err(_) => lo = mid,
        }
    }
    hi
}

/// K = 15 (a two-block halo): the outer ring of the halo stops being updated once it can no
/// longer reach the region (`TvProblem::limit_updates`), and the stored state after a sweep and
/// the final `u` are still the global solve's, bit for bit.
#[test]
fn sweeps_with_a_two_block_halo_equal_the_global_solve_bit_for_bit() {
    let dir = tempfile::tempdir().expect("tempdir");
    let map = dir.path().join("map");
    let (mem, mut store) = fused_store(&map);
    let params = TvParams {
        iterations: 40,
        ..TvParams::paper(0.05)
    };
    let opts = RegionalOptions {
        sweep_iterations: Some(15),
        ..swept(1)
    };
    let all = mem.indices_sorted();
    let mut global = TvProblem::gather(&mem, &all);
    // Stop after the first sweep and compare every stored state.
    let mut regions = 0;
    let first = regularize_map(&mut store, &params, &opts, |done, total| {
        regions = total / 4; // steps: initial state + 3 sweeps (15, 15, 10 iterations)
        done < 2 * regions
    })
    .expect("first sweep");
    assert_eq!(first.halo_blocks, 2, "15 iterations need 16 voxels of halo");
    for _ in 0..15 {
        global.iterate(&params);
    }
    assert_eq!(assert_state_equals(&map, 1, 1, &global), all.len());
    let last = regularize_map(&mut store, &params, &opts, |_, _| true).expect("finish");
    assert!(!last.interrupted && store.manifest().latest_pass_complete());
    for _ in 15..40 {
        global.iterate(&params);
    }
    let mut want = mem.clone();
    global.scatter(&mut want, &all);
    let (worst, _) = max_u_difference(&want, &store_layer(&store));
    assert_eq!(worst, 0.0, "max |u_swept − u_global|");
}

/// Issue 40: a swept pass reads, decodes and encodes a region's chunks on every thread but writes
/// them one by one in chunk order, so the regularized map — every chunk file and the manifest — is
/// byte for byte the same on 1 and 3 threads.
#[test]
fn a_swept_pass_writes_the_same_bytes_on_any_number_of_threads() {
    let dir = tempfile::tempdir().expect("tempdir");
    let (_, store) = fused_store(&dir.path().join("map"));
    drop(store);
    // Every file of a map (relative name, bytes), sorted.
    let files = |map: &Path| -> Vec<(String, Vec<u8>)> {
        let mut out = Vec::new();
        let mut stack = vec![map.to_path_buf()];
        while let Some(d) = stack.pop() {
            for e in std::fs::read_dir(&d).expect("ls") {
                let p = e.expect("entry").path();
                let rel = p.strip_prefix(map).expect("under").display().to_string();
                if p.is_dir() {
                    stack.push(p);
                } else {
                    out.push((rel, std::fs::read(&p).expect("read")));
                }
            }
        }
        out.sort();
        out
    };
    let mut maps = Vec::new();
    for threads in [1, 3] {
        let map = dir.path().join(format!("map_{threads}"));
        std::fs::create_dir_all(&map).expect("mkdir");
        for (rel, bytes) in files(&dir.path().join("map")) {
            let to = map.join(&rel);
            std::fs::create_dir_all(to.parent().expect("parent")).expect("mkdir");
            std::fs::write(&to, bytes).expect("copy");
        }
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .expect("pool");
        let stats = pool
            .install(|| {
                let mut store = MapStore::open(&map)?;
                regularize_map(&mut store, &params(), &swept(2), |_, _| true)
            })
            .expect("regularize");
        assert!(stats.regions > 3 && stats.core_blocks > 100, "{stats:?}");
        let written = files(&map).into_iter();
        maps.push(
            written
                .filter(|(rel, _)| rel.starts_with("chunks") || rel == "manifest.dmf")
                .collect::<Vec<_>>(),
        );
    }
    assert!(maps[0].len() > 10, "{} files", maps[0].len());
    let names = |m: &[(String, Vec<u8>)]| m.iter().map(|f| f.0.clone()).collect::<Vec<_>>();
    assert_eq!(names(&maps[0]), names(&maps[1]), "the same files");
    for (a, b) in maps[0].iter().zip(&maps[1]) {
        assert!(a.1 == b.1, "{} differs between 1 and 3 threads", a.0);
    }
}
