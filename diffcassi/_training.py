"""Helpers shared by the training scripts (``scripts/train_denoiser.py``, ``scripts/train_unrolled.py``): the
per-cube PSNR they validate with, and reading back the validation records of their JSONL training logs.

Example::

    from diffcassi._training import psnr_db, validation_records
    p = psnr_db(output, clean)                         # (N,) dB, peak 1
    recs = validation_records(pathlib.Path("out/train-log.jsonl"), "train_denoiser")
"""
from __future__ import annotations

import json
import pathlib
from typing import List


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
