#!/usr/bin/env python3
"""Makes the *artefact pairs* of the PnP fine-tuning (issue 22): what the learned denoiser is given inside
``pnp-gap`` — the GAP-TV iterate of a CASSI reconstruction — beside the truth, from procedural training scenes.

    .venv/bin/python scripts/make_pnp_pairs.py --out target/pnp-pairs/train.npz --first 0 --count 96
    .venv/bin/python scripts/make_pnp_pairs.py --out target/pnp-pairs/val.npz --split val --count 16

For each scene (a :func:`diffcassi.deadleaves.dead_leaves` cube, ``--size``², 28 bands 450–650 nm; two in three
uplifted-sRGB leaves, the evaluation scenes' spectral family, one in three measured-spectra leaves) and each
preset of ``--presets`` (SP, mSP): the realistic setting of docs/study.md — 112 planes, 20 rays per pixel per
plane (acquisition seed ``s``), Airy 2.5 px, a mask that is half the time a random crop of the paper's mask
(``--mask``) and half the time a random binary mask (opening 0.5) — rendered by :func:`diffcassi.render`; the
exact operator traced with another seed (``s + 1``, as ``reconstruct`` does), δ by
:func:`diffcassi.monte_carlo_noise_norm`. Then ``pnp-gap`` with an **identity network** (a
``spectral-unet-v2`` file whose output is its input: D = 0, G = I) returns exactly the iterate x the network
would be given at its first call — the GAP data step after GAP-TV's phase — for a TV phase that ends at GAP-TV's
own stop (stage ``stop``, the default PnP) or is capped at half of it (stage ``half``, an earlier iterate).
A pair is (x/p, truth/p) with p = max x (the solver's normalisation when the committed round-4 weights were
trained on these pairs; the solver now leaves out outliers above 1.5 × the 0.999 quantile,
``recon::solver::NetworkScale``, which lowers p on spiky iterates — +0.00 to +0.08 dB on PnP, docs/study.md),
float32 (B, H, W), with its RMSE/peak
``err`` (= ‖x − truth‖_rms / p, known here only: the network's σ input is the per-stage constant of
``scripts/train_denoiser.py``, available at inference).

Scene seeds: train ``PAIR_SEED_BASE + i`` (``--split train``), validation ``PAIR_VAL_SEED_BASE + i`` (``--split
val``): disjoint from each other and from the Gaussian training, validation and selection seeds of
``train_denoiser.py`` (tested); no evaluation scene or photograph is read. Deterministic (every seed fixed); one
``.npz`` with ``inputs`` (N, B, H, W), ``targets``, ``peak``, ``err``, ``stage`` (0 stop, 1 half), ``preset``
(0 SP, 1 mSP), ``scene_seed``, ``tv_iterations`` (K_TV), ``tv_error`` (ê) and a JSON ``manifest``.
"""
from __future__ import annotations

import argparse
import json
import pathlib
import sys
import tempfile
import time

import numpy as np

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import diffcassi  # noqa: E402
from diffcassi.deadleaves import BANDS_NM, dead_leaves, sources_manifest  # noqa: E402

#: Scene seeds of the artefact pairs (train / validation); disjoint from train_denoiser.py's seeds (0–15,
#: 1000–1015, ≥ 1 000 000 + 2·step with step < 500 000 in practice) — tested.
PAIR_SEED_BASE = 5_000_000
PAIR_VAL_SEED_BASE = 6_000_000
PRESETS = ("sp", "msp")
STAGES = ("stop", "half")
RAYS, PLANES = 20, 112
#: The TV phase's cap (``PNP_TV_WARMUP`` of ``recon::solver``): the identity run is the TV phase plus one call
#: (explicit: ``pnp-gap``'s default network phase has several calls since round 6: 20, then 5 in round 7).
TV_CAP = 300


def _sha256(path: str) -> str:
    import hashlib
    return hashlib.sha256(pathlib.Path(path).read_bytes()).hexdigest()


def scene_kind(i: int) -> str:
    """Two in three uplifted-sRGB leaves (the evaluation scenes' spectral family), one in three measured spectra."""
    return "spectral" if i % 3 == 2 else "rgb"


def identity_weights(path: pathlib.Path, bands: int) -> None:
    """A spectral-unet-v2 file whose network is the identity (D = 0, G = I): ``pnp-gap`` with it returns the
    iterate the network is given (× p / p: exact to f32 rounding)."""
    import torch
    from diffcassi.denoiser import SpectralUNet, save_weights
    net = SpectralUNet(bands=bands, width=32, latent=12)
    with torch.no_grad():
        net.lat_dec.weight.zero_()
        net.bypass.weight.copy_(torch.eye(bands).view(bands, bands, 1, 1))
    save_weights(net, path, {"note": "identity (make_pnp_pairs.py)"})


def scene_mask(rng: np.random.Generator, paper: np.ndarray, size: int) -> tuple:
    """A random crop of the paper's mask (p = 0.5) or a random binary mask of opening 0.5."""
    if rng.random() < 0.5:
        y0, x0 = (int(rng.integers(0, n - size + 1)) for n in paper.shape)
        return np.ascontiguousarray(paper[y0:y0 + size, x0:x0 + size], dtype=np.float32), f"paper crop ({y0}, {x0})"
    return (rng.random((size, size)) < 0.5).astype(np.float32), "random 0.5"


def network_scale(x: np.ndarray) -> float:
    """The PnP solvers' input scale p of ``x`` (``recon::solver::NetworkScale``): the largest value ≤ 1.5 × the
    0.999 quantile (order statistic k = round((n − 1)·0.999)); 1 when it is not positive."""
    v = np.ascontiguousarray(x, dtype=np.float32).ravel()
    k = int(round((v.size - 1) * 0.999))
    q = np.partition(v, k)[k]
    bound = np.float32(1.5) * q
    mx = v.max()
    p = mx if mx <= bound else max(q, v[v <= bound].max())
    return float(p) if np.isfinite(p) and p > 0 else 1.0


def sigma_schedule(s1: float, s2: float, n: int) -> list:
    """σ of the n network calls, geometric from s1 to s2 (``recon::solver::sigma_schedule``, f32 as there)."""
    if n <= 1:
        return [float(np.float32(s1))]
    return [float(np.float32(np.float32(s1) * (np.float64(np.float32(s2)) / np.float64(np.float32(s1))) ** (j / (n - 1))))
            for j in range(n)]


def gap_rollout(op, y: np.ndarray, theta0: np.ndarray, x1: np.ndarray, net, sigmas, accelerated: bool = True,
                transforms=None):
    """The network phase of ``pnp-gap`` in NumPy/PyTorch, from GAP-TV's stopped iterate θ₀ (= ``gap-tv``'s result,
    (H, W, B)) and the first network input x₁ (= ``pnp-gap`` with the identity network): θ_k = p·N(x_k/p, σ_k)
    (p :func:`network_scale`), then GAP's data step with D = diag(ΦΦᵀ𝟙) (guard 1e-6·max d, λ = 1). Accelerated:
    x_{k+1} = θ_k + h_{k+1} − ΦᵀD⁻¹Φθ_k with h = ΦᵀD⁻¹ỹ, h_{k+1} = h_k + ΦᵀD⁻¹(y − Φθ_k) and h₁ recovered from
    x₁ = θ₀ + h₁ − ΦᵀD⁻¹Φθ₀ (exact up to f32 rounding); plain: x_{k+1} = θ_k + ΦᵀD⁻¹(y − Φθ_k). Returns the
    inputs [x₁, …, x_n] of the n = len(sigmas) calls and the output θ_n (equal to the Rust solver's to f32 and
    the two inferences' 1e-4: checked by ``--check``). ``transforms``: equivariant PnP, one (quarter turns,
    flip) per call (``diffcassi.denoiser.dihedral_draw``), θ_k = p·g⁻¹N(g·x_k/p, σ_k)."""
    import torch
    from diffcassi.denoiser import denoise, transformed_denoise
    d = op.apply(op.adjoint(np.ones(op.image_shape, np.float32)))
    dinv = np.where(d > np.float32(1e-6) * d.max(), np.float32(1.0) / np.maximum(d, np.float32(1e-30)), 0).astype(np.float32)
    ptd = lambda r: op.adjoint(np.ascontiguousarray(r * dinv, dtype=np.float32))  # ΦᵀD⁻¹ r
    x = np.ascontiguousarray(x1, dtype=np.float32)
    h = (x - theta0) + ptd(op.apply(np.ascontiguousarray(theta0, dtype=np.float32)))
    inputs, theta = [], None
    for j, s in enumerate(sigmas):
        inputs.append(x)
        p = network_scale(x)
        with torch.no_grad():
            t = torch.from_numpy(np.ascontiguousarray(x.transpose(2, 0, 1) / np.float32(p)))[None]
            o = denoise(net, t, float(s)) if transforms is None else transformed_denoise(net, t, float(s), transforms[j])
            theta = np.ascontiguousarray(o[0].numpy().transpose(1, 2, 0) * np.float32(p))
        if j + 1 == len(sigmas):
            break
        phit = op.apply(theta)
        if accelerated:
            h = h + ptd(y - phit)
            x = np.ascontiguousarray(theta + h - ptd(phit), dtype=np.float32)
        else:
            x = np.ascontiguousarray(theta + ptd(y - phit), dtype=np.float32)
    return inputs, theta


def training_scene(seed: int, kind: str, size: int, paper: np.ndarray):
    """The dead-leaves cube of ``seed`` ((B, H, W), peak 1), the same as a scene (H, W, B), and its mask (drawn
    with ``seed``'s generator) with the mask's description."""
    cube = dead_leaves(seed, size, BANDS_NM, kind=kind)
    scene = np.ascontiguousarray(cube.transpose(1, 2, 0))
    mask, mask_desc = scene_mask(np.random.default_rng(seed), paper, size)
    return cube, scene, mask, mask_desc


def acquire(preset: str, seed: int, scene: np.ndarray, mask: np.ndarray, size: int):
    """The realistic-setting acquisition of ``scene`` (H, W, B) through ``preset`` (Monte-Carlo seed 2·seed), the
    exact operator of seed 2·seed + 1, and δ from the Monte-Carlo model: (op, y float32, δ)."""
    system = diffcassi.System.preset(preset)
    acq_seed = 2 * seed
    y, _ = diffcassi.render(system, scene, list(BANDS_NM), mask, rays=RAYS, planes=PLANES, seed=acq_seed)
    op = diffcassi.exact(system, size, size, mask, rays=RAYS, planes=PLANES, seed=acq_seed + 1)
    y32 = np.ascontiguousarray(y, dtype=np.float32)
    delta = diffcassi.monte_carlo_noise_norm(y32, RAYS, RAYS, PLANES / len(BANDS_NM))
    return op, y32, delta


def pairs_of_scene(seed: int, kind: str, size: int, paper: np.ndarray, ident: str, threads: int,
                   stages=STAGES):
    cube, scene, mask, mask_desc = training_scene(seed, kind, size, paper)
    out = []
    for pi, preset in enumerate(PRESETS):
        op, y32, delta = acquire(preset, seed, scene, mask, size)
        k_stop = None
        for si, stage in enumerate(stages):
            cap = 300 if stage == "stop" else max(1, k_stop // 2)
            x, rec = diffcassi.reconstruct(op, y32, "pnp-gap", denoiser=ident, noise_norm=delta, tv_warmup=cap,
                                           iterations=cap + 1, discrepancy=0.0, tolerance=0.0)
            tw = rec["denoiser"]["tv_warmup"]  # the TV phase's record (docs/reconstruction.md)
            k = int(tw["iterations_run"])
            if stage == "stop":
                k_stop = k
            x = x.transpose(2, 0, 1)  # (B, H, W)
            p = float(x.max()) if x.max() > 0 else 1.0
            err = float(np.sqrt(np.mean((x - cube) ** 2)) / p)
            out.append(dict(inputs=(x / p).astype(np.float32), targets=(cube / p).astype(np.float32), peak=p,
                            err=err, stage=si, preset=pi, scene_seed=seed, tv_iterations=k,
                            tv_error=float(tw.get("tv_error_estimate") or np.nan), mask=mask_desc, kind=kind))
    return out


def schedule_pairs_of_scene(seed: int, kind: str, size: int, paper: np.ndarray, ident: str, net, sigmas):
    """Round 6 (``--schedule``): the inputs of every network call of a multi-call ``pnp-gap`` schedule run with
    ``net`` (DAgger-like: the calls before call k are the current stage network's), one pair per call and preset;
    ``sigma`` the schedule's σ_k, ``stage`` = k − 1, the scale p the solver's (:func:`network_scale`)."""
    cube, scene, mask, mask_desc = training_scene(seed, kind, size, paper)
    out = []
    for pi, preset in enumerate(PRESETS):
        op, y32, delta = acquire(preset, seed, scene, mask, size)
        theta0, _ = diffcassi.reconstruct(op, y32, "gap-tv", noise_norm=delta)
        x1, rec = diffcassi.reconstruct(op, y32, "pnp-gap", denoiser=ident, noise_norm=delta, discrepancy=0.0,
                                        tolerance=0.0, tv_warmup=TV_CAP, iterations=TV_CAP + 1)
        k_tv = int(rec["denoiser"]["tv_warmup"]["iterations_run"])
        inputs, _ = gap_rollout(op, y32, theta0, x1, net, sigmas)
        for si, x in enumerate(inputs):
            x = x.transpose(2, 0, 1)
            p = network_scale(x)
            err = float(np.sqrt(np.mean((x - cube) ** 2)) / p)
            out.append(dict(inputs=(x / p).astype(np.float32), targets=(cube / p).astype(np.float32), peak=p,
                            err=err, stage=si, preset=pi, scene_seed=seed, tv_iterations=k_tv, sigma=sigmas[si],
                            tv_error=float(rec["denoiser"]["tv_warmup"].get("tv_error_estimate") or np.nan),
                            mask=mask_desc, kind=kind))
    return out


def check_rollout(weights: str, sigmas, size: int = 32, equivariant_seed=None) -> float:
    """Max |θ_rollout − θ_Rust| / peak of :func:`gap_rollout` against ``pnp-gap`` with the same network and
    schedule (no early stop), on a small dead-leaves scene through SP; equivariant PnP with ``equivariant_seed``
    (the rollout draws the transforms with ``diffcassi.denoiser.dihedral_draw``), else off in both."""
    from diffcassi.denoiser import dihedral_draw, load_weights
    cube = dead_leaves(PAIR_VAL_SEED_BASE + 999, size, BANDS_NM, kind="rgb")
    scene = np.ascontiguousarray(cube.transpose(1, 2, 0))
    mask = (np.random.default_rng(0).random((size, size)) < 0.5).astype(np.float32)
    system = diffcassi.System.preset("sp")
    y, _ = diffcassi.render(system, scene, list(BANDS_NM), mask, rays=RAYS, planes=PLANES, seed=0)
    op = diffcassi.exact(system, size, size, mask, rays=RAYS, planes=PLANES, seed=1)
    y32 = np.ascontiguousarray(y, dtype=np.float32)
    delta = diffcassi.monte_carlo_noise_norm(y32, RAYS, RAYS, PLANES / len(BANDS_NM))
    theta0, _ = diffcassi.reconstruct(op, y32, "gap-tv", noise_norm=delta)
    with tempfile.TemporaryDirectory() as tmp:
        ident = str(pathlib.Path(tmp) / "identity.safetensors")
        identity_weights(pathlib.Path(ident), len(BANDS_NM))
        x1, _ = diffcassi.reconstruct(op, y32, "pnp-gap", denoiser=ident, noise_norm=delta, discrepancy=0.0, tolerance=0.0,
                                        tv_warmup=TV_CAP, iterations=TV_CAP + 1, equivariant=False)
    n = len(sigmas)
    eq = equivariant_seed is not None
    tr = [dihedral_draw(equivariant_seed, j + 1, square=True) for j in range(n)] if eq else None
    _, theta = gap_rollout(op, y32, theta0, x1, load_weights(weights, bands=len(BANDS_NM)), sigmas, transforms=tr)
    ref, _ = diffcassi.reconstruct(op, y32, "pnp-gap", denoiser=weights, noise_norm=delta, discrepancy=0.0,
                                   tolerance=0.0, tv_warmup=TV_CAP, iterations=TV_CAP + n, sigma_max=sigmas[0],
                                   sigma_min=sigmas[-1], equivariant=eq, **({"equivariant_seed": equivariant_seed} if eq else {}))
    return float(np.abs(theta - ref).max() / ref.max())


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", required=True, help="the .npz to write (atomically)")
    ap.add_argument("--split", choices=("train", "val"), default="train")
    ap.add_argument("--first", type=int, default=0, help="first scene index")
    ap.add_argument("--count", type=int, default=64, help="number of scenes (each gives 2 presets × 2 stages)")
    ap.add_argument("--size", type=int, default=64, help="scene size (pixels, multiple of 4)")
    ap.add_argument("--mask", default=str(ROOT.parent / "shared/reference/paper_mask_512.npy"),
                    help="the paper's mask (.npy), cropped at random places (default: %(default)s)")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--minutes", type=float, default=None, help="stop after this wall time (writes what is done)")
    ap.add_argument("--schedule", default=None, metavar="N:S1:S2", help="round 6: one pair per network call of a "
                    "pnp-gap schedule of N calls, σ S1 → S2 (geometric), the calls run with --weights")
    ap.add_argument("--weights", default=str(ROOT / "src/recon/prior/weights/spectral-unet-v2-28.safetensors"),
                    help="with --schedule: the network the schedule's calls run (default: %(default)s)")
    ap.add_argument("--stop-only", action="store_true", help="only the stop stage (the default PnP's first network "
                    "input; half the solver runs of each scene)")
    ap.add_argument("--float16", action="store_true", help="store inputs and targets as float16, deflate-compressed "
                    "(≈ 0.3 MB a 64² pair instead of 0.9: what travels to a GPU machine; train_denoiser.py reads float32)")
    ap.add_argument("--check", action="store_true", help="with --schedule: compare the rollout with the Rust pnp-gap "
                    "on a 32² scene (max |difference| / peak) and exit")
    a = ap.parse_args(argv)
    sigmas = None
    if a.schedule is not None:
        try:
            n, s1, s2 = a.schedule.split(":")
            n, s1, s2 = int(n), float(s1), float(s2)
            if not (1 <= n <= 20 and 0 < s2 <= s1 <= 1):
                raise ValueError
        except ValueError:
            ap.error(f"--schedule {a.schedule!r}: expected N:S1:S2 with 1 ≤ N ≤ 20 and 0 < S2 ≤ S1 ≤ 1")
        sigmas = sigma_schedule(s1, s2, n)
        if a.check:
            diffcassi.set_num_threads(a.threads)
            print(f"rollout vs pnp-gap, {n} calls σ {sigmas}: max |Δθ| / peak = {check_rollout(a.weights, sigmas):.2e}")
            return 0
    if a.count < 1 or a.first < 0 or a.size < 16 or a.size % 4:
        ap.error("--count ≥ 1, --first ≥ 0, --size ≥ 16 and a multiple of 4")
    try:
        paper = np.load(a.mask).astype(np.float32)
    except (OSError, ValueError) as e:
        print(f"make_pnp_pairs: error: --mask {a.mask}: {e}", file=sys.stderr)
        return 1
    if paper.ndim != 2 or min(paper.shape) < a.size:
        print(f"make_pnp_pairs: error: --mask {a.mask}: shape {paper.shape} is not 2-D of at least {a.size}²",
              file=sys.stderr)
        return 1
    diffcassi.set_num_threads(a.threads)
    base = PAIR_SEED_BASE if a.split == "train" else PAIR_VAL_SEED_BASE
    t0 = time.time()
    rows = []
    run_stages = STAGES[:1] if a.stop_only else STAGES
    per_scene = len(PRESETS) * (len(run_stages) if sigmas is None else len(sigmas))
    if sigmas is not None:
        import torch
        from diffcassi.denoiser import load_weights
        torch.set_num_threads(a.threads)
        torch.manual_seed(0)
        net = load_weights(a.weights, bands=len(BANDS_NM))
    with tempfile.TemporaryDirectory() as tmp:
        ident = str(pathlib.Path(tmp) / "identity.safetensors")
        identity_weights(pathlib.Path(ident), len(BANDS_NM))
        for i in range(a.first, a.first + a.count):
            if a.minutes is not None and time.time() - t0 > 60 * a.minutes:
                break
            if sigmas is None:
                rows += pairs_of_scene(base + i, scene_kind(i), a.size, paper, ident, a.threads, run_stages)
            else:
                rows += schedule_pairs_of_scene(base + i, scene_kind(i), a.size, paper, ident, net, sigmas)
            last = rows[-per_scene:]
            print(f"scene {i} ({scene_kind(i)}): err " + " ".join(f"{r['err']:.3f}" for r in last)
                  + f", K_TV {[r['tv_iterations'] for r in last]}, {time.time() - t0:.0f} s", flush=True)
    if not rows:
        print("make_pnp_pairs: error: no scene done within --minutes", file=sys.stderr)
        return 1
    arrays = {k: np.stack([r[k] for r in rows]).astype(np.float16 if a.float16 else np.float32) for k in ("inputs", "targets")}
    arrays.update({k: np.array([r[k] for r in rows]) for k in ("peak", "err", "stage", "preset", "scene_seed",
                                                                   "tv_iterations", "tv_error")})
    stages = list(run_stages)
    if sigmas is not None:
        arrays["sigma"] = np.array([r["sigma"] for r in rows], dtype=np.float32)
        stages = [f"call{k + 1}" for k in range(len(sigmas))]
    manifest = {"split": a.split, "seed_base": base, "first": a.first, "scenes": len(rows) // per_scene, "size": a.size,
                "presets": list(PRESETS), "stages": stages, "rays": RAYS, "planes": PLANES,
                "acquisition_seed": "2*scene_seed", "operator_seed": "2*scene_seed + 1",
                "schedule": None if sigmas is None else {"calls": len(sigmas), "sigmas": sigmas, "accelerated": True,
                                                          "weights": a.weights, "weights_sha256": _sha256(a.weights)},
                "mask": a.mask, "masks": [r["mask"] for r in rows[::per_scene]],
                "kinds": [r["kind"] for r in rows[::per_scene]],
                "image_files": [], "evaluation_scenes_used": [], "wall_s": round(time.time() - t0, 1),
                "sources": sources_manifest(BANDS_NM)}
    out = pathlib.Path(a.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(out.name + ".tmp.npz")
    (np.savez_compressed if a.float16 else np.savez)(tmp, manifest=np.array(json.dumps(manifest)), **arrays)
    tmp.replace(out)
    print(f"wrote {len(rows)} pairs of {len(rows) // per_scene} scenes to {out} in {time.time() - t0:.0f} s; "
          f"err by stage: " + ", ".join(f"{s} {arrays['err'][arrays['stage'] == i].mean():.3f}"
                                         for i, s in enumerate(stages)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
