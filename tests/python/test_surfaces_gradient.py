"""The differentiable renderer through a diffraction grating from torch (issue 42): ``CassiRenderer`` on the grating
CASSI preset ``gsp`` (no longer refused; the reverse sweep transposes the grating equation, docs/zemax-files.md):
∂L/∂mask is exact (the acquisition is linear in it) and ∂L/∂θ of the grating's tilt and of a lens curvature match
central finite differences of the same-sample render."""
import pytest

import diffcassi
from conftest import check_cassi_renderer_gradients


def test_cassi_renderer_through_the_gsp_grating():
    pytest.importorskip("torch", reason="PyTorch not installed (DIFFCASSI_TORCH=skip)")
    check_cassi_renderer_gradients(diffcassi.System.preset("gsp"), ["s3.tilt_x_deg", "s8.curvature"], [480.0, 560.0, 640.0], [1e-6, 1e-8])
