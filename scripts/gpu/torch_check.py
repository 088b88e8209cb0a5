#!/usr/bin/env python3
"""The torch modules on a CUDA device (issue 41 items 3–4): one prepared check, run on the GPU machine from an
installed wheel (no Rust), prints a table and exits non-zero on any failed check.

    python scripts/gpu/torch_check.py                       # CUDA: SP 512×512×28 (2 rays, 28 planes), 128² training step
    python scripts/gpu/torch_check.py --cpu --size 32       # the same checks on the CPU at a tiny size (the tests run it)

Checks (each a row: value, bound, PASS/FAIL):
1. the exact operator's table: ``Transport`` trace, the library's CSR export and the gather tables built on the
   device (``CassiOperator.from_operator(T, matrix_free=True).to(device)``) — times, non-zeros, padding, bytes;
2. apply and adjoint on the device, batch 1, median of ``--reps`` (≥ 20 on CUDA) after warm-up, with
   ``torch.cuda.synchronize`` (bound: ``--time-bound-ms``, the issue's 10 ms, reported, checked on CUDA only);
3. the adjoint identity ⟨Φx, y⟩ = ⟨x, Φᵀy⟩ on device tensors, float32 (≤ 1e-6) and float64 (≤ 1e-12);
4. two runs bit-identical (apply and adjoint);
5. the device result against the same table applied on the CPU (CPU gather) and against the Rust operator
   (≤ 1e-5 of the peak: the library's export accuracy bound);
6. ``CassiRenderer`` on device cubes against the Rust render of the same seed (≤ 1e-6 of the peak), and its
   cube gradient against the Rust VJP;
7. one ``UnrolledGAP`` training step at ``--unrolled-size``² on the device: on CUDA, torch's profiler must show no
   host↔device copy of the cube or the acquisition (``diffcassi._gpu_check.unrolled_step``);
8. ``UnrolledDAUHST`` inference at ``--inference-size``² × 28 with the realistic exact operator (issue 43's speed
   line: ≤ 50 ms on the GPU), median time.
Checks 1–5 run under ``torch.use_deterministic_algorithms(True)``: an op torch does not guarantee deterministic on
the device raises there (a FAIL row).
"""
import argparse
import copy
import platform
import statistics
import sys
import time
import traceback

import numpy as np
import torch

import diffcassi
import diffcassi.torch as dt
from diffcassi import _gpu_check

ROWS = []


def row(check, value, bound, ok):
    ROWS.append((check, value, bound, "PASS" if ok else "FAIL"))
    print(f"  {ROWS[-1][3]}  {check}: {value} (bound {bound})", flush=True)  # as it goes: survives a time limit


def sync(dev):
    if dev.type == "cuda":
        torch.cuda.synchronize(dev)


def median_time(f, dev, reps, warm=3):
    for _ in range(warm):
        f()
    sync(dev)
    ts = []
    for _ in range(reps):
        t = time.perf_counter()
        f()
        sync(dev)
        ts.append(time.perf_counter() - t)
    return statistics.median(ts), min(ts)


def rel(a, b):
    a, b = a.detach().double().cpu(), b.detach().double().cpu()
    return float((a - b).abs().max() / b.abs().max().clamp_min(1e-300))


def operator_checks(a, dev):
    bands = torch.linspace(450.0, 650.0, a.bands).tolist()
    t = time.perf_counter()
    T = diffcassi.Transport(diffcassi.System.preset("sp"), a.size, a.size, bands_nm=bands, planes=a.planes, rays=a.rays)
    t_tr = time.perf_counter() - t
    op = T.operator
    mf = dt.CassiOperator.from_operator(T, matrix_free=True, memory_gb=a.memory_gb)
    t = time.perf_counter()
    mf = mf.to(dev) if dev.type == "cuda" else mf
    if dev.type == "cpu":
        mf._build_table(dev)  # the CUDA path's code on the CPU
    sync(dev)
    t_tab = time.perf_counter() - t
    A, At = mf.phi_table, mf.adjoint_table
    nbytes = A.nbytes() + At.nbytes()
    row(f"Transport(sp, {a.size}², {a.bands} bands, {a.planes} planes, {a.rays} rays)", f"{t_tr:.2f} s", "info", True)
    row("table: export + device build", f"{t_tab:.2f} s; {A.nnz:,} nnz; {nbytes / 1e9:.3f} GB ({nbytes / max(A.nnz, 1):.1f} B/nnz)",
        "info", True)
    row("table padding Φ · Φᵀ", f"{A.padding:.3f} ({len(A._buckets)} buckets) · {At.padding:.3f} ({len(At._buckets)})",
        "< 1.25", A.padding < 1.25 and At.padding < 1.25)
    H, W, B = op.cube_shape
    g = torch.Generator().manual_seed(0)
    x = torch.rand(1, B, H, W, generator=g)
    y = torch.rand(1, *op.image_shape, generator=g)
    xd, yd = x.to(dev), y.to(dev)
    with torch.no_grad():
        tf, tf_min = median_time(lambda: mf(xd), dev, a.reps)
        ta, ta_min = median_time(lambda: mf.adjoint(yd), dev, a.reps)
        timed = dev.type == "cuda"
        bound = f"≤ {a.time_bound_ms:g} ms" if timed else "info (CPU)"
        row(f"apply, median of {a.reps} (min)", f"{tf * 1e3:.3f} ms ({tf_min * 1e3:.3f})", bound, not timed or tf * 1e3 <= a.time_bound_ms)
        row(f"adjoint, median of {a.reps} (min)", f"{ta * 1e3:.3f} ms ({ta_min * 1e3:.3f})", bound, not timed or ta * 1e3 <= a.time_bound_ms)
        fx, aty = mf(xd), mf.adjoint(yd)
        for dtype, lim in ((torch.float32, 1e-6), (torch.float64, 1e-12)):
            xx, yy = xd.to(dtype), yd.to(dtype)
            lhs = float((mf(xx).double() * yy.double()).sum())
            rhs = float((xx.double() * mf.adjoint(yy).double()).sum())
            e = abs(lhs - rhs) / abs(lhs)
            row(f"adjoint identity {str(dtype)[6:]} on {dev.type}", f"{e:.2e}", f"≤ {lim:g}", e <= lim)
        same = torch.equal(mf(xd), fx) and torch.equal(mf(xd), fx)
        same_t = torch.equal(mf.adjoint(yd), aty) and torch.equal(mf.adjoint(yd), aty)
        row("apply · adjoint: repeated runs bit-identical", f"{same} · {same_t}", "True · True", same and same_t)
        # The same table on the CPU (the device's buffers copied; no rebuild). Both sides sum each row's n ≤ w
        # products in float32 in their own order, each within γ_(w+1)·(|A||x|) of the exact value (Higham), so
        # they differ by at most twice that, element by element (w: the table's widest bucket).
        Ac, Atc = copy.deepcopy(A).to("cpu"), copy.deepcopy(At).to("cpu")
        yc, xc = Ac.matmul(x.reshape(1, -1)), Atc.matmul(y.reshape(1, -1))
        d1, d2 = rel(fx.reshape(1, -1), yc), rel(aty.reshape(1, -1), xc)
        ok = True
        for t, out_dev, out_cpu, inp in ((Ac, fx.reshape(1, -1), yc, x.reshape(1, -1)), (Atc, aty.reshape(1, -1), xc, y.reshape(1, -1))):
            w = max(b[2] for b in t._buckets)
            gamma = (w + 1) * 2.0 ** -24 / (1 - (w + 1) * 2.0 ** -24)
            for _, vname, _ in t._buckets:
                getattr(t, vname).view(t.value_dtype).abs_()  # t becomes |A| (a copy)
            mag = t.matmul(inp.abs().double()).double()
            ok = ok and bool(((out_dev.detach().double().cpu() - out_cpu.double()).abs() <= 2 * gamma * mag).all())
        row(f"{dev.type} gather vs CPU gather (apply · adjoint, of peak)", f"{d1:.2e} · {d2:.2e}",
            "each ≤ 2γ_(w+1)·|A||x|", ok)
        del Ac, Atc
        ry = torch.from_numpy(op.apply(np.ascontiguousarray(x[0].permute(1, 2, 0).numpy())))
        rx = torch.from_numpy(op.adjoint(y[0].numpy())).permute(2, 0, 1)
        d1, d2 = rel(fx[0], ry), rel(aty[0], rx)
        row(f"{dev.type} gather vs Rust operator (apply · adjoint, of peak)", f"{d1:.2e} · {d2:.2e}", "≤ 1e-5", max(d1, d2) <= 1e-5)


def renderer_checks(a, dev):
    r = dt.CassiRenderer(diffcassi.System.preset("sp"), a.renderer_size, a.renderer_size, free=["prism_tilt_x"],
                         rays=2, planes=8, seed=1)
    cube = torch.rand(1, len(r.bands_nm), a.renderer_size, a.renderer_size, generator=torch.Generator().manual_seed(3))
    gy = None
    c0 = cube.double().requires_grad_(True)
    y0 = r(c0)  # the Rust render, float64, on the CPU
    gy = torch.rand_like(y0)
    (y0 * gy).sum().backward()
    r = r.to(dev)
    r.table_on_cpu = dev.type == "cpu"
    t = time.perf_counter()
    c1 = cube.to(dev).requires_grad_(True)
    y1 = r(c1)
    sync(dev)
    t1 = time.perf_counter() - t
    (y1 * gy.float().to(dev)).sum().backward()
    ok_dev = y1.device == c1.device == c1.grad.device
    d, dg = rel(y1, y0.detach()), rel(c1.grad, c0.grad)
    row(f"CassiRenderer {a.renderer_size}² on {dev.type} vs Rust render (of peak)", f"{d:.2e} (first call {t1:.2f} s)", "≤ 1e-6",
        d <= 1e-6 and ok_dev)
    row(f"CassiRenderer cube gradient on {dev.type} vs Rust VJP (of peak)", f"{dg:.2e}", "≤ 1e-6", dg <= 1e-6 and ok_dev)


def unrolled_checks(a, dev):
    out = _gpu_check.unrolled_step(dev, size=a.unrolled_size, bands=a.bands, planes=a.planes, rays=a.rays)
    if dev.type == "cuda":
        big = max([b for _, b in out["copies"] if b is not None] + [0])
        value = (f"step {out['step_s'] * 1e3:.1f} ms; {len(out['copies'])} host↔device copies (largest {big} B); "
                 f"{out['kernels']} kernels")
        bound = f"no copy ≥ {out['threshold_bytes']} B"
    else:
        value, bound = f"step {out['step_s'] * 1e3:.1f} ms, loss {out['loss']:.4g}", "runs (profiler on CUDA only)"
    row(f"UnrolledGAP training step {a.unrolled_size}² on {dev.type}", value, bound, np.isfinite(out["loss"]))


def inference_checks(a, dev):
    """Issue 43's GPU speed line: ``UnrolledDAUHST`` (v2 at its defaults, 1.1 M parameters) inference at
    ``--inference-size``² × 28 with the exact operator in the realistic setting (112 planes, 20 rays; the gather
    tables on the device), weights drawn N(0, 0.02) as ``scripts/bench_unrolled.py`` draws them (the time does not
    depend on their values; an untrained network's zero output layers would skip work). Bound ≤ 50 ms on CUDA."""
    n = a.inference_size
    t = time.perf_counter()
    op = diffcassi.exact(diffcassi.System.preset("sp"), n, n, planes=a.inference_planes, rays=a.inference_rays, seed=1)
    phi = dt.CassiOperator.from_operator(op, matrix_free=True, memory_gb=a.memory_gb).to(dev)
    t_op = time.perf_counter() - t
    net = dt.UnrolledDAUHST(phi)
    torch.manual_seed(0)
    with torch.no_grad():
        for p in net.parameters():
            p.normal_(0, 0.02)
    net = net.to(dev).eval()
    y = torch.rand(1, *phi.image_shape, generator=torch.Generator().manual_seed(5)).to(dev)
    with torch.no_grad():
        tm, t_min = median_time(lambda: net(y), dev, max(3, a.reps // 4), warm=2)
        out = net(y)
    timed = dev.type == "cuda"
    row(f"UnrolledDAUHST inference sp {n}²×{net.bands} ({a.inference_planes} planes, {a.inference_rays} rays) on {dev.type}, median (min)",
        f"{tm * 1e3:.1f} ms ({t_min * 1e3:.1f}); operator {t_op:.1f} s", "≤ 50 ms" if timed else "info (CPU)",
        bool(torch.isfinite(out).all()) and out.device == y.device and (not timed or tm * 1e3 <= 50.0))


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cpu", action="store_true", help="run the checks on the CPU (no GPU needed)")
    ap.add_argument("--size", type=int, default=512)
    ap.add_argument("--bands", type=int, default=28)
    ap.add_argument("--planes", type=int, default=28)
    ap.add_argument("--rays", type=int, default=2)
    ap.add_argument("--reps", type=int, default=20)
    ap.add_argument("--memory-gb", type=float, default=64.0)
    ap.add_argument("--time-bound-ms", type=float, default=10.0)
    ap.add_argument("--unrolled-size", type=int, default=128)
    ap.add_argument("--renderer-size", type=int, default=64)
    ap.add_argument("--inference-size", type=int, default=256, help="the unrolled v2 inference row's scene size")
    ap.add_argument("--inference-planes", type=int, default=112)
    ap.add_argument("--inference-rays", type=int, default=20)
    ap.add_argument("--threads", type=int, default=0, help="CPU threads of torch and the library (0: their defaults)")
    ap.add_argument("--out", default=None, help="folder for torch_check.json (the rows)")
    a = ap.parse_args()
    if a.threads:
        torch.set_num_threads(a.threads)
        diffcassi.set_num_threads(a.threads)
    if a.cpu:
        dev = torch.device("cpu")
    else:
        if not torch.cuda.is_available():
            print(f"torch_check: no CUDA device available to torch {torch.__version__} (CUDA build {torch.version.cuda}); "
                  "run with --cpu for the CPU checks", file=sys.stderr)
            return 2
        dev = torch.device("cuda", torch.cuda.current_device())
        if a.reps < 20:
            print("torch_check: --reps must be ≥ 20 on CUDA", file=sys.stderr)
            return 2
    name = torch.cuda.get_device_name(dev) if dev.type == "cuda" else platform.processor() or platform.machine()
    # On the CPU no figure is a GPU's: the table and the record say DRY RUN (`"dry_run": true`), as the render
    # checks' do (round 15: this one did not).
    dry = dev.type != "cuda"
    print(f"# torch_check: {'DRY RUN (CPU, no GPU figure); ' if dry else ''}{name}; torch {torch.__version__} (CUDA {torch.version.cuda}); "
          f"diffcassi {diffcassi.__file__}; {time.strftime('%Y-%m-%d %H:%M:%S %Z')}")
    t0 = time.perf_counter()
    for part in (operator_checks, renderer_checks, unrolled_checks, inference_checks):
        # The operator's table is built and applied with torch's deterministic-algorithms mode on: an op torch
        # does not guarantee deterministic on this device raises there. Not the training step: the U-Net's
        # determinism is not what is checked here, and cuBLAS-backed ops would need CUBLAS_WORKSPACE_CONFIG.
        torch.use_deterministic_algorithms(part is operator_checks)
        try:
            part(a, dev)
        except Exception as e:  # a failed part is a FAIL row; the others still run
            traceback.print_exc()
            row(part.__name__, f"{type(e).__name__}: {str(e)[:200]}", "no error", False)
    print(("\nDRY RUN (CPU): no figure below is a GPU's\n" if dry else "") + "\n| check | value | bound | result |\n|---|---|---|---|")
    for r in ROWS:
        print("| " + " | ".join(str(v) for v in r) + " |")
    failed = [r for r in ROWS if r[3] == "FAIL"]
    if a.out:
        import json
        import os
        os.makedirs(a.out, exist_ok=True)
        with open(os.path.join(a.out, "torch_check.json"), "w") as f:
            json.dump({"dry_run": dry, "device": name, "torch": torch.__version__, "rows": [dict(zip(("check", "value", "bound", "result"), map(str, r))) for r in ROWS]}, f, indent=1)
    print(f"\n{len(ROWS) - len(failed)}/{len(ROWS)} checks passed in {time.perf_counter() - t0:.1f} s"
          + ("; all checks passed" if not failed else f"; FAILED: {', '.join(r[0] for r in failed)}"))
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
