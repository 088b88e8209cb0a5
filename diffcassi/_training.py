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
    """The records of a JSONL training log that carry ``val_psnr_db``, by step — the **last** record of each step
    (a resume validates again the step it resumes at; a run continued from an older checkpoint re-does steps) —
    for a ``--summary EVERY`` table. A last line cut short (a run killed while writing it: no final newline) is
    skipped with a note on stderr; any other line that is not JSON, ``every`` < 1, a file that cannot be read, or
    one without a validation record raises ``ValueError`` naming ``prog``, the file and the line number."""
    import sys
    if every < 1:
        raise ValueError(f"{prog}: error: --summary EVERY must be ≥ 1, got {every}")
    try:
        text = log_path.read_text()
    except (OSError, UnicodeDecodeError) as e:
        raise ValueError(f"{prog}: error: {log_path}: {e}") from e
    lines = text.split("\n")
    by_step: dict = {}
    for number, line in enumerate(lines, 1):
        if not line.strip():
            continue
        try:
            r = json.loads(line)
        except json.JSONDecodeError as e:
            if number == len(lines):  # no newline after it: a write cut short (the run was killed)
                print(f"{prog}: note: {log_path}: line {number} is cut short (a run stopped while writing it); "
                      "skipped", file=sys.stderr)
                continue
            raise ValueError(f"{prog}: error: {log_path}: line {number}: not JSON ({e.msg}, column {e.colno})") from None
        if isinstance(r, dict) and "val_psnr_db" in r and isinstance(r.get("step"), int):
            by_step[r["step"]] = r
    if not by_step:
        raise ValueError(f"{prog}: error: {log_path} has no validation records")
    return [by_step[k] for k in sorted(by_step)]
