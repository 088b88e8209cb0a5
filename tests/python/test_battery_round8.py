"""Round 8 of the held-out battery (docs/robustness.md): the torch modules check their sizes against the
budgets before allocating anything."""
import pytest

import diffcassi

torch = pytest.importorskip("torch")


def test_unrolled_networks_refuse_weights_beyond_the_memory_budget():
    import diffcassi.torch as dt
    from diffcassi.unrolled import UnrolledDAUHST, UnrolledGAP
    op = diffcassi.exact(diffcassi.System.preset("sp"), 12, 12, rays=1, planes=28, seed=1)
    phi = dt.CassiOperator.from_operator(op)
    for cls, kw, needle in [(UnrolledGAP, dict(stages=10**9), "stages = 1000000000"), (UnrolledGAP, dict(width=10**6), "width = 1000000"),
                            (UnrolledDAUHST, dict(stages=10**9), "stages = 1000000000"), (UnrolledDAUHST, dict(width=10**6), "width = 1000000")]:
        with pytest.raises(diffcassi.DiffcassiValueError, match=needle) as e:
            cls(phi, **kw)
        assert "set_limits" in str(e.value)
    # The defaults are far within it.
    assert UnrolledGAP(phi).stages == 6 and UnrolledDAUHST(phi).stages == 3


def test_cassi_renderer_checks_the_ray_budget_before_drawing_its_mask():
    import diffcassi.torch as dt
    # H = 10¹²: the default random mask would be 87 TiB of float64; the ray budget refuses it first.
    with pytest.raises(diffcassi.DiffcassiValueError, match="max_rays"):
        dt.CassiRenderer(diffcassi.System.preset("msp"), 10**12, 12, rays=1, planes=1)
