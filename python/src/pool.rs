//! The thread pool heavy calls run in, and the GIL release around them.
//!
//! `set_num_threads(n)` builds a rayon pool of `n` threads, `n` in 1..=[`diffcassi::limits::MAX_THREADS`]
//! (the CLI's `--threads` range; 0: back to rayon's global pool, sized by `RAYON_NUM_THREADS` or the core
//! count). Results never depend on the thread count (the library's rule).
//!
//! **fork.** A child made by `fork()` (a `multiprocessing` pool with the `fork` context, a forked
//! DataLoader worker) inherits the parent's memory but none of its threads: a rayon pool the parent started
//! — its own or rayon's global one — has no workers in the child, and the first parallel call would wait
//! for them forever. Every heavy call therefore checks the process id ([`run`]): in a process other than
//! the one that built the pool it builds a fresh pool of the same size (the parent's `set_num_threads`
//! choice, else `RAYON_NUM_THREADS` or the core count) and forgets the stale one (its threads do not
//! exist; dropping it would signal nobody). The check is one `getpid` per call.
//!
//! ```text
//! diffcassi.set_num_threads(2)      # this process: a 2-thread pool
//! multiprocessing.get_context("fork").Pool(2).map(work, items)   # each child: its own 2-thread pool
//! ```
use crate::arrays::uint_arg;
use crate::errors::value_error;
use pyo3::prelude::*;

/// Record the importing process (the one whose threads exist); called at module initialisation. The pool
/// itself, its fork check and the thread count live in the library ([`diffcassi::pool`]), shared with the C++ API.
pub fn init() {
    diffcassi::pool::init();
}

/// The pool of this process (`None`: rayon's global pool), rebuilt first in a fork child.
fn current() -> PyResult<Option<std::sync::Arc<rayon::ThreadPool>>> {
    diffcassi::pool::current().map_err(|e| pyo3::exceptions::PyRuntimeError::new_err(format!("set_num_threads: {e}")))
}

/// Run `f` without the GIL, inside the chosen pool (a fresh one in a fork child, see the module docs).
pub fn run<T: Send>(py: Python<'_>, f: impl FnOnce() -> T + Send) -> T {
    // Building a pool can fail only when the OS refuses threads; rayon's global pool is the fallback
    // (as before this check existed).
    let pool = current().unwrap_or(None);
    py.allow_threads(move || match pool {
        Some(p) => p.install(f),
        None => f(),
    })
}

/// [`run`] for a long call that stops early when asked: `f` runs on another thread (in the chosen pool)
/// while this one — the thread that holds the GIL, the main thread of a script or a notebook — waits for it,
/// waking every 50 ms to run Python's pending signal handlers. A raised `KeyboardInterrupt` (Ctrl-C) cancels
/// `stop` ([`diffcassi::cancel::Cancel`]), which `f` polls (the library's render rows, operator planes, solver
/// iterations); the call then waits for `f` — a poll away — and returns the exception with its result. (The
/// signal handlers run only on the main thread: `f`'s own thread cannot see a Ctrl-C, and a call made from
/// another Python thread is never interrupted; each call has its own token, so one call's Ctrl-C stops no
/// other.) A call that ends before the first wake returns at once (the worker says so on a channel).
pub fn run_interruptible<T: Send>(py: Python<'_>, stop: &diffcassi::cancel::Cancel, f: impl FnOnce() -> T + Send) -> (T, Option<PyErr>) {
    let pool = current().unwrap_or(None);
    let mut signal = None;
    let out = py.allow_threads(|| {
        std::thread::scope(|scope| {
            let (done, finished) = std::sync::mpsc::channel::<()>();
            let worker = scope.spawn(move || {
                let v = match pool {
                    Some(p) => p.install(f),
                    None => f(),
                };
                // Dropped on a panic too: the wait below then sees the channel closed.
                let _ = done.send(());
                v
            });
            loop {
                match finished.recv_timeout(std::time::Duration::from_millis(50)) {
                    Err(std::sync::mpsc::RecvTimeoutError::Timeout) => {
                        if signal.is_none() {
                            if let Err(e) = Python::with_gil(|py| py.check_signals()) {
                                signal = Some(e);
                                stop.cancel();
                            }
                        }
                    }
                    _ => break,
                }
            }
            worker.join()
        })
    });
    match out {
        Ok(v) => (v, signal),
        Err(panic) => std::panic::resume_unwind(panic),
    }
}

/// A library call that stops on Ctrl-C: `f` gets a fresh [`diffcassi::cancel::Cancel`] to hand to the library
/// (a render's [`diffcassi::render::Renderer::with_cancel`], a solve's `cancel`) and runs through
/// [`run_interruptible`]. A Ctrl-C during the call raises the `KeyboardInterrupt` itself (whatever `f` returned:
/// its `Interrupted` error, or a result finished between the last poll and the signal, which is dropped);
/// otherwise `f`'s result, its error as the Python exception.
pub fn run_cancellable<T: Send>(py: Python<'_>, f: impl FnOnce(&diffcassi::cancel::Cancel) -> diffcassi::Result<T> + Send) -> PyResult<T> {
    let stop = diffcassi::cancel::Cancel::new();
    let token = stop.clone();
    let (out, signal) = run_interruptible(py, &stop, move || f(&token));
    if let Some(e) = signal {
        return Err(e);
    }
    crate::errors::IntoPy::py(out)
}

/// Use `n` threads for every following heavy call: 1..=1024 (the CLI's `--threads` range), or 0 for
/// rayon's default (all cores or `RAYON_NUM_THREADS`).
#[pyfunction]
pub fn set_num_threads(n: &Bound<'_, PyAny>) -> PyResult<()> {
    let max = diffcassi::limits::MAX_THREADS;
    let n = uint_arg("set_num_threads: n", n, 0, max as u64)
        .map_err(|e| value_error(format!("{} (0: all cores; results do not depend on the thread count; the CLI's --threads takes 1..={max})", e.value(n.py()))))?
        as usize;
    diffcassi::pool::set_num_threads(n, "set_num_threads").map_err(|e| pyo3::exceptions::PyRuntimeError::new_err(e.to_string()))
}

/// Threads the heavy calls use.
/// The environment's `RAYON_NUM_THREADS` checked as the CLI checks it (`limits::check_rayon_env`); the package
/// calls it at import, before any pool starts.
#[pyfunction]
pub fn _check_rayon_env() -> PyResult<()> {
    diffcassi::limits::check_rayon_env().map_err(crate::errors::to_py)
}

#[pyfunction]
pub fn get_num_threads() -> PyResult<usize> {
    Ok(match current()? {
        Some(p) => p.current_num_threads(),
        None => rayon::current_num_threads(),
    })
}
