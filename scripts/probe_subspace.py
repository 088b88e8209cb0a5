#!/usr/bin/env python3
"""Probe (src/recon/prior/MODEL.md, round 8): does constraining GAP-TV to the denoiser's spectral subspace help?

A NumPy twin of ``gap-tv`` (accelerated GAP, D = diag(ΦΦᵀ𝟙), Chambolle's vectorial TV with weight 0.1 and 5
iterations, 300 iterations, no stopping rule; it reproduces the Rust ``gap-tv`` of the same cell to 0.01 dB),
run as is and with every TV output projected on the committed network's fixed 12-dimensional spectral span
(``lat_dec`` = V, the projection V·Vᵀ), in ``eval_pnp.py``'s realistic setting (128², acquisition seed 0, operator
seed 1). Prints per scene the Rust GAP-TV, the twin, the projected twin (PSNR, dB, paper) and their SAM.

    .venv/bin/python scripts/probe_subspace.py --scenes val --count 3 --preset sp

A diagnostic, not a solver option: the projection gained +0.21 to +0.38 dB (round 8).
"""
from __future__ import annotations

import argparse
import pathlib
import sys

import numpy as np

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "scripts"))

import diffcassi  # noqa: E402
from diffcassi.deadleaves import BANDS_NM  # noqa: E402
from eval_denoiser import tv_denoise  # noqa: E402
from eval_pnp import ACQUISITION_SEED, OPERATOR_SEED, PLANES, RAYS, SIZE, project_metrics, scenes  # noqa: E402

TV_WEIGHT, TV_ITERATIONS, ITERATIONS = 0.1, 5, 300


def tv_vectorial(f: np.ndarray) -> np.ndarray:
    """Chambolle's vectorial TV of an (H, W, B) cube (``recon::tv``'s algorithm, from p = 0): eval_denoiser's
    NumPy transcription on the (B, H, W) layout."""
    return tv_denoise(f.transpose(2, 0, 1), TV_WEIGHT, TV_ITERATIONS).transpose(1, 2, 0)


def gap_tv(op, y: np.ndarray, shape, projection=None) -> np.ndarray:
    d = op.apply(op.adjoint(np.ones(op.image_shape, np.float32)))
    dinv = np.where(d > 1e-6 * d.max(), 1 / np.maximum(d, 1e-30), 0).astype(np.float32)
    theta, y_acc = np.zeros(shape, np.float32), np.zeros_like(y)
    for _ in range(ITERATIONS):
        phi_theta = op.apply(np.ascontiguousarray(theta))
        y_acc += y - phi_theta
        x = theta + op.adjoint(np.ascontiguousarray((y_acc - phi_theta) * dinv, dtype=np.float32))
        theta = tv_vectorial(x).astype(np.float32)
        if projection is not None:
            theta = (theta @ projection).astype(np.float32)
    return theta


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scenes", choices=("val", "natural"), default="val")
    ap.add_argument("--count", type=int, default=3)
    ap.add_argument("--preset", default="sp")
    ap.add_argument("--mask", default=str(ROOT.parent / "shared/reference/paper_mask_512.npy"))
    ap.add_argument("--weights", default=str(ROOT / "src/recon/prior/weights/spectral-unet-v2-28.safetensors"))
    a = ap.parse_args(argv)
    from safetensors.numpy import load_file
    v = load_file(a.weights)["lat_dec.weight"]
    v = v.reshape(v.shape[0], v.shape[1]).astype(np.float32)  # (28, K), orthonormal columns
    projection = v @ v.T
    paper = np.load(a.mask).astype(np.float32)
    y0, x0 = (paper.shape[0] - SIZE) // 2, (paper.shape[1] - SIZE) // 2
    mask = np.ascontiguousarray(paper[y0:y0 + SIZE, x0:x0 + SIZE])
    system = diffcassi.System.preset(a.preset)
    for name, truth in scenes(a.scenes, a.count):
        y, _ = diffcassi.render(system, truth, list(BANDS_NM), mask, rays=RAYS, planes=PLANES, seed=ACQUISITION_SEED)
        y = np.ascontiguousarray(y, dtype=np.float32)
        op = diffcassi.exact(system, SIZE, SIZE, mask, rays=RAYS, planes=PLANES, seed=OPERATOR_SEED)
        delta = diffcassi.monte_carlo_noise_norm(y, RAYS, RAYS, PLANES / len(BANDS_NM))
        rust, _ = diffcassi.reconstruct(op, y, "gap-tv", noise_norm=delta)
        row = {"rust gap-tv": rust, "twin": gap_tv(op, y, truth.shape), "twin, projected": gap_tv(op, y, truth.shape, projection)}
        print(name, a.preset, "  ".join(f"{k}: {m['psnr']:.2f} dB / {m['sam']:.2f}°"
                                        for k, m in ((k, project_metrics(truth, c)) for k, c in row.items())), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
