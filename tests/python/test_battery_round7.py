"""Round 7: the unrolled networks' entry check is the whole story. `UnrolledGAP` / `UnrolledDAUHST` accepted an
acquisition within ±3.403e29 at the entry but handed the operator y ⊘ d (d⁻¹ up to ≈ 3·10⁵), so y ≈ 10²⁵ failed
deep inside with `MatrixFreeCassiOperator.adjoint: y: value 3.5e+29 … beyond ±3.403e+29`. The networks now run
on y / c, c a power of two per sample (diffcassi/unrolled.py `_pow2_scale`): exact, N(y) = c·N(y/c) bit for bit,
so ordinary inputs give the same outputs as before and every accepted y works. Tiny sizes only."""
import pytest

torch = pytest.importorskip("torch", reason="torch not installed (DIFFCASSI_TORCH=skip)")

import diffcassi  # noqa: E402
import diffcassi.torch as dt  # noqa: E402
from diffcassi.unrolled import UnrolledDAUHST, UnrolledGAP  # noqa: E402

SP = diffcassi.System.preset("sp")


@pytest.fixture(scope="module")
def mf():
    """The tester's operator: SP, 8×8, rays=2, planes=28, matrix-free (its d⁻¹ reaches ≈ 3·10⁵)."""
    torch.set_num_threads(1)
    t = diffcassi.Transport(SP, 8, 8, planes=28, rays=2)
    return dt.CassiOperator.from_operator(t.operator, matrix_free=True)


def _net(kind, mf):
    torch.manual_seed(0)
    net = UnrolledGAP(mf, stages=2) if kind == "gap" else UnrolledDAUHST(mf, stages=2, width=8)
    with torch.no_grad():  # "trained": every path (the linear maps, the U-Nets' tails, the estimators) live
        for p in net.parameters():
            p.add_(0.01 * torch.randn_like(p))
    return net


def _y(n=2, seed=0, shape=None):
    return torch.rand(n, *shape, generator=torch.Generator().manual_seed(seed))


@pytest.mark.parametrize("kind", ["gap", "dauhst"])
def test_large_acquisitions_within_the_entry_limit_reconstruct(kind, mf):
    assert float(UnrolledGAP(mf, stages=1).dinv.max()) > 1e5  # the configuration that overflowed y ⊘ d
    net = _net(kind, mf)
    y = _y(shape=mf.image_shape)
    with torch.no_grad():
        base = net(y)
        peak = float(base.abs().max())
        for v in (1e25, 1e29, 3.4e29):  # all within ±3.403e29, y ⊘ d beyond it (failed before)
            out = net(y * v)
            assert torch.isfinite(out).all()
            assert float((out / v - base).abs().max()) <= 1e-5 * peak
        # The entry check is still the only refusal: beyond ±3.403e29 is refused there, naming the limit.
        with pytest.raises(diffcassi.DiffcassiValueError, match=r"forward: y holds .* beyond ±3\.403e\+29"):
            net(y * 1e30)


@pytest.mark.parametrize("kind", ["gap", "dauhst"])
def test_power_of_two_scaling_is_exact_over_the_whole_range(kind, mf):
    net = _net(kind, mf)
    y = _y(shape=mf.image_shape, seed=1)
    with torch.no_grad():
        base = net(y)
        for k in (-100, -20, 3, 40, 90, 97):  # 2⁹⁰ ≈ 1.2·10²⁷, 2⁹⁷ ≈ 1.6·10²⁹
            torch.testing.assert_close(net(y * 2.0 ** k), base * 2.0 ** k, rtol=0, atol=0)


@pytest.mark.parametrize("kind", ["gap", "dauhst"])
def test_per_sample_scale_and_gradients(kind, mf):
    net = _net(kind, mf)
    y = _y(shape=mf.image_shape, seed=2)
    plain = torch.stack([y[0], y[1], torch.zeros_like(y[1])])
    mixed = torch.stack([y[0] * 2.0 ** 95, y[1], torch.zeros_like(y[1])])  # one huge, one ordinary, one dark
    with torch.no_grad():
        ref, out = net(plain), net(mixed)  # (the same batch size: the convolutions' kernels depend on it)
        torch.testing.assert_close(out[0], ref[0] * 2.0 ** 95, rtol=0, atol=0)
        torch.testing.assert_close(out[1], ref[1], rtol=0, atol=0)
        assert torch.count_nonzero(out[2]) == 0  # a dark frame is still exactly zero
    # ∂N/∂y is homogeneous of degree 0: the same at y and at 2⁹⁰·y, finite (the scale is a constant of y).
    g = []
    for a in (1.0, 2.0 ** 90):
        yy = (y * a).requires_grad_(True)
        (net(yy) / a).square().sum().backward()
        g.append(yy.grad * a)
    assert torch.isfinite(g[1]).all()
    torch.testing.assert_close(g[1], g[0], rtol=0, atol=0)
