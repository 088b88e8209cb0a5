//! The `diffcassi` command line: one subcommand per analysis, each writing CSV/JSON/NPY/PNG outputs.
//!
//! ```text
//! diffcassi info --preset sp
//! diffcassi distortion --preset sp --wavelength-nm 450 --grid 13 --half-width-mm 2.5 --csv grid.csv --png grid.png
//! diffcassi spot --preset ap --wavelength-nm 520 --field-mm 2.5,0 --pupil-csv rays.csv --csv spot.csv
//! diffcassi mapping --preset msp --npy mapping.npy
//! diffcassi report --preset sp --out out/sp
//! diffcassi render --preset sp                  # the main job: out/render-sp
//! ```
mod args;
mod commands;
pub mod render;
mod design;
mod fidelity;

pub use args::*;
/// Text forms shared with other front ends (the C++ API parses pupil patterns the same way).
pub use commands::{parse_pupil, parse_wavelengths};
use clap::{CommandFactory, FromArgMatches};

/// The command tree, with negative numbers accepted as option values everywhere (`--tilt -5`,
/// `--tolerance-um -1` reach the option's own check, which names it, instead of clap's "unexpected argument").
pub fn command() -> clap::Command {
    fn relax(c: clap::Command) -> clap::Command {
        c.allow_negative_numbers(true).mut_subcommands(relax)
    }
    relax(Cli::command())
}

/// Entry point of the binary: parse, run, print errors; returns the process exit code
/// (0 success, 1 runtime error, 2 usage error).
pub fn main() -> i32 {
    let cli = match command().try_get_matches().and_then(|m| Cli::from_arg_matches(&m)) {
        Ok(c) => c,
        Err(e) => {
            let code = if e.use_stderr() { 2 } else { 0 };
            let _ = e.print();
            return code;
        }
    };
    if let Err(e) = crate::limits::set_budget(cli.max_memory_gb, cli.max_rays) {
        eprintln!("error: {e}");
        return 2;
    }
    if let Some(n) = cli.threads {
        if let Err(e) = crate::limits::check_threads(n) {
            eprintln!("error: {e}");
            return 2;
        }
        if let Err(e) = rayon::ThreadPoolBuilder::new().num_threads(n).build_global() {
            eprintln!("error: cannot set {n} threads: {e}");
            return 1;
        }
    }
    match commands::run(cli.command) {
        Ok(()) => 0,
        Err(e) => {
            eprintln!("error: {e:#}");
            1
        }
    }
}
