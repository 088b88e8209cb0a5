"""Helpers shared by the training scripts (``scripts/train_denoiser.py``, ``scripts/train_unrolled.py``): the
learning-rate schedule and the L1 optimisation step they both take, the per-cube PSNR they validate with, and
reading back the validation records of their JSONL training logs.

Example::

    from diffcassi._training import l1_step, lr_at, psnr_db, validation_records
    loss = l1_step(opt, net.parameters(), lr_at(step, steps, 3e-4, 1e-5, 100), 1.0, net(x), target)  # None: not finite
    p = psnr_db(output, clean)                         # (N,) dB, peak 1
    recs = validation_records(pathlib.Path("out/train-log.jsonl"), "train_denoiser")
"""
from __future__ import annotations

import json
import math
import pathlib
from typing import List, Optional


def lr_at(step: int, steps: int, lr: float, lr_min: float, warmup: int) -> float:
    """Linear warm-up over ``warmup`` steps, then cosine decay from ``lr`` to ``lr_min`` at ``steps``."""
    if step < warmup:
        return lr * (step + 1) / warmup
    p = min(1.0, (step - warmup) / max(1, steps - warmup))
    return lr_min + 0.5 * (lr - lr_min) * (1 + math.cos(math.pi * p))


def l1_step(opt, params, lr: float, clip: float, prediction, target) -> Optional[float]:
    """One optimisation step on the L1 loss mean|prediction − target|: every parameter group's learning rate set
    to ``lr``, then backward, gradient-norm clipping of ``params`` to ``clip`` and ``opt.step()``. Returns the
    loss's value, or None — nothing updated — when it is not finite (the caller says so and stops)."""
    import torch
    for pg in opt.param_groups:
        pg["lr"] = lr
    loss = (prediction - target).abs().mean()
    if not torch.isfinite(loss):
        return None
    opt.zero_grad(set_to_none=True)
    loss.backward()
    torch.nn.utils.clip_grad_norm_(params, clip)
    opt.step()
    return loss.item()


def psnr_db(x, ref):
    """Per-cube PSNR (dB) for a peak of 1: 10·log10(1/MSE), the MSE over every axis but the first (torch tensors)."""
    import torch
    mse = ((x - ref) ** 2).flatten(1).mean(1)
    return 10 * torch.log10(1.0 / mse)


def validation_records(log_path: pathlib.Path, prog: str, every: int = 1) -> List[dict]:
    """The records of a JSONL training log that carry ``val_psnr_db``, in order (for a ``--summary EVERY``
    table). ``every`` < 1, a file that cannot be read or parsed, or one without a validation record raises
    ``ValueError`` naming ``prog`` and the problem."""
    if every < 1:
        raise ValueError(f"{prog}: error: --summary EVERY must be ≥ 1, got {every}")
    try:
        recs = [json.loads(line) for line in log_path.read_text().splitlines() if line.strip()]
    except (OSError, json.JSONDecodeError) as e:
        raise ValueError(f"{prog}: error: {log_path}: {e}") from e
    vals = [r for r in recs if "val_psnr_db" in r]
    if not vals:
        raise ValueError(f"{prog}: error: {log_path} has no validation records")
    return vals
