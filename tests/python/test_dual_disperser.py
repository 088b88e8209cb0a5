"""Dual-disperser CASSI from Python (issue 44): the presets build, the exact operator equals the renderer and its
torch module, and the mapping/shift models run; the differentiable renderer's gradients go through the mask surface."""
import numpy as np
import pytest

import diffcassi
from conftest import SMALL, check_cassi_renderer_gradients, random_cube


@pytest.mark.parametrize("name", ["ddsp", "mddsp"])
def test_presets_render_and_their_exact_operator_equals_the_render(name):
    system = diffcassi.System.preset(name)
    # 40²: every plane's image meets the mask (at 10² six of eight passed nothing: `mask_dark_planes`).
    N = 40
    mask = (np.random.default_rng(3).random((N, N)) > 0.5).astype(np.float32)
    transport = diffcassi.Transport(system, N, N, mask=mask, **SMALL)
    x = random_cube(N, N, 4, seed=5)
    y = transport.operator.apply(x)
    assert y.shape == tuple(transport.detector_shape) and float(y.max()) > 0
    image, record = diffcassi.render(system, x, SMALL["bands_nm"], mask, **SMALL)
    assert record["ray_stats"]["masked"] > 0 and "mask_dark_planes" not in record
    assert np.abs(y - image).max() <= 1e-5 * image.max()
    # Adjoint consistency of the f32 operator (dot-product test).
    yt = np.random.default_rng(1).random(y.shape, dtype=np.float32)
    lhs = float(np.dot(y.astype(np.float64).ravel(), yt.astype(np.float64).ravel()))
    rhs = float(np.dot(x.astype(np.float64).ravel(), transport.operator.adjoint(yt).astype(np.float64).ravel()))
    assert abs(lhs - rhs) <= 1e-5 * abs(lhs)
    for op in (diffcassi.mapping_operator(system, N, N, mask, **SMALL), diffcassi.shift_operator(system, N, N, mask, **SMALL)):
        assert np.isfinite(op.apply(x)).all()


def test_torch_module_of_the_ddsp_operator():
    torch = pytest.importorskip("torch", reason="PyTorch not installed (DIFFCASSI_TORCH=skip)")
    import diffcassi.torch as dt
    transport = diffcassi.Transport(diffcassi.System.preset("ddsp"), 8, 8, **SMALL)
    phi = dt.CassiOperator.from_operator(transport)
    x = random_cube(8, 8, 4, seed=2)
    y = phi(torch.from_numpy(x).permute(2, 0, 1)[None])
    ref = transport.operator.apply(x)
    assert float((y[0] - torch.from_numpy(ref)).abs().max()) <= 1e-5 * float(ref.max())


def test_differentiable_renderer_through_the_mask_surface():
    """CassiRenderer on ddsp: the mask is read on its surface; ∂L/∂mask is exact (the acquisition is linear in
    it) and ∂L/∂θ of a second-arm parameter matches central finite differences of the same-sample render."""
    pytest.importorskip("torch", reason="PyTorch not installed (DIFFCASSI_TORCH=skip)")
    check_cassi_renderer_gradients(diffcassi.System.preset("ddsp"), ["s25.tilt_y_deg"], [516.0, 520.0, 524.0], [1e-6])
