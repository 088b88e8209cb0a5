"""Held-out battery, round 19 (prober D, finding 3): `CassiRenderer`'s memory check ignored `planes` and the
batch. `set_limits(max_memory_gb=0.3)` then `CassiRenderer(sp, 512, 512, rays=1, planes=112)` forward+backward
used 0.65 GB (the estimate, one render's buffers, was 0.24 GB at 28 and at 112 planes), and a batch of 4 peaked
at 4× the estimate with nothing refusing it. The constructor now counts the planes (the transport kept for the
backward pass) and `forward` checks the batch before its float64 copy is made."""
import pytest
import torch

import diffcassi
from diffcassi.torch import CassiRenderer


@pytest.fixture
def default_limits():
    yield
    diffcassi.set_limits()


def _estimate_gb(H, W, **kw):
    diffcassi.set_limits(max_memory_gb=1e-6)
    with pytest.raises(diffcassi.DiffcassiValueError) as e:
        CassiRenderer(diffcassi.System.preset("sp"), H, W, **kw)
    return float(str(e.value).split("needs an estimated ")[1].split(" GB")[0])


def test_the_constructor_counts_the_planes(default_limits):
    few, many = _estimate_gb(128, 128, rays=1, planes=7), _estimate_gb(128, 128, rays=1, planes=112)
    # 16 B per pixel-plane of transport kept for the backward pass: 128² × 105 planes more = 27.5 MB.
    assert many - few >= 0.02, (few, many)


def test_forward_checks_the_batch_before_allocating(default_limits):
    sp = diffcassi.System.preset("sp")
    one = _estimate_gb(32, 32, rays=1, planes=4)
    # A budget that holds one scene's render with room to spare, not eight.
    diffcassi.set_limits(max_memory_gb=one * 3)
    r = CassiRenderer(sp, 32, 32, rays=1, planes=4)
    y = r(torch.rand(1, 28, 32, 32))
    assert torch.isfinite(y).all()
    with pytest.raises(diffcassi.DiffcassiValueError, match=r"N × H × W × planes × rays \(8 × 32 × 32 × 4 × 1\): needs an estimated .*max_memory_gb"):
        r(torch.rand(8, 28, 32, 32))
