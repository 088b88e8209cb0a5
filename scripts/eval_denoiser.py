#!/usr/bin/env python3
"""Evaluates the learned denoiser on natural scenes it never saw, against Chambolle TV.

The scenes are the photographs of ``data/scenes/`` uplifted to 28-band reflectance cubes (450–650 nm) by the
project's Smits uplift (``diffcassi.load_scene``, the same as ``diffcassi make-scene``), peak-normalised to 1;
the training data (``diffcassi.deadleaves``) contains none of them. Each cube gets white Gaussian noise of
σ ∈ {0.02, 0.05, 0.1} (fixed seeds) and is denoised by

* the network (``diffcassi.denoiser.load_weights`` + ``denoise``, σ given; mean-colour neutralisation on unless
  ``--no-neutral``, the geometric self-ensemble with ``--ensemble``), and
* Chambolle's TV denoiser, a NumPy transcription of ``src/recon/tv.rs`` (that Rust function is not exposed to
  Python): isotropic, vectorial coupling (the project's default; ``--tv-per-band`` also tries per-band TV and
  reports the better), τ = 1/4, ``--tv-iterations`` steps from p = 0; its weight is tuned per σ on a grid for the
  best mean PSNR over these very scenes (an oracle choice, favourable to TV).

PSNR is 10·log10(1/MSE) over the whole cube (peak 1), averaged over the scenes. ``--diagnose`` adds, per scene,
the measurements of round 5 (src/recon/prior/MODEL.md): the E/D projection's own PSNR on the clean cube, the
network on a *constant* cube of the scene's mean spectrum (PSNR and the per-band bias's RMS: a denoiser should
return a constant unchanged) and on the clean cube, and the mean error per band (RMS over bands) of the output.

    .venv/bin/python scripts/eval_denoiser.py --json /tmp/eval.json
"""
from __future__ import annotations

import argparse
import json
import pathlib
import sys
import time

import numpy as np
import torch

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

SIGMAS = (0.02, 0.05, 0.1)
TV_WEIGHTS = (0.01, 0.02, 0.035, 0.05, 0.075, 0.1, 0.15, 0.2, 0.3, 0.45, 0.6)
NOISE_SEED = 20260


def tv_denoise(f: np.ndarray, weight: float, iterations: int, vectorial: bool = True) -> np.ndarray:
    """Chambolle (2004) TV denoising of a (B, H, W) cube, as ``src/recon/tv.rs``: the dual fixed point
    p ← (p + τ∇(div p − f/w)) / (1 + τ|∇(div p − f/w)|), τ = 1/4, u = f − w·div p; forward differences with
    Neumann boundary, div = −∇ᵀ; |∇| over the bands jointly (vectorial) or per band."""
    if weight <= 0 or iterations <= 0:
        return f.copy()
    tau = 0.25
    p1 = np.zeros_like(f)  # along columns (x)
    p2 = np.zeros_like(f)  # along rows (y)

    def div(p1, p2):
        d = p1.copy()
        d[:, :, 1:] -= p1[:, :, :-1]
        d += p2
        d[:, 1:, :] -= p2[:, :-1, :]
        return d

    g1, g2 = np.zeros_like(f), np.zeros_like(f)
    for _ in range(iterations):
        z = div(p1, p2) - f / weight
        g1[:, :, :-1] = z[:, :, 1:] - z[:, :, :-1]
        g2[:, :-1, :] = z[:, 1:, :] - z[:, :-1, :]
        mag = g1 * g1 + g2 * g2
        norm = np.sqrt(mag.sum(0, keepdims=True)) if vectorial else np.sqrt(mag)
        d = 1.0 / (1.0 + tau * norm)
        p1 = (p1 + tau * g1) * d
        p2 = (p2 + tau * g2) * d
    return f - weight * div(p1, p2)


def psnr_db(x: np.ndarray, ref: np.ndarray) -> float:
    return float(10 * np.log10(1.0 / np.mean((x.astype(np.float64) - ref) ** 2)))


def diagnose(net, run, clean: np.ndarray, out: np.ndarray) -> dict:
    """Round 5's per-scene measurements (module docs): ``run(cube)`` is the inference under test at this σ."""
    c = clean.astype(np.float64)
    e = net.lat_enc.weight.detach().double().numpy()[:, :, 0, 0]  # (K, B)
    d = net.lat_dec.weight.detach().double().numpy()[:, :, 0, 0]  # (B, K)
    proj = np.einsum("bk,kc,chw->bhw", d, e, c)
    const = np.broadcast_to(c.mean(axis=(1, 2), keepdims=True), c.shape)
    with torch.no_grad():
        oc, oz = run(const).astype(np.float64), run(c).astype(np.float64)
    band_rms = lambda err: float(np.sqrt(np.mean(err.mean(axis=(1, 2)) ** 2)))
    return {"projection_db": psnr_db(proj, c), "constant_db": psnr_db(oc, const), "constant_band_bias": band_rms(oc - const),
            "clean_in_db": psnr_db(oz, c), "band_bias": band_rms(out.astype(np.float64) - c)}


def load_scenes(folder: pathlib.Path, size: int):
    import diffcassi
    from diffcassi.deadleaves import BANDS_NM
    scenes = {}
    for png in sorted(folder.glob("*.png")):
        cube, _ = diffcassi.load_scene(png, list(BANDS_NM))
        cube = np.asarray(cube, dtype=np.float32)  # (H, W, B)
        h, w = cube.shape[:2]
        if size and size < min(h, w):  # centre crop
            y0, x0 = (h - size) // 2, (w - size) // 2
            cube = cube[y0:y0 + size, x0:x0 + size]
        cube = np.ascontiguousarray(cube.transpose(2, 0, 1))
        scenes[png.stem] = cube / cube.max()
    if not scenes:
        raise SystemExit(f"eval_denoiser: error: no *.png scenes in {folder}")
    return scenes


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--weights", default=str(ROOT / "src/recon/prior/weights/spectral-unet-v2-28.safetensors"))
    ap.add_argument("--scenes", default=str(ROOT / "data/scenes"), help="folder of RGB photographs (*.png)")
    ap.add_argument("--size", type=int, default=128, help="centre crop (pixels); 0 = whole image (256)")
    ap.add_argument("--tv-iterations", type=int, default=100)
    ap.add_argument("--tv-per-band", action="store_true", help="also try per-band TV (twice the TV time)")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--no-neutral", action="store_true", help="no mean-colour neutralisation (rounds 1–4's inference)")
    ap.add_argument("--ensemble", action="store_true", help="the geometric self-ensemble (8 dihedral transforms, 8× time)")
    ap.add_argument("--diagnose", action="store_true", help="per-scene diagnostics (projection, constant-cube bias)")
    ap.add_argument("--json", default=None, help="write the results here")
    ap.add_argument("--tv-from", default=None, metavar="JSON",
                    help="reuse the TV rows of an earlier --json result (same scenes, size, TV settings; checked) "
                         "instead of recomputing them: for evaluating many checkpoints")
    a = ap.parse_args(argv)
    if a.size < 0 or a.tv_iterations < 1 or a.threads < 1:
        ap.error("--size must be ≥ 0, --tv-iterations and --threads ≥ 1")
    torch.set_num_threads(a.threads)
    from diffcassi.denoiser import denoise, load_weights
    try:
        net = load_weights(a.weights, bands=28)
    except (FileNotFoundError, ValueError) as e:
        print(f"eval_denoiser: error: {e}", file=sys.stderr)
        return 1
    scenes = load_scenes(pathlib.Path(a.scenes), a.size)
    tv_cache = None
    if a.tv_from:
        try:
            tv_cache = json.loads(pathlib.Path(a.tv_from).read_text())
            same = (tv_cache["scenes"] == list(scenes) and tv_cache["size"] == a.size
                    and tv_cache["tv_iterations"] == a.tv_iterations and tv_cache["tv_weight_grid"] == list(TV_WEIGHTS)
                    and tv_cache.get("noise_seed") == NOISE_SEED and set(tv_cache["sigmas"]) == {f"{s:g}" for s in SIGMAS}
                    and tv_cache.get("tv_per_band", False) == a.tv_per_band)
        except (OSError, ValueError, KeyError, TypeError) as e:
            print(f"eval_denoiser: error: --tv-from {a.tv_from}: {e}", file=sys.stderr)
            return 1
        if not same:
            print(f"eval_denoiser: error: --tv-from {a.tv_from} was made with other scenes, size, noise or TV settings",
                  file=sys.stderr)
            return 1
    t0 = time.time()
    rows = {}
    for si, sigma in enumerate(SIGMAS):
        noisy = {}
        for k, (name, c) in enumerate(scenes.items()):
            rng = np.random.default_rng([NOISE_SEED, si, k])
            noisy[name] = (c + sigma * rng.standard_normal(c.shape)).astype(np.float32)
        r = {"noisy": float(np.mean([psnr_db(noisy[n], scenes[n]) for n in scenes]))}
        run = lambda c, s=sigma: denoise(net, torch.from_numpy(np.ascontiguousarray(c, dtype=np.float32))[None], s,
                                         neutral=not a.no_neutral, ensemble=a.ensemble)[0].numpy()
        with torch.no_grad():
            outs = {n: run(noisy[n]) for n in scenes}
        net_psnr = {n: psnr_db(outs[n], scenes[n]) for n in scenes}
        r["net"], r["net_per_scene"] = float(np.mean(list(net_psnr.values()))), net_psnr
        if a.diagnose:
            r["diagnose"] = {n: diagnose(net, run, scenes[n], outs[n]) for n in scenes}
        best = None
        if tv_cache is not None:
            c = tv_cache["sigmas"][f"{sigma:g}"]
            best = (c["tv"], c["tv_weight"], c["tv_coupling"], c["tv_per_scene"])
        for vectorial in ((True, False) if a.tv_per_band and best is None else (True,) if best is None else ()):
            for w in TV_WEIGHTS:
                per = {n: psnr_db(tv_denoise(noisy[n], w, a.tv_iterations, vectorial), scenes[n]) for n in scenes}
                m = float(np.mean(list(per.values())))
                if best is None or m > best[0]:
                    best = (m, w, "vectorial" if vectorial else "per_band", per)
        r["tv"], r["tv_weight"], r["tv_coupling"], r["tv_per_scene"] = best
        r["gain_db"] = r["net"] - r["tv"]
        rows[f"{sigma:g}"] = r
        print(f"σ={sigma:g}: noisy {r['noisy']:.2f} dB, TV {r['tv']:.2f} dB (w={r['tv_weight']}, {r['tv_coupling']}), "
              f"network {r['net']:.2f} dB, gain {r['gain_db']:+.2f} dB", flush=True)
        print("  per scene, network / TV: " + ", ".join(f"{n} {net_psnr[n]:.2f} / {r['tv_per_scene'][n]:.2f}" for n in scenes))
        for n, d in r.get("diagnose", {}).items():
            print(f"  {n}: " + ", ".join(f"{k} {v:.4g}" for k, v in d.items()))
    res = {"scenes": list(scenes), "size": a.size, "weights": a.weights, "neutral": not a.no_neutral,
           "ensemble": a.ensemble, "tv_iterations": a.tv_iterations,
           "tv_weight_grid": list(TV_WEIGHTS), "noise_seed": NOISE_SEED, "tv_per_band": a.tv_per_band,
           "tv_from": a.tv_from, "sigmas": rows, "elapsed_s": round(time.time() - t0, 1)}
    print("\n| σ | noisy | TV (tuned weight, coupling) | network | gain |\n|---|---|---|---|---|")
    for s, r in rows.items():
        print(f"| {s} | {r['noisy']:.2f} | {r['tv']:.2f} ({r['tv_weight']}, {r['tv_coupling']}) | {r['net']:.2f} "
              f"| {r['gain_db']:+.2f} |")
    if a.json:
        pathlib.Path(a.json).write_text(json.dumps(res, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
