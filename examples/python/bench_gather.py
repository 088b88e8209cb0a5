"""The gather table (the CUDA path's code, `diffcassi._gather`) on the CPU, against the Rust operator and torch's
sparse CSR matmul, on the same exported matrix.

    .venv/bin/python examples/python/bench_gather.py --size 128            # SP, 28 bands, 112 planes, 20 rays
    .venv/bin/python examples/python/bench_gather.py --size 128 --rays 2 --planes 28

Steps: `Transport(sp, N, N)` (trace once); the library's CSR export (`Operator.to_csr_arrays`); the gather
tables of Φ and Φᵀ built from it (`CassiOperator(...)`, bucketed, padding reported); then forward and adjoint,
interleaved repetition by repetition (best and median of `--reps`, batch 1): the Rust operator through the
matrix-free module, the gather tables, and `torch.sparse.mm` on the CSR matrices (float32; Φᵀ as its own CSR).
Prints a Markdown table and the machine load (`uptime`).
"""
import argparse
import os
import time
import warnings

import numpy as np
import torch

import diffcassi
import diffcassi.torch as dt


def timed(f):
    t = time.perf_counter()
    r = f()
    return time.perf_counter() - t, r


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--size", type=int, default=128)
    ap.add_argument("--rays", type=int, default=20)
    ap.add_argument("--planes", type=int, default=112)
    ap.add_argument("--reps", type=int, default=7)
    ap.add_argument("--memory-gb", type=float, default=8.0)
    ap.add_argument("--threads", type=int, default=0, help="torch and Rust threads (0: the defaults)")
    a = ap.parse_args()
    if a.threads:
        torch.set_num_threads(a.threads)
        diffcassi.set_num_threads(a.threads)
    n = a.size
    t_tr, T = timed(lambda: diffcassi.Transport(diffcassi.System.preset("sp"), n, n, planes=a.planes, rays=a.rays))
    op = T.operator
    t_csr, (ip, ix, dv, shape) = timed(lambda: op.to_csr_arrays(a.memory_gb))
    t_tab, phi = timed(lambda: dt.CassiOperator(ip, ix, dv, shape, op.cube_shape, op.image_shape))
    mf = dt.CassiOperator.from_operator(T, matrix_free=True)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        A = torch.sparse_csr_tensor(torch.from_numpy(ip), torch.from_numpy(ix.astype(np.int64)), torch.from_numpy(dv), size=shape)
        At = A.t().to_sparse_csr()
    H, W, B = op.cube_shape
    x = torch.rand(1, B, H, W, generator=torch.Generator().manual_seed(0))
    y = torch.rand(1, *op.image_shape, generator=torch.Generator().manual_seed(1))
    xcols = x.permute(0, 2, 3, 1).reshape(1, -1)  # the CSR's column order [row][col][band]

    def sp_fwd():
        return torch.sparse.mm(A, xcols.t().contiguous()).t()

    def sp_adj():
        return torch.sparse.mm(At, y.reshape(1, -1).t().contiguous()).t()

    forms = {"Rust (matrix-free module)": (lambda: mf(x), lambda: mf.adjoint(y)),
             "gather table (CassiOperator)": (lambda: phi(x), lambda: phi.adjoint(y)),
             "torch.sparse.mm (CSR)": (sp_fwd, sp_adj)}
    times = {k: ([], []) for k in forms}
    with torch.no_grad():
        for _ in range(a.reps):
            for k, (f, g) in forms.items():
                times[k][0].append(timed(f)[0])
                times[k][1].append(timed(g)[0])
        ref_y, ref_x = mf(x).double(), mf.adjoint(y).double()
        dy = float((phi(x).double() - ref_y).abs().max() / ref_y.abs().max())
        dx = float((phi.adjoint(y).double() - ref_x).abs().max() / ref_x.abs().max())
    nnz = phi.nnz
    print(f"SP {n}×{n}×{B}, {a.planes} planes, {a.rays} rays; torch {torch.__version__}, {torch.get_num_threads()} threads")
    print(f"Transport {t_tr:.2f} s · CSR export {t_csr:.2f} s ({nnz:,} non-zeros) · gather tables {t_tab:.2f} s")
    print(f"padding: Φ {phi.phi_table.padding:.3f} ({len(phi.phi_table._buckets)} buckets, rows {shape[0]:,}) · "
          f"Φᵀ {phi.adjoint_table.padding:.3f} ({len(phi.adjoint_table._buckets)} buckets, rows {shape[1]:,}) · "
          f"table bytes {(phi.phi_table.nbytes() + phi.adjoint_table.nbytes()) / 1e6:.1f} MB "
          f"({(phi.phi_table.nbytes() + phi.adjoint_table.nbytes()) / nnz:.2f} B per non-zero)")
    print(f"gather vs Rust, max |diff| / peak: forward {dy:.2e}, adjoint {dx:.2e}")
    print("| form | forward best (median) | adjoint best (median) |\n|---|---|---|")
    for k, (f, g) in times.items():
        print(f"| {k} | {min(f):.4f} s ({np.median(f):.4f}) | {min(g):.4f} s ({np.median(g):.4f}) |")
    print("load:", os.getloadavg())


if __name__ == "__main__":
    main()
