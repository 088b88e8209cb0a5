#!/usr/bin/env python3
"""Trains the learned hyperspectral denoiser (``diffcassi.denoiser.SpectralUNet``, arch spectral-unet-v2) on CPU
or a GPU with procedural dead-leaves cubes (``diffcassi.deadleaves``) generated on the fly from seeds.

    .venv/bin/python scripts/train_denoiser.py --out OUT --init V1.safetensors --latent 12 --freeze-spectral \
        --patch 48 --steps 2400 --threads 1 --lr 3e-4     # round 3 (MODEL.md gives the exact command)
    .venv/bin/python scripts/train_denoiser.py --out OUT --resume OUT/train-state.pt ...the same arguments...

Recipe (src/recon/prior/MODEL.md states the run's numbers):

* data: at step s the batch holds the cubes of the train seeds of steps s-3…s (two new cubes per step, each
  seen in four consecutive steps under a different random flip/rotation and noise); train seeds are
  ``TRAIN_SEED_BASE + 2·s + i`` (≥ 1 000 000): i = 0 measured-spectra leaves, i = 1 uplifted-sRGB leaves
  (``dead_leaves(kind=...)``); validation seeds ``0…VAL_COUNT-1`` of both kinds: disjoint by construction;
* ``--init`` starts from existing weights (fine-tuning; their SHA-256 goes into the manifest and the state): a
  v2 file of the same width and latent, or a ``spectral-unet-v1`` file converted by ``denoiser.from_v1`` with the
  linear path set to the projection on ``--latent`` principal directions of training spectra
  (:func:`spectral_basis`, from the cubes of the first ``PCA_STEPS`` steps' train seeds); ``--freeze-spectral``
  keeps E and D fixed there;
* augmentation for the plug-and-play use (structured errors) and dark scenes: random brightness (log-uniform
  in [0.05, 1] with p = 0.3, U[0.5, 1] with p = 0.3, else 1; the noise stays on the peak-1 scale), random
  per-band gains (×(1 + N(0, 0.05)) per band, p = 0.3), noise σ ~ U[0, 0.2] per sample (the σ channel), white
  Gaussian or (p = 0.25) a mixture with spatially correlated Gaussian noise of the same total σ;
* loss: L1 between the network's output and the clean cube; Adam (β = 0.9, 0.999), learning rate ``--lr`` with a
  linear warm-up (``--warmup`` steps) and a cosine decay to ``--lr-min`` over ``--steps``; gradient-norm clipping;
* validation every ``--val-every`` steps: PSNR (peak 1) at σ ∈ {0.02, 0.05, 0.1} with fixed noise on the fixed
  validation cubes of both kinds (``--patch`` pixels) and on the *selection set* (:func:`selection_set`:
  uplifted-sRGB leaves — the spectral family of photographs — at 64×64 with large flat leaves and a fixed share
  of dark cubes, where round 2 failed); the weights file holds the best selection score so far: the mean over σ
  of the selection set's mean PSNR (round 2's six-number mean did not predict the natural scenes: MODEL.md);
* outputs in ``--out``: ``spectral-unet-v2-<bands>.safetensors`` (best), ``train-log.jsonl`` (one JSON object
  per validation, appended on resume), ``train-manifest.json`` (the data's sources and seed rules),
  ``train-state.pt`` (the latest state for ``--resume``; not committed).

* ``--pairs FILE`` (round 4, issue 22's PnP fine-tuning): each step also takes ``--pair-batch`` *artefact pairs*
  from FILE (``scripts/make_pnp_pairs.py``: the iterate ``pnp-gap`` gives the network — the GAP data step after
  GAP-TV's phase — and the truth, both divided by the iterate's peak), a random ``--patch`` crop and flips (no
  rotation: the dispersion stays along x), the σ input the pair's stage constant :data:`PAIR_SIGMA` (what PnP
  passes; no truth needed at inference); ``--pairs-val FILE`` (validation scenes, other seeds) is scored every
  validation: the mean PSNR of the network's output on the stop-stage pairs (= one-call PnP's PSNR on those
  renders); with it, the weights file holds the best such score among checkpoints whose Gaussian selection score
  is at most ``--sel-tolerance`` dB under the start's (the Gaussian benchmark must not regress);

* on a GPU (round 9, MODEL.md): ``--device cuda`` (the augmentation's draws from a generator on the device, seeded
  alike), ``--workers N`` processes making the coming steps' cubes (the same cubes as one process makes),
  ``--new-per-step`` cubes per step (the batch is 4× that), ``--init-spectral`` (a new network of any width that
  starts from another file's E, D and G), ``--sel-floor`` (an absolute Gaussian floor for the pair rule) and
  ``--keep-every`` (checkpoints to choose among elsewhere). The script needs the ``diffcassi`` package with its
  extension (the RGB leaves' uplift is the library's); on a machine without Rust install the wheel
  (``bash scripts/build_wheel.sh`` here, then ``pip install --no-deps dist/diffcassi-*.whl`` there).

Every random choice derives from ``--seed`` and the step, so a resumed run continues exactly as the uninterrupted
one would; ``--minutes`` only caps the wall time of this invocation (the schedule depends on the step alone).
"""
from __future__ import annotations

import argparse
import json
import math
import os
import pathlib
import sys
import time
from typing import Optional

import numpy as np
import torch
import torch.nn.functional as F

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


from diffcassi.deadleaves import BANDS_NM, dead_leaves, sources_manifest  # noqa: E402
from diffcassi.denoiser import ARCH, SpectralUNet, from_v1, load_weights, save_weights  # noqa: E402
from diffcassi._training import l1_step, lr_at, psnr_db, validation_records  # noqa: E402

#: Train seeds are TRAIN_SEED_BASE + 2·step + i; validation seeds are 0 … VAL_COUNT-1.
TRAIN_SEED_BASE = 1_000_000
NEW_PER_STEP = 2
WINDOW = 4
VAL_COUNT = 16
VAL_SIGMAS = (0.02, 0.05, 0.1)
VAL_NOISE_SEED = 424242
SIGMA_MAX = 0.2
#: The linear path's PCA (``--init`` of a v1 file): the train cubes of steps 0 … PCA_STEPS-1, PCA_SIZE pixels.
PCA_STEPS, PCA_SIZE = 100, 32
#: The selection set (:func:`selection_set`): uplifted-sRGB leaves, seeds SEL_SEED_BASE + i, i < SEL_COUNT,
#: SEL_SIZE pixels, smallest leaf radius in SEL_RMIN_PX, textures (flat, gradient, fractal, stripes) SEL_TEXTURES,
#: and the brightness of cube i SEL_BRIGHTNESS[i % 4] (a quarter dark, a quarter dim).
SEL_SEED_BASE, SEL_COUNT, SEL_SIZE = 1000, 16, 64
SEL_RMIN_PX, SEL_TEXTURES, SEL_BRIGHTNESS = (4.0, 16.0), (0.6, 0.15, 0.15, 0.1), (1.0, 1.0, 0.5, 0.15)
#: The σ input of an artefact pair, per stage of ``scripts/make_pnp_pairs.py`` (0 ``stop``: the iterate after
#: GAP-TV's own stop, the default PnP's network call; 1 ``half``: an earlier iterate), relative to the iterate's
#: peak: fixed per stage, so that ``pnp-gap`` can pass it without the truth (``PNP_SIGMA_MAX`` in
#: ``src/recon/solver.rs`` is the stop stage's). Above the Gaussian range (σ ≤ 0.2), so the σ input also tells
#: the network which kind of error it is given.
PAIR_SIGMA = (0.3, 0.4)
#: The stages of round 4's pair files (round 6's files name theirs in the manifest: ``call1`` …).
STAGE_NAMES = ("stop", "half")


def seed_kind(seed: int) -> str:
    """The kind of dead-leaves cube a train seed makes (``diffcassi.deadleaves.KINDS``): of the new seeds of a
    step, even ones are measured-spectra leaves, odd ones uplifted sRGB leaves (a 50/50 mix)."""
    return "rgb" if (seed - TRAIN_SEED_BASE) % 2 else "spectral"


def train_seeds(step: int, new: int = NEW_PER_STEP) -> list:
    """The dead-leaves seeds of the batch at ``step`` (the ``new`` new seeds of each of the steps max(0, s-3) …
    max(0, s-3)+3; ``--new-per-step``, 2 by default)."""
    first = max(0, step - (WINDOW - 1))
    return [TRAIN_SEED_BASE + new * s + i for s in range(first, first + WINDOW) for i in range(new)]


class CubeSource:
    """The training cubes of the coming steps, by seed: made in this process (``workers`` = 0) or by a pool of
    ``workers`` processes ``ahead`` steps in advance (the same cubes: each is a function of its seed alone)."""

    def __init__(self, size: int, new: int, workers: int, ahead: int = 48):
        self.size, self.new, self.ahead = size, new, ahead
        self.cache: dict = {}
        self.pending: dict = {}
        self.pool = None
        if workers > 0:
            import multiprocessing
            # fork before any CUDA call (the pool is made before the network moves to the device)
            self.pool = multiprocessing.get_context("fork").Pool(workers)

    def batch(self, step: int) -> torch.Tensor:
        seeds = train_seeds(step, self.new)
        if self.pool is not None:
            last = max(seeds) + self.new * self.ahead
            for s in range(max(seeds) + 1 - self.new * WINDOW, last + 1):
                if s not in self.cache and s not in self.pending:
                    # (dead_leaves itself is the job: a module function pickles by name from any caller)
                    self.pending[s] = self.pool.apply_async(dead_leaves, (s, self.size), {"kind": seed_kind(s)})
        for s in seeds:
            if s not in self.cache:
                job = self.pending.pop(s, None)
                self.cache[s] = torch.from_numpy(job.get() if job is not None else
                                                 dead_leaves(s, self.size, BANDS_NM, kind=seed_kind(s)))
        for s in [s for s in self.cache if s not in seeds]:
            del self.cache[s]
        return torch.stack([self.cache[s] for s in seeds])

    def close(self):
        if self.pool is not None:
            self.pool.terminate()


def val_seeds() -> list:
    return list(range(VAL_COUNT))


def sel_seeds() -> list:
    return [SEL_SEED_BASE + i for i in range(SEL_COUNT)]


def spectral_basis(k: int, bands_nm) -> torch.Tensor:
    """(bands, k) orthonormal, from training cubes only (the new cubes of steps 0 … PCA_STEPS-1, PCA_SIZE² pixels
    each): the principal directions (uncentred: the linear path has no offset) of the uplifted-sRGB cubes with a
    non-zero share of their energy (> 1e-9: they span exactly Smits' 7 basis spectra), then those of the
    measured-spectra cubes' residual orthogonal to them, k in all; signs fixed so that each column sums to ≥ 0.
    (A PCA of both kinds together weights the uplifted family's weak directions down and loses them: MODEL.md.)"""
    seeds = [TRAIN_SEED_BASE + i for i in range(NEW_PER_STEP * PCA_STEPS)]  # the new seeds of steps < PCA_STEPS
    x = {kind: np.concatenate([dead_leaves(s, PCA_SIZE, bands_nm, kind=kind).reshape(len(bands_nm), -1)
                               for s in seeds if seed_kind(s) == kind], axis=1).astype(np.float64)
         for kind in ("rgb", "spectral")}
    u, ev, _ = np.linalg.svd(x["rgb"] @ x["rgb"].T)
    basis = u[:, :min(k, int((ev > 1e-9 * ev.sum()).sum()))]
    r = x["spectral"] - basis @ (basis.T @ x["spectral"])
    u2, _, _ = np.linalg.svd(r @ r.T)
    basis = np.linalg.qr(np.concatenate([basis, u2[:, :k - basis.shape[1]]], axis=1))[0]
    basis = basis * np.where(basis.sum(0) < 0, -1.0, 1.0)
    return torch.from_numpy(basis.astype(np.float32))


def weights_name(bands: int) -> str:
    return f"{ARCH}-{bands}.safetensors"


def brightness(n: int, g: torch.Generator) -> torch.Tensor:
    """Per-cube brightness factors (n,): log-uniform in [0.05, 1] with p = 0.3 (dark scenes: the noise, drawn on
    the peak-1 scale, then dominates), U[0.5, 1] with p = 0.3, else 1 (plug-and-play iterates are not peak-1)."""
    dev = g.device
    u = torch.rand(n, generator=g, device=dev)
    dark = torch.exp(math.log(0.05) * torch.rand(n, generator=g, device=dev))
    half = 0.5 + 0.5 * torch.rand(n, generator=g, device=dev)
    return torch.where(u < 0.3, dark, torch.where(u < 0.6, half, torch.ones(n, device=dev)))


def _blur(x: torch.Tensor) -> torch.Tensor:
    """Separable 5-tap Gaussian (σ ≈ 1 px) over the spatial axes of (N, B, H, W), per band."""
    k = torch.tensor([0.0545, 0.2442, 0.4026, 0.2442, 0.0545], dtype=x.dtype, device=x.device)
    n, b, h, w = x.shape
    y = x.reshape(n * b, 1, h, w)
    y = F.conv2d(F.pad(y, (2, 2, 0, 0), mode="circular"), k.view(1, 1, 1, 5))
    y = F.conv2d(F.pad(y, (0, 0, 2, 2), mode="circular"), k.view(1, 1, 5, 1))
    return y.reshape(n, b, h, w)


def make_batch(clean: torch.Tensor, g: torch.Generator):
    """Augments clean cubes (N, B, H, W) and adds noise; returns (noisy, sigma (N,), target). The random draws
    come from ``g`` on its device (``clean`` must be there too)."""
    n, b = clean.shape[:2]
    dev = g.device
    out = []
    for i in range(n):
        c = clean[i]
        k = int(torch.randint(0, 4, (1,), generator=g, device=dev))
        c = torch.rot90(c, k, dims=(1, 2))
        if torch.rand(1, generator=g, device=dev) < 0.5:
            c = torch.flip(c, dims=(2,))
        out.append(c)
    x = torch.stack(out)
    x = x * brightness(n, g).view(n, 1, 1, 1)
    gains = 1 + 0.05 * torch.randn(n, b, generator=g, device=dev)
    use = (torch.rand(n, generator=g, device=dev) < 0.3).float().view(n, 1)
    x = x * (use * gains + (1 - use)).clamp(min=0).view(n, b, 1, 1)
    sigma = SIGMA_MAX * torch.rand(n, generator=g, device=dev)
    white = torch.randn(x.shape, generator=g, device=dev)
    corr = _blur(torch.randn(x.shape, generator=g, device=dev))
    corr = corr / corr.std(dim=(1, 2, 3), keepdim=True).clamp(min=1e-6)
    rho = torch.where(torch.rand(n, generator=g, device=dev) < 0.25, 0.3 + 0.4 * torch.rand(n, generator=g, device=dev),
                      torch.zeros(n, device=dev))
    noise = torch.sqrt(1 - rho).view(n, 1, 1, 1) * white + torch.sqrt(rho).view(n, 1, 1, 1) * corr
    return x + sigma.view(n, 1, 1, 1) * noise, sigma, x


def load_pairs(path) -> dict:
    """The artefact pairs of ``scripts/make_pnp_pairs.py`` as torch tensors (clear errors for a missing or bad
    file), with the file's SHA-256 and manifest."""
    import hashlib
    path = pathlib.Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"artefact pairs {path}: no such file")
    try:
        with np.load(path) as z:
            d = {k: z[k] for k in ("inputs", "targets", "stage", "err", "preset")}
            file_sigma = z["sigma"] if "sigma" in z.files else None
            manifest = json.loads(str(z["manifest"]))
    except (OSError, ValueError, KeyError) as e:
        raise ValueError(f"artefact pairs {path}: not a make_pnp_pairs.py file ({e})") from None
    x, t = d["inputs"], d["targets"]
    if x.ndim != 4 or x.shape != t.shape or x.shape[1] != len(BANDS_NM) or not (np.isfinite(x).all() and np.isfinite(t).all()):
        raise ValueError(f"artefact pairs {path}: inputs/targets must be finite (N, {len(BANDS_NM)}, H, W) of one shape, "
                         f"got {x.shape} and {t.shape}")
    if file_sigma is not None:
        # Round 6 (``make_pnp_pairs.py --schedule``): one stage per network call, σ the schedule's.
        names = list(manifest.get("stages") or [])
        sigma = np.asarray(file_sigma, dtype=np.float32)
        if sigma.shape != d["stage"].shape or not (np.isfinite(sigma).all() and (sigma > 0).all()):
            raise ValueError(f"artefact pairs {path}: `sigma` must be finite and > 0, one per pair")
    else:
        names = list(manifest.get("stages") or STAGE_NAMES[:len(PAIR_SIGMA)])  # (``--stop-only`` files: stop alone)
        if not set(names) <= set(STAGE_NAMES):
            raise ValueError(f"artefact pairs {path}: unknown stages {names} (expected some of {list(STAGE_NAMES)})")
        sigma = None
    if not names or not np.isin(d["stage"], range(len(names))).all():
        raise ValueError(f"artefact pairs {path}: a stage outside 0..{len(names) - 1}")
    if sigma is None:
        sigma = np.asarray([PAIR_SIGMA[STAGE_NAMES.index(n)] for n in names], dtype=np.float32)[d["stage"]]
    # float32 in memory (``make_pnp_pairs.py --float16`` files store half precision)
    x, t = x.astype(np.float32, copy=False), t.astype(np.float32, copy=False)
    return {"stage_names": names, "inputs": torch.from_numpy(x), "targets": torch.from_numpy(t), "sigma": torch.from_numpy(sigma),
            "stage": torch.from_numpy(d["stage"]), "err": d["err"], "preset": d["preset"], "manifest": manifest,
            "sha256": hashlib.sha256(path.read_bytes()).hexdigest(), "path": str(path)}


def pair_batch(pairs: dict, n: int, patch: int, g: torch.Generator, rotate: bool = False):
    """n artefact pairs drawn with ``g``: a random patch² crop of each, flipped along y and/or x (p = 0.5 each)
    and, with ``rotate`` (``--pair-rotate``: the whole dihedral group, for equivariant PnP, whose calls see the
    iterate turned by quarter turns), turned by k·90°, k uniform in 0..4 (drawn after the flips; without it the
    draws are as before); returns (input, sigma (n,), target)."""
    count, _, h, w = pairs["inputs"].shape
    idx = torch.randint(0, count, (n,), generator=g)
    xs, ts = [], []
    for i in idx.tolist():
        y0 = int(torch.randint(0, h - patch + 1, (1,), generator=g))
        x0 = int(torch.randint(0, w - patch + 1, (1,), generator=g))
        x = pairs["inputs"][i, :, y0:y0 + patch, x0:x0 + patch]
        t = pairs["targets"][i, :, y0:y0 + patch, x0:x0 + patch]
        for dim in (1, 2):
            if torch.rand(1, generator=g) < 0.5:
                x, t = torch.flip(x, dims=(dim,)), torch.flip(t, dims=(dim,))
        if rotate:
            k = int(torch.randint(0, 4, (1,), generator=g))
            x, t = torch.rot90(x, k, dims=(1, 2)), torch.rot90(t, k, dims=(1, 2))
        xs.append(x)
        ts.append(t)
    return torch.stack(xs), pairs["sigma"][idx], torch.stack(ts)


@torch.no_grad()
def validate_pairs(net: SpectralUNet, pairs: dict) -> dict:
    """Mean PSNR (dB, peak of the iterate) of the network's output against the truth on the pairs of each stage,
    and of the input (the GAP-TV iterate itself) — the output's is one-call PnP's PSNR on those renders. The
    network as trained (``neutral=False``: training never neutralises the mean colour; round 4's log reproduces)."""
    from diffcassi.denoiser import denoise
    net.eval()
    res = {}
    for si, name in enumerate(pairs["stage_names"]):
        sel = pairs["stage"] == si
        if not bool(sel.any()):
            continue
        x, t = pairs["inputs"][sel], pairs["targets"][sel]
        out = torch.cat([denoise(net, x[i:i + 8], pairs["sigma"][sel][i:i + 8], neutral=False) for i in range(0, len(x), 8)])
        res[name] = float(psnr_db(out, t).mean())
        res[f"{name}_input"] = float(psnr_db(x, t).mean())
    net.train()
    return res


def validation_set(size: int, bands_nm, kind: str = "spectral"):
    """The fixed validation cubes of one kind (seeds :func:`val_seeds`) and their noisy versions per σ."""
    clean = torch.from_numpy(np.stack([dead_leaves(s, size, bands_nm, kind=kind) for s in val_seeds()]))
    g = torch.Generator().manual_seed(VAL_NOISE_SEED + (1 if kind == "rgb" else 0))
    noisy = {s: clean + s * torch.randn(clean.shape, generator=g) for s in VAL_SIGMAS}
    return clean, noisy


def selection_set(bands_nm):
    """The fixed selection set (the rule that picks the committed weights): uplifted-sRGB dead leaves — the
    spectral family of uplifted photographs — with large, mostly flat leaves, a quarter of the cubes dimmed to 0.5
    and a quarter darkened to 0.15 (the noise stays on the peak-1 scale, as in a photograph's dark regions); fixed
    noise per σ. Never an evaluation scene."""
    clean = torch.from_numpy(np.stack([dead_leaves(s, SEL_SIZE, bands_nm, kind="rgb", rmin_px=SEL_RMIN_PX,
                                                   textures=SEL_TEXTURES) for s in sel_seeds()]))
    clean = clean * torch.tensor([SEL_BRIGHTNESS[i % 4] for i in range(SEL_COUNT)]).view(-1, 1, 1, 1)
    g = torch.Generator().manual_seed(VAL_NOISE_SEED + 2)
    noisy = {s: clean + s * torch.randn(clean.shape, generator=g) for s in VAL_SIGMAS}
    return clean, noisy


@torch.no_grad()
def validate(net: SpectralUNet, clean, noisy) -> dict:
    net.eval()
    res = {}
    for s, y in noisy.items():
        res[f"{s:g}"] = float(psnr_db(net(y, s), clean).mean())
    net.train()
    return res


def summary(log_path: pathlib.Path, every: int) -> int:
    """Prints the validation curve of a training log as a Markdown table."""
    try:
        vals = validation_records(log_path, "train_denoiser", every)
    except ValueError as e:
        print(e, file=sys.stderr)
        return 1
    best = max(vals, key=lambda r: r["sel_score_db"])
    keys = list(vals[0]["val_psnr_db"])
    cols = [f"{name} σ = {k}" for name in ("spectral", "RGB", "**selection**") for k in keys]
    print("| step | minutes | lr | train L1 | " + " | ".join(cols) + " | score |")
    print("|---" * (5 + len(cols)) + "|")
    for r in vals:
        if r["step"] % every == 0 or r is best or r is vals[-1]:
            l1 = "–" if r["train_l1"] is None else f"{r['train_l1']:.4f}"
            v = [r[name][k] for name in ("val_psnr_db", "val_rgb_psnr_db", "sel_psnr_db") for k in keys]
            print(f"| {r['step']}{' (best)' if r is best else ''} | {r['elapsed_s'] / 60:.1f} | {r['lr']:.2e} | {l1} | "
                  + " | ".join(f"{x:.2f}" for x in v) + f" | {r['sel_score_db']:.2f} |")
    return 0


def init_network(path, bands: int, latent: int, pca: Optional[int] = None):
    """The network ``--init`` starts from, and a description: a v2 file as it is, or a ``spectral-unet-v1`` file
    converted by :func:`diffcassi.denoiser.from_v1`: with ``latent`` = bands the same function (E = D = I, G = 0),
    with ``latent`` < bands the linear path the projection on :func:`spectral_basis`'s first ``latent`` components."""
    from safetensors import safe_open
    path = os.fspath(path)
    if not os.path.isfile(path):
        raise FileNotFoundError(f"denoiser weights {path}: no such file")
    try:
        with safe_open(path, framework="pt") as f:
            meta, tensors = f.metadata() or {}, {k: f.get_tensor(k) for k in f.keys()}
    except Exception as e:
        raise ValueError(f"denoiser weights {path}: not a valid safetensors file ({e})") from None
    if meta.get("arch") != "spectral-unet-v1":
        return load_weights(path, bands=bands), "a spectral-unet-v2 checkpoint (--init)"
    if meta.get("bands") != str(bands):
        raise ValueError(f"denoiser weights {path}: the network is for {meta.get('bands')} bands, not {bands}")
    v1 = SpectralUNet(bands=bands, width=int(meta.get("width", 0)) or 1, latent=bands)
    want = {k: tuple(t.shape) for k, t in v1.state_dict().items() if not k.startswith(("lat_", "bypass"))}
    if {k: tuple(t.shape) for k, t in tensors.items()} != want:
        raise ValueError(f"denoiser weights {path}: not the tensors of a spectral-unet-v1 of width {meta.get('width')}")
    k = latent if pca is None else pca
    if k == bands:
        return from_v1(tensors), "a spectral-unet-v1 checkpoint (--init), converted: E = D = I, G = 0"
    if latent == bands:
        return (from_v1(tensors, spectral_basis(k, BANDS_NM), full_latent=True),
                f"a spectral-unet-v1 checkpoint (--init), converted: E = I, D = the projection on {k} principal "
                f"directions of training spectra, G = 0")
    if k != latent:
        raise ValueError(f"--pca {k} must equal --latent {latent} when the latent is smaller than the bands")
    return (from_v1(tensors, spectral_basis(latent, BANDS_NM)),
            f"a spectral-unet-v1 checkpoint (--init), converted: E, D from the principal directions of training spectra (K = {latent})")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", default=str(ROOT / "src/recon/prior/weights"), help="output folder (default: %(default)s)")
    ap.add_argument("--steps", type=int, default=6000, help="total optimiser steps; the learning-rate schedule spans them")
    ap.add_argument("--minutes", type=float, default=None, help="wall-time cap of this invocation (stops early, state saved)")
    ap.add_argument("--threads", type=int, default=2, help="torch intra-op threads")
    ap.add_argument("--seed", type=int, default=0, help="torch seed of the initial weights and the augmentation")
    ap.add_argument("--new-per-step", type=int, default=NEW_PER_STEP, help="new dead-leaves cubes per step (even; "
                    "each is seen in %d consecutive steps, so the batch is %d times this; default: %%(default)s)" % (WINDOW, WINDOW))
    ap.add_argument("--batch", type=int, default=None, help="if given, must be %d × --new-per-step (the data window)" % WINDOW)
    ap.add_argument("--device", default="cpu", help="torch device of the training (cpu, cuda; default: %(default)s)")
    ap.add_argument("--workers", type=int, default=0, help="processes that make the training cubes ahead (0: this "
                    "process; the same cubes either way)")
    ap.add_argument("--init-spectral", default=None, help="a spectral-unet-v2 file of any width whose linear spectral "
                    "path (E, D, G) this network starts from (its U-Net starts at random); latent must match")
    ap.add_argument("--sel-floor", type=float, default=None, help="with --pairs-val: the absolute selection score (dB) a "
                    "checkpoint must keep, instead of step 0's minus --sel-tolerance (for a network trained from scratch)")
    ap.add_argument("--keep-every", type=int, default=None, help="also keep the weights of every N-th step as "
                    "ckpt-STEP.safetensors (to choose among them elsewhere)")
    ap.add_argument("--patch", type=int, default=64, help="training cube size (pixels, multiple of 4)")
    ap.add_argument("--width", type=int, default=32, help="network width C")
    ap.add_argument("--latent", type=int, default=28, help="latent channels K of the linear spectral path (≤ bands)")
    ap.add_argument("--freeze-spectral", action="store_true", help="keep E and D (the spectral encoder and decoder) "
                    "fixed at their initial values (the bypass G and the U-Net are trained)")
    ap.add_argument("--pca", type=int, default=None, help="with --init of a v1 file: the linear path starts as the "
                    "projection on this many principal components of training spectra (default: --latent; with "
                    "--latent = bands, D = that projection and E = I)")
    ap.add_argument("--lr", type=float, default=1e-3)
    ap.add_argument("--lr-min", type=float, default=1e-5)
    ap.add_argument("--warmup", type=int, default=100)
    ap.add_argument("--clip", type=float, default=1.0, help="gradient-norm clipping")
    ap.add_argument("--val-every", type=int, default=100, help="validate (and checkpoint) every N steps")
    ap.add_argument("--resume", default=None, help="a train-state.pt to continue from")
    ap.add_argument("--init", default=None, help="start from these weights instead of a random initialisation (its "
                    "SHA-256 goes into the manifest): a spectral-unet-v2 file of the same width and latent, or a "
                    "spectral-unet-v1 file of the same width (converted; the linear path starts as the projection "
                    "on the first --latent principal components of training spectra)")
    ap.add_argument("--pairs", default=None, help="artefact pairs (scripts/make_pnp_pairs.py .npz) mixed into every step")
    ap.add_argument("--pair-batch", type=int, default=4, help="artefact pairs per step with --pairs (default: %(default)s)")
    ap.add_argument("--pair-rotate", action="store_true", help="artefact pairs also turned by random quarter turns "
                    "(the dihedral group; default: flips only, the dispersion staying along x)")
    ap.add_argument("--pairs-val", default=None, help="validation artefact pairs (other scenes); with them the "
                    "weights file keeps the best stop-stage PSNR within --sel-tolerance of the start's selection score")
    ap.add_argument("--stage-net", action="store_true", help="round 6: a PnP-stage network trained on --pairs only "
                    "(no Gaussian cubes); the weights file keeps the best mean over stages of --pairs-val's output PSNR, "
                    "its metadata says stage = pnp")
    ap.add_argument("--sel-tolerance", type=float, default=0.2, help="dB the Gaussian selection score may lose against "
                    "the step-0 score for a checkpoint to be kept under --pairs-val (default: %(default)s)")
    ap.add_argument("--summary", type=int, metavar="EVERY", default=None,
                    help="print the validation curve of --out's train-log.jsonl (every EVERY steps, the best and the "
                         "last) as a Markdown table, and exit")
    a = ap.parse_args(argv)
    if a.summary is not None:
        return summary(pathlib.Path(a.out) / "train-log.jsonl", a.summary)
    for name in ("steps", "threads", "patch", "width", "latent", "val_every", "warmup", "new_per_step"):
        if getattr(a, name) < 1:
            ap.error(f"--{name.replace('_', '-')} must be at least 1 (got {getattr(a, name)})")
    if a.new_per_step % 2:
        ap.error(f"--new-per-step must be even (half measured-spectra, half uplifted-sRGB cubes), got {a.new_per_step}")
    if a.batch is not None and a.batch != a.new_per_step * WINDOW:
        ap.error(f"--batch must be {a.new_per_step * WINDOW} (the data window), got {a.batch}")
    if a.workers < 0 or (a.keep_every is not None and a.keep_every < 1):
        ap.error("--workers must be non-negative and --keep-every at least 1")
    try:
        dev = torch.device(a.device)
        torch.empty(1, device=dev) if dev.type != "cuda" else None
    except (RuntimeError, ValueError) as e:
        ap.error(f"--device {a.device!r}: {e}")
    if dev.type == "cuda" and not torch.cuda.is_available():
        ap.error(f"--device {a.device!r}: CUDA is not available here")
    if a.patch % 4:
        ap.error(f"--patch must be a multiple of 4 (got {a.patch})")
    if a.latent > len(BANDS_NM):
        ap.error(f"--latent must be at most the {len(BANDS_NM)} bands (got {a.latent})")
    if a.pair_batch < 1 or not a.sel_tolerance >= 0:
        ap.error("--pair-batch must be at least 1 and --sel-tolerance non-negative")
    if a.stage_net and not (a.pairs and a.pairs_val):
        ap.error("--stage-net needs --pairs and --pairs-val")
    if not (a.lr > 0 and a.lr_min >= 0 and a.clip > 0) or (a.minutes is not None and not a.minutes > 0):
        ap.error("--lr, --clip and --minutes must be positive, --lr-min non-negative")

    pairs, pairs_val = None, None
    try:
        if a.pairs:
            pairs = load_pairs(a.pairs)
            if min(pairs["inputs"].shape[2:]) < a.patch:
                ap.error(f"--pairs {a.pairs}: its cubes ({tuple(pairs['inputs'].shape[2:])}) are smaller than --patch {a.patch}")
        if a.pairs_val:
            pairs_val = load_pairs(a.pairs_val)
    except (FileNotFoundError, ValueError) as e:
        print(f"train_denoiser: error: {e}", file=sys.stderr)
        return 1
    torch.set_num_threads(a.threads)
    torch.manual_seed(a.seed)
    np.random.seed(a.seed)
    bands_nm = BANDS_NM
    out = pathlib.Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    wpath, lpath, spath = out / weights_name(len(bands_nm)), out / "train-log.jsonl", out / "train-state.pt"

    net = SpectralUNet(bands=len(bands_nm), width=a.width, latent=a.latent)
    init_sha, init_kind = None, None
    if a.init_spectral:
        import hashlib
        if a.init or a.resume:
            print("train_denoiser: error: --init-spectral is for a new network (not with --init or --resume)", file=sys.stderr)
            return 2
        try:
            src = load_weights(a.init_spectral, bands=len(bands_nm))
        except (FileNotFoundError, ValueError) as e:
            print(f"train_denoiser: error: --init-spectral: {e}", file=sys.stderr)
            return 1
        if src.latent != a.latent:
            print(f"train_denoiser: error: --init-spectral {a.init_spectral} has latent {src.latent}, this run asks for "
                  f"--latent {a.latent}", file=sys.stderr)
            return 2
        with torch.no_grad():
            for name in ("lat_enc", "lat_dec", "bypass"):
                getattr(net, name).weight.copy_(getattr(src, name).weight)
        init_sha = hashlib.sha256(pathlib.Path(a.init_spectral).read_bytes()).hexdigest()
        init_kind = "random U-Net; E, D and G (the linear spectral path) of a spectral-unet-v2 file (--init-spectral)"
    if a.init:
        import hashlib
        try:
            init, init_kind = init_network(a.init, len(bands_nm), a.latent, a.pca)
        except (FileNotFoundError, ValueError) as e:
            print(f"train_denoiser: error: --init: {e}", file=sys.stderr)
            return 1
        if (init.width, init.latent) != (a.width, a.latent):
            print(f"train_denoiser: error: --init {a.init} has width {init.width} and latent {init.latent}, this run "
                  f"asks for --width {a.width} --latent {a.latent}", file=sys.stderr)
            return 2
        net.load_state_dict(init.state_dict())
        init_sha = hashlib.sha256(pathlib.Path(a.init).read_bytes()).hexdigest()
    if a.freeze_spectral:
        net.lat_enc.weight.requires_grad_(False)
        net.lat_dec.weight.requires_grad_(False)
    step, best, elapsed0, sel0 = 0, -math.inf, 0.0, None
    st = None
    if a.resume:
        if not os.path.isfile(a.resume):
            print(f"train_denoiser: error: --resume {a.resume}: no such file", file=sys.stderr)
            return 1
        st = torch.load(a.resume, weights_only=False, map_location="cpu")
        made = (st.get("width"), st.get("latent"), st.get("patch"), st.get("seed"), st.get("freeze_spectral", False),
                st.get("pairs_sha256"), st.get("pair_batch"), st.get("new_per_step", NEW_PER_STEP))
        want = (a.width, a.latent, a.patch, a.seed, a.freeze_spectral, pairs and pairs["sha256"],
                a.pair_batch if pairs else None, a.new_per_step)
        if made != want:
            print(f"train_denoiser: error: --resume {a.resume} was made with (width, latent, patch, seed, "
                  f"freeze-spectral, pairs SHA-256, pair-batch, new-per-step) = {made}, this run asks for {want}",
                  file=sys.stderr)
            return 2
    source = None if a.stage_net else CubeSource(a.patch, a.new_per_step, a.workers)  # forks before any CUDA call
    net.to(dev)
    opt = torch.optim.Adam([p for p in net.parameters() if p.requires_grad], lr=a.lr)
    if st is not None:
        net.load_state_dict(st["model"])
        opt.load_state_dict(st["optim"])  # (moves the moments to the parameters' device)
        step, best, elapsed0 = st["step"], st["best"], st["elapsed_s"]
        sel0 = st.get("sel0")
        init_sha = st.get("init_weights_sha256", init_sha)
        init_kind = st.get("init_kind", init_kind)
    manifest = sources_manifest(bands_nm)
    manifest.update({
        "train_seeds": f"{TRAIN_SEED_BASE} + {a.new_per_step}*step + i, i < {a.new_per_step}; even i spectral, odd i rgb",
        "device": str(dev),
        "init_weights": "random (torch seed)" if init_sha is None else init_kind,
        "init_weights_sha256": init_sha,
        "train_seed_min": TRAIN_SEED_BASE, "val_seeds": val_seeds(), "val_sigmas": list(VAL_SIGMAS),
        "val_kinds": ["spectral", "rgb"], "patch": a.patch, "evaluation_scenes_used": [],
        "selection_set": {"kind": "rgb", "seeds": sel_seeds(), "size": SEL_SIZE, "rmin_px": list(SEL_RMIN_PX),
                          "textures": list(SEL_TEXTURES), "brightness_cycle": list(SEL_BRIGHTNESS),
                          "score": "mean over sigma of the mean PSNR over the selection cubes"},
        "latent": a.latent, "freeze_spectral": a.freeze_spectral,
        "artefact_pairs": None if pairs is None else {
            "file": pairs["path"], "sha256": pairs["sha256"], "count": int(pairs["inputs"].shape[0]),
            "per_step": a.pair_batch, "stage_net": a.stage_net,
            "augmentation": "random crop, flips, quarter turns" if a.pair_rotate else "random crop, flips",
            "sigma_per_stage": {n: float(pairs["sigma"][pairs["stage"] == i][0]) for i, n in enumerate(pairs["stage_names"])
                                if bool((pairs["stage"] == i).any())},
            "mean_err_per_stage": {n: float(pairs["err"][pairs["stage"].numpy() == i].mean())
                                   for i, n in enumerate(pairs["stage_names"]) if (pairs["stage"].numpy() == i).any()},
            "made_by": "scripts/make_pnp_pairs.py", "manifest": {k: v for k, v in pairs["manifest"].items() if k != "sources"}},
        "artefact_pairs_val": None if pairs_val is None else {
            "file": pairs_val["path"], "sha256": pairs_val["sha256"], "count": int(pairs_val["inputs"].shape[0]),
            "manifest": {k: v for k, v in pairs_val["manifest"].items() if k != "sources"},
            "rule": "best mean over stages of the output PSNR (stage network: no Gaussian constraint)" if a.stage_net else
            (f"best stop-stage PSNR among checkpoints whose selection score >= {a.sel_floor} dB" if a.sel_floor is not None
             else f"best stop-stage PSNR among checkpoints whose selection score >= step-0's - {a.sel_tolerance} dB")},
        "pca": {"components": a.pca or a.latent, "train_steps": PCA_STEPS, "size": PCA_SIZE}
        if init_kind and "principal" in init_kind else None,
    })
    (out / "train-manifest.json").write_text(json.dumps(manifest, indent=1) + "\n")

    to_dev = lambda c, n: (c.to(dev), {k: v.to(dev) for k, v in n.items()})
    clean_val, noisy_val = to_dev(*validation_set(a.patch, bands_nm))
    clean_rgb, noisy_rgb = to_dev(*validation_set(a.patch, bands_nm, "rgb"))
    clean_sel, noisy_sel = to_dev(*selection_set(bands_nm))
    if pairs_val is not None:
        pairs_val.update({k: pairs_val[k].to(dev) for k in ("inputs", "targets", "sigma")})
    t0 = time.time()
    log = open(lpath, "a")
    log.write(json.dumps({"event": "resume" if a.resume else "start", "step": step, "args": vars(a),
                          "init_weights_sha256": init_sha,
                          "params": sum(p.numel() for p in net.parameters()), "torch": torch.__version__}) + "\n")
    log.flush()
    losses = []

    def val_all() -> tuple:
        return (validate(net, clean_val, noisy_val), validate(net, clean_rgb, noisy_rgb),
                validate(net, clean_sel, noisy_sel), None if pairs_val is None else validate_pairs(net, pairs_val))

    def checkpoint(vals: tuple):
        nonlocal best, sel0
        val, val_rgb, val_sel, val_pairs = vals
        # Selection: the selection set's mean over σ (the two validation sets are logged, not used to select);
        # with --pairs-val, the stop-stage artefact PSNR among checkpoints that keep the selection score.
        mean = sum(val_sel.values()) / len(val_sel)
        if sel0 is None:
            sel0 = mean
        if a.stage_net:
            score = sum(val_pairs[n] for n in pairs_val["stage_names"]) / len(pairs_val["stage_names"])
        else:
            floor = sel0 - a.sel_tolerance if a.sel_floor is None else a.sel_floor
            score = mean if val_pairs is None else (val_pairs["stop"] if mean >= floor else -math.inf)
        improved = score > best
        if improved:
            best = score
            extra = {} if val_pairs is None else {"pnp_val_psnr_db": json.dumps(val_pairs),
                                                  "pnp_sigma_per_stage": json.dumps(
                (manifest["artefact_pairs"] or {}).get("sigma_per_stage") if a.stage_net
                else dict(zip(STAGE_NAMES, PAIR_SIGMA)))}
            if a.stage_net:
                extra["stage"] = "pnp"
                extra["pnp_schedule"] = json.dumps(pairs["manifest"].get("schedule"))
            save_weights(net, wpath, {"training_step": str(step), "val_psnr_db": json.dumps(val),
                                      "val_rgb_psnr_db": json.dumps(val_rgb), "sel_psnr_db": json.dumps(val_sel), **extra})
        if a.keep_every is not None and step % a.keep_every == 0:
            save_weights(net, out / f"ckpt-{step}.safetensors", {"training_step": str(step), "sel_psnr_db": json.dumps(val_sel),
                                                                  **({} if val_pairs is None else {"pnp_val_psnr_db": json.dumps(val_pairs)})})
        elapsed = elapsed0 + time.time() - t0
        rec = {"step": step, "elapsed_s": round(elapsed, 1), "lr": opt.param_groups[0]["lr"],
               "train_l1": (sum(losses) / len(losses)) if losses else None, "val_psnr_db": val,
               "val_rgb_psnr_db": val_rgb, "sel_psnr_db": val_sel,
               "sel_score_db": mean, "best": improved}
        if val_pairs is not None:
            rec["pnp_val_psnr_db"] = val_pairs
        log.write(json.dumps(rec) + "\n")
        log.flush()
        losses.clear()
        tmp = f"{spath}.tmp"
        torch.save({"model": net.state_dict(), "optim": opt.state_dict(), "step": step, "best": best,
                    "elapsed_s": elapsed, "width": a.width, "latent": a.latent, "patch": a.patch,
                    "freeze_spectral": a.freeze_spectral, "sel0": sel0,
                    "pairs_sha256": pairs and pairs["sha256"], "pair_batch": a.pair_batch if pairs else None,
                    "new_per_step": a.new_per_step,
                    "seed": a.seed, "init_weights_sha256": init_sha, "init_kind": init_kind}, tmp)
        os.replace(tmp, spath)
        print(f"step {step} val {val} rgb {val_rgb} selection {val_sel} score {mean:.2f} dB pnp {val_pairs}{' (best)' if improved else ''} "
              f"{elapsed / 60:.1f} min", flush=True)

    if step == 0:
        checkpoint(val_all())
    net.train()

    def optimise(noisy, sigma, target) -> bool:
        """One L1 Adam step at the schedule's learning rate, then the step count and the validation; False
        (with the error printed) on a non-finite loss."""
        nonlocal step
        loss = l1_step(opt, net.parameters(), lr_at(step, a.steps, a.lr, a.lr_min, a.warmup), a.clip, net(noisy, sigma), target)
        if loss is None:
            print(f"train_denoiser: error: non-finite loss at step {step}; the weights file keeps the best so far",
                  file=sys.stderr)
            if source is not None:
                source.close()
            return False
        losses.append(loss)
        step += 1
        if step % a.val_every == 0 or step == a.steps:
            checkpoint(val_all())
        return True

    while step < a.steps:
        if a.minutes is not None and time.time() - t0 > 60 * a.minutes:
            break
        g = torch.Generator().manual_seed(a.seed * 1_000_003 + step)
        if a.stage_net:
            noisy, sigma, target = (t.to(dev) for t in pair_batch(pairs, a.pair_batch, a.patch, g, a.pair_rotate))
            if not optimise(noisy, sigma, target):
                return 1
            continue
        clean = source.batch(step)
        g = torch.Generator().manual_seed(a.seed * 1_000_003 + step)
        # on CPU one generator draws the augmentation and then the pairs (as before); on another device the
        # augmentation's draws come from a generator there with the same seed
        gd = g if dev.type == "cpu" else torch.Generator(device=dev).manual_seed(a.seed * 1_000_003 + step)
        noisy, sigma, target = make_batch(clean.to(dev), gd)
        if pairs is not None:
            px, ps, pt = (t.to(dev) for t in pair_batch(pairs, a.pair_batch, a.patch, g, a.pair_rotate))
            noisy, sigma, target = torch.cat([noisy, px]), torch.cat([sigma, ps]), torch.cat([target, pt])
        if not optimise(noisy, sigma, target):
            return 1
    if step % a.val_every and step != a.steps:
        checkpoint(val_all())
    if a.keep_every is not None and not (out / f"ckpt-{step}.safetensors").exists():
        save_weights(net, out / f"ckpt-{step}.safetensors", {"training_step": str(step)})  # the last step's, too
    log.close()
    if source is not None:
        source.close()
    if best == -math.inf:
        print(f"train_denoiser: error: no checkpoint met the selection rule ({manifest['artefact_pairs_val']['rule']}); "
              f"no weights file written", file=sys.stderr)
        return 1
    load_weights(wpath, bands=len(bands_nm))  # the file written reads back
    print(f"done at step {step}: best validation mean {best:.2f} dB in {wpath}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
