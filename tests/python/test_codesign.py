"""diffcassi.torch.CassiRenderer (issue 24): the interface, torch gradcheck for cube, mask and optical
parameters, clear errors out of range, and the co-design example at a tiny size (its loss decreases)."""
import importlib.util

import numpy as np
import pytest

torch = pytest.importorskip("torch", reason="PyTorch not installed (DIFFCASSI_TORCH=skip)")
import diffcassi  # noqa: E402
import diffcassi.torch as dt  # noqa: E402
from conftest import ROOT  # noqa: E402

BANDS = [450.0, 550.0, 650.0]


def test_interface_shapes_and_parameters():
    sp = diffcassi.System.preset("sp")
    r = dt.CassiRenderer(sp, 6, 6, free=["prism_tilt_x"], rays=4, planes=28, seed=0)
    h, w = r.image_shape
    y = r(torch.rand(1, 28, 6, 6, dtype=torch.float32))
    assert y.shape == (1, h, w) and y.dtype == torch.float32
    assert torch.isfinite(y).all() and float(y.detach().sum()) > 0
    params = list(r.parameters())
    assert len(params) == 2 and {tuple(p.shape) for p in params} == {(1,), (6, 6)}
    assert r.names == ["s4.tilt_x_deg"]
    # Same samples, same result.
    x = torch.rand(2, 28, 6, 6)
    assert torch.equal(r(x), r(x))


def test_gradcheck_cube_mask_and_parameters():
    msp = diffcassi.System.preset("msp")
    r = dt.CassiRenderer(msp, 4, 4, free=["prism_tilt_x", "s16.radius_mm", "glass_nd:N-BK7"], rays=2, planes=3,
                         seed=1, bands_nm=BANDS)
    g = torch.Generator().manual_seed(0)
    cube = torch.rand(2, 3, 4, 4, dtype=torch.float64, generator=g, requires_grad=True)
    mask = (0.2 + 0.7 * torch.rand(4, 4, dtype=torch.float64, generator=g)).requires_grad_(True)
    theta = r.theta.detach().clone().requires_grad_(True)

    def f(c, m, t):
        return dt._RenderFn.apply(c, m, t, r)

    # float64 throughout; the optical parameters move landings by ≪ a pixel at eps = 1e-6, so the
    # same-sample acquisition is smooth over the difference (the Rust test bounds the error by 6e-8).
    assert torch.autograd.gradcheck(f, (cube, mask, theta), eps=1e-6, atol=1e-6, rtol=1e-4)


def test_learnable_mask_gets_gradients_through_the_module():
    r = dt.CassiRenderer(diffcassi.System.preset("sp"), 4, 4, free=["prism_tilt_x"], rays=2, planes=3, bands_nm=BANDS,
                         temperature=0.5, straight_through=True)
    y = r(torch.rand(1, 3, 4, 4))
    (y ** 2).sum().backward()
    assert r.mask_logits.grad is not None and torch.isfinite(r.mask_logits.grad).all()
    assert r.theta.grad is not None and torch.isfinite(r.theta.grad).all() and float(r.theta.grad.abs()) > 0
    assert set(np.unique(r.binary_mask())) <= {0.0, 1.0}


def test_out_of_range_parameters_raise_clear_errors():
    sp = diffcassi.System.preset("sp")
    x = torch.rand(1, 3, 4, 4)
    r = dt.CassiRenderer(sp, 4, 4, free=["glass_nd:N-BK7"], rays=1, planes=3, bands_nm=BANDS)
    with torch.no_grad():
        r.theta[0] = 2.6
    with pytest.raises(diffcassi.DiffcassiValueError, match=r"glass_nd:N-BK7.*range"):
        r(x)
    r = dt.CassiRenderer(sp, 4, 4, free=["prism_tilt_x"], rays=1, planes=3, bands_nm=BANDS)
    with torch.no_grad():
        r.theta[0] = float("nan")
    with pytest.raises(diffcassi.DiffcassiValueError, match="not finite"):
        r(x)
    with torch.no_grad():
        r.theta[0] = 60.0
    with pytest.raises(diffcassi.DiffcassiValueError, match="no ray reaches the detector|chief-ray solve failed"):
        r(x)
    with pytest.raises(diffcassi.DiffcassiValueError, match="cube: expected shape"):
        dt.CassiRenderer(sp, 4, 4, rays=1, planes=3, bands_nm=BANDS)(torch.rand(1, 3, 5, 4))
    with pytest.raises(diffcassi.DiffcassiValueError, match="prism_tilt_q"):
        dt.CassiRenderer(sp, 4, 4, free=["prism_tilt_q"], rays=1, planes=3, bands_nm=BANDS)
    last = len(diffcassi.surfaces(sp)) - 1
    with pytest.raises(diffcassi.DiffcassiValueError, match="no effect on the detector"):
        dt.CassiRenderer(sp, 4, 4, free=[f"s{last}.thickness_mm"], rays=1, planes=3, bands_nm=BANDS)
    with pytest.raises(diffcassi.DiffcassiValueError, match="mask"):
        dt.CassiRenderer(sp, 4, 4, mask=np.ones((3, 4)), rays=1, planes=3, bands_nm=BANDS)
    # A non-finite upstream gradient.
    r = dt.CassiRenderer(sp, 4, 4, rays=1, planes=3, bands_nm=BANDS)
    y = r(x)
    with pytest.raises(diffcassi.DiffcassiValueError, match="upstream gradient"):
        y.backward(torch.full_like(y, float("nan")))


def test_mapping_jacobian_shapes():
    r = dt.CassiRenderer(diffcassi.System.preset("msp"), 3, 3, free=["prism_tilt_x", "prism_tilt_y"], rays=1, planes=3,
                         bands_nm=BANDS)
    pos, jac, valid = r.mapping_jacobian()
    assert pos.shape == (3, 3, 3, 2) and jac.shape == (3, 3, 3, 2, 2) and valid.all()
    assert np.abs(jac).max() > 0


def test_codesign_example_loss_decreases():
    res = _example_module().main(["--tiny"])
    losses = [h["loss"] for h in res["history"]]
    assert np.isfinite(losses).all()
    assert np.mean(losses[-3:]) < np.mean(losses[:3]), losses
    assert len(res["psnr_after"]) == 6


def _example_module():
    spec = importlib.util.spec_from_file_location("codesign", ROOT / "examples" / "python" / "codesign.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_codesign_example_adjoint_is_the_full_vjps_scene_gradient_bit_for_bit():
    """The example's decoder computes Tᵀ with ``vjp(..., params=False, mask_grad=False)`` (no reverse sweep, no
    mask sums): the same array, bit for bit, as the scene gradient of the full ``vjp``; and it is T's adjoint."""
    mod = _example_module()
    r = dt.CassiRenderer(diffcassi.System.preset("msp"), 5, 5, free=["prism_tilt_x"], rays=2, planes=3, seed=4,
                         bands_nm=BANDS)
    T = mod.Transport(r, [0.0])
    g = torch.rand((2,) + tuple(r.image_shape), generator=torch.Generator().manual_seed(5), dtype=torch.float64)
    got = T.T(g).numpy()
    ones = np.ones((5, 5))
    full = T.inner.vjp(np.zeros((2, 3, 5, 5)), ones, np.ascontiguousarray(g.numpy()))
    assert full[0] is not None and full[1] is not None and np.abs(full[2]).max() > 0
    assert got.shape == (2, 3, 5, 5) and np.array_equal(got, full[2])
    # ⟨T x, g⟩ = ⟨x, Tᵀ g⟩.
    x = torch.rand(2, 3, 5, 5, generator=torch.Generator().manual_seed(6), dtype=torch.float64)
    lhs, rhs = float((T(x) * g).sum()), float((x * T.T(g)).sum())
    assert abs(lhs - rhs) <= 1e-12 * abs(lhs), (lhs, rhs)


def test_only_the_gradients_autograd_needs_are_computed_bit_identical():
    """A frozen mask, cube or θ is not differentiated (``ctx.needs_input_grad``); the gradients that are
    computed equal those of the backward that computes all three, bit for bit (straight-through mask: half
    the pixels closed, whose rays are then not traced)."""
    r = dt.CassiRenderer(diffcassi.System.preset("msp"), 5, 5, free=["prism_tilt_x", "glass_nd:N-BK7"], rays=2,
                         planes=3, seed=2, bands_nm=BANDS, straight_through=True, mask_seed=3)
    cube0 = torch.rand(2, 3, 5, 5, generator=torch.Generator().manual_seed(1), dtype=torch.float64)

    def grads(mask_on, theta_on, cube_on):
        r.zero_grad(set_to_none=True)
        r.mask_logits.requires_grad_(mask_on)
        r.theta.requires_grad_(theta_on)
        cube = cube0.clone().requires_grad_(cube_on)
        (r(cube) ** 2).sum().backward()
        return r.mask_logits.grad, r.theta.grad, cube.grad

    full = grads(True, True, True)
    assert all(g is not None for g in full)
    assert (r.binary_mask() == 0).any() and (r.binary_mask() == 1).any()
    for on in [(False, True, False), (True, False, False), (False, False, True), (True, True, False), (False, True, True)]:
        got = grads(*on)
        for want, g, f in zip(on, got, full):
            if want:
                assert g is not None and torch.equal(g, f), on
            else:
                assert g is None, on
    # The native call: a gradient not wanted is None.
    base = r._renderer(r.theta)
    s = np.ascontiguousarray(cube0.numpy())
    m = np.ascontiguousarray(r.mask().detach().double().numpy())
    g = np.ones((2,) + tuple(r.image_shape))
    gp, gm, gs = base.vjp(s, m, g, params=True, mask_grad=False, scene_grad=False)
    assert gm is None and gs is None and gp.shape == (2,)
    assert np.array_equal(gp, base.vjp(s, m, g)[0])
    r.mask_logits.requires_grad_(True)
    r.theta.requires_grad_(True)
