//! The `denser` command line: see [`cli`] (one module per command over the library).

mod cli;

fn main() -> std::process::ExitCode {
    cli::main()
}
