"""Train a tiny unrolled network (a few GAP steps, each followed by a small CNN denoiser) on acquisitions rendered
on the fly by diffcassi — the shape of the reference paper's pipeline, on CPU in minutes.

    .venv/bin/python examples/python/train_unrolled.py            # 40 iterations, prints a falling loss
    .venv/bin/python examples/python/train_unrolled.py --iterations 200 --size 32

Data: the CLI's synthetic scenes (48×48, 31 bands), cropped/flipped/rotated per (seed, index, epoch) by
CassiDataset and rendered through the exact light transport (Transport) of the SP system; the network sees
the acquisition, the mask and the paper's initialisation I = A ∘ f, and uses the exact operator Φ
(CassiOperator, differentiable) in its GAP steps:

    x₀ = Φᵀ(y ⊘ d),   x_{k+1} = D_k(x_k + Φᵀ((y − Φ x_k) ⊘ d)),   d = Φ Φᵀ 1 (the GAP preconditioner)
"""
import argparse
import time

import numpy as np
import torch
from torch import nn

import diffcassi
import diffcassi.torch as dt


class Denoiser(nn.Module):
    """A residual 3-layer CNN over the bands (input: the estimate and the initialisation I = A ∘ f)."""

    def __init__(self, bands: int, width: int = 32):
        super().__init__()
        self.net = nn.Sequential(nn.Conv2d(2 * bands, width, 3, padding=1), nn.ReLU(),
                                 nn.Conv2d(width, width, 3, padding=1), nn.ReLU(),
                                 nn.Conv2d(width, bands, 3, padding=1))

    def forward(self, x, init):
        return x + self.net(torch.cat([x, init], dim=1))


class UnrolledGap(nn.Module):
    def __init__(self, phi: dt.CassiOperator, stages: int):
        super().__init__()
        self.phi = phi
        bands = phi.cube_shape[2]
        self.denoisers = nn.ModuleList(Denoiser(bands) for _ in range(stages))
        with torch.no_grad():
            d = phi(phi.adjoint(torch.ones(phi.image_shape)))
        self.register_buffer("d", d.clamp_min(1e-6 * float(d.max())))

    def forward(self, y, init):
        x = self.phi.adjoint(y / self.d)
        for den in self.denoisers:
            x = x + self.phi.adjoint((y - self.phi(x)) / self.d)
            x = den(x, init)
        return x


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--iterations", type=int, default=40)
    ap.add_argument("--size", type=int, default=16, help="crop side (pixels)")
    ap.add_argument("--bands", type=int, default=8)
    ap.add_argument("--stages", type=int, default=3)
    ap.add_argument("--batch", type=int, default=4)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--seed", type=int, default=0)
    a = ap.parse_args()
    torch.manual_seed(a.seed)
    t0 = time.time()
    bands = np.linspace(450, 650, a.bands)
    scenes = [diffcassi.synthetic_scene(48, 48, seed=s) for s in range(8)]
    per_epoch = a.batch * 10
    ds = dt.CassiDataset(scenes, "sp", a.size, length=per_epoch, seed=a.seed,
                         transport=dict(bands_nm=bands, planes=2 * a.bands, rays=4))
    phi = dt.CassiOperator.from_operator(ds.transport)
    print(f"{ds.transport}; operator {phi.extra_repr()}; set up in {time.time() - t0:.1f} s")
    model = UnrolledGap(phi, a.stages)
    opt = torch.optim.Adam(model.parameters(), lr=2e-3)
    it, epoch, losses = 0, 0, []
    while it < a.iterations:
        ds.set_epoch(epoch)
        loader = torch.utils.data.DataLoader(ds, batch_size=a.batch, num_workers=a.workers, shuffle=False)
        for acq, mask, truth, init in loader:
            est = model(acq, init)
            loss = nn.functional.mse_loss(est, truth)
            opt.zero_grad()
            loss.backward()
            opt.step()
            losses.append(loss.item())
            it += 1
            if it % 5 == 0 or it == 1:
                print(f"iteration {it:4d}  epoch {epoch}  loss {losses[-1]:.5f}  (mean of last 5: {np.mean(losses[-5:]):.5f})")
            if it >= a.iterations:
                break
        epoch += 1
    first, last = np.mean(losses[:5]), np.mean(losses[-5:])
    print(f"loss: first 5 iterations {first:.5f} → last 5 {last:.5f} ({last / first:.2f}×) in {time.time() - t0:.1f} s")


if __name__ == "__main__":
    main()
