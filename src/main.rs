fn main() {
    // A closed stdout (`diffcassi info … | head -1`) ends the process quietly, as it ends `cat`: Rust ignores
    // SIGPIPE, so `println!` would panic with "failed printing to stdout: Broken pipe" (a held-out battery,
    // round 7). Only the binary does this; the library (Python, C++) keeps the host's signal handling.
    #[cfg(unix)]
    // SAFETY: at the start of `main`, before any thread exists; restores the default action of one signal.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
    std::process::exit(diffcassi::cli::main());
}
