"""A toy run of the unrolled network (``diffcassi.torch.UnrolledGAP``: GAP stages with learned denoisers around the
exact operator) — seconds to minutes on a CPU, a falling loss. The real training is ``scripts/train_unrolled.py``
(diffcassi/weights/UNROLLED.md: the realistic setting at 128×128, the committed weights).

    .venv/bin/python examples/python/train_unrolled.py            # 40 iterations
    .venv/bin/python examples/python/train_unrolled.py --iterations 200 --size 32

Data: the CLI's synthetic scenes (48×48, 31 bands), cropped/flipped/rotated per (seed, index, epoch) by
CassiDataset and rendered through the exact light transport (Transport) of the SP system; the network sees the
acquisition and uses the exact operator Φ of *another* Monte-Carlo seed (matrix-free, differentiable):

    x₀ = Φᵀ(y ⊘ d),   x_k = s·D_k((x_{k−1} + λ_k Φᵀ((y − Φ x_{k−1}) ⊘ d)) / s),   d = Φ Φᵀ 𝟙,  s = mean(x₀)
"""
import argparse
import time

import numpy as np
import torch

import diffcassi
import diffcassi.torch as dt


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
    settings = dict(bands_nm=bands, planes=2 * a.bands, rays=4)
    ds = dt.CassiDataset(scenes, "sp", a.size, length=a.batch * 10, seed=a.seed, transport=dict(settings, seed=0))
    op = diffcassi.exact(diffcassi.System.preset("sp"), a.size, a.size, **settings, seed=1)  # not the acquisition's rays
    phi = dt.CassiOperator.from_operator(op, matrix_free=True)
    print(f"{ds.transport}; operator {phi.extra_repr()}; set up in {time.time() - t0:.1f} s")
    model = dt.UnrolledGAP(phi, stages=a.stages, width=8)
    opt = torch.optim.Adam(model.parameters(), lr=2e-3)
    it, epoch, losses = 0, 0, []
    while it < a.iterations:
        ds.set_epoch(epoch)
        loader = torch.utils.data.DataLoader(ds, batch_size=a.batch, num_workers=a.workers, shuffle=False)
        for acq, _mask, truth, _init in loader:
            loss = (model(acq) - truth).abs().mean()
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
