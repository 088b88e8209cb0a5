#!/usr/bin/env python3
"""Trains an unrolled network around the exact operator for one system, on acquisitions rendered on the fly:
``unrolled-gap-v1`` (``diffcassi.torch.UnrolledGAP``, the default ``--arch``) or ``unrolled-dauhst-v2``
(``diffcassi.torch.UnrolledDAUHST``, issue 43), on the CPU or a CUDA device, in short resumable runs.

    nice -n 10 .venv/bin/python scripts/train_unrolled.py --system sp --mask ../shared/reference/paper_mask_512.npy \\
        --out out/unrolled-sp --steps 400 --minutes 25 --threads 1
    .venv/bin/python scripts/train_unrolled.py --system sp ... --resume out/unrolled-sp/unrolled-sp-state.pt
    .venv/bin/python scripts/train_unrolled.py --out out/unrolled-sp --system sp --summary 50   # the curve
    # v2, one ≤ 9-minute GPU run continuing the committed initial checkpoint (scripts/gpu/train_run.sh):
    python scripts/train_unrolled.py --arch unrolled-dauhst-v2 --system sp --device cuda --workers 14 \\
        --resume diffcassi/weights/unrolled-dauhst-v2-sp-init.pt --out $OUT --time-budget-s 450

Recipe of ``unrolled-gap-v1`` (diffcassi/weights/UNROLLED.md states the run's numbers):

* scenes: procedural dead-leaves cubes only (``diffcassi.deadleaves``, both kinds: measured-spectra and
  uplifted-sRGB leaves), ``--size``² × 28 bands (450–650 nm), peak 1; at step s the batch holds the cubes of
  seeds ``TRAIN_SEED_BASE + batch·s + i`` (i even: spectral, odd: rgb); validation seeds ``0 … VAL_COUNT−1`` of
  each kind: disjoint by construction, and no image file is read (the evaluation scenes of ``data/scenes`` never
  enter: tested);
* acquisitions: rendered through the system's exact light transport (``diffcassi.Transport``: the renderer, bit
  for bit) in the realistic setting of docs/study.md — 112 planes, 20 rays per pixel per plane, stratified, Airy
  2.5 px at 520 nm, the mask ``--mask`` centre-cropped to the scene (the study's rule; default a random mask of
  opening 0.5, seed 0) — traced with ``--acquisition-seed`` (1000: neither the evaluation's acquisition seed 0 nor
  the operator's); no sensor noise;
* operator: the exact operator traced with ``--operator-seed`` (1: the evaluation's ``reconstruct`` default,
  acquisition seed + 1), in its matrix-free torch form; its Monte-Carlo rays differ from the acquisition's (the
  realistic setting, no oracle);
* loss: L1 between the output and the cube; Adam (β 0.9/0.999), learning rate ``--lr`` with a linear warm-up and
  a cosine decay to ``--lr-min`` at ``--steps``; gradient-norm clipping ``--clip``; torch seed ``--seed``;
* validation every ``--val-every`` steps (default 25; kept in the checkpoint and restored on resume): PSNR (peak 1)
  of the fixed validation cubes of both kinds; each validation saves the state, then the weights, then the manifest
  of that step (so they always describe one step), then logs it;
* outputs in ``--out``: ``unrolled-gap-v1-<system>.safetensors`` (the weights of the last step saved: at the end
  the end of the schedule, a validation-independent choice), ``unrolled-<system>-log.jsonl`` (one JSON line per
  validation, appended on resume; strict JSON: no NaN or infinity), ``unrolled-<system>-manifest.json`` (data
  sources and seed rules) and ``unrolled-<system>-state.pt`` (the resume state; not committed).

``unrolled-dauhst-v2`` differs in the data and the bookkeeping: the cubes are :func:`diffcassi.training_data.sample`
of seeds ``TRAIN_SEED_BASE_V2 + batch·s + i`` (measured-spectra and current dead leaves, scikit-image textures lifted
to measured spectra; crops, flips, exposure), each acquisition with its own sensor noise
(:func:`diffcassi.training_data.noisy`, seeded by the cube's seed); validation seeds ``0 … VAL_COUNT_V2−1``; the
files are ``unrolled-dauhst-v2-<system>.safetensors``, ``…-log.jsonl``, ``…-manifest.json`` and
``…-checkpoint.pt``. The manifest lists **every run** that made the weights (start and end time UTC, device,
steps from → to: the data seeds follow from the steps), carried from checkpoint to checkpoint, so that several
short GPU runs continue one training. ``--workers N`` makes the cubes and renders their acquisitions in N processes
(the GPU machine's cores; the same batches as without workers, tested).

Short runs: ``--time-budget-s`` (v2 default 450 s, a ≤ 9-minute GPU call with the wheel's install) stops the
loop before the budget would be passed (measured step and validation times), validates, saves the checkpoint and
the weights and exits 0. ``--resume CHECKPOINT`` continues from a checkpoint (model, optimiser, step, RNG state,
the training mask, ``--val-every`` and the runs so far); settings not given on the command line are the
checkpoint's. The optimiser's ``--lr``, ``--lr-min`` and ``--clip`` may be given with new values (a lower rate after
a divergence, a longer decay's floor): the run's manifest entry records them under ``changed`` as
``[checkpoint's, this run's]``. Any other setting given with another value — or a checkpoint of another
architecture, system or band count, or
a file that is truncated or not a checkpoint — is refused with a clear error (exit 2; a missing file: 1) **before
anything is written**; so is, strictly (round 21), a checkpoint without the format tag or of another one, whose model
misses a tensor of the network, has another or one of another shape, whose Adam moments are gone after step 0, whose
step is beyond ``--steps``, or with a corrupt field (``torch_rng``, ``elapsed_s``, ``runs``, ``threads``, ``mask``
outside [0, 1], a config value of another type), each named with the file; the checkpoint records ``--threads``
and a resume with another count warns (torch's CPU gradients depend on its thread count: not bit for bit) and
records it; so is a fresh run into a folder that already holds this system's and architecture's training
files, and a resume into such a folder unless its checkpoint is the one resumed (the same file, or the same bytes):
either would overwrite another training. On CUDA the convolutions and matrix products use TF32 and cuDNN's
autotuning (speed; resumes there are not bit for bit).

Bad options are usage errors (exit 2) naming the option before any work: ``--lr`` not in (0, 1], ``--lr-min`` not
in [0, ``--lr``], ``--clip``/``--minutes``/``--time-budget-s`` not finite and positive, ``--warmup`` not below
``--steps``, seeds outside 0 … 2⁶⁴ − 1, ``--threads``/``--workers`` beyond four per core (at most 1024),
``--workers`` with v1, ``--stop-at`` < 0, ``--device cpu:N``, an ``--out`` under a file; before tracing: a network
whose weights (``--bands``, ``--stages``, ``--width``) or a training step whose memory (``--batch`` × ``--size``²:
activations and cubes, :func:`step_memory_bytes`) exceeds the budget; the operators' own refusals (``--planes``,
``--rays``, ``--size``) are one line naming the options.

Stops. **Ctrl-C** (SIGINT) asks for a stop at the next step boundary: the step is validated and saved (checkpoint,
weights, manifest), the log gets a ``stop`` event of reason ``interrupted``, and the script exits 130 saying
"interrupted at step N: the state keeps step N; continue with --resume …"; a Ctrl-C during a save waits for the
save to end, another one outside a save stops at once (the last saved step is kept). **Divergence**: a step whose
loss, validation PSNRs or parameters are not finite is never saved — the script stops (exit 1) naming that step and
the last good step the folder keeps, and suggests a lower ``--lr``. At start a run removes its own staged
``<file>.tmp`` files (a run killed while saving) and a log line cut short, and rewrites the manifest to describe
what the folder's checkpoint holds (the runs so far). ``--summary`` keeps the last record of each step (a v2 resume
validates the step it resumes at again), names the line of a record that is not JSON, and skips a last line cut
short with a note on stderr.

Every random choice derives from the seeds and the step: ``--resume`` continues exactly as the uninterrupted run
(tested); ``--minutes``/``--time-budget-s`` only cap one invocation's wall time (the schedule depends on the step
alone).
"""
from __future__ import annotations

import argparse
import contextlib
import datetime
import filecmp
import json
import math
import os
import pathlib
import signal
import sys
import threading
import time

import numpy as np
import torch

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import diffcassi  # noqa: E402
import diffcassi.torch as dt  # noqa: E402
from diffcassi.deadleaves import BANDS_NM, dead_leaves, sources_manifest  # noqa: E402
from diffcassi.unrolled import (ARCH, ARCH_V2, ARCHS, activation_bytes, check_network_size,  # noqa: E402
                                count_parameters, load_unrolled, make_unrolled, mask_sha256, save_unrolled,
                                system_sha256)
from diffcassi._training import l1_step, lr_at, psnr_db, validation_records  # noqa: E402

#: Train seeds are TRAIN_SEED_BASE + batch·step + i; validation seeds 0 … VAL_COUNT−1 (of each kind).
TRAIN_SEED_BASE = 3_000_000
VAL_COUNT = 4
#: v2: train seeds TRAIN_SEED_BASE_V2 + batch·step + i of diffcassi.training_data.sample; validation 0 … VAL_COUNT_V2−1.
TRAIN_SEED_BASE_V2 = 5_000_000
VAL_COUNT_V2 = 8
#: The realistic setting of docs/study.md.
PLANES, RAYS = 112, 20
#: The checkpoint format tag (a checkpoint without it is refused).
CHECKPOINT_FORMAT = "diffcassi-unrolled-checkpoint-1"
#: Defaults of the settings that make a training (its config); None in argparse so that a resume can tell a
#: setting given on the command line from one to take from the checkpoint.
# Settings a --resume may change (given on its command line): the optimiser's, recorded in the run's "changed".
RESUME_MAY_CHANGE = ("lr", "lr_min", "clip")
DEFAULTS = {"size": 128, "steps": 400, "batch": 2, "seed": 0, "lr": 1e-3, "lr_min": 2e-5, "warmup": 20, "clip": 1.0,
            "planes": PLANES, "rays": RAYS, "acquisition_seed": 1000, "operator_seed": 1, "bands": 28}
ARCH_DEFAULTS = {ARCH: {"stages": 6, "width": 16}, ARCH_V2: {"stages": 3, "width": 24}}
#: The v2 default wall-time budget of one invocation (s): a ≤ 9-minute GPU call, the wheel's install included.
TIME_BUDGET_V2_S = 450.0


class CheckpointError(ValueError):
    """A checkpoint that cannot be resumed (names the file and the problem)."""


def seed_kind(seed: int) -> str:
    """Kind of the dead-leaves cube of a train seed: even offsets measured-spectra leaves, odd uplifted sRGB."""
    return "rgb" if (seed - TRAIN_SEED_BASE) % 2 else "spectral"


def train_seeds(step: int, batch: int, arch: str = ARCH) -> list:
    base = TRAIN_SEED_BASE_V2 if arch == ARCH_V2 else TRAIN_SEED_BASE
    return [base + batch * step + i for i in range(batch)]


def val_seeds(arch: str = ARCH) -> list:
    return list(range(VAL_COUNT_V2 if arch == ARCH_V2 else VAL_COUNT))


def names(system: str, arch: str = ARCH) -> dict:
    if arch == ARCH_V2:
        b = f"{ARCH_V2}-{system}"
        return {"weights": f"{b}.safetensors", "log": f"{b}-log.jsonl", "manifest": f"{b}-manifest.json",
                "state": f"{b}-checkpoint.pt"}
    return {"weights": f"unrolled-gap-v1-{system}.safetensors", "log": f"unrolled-{system}-log.jsonl",
            "manifest": f"unrolled-{system}-manifest.json", "state": f"unrolled-{system}-state.pt"}


def bands_nm_of(n: int) -> list:
    """The project's band grid 450–650 nm with ``n`` bands (28: the CLI's 450:650:28)."""
    return [float(b) for b in (BANDS_NM if n == 28 else np.linspace(450.0, 650.0, n))]


def load_mask(path, size: int) -> np.ndarray:
    """A mask file ((H, W) NPY, values in [0, 1]) centre-cropped to size × size as ``diffcassi study --mask`` does
    (offset ⌊(H − size)/2⌋, ⌊(W − size)/2⌋); float32."""
    m = np.load(path, allow_pickle=False)
    if m.ndim != 2 or min(m.shape) < size:
        raise diffcassi.DiffcassiValueError(f"{path}: mask of shape {m.shape}: expected (H, W) with H, W ≥ {size}")
    m = m.astype(np.float32)
    if not np.isfinite(m).all() or m.min() < 0 or m.max() > 1:
        raise diffcassi.DiffcassiValueError(f"{path}: mask values must be finite and in [0, 1]")
    r0, c0 = (m.shape[0] - size) // 2, (m.shape[1] - size) // 2
    return np.ascontiguousarray(m[r0:r0 + size, c0:c0 + size])


def step_memory_bytes(arch: str, bands: int, stages: int, width: int, size: int, batch: int) -> float:
    """Estimated memory (bytes) of one training step: the network's activations kept for backward
    (:func:`diffcassi.unrolled.activation_bytes`, 0.98–1.27× the measured peak) and the batch's data — each cube
    made (bands·size² floats), its transposed copy for the render and the stacked batch, and the acquisitions
    (≲ 2·size² each) — float32. ``--batch 1e9`` wrote the step-0 checkpoint, then died in a MemoryError (round 21)."""
    data = float(batch) * (3.0 * bands + 2.0) * float(size) ** 2 * 4.0
    return activation_bytes(arch, bands, width, stages, size, size, batch, grad=True) + data


def setting(mask, planes: int, rays: int, bands_nm) -> dict:
    """Keywords of diffcassi.Transport / diffcassi.exact for the realistic setting (Airy 2.5 px and stratified
    sampling: the CLI's defaults) — minus the seed."""
    return dict(mask=mask, bands_nm=[float(b) for b in bands_nm], planes=planes, rays=rays)


def build_operators(system: str, size: int, mask: np.ndarray, planes: int, rays: int, acq_seed: int, op_seed: int,
                    bands_nm=BANDS_NM):
    """(acquisition Transport, the matrix-free operator of another seed)."""
    sysm = diffcassi.System.preset(system)
    kw = setting(mask, planes, rays, bands_nm)
    acq = diffcassi.Transport(sysm, size, size, seed=acq_seed, **kw)
    op = diffcassi.exact(sysm, size, size, seed=op_seed, **kw)
    return acq, dt.CassiOperator.from_operator(op, matrix_free=True)


def render_batch(transport, seeds, size: int, bands_nm=BANDS_NM, kinds=None):
    """(acquisitions (N, h, w), cubes (N, bands, H, W)) float32 tensors of the dead-leaves cubes of ``seeds``."""
    cubes, acqs = [], []
    for j, s in enumerate(seeds):
        kind = kinds[j] if kinds is not None else seed_kind(s)
        c = dead_leaves(s, size, bands_nm, kind=kind)  # (B, H, W), peak 1
        acqs.append(transport.apply(np.ascontiguousarray(c.transpose(1, 2, 0))).astype(np.float32))
        cubes.append(c)
    return torch.from_numpy(np.stack(acqs)), torch.from_numpy(np.stack(cubes))


def make_cubes_v2(seeds, size: int, bands_nm) -> np.ndarray:
    """(N, bands, size, size) float32: :func:`diffcassi.training_data.sample` of each seed."""
    from diffcassi.training_data import sample
    return np.stack([sample(int(s), size, bands_nm)[0] for s in seeds])


def render_v2(transport, seeds, cubes: np.ndarray):
    """(acquisitions (N, h, w) with each sample's sensor noise, cubes) float32 tensors (CPU)."""
    from diffcassi.training_data import noisy
    acqs = [noisy(transport.apply(np.ascontiguousarray(c.transpose(1, 2, 0))), int(s))[0] for s, c in zip(seeds, cubes)]
    return torch.from_numpy(np.stack(acqs)), torch.from_numpy(np.ascontiguousarray(cubes))


class StepData(torch.utils.data.Dataset):
    """Item k: the v2 training batch of step ``first + k`` — (step, seeds, acquisitions with their sensor noise,
    cubes) — for a DataLoader with worker processes. Each worker traces its own copy of the acquisition transport
    (the same settings and seed: the same light transport bit for bit) on one thread; the cubes and the noise are
    pure functions of the seeds, so any worker makes the same batch as the main process would."""

    def __init__(self, first: int, last: int, batch: int, size: int, bands_nm, transport_args: dict):
        self.first, self.n, self.batch, self.size, self.bands_nm = first, max(0, last - first), batch, size, list(bands_nm)
        self.transport_args = transport_args
        self._transport = None

    def __len__(self) -> int:
        return self.n

    def __getitem__(self, k: int):
        if self._transport is None:  # once per worker process
            diffcassi.set_num_threads(1)
            t = dict(self.transport_args)
            self._transport = diffcassi.Transport(diffcassi.System.preset(t.pop("system")), self.size, self.size, **t)
        seeds = train_seeds(self.first + k, self.batch, ARCH_V2)
        acq, cube = render_v2(self._transport, seeds, make_cubes_v2(seeds, self.size, self.bands_nm))
        return self.first + k, seeds, acq, cube


def summary(log_path: pathlib.Path, every: int) -> int:
    """Prints the validation curve of a training log as a Markdown table."""
    try:
        vals = validation_records(log_path, "train_unrolled", every)
    except ValueError as e:
        print(e, file=sys.stderr)
        return 1
    keys = list(vals[0]["val_psnr_db"])
    print("| step | minutes | lr | train L1 | " + " | ".join(f"val {k} (dB)" for k in keys) + " | mean |")
    print("|---|---|---|---|" + "---|" * len(keys) + "---|")
    for r in vals:
        if r["step"] % every == 0 or r is vals[-1]:
            l1 = "–" if r["train_l1"] is None else f"{r['train_l1']:.4f}"
            cells = " | ".join(f"{r['val_psnr_db'].get(k, float('nan')):.2f}" for k in keys)
            print(f"| {r['step']} | {r['elapsed_s'] / 60:.1f} | {r['lr']:.2e} | {l1} | {cells} | {r['val_mean_db']:.2f} |")
    return 0


def read_checkpoint(path, arch=None, system=None, bands=None) -> dict:
    """A training checkpoint, checked before anything is built or written: a regular file that torch reads
    (``weights_only``: tensors, numbers, strings and lists only), the format tag, and — when given — the
    architecture, system and band count it was made for. Each failure a :class:`CheckpointError` naming the file
    and the problem (a missing file: FileNotFoundError)."""
    path = os.fspath(path)
    if not os.path.exists(path):
        raise FileNotFoundError(f"--resume {path}: no such file")
    if not os.path.isfile(path):
        raise CheckpointError(f"--resume {path}: not a regular file")
    try:
        ck = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as e:  # a truncated zip, a pickle of other objects, not a torch file at all
        raise CheckpointError(f"--resume {path}: not a readable checkpoint (truncated, or not written by "
                              f"train_unrolled.py): {type(e).__name__}: {str(e).splitlines()[0] if str(e) else ''}") from None
    if not isinstance(ck, dict) or "config" not in ck or "model" not in ck or "step" not in ck:
        raise CheckpointError(f"--resume {path}: not a train_unrolled.py checkpoint (no config, model or step)")
    cfg = ck["config"]
    if isinstance(cfg, str):
        try:
            cfg = json.loads(cfg)
        except json.JSONDecodeError as e:
            raise CheckpointError(f"--resume {path}: its config is not JSON ({e})") from None
    if not isinstance(cfg, dict):
        raise CheckpointError(f"--resume {path}: its config is not a mapping")
    ck["config"] = cfg
    have = cfg.get("arch", ARCH)
    if have not in ARCHS:
        raise CheckpointError(f"--resume {path}: checkpoint of unknown architecture {have!r}")
    if arch is not None and have != arch:
        raise CheckpointError(f"--resume {path}: checkpoint of architecture {have!r}, not --arch {arch!r}")
    if system is not None and cfg.get("system") != system:
        raise CheckpointError(f"--resume {path}: checkpoint trained for system {cfg.get('system')!r}, not --system {system!r}")
    if bands is not None and cfg.get("bands", 28) != bands:
        raise CheckpointError(f"--resume {path}: checkpoint for {cfg.get('bands', 28)} bands, not --bands {bands}")
    if not isinstance(ck["step"], int) or ck["step"] < 0:
        raise CheckpointError(f"--resume {path}: step {ck['step']!r} is not an integer ≥ 0")
    if "val_every" in ck and not (isinstance(ck["val_every"], int) and ck["val_every"] >= 1):
        raise CheckpointError(f"--resume {path}: val_every {ck['val_every']!r} is not an integer ≥ 1")
    # The format tag: a checkpoint without it, or of another (a future) format, is refused (its fields may mean
    # other things; round 21: both were resumed, exit 0).
    if ck.get("format") != CHECKPOINT_FORMAT:
        raise CheckpointError(f"--resume {path}: format {ck.get('format')!r}: expected {CHECKPOINT_FORMAT!r} (a "
                              "checkpoint written by another version of train_unrolled.py, or edited)")
    if not isinstance(ck["model"], dict) or not ck["model"]:
        raise CheckpointError(f"--resume {path}: field model is empty (no tensors of the network)")
    for k, v in ck["model"].items():
        if not isinstance(v, torch.Tensor) or not torch.isfinite(v).all():
            raise CheckpointError(f"--resume {path}: model tensor {k} is missing or not finite")
    _check_fields(path, ck, cfg)
    return ck


#: The config's integer settings and its number settings (a checkpoint's config is checked field by field: a
#: "16" for size ended in a TypeError traceback, round 21).
_INT_SETTINGS = ("size", "stages", "width", "steps", "batch", "seed", "warmup", "planes", "rays", "acquisition_seed",
                 "operator_seed", "bands")
_NUM_SETTINGS = ("lr", "lr_min", "clip")


def _check_fields(path, ck: dict, cfg: dict) -> None:
    """The checkpoint's other fields, each of its type and range, so that a corrupt value is refused naming the
    field and the value rather than ending in a traceback after the set-up (round 21): the config's settings,
    ``elapsed_s``, ``runs`` (a JSON list), ``torch_rng`` (torch's CPU generator state: a uint8 tensor of that
    size), ``mask`` (a finite (H, W) tensor in [0, 1]), ``threads``, ``optim``."""
    def bad(field, why):
        return CheckpointError(f"--resume {path}: field {field} = {_short(ck.get(field) if '.' not in field else cfg.get(field.split('.', 1)[1]))}: {why}")
    for k in _INT_SETTINGS:
        if k in cfg and (isinstance(cfg[k], bool) or not isinstance(cfg[k], int) or cfg[k] < 0):
            raise bad(f"config.{k}", "expected an integer ≥ 0")
    for k in _NUM_SETTINGS:
        if k in cfg and (isinstance(cfg[k], bool) or not isinstance(cfg[k], (int, float)) or not math.isfinite(cfg[k])):
            raise bad(f"config.{k}", "expected a finite number")
    if "system" in cfg and not isinstance(cfg["system"], str):
        raise bad("config.system", "expected a preset name")
    el = ck.get("elapsed_s", 0.0)
    if isinstance(el, bool) or not isinstance(el, (int, float)) or not (math.isfinite(el) and el >= 0):
        raise bad("elapsed_s", "expected a finite number of seconds ≥ 0")
    if "runs" in ck:
        try:
            runs = json.loads(ck["runs"]) if isinstance(ck["runs"], str) else None
        except json.JSONDecodeError as e:
            raise bad("runs", f"not JSON ({e})") from None
        if not isinstance(runs, list) or not all(isinstance(r, dict) for r in runs):
            raise bad("runs", "expected a JSON list of the runs so far")
    if "torch_rng" in ck:
        want = torch.get_rng_state()
        r = ck["torch_rng"]
        if not isinstance(r, torch.Tensor) or r.dtype != want.dtype or r.shape != want.shape:
            raise bad("torch_rng", f"expected torch's CPU generator state, a {want.dtype} tensor of shape "
                                   f"{tuple(want.shape)}")
    if "mask" in ck:
        m = ck["mask"]
        if not isinstance(m, torch.Tensor) or m.dim() != 2 or not m.dtype.is_floating_point:
            raise bad("mask", "expected an (H, W) floating-point tensor")
        if not bool((torch.isfinite(m) & (m >= 0) & (m <= 1)).all()):
            i = int((~(torch.isfinite(m) & (m >= 0) & (m <= 1))).flatten().nonzero()[0])
            raise CheckpointError(f"--resume {path}: field mask: value {float(m.flatten()[i])} at index "
                                  f"{divmod(i, m.shape[1])} is not in [0, 1]")
    if "threads" in ck and (isinstance(ck["threads"], bool) or not isinstance(ck["threads"], int) or ck["threads"] < 1):
        raise bad("threads", "expected an integer ≥ 1")
    o = ck.get("optim")
    if not isinstance(o, dict) or not isinstance(o.get("state"), dict) or not isinstance(o.get("param_groups"), list):
        raise CheckpointError(f"--resume {path}: field optim: not an optimiser state (state, param_groups)")


def _short(v) -> str:
    r = repr(v)
    return r if len(r) <= 80 else r[:77] + "…"


def check_resume_fit(path, ck: dict, net, opt_state_needed: bool) -> None:
    """The checkpoint's model and optimiser against the network built for it, strictly: every tensor of the
    network present (``missing``), none other (``unexpected``), each of the network's shape; and from step 1 on the
    optimiser state of every parameter (Adam's moments: a checkpoint without them resumed with fresh moments, and a
    partial model kept the missing tensors' fresh initialisation, exit 0 — round 21)."""
    want = {k: v for k, v in net.state_dict().items() if not k.startswith("phi.")}
    have = ck["model"]
    missing = sorted(set(want) - set(have))
    unexpected = sorted(set(have) - set(want))
    shapes = [f"{k} {tuple(have[k].shape)} (the network's {tuple(want[k].shape)})" for k in sorted(set(want) & set(have))
              if tuple(have[k].shape) != tuple(want[k].shape)]
    probs = []
    if missing:
        probs.append(f"{len(missing)} missing tensor(s) {', '.join(missing[:4])}{' …' if len(missing) > 4 else ''}")
    if unexpected:
        probs.append(f"{len(unexpected)} unexpected tensor(s) {', '.join(unexpected[:4])}{' …' if len(unexpected) > 4 else ''}")
    if shapes:
        probs.append("other shapes: " + "; ".join(shapes[:4]))
    if probs:
        raise CheckpointError(f"--resume {path}: field model does not fit this network: " + "; ".join(probs))
    st, groups = ck["optim"]["state"], ck["optim"]["param_groups"]
    n = sum(1 for _ in net.parameters())
    ids = [i for g in groups if isinstance(g, dict) for i in g.get("params", [])]
    if len(ids) != n:
        raise CheckpointError(f"--resume {path}: field optim: {len(ids)} parameters in its groups, the network has {n}")
    if opt_state_needed:
        params = list(net.parameters())
        for j, i in enumerate(ids):
            s = st.get(i)
            if not isinstance(s, dict) or not all(isinstance(s.get(k), torch.Tensor) for k in ("step", "exp_avg", "exp_avg_sq")):
                raise CheckpointError(f"--resume {path}: field optim: no Adam state (step, exp_avg, exp_avg_sq) of "
                                      f"parameter {i} at step {ck['step']} > 0 (its moments were dropped)")
            if tuple(s["exp_avg"].shape) != tuple(params[j].shape) or tuple(s["exp_avg_sq"].shape) != tuple(params[j].shape):
                raise CheckpointError(f"--resume {path}: field optim: the Adam moments of parameter {i} have shape "
                                      f"{tuple(s['exp_avg'].shape)}, the parameter {tuple(params[j].shape)}")


def utc_now() -> str:
    return datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ")


#: Seeds (--seed, --acquisition-seed, --operator-seed) are unsigned 64-bit integers.
SEED_LIMIT = 2 ** 64
#: The most --threads and --workers: four per core, at most 1024 (the library's set_num_threads limit).
PROCESS_LIMIT = min(1024, 4 * (os.cpu_count() or 1))


def _seed_arg(text: str) -> int:
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer in 0 … 2**64 − 1, got {text!r}") from None
    if not 0 <= v < SEED_LIMIT:
        raise argparse.ArgumentTypeError(f"{v} is out of range: a seed is an integer in 0 … 2**64 − 1")
    return v


def _count_arg(text: str) -> int:
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
    if v > PROCESS_LIMIT:
        raise argparse.ArgumentTypeError(f"{v} is more than this machine takes (at most {PROCESS_LIMIT}: four per core, "
                                         "at most 1024)")
    return v


def _finite_arg(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not math.isfinite(v):
        raise argparse.ArgumentTypeError(f"expected a finite number, got {text!r}")
    return v


def _same_file(a, b) -> bool:
    """Whether two paths are one file, or two files of identical bytes."""
    try:
        if os.path.samefile(a, b):
            return True
        return os.path.getsize(a) == os.path.getsize(b) and filecmp.cmp(a, b, shallow=False)
    except OSError:
        return False


class Diverged(Exception):
    """The training left the finite numbers at ``step`` (``what`` says how); nothing of that step was saved."""

    def __init__(self, step: int, what: str):
        super().__init__(f"at step {step}: {what}")
        self.step, self.what = step, what


class StopRequest:
    """SIGINT (Ctrl-C) during a training: the first one asks the loop to stop at the next step boundary (validate,
    save, exit 130); another one stops at once — unless it arrives while the checkpoint, the weights and the
    manifest are being written, when it waits for the save to be complete (they always describe one step)."""

    def __init__(self):
        self.requested = False
        self._saving = False
        self._deferred = False
        self._old = None

    def install(self) -> None:
        if threading.current_thread() is threading.main_thread():
            self._old = signal.signal(signal.SIGINT, self._handler)

    def restore(self) -> None:
        if self._old is not None:
            signal.signal(signal.SIGINT, self._old)
            self._old = None

    def _handler(self, signum, frame) -> None:
        if not self.requested:
            self.requested = True
            os.write(2, b"train_unrolled: Ctrl-C: stopping at the next step boundary (validate, save the state); "
                        b"Ctrl-C again to stop at once\n")
        elif self._saving:
            self._deferred = True
        else:
            raise KeyboardInterrupt

    @contextlib.contextmanager
    def saving(self):
        self._saving = True
        try:
            yield
        finally:
            self._saving = False
        if self._deferred:
            self._deferred = False
            raise KeyboardInterrupt


def _ignore_sigint(_worker_id: int) -> None:
    """DataLoader workers leave Ctrl-C to the main process (which stops at a step boundary)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)


def main(argv=None) -> int:
    try:
        return _main(argv)
    except KeyboardInterrupt:  # a Ctrl-C before any output was written
        print("train_unrolled: interrupted before the training started; nothing written", file=sys.stderr)
        return 130


def _main(argv=None) -> int:
    t_start = time.time()
    start_utc = utc_now()
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--system", default=None, help="preset: sp, msp, ap, map (required unless --resume names it)")
    ap.add_argument("--arch", default=None, choices=sorted(ARCHS), help=f"network (default {ARCH}, or the checkpoint's)")
    ap.add_argument("--out", required=True, help="output folder")
    ap.add_argument("--mask", default=None, help="mask file ((H, W) NPY), centre-cropped to --size (default: the "
                    "checkpoint's on --resume, else random, seed 0)")
    ap.add_argument("--size", type=int, default=None, help="scene side (pixels; default 128)")
    ap.add_argument("--bands", type=int, default=None, help="bands 450–650 nm (default 28)")
    ap.add_argument("--stages", type=int, default=None, help="stages (default 6 for v1, 3 for v2)")
    ap.add_argument("--width", type=int, default=None, help="network width C (default 16 for v1, 24 for v2)")
    ap.add_argument("--steps", type=int, default=None, help="total optimiser steps; the learning-rate schedule spans them (default 400)")
    ap.add_argument("--minutes", type=_finite_arg, default=None, help="wall-time cap of this invocation (stops early, state saved)")
    ap.add_argument("--time-budget-s", type=_finite_arg, default=None, help="wall-time budget of this invocation, set-up and "
                    f"final save included: stop in time, save, exit 0 (v2 default {TIME_BUDGET_V2_S:g})")
    ap.add_argument("--stop-at", type=int, default=None, help="stop this invocation at this step (state saved; the "
                    "schedule still spans --steps)")
    ap.add_argument("--batch", type=int, default=None, help="cubes per step (default 2)")
    ap.add_argument("--threads", type=_count_arg, default=1, help=f"torch and Rust threads (1 … {PROCESS_LIMIT})")
    ap.add_argument("--workers", type=_count_arg, default=0, help="v2: processes making the training cubes (0: in this one)")
    ap.add_argument("--device", default="cpu", help="cpu or cuda[:N]: where the network and its operator run")
    ap.add_argument("--seed", type=_seed_arg, default=None, help="torch seed of the initial weights (default 0)")
    ap.add_argument("--lr", type=_finite_arg, default=None, help="peak learning rate, in (0, 1] (default 1e-3)")
    ap.add_argument("--lr-min", type=_finite_arg, default=None, help="learning rate at the end of the cosine decay, in [0, --lr]")
    ap.add_argument("--warmup", type=int, default=None, help="linear warm-up steps, fewer than --steps (default 20)")
    ap.add_argument("--clip", type=_finite_arg, default=None, help="gradient-norm clipping (default 1)")
    ap.add_argument("--val-every", type=int, default=None, help="validate (and save the state and the weights) every N "
                    "steps (default 25, or the checkpoint's)")
    ap.add_argument("--planes", type=int, default=None)
    ap.add_argument("--rays", type=int, default=None)
    ap.add_argument("--acquisition-seed", type=_seed_arg, default=None, help="Monte-Carlo seed of the training renders (default 1000)")
    ap.add_argument("--operator-seed", type=_seed_arg, default=None, help="Monte-Carlo seed of the operator (default 1: "
                    "reconstruct's default for acquisitions of seed 0)")
    ap.add_argument("--resume", default=None, help="a checkpoint (…-state.pt, …-checkpoint.pt) to continue from")
    ap.add_argument("--summary", type=int, metavar="EVERY", default=None,
                    help="print the validation curve of --out's log as a Markdown table, and exit")
    a = ap.parse_args(argv)
    prog = "train_unrolled"
    if a.system is not None and a.system not in ("sp", "msp", "ap", "map"):
        ap.error(f"--system {a.system!r}: expected one of sp, msp, ap, map")
    out = pathlib.Path(a.out)
    if a.summary is not None:
        if a.system is None:
            ap.error("--summary needs --system")
        return summary(out / names(a.system, a.arch or ARCH)["log"], a.summary)
    # --out: a folder, or to be made in one (a file on its path failed after the set-up, NotADirectoryError).
    for p in [out, *out.parents]:
        if p.exists() or p.is_symlink():
            if not p.is_dir():
                print(f"{prog}: error: --out {out} " + ("exists and is not a folder" if p == out else
                      f"cannot be made: {p} is not a folder") + "; nothing written", file=sys.stderr)
                return 2
            break
    if a.stop_at is not None and a.stop_at < 0:
        ap.error(f"--stop-at must be ≥ 0 (got {a.stop_at})")

    # The checkpoint first (cheap, writes nothing): its architecture, system and band count, then its settings.
    ck = None
    if a.resume:
        try:
            ck = read_checkpoint(a.resume, a.arch, a.system, a.bands)
        except FileNotFoundError as e:
            print(f"{prog}: error: {e}", file=sys.stderr)
            return 1
        except CheckpointError as e:
            print(f"{prog}: error: {e}; nothing written", file=sys.stderr)
            return 2
    base = dict(ck["config"]) if ck else {}
    arch = a.arch or base.get("arch", ARCH)
    system = a.system or base.get("system")
    if system is None:
        ap.error("--system is required (or --resume a checkpoint that names it)")
    given = {k: getattr(a, k) for k in list(DEFAULTS) + ["stages", "width"] if getattr(a, k) is not None}
    conf = dict(DEFAULTS, **ARCH_DEFAULTS[arch])
    conf.update({k: v for k, v in base.items() if k in conf})
    conf.update(given)
    # --val-every is no setting of the training (its schedule and data do not depend on it): not compared on
    # resume, but kept in the checkpoint and taken from there when not given.
    val_every = a.val_every if a.val_every is not None else (ck.get("val_every", 25) if ck else 25)
    for name in ("size", "stages", "width", "steps", "batch", "planes", "rays", "bands"):
        if conf[name] < 1:
            ap.error(f"--{name.replace('_', '-')} must be at least 1 (got {conf[name]})")
    if conf["warmup"] < 0:
        ap.error(f"--warmup must be ≥ 0 (got {conf['warmup']})")
    if conf["warmup"] >= conf["steps"]:
        ap.error(f"--warmup {conf['warmup']} must be less than --steps {conf['steps']} (the learning rate would not "
                 "reach --lr before the schedule ends)")
    if a.threads < 1:
        ap.error(f"--threads must be at least 1 (got {a.threads})")
    if val_every < 1:
        ap.error(f"--val-every must be at least 1 (got {val_every})")
    if a.workers < 0:
        ap.error(f"--workers must be ≥ 0 (got {a.workers})")
    if a.workers > 0 and arch != ARCH_V2:
        ap.error(f"--workers {a.workers}: only {ARCH_V2} makes its batches in worker processes (this is {arch}); "
                 "leave --workers out")
    if conf["size"] < 8:
        ap.error(f"--size must be at least 8 (got {conf['size']})")
    for name in ("lr", "lr_min", "clip"):
        if not math.isfinite(conf[name]):
            ap.error(f"--{name.replace('_', '-')} must be a finite number (got {conf[name]})")
    if not 0 < conf["lr"] <= 1:
        ap.error(f"--lr must be in (0, 1] (got {conf['lr']:g})")
    if not 0 <= conf["lr_min"] <= conf["lr"]:
        ap.error(f"--lr-min must be in [0, --lr {conf['lr']:g}] (got {conf['lr_min']:g})")
    if not conf["clip"] > 0:
        ap.error(f"--clip must be positive (got {conf['clip']:g})")
    for name in ("minutes", "time_budget_s"):
        if getattr(a, name) is not None and not getattr(a, name) > 0:
            ap.error(f"--{name.replace('_', '-')} must be positive (got {getattr(a, name):g})")
    for name in ("seed", "acquisition_seed", "operator_seed"):
        if not (isinstance(conf[name], int) and 0 <= conf[name] < SEED_LIMIT):
            ap.error(f"--{name.replace('_', '-')} must be an integer in 0 … 2**64 − 1 (got {conf[name]!r})")
    if conf["acquisition_seed"] == conf["operator_seed"]:
        ap.error("--acquisition-seed and --operator-seed must differ (the realistic setting: no oracle)")
    budget = a.time_budget_s if a.time_budget_s is not None else (TIME_BUDGET_V2_S if arch == ARCH_V2 else None)
    try:
        device = torch.device(a.device)
    except RuntimeError:
        print(f"{prog}: error: --device {a.device!r}: expected cpu or cuda[:N]; nothing written", file=sys.stderr)
        return 2
    if device.type not in ("cpu", "cuda") or (device.type == "cuda" and not torch.cuda.is_available()) \
            or (device.type == "cpu" and device.index not in (None, 0)):
        why = ("no CUDA device here" if device.type == "cuda" else
               "the CPU has no device index: give cpu" if device.type == "cpu" else "expected cpu or cuda[:N]")
        print(f"{prog}: error: --device {a.device}: {why}; nothing written", file=sys.stderr)
        return 2

    if ck is not None and ck["step"] > conf["steps"]:
        print(f"{prog}: error: --resume {a.resume}: field step = {ck['step']} is beyond --steps {conf['steps']} (the "
              "schedule's end; a checkpoint of another training, or edited); nothing written", file=sys.stderr)
        return 2
    # Checks that need no trace, before the operators are traced (round 21: --bands 100000 and --stages 100000 were
    # refused only after both operators were traced): the network's weights and one training step's memory against
    # the budget (diffcassi.set_limits).
    try:
        check_network_size(arch, conf["bands"], conf["stages"], conf["width"])
    except diffcassi.DiffcassiValueError as e:
        print(f"{prog}: error: --bands {conf['bands']}, --stages {conf['stages']}, --width {conf['width']}: {e}; "
              "nothing written", file=sys.stderr)
        return 2
    need = step_memory_bytes(arch, conf["bands"], conf["stages"], conf["width"], conf["size"], conf["batch"])
    limit = float(diffcassi.get_limits()["max_memory_gb"]) * 1e9
    if need > limit:
        print(f"{prog}: error: --batch {conf['batch']} at --size {conf['size']} (× {conf['bands']} bands, --stages "
              f"{conf['stages']}, --width {conf['width']}): a training step needs an estimated {need / 1e9:.3g} GB "
              f"(the network's activations and the batch's cubes), over the memory budget of {limit / 1e9:.3g} GB "
              f"({diffcassi.get_limits().get('memory_source', '')}); use a smaller --batch or --size; nothing written",
              file=sys.stderr)
        return 2
    threads_changed = None
    if ck is not None:
        # torch's CPU convolutions (their backward above all) sum in an order that depends on its intra-op thread
        # count, so the parameters' gradients — and the whole training from here on — differ in their last bits
        # with another --threads (diffcassi's own part does not: its sums are thread-invariant). Such a resume is
        # allowed (the numbers are as valid; a longer run may want more threads) but is loud, and recorded in
        # the run's "changed". Not at step 0 (no gradient yet) and not on CUDA (TF32, not bit for bit anyway).
        before = ck.get("threads")
        if before is None:  # a checkpoint of before round 21: the threads of its last run
            prev = json.loads(ck["runs"]) if isinstance(ck.get("runs"), str) else []
            before = prev[-1].get("threads") if prev and isinstance(prev[-1].get("threads"), int) else None
        last_dev = ""
        if isinstance(ck.get("runs"), str):
            prev = json.loads(ck["runs"])
            last_dev = str(prev[-1].get("device", "")) if prev else ""
        if before is not None and before != a.threads and ck["step"] > 0 and device.type == "cpu" \
                and not last_dev.startswith("cuda"):
            threads_changed = [before, a.threads]
            print(f"{prog}: WARNING: --resume {a.resume} was trained with --threads {before}, this run uses --threads "
                  f"{a.threads}: torch's CPU gradients depend on its thread count, so the training continues with "
                  "other rounding than the uninterrupted run (not bit for bit; recorded in the manifest's runs under "
                  f"\"changed\"); resume with --threads {before} to continue it exactly", file=sys.stderr)

    size, bands_nm = conf["size"], bands_nm_of(conf["bands"])
    config = {"system": system, "size": size, "stages": conf["stages"], "width": conf["width"], "steps": conf["steps"],
              "batch": conf["batch"], "seed": conf["seed"], "lr": conf["lr"], "lr_min": conf["lr_min"],
              "warmup": conf["warmup"], "clip": conf["clip"], "planes": conf["planes"], "rays": conf["rays"],
              "acquisition_seed": conf["acquisition_seed"], "operator_seed": conf["operator_seed"]}
    if arch == ARCH_V2 or conf["bands"] != 28:
        config["bands"] = conf["bands"]
    if arch == ARCH_V2:
        config = dict({"arch": arch}, **config, system_sha256=system_sha256(diffcassi.System.preset(system)))
    changed = {}  # the optimiser's settings a resume changes: {name: [checkpoint's, this run's]}
    if ck is not None:  # every setting but the mask's hash (that of the library's default mask needs the trace)
        saved = ck["config"]
        # The optimiser's settings (--lr, --lr-min, --clip) may change on a resume when given: they shape the
        # steps from here on, not the data, the network or the schedule's length; the run records the change.
        changed = {k: [saved[k], config[k]] for k in RESUME_MAY_CHANGE if k in saved and saved[k] != config[k]}
        saved = dict(saved, **{k: config[k] for k in changed})
        diff = {k: (saved.get(k), config.get(k)) for k in sorted(set(saved) | set(config))
                if k != "mask_sha256" and saved.get(k) != config.get(k)}
        if diff:
            print(f"{prog}: error: --resume {a.resume} was made with other settings (saved, asked): {diff}; nothing "
                  "written", file=sys.stderr)
            return 2
    try:  # no --mask: the checkpoint's, else the library's random mask (opening 0.5, seed 0), render's default
        if a.mask:
            mask = load_mask(a.mask, size)
        elif ck is not None and isinstance(ck.get("mask"), torch.Tensor):
            mask = np.ascontiguousarray(ck["mask"].numpy(), dtype=np.float32)
        else:
            mask = None
    except (OSError, ValueError, EOFError) as e:  # EOFError: an empty file (/dev/null), round 21
        print(f"{prog}: error: --mask {a.mask}: {type(e).__name__ if isinstance(e, EOFError) else ''}"
              f"{': ' if isinstance(e, EOFError) else ''}{e or 'empty file'}; nothing written", file=sys.stderr)
        return 1
    if mask is not None and mask.shape != (size, size):
        print(f"{prog}: error: the mask is {mask.shape[0]}×{mask.shape[1]}, the scene {size}×{size}; nothing written",
              file=sys.stderr)
        return 2
    if ck is not None and mask is not None and base.get("mask_sha256") not in (None, mask_sha256(mask)) and a.mask:
        print(f"{prog}: error: --resume {a.resume} was trained with another mask (SHA-256 {base.get('mask_sha256')}, "
              f"--mask {a.mask}: {mask_sha256(mask)}); nothing written", file=sys.stderr)
        return 2

    # A run into a folder that holds another training's files would replace its weights and checkpoint and append
    # to its log: refused, for every architecture — a fresh run (round 4), and a resume unless the folder's
    # checkpoint is the one resumed (the same file, or the same bytes) (round 9: a resume replaced another training).
    run_files = names(system, arch)
    existing = out / run_files["state"]
    held = [n for n in run_files.values() if (out / n).exists()]
    if held:
        what = f"the checkpoint {existing.name}" if existing.exists() else "the files " + ", ".join(held)
        if ck is None:
            print(f"{prog}: error: --out {out} already holds {what} of another training: --resume "
                  f"{existing}, or choose another folder; nothing written", file=sys.stderr)
            return 2
        if not (existing.is_file() and _same_file(a.resume, existing)):
            print(f"{prog}: error: --out {out} already holds {what} of another training, not the checkpoint "
                  f"--resume {a.resume}: resume in the folder of that checkpoint, or into a folder without "
                  f"{system}'s {arch} files; nothing written", file=sys.stderr)
            return 2

    torch.set_num_threads(a.threads)
    diffcassi.set_num_threads(a.threads)
    torch.manual_seed(conf["seed"])
    t_setup = time.time()
    try:  # the library's refusals (planes, rays, memory) name their values: one line, not a traceback (round 21)
        transport, phi = build_operators(system, size, mask, conf["planes"], conf["rays"], conf["acquisition_seed"],
                                         conf["operator_seed"], bands_nm)
    except diffcassi.DiffcassiValueError as e:
        print(f"{prog}: error: the operators of --size {size}, --planes {conf['planes']}, --rays {conf['rays']}, "
              f"--bands {conf['bands']}: {e}; nothing written", file=sys.stderr)
        return 2
    mask = transport.mask
    config["mask_sha256"] = mask_sha256(mask)
    if ck is not None and dict(ck["config"], **{k: config[k] for k in changed}) != config:
        saved = ck["config"]
        diff = {k: (saved.get(k), config.get(k)) for k in sorted(set(saved) | set(config)) if saved.get(k) != config.get(k)}
        print(f"{prog}: error: --resume {a.resume} was made with other settings (saved, asked): {diff}; nothing written",
              file=sys.stderr)
        return 2
    if device.type == "cuda":  # TF32 convolutions and matrix products, autotuned: speed over bit-exact resumes there
        torch.backends.cudnn.benchmark = True
        torch.backends.cudnn.allow_tf32 = True
        torch.backends.cuda.matmul.allow_tf32 = True
        phi = phi.to(device)
    setup_s = time.time() - t_setup
    try:
        net = make_unrolled(arch, phi, conf["stages"], conf["width"])
    except diffcassi.DiffcassiValueError as e:
        print(f"{prog}: error: --stages {conf['stages']}, --width {conf['width']}: {e}; nothing written", file=sys.stderr)
        return 2
    opt = torch.optim.Adam(net.parameters(), lr=conf["lr"])
    step, elapsed0, runs = 0, 0.0, []
    if ck is not None:
        try:
            # Strict: every tensor of the network, none other, each of its shape; the optimiser's moments from
            # step 1 on (check_resume_fit names what is wrong; strict=False kept a partial model's fresh tensors).
            check_resume_fit(a.resume, ck, net, opt_state_needed=ck["step"] > 0)
            net.load_state_dict(ck["model"], strict=True)
            opt.load_state_dict(ck["optim"])
        except CheckpointError as e:
            print(f"{prog}: error: {e}; nothing written", file=sys.stderr)
            return 2
        except (RuntimeError, KeyError, ValueError) as e:
            print(f"{prog}: error: --resume {a.resume}: its model or optimiser does not fit this network ({e}); "
                  "nothing written", file=sys.stderr)
            return 2
        step, elapsed0 = ck["step"], float(ck.get("elapsed_s", 0.0))
        runs = json.loads(ck["runs"]) if isinstance(ck.get("runs"), str) else []
        if isinstance(ck.get("torch_rng"), torch.Tensor):
            torch.set_rng_state(ck["torch_rng"])
    step0 = step

    # Outputs from here on. A Ctrl-C now stops at a step boundary with the state saved (StopRequest).
    stop = StopRequest()
    stop.install()
    try:
        return _train(a, prog, t_start, start_utc, out, arch, system, conf, config, size, bands_nm, mask, transport,
                      phi, net, opt, device, budget, val_every, setup_s, ck, step0, elapsed0, runs, stop, threads_changed)
    finally:
        stop.restore()


def _train(a, prog, t_start, start_utc, out, arch, system, conf, config, size, bands_nm, mask, transport, phi, net, opt,
           device, budget, val_every, setup_s, ck, step0, elapsed0, runs, stop, threads_changed=None) -> int:
    """The training loop and its outputs (``_main`` has checked everything and written nothing)."""
    nm = names(system, arch)
    out.mkdir(parents=True, exist_ok=True)
    for n in nm.values():  # the staged files of a run killed while saving
        stale = out / f"{n}.tmp"
        if stale.is_file() and not stale.is_symlink():
            stale.unlink()
    wpath, lpath, spath, mpath = out / nm["weights"], out / nm["log"], out / nm["state"], out / nm["manifest"]
    _trim_cut_line(lpath, prog)
    with open(lpath, "a") as log:
        return _loop(a, prog, t_start, start_utc, out, arch, system, conf, config, size, bands_nm, mask, transport, phi,
                     net, opt, device, budget, val_every, setup_s, ck, step0, elapsed0, runs, stop, log,
                     wpath, spath, mpath, threads_changed)


def _loop(a, prog, t_start, start_utc, out, arch, system, conf, config, size, bands_nm, mask, transport, phi, net, opt,
          device, budget, val_every, setup_s, ck, step0, elapsed0, runs, stop, log, wpath, spath, mpath,
          threads_changed=None) -> int:
    step = step0
    run = {"start_utc": start_utc, "end_utc": None, "device": str(device),
           "device_name": torch.cuda.get_device_name(device) if device.type == "cuda" else "cpu",
           "threads": a.threads, "workers": a.workers, "steps_from": step0, "steps_to": step0,
           "resumed_from": os.path.basename(a.resume) if a.resume else None, "time_budget_s": budget,
           "torch": torch.__version__, "diffcassi": getattr(diffcassi, "__version__", None),
           "tf32": device.type == "cuda"}
    if ck is not None:  # the optimiser's settings this resume changed (RESUME_MAY_CHANGE): {name: [before, now]}
        saved = ck["config"]
        run["changed"] = {k: [saved[k], config[k]] for k in RESUME_MAY_CHANGE if k in saved and saved[k] != config[k]}
        if threads_changed is not None:
            run["changed"]["threads"] = threads_changed
    last_saved = None  # the step of the state, weights and manifest this run saved last (None: none yet)
    losses: list = []
    timing = {"val_s": 0.0, "save_s": 0.0}
    t0 = time.time()

    def log_line(rec: dict) -> None:  # never a NaN or an infinity: the log stays JSON
        log.write(json.dumps(rec, allow_nan=False) + "\n")
        log.flush()

    def write_manifest(made_by: list, at_step: int) -> None:
        if arch == ARCH_V2:
            from diffcassi.training_data import manifest as data_manifest
            man = data_manifest(bands_nm)
            man.update({"train_seeds": f"{TRAIN_SEED_BASE_V2} + batch*step + i (diffcassi.training_data.sample; noise: "
                                       "diffcassi.training_data.noisy of the same seed)",
                        "train_seed_min": TRAIN_SEED_BASE_V2, "val_seeds": val_seeds(arch)})
        else:
            man = sources_manifest(bands_nm)
            man.update({"train_seeds": f"{TRAIN_SEED_BASE} + batch*step + i; i even spectral, odd rgb",
                        "train_seed_min": TRAIN_SEED_BASE, "val_seeds": val_seeds(arch), "val_kinds": ["spectral", "rgb"]})
        man.update({"evaluation_scenes_used": [], "arch": arch, "config": config, "operator": repr(phi.op),
                    "acquisition_transport": repr(transport), "parameters": count_parameters(net)})
        if arch == ARCH_V2:
            man["runs"] = made_by
            man["steps"] = at_step
        tmp = f"{mpath}.tmp"
        pathlib.Path(tmp).write_text(json.dumps(man, indent=1, allow_nan=False) + "\n")
        os.replace(tmp, mpath)

    def finite_parameters() -> bool:
        return all(bool(torch.isfinite(p).all()) for p in net.parameters())

    def forward(y):
        try:
            return net(y)
        except diffcassi.DiffcassiValueError as e:  # the operator refuses a non-finite estimate
            if finite_parameters():
                raise
            raise Diverged(step, f"the network's parameters are not finite ({e})") from None

    @torch.no_grad()
    def validate() -> dict:
        tv = time.time()
        net.eval()
        chunk = 2 if device.type == "cpu" else 8
        p = psnr_db(torch.cat([forward(val_acq[i:i + chunk]) for i in range(0, len(val_acq), chunk)]), val_cube)
        net.train()
        timing["val_s"] = time.time() - tv
        return {k: float(p[idx].mean()) for k, idx in val_groups.items() if idx}

    def checkpoint():
        """Validate, then save the state, the weights and the manifest of this step (in that order, each whole;
        a Ctrl-C meanwhile waits) and log the validation. A non-finite validation or parameter saves nothing."""
        nonlocal last_saved
        val = validate()
        bad = sorted(k for k, v in val.items() if not math.isfinite(v))
        if bad:
            raise Diverged(step, "validation PSNR " + ", ".join(f"{k} {val[k]}" for k in bad))
        if not finite_parameters():
            raise Diverged(step, "the network's parameters are not finite")
        ts = time.time()
        elapsed = elapsed0 + time.time() - t0
        rec = {"step": step, "elapsed_s": round(elapsed, 1), "lr": opt.param_groups[0]["lr"],
               "train_l1": (sum(losses) / len(losses)) if losses else None, "val_psnr_db": val,
               "val_mean_db": float(np.mean(list(val.values())))}
        if arch == ARCH:
            rec["steps_lambda"] = [round(float(v), 4) for v in net.steps.detach()]
        made = dict(run, steps_to=step, end_utc=utc_now(),
                    train_seeds=([train_seeds(step0, conf["batch"], arch)[0], train_seeds(step - 1, conf["batch"], arch)[-1]]
                                 if step > step0 else []))
        state = {"format": CHECKPOINT_FORMAT, "model": {k: v.detach().cpu() for k, v in net.state_dict().items()
                                                         if not k.startswith("phi.")},
                 "optim": _to_cpu(opt.state_dict()), "step": step, "elapsed_s": elapsed, "config": config,
                 "torch_rng": torch.get_rng_state(), "mask": torch.from_numpy(np.ascontiguousarray(mask)),
                 "runs": json.dumps(runs + [made]), "val_every": val_every, "threads": a.threads}
        meta = dict(config, bands_nm=bands_nm, height=size, width_px=size, training_step=step,
                    trained_minutes=round(elapsed / 60, 1), airy_diameter_px=2.5, sampling="stratified")
        meta.pop("width", None)
        if arch == ARCH_V2:
            meta["runs"] = len(runs) + 1
        with stop.saving():  # checkpoint, weights, manifest (last): one step; then the log's record of it
            tmp = f"{spath}.tmp"
            torch.save(state, tmp)
            os.replace(tmp, spath)
            save_unrolled(net, wpath, meta)
            write_manifest(runs + [made], step)
            run.update(made)
            last_saved = step
            log_line(rec)
        losses.clear()
        timing["save_s"] = time.time() - ts
        print(f"step {step} val {val} {elapsed / 60:.1f} min", flush=True)

    def kept() -> str:
        if last_saved is not None:
            return f"the state keeps step {last_saved}"
        return f"this run saved nothing; --resume {a.resume} keeps step {step0}" if ck is not None else "nothing saved"

    def resume_hint() -> str:
        if last_saved is not None:
            return f"{kept()}; continue with --resume {spath}"
        return f"{kept()}; continue with --resume {a.resume}" if ck is not None else kept()

    stop_reason = "steps done"
    try:
        # The manifest describes what the folder's checkpoint holds: the runs so far (this one joins at its first save).
        write_manifest(runs, step0)
        log_line({"event": "resume" if a.resume else "start", "step": step, "args": vars(a), "config": config,
                  "val_every": val_every, "setup_s": round(setup_s, 1), "params": count_parameters(net),
                  "device": str(device), "torch": torch.__version__, "threads": a.threads, "utc": start_utc,
                  **({"threads_changed": threads_changed} if threads_changed is not None else {})})
        if arch == ARCH_V2:
            vs = val_seeds(arch)
            val_acq, val_cube = render_v2(transport, vs, make_cubes_v2(vs, size, bands_nm))
            val_groups = {"clean": [i for i, s in enumerate(vs) if not _noise_on(s)],
                          "noisy": [i for i, s in enumerate(vs) if _noise_on(s)]}
        else:
            val_acq, val_cube = render_batch(transport, val_seeds() * 2, size, bands_nm,
                                             ["spectral"] * VAL_COUNT + ["rgb"] * VAL_COUNT)
            val_groups = {"spectral": list(range(VAL_COUNT)), "rgb": list(range(VAL_COUNT, 2 * VAL_COUNT))}
        val_acq, val_cube = val_acq.to(device), val_cube.to(device)
        if step == 0 or step == step0 and arch == ARCH_V2:
            checkpoint()
        net.train()
        loader = None
        if arch == ARCH_V2 and a.workers > 0 and step < conf["steps"]:
            targs = dict(system=system, seed=conf["acquisition_seed"], **setting(mask, conf["planes"], conf["rays"], bands_nm))
            loader = iter(torch.utils.data.DataLoader(StepData(step, conf["steps"], conf["batch"], size, bands_nm, targs),
                                                      batch_size=None, shuffle=False, num_workers=a.workers,
                                                      prefetch_factor=4, persistent_workers=False,
                                                      worker_init_fn=_ignore_sigint))
        step_s = None
        while step < conf["steps"]:
            now = time.time()
            if stop.requested:
                stop_reason = "interrupted"
                break
            if a.minutes is not None and now - t0 > 60 * a.minutes:
                stop_reason = "minutes"
                break
            if a.stop_at is not None and step >= a.stop_at:
                stop_reason = "stop-at"
                break
            if budget is not None and step_s is not None and \
                    now - t_start + step_s + 1.5 * (timing["val_s"] + timing["save_s"]) + 5.0 > budget:
                stop_reason = "time budget"
                break
            ts = time.time()
            if arch == ARCH_V2:
                if loader is not None:
                    k, seeds, acq, cube = next(loader)
                    assert k == step, (k, step)
                else:
                    seeds = train_seeds(step, conf["batch"], arch)
                    acq, cube = render_v2(transport, seeds, make_cubes_v2(seeds, size, bands_nm))
            else:
                acq, cube = render_batch(transport, train_seeds(step, conf["batch"]), size, bands_nm)
            acq, cube = acq.to(device, non_blocking=True), cube.to(device, non_blocking=True)
            loss = l1_step(opt, net.parameters(), lr_at(step, conf["steps"], conf["lr"], conf["lr_min"], conf["warmup"]),
                           conf["clip"], forward(acq), cube)
            if loss is None:
                raise Diverged(step, "the training loss is not finite")
            losses.append(loss)
            step += 1
            dt_s = time.time() - ts
            step_s = dt_s if step_s is None else max(dt_s, 0.8 * step_s + 0.2 * dt_s)
            if step % val_every == 0 or step == conf["steps"]:
                checkpoint()
        if step != last_saved:
            checkpoint()
    except Diverged as e:
        log_line({"event": "stop", "step": e.step, "reason": "diverged", "detail": e.what, "saved_step": last_saved,
                  "utc": utc_now(), "wall_s": round(time.time() - t_start, 1)})
        where = f" (the state, weights and manifest in {out}: the last good step)" if last_saved is not None else ""
        print(f"{prog}: error: the training diverged at step {e.step} ({e.what}); nothing of that step was saved: "
              f"{kept()}{where}. The learning rate is too high for this network: train again with a lower --lr than "
              f"{conf['lr']:g} (or --resume the kept step with a lower --lr)", file=sys.stderr)
        return 1
    except KeyboardInterrupt:  # a second Ctrl-C: at once (never inside a save)
        log_line({"event": "stop", "step": step, "reason": "interrupted", "saved_step": last_saved, "utc": utc_now(),
                  "wall_s": round(time.time() - t_start, 1)})
        print(f"{prog}: interrupted at step {step}: {resume_hint()}", file=sys.stderr)
        return 130
    log_line({"event": "stop", "step": step, "reason": stop_reason, "utc": utc_now(),
              "wall_s": round(time.time() - t_start, 1)})
    load_unrolled(wpath, phi, system=system, mask=mask)  # the file written reads back
    if stop_reason == "interrupted":
        print(f"{prog}: interrupted at step {step}: {resume_hint()}", file=sys.stderr)
        return 130
    if step < conf["steps"]:  # the weights are then those of this step, before the end of the schedule
        print(f"stopped at step {step} of {conf['steps']} ({stop_reason}): continue with --resume {spath}")
    print(f"done at step {step}: {wpath} ({time.time() - t_start:.0f} s)")
    return 0


def _trim_cut_line(path: pathlib.Path, prog: str) -> None:
    """A log whose last line was cut short (a run killed while writing it) loses that line before a run appends to
    it (appended to, it would join the next record on one unreadable line)."""
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        return
    if data and not data.endswith(b"\n"):
        keep = data.rfind(b"\n") + 1
        with open(path, "r+b") as f:
            f.truncate(keep)
        print(f"{prog}: note: {path}: removed its last line, cut short ({len(data) - keep} bytes: a run stopped while "
              "writing it)", file=sys.stderr)


def _noise_on(seed: int) -> bool:
    from diffcassi.training_data import draw_noise
    return draw_noise(seed) is not None


def _to_cpu(obj):
    """An optimiser state with every tensor on the CPU (a checkpoint from a GPU run resumes anywhere)."""
    if isinstance(obj, torch.Tensor):
        return obj.detach().cpu()
    if isinstance(obj, dict):
        return {k: _to_cpu(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return type(obj)(_to_cpu(v) for v in obj)
    return obj


if __name__ == "__main__":
    sys.exit(main())
