"""Training data of the unrolled network ``unrolled-dauhst-v2`` (issue 43 item 1): hyperspectral cubes made from
measured reflectances and natural textures, every random choice a function of one integer seed, and the sensor
noise drawn per sample.

Kinds of cube (chosen by the seed, probabilities :data:`KIND_PROBABILITIES`):

* ``leaves-measured``: dead leaves (:mod:`diffcassi.deadleaves`' geometry and textures) whose palette comes from the
  *extended* measured library: the sets of :data:`diffcassi.deadleaves.SOURCES` (ColorChecker ×3, PMC skin tones,
  CIE 13.3 / CIE 2024 test colour samples of CRI, NIST CQS) **plus the 99 CIE 2017 colour-fidelity samples**
  (CIE 224:2017, shipped by colour-science as ``colour/quality/datasets/tcs_cfi2017_1_nm.csv.gz``);
* ``leaves-spectral`` and ``leaves-rgb``: the current generator unchanged (:func:`diffcassi.deadleaves.dead_leaves`,
  measured-spectra leaves and Smits-uplifted sRGB leaves);
* ``texture``: a crop of one of scikit-image's shipped images — **only** :data:`TEXTURES` (brick, grass, gravel,
  camera, moon, coins, text, page, clock, motorcycle_left, motorcycle_right; never the evaluation photographs of
  ``data/scenes``, which also come from scikit-image: :data:`EVALUATION_SCENES`, refused by name) — lifted to
  spectra: the grey level t(x) selects among 2–4 measured reflectances through soft memberships (centres and
  softness drawn per cube, shifted in space by a 1/f noise field), shaded by t; for the two colour photographs
  (motorcycle) the Smits uplift of the pixel's sRGB (:func:`diffcassi.uplift_srgb`, the evaluation scenes' uplift)
  mixed with such measured-reflectance spectra (weight 0.3–0.7), so the spectra are not all smooth rank-3 uplifts.

Then, for every kind: a D65/A illuminant mixture (measured kinds, p = 0.7), random flips and a 90° rotation, the
peak normalised to 1 and an **exposure** factor log-uniform in [0.5, 1] (the cube's peak). Texture crops: a side
of ``size``·z pixels, z log-uniform in [0.6, 2] (clamped to the image), at a uniform position, resampled to
``size`` by linear interpolation.

Sensor noise (:func:`draw_noise`, :func:`sensor_noise`): the model of ``src/render/noise.rs`` (docs/noise.md:
auto exposure K = full well / clean peak, Poisson shot noise, Gaussian read noise 2 e⁻, a 12-bit ADC, back to
acquisition units) in NumPy with the sample's own PCG64 stream (the library's ChaCha8 streams are not exposed per
image); per sample: no noise with p = 0.2, else a full well log-uniform in [1 000, 40 000] e⁻ (peak SNR 32–200).
The ADC step is checked bit for bit against ``diffcassi.render(noise="adc")`` (tests).

Every cube is a pure function of (seed, size, bands): ``numpy.random.default_rng([SALT, seed])``; the noise of a
sample uses ``default_rng([NOISE_SALT, seed])``. The scikit-image files are read from the installed wheel's
``skimage/data`` folder (no download: a missing file is an error naming it). Sources and licences:
:func:`manifest` (written to the training manifest) and ``diffcassi/weights/UNROLLED.md``.

>>> from diffcassi.training_data import KINDS, sample
>>> cube, info = sample(11, size=32)            # (28, 32, 32) float32
>>> cube.shape, info["kind"] in KINDS
((28, 32, 32), True)
"""
from __future__ import annotations

import functools
import os
from typing import Any, Dict, List, Optional, Sequence, Tuple

import numpy as np

from . import deadleaves
from .deadleaves import BANDS_NM

#: scikit-image sample images the textures may come from (name → file in ``skimage/data``), and nothing else.
TEXTURES: Dict[str, str] = {
    "brick": "brick.png", "grass": "grass.png", "gravel": "gravel.png", "camera": "camera.png", "moon": "moon.png",
    "coins": "coins.png", "text": "text.png", "page": "page.png", "clock": "clock_motion.png",
    "motorcycle_left": "motorcycle_left.png", "motorcycle_right": "motorcycle_right.png",
}
#: The evaluation photographs (``data/scenes``, also scikit-image samples): never training data.
EVALUATION_SCENES = ("astronaut", "chelsea", "coffee", "ihc", "retina", "rocket")

#: Sources and licences of the texture images, as scikit-image documents them (``skimage.data`` docstrings).
TEXTURE_SOURCES: Dict[str, str] = {
    "brick": "CC0Textures 'Bricks25' (cc0textures.com); CC0",
    "grass": "DeviantArt 'Grass-01' by linolafett; CC0",
    "gravel": "CC0Textures 'Gravel04' (cc0textures.com); CC0",
    "camera": "photograph by Lav Varshney; CC0 ('no copyright restrictions')",
    "moon": "surface of the moon, scikit-image sample data (no separate licence stated; distributed with scikit-image, BSD-3)",
    "coins": "Greek coins from Pompeii, Brooklyn Museum open collection; 'no known copyright restrictions'",
    "text": "Wikipedia File:Corner.png; public domain",
    "page": "scanned page, scikit-image sample data (no separate licence stated; distributed with scikit-image, BSD-3)",
    "clock": "motion-blurred clock, photograph by Stefan van der Walt; public domain",
    "motorcycle_left": "Middlebury 2014 stereo benchmark (Scharstein et al. 2014), downsampled by scikit-image; "
                       "Middlebury's terms: free for research use, cite the paper",
    "motorcycle_right": "Middlebury 2014 stereo benchmark (Scharstein et al. 2014), downsampled by scikit-image; "
                        "Middlebury's terms: free for research use, cite the paper",
}

#: The measured set added to :data:`diffcassi.deadleaves.SOURCES`.
CIE2017_SOURCE = {"name": "TCS CIE 2017", "package": "colour-science (BSD-3)",
                  "object": "colour.quality.cfi2017.load_TCS_CIE2017 (tcs_cfi2017_1_nm.csv.gz)",
                  "reference": "CIE 224:2017 colour fidelity index, 99 colour evaluation samples"}

KINDS = ("leaves-measured", "leaves-spectral", "leaves-rgb", "texture")
KIND_PROBABILITIES = (0.25, 0.1, 0.15, 0.5)
#: Salts of the per-sample random streams (cube, noise).
SALT, NOISE_SALT = 43_001, 43_002
#: Sensor-noise draw: P(no noise), full-well range (e⁻), read noise (e⁻), ADC bits.
NOISE_FREE_PROBABILITY, FULL_WELL_RANGE_E, READ_NOISE_E, ADC_BITS = 0.2, (1_000.0, 40_000.0), 2.0, 12


class TrainingDataError(ValueError):
    """Bad input to the training-data generator (names the argument and value)."""


def _check_seed(seed: Any) -> int:
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise TrainingDataError(f"training_data: seed: expected an integer ≥ 0, got {type(seed).__name__} {seed!r}")
    return int(seed)


@functools.lru_cache(maxsize=8)
def _library(bands_key: Tuple[float, ...]) -> Tuple[np.ndarray, Tuple[str, ...]]:
    """The extended measured library (K, B) in [0, 1] and each spectrum's set: deadleaves' sets + CIE 2017."""
    lib, _, names = deadleaves._tables(bands_key)
    import warnings
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        from colour.quality.cfi2017 import SPECTRAL_SHAPE_CIE2017, load_TCS_CIE2017
    m = load_TCS_CIE2017(SPECTRAL_SHAPE_CIE2017)
    wl, vals = np.asarray(m.wavelengths, float), np.asarray(m.values, float)
    to = np.asarray(bands_key, float)
    extra = np.clip(np.stack([np.interp(to, wl, vals[:, j]) for j in range(vals.shape[1])]), 0.0, 1.0)
    return np.concatenate([lib, extra]), tuple(names) + (CIE2017_SOURCE["name"],) * extra.shape[0]


def reflectance_library(bands_nm: Sequence[float] = BANDS_NM) -> Tuple[np.ndarray, List[str]]:
    """The extended measured library at ``bands_nm``: (K, B) reflectances and the set of each."""
    r, names = _library(tuple(float(b) for b in bands_nm))
    return r.copy(), list(names)


def skimage_data_dir() -> str:
    """The ``skimage/data`` folder of the installed scikit-image (located without importing it)."""
    import importlib.util
    spec = importlib.util.find_spec("skimage")
    if spec is None or not spec.submodule_search_locations:
        raise ImportError("diffcassi.training_data needs scikit-image's shipped sample images: scripts/setup.sh "
                          "installs scikit-image into .venv (or `pip install scikit-image`)")
    return os.path.join(list(spec.submodule_search_locations)[0], "data")


def _read_image(path: str) -> np.ndarray:
    """The one file reader of this module (8-bit PNG → float in [0, 1]; grey (H, W) or RGB (H, W, 3))."""
    from PIL import Image
    with Image.open(path) as im:
        a = np.asarray(im)
    if a.ndim == 3:
        a = a[..., :3]
    return a.astype(np.float64) / 255.0


@functools.lru_cache(maxsize=None)
def texture_image(name: str) -> np.ndarray:
    """The scikit-image sample ``name`` (one of :data:`TEXTURES`) as float64 in [0, 1], read from the wheel's
    ``skimage/data``; another name (an evaluation photograph above all) or a missing file is an error."""
    if name in EVALUATION_SCENES:
        raise TrainingDataError(f"training_data: texture {name!r} is an evaluation photograph (data/scenes): never "
                                "training data")
    if name not in TEXTURES:
        raise TrainingDataError(f"training_data: texture {name!r} is not one of the allowed images {sorted(TEXTURES)}")
    path = os.path.join(skimage_data_dir(), TEXTURES[name])
    if not os.path.isfile(path):
        raise FileNotFoundError(f"training_data: texture {name!r}: {path} is missing from the installed scikit-image "
                                "(only images shipped in its wheel are used; nothing is downloaded)")
    img = _read_image(path)
    img.setflags(write=False)
    return img


def check_textures() -> Dict[str, Tuple[int, ...]]:
    """Reads every allowed texture (an error names the first missing one); returns their shapes."""
    return {n: texture_image(n).shape for n in TEXTURES}


def _resize(img: np.ndarray, size: int) -> np.ndarray:
    """Linear resampling of a square (s, s[, 3]) crop to (size, size[, 3])."""
    from scipy.ndimage import zoom
    z = size / img.shape[0]
    out = zoom(img, (z, z) + (1,) * (img.ndim - 2), order=1, mode="nearest", grid_mode=True)
    return out[:size, :size]


def _crop(rng: np.random.Generator, img: np.ndarray, size: int) -> np.ndarray:
    """A random square crop of side size·z (z log-uniform in [0.6, 2], at most the image's), resampled to size."""
    h, w = img.shape[:2]
    side = int(round(size * np.exp(rng.uniform(np.log(0.6), np.log(2.0)))))
    side = max(4, min(side, h, w))
    r0, c0 = int(rng.integers(0, h - side + 1)), int(rng.integers(0, w - side + 1))
    crop = img[r0:r0 + side, c0:c0 + side]
    return crop if side == size else np.clip(_resize(crop, size), 0.0, 1.0)


def _memberships(rng: np.random.Generator, t: np.ndarray, n: int) -> np.ndarray:
    """(n, H, W) soft memberships of the grey level t (plus a low-frequency shift field) to n sorted centres."""
    centres = np.sort(rng.uniform(0.0, 1.0, size=n))
    tau = rng.uniform(0.05, 0.2)
    shift = 0.3 * (deadleaves._fractal_noise(rng, t.shape[0]) - 0.5) if rng.random() < 0.7 else 0.0
    u = t + shift
    logit = -((u[None] - centres[:, None, None]) ** 2) / (2 * tau * tau)
    logit -= logit.max(0, keepdims=True)
    w = np.exp(logit)
    return w / w.sum(0, keepdims=True)


def _texture_cube(rng: np.random.Generator, size: int, bands_nm: Sequence[float], lib: np.ndarray) -> Tuple[np.ndarray, str]:
    name = list(TEXTURES)[int(rng.integers(len(TEXTURES)))]
    img = _crop(rng, texture_image(name), size)
    grey = img if img.ndim == 2 else img @ np.array([0.2126, 0.7152, 0.0722])
    n = int(rng.integers(2, 5))
    refl = np.stack([deadleaves.random_reflectance(rng, lib) for _ in range(n)])  # (n, B)
    w = _memberships(rng, grey, n)
    shading = (0.15 + 0.85 * grey) ** rng.uniform(0.5, 1.5)
    measured = np.einsum("nb,nhw->bhw", refl, w) * shading[None]
    if img.ndim == 2:
        return measured, name
    from ._native import uplift_srgb
    up = uplift_srgb(np.ascontiguousarray(img, dtype=np.float32), [float(b) for b in bands_nm]).transpose(2, 0, 1)
    a = rng.uniform(0.3, 0.7)
    return (1 - a) * up.astype(np.float64) + a * measured, name


def _measured_leaves(rng: np.random.Generator, size: int, lib: np.ndarray) -> np.ndarray:
    palette = [deadleaves.random_reflectance(rng, lib) for _ in range(int(rng.integers(3, 11)))]
    cube = deadleaves._paint_leaves(rng, size, palette, 600)
    if rng.random() < 0.5:
        from scipy.ndimage import gaussian_filter
        cube = gaussian_filter(cube, sigma=(0.0, *(2 * [rng.uniform(0.5, 1.5)])), mode="reflect")
    return cube


def sample(seed: int, size: int = 128, bands_nm: Sequence[float] = BANDS_NM) -> Tuple[np.ndarray, Dict[str, Any]]:
    """One training cube (B, size, size) float32 with peak = its exposure (in [0.5, 1]) and a record of what made
    it (``kind``, ``texture`` for textures, ``exposure``, ``flips``, ``rot90``); a pure function of the arguments."""
    seed = _check_seed(seed)
    if isinstance(size, bool) or not isinstance(size, (int, np.integer)) or size < 4:
        raise TrainingDataError(f"training_data: size: expected an integer ≥ 4, got {size!r}")
    size = int(size)
    key = tuple(float(b) for b in bands_nm)
    lib, _ = _library(key)
    _, ill, _ = deadleaves._tables(key)
    rng = np.random.default_rng([SALT, seed])
    kind = KINDS[int(rng.choice(len(KINDS), p=list(KIND_PROBABILITIES)))]
    info: Dict[str, Any] = {"seed": seed, "kind": kind}
    if kind == "leaves-spectral":
        cube = deadleaves.dead_leaves(int(rng.integers(2**62)), size, bands_nm, kind="spectral").astype(np.float64)
    elif kind == "leaves-rgb":
        cube = deadleaves.dead_leaves(int(rng.integers(2**62)), size, bands_nm, kind="rgb").astype(np.float64)
    elif kind == "leaves-measured":
        cube = _measured_leaves(rng, size, lib)
    else:
        cube, info["texture"] = _texture_cube(rng, size, bands_nm, lib)
    if kind in ("leaves-measured", "texture") and rng.random() < 0.7:
        wmix = rng.random()
        cube = cube * ((1 - wmix) * ill[0] + wmix * ill[1])[:, None, None]
    fy, fx, k = bool(rng.random() < 0.5), bool(rng.random() < 0.5), int(rng.integers(4))
    if fy:
        cube = cube[:, ::-1]
    if fx:
        cube = cube[:, :, ::-1]
    cube = np.rot90(cube, k, axes=(1, 2))
    exposure = float(np.exp(rng.uniform(np.log(0.5), 0.0)))
    peak = float(cube.max())
    cube = np.full(cube.shape, exposure) if not peak > 0 else cube * (exposure / peak)
    info.update(flips=[fy, fx], rot90=k, exposure=round(exposure, 6))
    return np.ascontiguousarray(cube, dtype=np.float32), info


def draw_noise(seed: int) -> Optional[Dict[str, Any]]:
    """The sensor-noise settings of sample ``seed``: None (p = 0.2) or {full_well_e, read_noise_e, adc_bits}."""
    rng = np.random.default_rng([NOISE_SALT, _check_seed(seed)])
    if rng.random() < NOISE_FREE_PROBABILITY:
        return None
    lo, hi = FULL_WELL_RANGE_E
    return {"full_well_e": float(np.exp(rng.uniform(np.log(lo), np.log(hi)))), "read_noise_e": READ_NOISE_E,
            "adc_bits": ADC_BITS}


def sensor_noise(clean: np.ndarray, rng: Optional[np.random.Generator], full_well_e: float, read_noise_e: float = 0.0,
                 adc_bits: Optional[int] = None, shot: bool = True) -> np.ndarray:
    """docs/noise.md's model on an acquisition (h, w) in acquisition units: K = full well / peak electrons per
    unit; shot noise Poisson(K·v) (if ``shot``), read noise N(0, σ²) e⁻ (σ = ``read_noise_e``, 0: off), an ADC of
    ``adc_bits`` (None: off) with gain full well / (2^N − 1), clamped to [0, 2^N − 1]; returned in acquisition
    units (float64). ``rng`` may be None when neither shot nor read noise is on."""
    v = np.asarray(clean, dtype=np.float64)
    if not np.isfinite(v).all():
        raise TrainingDataError("sensor_noise: the clean acquisition has non-finite values")
    if not (np.isfinite(full_well_e) and full_well_e > 0):
        raise TrainingDataError(f"sensor_noise: full_well_e: expected a finite number > 0, got {full_well_e!r}")
    peak = float(v.max())
    if not peak > 0:
        return v.copy()
    k = full_well_e / peak
    n = k * v
    if shot:
        n = rng.poisson(np.maximum(n, 0.0)).astype(np.float64)
    if read_noise_e > 0:
        n = n + rng.normal(0.0, read_noise_e, size=n.shape)
    if adc_bits is not None:
        levels = 2 ** int(adc_bits) - 1
        g = full_well_e / levels
        n = np.clip(np.round(n / g), 0, levels) * g
    return n / k


def noisy(clean: np.ndarray, seed: int) -> Tuple[np.ndarray, Optional[Dict[str, Any]]]:
    """Sample ``seed``'s acquisition with its sensor noise (:func:`draw_noise`; float32) and the settings used."""
    nz = draw_noise(seed)
    if nz is None:
        return np.asarray(clean, dtype=np.float32), None
    rng = np.random.default_rng([NOISE_SALT, seed, 1])
    out = sensor_noise(clean, rng, nz["full_well_e"], nz["read_noise_e"], nz["adc_bits"])
    return out.astype(np.float32), nz


def manifest(bands_nm: Sequence[float] = BANDS_NM) -> Dict[str, Any]:
    """What the data is made of, for the training manifest: the measured sets (with counts), the texture images
    (file, source, licence), the kinds and their probabilities, the noise model, the images never used."""
    key = tuple(float(b) for b in bands_nm)
    _, names = _library(key)
    sets = [dict(s, spectra=names.count(s["name"])) for s in list(deadleaves.SOURCES) + [CIE2017_SOURCE]]
    base = deadleaves.sources_manifest(bands_nm)
    return {
        "generator": "diffcassi.training_data", "spectral_sets": sets, "illuminants": base["illuminants"],
        "rgb_leaves": base["rgb_leaves"],
        "textures": [{"name": n, "file": f"skimage/data/{f}", "package": "scikit-image (BSD-3; the image's own licence)",
                      "source_licence": TEXTURE_SOURCES[n]} for n, f in TEXTURES.items()],
        "kinds": dict(zip(KINDS, KIND_PROBABILITIES)),
        "augmentation": "random crop (texture: side size·z, z log-uniform [0.6, 2]), flips, 90° rotation, exposure "
                        "(peak) log-uniform [0.5, 1]",
        "sensor_noise": {"model": "docs/noise.md (auto exposure, Poisson shot, Gaussian read, ADC), NumPy PCG64 per sample",
                         "noise_free_probability": NOISE_FREE_PROBABILITY, "full_well_e_range": list(FULL_WELL_RANGE_E),
                         "read_noise_e": READ_NOISE_E, "adc_bits": ADC_BITS},
        "image_files": [f"skimage/data/{f}" for f in TEXTURES.values()],
        "evaluation_scenes_used": [], "evaluation_scenes_excluded": list(EVALUATION_SCENES),
        "bands_nm": [float(b) for b in bands_nm],
    }
