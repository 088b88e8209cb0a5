"""diffcassi: coded-aperture snapshot spectral imager (CASSI) simulation from Python.

Exact f64 ray tracing (Zemax-exact), Monte-Carlo rendering of coded acquisitions, the dataset-mode light
transport as an object, and (when built with them) the reconstruction operators, solvers and metrics of the
Rust library ``diffcassi``. NumPy in, NumPy out; the GIL is released during every heavy call; the thread
count is set with :func:`set_num_threads`. See docs/python.md.

>>> import numpy as np, diffcassi
>>> sp = diffcassi.System.preset("sp")
>>> scene = np.ones((16, 16, 28), np.float32)
>>> acq, info = diffcassi.render(sp, scene, np.linspace(450, 650, 28), rays=2, planes=28)
>>> acq.shape == (info["detector"]["height"], info["detector"]["width"])
True
"""
from __future__ import annotations

import json as _json
import os
import re
from typing import Any, Dict, List, Optional, Sequence, Tuple, Union

import numpy as np

from . import _files

from . import _native
from ._errors import DiffcassiError, DiffcassiFileError, DiffcassiValueError

# rayon sizes its default pool by RAYON_NUM_THREADS: a huge value would start that many threads at the first
# heavy call (100 000 hung). Refused at import, by the CLI's check (limits::check_rayon_env).
_native._check_rayon_env()
from ._native import (Operator, System, Transport, get_limits, get_num_threads, jacobian, load_scene, mapping, read_exr,
                      set_limits, set_num_threads, synthetic_scene, trace, uplift_srgb)

__version__: str = _native.__version__
#: Whether the Embree backends (``embree-user``, ``embree-mesh``) were compiled in.
EMBREE: bool = _native.EMBREE

#: Ray status codes of :func:`trace` (``status`` array) and their names (the library's ``RayStatus``: every
#: code it returns, 0 ``ok`` … 9 ``evanescent``).
STATUS: dict = dict(_native.STATUS)

__all__ = [
    "System", "Transport", "Operator", "exact", "metrics", "load_scene", "synthetic_scene", "uplift_srgb", "trace", "spot", "distortion", "dispersion", "mapping", "jacobian", "render", "gpu_check",
    "read_exr", "set_num_threads", "get_num_threads", "set_limits", "get_limits", "surfaces", "DiffcassiError", "DiffcassiValueError",
    "DiffcassiFileError", "STATUS", "EMBREE", "__version__",
]


def _check_backend(backend: str) -> str:
    if not isinstance(backend, str):
        raise DiffcassiValueError(f"backend: expected a string such as 'analytic', got {type(backend).__name__}")
    if backend.startswith("embree") and not EMBREE:
        raise DiffcassiValueError(
            f"backend `{backend}`: this diffcassi was built without Embree; install Embree 4.3 "
            "(bash scripts/setup.sh) and reinstall (pip install .), or use backend='analytic'")
    return backend


# The native ray-batch calls, each behind the same backend check as `spot`, `render`, … so that a build without
# Embree (the wheel) names the fix a wheel user can act on (round 21: these four said "rebuild with the default
# `embree` feature", cargo's). `Transport` takes its backend among the render keywords; the library's own
# refusal (`tracer::embree_missing`) gives it the same text.
_native_trace, _native_jacobian, _native_mapping = trace, jacobian, mapping


def trace(system: System, origins: Any, directions: Any, wavelengths_nm: Any, backend: str = "analytic") -> Dict[str, Any]:
    return _native_trace(system, origins, directions, wavelengths_nm, _check_backend(backend))


def jacobian(system: System, parameters: Any, origins: Any, directions: Any, wavelengths_nm: Any, backend: str = "analytic") -> Dict[str, Any]:
    return _native_jacobian(system, parameters, origins, directions, wavelengths_nm, _check_backend(backend))


def mapping(system: System, height: int, width: int, wavelengths_nm: Sequence[float], pitch_mm: Optional[float] = None,
            backend: str = "analytic", device: str = "cpu", precision: str = "f64", scene_fov_deg: Optional[float] = None) -> Any:
    return _native_mapping(system, height, width, wavelengths_nm, pitch_mm=pitch_mm, backend=_check_backend(backend), device=device,
                           precision=precision, scene_fov_deg=scene_fov_deg)


trace.__doc__, jacobian.__doc__, mapping.__doc__ = _native_trace.__doc__, _native_jacobian.__doc__, _native_mapping.__doc__


def surfaces(system: System) -> list:
    """The resolved Lens Data Editor of ``system``: one dict per surface (index, kind, material, radius_mm,
    thickness_mm, conic, semi_diameter_mm, decenters, tilts, vertex_global_mm)."""
    return _json.loads(system._surfaces_json())


# `System.surfaces` as a property (the class is compiled; the property is added here).
System.surfaces = property(surfaces, doc=surfaces.__doc__)  # type: ignore[attr-defined]


def spot(system: System, field_mm: Optional[Sequence[float]], wavelength_nm: float, pupil: Union[str, np.ndarray, None] = None,
         backend: str = "analytic", field_deg: Optional[Sequence[float]] = None) -> Dict[str, Any]:
    """Spot diagram of one field (x, y mm; at infinity ``field_mm=None, field_deg=(x, y)`` in degrees, as
    :meth:`System.rays_for_field`) at one wavelength: a dict with ``x_mm``, ``y_mm``, ``status``,
    ``pupil``, ``chief_mm``, ``stats`` (centroid_mm, rms_radius_um, geo_radius_um),
    ``rms_radius_chief_um`` and ``lost`` (the lost rays by outcome and stopping surface, most first: dicts
    ``{status, surface, count}``). ``pupil``: a pattern (default ``hexapolar:12``, as the CLI) or (N, 2) float64
    normalised pupil points. Arrays are returned as NumPy float64."""
    # The native call returns the small parts as JSON and the per-ray parts as arrays and a list, made
    # without the GIL (a JSON of a million rays parsed here held it for seconds).
    text, (pupil_pts, x, y, status) = _native._spot(system, None if field_mm is None else _pair("field_mm", field_mm),
                                                    _number("wavelength_nm", wavelength_nm), pupil, _check_backend(backend),
                                                    None if field_deg is None else _pair("field_deg", field_deg))
    d = _json.loads(text)
    d.update(pupil=pupil_pts, x_mm=x, y_mm=y, status=status)
    return d


def distortion(system: System, wavelength_nm: Optional[float] = None, grid: int = 13, half_width_mm: float = 2.5,
               backend: str = "analytic") -> Dict[str, Any]:
    """Zemax-style grid distortion (``grid`` × ``grid`` chief rays over ±``half_width_mm``) at
    ``wavelength_nm`` (default: the primary): dict with ``reference_mm``, ``abcd``, ``max_distortion_pct`` and
    ``points`` (one dict per grid point, as the CLI's CSV)."""
    w = system.primary_wavelength_nm if wavelength_nm is None else _number("wavelength_nm", wavelength_nm)
    text, chunks = _native._distortion(system, w, grid, _number("half_width_mm", half_width_mm), _check_backend(backend))
    d = _json.loads(text)
    # One chunk per iteration of a Python loop: the interpreter hands the GIL to a waiting thread between two
    # (a native loop did not; see `_distortion` in python/src/system.rs).
    points: List[Dict[str, Any]] = []
    for chunk in chunks:
        points.extend(_json.loads(chunk))
    d["points"] = points
    return d


def dispersion(system: System, wavelengths_nm: Sequence[float] = tuple(np.linspace(450, 650, 28)),
               field_mm: Optional[Sequence[float]] = None, backend: str = "analytic",
               field_deg: Optional[Sequence[float]] = None) -> Dict[str, Any]:
    """Chief-ray positions of one field over wavelength (the paper's spreading curve): dict with
    ``wavelength_nm``, ``x_mm``, ``y_mm`` (NumPy arrays) and ``spread_um``. The field: ``field_mm`` (an object
    height) or, at infinity, ``field_deg`` (angles); neither: the axis, in the system's own unit."""
    if field_mm is None and field_deg is None:
        field_deg, field_mm = ((0.0, 0.0), None) if system.object_at_infinity else (None, (0.0, 0.0))
    d = _json.loads(_native._dispersion(system, None if field_mm is None else _pair("field_mm", field_mm), wavelengths_nm,
                                        _check_backend(backend), None if field_deg is None else _pair("field_deg", field_deg)))
    for k in ("wavelength_nm", "x_mm", "y_mm"):
        d[k] = np.asarray(d[k], dtype=np.float64)
    return d


def render(system: System, scene: np.ndarray, wavelengths_nm: Sequence[float], mask: Optional[np.ndarray] = None, *,
           bands_nm: Optional[Sequence[float]] = None, planes: Optional[int] = None, rays: Optional[int] = None,
           seed: Optional[int] = None, sampling: Optional[str] = None, opening: Optional[float] = None,
           mask_seed: Optional[int] = None, airy_diameter_px: Optional[float] = None, airy: Optional[bool] = None,
           backend: Optional[str] = None, noise: Optional[dict] = None, device: Optional[str] = None,
           precision: Optional[str] = None, scene_fov_deg: Optional[float] = None,
           tolerance_um: Optional[float] = None, calibration_cache: Optional[str] = None) -> Tuple[np.ndarray, Dict[str, Any]]:
    """Render the coded acquisition of ``scene`` through ``system``.

    ``scene``: (H, W, B) float32, C-contiguous, finite, its bands at ``wavelengths_nm`` (B values).
    Every setting left at ``None`` is the CLI's default (``diffcassi render --help``): bands 450:650:28,
    planes 112, rays 20 per pixel per plane, seed 0, stratified sampling, a random binary mask of opening
    0.5 and seed 0 (or ``mask``: (H, W) float32 in [0, 1]), Airy disk 2.5 px at 520 nm. So
    ``render(sp, cube, wl)`` equals ``diffcassi render --preset sp --scene cube.npy --scene-size N`` bit for
    bit. ``noise``: sensor noise as the CLI's ``--noise`` options: ``"shot,read,adc"`` or a dict
    ``{"noise": "shot,read", "full_well_e": 20000, "read_noise_e": 2, "adc_bits": 12, "noise_seed": 0,
    "electrons_per_unit": ...}`` (``None``: a clean acquisition, the default); ``info["noise"]`` reports it.
    ``device``: ``"cpu"`` (the default), ``"cuda"`` / ``"cuda:N"`` (the GPU kernels on CUDA device 0 / N, f64; refused with
    what is missing where there is none; ``info["device"]`` names the GPU, the driver and the accumulation) or
    ``"cpu-twin"`` (the GPU kernels run on the CPU: the device's bits, slowly). docs/gpu.md. ``precision``:
    ``"f64"`` (the default) or ``"f32"`` (the ray kernel in f32, as ``--precision``; on any device).
    ``scene_fov_deg``: for a system whose object is at infinity (``System.object_at_infinity``), the scene's
    full angular extent across its width in degrees, in (0, 180) (the CLI's ``--scene-fov-deg``): pixels are
    uniform in field angle, and ``info["scene_fov_deg"]`` records it. Required at infinity, refused for a
    finite object (whose scene lies on the object plane at 10 µm per pixel). The operators (:func:`exact`,
    :func:`mapping_operator`, :func:`shift_operator`) and :class:`Transport` take it too.
    ``backend``: the tracer (``None``: ``"analytic"``). ``tolerance_um``: instead of ``backend``, ``rays`` and
    ``precision`` (refused beside them), the cheapest backend, rays per pixel and precision whose predicted error
    of where a scene pixel's energy lands is within this many µm on the detector, calibrated on ``system`` over the
    render's planes and scene (the CLI's ``--tolerance-um``; docs/tradeoff.md; seconds the first time, then cached
    in ``calibration_cache`` or the CLI's default cache folder); ``info["tolerance_um"]``,
    ``info["tolerance_predicted_error_um"]`` (``None`` without a tolerance) and ``info["fidelity_choice"]`` (the
    choice and its candidates) record it. On ``device="cuda"`` it chooses the analytic f64 tracer's rays only.
    The memory and ray budgets are the CLI's defaults unless :func:`set_limits` changed them.

    Returns ``(acquisition, info)``: the detector image (h, w) float64 and a dict with ``render.json``'s
    keys (``acquisition_total``, ``detector``, ``bands_nm``, ``planes_nm``, ``rays_traced``, ...). Planes that lie
    more than one band beyond the scene's bands (its spectrum held constant there) give a ``UserWarning`` and
    ``info["spectral_extrapolation"]``; a scene entirely outside the render's planes is refused. As the CLI, a
    zero acquisition, and sensor noise whose exposure puts less than one electron in the brightest pixel, give a
    ``UserWarning`` naming why; so do a dual-disperser system whose mask passes nothing at some planes
    (``info["mask_dark_planes"]``), an f32 render whose measured chief-ray error exceeds 0.1 µm
    (``info["f32_chief_ray_error"]``, recorded for every f32 render), and a device render of a scene whose
    dynamic range the fixed-point accumulation resolves coarsely (``info["device"]["fixed_point_warning"]``).
    """
    nz: Dict[str, Any] = {}
    if isinstance(noise, str):
        nz = {"noise": noise}
    elif isinstance(noise, dict):
        nz = dict(noise)
        unknown = set(nz) - {"noise", "full_well_e", "electrons_per_unit", "read_noise_e", "adc_bits", "noise_seed"}
        if unknown:
            raise DiffcassiValueError(f"noise: unknown keys {sorted(unknown)} (use noise, full_well_e, electrons_per_unit, "
                                      "read_noise_e, adc_bits, noise_seed: the CLI's --noise options)")
    elif noise is not None:
        raise DiffcassiValueError(f"noise: expected None, a string such as 'shot,read,adc' or a dict, got {type(noise).__name__}")
    if device is not None:  # checked here: the native reader named only "cpu", and took " cpu" (trimmed)
        if not isinstance(device, str):
            raise TypeError(f'device: expected "cpu", "cuda", "cuda:N", "cpu-twin" or None, got '
                                      f"{type(device).__name__} {device!r}")
        if device != device.strip() or not device:
            raise DiffcassiValueError(f'device {device!r}: expected "cpu", "cuda", "cuda:N" or "cpu-twin" (no spaces '
                                      "around it)")
    acq, info = _native._render(system, scene, wavelengths_nm, mask, bands_nm=bands_nm, planes=planes, rays=rays, seed=seed,
                                sampling=sampling, opening=opening, mask_seed=mask_seed, airy_diameter_px=airy_diameter_px,
                                airy=airy, backend=None if backend is None else _check_backend(backend), device=device,
                                precision=precision, scene_fov_deg=scene_fov_deg, tolerance_um=tolerance_um,
                                calibration_cache=None if calibration_cache is None else os.fspath(calibration_cache), **nz)
    info = _json.loads(info)
    import warnings
    # The CLI's: an exposure below an electron, a zero acquisition, planes beyond the scene's bands (held at
    # its end band), a dual disperser's dark planes, the f32 kernel's rounding.
    for text in info.pop("warnings", []):
        warnings.warn(text, stacklevel=2)
    return acq, info


def gpu_check(system: System, scene: np.ndarray, wavelengths_nm: Sequence[float], twin: bool = True,
              dry_run: bool = False, **settings: Any) -> Dict[str, Any]:
    """The GPU's figures on one render of ``scene`` (the keywords of :func:`render`): the acquisition on the
    CUDA device twice (time; ``runs_bit_identical``), on the CPU (``cpu_max_rel_diff``: the largest difference
    relative to the CPU's peak), through the host twin (``twin_bit_identical``, ``twin_max_rel_diff``) when
    ``twin``, and the middle plane's rays landed on both (``landing_max_diff_mm``, ``landing_status_mismatches``);
    ``at_infinity``: the object is at infinity, where the device's ``tan`` may differ from the host's by 2 ulp
    (docs/gpu.md). Needs a CUDA device — except with ``dry_run``: the host twin stands in for the device (the same
    plan, renders, landings and comparisons; ``dry_run`` is True in the report and no figure is a GPU's), to check
    the check on a machine without a GPU (``scripts/gpu_check.sh`` with ``DRY_RUN=1``)."""
    _check_backend(settings.get("backend", "analytic"))
    return _json.loads(_native._gpu_check(system, scene, wavelengths_nm, twin, bool(dry_run), **settings))


def _warn_dark_bands(op: Operator, what: str) -> Operator:
    """Warn (``UserWarning``) when no detector pixel sees some band of ``op`` (Φᵀ𝟙 = 0 over the band): a
    reconstruction gives 0 there, not an estimate. ``render`` warns of planes the mask passes no light at; an
    operator of the same settings was built silently (ddsp at 3×3: zero in every band but one; a held-out
    battery, round 17). One adjoint of the operator (``Operator.dark_bands``, as the solvers find them)."""
    dark = op.dark_bands()
    if dark:
        b = op.cube_shape[2]
        import warnings

        bands, settings_bands = None, None
        try:
            settings_bands = op.__reduce__()[1][2].get("bands_nm")
        except Exception:
            pass
        shown, more = dark[:8], (f", … {len(dark) - 8} more" if len(dark) > 8 else "")
        if settings_bands is not None and len(settings_bands) == b:
            bands = ", ".join(f"{float(settings_bands[k]):g} nm" for k in shown) + more
        warnings.warn(f"{what}: {len(dark)} of {b} bands ({bands or 'index ' + ', '.join(map(str, shown)) + more}) are seen "
                      "by no detector pixel (Φᵀ𝟙 = 0 over the band): a reconstruction gives 0 there, not an estimate "
                      "(fewer render planes than bands left them unsampled, or the mask is closed or passed by where "
                      "their light lands: more planes, a wider scene or narrower bands_nm)",
                      UserWarning, stacklevel=3)
    return op


def exact(system: System, height: int, width: int, mask: Optional[np.ndarray] = None, **settings: Any) -> Operator:
    """The ``exact`` operator Φ: the renderer's own light transport as a linear map from a float32 cube
    (H, W, B) at the render bands (``bands_nm``, default the CLI's 450:650:28) to the detector image (h, w).
    ``settings``: the keywords of :func:`render` (planes, rays, seed, sampling, opening, mask_seed,
    airy_diameter_px, airy, backend). ``Transport(...).operator`` gives the same operator sharing a trace.
    Warns (``UserWarning``) when no detector pixel sees a band."""
    _check_backend(settings.get("backend", "analytic"))
    return _warn_dark_bands(_native.exact_operator(system, height, width, mask, **settings), "exact")


def _check_twin_recipe(op: Operator, twin: Operator) -> None:
    """A ``noise_twin`` is the operator's recipe with another ``seed`` (same system, size, mask and settings):
    a twin of another mask or opening was taken and gave δ up to 1.8× too large (a held-out battery, round 10).
    The native solve also refuses a model operator and the same seed (its images equal the operator's)."""
    (_, (f1, a1, k1, v1)), (_, (f2, a2, k2, v2)) = op.__reduce__(), twin.__reduce__()
    if f1 != "exact" or f2 != "exact":
        return  # named by the native check (a model operator or twin)
    (s1, h1, w1, m1), (s2, h2, w2, m2) = a1, a2
    differ = []
    if s1.prescription_sha256() != s2.prescription_sha256():
        differ.append("system")
    if (h1, w1) != (h2, w2):
        return  # the native solve's "other shapes"
    if (m1 is None) != (m2 is None) or (m1 is not None and not np.array_equal(m1, m2)):
        differ.append("mask")
    keys = (set(k1) | set(k2)) - {"seed"}
    differ += sorted(k for k in keys if k1.get(k) != k2.get(k))
    if v1 is not None or v2 is not None:
        differ.append("parameter values")
    if differ:
        raise DiffcassiValueError(f"noise_twin: its {', '.join(differ)} {'differs' if len(differ) == 1 else 'differ'} from the operator's; the twin is the operator's recipe with another seed only (diffcassi.exact(..., seed=...))")


def _budget(memory_gb: float) -> int:
    if isinstance(memory_gb, bool) or not (isinstance(memory_gb, (int, float, np.integer, np.floating)) and np.isfinite(memory_gb) and memory_gb >= 0):
        raise DiffcassiValueError(f"memory_gb: expected a finite number ≥ 0, got {memory_gb!r}")
    # Bytes as an unsigned 64-bit count (a budget beyond 1.8e10 GB is no budget at all).
    return min(int(float(memory_gb) * 1e9), 2 ** 64 - 1)


def _number(name: str, v: Any) -> float:
    """A real number argument, else a DiffcassiValueError naming it (float('x') would not)."""
    if isinstance(v, bool) or not isinstance(v, (int, float, np.integer, np.floating)):
        raise DiffcassiValueError(f"{name}: expected a number, got {type(v).__name__} {v!r}")
    try:
        return float(v)
    except OverflowError:
        raise DiffcassiValueError(f"{name}: {v!r} is beyond the float64 range") from None


def _rays(name: str, v: Any) -> int:
    """A ray count: an integer ≥ 1 (a float such as 1.5 was truncated by ``int``), else a DiffcassiValueError naming it."""
    if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or not 1 <= v < 2 ** 63:
        raise DiffcassiValueError(f"{name}: expected an integer ≥ 1, got {type(v).__name__} {v!r}")
    return int(v)


def _pair(name: str, v: Any) -> list:
    """Two numbers (x, y), else a DiffcassiValueError naming the argument and value."""
    try:
        t = [float(u) for u in v]
    except (TypeError, ValueError, OverflowError):
        raise DiffcassiValueError(f"{name}: expected two numbers (x, y), got {type(v).__name__} {v!r}") from None
    if len(t) != 2:
        raise DiffcassiValueError(f"{name}: expected two numbers (x, y), got {len(t)}: {v!r}")
    return t


#: Integer settings of :func:`reconstruct` and their ranges (the CLI's: 1 to 10⁵ iterations; 0 TV iterations only with
#: tv_weight 0, which the library checks).
_SOLVER_INTS = {"iterations": (1, 100_000), "tv_iterations": (0, 100_000), "tv_warmup": (0, 100_000), "equivariant_seed": (0, 2**64 - 1)}
#: The solve's real-valued keywords: a bool is refused (``step=True`` was a step of 1, as ``iterations=True``
#: was one iteration before the integers were checked); the values themselves are the library's to check.
_SOLVER_FLOATS = ("step", "tv_weight", "admm_eta", "sigma_max", "sigma_min", "tolerance", "discrepancy", "noise_norm",
                  "noise_factor")
#: The solve's True/False keywords (``accelerated=1`` was PyO3's TypeError naming no keyword's use).
_SOLVER_BOOLS = ("accelerated", "sigma_auto", "equivariant")


def _csr_arrays(op: Operator, memory_gb: float = 4.0):
    return op._csr(_budget(memory_gb))


def _to_scipy(self: Operator, memory_gb: float = 4.0):
    """Φ as a ``scipy.sparse.csr_matrix`` of shape (h·w, H·W·B), float32: rows are detector pixels
    (row-major), columns the cube's entries in C order [row][col][band] (so ``A @ cube.ravel()`` is
    ``apply(cube).ravel()`` to float rounding). Built by the library from the operator's footprints, Airy
    kernels and interpolation table; a ValueError names the size when assembling it would take more than
    ``memory_gb`` GB. Needs SciPy."""
    try:
        import scipy.sparse
    except ImportError as e:  # pragma: no cover - depends on the environment
        raise ImportError("to_scipy needs SciPy: pip install scipy (or use save_npz, which needs only NumPy)") from e
    indptr, indices, data, shape = _csr_arrays(self, memory_gb)
    return scipy.sparse.csr_matrix((data, indices, indptr), shape=shape)


def _save_npz(self: Operator, path, memory_gb: float = 4.0, compressed: bool = True) -> None:
    """Write Φ in ``scipy.sparse.save_npz``'s own layout (keys indices, indptr, format=b"csr", shape, data),
    with NumPy only: ``scipy.sparse.load_npz(path)`` reads it without diffcassi installed. Two more keys,
    ``cube_shape`` (H, W, B) and ``image_shape`` (h, w) (int64; SciPy ignores them), let
    :meth:`diffcassi.torch.CassiOperator.from_npz` check the shapes it is given. ``path`` must end in .npz and its
    folder exist (else a DiffcassiValueError / DiffcassiFileError naming it)."""
    # NumPy appends ".npz" to a name without it (a folder `d` became `d.npz` beside it, silently): the path is
    # written as given, whole — staged beside it and renamed into place, so a failure leaves any old file intact.
    target = os.fspath(path)
    if not isinstance(target, str) or not target.endswith(".npz"):
        raise DiffcassiValueError(f"save_npz: path {target!r} must end in .npz")
    # Checked before the export (which may take seconds) and named by the target (a missing folder was the stage
    # file's FileNotFoundError, naming `.NAME.PID.stage.npz`); a folder, a pipe, a device or a link refused.
    _files.check_output_file("save_npz", target)
    if not isinstance(compressed, (bool, np.bool_)):  # "no" was taken as true
        raise DiffcassiValueError(f"save_npz: compressed: expected True or False, got {type(compressed).__name__} {compressed!r}")
    indptr, indices, data, shape = _csr_arrays(self, memory_gb)
    save = np.savez_compressed if compressed else np.savez
    # The operator's own shapes beside SciPy's keys (scipy.sparse.load_npz ignores extra keys): the matrix shows
    # only the products h·w and H·W·B, so CassiOperator.from_npz checks the shapes it is given against these.
    shapes = {k: np.array(getattr(self, k), dtype=np.int64) for k in ("cube_shape", "image_shape") if hasattr(self, k)}

    def write(stage: str) -> None:
        with open(stage, "wb") as f:  # a file object: NumPy appends nothing to its name
            save(f, indices=indices, indptr=indptr, format=np.array(b"csr"), shape=np.array(shape, dtype=np.int64), data=data,
                 **shapes)

    _files.write_staged("save_npz", target, write, suffix=".npz")


Operator.to_scipy = _to_scipy  # type: ignore[attr-defined]
Operator.save_npz = _save_npz  # type: ignore[attr-defined]
Operator.to_csr_arrays = lambda self, memory_gb=4.0: _csr_arrays(self, memory_gb)  # type: ignore[attr-defined]
Operator.to_csr_arrays.__doc__ = "(indptr int64, indices int32, data float32, shape) of Φ (see to_scipy)."
Transport.to_scipy = lambda self, memory_gb=4.0: _to_scipy(self.operator, memory_gb)  # type: ignore[attr-defined]
Transport.save_npz = lambda self, path, memory_gb=4.0, compressed=True: _save_npz(self.operator, path, memory_gb, compressed)  # type: ignore[attr-defined]
Transport.detector = property(lambda self: _json.loads(self._detector_json()),  # type: ignore[attr-defined]
                              doc="The detector: width, height, pitch_mm, x_left_mm, y_top_mm.")


def metrics(truth: np.ndarray, estimate: np.ndarray, truth_wavelengths_nm: Optional[Sequence[float]] = None,
            estimate_wavelengths_nm: Optional[Sequence[float]] = None) -> Dict[str, Any]:
    """The field's reconstruction metrics of ``estimate`` against ``truth`` ((H, W, B) float32 each; H, W ≥ 11
    for SSIM): ``rmse``, ``psnr_db`` (paper: one MSE over the cube, peak = max of the truth), ``psnr_band_db``
    (MST: mean of per-band PSNR on [0, 1]), ``ssim`` (11×11 Gaussian σ 1.5, mean over bands), ``sam_rad``,
    ``sam_deg``. With both wavelength lists the truth is resampled to the estimate's and the result also
    holds ``wavelengths_nm``, ``truth_resampled``, ``truth_peak`` (as ``diffcassi evaluate``). An infinite
    PSNR (identical cubes within [0, 1]) is ``inf``. PSNR and SSIM clamp the estimate to [0, 1], the field's
    convention: a truth beyond 1, or an infinite PSNR with a non-zero RMSE (the cubes differ only outside
    [0, 1]), gives a ``UserWarning`` saying so (those numbers are not meaningful then)."""
    d = _json.loads(_native._metrics(truth, estimate, truth_wavelengths_nm, estimate_wavelengths_nm))
    # One flat dict either way, as `evaluate --json` (with wavelengths the library nests the metrics under
    # "metrics", and m["psnr_db"] raised KeyError; round 15).
    m = dict(d.get("metrics", d))
    m.update({k: v for k, v in d.items() if k != "metrics"})
    for k in ("psnr_db", "psnr_band_db"):
        if m.get(k) is None:
            m[k] = float("inf")
    import warnings
    for w in d.get("warnings", []):  # the library's (recon::metrics::clamp_warning), as `diffcassi evaluate` prints them
        warnings.warn(f"metrics: {w}", UserWarning, stacklevel=2)
    return m


def mapping_operator(system: System, height: int, width: int, mask: Optional[np.ndarray] = None,
                     interpolation: str = "nearest", **settings: Any) -> Operator:
    """The paper's ``mapping`` operator (each band placed at its chief-ray mapped detector pixel, ``nearest``
    or ``bilinear``) on the detector and mask of :func:`render` with the same settings; ``.initialisation(acq)``
    gives the paper's I = A ∘ f."""
    _check_backend(settings.get("backend", "analytic"))
    return _warn_dark_bands(_native.model_operator("mapping", system, height, width, mask, interpolation=interpolation, **settings),
                            "mapping_operator")


def shift_operator(system: System, height: int, width: int, mask: Optional[np.ndarray] = None, **settings: Any) -> Operator:
    """The field's simplified SD-CASSI ``shift`` model (band b shifted by the central field's dispersion along x,
    no distortion, no blur) on the detector and mask of :func:`render` with the same settings."""
    _check_backend(settings.get("backend", "analytic"))
    return _warn_dark_bands(_native.model_operator("shift", system, height, width, mask, **settings), "shift_operator")


def reconstruct(operator: Union[Operator, Transport], acquisition: np.ndarray, solver: str = "gap-tv",
                init: Optional[np.ndarray] = None, **settings: Any) -> Tuple[np.ndarray, Dict[str, Any]]:
    """Reconstruct a cube (H, W, B) float32 from ``acquisition`` ((h, w) float32; float64 is converted, the
    image being small) with ``solver`` ``gap-tv`` (accelerated GAP by default) or ``admm-tv``, as
    ``diffcassi reconstruct``, or ``pnp-gap`` / ``pnp-admm`` (plug-and-play with the learned denoiser: a TV
    phase, then the network; docs/reconstruction.md). ``settings`` (default: the library's, as the CLI's):
    iterations (the cap: 300 GAP-TV, 100 ADMM-TV, 305 PnP: the TV phase and 5 network steps), step (1), tv_weight (0.1), tv_iterations (5),
    tv_coupling (``vectorial`` | ``per_band``), accelerated (GAP-TV and PnP-GAP only: True), admm_eta (ADMM-TV and PnP-ADMM only: 0.01);
    the stopping rules as the CLI's: discrepancy (τ; 0.65 TV, see the docs for PnP) with noise_norm (δ, the
    expected ‖y − Φx_true‖₂ in acquisition units, e.g. :func:`monte_carlo_noise_norm`; 0 or absent: the rule is
    off), tolerance (relative change; 0 for TV); for PnP tv_warmup (the TV phase's cap), sigma_max, sigma_min
    (the σ schedule's ceiling and floor), sigma_auto (True: σ_1 from the TV iterate's estimated error),
    denoiser (a weights file; default the embedded one), equivariant (True: each network call denoises a
    randomly flipped/rotated iterate and turns it back; default the library's, ``--equivariant`` of the CLI),
    equivariant_seed (the transforms' seed, an integer ≥ 0; default 0).
    δ from the data, as the CLI's default: ``noise_twin`` (an exact operator with the same settings and rays
    as ``operator`` but another ``seed``) makes the rule re-estimate δ every 5 iterations as
    (noise_norm² + (noise_factor·‖(Φ − Φ')θ‖)²)^½ at the iterate θ — noise_norm is then the sensor part (0 for
    a noiseless acquisition), ``noise_factor`` = :func:`spread_noise_factor` (1 for equal ray counts).
    Returns ``(cube, record)``; the record holds the settings, per-iteration residuals, seconds and
    ``stopping`` (the rule, τ, δ, the cap, ``iterations_run``, ``stopped_by``, ``noise_estimator``,
    ``noise_norm_per_estimate``), as ``reconstruct.json``'s ``stopping`` — the record is the solver's
    (``residuals`` per iteration, the settings at its top level), not the file's whole layout (which adds the
    render's provenance, ``residual``, and the settings under ``solver_settings``). ``noise_factor`` is at most
    1e6 (:func:`spread_noise_factor` of ray counts within the budget is ≤ ~1e5). An unknown keyword is a DiffcassiValueError naming it
    and the valid ones (those of the native solve's signature); so is a keyword of another solver (the PnP ones,
    ``accelerated`` or ``admm_eta`` where they do not apply), never ignored."""
    # The keywords the native solve takes, read from its own signature (PyO3's text signature of `_reconstruct`,
    # generated from the Rust one): one source, so this list cannot drift. Python's own TypeError named
    # `_reconstruct` and not the valid keywords.
    import inspect
    valid = [k for k in inspect.signature(_native._reconstruct).parameters if k not in ("operator", "acquisition", "solver", "init")]
    unknown = [k for k in settings if k not in valid]
    if unknown:
        raise DiffcassiValueError(f"reconstruct: unexpected keyword `{unknown[0]}` (valid: {', '.join(valid)})")
    op = operator.operator if isinstance(operator, Transport) else operator
    if not isinstance(op, Operator):
        raise DiffcassiValueError(f"operator: expected a diffcassi.Operator or Transport, got {type(operator).__name__}")
    for k, (lo, hi) in _SOLVER_INTS.items():
        v = settings.get(k)
        if v is not None and (isinstance(v, bool) or not isinstance(v, (int, np.integer)) or not lo <= v <= hi):
            raise DiffcassiValueError(f"{k}: expected an integer in {lo}..={hi}, got {type(v).__name__} {v!r}")
    for k in _SOLVER_FLOATS:
        v = settings.get(k)
        if v is not None and (isinstance(v, (bool, np.bool_)) or not isinstance(v, (int, float, np.integer, np.floating))):
            raise DiffcassiValueError(f"{k}: expected a number, got {type(v).__name__} {v!r}")
    for k in _SOLVER_BOOLS:
        v = settings.get(k)
        if v is not None and not isinstance(v, (bool, np.bool_)):
            raise DiffcassiValueError(f"{k}: expected True or False, got {type(v).__name__} {v!r}")
    acq = _as_f32("acquisition", acquisition)
    twin = settings.get("noise_twin")
    if twin is not None:
        twin = twin.operator if isinstance(twin, Transport) else twin
        if not isinstance(twin, Operator):
            raise DiffcassiValueError(f"noise_twin: expected a diffcassi.Operator or Transport, got {type(twin).__name__}")
        _check_twin_recipe(op, twin)
        settings["noise_twin"] = twin
    _weights_file("denoiser", settings.get("denoiser"))
    cube, record = _native._reconstruct(op, acq, solver, init, **settings)
    return cube, _json.loads(record)


#: The largest |value| the operators and solvers take (f32's range / 10⁹: their f32 sums must not overflow),
#: as the library's ``limits::MAX_SCENE_VALUE``.
_MAX_VALUE = float(np.finfo(np.float32).max) / 1e9


def _as_f32(name: str, a: Any) -> Any:
    """A float64 array as float32 for the native calls, checked first — finite and within ±``_MAX_VALUE`` — so that
    a value float32 cannot hold (1e300) is named as given, not as the inf NumPy's cast makes of it (with an overflow
    warning). Anything else is passed on for the native call's own checks."""
    if getattr(a, "dtype", None) != np.float64:
        return a
    v = np.asarray(a)
    bad = ~np.isfinite(v) | (np.abs(v) > _MAX_VALUE)
    if bad.any():
        k = np.unravel_index(int(np.argmax(bad)), v.shape)
        raise DiffcassiValueError(f"{name}: value {v[k]:e} at index {list(map(int, k))} is not finite or beyond ±{_MAX_VALUE:.3e} "
                                  "(f32's range / 10⁹) that the operators' and solvers' f32 sums allow; rescale it")
    return np.ascontiguousarray(v, dtype=np.float32)


def monte_carlo_noise_norm(acquisition: np.ndarray, acquisition_rays: int, operator_rays: int, planes_per_band: float) -> float:
    """δ for the discrepancy stop of :func:`reconstruct` (``noise_norm``), as the CLI estimates its Monte-Carlo
    term: 0.062·((1/R_a + 1/R_o)/F)^½·‖y‖ for an exact operator traced with another seed (R_o rays per pixel per
    plane) against an acquisition traced with R_a rays, F render planes per band (docs/reconstruction.md,
    "Defaults and stopping"). Add the sensor noise yourself when the acquisition has any. The constant model
    (the CLI's ``--noise-estimate model``); the default estimate is from the data (``noise_twin`` of
    :func:`reconstruct`): the model overestimates δ on smoother, larger scenes."""
    acq = np.ascontiguousarray(_as_f32("acquisition", acquisition), dtype=np.float32)
    return float(_native.monte_carlo_noise_norm(acq, _rays("acquisition_rays", acquisition_rays), _rays("operator_rays", operator_rays),
                                                _number("planes_per_band", planes_per_band)))


def spread_noise_factor(acquisition_rays: int, operator_rays: int) -> float:
    """((1 + R_o/R_a)/2)^½: scales an exact operator's spread against its twin, ‖(Φ − Φ')θ‖, to the expected
    ‖y − Φx_true‖ of an acquisition traced with R_a rays (``noise_factor`` of :func:`reconstruct`)."""
    return float(_native.spread_noise_factor(_rays("acquisition_rays", acquisition_rays), _rays("operator_rays", operator_rays)))


__all__ += ["mapping_operator", "shift_operator", "reconstruct", "monte_carlo_noise_norm", "spread_noise_factor"]


def study(out: Union[str, "os.PathLike[str]"], **settings: Any) -> Dict[str, Any]:
    """The reference paper's four-system study (``diffcassi study``, the library's ``diffcassi::study``) into
    the folder ``out``: every scene rendered through every system with one mask, reconstructed with every
    operator and solver, and evaluated; ``study.csv``, ``study.md`` and ``study_psnr.png`` in ``out``, with the
    same layout and resumption as the command (a second call with the same settings reuses every cell).

    Keywords are the command's options in snake case, with its defaults: ``presets`` ("ap,sp,map,msp"),
    ``systems`` (lens files), ``operators`` ("exact,mapping,shift"), ``solvers`` ("gap-tv"), ``scenes`` (a
    folder) or ``synthetic`` (N), ``scene_size`` (128), ``bands`` ("450:650:28"), ``planes`` (112), ``rays``
    (20), ``seed``, ``mask`` or ``opening``/``mask_seed``, ``airy_diameter_px``, the solver settings
    (``iterations``, ``tv_weight``, ``denoiser``, ``weights``, …), ``force``. Lists are a comma string or a
    sequence. Returns ``{"computed", "skipped", "seconds", "table"}``; bad settings raise
    ``DiffcassiValueError`` / ``DiffcassiFileError`` before anything is written."""
    try:
        return _json.loads(_native._study(os.fspath(out), **settings))
    except DiffcassiError as e:
        # The library names the render bands as render's keyword (``bands_nm``); study's is ``bands``.
        if "bands_nm" in str(e):
            raise type(e)(re.sub(r"\bbands_nm\b", "bands", str(e))) from None
        raise


__all__ += ["study"]


def denoise(cube: np.ndarray, sigma: float, weights: Optional[str] = None, neutral: bool = False,
            ensemble: bool = False) -> np.ndarray:
    """The learned denoiser (``spectral-unet-v2``, the prior of ``pnp-gap``/``pnp-admm``; Rust inference) on
    ``cube`` (H, W, B) float32 at noise level ``sigma`` (standard deviation on the cube's scale; trained on
    cubes of peak ≈ 1). ``weights``: a safetensors file (default: the embedded checkpoint). Equal to
    :class:`diffcassi.denoiser.SpectralUNet` within 1e-4 of the peak. ``neutral`` (mean-colour
    neutralisation, default off) and ``ensemble`` (the geometric self-ensemble, 8× the time) as in
    :func:`diffcassi.denoiser.denoise`. ``sigma``: a real number ≥ 0 (a string, a bool or None is a
    DiffcassiValueError naming ``sigma`` and the value)."""
    _weights_file("weights", weights)
    # Any real number (NumPy and 0-dim torch scalars included, as float() took them); float("a") and float(None)
    # raised bare errors that named neither sigma nor the value; bools and strings are no noise levels.
    try:
        if isinstance(sigma, (bool, np.bool_, str, bytes)):
            raise TypeError
        s = float(sigma)
    except (TypeError, ValueError, OverflowError):
        raise DiffcassiValueError(f"sigma: expected a number (the noise level, finite and ≥ 0), got {type(sigma).__name__} {sigma!r}") from None
    # An empty cube: its size named (the native check read "the cube has 0 values (output 0), shape 0×16×28 needs 0":
    # a held-out battery, round 16).
    shape = getattr(cube, "shape", None)
    if isinstance(shape, tuple) and len(shape) == 3 and min(shape) < 1:
        raise DiffcassiValueError(f"denoise: cube of shape {shape} (H, W, B) is empty: height, width and bands must "
                                  "each be ≥ 1")
    return _native.denoise(cube, s, None if weights is None else str(weights), bool(neutral), bool(ensemble))


def _weights_file(name: str, path: Any) -> None:
    """A weights path that is a directory: a DiffcassiFileError saying so (not "no such file")."""
    if isinstance(path, (str, os.PathLike)) and os.path.isdir(path):
        raise DiffcassiFileError(f"{name} {os.fspath(path)}: is a directory, not a weights file")


__all__ += ["denoise"]


def _rebuild(factory: str, args: tuple, kwargs: Dict[str, Any], values: Optional[Sequence[float]] = None) -> Any:
    """Unpickling of the native objects (:class:`Operator`, :class:`Transport`, ``DiffRenderer``): the factory
    that built the object is called again with its arguments, recorded at construction (their ``__reduce__``;
    python/src/recipe.rs) — the same seeds trace the same numbers, so the copy equals the original bit for
    bit, at the cost of tracing again; ``values``: then ``with_values(values)`` (a moved ``DiffRenderer``)."""
    table = {"exact": exact, "mapping_operator": mapping_operator, "shift_operator": shift_operator,
             "Transport": Transport, "DiffRenderer": _native.DiffRenderer}
    if factory not in table:
        raise DiffcassiValueError(f"_rebuild: unknown factory {factory!r} (a pickle from another diffcassi version?)")
    obj = table[factory](*args, **kwargs)
    return obj if values is None else obj.with_values(list(values))
