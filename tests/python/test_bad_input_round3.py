"""Issue 39 (reliability round 3), the Python part: CassiRenderer refuses cubes that are not floating point
(naming the dtype) and never returns inf for a narrow dtype; its arguments are checked and named (no bare
OverflowError/AttributeError, no silent truncation of 1.7 or 8.9); its rays and memory are within the budgets,
which Python sets with ``diffcassi.set_limits`` and whose refusals name those keywords; radiances and masks
within the CLI's limits; load_unrolled/load_weights/System.from_file/denoise name a directory as one. Issue 40:
the render settings' ``device`` (cpu only in this build) and the conflicting-keyword refusals."""
import subprocess
import sys

import numpy as np
import pytest

import diffcassi
from conftest import ROOT, SMALL, random_cube

torch = pytest.importorskip("torch", reason="PyTorch not installed (DIFFCASSI_TORCH=skip)")
import diffcassi.torch as dt  # noqa: E402

BANDS = [450.0, 550.0, 650.0]
WL = SMALL["bands_nm"]


@pytest.fixture(scope="module")
def sp():
    return diffcassi.System.preset("sp")


@pytest.fixture(scope="module")
def tiny(sp):
    return dt.CassiRenderer(sp, 4, 4, rays=1, planes=3, bands_nm=BANDS)


@pytest.fixture
def default_limits():
    yield
    diffcassi.set_limits()


# ------------------------------------------------------------------ dtypes of the cube
@pytest.mark.parametrize("dtype", [torch.int64, torch.int32, torch.bool, torch.complex64, torch.uint8])
def test_non_floating_cubes_are_refused_naming_the_dtype(tiny, dtype):
    x = torch.ones(1, 3, 4, 4).to(dtype)
    with pytest.raises(TypeError, match=rf"CassiRenderer.forward: cube: expected a floating-point tensor .* got {dtype}"):
        tiny(x)
    with pytest.raises(TypeError, match=rf"CassiRenderer.render: cube: .* got {dtype}"):
        tiny.render(x, tiny.mask().detach())


@pytest.mark.parametrize("cube", [np.ones((1, 3, 4, 4), np.float32), [[[[1.0] * 4] * 4] * 3], 1.0])
def test_a_cube_that_is_not_a_tensor_is_a_type_error(tiny, cube):
    with pytest.raises(TypeError, match="cube: expected a torch.Tensor"):
        tiny(cube)


def test_half_precision_cubes_never_return_inf(tiny):
    # All open, a pixel collects 1.28× the radiance: 7.7·10⁴ > 65504 (before: inf in float16).
    big = torch.full((1, 3, 4, 4), 6e4, dtype=torch.float16)
    with pytest.raises(diffcassi.DiffcassiValueError, match=r"acquisition reaches 76860.7, beyond torch.float16's range \(largest 65504\)"):
        tiny.render(big, torch.ones(4, 4, dtype=torch.float16))
    # In range: computed in float64, returned in float16 and bfloat16, equal to the float64 result rounded.
    x = torch.rand(1, 3, 4, 4, generator=torch.Generator().manual_seed(3))
    ref = tiny(x.double()).detach()
    for dtype in (torch.float16, torch.bfloat16):
        y = tiny(x.to(dtype)).detach()
        assert y.dtype == dtype and torch.isfinite(y).all()
        assert float((y.double() - ref).abs().max()) <= 0.02 * float(ref.abs().max())


def test_radiance_beyond_the_cli_limit_is_refused(tiny):
    x = torch.ones(1, 3, 4, 4, dtype=torch.float64)
    x[0, 1, 2, 3] = 1e300
    with pytest.raises(diffcassi.DiffcassiValueError, match=r"scene: value 1e300 at index \[0, 1, 2, 3\]: radiances must be ≤ 3.403e29"):
        tiny(x)
    x[0, 1, 2, 3] = 3e29  # within the limit
    assert torch.isfinite(tiny(x)).all()


# ------------------------------------------------------------------ arguments named
@pytest.mark.parametrize("kwargs, message", [
    (dict(rays=-1), r"rays: expected an integer in 1..=18446744073709551615, got int -1"),
    (dict(rays=0), r"rays: expected an integer in 1..=18446744073709551615, got int 0"),
    (dict(rays=1.7), r"rays: expected an integer in 1..=18446744073709551615, got float 1.7"),
    (dict(rays=float("nan")), r"rays: expected an integer in 1..=18446744073709551615, got float nan"),
    (dict(rays=2 ** 70), r"rays: expected an integer in 1..=18446744073709551615"),
    (dict(H=-4), r"H: expected an integer in 1..=18446744073709551615, got int -4"),
    (dict(H=8.9), r"H: expected an integer in 1..=18446744073709551615, got float 8.9"),
    (dict(W=True), r"W: expected an integer in 1..=18446744073709551615, got bool True"),
    (dict(seed=-1), r"seed: expected an integer in 0..=18446744073709551615, got int -1"),
    (dict(mask_seed=-2), r"mask_seed: expected an integer in 0..=18446744073709551615, got int -2"),
    (dict(planes=2.0), r"planes: expected an integer in 1..=18446744073709551615, got float 2.0"),
    (dict(free=[""]), r"free: name 0 is empty"),
    (dict(free=["prism_tilt_x", " "]), r"free: name 1 is empty"),
    (dict(mask=np.full((4, 4), 2.0)), r"mask: values must be finite and in \[0, 1\]"),
])
def test_constructor_arguments_are_named(sp, kwargs, message):
    args = dict(H=4, W=4, rays=1, planes=3, bands_nm=BANDS)
    args.update(kwargs)
    with pytest.raises(diffcassi.DiffcassiValueError, match=message):
        dt.CassiRenderer(sp, **args)


@pytest.mark.parametrize("kwargs, message", [
    (dict(free=None), r"free: expected a parameter name or a list of names .* got NoneType"),
    (dict(free=[3]), r"free: expected a parameter name or a list of names"),
    (dict(mask="random"), r"mask: expected None or an \(4, 4\) array .* got str 'random'"),
    (dict(mask=np.ones((4, 4), np.complex64)), r"mask: expected real values in \[0, 1\], got dtype complex64"),
    (dict(airy="no"), r"airy: expected True or False, got str"),
    (dict(straight_through=1), r"straight_through: expected True or False, got int"),
])
def test_constructor_argument_types_are_named(sp, kwargs, message):
    args = dict(H=4, W=4, rays=1, planes=3, bands_nm=BANDS)
    args.update(kwargs)
    with pytest.raises(TypeError, match=message):
        dt.CassiRenderer(sp, **args)


def test_masks_as_tensors_and_bools_are_accepted(sp):
    m = torch.zeros(4, 4)
    m[::2] = 1
    a = dt.CassiRenderer(sp, 4, 4, rays=1, planes=3, bands_nm=BANDS, mask=m)
    b = dt.CassiRenderer(sp, 4, 4, rays=1, planes=3, bands_nm=BANDS, mask=m.numpy().astype(bool))
    assert torch.equal(a.mask_logits, b.mask_logits)


def test_render_refuses_a_mask_outside_0_1_like_the_constructor(tiny):
    x = torch.rand(1, 3, 4, 4)
    with pytest.raises(diffcassi.DiffcassiValueError, match=r"CassiRenderer.render: mask: values must be finite and in \[0, 1\], got min 2.0, max 2.0"):
        tiny.render(x, torch.full((4, 4), 2.0))
    with pytest.raises(diffcassi.DiffcassiValueError, match=r"mask: values must be finite and in \[0, 1\]"):
        tiny.render(x, torch.full((4, 4), -0.5))
    with pytest.raises(TypeError, match="CassiRenderer.render: mask: expected a torch.Tensor, got float"):
        tiny.render(x, 2.0)
    assert torch.isfinite(tiny.render(x, torch.full((4, 4), 1.0))).all()


def test_a_tilt_that_breaks_the_system_names_the_free_parameter(sp):
    r = dt.CassiRenderer(sp, 4, 4, free=["prism_tilt_x"], rays=1, planes=3, bands_nm=BANDS)
    with torch.no_grad():
        r.theta[0] = 60.0
    with pytest.raises(diffcassi.DiffcassiValueError, match=r"s4.tilt_x_deg = 60.0"):
        r(torch.rand(1, 3, 4, 4))


# ------------------------------------------------------------------ budgets
def test_huge_ray_counts_are_refused_before_allocating(sp):
    # Before the fix this aborted the interpreter (8 TB); in a subprocess so a regression cannot take pytest down.
    code = ("import diffcassi, diffcassi.torch as dt\n"
            "sp = diffcassi.System.preset('sp')\n"
            "try:\n"
            "    dt.CassiRenderer(sp, 4, 4, rays=10**12, planes=3, bands_nm=[450.0, 550.0, 650.0])\n"
            "except diffcassi.DiffcassiValueError as e:\n"
            "    print(e)\n")
    r = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert "H × W × planes × rays (4 × 4 × 3 × 1000000000000)" in r.stdout, r.stdout
    assert "raise max_rays (diffcassi.set_limits)" in r.stdout or "raise max_memory_gb (diffcassi.set_limits)" in r.stdout, r.stdout


def test_set_limits_sets_the_budgets_and_messages_name_the_keywords(sp, default_limits):
    d = diffcassi.get_limits()
    assert d["max_rays"] == 2e10 and d["max_memory_gb"] > 0
    diffcassi.set_limits(max_rays=100)
    assert diffcassi.get_limits()["max_rays"] == 100
    with pytest.raises(diffcassi.DiffcassiValueError, match=r"\(4 × 4 × 3 × 4\): 192 rays to trace, over the budget of 100 \(max_rays; .*raise max_rays \(diffcassi.set_limits\)") as e:
        dt.CassiRenderer(sp, 4, 4, rays=4, planes=3, bands_nm=BANDS)
    assert "--max-rays" not in str(e.value)
    with pytest.raises(diffcassi.DiffcassiValueError, match=r"rays to trace, over the budget.*raise max_rays \(diffcassi.set_limits\)"):
        diffcassi.render(sp, random_cube(8, 8, 4), WL, **SMALL)
    diffcassi.set_limits(max_memory_gb=0.0001)
    assert diffcassi.get_limits()["memory_source"] == "max_memory_gb=0.0001"
    with pytest.raises(diffcassi.DiffcassiValueError, match=r"over the budget of 1.000e-4 GB \(max_memory_gb=0.0001\); .*raise max_memory_gb \(diffcassi.set_limits\)") as e:
        diffcassi.Transport(sp, 64, 64, **SMALL)
    assert "--max-memory-gb" not in str(e.value)
    # Back to the defaults: the same call works.
    diffcassi.set_limits()
    assert diffcassi.get_limits() == d
    diffcassi.Transport(sp, 8, 8, **SMALL)


@pytest.mark.parametrize("kwargs, message", [
    (dict(max_memory_gb=0), r"max_memory_gb=0: must be a finite number of GB > 0"),
    (dict(max_memory_gb=float("inf")), r"max_memory_gb=inf: must be a finite number"),
    (dict(max_rays=0.5), r"max_rays=0.5: must be a finite count ≥ 1"),
    (dict(max_rays="many"), r"max_rays: expected a number or None, got str 'many'"),
    (dict(max_memory_gb=True), r"max_memory_gb: expected a number or None, got bool"),
])
def test_set_limits_refuses_bad_values_and_keeps_the_budget(kwargs, message, default_limits):
    before = diffcassi.get_limits()
    with pytest.raises(diffcassi.DiffcassiValueError, match=message):
        diffcassi.set_limits(**kwargs)
    assert diffcassi.get_limits() == before


# ------------------------------------------------------------------ files and weights
def test_load_unrolled_without_an_operator_is_a_type_error(tmp_path):
    with pytest.raises(TypeError, match="load_unrolled: phi: expected a diffcassi.torch.CassiOperator .* got NoneType"):
        dt.load_unrolled(tmp_path / "w.safetensors", None)


def test_a_directory_is_reported_as_a_directory(sp, tmp_path):
    with pytest.raises(diffcassi.DiffcassiFileError, match="is a directory, not a system file"):
        diffcassi.System.from_file(tmp_path)
    phi = dt.CassiOperator.from_operator(diffcassi.exact(sp, 4, 4, **SMALL))
    with pytest.raises(diffcassi.DiffcassiFileError, match="unrolled weights .*: is a directory, not a weights file"):
        dt.load_unrolled(tmp_path, phi)
    from diffcassi.denoiser import load_weights
    with pytest.raises(IsADirectoryError, match="denoiser weights .*: is a directory"):
        load_weights(tmp_path)
    with pytest.raises(diffcassi.DiffcassiFileError, match="weights .*: is a directory, not a weights file"):
        diffcassi.denoise(np.zeros((4, 4, 4), np.float32), 0.1, weights=str(tmp_path))


# ------------------------------------------------------------------ render settings (issue 40)
def _has_cuda_driver() -> bool:
    """Whether the CUDA driver library loads here (the library's probe opens the same file)."""
    import ctypes
    try:
        ctypes.CDLL("libcuda.so.1")
        return True
    except OSError:
        return False


def test_device_cpu_twin_and_cuda_without_a_gpu(sp):
    cube = random_cube(8, 8, 4)
    a, info = diffcassi.render(sp, cube, WL, **SMALL)
    b, _ = diffcassi.render(sp, cube, WL, device="cpu", **SMALL)
    assert np.array_equal(a, b)
    assert info["device"]["device"] == "cpu"
    # The GPU kernels on the CPU: the CPU's acquisition to its f32 rounding, recorded as such.
    t, tinfo = diffcassi.render(sp, cube, WL, device="cpu-twin", **SMALL)
    assert tinfo["device"]["device"] == "cpu-twin" and tinfo["device"]["precision"] == "f64"
    assert np.abs(t - a).max() <= 1e-6 * np.abs(a).max()
    # Host-only calls never ignore a device: they say where the GPU path is.
    for call in (lambda: diffcassi.Transport(sp, 8, 8, device="cpu-twin", **SMALL), lambda: diffcassi.exact(sp, 8, 8, device="cpu-twin", **SMALL)):
        with pytest.raises(diffcassi.DiffcassiValueError, match=r'(Transport|exact): device="cpu-twin": .*computes on the CPU.*\.to\("cuda"\)'):
            call()
    # device="cuda" too, with or without a driver (the device probe blamed a missing driver; round 12).
    for call in (lambda: diffcassi.Transport(sp, 8, 8, device="cuda", **SMALL), lambda: diffcassi.exact(sp, 8, 8, device="cuda:1", **SMALL),
                 lambda: diffcassi.shift_operator(sp, 8, 8, device="cuda", **SMALL)):
        with pytest.raises(diffcassi.DiffcassiValueError, match=r'device="cuda(:1)?": .*computes on the CPU.*\.to\("cuda"\)'):
            call()
    if not _has_cuda_driver():
        with pytest.raises(diffcassi.DiffcassiValueError, match='device "cuda": (no NVIDIA driver|no CUDA device|the NVIDIA driver is installed but).*use device="cpu"'):
            diffcassi.render(sp, cube, WL, device="cuda", **SMALL)
        with pytest.raises(diffcassi.DiffcassiValueError, match="gpu_check: no CUDA device"):
            diffcassi.gpu_check(sp, cube, WL, **SMALL)
    with pytest.raises(diffcassi.DiffcassiValueError, match="device \"tpu\": use cpu, cuda or cuda:N"):
        diffcassi.Transport(sp, 8, 8, device="tpu", **SMALL)


def test_mapping_on_the_gpu_kernels(sp):
    """mapping(device="cpu-twin"): the GPU trace kernels on the CPU give the CPU's cube bit for bit (f64) and
    the f32 lane kernel's (f32); "cuda" without a GPU, an unknown device and a backend beside a device are
    refused by name."""
    ws = [450.0, 550.0, 650.0]
    for precision in ("f64", "f32"):
        a, va = diffcassi.mapping(sp, 6, 7, ws, pitch_mm=3.0, precision=precision)
        b, vb = diffcassi.mapping(sp, 6, 7, ws, pitch_mm=3.0, device="cpu-twin", precision=precision)
        assert va.any() and not va.all()  # the outer pixels' chief rays do not arrive
        assert np.array_equal(va, vb) and np.array_equal(a.view(np.uint64), b.view(np.uint64)), precision
    if not _has_cuda_driver():
        with pytest.raises(diffcassi.DiffcassiValueError, match='device "cuda": .*(NVIDIA driver|CUDA device).*use device="cpu"'):
            diffcassi.mapping(sp, 4, 4, ws, device="cuda")
    with pytest.raises(diffcassi.DiffcassiValueError, match="device \"tpu\": use cpu, cuda or cuda:N"):
        diffcassi.mapping(sp, 4, 4, ws, device="tpu")
    with pytest.raises(diffcassi.DiffcassiValueError, match='backend="embree-user" cannot be combined'):
        diffcassi.mapping(sp, 4, 4, ws, device="cpu-twin", backend="embree-user")


def test_conflicting_render_keywords_are_refused(sp):
    cube = random_cube(8, 8, 4)
    with pytest.raises(diffcassi.DiffcassiValueError, match="airy=False with airy_diameter_px"):
        diffcassi.render(sp, cube, WL, airy=False, airy_diameter_px=3.0, **SMALL)
    mask = np.ones((8, 8), np.float32)
    with pytest.raises(diffcassi.DiffcassiValueError, match="mask with opening or mask_seed"):
        diffcassi.render(sp, cube, WL, mask, opening=0.3, **SMALL)
    with pytest.raises(diffcassi.DiffcassiValueError, match="mask with opening or mask_seed"):
        diffcassi.Transport(sp, 8, 8, mask, mask_seed=2, **SMALL)
    # Each alone is fine.
    diffcassi.render(sp, cube, WL, airy=False, **SMALL)
    diffcassi.render(sp, cube, WL, mask, **SMALL)
