"""End-to-end co-design of a CASSI: the prism tilt and the coded mask optimised jointly with a small
unrolled reconstruction, by gradient descent through the differentiable acquisition
(``diffcassi.torch.CassiRenderer``; docs/codesign.md).

The system starts as mSP (the SP prism misaligned by 5° about x) with a random binary mask. The decoder is
a few Landweber/GAP-like steps with a tiny CNN; its forward model is the *aligned* system's light transport
(prism tilt 0) with the learnable mask, so the reconstruction is best when the real acquisition matches the
model: the optimiser moves the tilt towards alignment while it learns the mask and the network. Training
scenes: hyperspectral dead leaves (``diffcassi.deadleaves``); PSNR before and after on the six natural
scenes of ``data/scenes`` (never used in training).

    python examples/python/codesign.py                 # full size (CPU, minutes)
    python examples/python/codesign.py --tiny          # the test suite's size (seconds)
"""
from __future__ import annotations

import argparse
import json
import os
import time
from typing import Dict, List

import numpy as np
import torch
from torch import nn

import diffcassi
import diffcassi.torch as dt
from diffcassi.deadleaves import dead_leaves

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


class _Linear(torch.autograd.Function):
    """x ↦ T x or y ↦ Tᵀ y for the fixed transport T (mask 1) of a DiffRenderer; each is the other's adjoint."""

    @staticmethod
    def forward(ctx, x, r, adjoint):  # type: ignore[override]
        ctx.r, ctx.adjoint = r, adjoint
        return _apply(r, x, adjoint)

    @staticmethod
    def backward(ctx, g):  # type: ignore[override]
        return _apply(ctx.r, g, not ctx.adjoint), None, None


def _apply(r, t: torch.Tensor, adjoint: bool) -> torch.Tensor:
    H, W = r.scene_shape
    ones = np.ones((H, W))
    if not adjoint:
        out = r.inner.render(np.ascontiguousarray(t.detach().numpy(), dtype=np.float64), ones)
    else:
        n = t.shape[0]
        zero = np.zeros((n, len(r.bands), H, W))
        # Only the scene's gradient is Tᵀ: no parameter or mask gradient (no reverse sweep, no mask sums).
        out = r.inner.vjp(zero, ones, np.ascontiguousarray(t.detach().numpy(), dtype=np.float64),
                          params=False, mask_grad=False)[2]
    return torch.from_numpy(out).to(t.dtype)


class Transport:
    """The aligned system's transport T (mask 1) on the renderer's detector."""

    def __init__(self, renderer: dt.CassiRenderer, values: List[float]):
        self.inner = renderer._base.with_values(values)
        self.scene_shape = (renderer.H, renderer.W)
        self.bands = renderer.bands_nm

    def __call__(self, x: torch.Tensor) -> torch.Tensor:
        return _Linear.apply(x, self, False)

    def T(self, y: torch.Tensor) -> torch.Tensor:
        return _Linear.apply(y, self, True)


class Unrolled(nn.Module):
    """K steps x ← x + α_k·M⊙Tᵀ(y − T(M⊙x)), each followed by a residual tiny CNN (shared)."""

    def __init__(self, bands: int, steps: int, width: int = 16):
        super().__init__()
        self.log_alpha = nn.Parameter(torch.zeros(steps))
        self.net = nn.Sequential(nn.Conv2d(bands, width, 3, padding=1), nn.ReLU(), nn.Conv2d(width, bands, 3, padding=1))
        self.steps = steps

    def forward(self, y: torch.Tensor, mask: torch.Tensor, T: Transport, norm: torch.Tensor) -> torch.Tensor:
        x = mask * T.T(y / norm)
        for k in range(self.steps):
            r = (y - T(mask * x)) / norm
            x = x + torch.exp(self.log_alpha[k]) * mask * T.T(r)
            x = x + 0.1 * self.net(x)
        return x


def psnr(a: np.ndarray, b: np.ndarray) -> float:
    mse = float(np.mean((a - b) ** 2))
    return 10 * np.log10(1.0 / max(mse, 1e-12))


def natural_scenes(size: int, bands: List[float]) -> Dict[str, np.ndarray]:
    """The six data/scenes photographs as (B, size, size) cubes in [0, 1] (area-downscaled)."""
    out = {}
    for name in sorted(os.listdir(os.path.join(ROOT, "data", "scenes"))):
        if not name.endswith(".png"):
            continue
        cube, wl = diffcassi.load_scene(os.path.join(ROOT, "data", "scenes", name))
        H = cube.shape[0]
        f = H // size
        c = cube[: f * size, : f * size].reshape(size, f, size, f, -1).mean(axis=(1, 3))
        c = np.stack([np.interp(bands, wl, c[i, j]) for i in range(size) for j in range(size)]).reshape(size, size, -1)
        out[name[:-4]] = np.ascontiguousarray(c.transpose(2, 0, 1), dtype=np.float32)
    return out


def evaluate(renderer: dt.CassiRenderer, net: Unrolled, T: Transport, scenes: Dict[str, np.ndarray]) -> Dict[str, float]:
    with torch.no_grad():
        mask = renderer.mask()
        norm = _norm(T, mask)
        res = {}
        for name, c in scenes.items():
            x = torch.from_numpy(c)[None]
            est = net(renderer(x), mask, T, norm)
            res[name] = psnr(np.clip(est[0].numpy(), 0, 1), c)
    return res


def _norm(T: Transport, mask: torch.Tensor) -> torch.Tensor:
    """Per-detector-pixel normaliser T(M ⊙ 1) (+ a floor), detached: GAP's (ΦΦᵀ)⁻¹ approximated by a diagonal."""
    with torch.no_grad():
        ones = torch.ones((1, len(T.bands)) + T.scene_shape)
        n = T(mask.detach() * ones)
    return n + 0.05 * float(n.max())


def main(argv=None) -> Dict[str, object]:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--tiny", action="store_true", help="the test suite's size")
    ap.add_argument("--size", type=int, default=32)
    ap.add_argument("--iters", type=int, default=150)
    ap.add_argument("--batch", type=int, default=4)
    ap.add_argument("--rays", type=int, default=4)
    ap.add_argument("--planes", type=int, default=28)
    ap.add_argument("--steps", type=int, default=3)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--pool", type=int, default=64, help="training scenes (dead leaves), batches drawn from them")
    ap.add_argument("--freeze-tilt", action="store_true", help="ablation: keep the tilt at 5° (mask and network only)")
    ap.add_argument("--out", default=None, help="write the trajectory, mask and PSNRs as JSON here")
    a = ap.parse_args(argv)
    if a.tiny:
        a.size, a.iters, a.batch, a.rays, a.planes, a.steps, a.pool = 8, 16, 2, 1, 7, 1, 2
    torch.manual_seed(a.seed)
    t0 = time.time()
    msp = diffcassi.System.preset("msp")
    renderer = dt.CassiRenderer(msp, a.size, a.size, free=["prism_tilt_x"], rays=a.rays, planes=a.planes, seed=a.seed,
                                mask_seed=a.seed)
    T = Transport(renderer, [0.0])
    bands = renderer.bands_nm
    net = Unrolled(len(bands), a.steps)
    tests = natural_scenes(a.size, bands)
    before = evaluate(renderer, net, T, tests)
    opt = torch.optim.Adam([{"params": net.parameters(), "lr": 3e-3},
                            {"params": [renderer.mask_logits], "lr": 5e-2},
                            {"params": [renderer.theta], "lr": 0.0 if a.freeze_tilt else 0.1}])
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, a.iters)
    pool = np.stack([dead_leaves(a.seed * 100000 + k, size=a.size, bands_nm=bands) for k in range(a.pool)])
    rng = np.random.default_rng(a.seed)
    history: List[Dict[str, float]] = []
    for it in range(a.iters):
        # Temperature schedule: 1 → 0.2 geometrically, pushing the mask towards binary.
        renderer.temperature = 1.0 * (0.2 ** (it / max(a.iters - 1, 1)))
        x = torch.from_numpy(pool[rng.choice(a.pool, size=a.batch, replace=False)])
        mask = renderer.mask()
        y = renderer(x)
        est = net(y, mask, T, _norm(T, mask))
        loss = torch.mean((est - x) ** 2)
        opt.zero_grad()
        loss.backward()
        opt.step()
        sched.step()
        history.append({"iter": it, "loss": loss.item(), "tilt_deg": float(renderer.theta.detach()[0]),
                        "temperature": renderer.temperature})
        if it % max(a.iters // 10, 1) == 0 or it == a.iters - 1:
            print(f"iter {it:4d}  loss {loss.item():.5f}  prism_tilt_x {history[-1]['tilt_deg']:+.4f}°  "
                  f"{time.time() - t0:.0f} s", flush=True)
    after = evaluate(renderer, net, T, tests)
    result = {
        "size": a.size, "iters": a.iters, "batch": a.batch, "rays": a.rays, "planes": a.planes, "steps": a.steps,
        "seconds": time.time() - t0, "history": history, "psnr_before": before, "psnr_after": after,
        "mean_psnr_before": float(np.mean(list(before.values()))), "mean_psnr_after": float(np.mean(list(after.values()))),
        "mask": renderer.binary_mask().astype(int).tolist(), "mask_open_fraction": float(renderer.binary_mask().mean()),
    }
    print(f"PSNR on data/scenes (unseen): before {result['mean_psnr_before']:.2f} dB, after {result['mean_psnr_after']:.2f} dB; "
          f"tilt {history[0]['tilt_deg']:+.3f}° → {history[-1]['tilt_deg']:+.3f}°; {result['seconds']:.0f} s")
    if a.out:
        with open(a.out, "w") as f:
            json.dump(result, f)
    return result


if __name__ == "__main__":
    main()
