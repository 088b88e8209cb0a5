//! Helpers the hand-timed benches share (`#[path = "common/mod.rs"] mod common;`): environment overrides and
//! the process's CPU time, so that figures are reported as wall and CPU seconds (docs/performance.md).
#![allow(dead_code)]

/// A `usize` from the environment variable `name`, if set and parseable.
pub fn env_usize(name: &str) -> Option<usize> {
    std::env::var(name).ok().and_then(|v| v.parse().ok())
}

/// CPU seconds (user + system) of this process, from /proc/self/stat (Linux; NaN elsewhere).
pub fn cpu_seconds() -> f64 {
    let Ok(s) = std::fs::read_to_string("/proc/self/stat") else { return f64::NAN };
    let f: Vec<&str> = s.rsplit(')').next().unwrap_or("").split_whitespace().collect();
    let field = |i: usize| f.get(i).and_then(|v| v.parse::<f64>().ok()).unwrap_or(f64::NAN);
    (field(11) + field(12)) / 100.0
}

/// The load average over the last minute (Linux; NaN elsewhere).
pub fn load_average() -> f64 {
    std::fs::read_to_string("/proc/loadavg").ok().and_then(|s| s.split_whitespace().next().and_then(|v| v.parse().ok())).unwrap_or(f64::NAN)
}

/// Run `f` `reps` times (odd) and return the (wall, CPU) seconds of the median run by wall time.
pub fn median_timing(reps: usize, f: &mut dyn FnMut()) -> (f64, f64) {
    let mut v: Vec<(f64, f64)> = (0..reps)
        .map(|_| {
            let (t, c) = (std::time::Instant::now(), cpu_seconds());
            f();
            (t.elapsed().as_secs_f64(), cpu_seconds() - c)
        })
        .collect();
    v.sort_by(|a, b| a.0.total_cmp(&b.0));
    v[reps / 2]
}
