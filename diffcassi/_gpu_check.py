"""Device checks of the torch modules, called by ``scripts/gpu/torch_check.py`` on the GPU machine and by the tests on
the CPU (issue 41): one training step of :class:`diffcassi.torch.UnrolledGAP` around the exact operator on a device,
and, on CUDA, the proof from torch's profiler that the step copies neither the cube nor the acquisition between
host and device.
"""
from __future__ import annotations

import json
import os
import tempfile
from typing import Any, Dict, List, Tuple

import torch
import torch.nn.functional as F

import diffcassi


def _memcpys(trace_path: str) -> Tuple[List[Tuple[str, Any]], int]:
    """The host↔device copies ((name, bytes or None)) and the number of CUDA kernels in a Chrome trace written by
    ``torch.profiler.profile.export_chrome_trace``."""
    with open(trace_path) as f:
        events = json.load(f).get("traceEvents", [])
    copies, kernels = [], 0
    for e in events:
        if not isinstance(e, dict):
            continue
        name, cat = str(e.get("name", "")), str(e.get("cat", "")).lower()
        if cat == "kernel":
            kernels += 1
        if ("memcpy" in cat or name.startswith("Memcpy")) and ("HtoD" in name or "DtoH" in name):
            args = e.get("args") or {}
            copies.append((name, args.get("bytes")))
    return copies, kernels


def unrolled_step(device: Any = "cuda", size: int = 128, bands: int = 28, planes: int = 28, rays: int = 2,
                  stages: int = 2, width: int = 8, batch: int = 1, seed: int = 0) -> Dict[str, Any]:
    """One training step (forward, MSE loss, backward, Adam) of an ``UnrolledGAP`` around the matrix-free exact
    operator of SP at ``size``² on ``device``, after one warm-up step. On CUDA the step runs under
    ``torch.profiler.profile(activities=[CPU, CUDA])`` and an AssertionError is raised when the trace shows a
    host↔device copy (``Memcpy HtoD``/``DtoH``) of ≥ 1/8 of the smaller of one acquisition and one cube (or of
    unknown size), or no CUDA kernel at all (a vacuous trace). On the CPU the step runs without the profiler.
    Returns the figures (device, loss before/after, shapes, copies seen, threshold, kernels, seconds)."""
    import time

    import diffcassi.torch as dt

    dev = torch.device(device)
    bands_nm = [float(v) for v in torch.linspace(450.0, 650.0, bands).tolist()]
    t0 = time.perf_counter()
    transport = diffcassi.Transport(diffcassi.System.preset("sp"), size, size, bands_nm=bands_nm, planes=planes, rays=rays)
    phi = dt.CassiOperator.from_operator(transport, matrix_free=True, device=dev)
    net = dt.UnrolledGAP(phi, stages=stages, width=width)
    build_s = time.perf_counter() - t0
    assert net.device == dev and all(p.device == dev for p in net.parameters()), "UnrolledGAP is not on the operator's device"
    gen = torch.Generator(device=dev).manual_seed(seed)
    truth = torch.rand(batch, bands, size, size, device=dev, generator=gen)
    with torch.no_grad():
        y = phi(truth)
    opt = torch.optim.Adam(net.parameters(), lr=1e-3)

    def step():
        opt.zero_grad(set_to_none=True)
        loss = F.mse_loss(net(y), truth)
        loss.backward()
        opt.step()
        return loss.detach()

    first = step()  # warm-up: allocator, kernels' first launches
    h, w = phi.image_shape
    acq_bytes, cube_bytes = h * w * 4, bands * size * size * 4
    out: Dict[str, Any] = {"device": str(dev), "size": size, "bands": bands, "image_shape": (h, w), "build_s": build_s,
                           "threshold_bytes": min(acq_bytes, cube_bytes) // 8}
    if dev.type != "cuda":
        t = time.perf_counter()
        loss = step()
        out.update(step_s=time.perf_counter() - t, loss_first=float(first), loss=float(loss), copies=None, kernels=None)
        return out
    torch.cuda.synchronize(dev)
    acts = [torch.profiler.ProfilerActivity.CPU, torch.profiler.ProfilerActivity.CUDA]
    with torch.profiler.profile(activities=acts) as prof:
        t = time.perf_counter()
        loss = step()
        torch.cuda.synchronize(dev)
        step_s = time.perf_counter() - t
    fd, path = tempfile.mkstemp(suffix=".json")
    os.close(fd)
    try:
        prof.export_chrome_trace(path)
        copies, kernels = _memcpys(path)
    finally:
        os.remove(path)
    out.update(step_s=step_s, loss_first=float(first), loss=float(loss), copies=copies, kernels=kernels)
    big = [(n, b) for n, b in copies if b is None or int(b) >= out["threshold_bytes"]]
    assert kernels > 0, "the profiler recorded no CUDA kernel in the training step: the copy check would be vacuous"
    assert not big, (f"the training step copied between host and device: {big} (threshold {out['threshold_bytes']} bytes; "
                     f"one acquisition is {acq_bytes} bytes, one cube {cube_bytes})")
    return out
