#!/usr/bin/env python3
"""Trains the unrolled network (``diffcassi.torch.UnrolledGAP``, arch unrolled-gap-v1: GAP stages with learned
denoisers around the exact operator) for one system, on CPU, on acquisitions rendered on the fly.

    nice -n 10 .venv/bin/python scripts/train_unrolled.py --system sp --mask ../shared/reference/paper_mask_512.npy \\
        --out out/unrolled-sp --steps 400 --minutes 25 --threads 1
    .venv/bin/python scripts/train_unrolled.py --system sp ... --resume out/unrolled-sp/unrolled-sp-state.pt
    .venv/bin/python scripts/train_unrolled.py --out out/unrolled-sp --system sp --summary 50   # the curve

Recipe (diffcassi/weights/UNROLLED.md states the run's numbers):

* scenes: procedural dead-leaves cubes only (``diffcassi.deadleaves``, both kinds: measured-spectra and
  uplifted-sRGB leaves), ``--size``² × 28 bands (450–650 nm), peak 1; at step s the batch holds the cubes of
  seeds ``TRAIN_SEED_BASE + batch·s + i`` (i even: spectral, odd: rgb); validation seeds ``0 … VAL_COUNT−1`` of
  each kind: disjoint by construction, and no image file is read (the evaluation scenes of ``data/scenes`` never
  enter: tested);
* acquisitions: rendered through the system's exact light transport (``diffcassi.Transport``: the renderer, bit
  for bit) in the realistic setting of docs/study.md — 112 planes, 20 rays per pixel per plane, stratified, Airy
  2.5 px at 520 nm, the mask ``--mask`` centre-cropped to the scene (the study's rule; default a random mask of
  opening 0.5, seed 0) — traced with ``--acquisition-seed`` (1000: neither the evaluation's acquisition seed 0 nor
  the operator's);
* operator: the exact operator traced with ``--operator-seed`` (1: the evaluation's ``reconstruct`` default,
  acquisition seed + 1), in its matrix-free torch form; its Monte-Carlo rays differ from the acquisition's (the
  realistic setting, no oracle);
* loss: L1 between the output and the cube; Adam (β 0.9/0.999), learning rate ``--lr`` with a linear warm-up and
  a cosine decay to ``--lr-min`` at ``--steps``; gradient-norm clipping ``--clip``; torch seed ``--seed``;
* validation every ``--val-every`` steps: PSNR (peak 1) of the fixed validation cubes of both kinds;
* outputs in ``--out``: ``unrolled-gap-v1-<system>.safetensors`` (the weights of the last step: the end of the
  schedule, a validation-independent choice), ``unrolled-<system>-log.jsonl`` (one JSON line per validation,
  appended on resume), ``unrolled-<system>-manifest.json`` (data sources and seed rules) and
  ``unrolled-<system>-state.pt`` (the resume state; not committed).

Every random choice derives from the seeds and the step: ``--resume`` continues exactly as the uninterrupted run
(tested); ``--minutes`` only caps one invocation's wall time (the schedule depends on the step alone).
"""
from __future__ import annotations

import argparse
import json
import os
import pathlib
import sys
import time

import numpy as np
import torch

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import diffcassi  # noqa: E402
import diffcassi.torch as dt  # noqa: E402
from diffcassi.deadleaves import BANDS_NM, dead_leaves, sources_manifest  # noqa: E402
from diffcassi.unrolled import UnrolledGAP, load_unrolled, mask_sha256, save_unrolled  # noqa: E402
from diffcassi._training import l1_step, lr_at, psnr_db, validation_records  # noqa: E402

#: Train seeds are TRAIN_SEED_BASE + batch·step + i; validation seeds 0 … VAL_COUNT−1 (of each kind).
TRAIN_SEED_BASE = 3_000_000
VAL_COUNT = 4
#: The realistic setting of docs/study.md.
PLANES, RAYS = 112, 20


def seed_kind(seed: int) -> str:
    """Kind of the dead-leaves cube of a train seed: even offsets measured-spectra leaves, odd uplifted sRGB."""
    return "rgb" if (seed - TRAIN_SEED_BASE) % 2 else "spectral"


def train_seeds(step: int, batch: int) -> list:
    return [TRAIN_SEED_BASE + batch * step + i for i in range(batch)]


def val_seeds() -> list:
    return list(range(VAL_COUNT))


def names(system: str) -> dict:
    return {"weights": f"unrolled-gap-v1-{system}.safetensors", "log": f"unrolled-{system}-log.jsonl",
            "manifest": f"unrolled-{system}-manifest.json", "state": f"unrolled-{system}-state.pt"}


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


def summary(log_path: pathlib.Path, every: int) -> int:
    """Prints the validation curve of a training log as a Markdown table."""
    try:
        vals = validation_records(log_path, "train_unrolled", every)
    except ValueError as e:
        print(e, file=sys.stderr)
        return 1
    print("| step | minutes | lr | train L1 | val spectral (dB) | val RGB (dB) | mean |")
    print("|---|---|---|---|---|---|---|")
    for r in vals:
        if r["step"] % every == 0 or r is vals[-1]:
            l1 = "–" if r["train_l1"] is None else f"{r['train_l1']:.4f}"
            print(f"| {r['step']} | {r['elapsed_s'] / 60:.1f} | {r['lr']:.2e} | {l1} | {r['val_psnr_db']['spectral']:.2f} | "
                  f"{r['val_psnr_db']['rgb']:.2f} | {r['val_mean_db']:.2f} |")
    return 0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--system", required=True, help="preset: sp, msp, ap, map")
    ap.add_argument("--out", required=True, help="output folder")
    ap.add_argument("--mask", default=None, help="mask file ((H, W) NPY), centre-cropped to --size (default: random, seed 0)")
    ap.add_argument("--size", type=int, default=128, help="scene side (pixels)")
    ap.add_argument("--stages", type=int, default=6)
    ap.add_argument("--width", type=int, default=16, help="U-Net width C of each stage's denoiser")
    ap.add_argument("--steps", type=int, default=400, help="total optimiser steps; the learning-rate schedule spans them")
    ap.add_argument("--minutes", type=float, default=None, help="wall-time cap of this invocation (stops early, state saved)")
    ap.add_argument("--stop-at", type=int, default=None, help="stop this invocation at this step (state saved; the "
                    "schedule still spans --steps)")
    ap.add_argument("--batch", type=int, default=2, help="cubes per step (half measured-spectra, half RGB leaves)")
    ap.add_argument("--threads", type=int, default=1, help="torch and Rust threads")
    ap.add_argument("--seed", type=int, default=0, help="torch seed of the initial weights")
    ap.add_argument("--lr", type=float, default=1e-3)
    ap.add_argument("--lr-min", type=float, default=2e-5)
    ap.add_argument("--warmup", type=int, default=20)
    ap.add_argument("--clip", type=float, default=1.0, help="gradient-norm clipping")
    ap.add_argument("--val-every", type=int, default=25, help="validate (and save the state) every N steps")
    ap.add_argument("--planes", type=int, default=PLANES)
    ap.add_argument("--rays", type=int, default=RAYS)
    ap.add_argument("--acquisition-seed", type=int, default=1000, help="Monte-Carlo seed of the training renders")
    ap.add_argument("--operator-seed", type=int, default=1, help="Monte-Carlo seed of the operator (default 1: "
                    "reconstruct's default for acquisitions of seed 0)")
    ap.add_argument("--resume", default=None, help="a state file (unrolled-<system>-state.pt) to continue from")
    ap.add_argument("--summary", type=int, metavar="EVERY", default=None,
                    help="print the validation curve of --out's log as a Markdown table, and exit")
    a = ap.parse_args(argv)
    if a.system not in ("sp", "msp", "ap", "map"):
        ap.error(f"--system {a.system!r}: expected one of sp, msp, ap, map")
    nm = names(a.system)
    out = pathlib.Path(a.out)
    if a.summary is not None:
        return summary(out / nm["log"], a.summary)
    for name in ("size", "stages", "width", "steps", "batch", "threads", "val_every", "warmup", "planes", "rays"):
        if getattr(a, name) < 1:
            ap.error(f"--{name.replace('_', '-')} must be at least 1 (got {getattr(a, name)})")
    if a.size < 8:
        ap.error(f"--size must be at least 8 (got {a.size})")
    if not (a.lr > 0 and a.lr_min >= 0 and a.clip > 0) or (a.minutes is not None and not a.minutes > 0):
        ap.error("--lr, --clip and --minutes must be positive, --lr-min non-negative")
    if a.acquisition_seed == a.operator_seed:
        ap.error("--acquisition-seed and --operator-seed must differ (the realistic setting: no oracle)")

    torch.set_num_threads(a.threads)
    diffcassi.set_num_threads(a.threads)
    torch.manual_seed(a.seed)
    bands_nm = BANDS_NM
    try:  # no --mask: the library's random mask (opening 0.5, seed 0), render's default
        mask = load_mask(a.mask, a.size) if a.mask else None
    except (OSError, ValueError) as e:
        print(f"train_unrolled: error: --mask: {e}", file=sys.stderr)
        return 1
    t_setup = time.time()
    transport, phi = build_operators(a.system, a.size, mask, a.planes, a.rays, a.acquisition_seed, a.operator_seed,
                                     bands_nm)
    mask = transport.mask
    setup_s = time.time() - t_setup
    net = UnrolledGAP(phi, stages=a.stages, width=a.width)
    opt = torch.optim.Adam(net.parameters(), lr=a.lr)
    out.mkdir(parents=True, exist_ok=True)
    wpath, lpath, spath = out / nm["weights"], out / nm["log"], out / nm["state"]
    config = {k: getattr(a, k) for k in ("system", "size", "stages", "width", "steps", "batch", "seed", "lr", "lr_min",
                                         "warmup", "clip", "planes", "rays", "acquisition_seed", "operator_seed")}
    config["mask_sha256"] = mask_sha256(mask)
    step, elapsed0 = 0, 0.0
    if a.resume:
        if not os.path.isfile(a.resume):
            print(f"train_unrolled: error: --resume {a.resume}: no such file", file=sys.stderr)
            return 1
        st = torch.load(a.resume, weights_only=False)
        if st.get("config") != config:
            diff = {k: (st.get("config", {}).get(k), v) for k, v in config.items() if st.get("config", {}).get(k) != v}
            print(f"train_unrolled: error: --resume {a.resume} was made with other settings (saved, asked): {diff}",
                  file=sys.stderr)
            return 2
        net.load_state_dict(st["model"], strict=False)
        opt.load_state_dict(st["optim"])
        step, elapsed0 = st["step"], st["elapsed_s"]
    manifest = sources_manifest(bands_nm)
    manifest.update({
        "train_seeds": f"{TRAIN_SEED_BASE} + batch*step + i; i even spectral, odd rgb", "train_seed_min": TRAIN_SEED_BASE,
        "val_seeds": val_seeds(), "val_kinds": ["spectral", "rgb"], "evaluation_scenes_used": [], "config": config,
        "operator": repr(phi.op), "acquisition_transport": repr(transport),
    })
    (out / nm["manifest"]).write_text(json.dumps(manifest, indent=1) + "\n")

    val_acq, val_cube = render_batch(transport, val_seeds() * 2, a.size, bands_nm, ["spectral"] * VAL_COUNT + ["rgb"] * VAL_COUNT)
    log = open(lpath, "a")
    log.write(json.dumps({"event": "resume" if a.resume else "start", "step": step, "args": vars(a), "config": config,
                          "setup_s": round(setup_s, 1), "params": sum(p.numel() for p in net.parameters()),
                          "torch": torch.__version__, "threads": a.threads}) + "\n")
    log.flush()
    t0 = time.time()
    losses: list = []

    @torch.no_grad()
    def validate() -> dict:
        net.eval()
        p = psnr_db(torch.cat([net(val_acq[i:i + 2]) for i in range(0, len(val_acq), 2)]), val_cube)
        net.train()
        return {"spectral": float(p[:VAL_COUNT].mean()), "rgb": float(p[VAL_COUNT:].mean())}

    def checkpoint():
        val = validate()
        elapsed = elapsed0 + time.time() - t0
        rec = {"step": step, "elapsed_s": round(elapsed, 1), "lr": opt.param_groups[0]["lr"],
               "train_l1": (sum(losses) / len(losses)) if losses else None, "val_psnr_db": val,
               "val_mean_db": (val["spectral"] + val["rgb"]) / 2,
               "steps_lambda": [round(float(v), 4) for v in net.steps.detach()]}
        log.write(json.dumps(rec) + "\n")
        log.flush()
        losses.clear()
        tmp = f"{spath}.tmp"
        torch.save({"model": {k: v for k, v in net.state_dict().items() if not k.startswith("phi.")},
                    "optim": opt.state_dict(), "step": step, "elapsed_s": elapsed, "config": config}, tmp)
        os.replace(tmp, spath)
        print(f"step {step} val {val} {elapsed / 60:.1f} min", flush=True)

    if step == 0:
        checkpoint()
    net.train()
    while step < a.steps:
        if (a.minutes is not None and time.time() - t0 > 60 * a.minutes) or (a.stop_at is not None and step >= a.stop_at):
            break
        acq, cube = render_batch(transport, train_seeds(step, a.batch), a.size, bands_nm)
        loss = l1_step(opt, net.parameters(), lr_at(step, a.steps, a.lr, a.lr_min, a.warmup), a.clip, net(acq), cube)
        if loss is None:
            print(f"train_unrolled: error: non-finite loss at step {step}; the state keeps step {step}", file=sys.stderr)
            return 1
        losses.append(loss)
        step += 1
        if step % a.val_every == 0 or step == a.steps:
            checkpoint()
    if step % a.val_every and step != a.steps:
        checkpoint()
    log.close()
    if step < a.steps:  # the weights below are then those of this step, before the end of the schedule
        print(f"stopped at step {step} of {a.steps}: continue with --resume {spath}")
    meta = dict(config, bands_nm=[float(b) for b in bands_nm], height=a.size, width_px=a.size, training_step=step,
                trained_minutes=round((elapsed0 + time.time() - t0) / 60, 1), airy_diameter_px=2.5, sampling="stratified")
    meta.pop("width", None)
    save_unrolled(net, wpath, meta)
    load_unrolled(wpath, phi, system=a.system, mask=mask)  # the file written reads back
    print(f"done at step {step}: {wpath}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
