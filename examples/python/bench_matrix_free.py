"""The matrix-free torch operator against the Rust operator it calls, and against the CSR form.

    .venv/bin/python examples/python/bench_matrix_free.py --size 128      # SP, 112 planes, 20 rays (CSR form too)
    .venv/bin/python examples/python/bench_matrix_free.py --size 512      # ~1 min to build; CSR refused (size printed)

One process per size (peak RSS is per process). Steps, all on SP with 28 bands, 112 planes, `--rays` rays per
pixel per plane:

1. `Transport(sp, N, N)` — trace once; RSS after it (the operator's own memory).
2. Forward and adjoint, interleaved repetition by repetition so that load changes hit all alike (best and
   median of `--reps`, batch 1): the Rust operator's `Operator.apply(cube)` / `.adjoint(image)` from NumPy
   (the reference), the matrix-free module `CassiOperator.from_operator(T, matrix_free=True)` on a
   (1, 28, N, N) tensor (one re-layout copy to the operator's (H, W, bands)) and on a channels-last view
   (no copy), and its adjoint on a (1, h, w) tensor.
3. Peak memory of each form's calls: the peak RSS (VmHWM, reset before each form through
   /proc/self/clear_refs) during two forward + adjoint calls of the Rust operator from NumPy, then of the
   matrix-free module, each minus the RSS after step 1 (the operator's scratch buffers, allocated at its
   first use, count in the first form measured: the Rust one).
4. The CSR form (`CassiOperator.from_operator(T)`, `--csr-memory-gb`): built when it fits; its RSS increase and
   forward/adjoint times — or, when refused, the library's estimate from the refusal.
Prints a Markdown table and the machine load (`uptime`).
"""
import argparse
import os
import re
import time

import numpy as np
import torch

import diffcassi
import diffcassi.torch as dt


def status_kb(key):
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith(key + ":"):
                return int(line.split()[1])
    return 0


def gb(kb):
    return kb * 1024 / 1e9


def peak_over(base_kb, f):
    """Peak RSS (kB) during f() above base_kb: VmHWM reset first (/proc/self/clear_refs, "5"); if the reset
    is not allowed, the process's peak so far."""
    try:
        with open("/proc/self/clear_refs", "w") as c:
            c.write("5")
    except OSError:
        pass
    f()
    return status_kb("VmHWM") - base_kb


def timed(f):
    t = time.perf_counter()
    f()
    return time.perf_counter() - t


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--size", type=int, default=128)
    ap.add_argument("--planes", type=int, default=112)
    ap.add_argument("--rays", type=int, default=20)
    ap.add_argument("--reps", type=int, default=7)
    ap.add_argument("--csr-memory-gb", type=float, default=4.0)
    a = ap.parse_args()
    torch.set_grad_enabled(False)
    sp = diffcassi.System.preset("sp")
    n = a.size
    rss0 = status_kb("VmRSS")
    t = time.perf_counter()
    T = diffcassi.Transport(sp, n, n, planes=a.planes, rays=a.rays)
    build = time.perf_counter() - t
    rss_op = status_kb("VmRSS")
    op = T.operator
    H, W, B = op.cube_shape
    h, w = op.image_shape
    rng = np.random.default_rng(0)
    cube = rng.random((H, W, B), dtype=np.float32)
    image = rng.random((h, w), dtype=np.float32)
    mf = dt.CassiOperator.from_operator(T, matrix_free=True)
    x = torch.from_numpy(np.ascontiguousarray(cube.transpose(2, 0, 1)))[None]  # (1, bands, H, W) contiguous
    x_cl = torch.from_numpy(cube)[None].permute(0, 3, 1, 2)                     # channels-last view, same values
    y = torch.from_numpy(image)[None]
    peak_rust = peak_over(rss_op, lambda: [(op.apply(cube), op.adjoint(image)) for _ in range(2)])
    peak_mf = peak_over(rss_op, lambda: [(mf(x), mf.adjoint(y)) for _ in range(2)])
    assert np.array_equal(mf(x)[0].numpy(), op.apply(cube))
    assert np.array_equal(mf.adjoint(y)[0].permute(1, 2, 0).numpy(), op.adjoint(image))
    rows = {k: [] for k in ("rust_fwd", "mf_fwd", "mf_fwd_cl", "rust_adj", "mf_adj")}
    for _ in range(a.reps):
        rows["rust_fwd"].append(timed(lambda: op.apply(cube)))
        rows["mf_fwd"].append(timed(lambda: mf(x)))
        rows["mf_fwd_cl"].append(timed(lambda: mf(x_cl)))
        rows["rust_adj"].append(timed(lambda: op.adjoint(image)))
        rows["mf_adj"].append(timed(lambda: mf.adjoint(y)))
    best = {k: min(v) for k, v in rows.items()}
    med = {k: float(np.median(v)) for k, v in rows.items()}
    print(f"SP {n}×{n}×{B}, {a.planes} planes, {a.rays} rays; detector {h}×{w}; threads {diffcassi.get_num_threads()}; "
          f"torch {torch.__version__}")
    print("| what | best s | median s | vs Rust (best · median) |")
    print("|---|---|---|---|")
    print(f"| Transport build (trace once; {T.nbytes / 1e9:.2f} GB kept) | {build:.2f} | | |")
    for k, label, ref in (("rust_fwd", "Rust `Operator.apply` (NumPy)", "rust_fwd"),
                          ("mf_fwd", "matrix-free forward, (1, 28, H, W) tensor (one re-layout copy)", "rust_fwd"),
                          ("mf_fwd_cl", "matrix-free forward, channels-last view (no copy)", "rust_fwd"),
                          ("rust_adj", "Rust `Operator.adjoint` (NumPy)", "rust_adj"),
                          ("mf_adj", "matrix-free adjoint, (1, h, w) tensor", "rust_adj")):
        print(f"| {label} | {best[k]:.4f} | {med[k]:.4f} | {best[k] / best[ref]:.3f}× · {med[k] / med[ref]:.3f}× |")
    print(f"| RSS: before the Transport · after it (the operator) | {gb(rss0):.2f} GB · {gb(rss_op):.2f} GB | | |")
    print(f"| peak RSS over the operator's: Rust apply + adjoint · matrix-free forward + adjoint | "
          f"+{gb(peak_rust):.3f} GB · +{gb(peak_mf):.3f} GB | | |")
    try:
        rss_before = status_kb("VmRSS")
        t = time.perf_counter()
        csr = dt.CassiOperator.from_operator(T, memory_gb=a.csr_memory_gb)
        csr_build = time.perf_counter() - t
        rss_csr = status_kb("VmRSS")
        f_csr = min(timed(lambda: csr(x)) for _ in range(2))
        a_csr = min(timed(lambda: csr.adjoint(y)) for _ in range(2))
        print(f"| CSR form: build · nnz | {csr_build:.2f} s · {csr.nnz:,} | | |")
        print(f"| CSR form: RSS added (Φ and Φᵀ kept) · peak RSS | +{gb(rss_csr - rss_before):.2f} GB · {gb(status_kb('VmHWM')):.2f} GB | | |")
        print(f"| CSR form forward · adjoint (float32, best of 2) | {f_csr:.4f} · {a_csr:.4f} | | "
              f"{f_csr / best['rust_fwd']:.1f}× · {a_csr / best['rust_adj']:.1f}× |")
    except diffcassi.DiffcassiValueError as e:
        m = re.search(r"([0-9.]+ GB)", str(e))
        print(f"| CSR form: refused above --csr-memory-gb {a.csr_memory_gb} | estimate {m.group(1) if m else '?'} | | |")
        print(f"\n(refusal: {e})")
    print("load:", os.popen("uptime").read().strip())


if __name__ == "__main__":
    main()
