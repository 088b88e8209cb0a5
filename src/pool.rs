//! The thread pool the bindings' heavy calls run in, safe across `fork()`.
//!
//! The Python module and the C++ library both run the library's parallel work (rayon) from a caller's
//! process whose lifetime they do not control. Two things follow, owned here so that both bindings behave
//! the same:
//!
//! - **The thread count.** [`set_num_threads`]`(n)` builds a rayon pool of `n` threads, `n` in
//!   1..=[`crate::limits::MAX_THREADS`] (the CLI's `--threads` range); 0 goes back to rayon's global pool, sized
//!   by `RAYON_NUM_THREADS` or the core count. Results never depend on the thread count (the library's rule).
//! - **fork.** A child made by `fork()` (a pre-fork server, a `multiprocessing` pool with the `fork` context, a
//!   forked DataLoader worker) inherits the parent's memory but none of its threads: a rayon pool the parent
//!   started — its own or rayon's global one — has no workers in the child, and the first parallel call would
//!   wait for them forever (round 21: a C++ program that traced once, forked and traced again hung in the
//!   child). Every call through [`install`] therefore checks the process id: in a process other than the one
//!   that recorded the pool it builds a fresh pool of the same size (the parent's [`set_num_threads`] choice,
//!   else `RAYON_NUM_THREADS` or the core count) and forgets the stale one (its threads do not exist; dropping
//!   it would signal nobody). The check is one `getpid` per call.
//!
//! A binding calls [`init`] when it starts (Python at import, C++ on its first call), before any rayon work,
//! so that the process whose threads exist is on record; [`install`] records it too if no one did.
//!
//! ```
//! diffcassi::pool::init();
//! let sum: u64 = diffcassi::pool::install(|| { use rayon::prelude::*; (0..1000u64).into_par_iter().sum() });
//! assert_eq!(sum, 499_500);
//! ```
use crate::error::{Error, Result};
use std::sync::{Arc, RwLock};

/// The pool of this process: the thread count asked for (0: rayon's default), the pool (`None`: rayon's
/// global pool) and the process that built it.
struct State {
    requested: usize,
    pool: Option<Arc<rayon::ThreadPool>>,
    pid: u32,
}

static POOL: RwLock<Option<State>> = RwLock::new(None);

/// Record this process as the one whose threads exist (idempotent); a binding calls it once at start-up.
pub fn init() {
    let mut st = POOL.write().unwrap_or_else(|p| p.into_inner());
    if st.is_none() {
        *st = Some(State { requested: 0, pool: None, pid: std::process::id() });
    }
}

/// rayon's default thread count: `RAYON_NUM_THREADS` when set to a positive integer, else the cores.
fn default_threads() -> usize {
    std::env::var("RAYON_NUM_THREADS")
        .ok()
        .and_then(|v| v.trim().parse::<usize>().ok())
        .filter(|&n| n > 0)
        .unwrap_or_else(|| std::thread::available_parallelism().map(|c| c.get()).unwrap_or(1))
}

fn build(n: usize) -> Result<Arc<rayon::ThreadPool>> {
    rayon::ThreadPoolBuilder::new()
        .num_threads(n)
        .build()
        .map(Arc::new)
        .map_err(|e| Error::invalid(format!("cannot start a pool of {n} threads: {e}")))
}

/// The pool of this process (`None`: rayon's global pool), rebuilt first when this process is a fork child of
/// the one that recorded it. An error only when the OS refuses the threads.
pub fn current() -> Result<Option<Arc<rayon::ThreadPool>>> {
    let pid = std::process::id();
    {
        let st = POOL.read().unwrap_or_else(|p| p.into_inner());
        if let Some(s) = &*st {
            if s.pid == pid {
                return Ok(s.pool.clone());
            }
        }
    }
    let mut st = POOL.write().unwrap_or_else(|p| p.into_inner());
    let s = st.get_or_insert_with(|| State { requested: 0, pool: None, pid });
    if s.pid != pid {
        // A fork child: the pool's threads (and the global pool's, if the parent used it) are gone.
        let n = if s.requested > 0 { s.requested } else { default_threads() };
        let fresh = build(n)?;
        if let Some(stale) = s.pool.replace(fresh) {
            std::mem::forget(stale);
        }
        s.pid = pid;
    }
    Ok(s.pool.clone())
}

/// Run `f` inside this process's pool ([`current`]; a fresh one in a fork child). Building a pool fails only
/// when the OS refuses threads; rayon's global pool is then the fallback.
pub fn install<T: Send>(f: impl FnOnce() -> T + Send) -> T {
    match current().unwrap_or(None) {
        Some(p) => p.install(f),
        None => f(),
    }
}

/// Use `n` threads for every following call through [`install`]: 1..=[`crate::limits::MAX_THREADS`], or 0 for
/// rayon's default (all cores or `RAYON_NUM_THREADS`). A refused `n` leaves the pool as it was; the message
/// names `setter` (the front end's call, `diffcassi::set_num_threads`).
pub fn set_num_threads(n: usize, setter: &str) -> Result<()> {
    let max = crate::limits::MAX_THREADS;
    if n > max {
        return Err(Error::invalid(format!(
            "{setter}({n}): the thread count must be 0..={max} (0: all cores; results do not depend on the thread count; the CLI's --threads takes 1..={max})"
        )));
    }
    let pool = if n == 0 { None } else { Some(build(n).map_err(|e| Error::invalid(format!("{setter}({n}): {e}")))?) };
    let mut st = POOL.write().unwrap_or_else(|p| p.into_inner());
    *st = Some(State { requested: n, pool, pid: std::process::id() });
    Ok(())
}

/// The threads a call through [`install`] uses now.
pub fn num_threads() -> Result<usize> {
    Ok(match current()? {
        Some(p) => p.current_num_threads(),
        None => rayon::current_num_threads(),
    })
}
