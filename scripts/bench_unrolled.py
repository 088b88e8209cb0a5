#!/usr/bin/env python3
"""CPU (or CUDA) inference time of an unrolled network at a given size (issue 43's speed line: SP 256×256×28 on the
CPU ≤ 10 s; on the GPU ≤ 50 ms):

    .venv/bin/python scripts/bench_unrolled.py --size 256 --threads 2 --reps 3           # v2, random weights
    .venv/bin/python scripts/bench_unrolled.py --weights W.safetensors --system sp --device cuda
    .venv/bin/python scripts/bench_unrolled.py --size 256 --threads 2 --reps 3 --rust     # the Rust inference (candle)

The operator is the exact one in the realistic setting (112 planes, 20 rays, seed 1; the paper mask's centre crop
with --mask, else the library's random mask). Without --weights the network is ``unrolled-dauhst-v2`` at its
defaults with weights drawn N(0, 0.02) (torch seed 0), so every layer works (an untrained network's zero output
layers would not). Prints the trace time, each forward's time, Φ's and Φᵀ's, and the load average."""
import argparse
import os
import pathlib
import sys
import time

import numpy as np
import torch

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))
import diffcassi  # noqa: E402
import diffcassi.torch as dt  # noqa: E402
from diffcassi.unrolled import count_parameters, load_unrolled  # noqa: E402


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--system", default="sp")
    ap.add_argument("--size", type=int, default=256)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--reps", type=int, default=3)
    ap.add_argument("--planes", type=int, default=112)
    ap.add_argument("--rays", type=int, default=20)
    ap.add_argument("--mask", default=None, help="mask NPY, centre-cropped to --size")
    ap.add_argument("--weights", default=None)
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--rust", action="store_true", help="time the Rust inference (reconstruct --solver unrolled's) "
                    "on the same operator and weights (written to a temporary safetensors file) instead of PyTorch")
    a = ap.parse_args(argv)
    torch.set_num_threads(a.threads)
    diffcassi.set_num_threads(a.threads)
    mask = None
    if a.mask:
        m = np.load(a.mask).astype(np.float32)
        r0, c0 = (m.shape[0] - a.size) // 2, (m.shape[1] - a.size) // 2
        mask = np.ascontiguousarray(m[r0:r0 + a.size, c0:c0 + a.size])
    t = time.time()
    # Transport(...).operator is exact(...) with the same settings (one trace); it also gives the mask it used.
    transport = diffcassi.Transport(diffcassi.System.preset(a.system), a.size, a.size, mask=mask, planes=a.planes, rays=a.rays, seed=1)
    op = transport.operator
    phi = dt.CassiOperator.from_operator(op, matrix_free=True).to(a.device)
    print(f"trace {time.time() - t:.1f} s", flush=True)
    if a.weights:
        net = load_unrolled(a.weights, phi, system=a.system, mask=mask)
    else:
        net = dt.UnrolledDAUHST(phi)
        torch.manual_seed(0)
        with torch.no_grad():
            for p in net.parameters():
                p.normal_(0, 0.02)
    net.eval()
    if a.rust:
        import json
        import tempfile
        from diffcassi import _native
        from diffcassi.unrolled import mask_sha256, save_unrolled, system_sha256
        with tempfile.TemporaryDirectory() as d:
            path = os.path.join(d, "w.safetensors")
            if a.weights:
                path = a.weights
            else:
                save_unrolled(net, path, {"system": a.system, "mask_sha256": mask_sha256(transport.mask),
                                          "system_sha256": system_sha256(diffcassi.System.preset(a.system))})
            y = np.random.default_rng(0).uniform(0, 1, op.image_shape).astype(np.float32)
            ts = []
            for _ in range(a.reps):
                t = time.time()
                x, rec = _native._unrolled(op, y, path, a.system)
                ts.append(time.time() - t)
            rec = json.loads(rec)
        print(f"Rust {rec['network']['name']} ({count_parameters(net)} parameters), {a.system} {a.size}×{a.size}×{x.shape[2]}, "
              f"{a.threads} threads: forward {[round(v, 3) for v in ts]} s; load average {os.getloadavg()[0]:.2f}")
        return 0
    y = torch.rand(1, *phi.image_shape, device=phi.device)
    sync = torch.cuda.synchronize if phi.device.type == "cuda" else (lambda: None)
    ts = []
    with torch.no_grad():
        for _ in range(a.reps + (1 if phi.device.type == "cuda" else 0)):
            sync()
            t = time.time()
            net(y)
            sync()
            ts.append(time.time() - t)
        x = torch.rand(1, net.bands, a.size, a.size, device=phi.device)
        sync()
        t = time.time()
        phi(x)
        sync()
        tf = time.time() - t
        t = time.time()
        phi.adjoint(y)
        sync()
        ta = time.time() - t
    print(f"{type(net).__name__} ({count_parameters(net)} parameters), {a.system} {a.size}×{a.size}×{net.bands}, "
          f"{a.threads} threads, {phi.device}: forward {[round(v, 3) for v in ts]} s; Φ {tf:.3f} s, Φᵀ {ta:.3f} s; "
          f"load average {os.getloadavg()[0]:.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
