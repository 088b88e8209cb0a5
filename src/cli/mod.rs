//! The `diffcassi` command line: one subcommand per analysis, each writing CSV/JSON/NPY/PNG outputs.
//!
//! ```text
//! diffcassi info --preset sp
//! diffcassi distortion --preset sp --wavelength-nm 450 --grid 13 --half-width-mm 2.5 --csv grid.csv --png grid.png
//! diffcassi spot --preset ap --wavelength-nm 520 --field-mm 2.5,0 --pupil-csv rays.csv --csv spot.csv
//! diffcassi mapping --preset msp --npy mapping.npy
//! diffcassi report --preset sp --out out/sp
//! diffcassi render --preset sp                  # the main job: out/render-sp
//! diffcassi evaluate --truth scene.npy --estimate cube.npy --json metrics.json
//! ```
mod args;
mod commands;
pub mod render;
mod design;
pub mod evaluate;
mod fidelity;

pub use args::*;
/// Text forms shared with other front ends (the C++ API parses pupil patterns the same way).
pub use commands::{parse_pupil, parse_wavelengths};
use clap::Parser;

/// Entry point of the binary: parse, run, print errors; returns the process exit code
/// (0 success, 1 runtime error, 2 usage error).
pub fn main() -> i32 {
    let cli = match Cli::try_parse() {
        Ok(c) => c,
        Err(e) => {
            let code = if e.use_stderr() { 2 } else { 0 };
            let _ = e.print();
            return code;
        }
    };
    if let Some(n) = cli.threads {
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
