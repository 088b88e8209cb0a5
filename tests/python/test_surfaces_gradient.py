"""The differentiable renderer through a diffraction grating from torch (issue 42): ``CassiRenderer`` on the grating
CASSI preset ``gsp`` (no longer refused; the reverse sweep transposes the grating equation, docs/zemax-files.md):
∂L/∂mask is exact (the acquisition is linear in it) and ∂L/∂θ of the grating's tilt and of a lens curvature match
central finite differences of the same-sample render."""
import numpy as np
import pytest

import diffcassi


def test_cassi_renderer_through_the_gsp_grating():
    torch = pytest.importorskip("torch", reason="PyTorch not installed (DIFFCASSI_TORCH=skip)")
    import diffcassi.torch as dt
    bands = [480.0, 560.0, 640.0]
    r = dt.CassiRenderer(diffcassi.System.preset("gsp"), 6, 6, free=["s3.tilt_x_deg", "s8.curvature"], rays=2, planes=3,
                         bands_nm=bands, seed=1)
    cube = torch.from_numpy(np.random.default_rng(4).random((1, 3, 6, 6))).to(torch.float64)
    mask = torch.from_numpy(np.random.default_rng(5).random((6, 6))).requires_grad_(True)
    y = r.render(cube, mask)
    g = torch.from_numpy(np.random.default_rng(6).random(tuple(y.shape)) - 0.5)
    loss = (y * g).sum()
    loss.backward()
    assert float(y.detach().max()) > 0 and mask.grad is not None and r.theta.grad is not None
    assert abs(float((mask.grad * mask).sum()) - float(loss)) <= 1e-12 * abs(float(loss))
    for k, h in ((0, 1e-6), (1, 1e-8)):
        grad = float(r.theta.grad[k])
        at = []
        for d in (h, -h):
            with torch.no_grad():
                r.theta[k] += d
                at.append(float((r.render(cube, mask.detach()) * g).sum()))
                r.theta[k] -= d
        fd = (at[0] - at[1]) / (2 * h)
        assert grad != 0 and abs(fd - grad) <= 1e-6 * abs(grad), (k, grad, fd)
