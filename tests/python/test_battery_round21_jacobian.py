"""Held-out battery, round 21 (prober `signals`, findings 1 and 2): the Jacobian entry points applied no budget.

- `CassiRenderer.mapping_jacobian` traced H·W·L chief rays with tangents unchecked (128² × 1500 wavelengths grew
  to 8.3 GB under max_memory_gb=0.5 and died by SIGABRT). The library's `DiffRenderer::mapping_jacobian` now checks
  the ray budget and its estimate (`limits::bytes_mapping_jacobian`: the returned arrays and one traced block)
  before allocating, and traces a block of rays at a time into the returned arrays.
- `diffcassi.jacobian` ((N, 6, K) float64, a K-fold amplification of its input) and `diffcassi.trace` checked
  neither max_memory_gb nor max_rays; they apply `limits::check_jacobian` / `limits::check_traced_rays` (the
  CLI's `trace`/`spot` use the latter) before anything N-sized is allocated.
"""
import numpy as np
import pytest

torch = pytest.importorskip("torch", reason="PyTorch not installed (DIFFCASSI_TORCH=skip)")
import diffcassi  # noqa: E402
import diffcassi.torch as dt  # noqa: E402

BANDS = [450.0, 550.0, 650.0]


@pytest.fixture(scope="module")
def sp():
    return diffcassi.System.preset("sp")


@pytest.fixture
def default_limits():
    yield
    diffcassi.set_limits()


@pytest.fixture(scope="module")
def renderer():
    return dt.CassiRenderer(diffcassi.System.preset("msp"), 16, 16, free=["prism_tilt_x", "prism_tilt_y"], rays=1,
                            planes=3, bands_nm=BANDS)


def rays(sp, n):
    o, d, w = sp.seeded_rays(300, [450.0, 520.0, 650.0], 1)
    reps = -(-n // len(w))
    tile = lambda a: np.ascontiguousarray(np.tile(a, (reps,) + (1,) * (a.ndim - 1))[:n])  # noqa: E731
    return tile(o), tile(d), tile(w)


# ------------------------------------------------------------------ finding 1: mapping_jacobian
def test_mapping_jacobian_refuses_over_the_memory_budget_before_allocating(renderer, default_limits):
    # 16 × 16 × 10⁵ wavelengths: 2.56·10⁷ chief rays, ~2.4 GB of result; refused at once (before, it traced).
    wl = np.linspace(450.0, 650.0, 100_000)
    diffcassi.set_limits(max_memory_gb=0.5)
    with pytest.raises(diffcassi.DiffcassiValueError,
                       match=r"mapping Jacobian: H × W × wavelengths \(16 × 16 × 100000\) chief rays, 2 free parameters: "
                             r"needs an estimated [0-9.]+ GB of memory, over the budget of 0.50 GB \(max_memory_gb=0.5\); "
                             r"reduce the scene size or the wavelengths or raise max_memory_gb"):
        renderer.mapping_jacobian(wl)


def test_mapping_jacobian_refuses_over_the_ray_budget(renderer, default_limits):
    diffcassi.set_limits(max_rays=1000)
    with pytest.raises(diffcassi.DiffcassiValueError, match=r"\(16 × 16 × 8\) chief rays, 2 free parameters: 2048 rays to trace, over the budget of 1000 "
                                                            r"\(max_rays; .*reduce the scene size or the wavelengths or raise max_rays"):
        renderer.mapping_jacobian(np.linspace(450.0, 650.0, 8))


def test_mapping_jacobian_in_blocks_equals_the_calls_of_each_half(renderer):
    # 16 × 16 × 300 = 76 800 entries: two blocks of the library's 65 536-ray trace; each half of the wavelengths
    # is one block. Every ray is independent, so the halves are the whole's, bit for bit.
    wl = np.linspace(450.0, 650.0, 300)
    pos, jac, valid = renderer.mapping_jacobian(wl)
    assert pos.shape == (16, 16, 300, 2) and jac.shape == (16, 16, 300, 2, 2) and valid.shape == (16, 16, 300)
    assert valid.all() and np.abs(jac).max() > 0
    for part in (slice(0, 150), slice(150, 300)):
        p, j, v = renderer.mapping_jacobian(wl[part])
        assert np.array_equal(p, pos[:, :, part]) and np.array_equal(j, jac[:, :, part]) and np.array_equal(v, valid[:, :, part])


def test_a_small_mapping_jacobian_still_works_under_a_small_budget(renderer, default_limits):
    diffcassi.set_limits(max_memory_gb=0.05, max_rays=10_000)
    pos, jac, valid = renderer.mapping_jacobian(BANDS)
    assert pos.shape == (16, 16, 3, 2) and valid.all() and np.isfinite(jac).all()


# ------------------------------------------------------------------ finding 2: jacobian and trace
def test_jacobian_refuses_over_the_ray_budget(sp, default_limits):
    o, d, w = rays(sp, 18_000)
    diffcassi.set_limits(max_rays=1000)
    with pytest.raises(diffcassi.DiffcassiValueError,
                       match=r"jacobian of N × K = 18000 rays × 1 parameters: 18000 rays to trace, over the budget of 1000 "
                             r"\(max_rays; .*reduce the rays or the parameters or raise max_rays \(diffcassi.set_limits\)"):
        diffcassi.jacobian(sp, "prism_tilt_x", o, d, w)


def test_jacobian_refuses_over_the_memory_budget(sp, default_limits):
    # 2·10⁵ rays × 8 parameters: (220 + 48·8) B × 1.1 per ray = 0.133 GB, over a 0.1 GB budget.
    o, d, w = rays(sp, 200_000)
    names = ["prism_tilt_x", "prism_tilt_y", "prism_tilt_z", "wavelength", "ray.origin_x", "ray.origin_y", "ray.dir_x", "ray.dir_y"]
    diffcassi.set_limits(max_memory_gb=0.1)
    with pytest.raises(diffcassi.DiffcassiValueError,
                       match=r"jacobian of N × K = 200000 rays × 8 parameters: needs an estimated 0.13 GB of memory, over the "
                             r"budget of 0.10 GB \(max_memory_gb=0.1\); reduce the rays or the parameters or raise max_memory_gb"):
        diffcassi.jacobian(sp, names, o, d, w)
    # The same rays with one parameter fit ((220 + 48) × 1.1 B per ray = 0.059 GB).
    r = diffcassi.jacobian(sp, "prism_tilt_x", o, d, w)
    assert r["jacobian"].shape == (200_000, 6, 1) and r["available"].any()


def test_trace_refuses_over_the_ray_budget_and_memory_budget(sp, default_limits):
    o, d, w = rays(sp, 18_000)
    diffcassi.set_limits(max_rays=1000)
    with pytest.raises(diffcassi.DiffcassiValueError,
                       match=r"trace of N = 18000 rays: 18000 rays to trace, over the budget of 1000 .*reduce the rays or raise max_rays"):
        diffcassi.trace(sp, o, d, w)
    # 160 B per ray (the CLI's `trace` figure): 18 000 rays are 2.88 MB, over 1 MB.
    diffcassi.set_limits(max_memory_gb=0.001)
    with pytest.raises(diffcassi.DiffcassiValueError, match=r"trace of N = 18000 rays: needs an estimated 2.880e-3 GB of memory"):
        diffcassi.trace(sp, o, d, w)
    diffcassi.set_limits(max_rays=18_000)
    t = diffcassi.trace(sp, o, d, w)
    assert t["positions"].shape == (18_000, 3)
