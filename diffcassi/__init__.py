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
from typing import Any, Dict, Optional, Sequence, Tuple, Union

import numpy as np

from . import _native
from ._errors import DiffcassiError, DiffcassiFileError, DiffcassiValueError
from ._native import System, Transport, get_num_threads, jacobian, mapping, read_exr, set_num_threads, trace

__version__: str = _native.__version__
#: Whether the Embree backends (``embree-user``, ``embree-mesh``) were compiled in.
EMBREE: bool = _native.EMBREE

#: Ray status codes of :func:`trace` (``status`` array) and their names.
STATUS = {0: "ok", 1: "missed", 2: "vignetted", 3: "total internal reflection", 4: "no convergence",
          5: "invalid input", 6: "absorbed", 7: "bounce limit"}

__all__ = [
    "System", "Transport", "trace", "spot", "distortion", "dispersion", "mapping", "jacobian", "render",
    "read_exr", "set_num_threads", "get_num_threads", "surfaces", "DiffcassiError", "DiffcassiValueError",
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


def surfaces(system: System) -> list:
    """The resolved Lens Data Editor of ``system``: one dict per surface (index, kind, material, radius_mm,
    thickness_mm, conic, semi_diameter_mm, decenters, tilts, vertex_global_mm)."""
    return _json.loads(system._surfaces_json())


# `System.surfaces` as a property (the class is compiled; the property is added here).
System.surfaces = property(surfaces, doc=surfaces.__doc__)  # type: ignore[attr-defined]


def spot(system: System, field_mm: Sequence[float], wavelength_nm: float, pupil: Union[str, np.ndarray, None] = None,
         backend: str = "analytic") -> Dict[str, Any]:
    """Spot diagram of one field (x, y mm) at one wavelength: a dict with ``x_mm``, ``y_mm``, ``status``,
    ``pupil``, ``chief_mm``, ``stats`` (centroid_mm, rms_radius_um, geo_radius_um) and
    ``rms_radius_chief_um``. ``pupil``: a pattern (default ``hexapolar:12``, as the CLI) or (N, 2) float64
    normalised pupil points. Arrays are returned as NumPy float64."""
    d = _json.loads(_native._spot(system, list(field_mm), float(wavelength_nm), pupil, _check_backend(backend)))
    for k in ("x_mm", "y_mm", "pupil"):
        d[k] = np.asarray(d[k], dtype=np.float64)
    return d


def distortion(system: System, wavelength_nm: Optional[float] = None, grid: int = 13, half_width_mm: float = 2.5,
               backend: str = "analytic") -> Dict[str, Any]:
    """Zemax-style grid distortion (``grid`` × ``grid`` chief rays over ±``half_width_mm``) at
    ``wavelength_nm`` (default: the primary): dict with ``reference_mm``, ``abcd``, ``max_distortion_pct`` and
    ``points`` (one dict per grid point, as the CLI's CSV)."""
    w = system.primary_wavelength_nm if wavelength_nm is None else float(wavelength_nm)
    return _json.loads(_native._distortion(system, w, int(grid), float(half_width_mm), _check_backend(backend)))


def dispersion(system: System, wavelengths_nm: Sequence[float] = tuple(np.linspace(450, 650, 28)),
               field_mm: Sequence[float] = (0.0, 0.0), backend: str = "analytic") -> Dict[str, Any]:
    """Chief-ray positions of one field over wavelength (the paper's spreading curve): dict with
    ``wavelength_nm``, ``x_mm``, ``y_mm`` (NumPy arrays) and ``spread_um``."""
    d = _json.loads(_native._dispersion(system, list(field_mm), wavelengths_nm, _check_backend(backend)))
    for k in ("wavelength_nm", "x_mm", "y_mm"):
        d[k] = np.asarray(d[k], dtype=np.float64)
    return d


def render(system: System, scene: np.ndarray, wavelengths_nm: Sequence[float], mask: Optional[np.ndarray] = None, *,
           bands_nm: Optional[Sequence[float]] = None, planes: Optional[int] = None, rays: Optional[int] = None,
           seed: Optional[int] = None, sampling: Optional[str] = None, opening: Optional[float] = None,
           mask_seed: Optional[int] = None, airy_diameter_px: Optional[float] = None, airy: Optional[bool] = None,
           backend: str = "analytic", noise: Optional[dict] = None) -> Tuple[np.ndarray, Dict[str, Any]]:
    """Render the coded acquisition of ``scene`` through ``system``.

    ``scene``: (H, W, B) float32, C-contiguous, finite, its bands at ``wavelengths_nm`` (B values).
    Every setting left at ``None`` is the CLI's default (``diffcassi render --help``): bands 450:650:28,
    planes 112, rays 20 per pixel per plane, seed 0, stratified sampling, a random binary mask of opening
    0.5 and seed 0 (or ``mask``: (H, W) float32 in [0, 1]), Airy disk 2.5 px at 520 nm. So
    ``render(sp, cube, wl)`` equals ``diffcassi render --preset sp --scene cube.npy --scene-size N`` bit for
    bit. ``noise``: sensor noise settings (see docs/python.md; ``None``: a clean acquisition, the default).

    Returns ``(acquisition, info)``: the detector image (h, w) float64 and a dict with ``render.json``'s
    keys (``acquisition_total``, ``detector``, ``bands_nm``, ``planes_nm``, ``rays_traced``, ...).
    """
    if noise is not None:
        raise DiffcassiValueError("noise: sensor noise is not available in this build (noise=None renders a clean acquisition)")
    acq, info = _native._render(system, scene, wavelengths_nm, mask, bands_nm, planes, rays, seed, sampling, opening,
                                mask_seed, airy_diameter_px, airy, _check_backend(backend))
    return acq, _json.loads(info)
