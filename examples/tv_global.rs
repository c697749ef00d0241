//! The global in-memory TV solve of a stored map, the reference that regional regularization
//! (`denser regularize MAP`) is measured against (`docs/bench/regularize.md`): every block loaded
//! into one `Layer`, one `TvProblem`, the iterations, `u` quantised as the map stores it. Prints
//! the CPU seconds (user + sys, `getrusage`) and wall seconds of loading and of the solve; given a
//! regularized map, also the largest |u − u_global| over its Ω voxels (the parameters are then that
//! map's latest pass). Usage: `tv_global MAP [REGULARISED_MAP]`.

use denser::grid::{decode_tsdf, Layer};
use denser::map::store::MapStore;
use denser::regularize::{TvParams, TvProblem};
use std::path::Path;

fn cpu_seconds() -> f64 {
    // SAFETY: getrusage writes the struct it is given and nothing else.
    let mut r: libc::rusage = unsafe { std::mem::zeroed() };
    unsafe { libc::getrusage(libc::RUSAGE_SELF, &mut r) };
    let tv = |t: libc::timeval| t.tv_sec as f64 + t.tv_usec as f64 * 1e-6;
    tv(r.ru_utime) + tv(r.ru_stime)
}

fn load(dir: &str) -> denser::Result<(MapStore, Layer)> {
    let store = MapStore::open_read_only(Path::new(dir))?;
    let mut layer = Layer::new(store.grid());
    for c in store.chunk_indices() {
        if let Some(d) = store.read_chunk(c)? {
            layer.put_blocks(d.blocks);
        }
    }
    Ok((store, layer))
}

fn main() -> denser::Result<()> {
    let args: Vec<String> = std::env::args().collect();
    let Some(dir) = args.get(1) else {
        eprintln!("usage: tv_global MAP [REGULARISED_MAP]");
        std::process::exit(2);
    };
    let (c0, w0) = (cpu_seconds(), std::time::Instant::now());
    let (store, mut layer) = load(dir)?;
    let compare = args.get(2).map(|d| load(d)).transpose()?;
    let params = match &compare {
        Some((s, _)) => s.manifest().header.reg_params,
        None => TvParams::paper(store.grid().voxel_size_m),
    };
    let (c1, w1) = (cpu_seconds(), std::time::Instant::now());
    let blocks = layer.indices_sorted();
    let mut problem = TvProblem::gather(&layer, &blocks);
    problem.solve(&params);
    problem.scatter(&mut layer, &blocks);
    let (c2, w2) = (cpu_seconds(), std::time::Instant::now());
    println!(
        "{} blocks, {} Ω voxels, {} iterations (λ {})",
        blocks.len(),
        problem.omega_count(),
        params.iterations,
        params.lambda
    );
    println!(
        "load: {:.2} s CPU, {:.2} s wall; global solve (gather, iterations, scatter): {:.2} s CPU, {:.2} s wall",
        c1 - c0,
        (w1 - w0).as_secs_f64(),
        c2 - c1,
        (w2 - w1).as_secs_f64()
    );
    if let Some((_, other)) = compare {
        let (mut worst, mut voxels, mut missing) = (0f32, 0u64, 0usize);
        for b in &blocks {
            let a = layer.get(b).expect("loaded block");
            let Some(o) = other.get(b).and_then(|o| o.regularized.as_ref()) else {
                missing += 1;
                continue;
            };
            let ua = a.regularized.as_ref().expect("scattered");
            for i in 0..512 {
                if a.omega(i) {
                    worst = worst.max((decode_tsdf(ua[i]) - decode_tsdf(o[i])).abs());
                    voxels += 1;
                }
            }
        }
        println!(
            "max |u − u_global| over {voxels} Ω voxels: {worst:e} ({missing} blocks without u)"
        );
    }
    Ok(())
}
