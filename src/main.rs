//! The `denser` command line: see [`cli`] (one module per command over the library).

mod cli;

/// Stack of each of rayon's workers: the command runs on one of them (see `main`), so it gets
/// what a main thread would have.
const WORKER_STACK_BYTES: usize = 8 << 20;

fn main() -> std::process::ExitCode {
    // The whole command runs on a worker of rayon's pool, so every parallel loop starts from
    // inside the pool instead of waking it from outside: a futex round trip per loop, which
    // cost 3 s of a 25 s regional regularisation made of ~50 000 small loops.
    let pool = rayon::ThreadPoolBuilder::new()
        .stack_size(WORKER_STACK_BYTES)
        .build_global();
    if let Err(e) = pool {
        eprintln!("denser: could not start the worker threads ({e}); running on the main thread");
        return cli::main();
    }
    rayon::scope(|_| cli::main())
}
