"""The Python package's overhead, measured against the same work in Rust.

    .venv/bin/python examples/python/bench_overhead.py                       # 1e6 rays; 512×512×28, 20 rays
    .venv/bin/python examples/python/bench_overhead.py --size 128 --rays 4   # a quicker render part

1. Trace throughput at N rays (SP, seeded workload over the system's wavelengths): `diffcassi.trace` called from
   Python (NumPy (N, 3) arrays in, the dict of NumPy arrays out) against, timed inside Rust on the same rays
   (`_native._time_rust_trace`), `Tracer::trace` on an owned `RayBatch` and the binding's own blocked path
   without Python (so the last difference is the binding alone). Repetitions interleaved; best of `--reps`.
2. Dataset mode: `Transport.apply` per size×size×28 scene from Python against `Renderer::render_cached` (the
   call `apply` and `render-dataset` make per scene) timed inside Rust in the same process on the same scenes
   (interleaved), and against the CLI's dataset mode (`diffcassi bench-render`, its "dataset: per scene" row,
   a separate process run afterwards), same system, size, 112 planes, rays and mask opening 0.5.
Prints a Markdown table and the machine load (`uptime`).
"""
import argparse
import os
import pathlib
import re
import subprocess
import time

import numpy as np

import diffcassi
from diffcassi import _native

ROOT = pathlib.Path(__file__).resolve().parents[2]


def best(f, reps):
    times = []
    for _ in range(reps):
        t = time.perf_counter()
        f()
        times.append(time.perf_counter() - t)
    return min(times)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--rays-total", type=int, default=1_000_000)
    ap.add_argument("--reps", type=int, default=3)
    ap.add_argument("--size", type=int, default=512)
    ap.add_argument("--rays", type=int, default=20)
    ap.add_argument("--scenes", type=int, default=3)
    ap.add_argument("--skip-render", action="store_true")
    a = ap.parse_args()
    sp = diffcassi.System.preset("sp")
    ws = sp.wavelengths_nm
    o, d, w = sp.seeded_rays(a.rays_total // len(ws), ws, 1)
    n = len(w)
    # Interleaved repetitions (Rust, Rust blocked, Python, ...) so that a change of machine load hits all
    # three alike; the best of each is reported.
    t_rs, t_blk, t_py = [], [], []
    for _ in range(a.reps):
        t_rs += _native._time_rust_trace(sp, o, d, w, reps=1)
        t_blk += _native._time_rust_trace(sp, o, d, w, reps=1, blocked=True)
        t_py.append(best(lambda: diffcassi.trace(sp, o, d, w), 1))
    t_rs, t_blk, t_py = min(t_rs), min(t_blk), min(t_py)
    print(f"threads: {diffcassi.get_num_threads()}")
    print("| what | seconds | M rays/s |")
    print("|---|---|---|")
    print(f"| trace {n} rays, Rust (`Tracer::trace` on a `RayBatch`) | {t_rs:.3f} | {n / t_rs / 1e6:.2f} |")
    print(f"| trace {n} rays, Rust (the binding's blocked path, no Python) | {t_blk:.3f} | {n / t_blk / 1e6:.2f} |")
    print(f"| trace {n} rays, Python (`diffcassi.trace`, NumPy in/out) | {t_py:.3f} | {n / t_py / 1e6:.2f} |")
    print(f"| Python vs `Tracer::trace` | {100 * (t_py / t_rs - 1):+.1f} % | |")
    print(f"| Python vs the same path in Rust (binding overhead) | {100 * (t_py / t_blk - 1):+.1f} % | |")
    if not a.skip_render:
        s = a.size
        t = time.perf_counter()
        tr = diffcassi.Transport(sp, s, s, rays=a.rays)
        setup = time.perf_counter() - t
        per, per_rs = [], []
        for k in range(a.scenes):
            cube, wl = diffcassi.synthetic_scene(s, s, seed=100 + k)
            cube31 = np.ascontiguousarray(cube)  # 31 bands 400–700 nm; apply resamples to the transport's 28 bands
            # Interleaved: the same render_cached timed inside Rust, then Transport.apply from Python.
            per_rs += tr._time_render_cached(cube31, wl, reps=1)
            t = time.perf_counter()
            tr.apply(cube31, wl)
            per.append(time.perf_counter() - t)
        print(f"| Transport({s}×{s}, 112 planes, {a.rays} rays) build (trace once, {tr.nbytes / 1e9:.2f} GB) | {setup:.2f} | |")
        print(f"| `render_cached` per scene timed in Rust, same process (mean of {a.scenes}) | {np.mean(per_rs):.3f} | |")
        print(f"| Transport.apply per scene, Python (mean of {a.scenes}) | {np.mean(per):.3f} | |")
        print(f"| Python vs Rust, dataset mode | {100 * (np.mean(per) / np.mean(per_rs) - 1):+.1f} % | |")
        exe = ROOT / "target" / "release" / "diffcassi"
        out = subprocess.run([str(exe), "bench-render", "--preset", "sp", "--scene-size", str(s), "--rays", str(a.rays),
                              "--scenes", str(a.scenes)], check=True, capture_output=True, text=True).stdout
        m = re.search(r"\| dataset: per scene[^|]*\| ([0-9.]+) \|", out)
        print(f"| CLI dataset mode per scene (`bench-render`, render_cached) | {m.group(1) if m else '?'} | |")
    print("load:", os.popen("uptime").read().strip())


if __name__ == "__main__":
    main()
