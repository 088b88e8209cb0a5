"""Shared fixtures of the Python tests: the presets, a small render configuration, and the CLI binary
(built by cargo into the repository's target/; `cargo build --release --bin diffcassi` is a no-op when fresh)."""
import importlib.util
import os
import pathlib
import subprocess

import numpy as np
import pytest

import diffcassi

ROOT = pathlib.Path(__file__).resolve().parents[2]
PRESETS = ["sp", "ap", "msp", "map"]
#: Small render settings (the suite stays fast).
SMALL = dict(bands_nm=[480.0, 520.0, 560.0, 600.0], planes=8, rays=4)


@pytest.fixture(scope="session")
def cli():
    exe = ROOT / "target" / "release" / "diffcassi"
    subprocess.run(["cargo", "build", "--release", "--quiet", "--bin", "diffcassi"], cwd=ROOT, check=True)
    assert exe.is_file(), exe
    return str(exe)


@pytest.fixture(scope="session", params=PRESETS)
def system(request):
    return diffcassi.System.preset(request.param)


def random_cube(h, w, b, seed=0):
    return np.random.default_rng(seed).random((h, w, b), dtype=np.float32)


def load_script(name):
    """The module of ``scripts/NAME.py`` (the training and evaluation scripts are not a package)."""
    spec = importlib.util.spec_from_file_location(name, ROOT / "scripts" / f"{name}.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def check_cassi_renderer_gradients(system, free, bands, steps, **settings):
    """``CassiRenderer`` on ``system`` (6×6 scene, 2 rays, 3 planes over ``bands``, seed 1, and the constructor's
    keywords ``settings``, e.g. ``scene_fov_deg`` at infinity) with the free parameters ``free``: ∂L/∂mask is
    exact for L = Σ g·render (the acquisition is linear in the mask), and each ∂L/∂θ_k matches the central
    finite difference of the same-sample render with step ``steps[k]`` to 1e-6. Returns the largest relative
    difference."""
    import torch
    import diffcassi.torch as dt
    r = dt.CassiRenderer(system, 6, 6, free=free, rays=2, planes=3, bands_nm=bands, seed=1, **settings)
    cube = torch.from_numpy(np.random.default_rng(4).random((1, 3, 6, 6))).to(torch.float64)
    mask = torch.from_numpy(np.random.default_rng(5).random((6, 6))).requires_grad_(True)
    y = r.render(cube, mask)
    g = torch.from_numpy(np.random.default_rng(6).random(tuple(y.shape)) - 0.5)
    loss = (y * g).sum()
    loss.backward()
    assert float(y.detach().max()) > 0 and mask.grad is not None and r.theta.grad is not None
    assert abs(float((mask.grad * mask.detach()).sum()) - float(loss.detach())) <= 1e-12 * abs(float(loss.detach()))
    worst = 0.0
    for k, h in enumerate(steps):
        grad = float(r.theta.grad[k])
        at = []
        for d in (h, -h):
            with torch.no_grad():
                r.theta[k] += d
                at.append(float((r.render(cube, mask.detach()) * g).sum()))
                r.theta[k] -= d
        fd = (at[0] - at[1]) / (2 * h)
        assert grad != 0 and abs(fd - grad) <= 1e-6 * abs(grad), (free[k], grad, fd)
        worst = max(worst, abs(fd - grad) / abs(grad))
    return worst
