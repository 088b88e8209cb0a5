"""Procedural hyperspectral "dead leaves" cubes: the training data of the learned denoiser (``SpectralUNet``).

A dead-leaves image (Matheron; Lee, Mumford & Huang 2001) is a stack of occluding random shapes whose sizes follow
a power law (density ∝ r⁻³, scale invariant like natural images); networks trained on such synthetic images
generalise to natural photographs (Achddou, Gousseau & Ladjal 2021, "Synthetic images as a regularity prior for image
restoration neural networks"). Here every leaf is a disc, an ellipse or a convex polygon carrying a texture (flat,
smooth gradient, fractal 1/f^β noise or stripes) that blends two *reflectance spectra* taken from the cube's
palette of 3–10 "materials" (each with its own brightness: shading); the cube is lit by a smooth illuminant (a
mixture of CIE D65 and A, or equal energy), optionally blurred (depth of field) and peak-normalised to [0, 1].
Leaves are large and flat often enough for natural scenes' flat regions (the smallest radius is 2–8 px per cube,
four leaves in ten are flat).

A second kind, ``kind="rgb"``, paints the same geometry and textures with random *sRGB colours*, quantises them to
8 bits and uplifts every pixel by Smits' RGB → spectrum method (:func:`diffcassi.uplift_srgb`, the library's uplift,
the one ``diffcassi.load_scene`` applies to a photograph): the spectra then lie on the same low-dimensional family as
the evaluation scenes' (which are Smits uplifts of photographs), while no photograph is used. (Until the wheel made
the extension installable everywhere, a NumPy transcription, ``diffcassi/smits.py``, did the uplift here; the
library's gives bit-identical cubes, measured: src/recon/prior/MODEL.md, "Training data".)

The spectra come only from measured reflectance sets shipped by the ``colour-science`` pip package (BSD-3; see
:data:`SOURCES`): the ColorChecker (Ohta 1997, BabelColor average, ISO 17321-1), the PMC skin-tone patches, the
CIE test-colour samples (CRI, CIE 13.3 / CIE 2024), the NIST CQS samples and Smits' (1999) seven basis spectra.
A leaf's spectrum is a random convex mixture of one to three of them times a smooth random perturbation
(exp of a low-order cosine series), clipped to [0, 1]. Nothing here reads an image: the evaluation scenes of
``data/scenes/`` are never used for training (tested).

Every cube is a pure function of its seed (NumPy PCG64), so training data is regenerated on the fly, the same on
every machine::

    >>> from diffcassi.deadleaves import dead_leaves, BANDS_NM
    >>> cube = dead_leaves(seed=7, size=64)           # (28, 64, 64) float32, max 1
    >>> cube.shape, float(cube.max())
    ((28, 64, 64), 1.0)
    >>> dead_leaves(seed=7, size=32, kind="rgb").shape  # uplifted sRGB leaves
    (28, 32, 32)

Wavelengths are in nm; the default bands are the project's 450–650 nm, 28 bands (``numpy.linspace(450, 650, 28)``).
"""
from __future__ import annotations

import functools
from typing import Dict, List, Optional, Sequence, Tuple

import numpy as np

#: The project's default bands (nm): the CLI's 450:650:28.
BANDS_NM = np.linspace(450.0, 650.0, 28)

#: The measured spectral sets the generator draws from: (name, colour-science object, licence / reference).
SOURCES: List[Dict[str, str]] = [
    {"name": "ColorChecker N Ohta", "package": "colour-science (BSD-3)", "object": "SDS_COLOURCHECKERS['ColorChecker N Ohta']",
     "reference": "N. Ohta (1997), The basis of color reproduction engineering; 24 reflectances"},
    {"name": "BabelColor Average", "package": "colour-science (BSD-3)", "object": "SDS_COLOURCHECKERS['BabelColor Average']",
     "reference": "D. Pascale (2006), BabelColor ColorChecker average of 30 charts; 24 reflectances"},
    {"name": "ISO 17321-1", "package": "colour-science (BSD-3)", "object": "SDS_COLOURCHECKERS['ISO 17321-1']",
     "reference": "ISO 17321-1:2012 ColorChecker reflectances; 24 reflectances"},
    {"name": "PMC", "package": "colour-science (BSD-3)", "object": "SDS_COLOURCHECKERS['PMC']",
     "reference": "Skin-tone ColorChecker patches (colour-science 'PMC'); 30 reflectances"},
    {"name": "TCS CIE 1995", "package": "colour-science (BSD-3)", "object": "colour.quality.datasets.SDS_TCS['CIE 1995']",
     "reference": "CIE 13.3-1995 test colour samples (CRI); 14 reflectances"},
    {"name": "TCS CIE 2024", "package": "colour-science (BSD-3)", "object": "colour.quality.datasets.SDS_TCS['CIE 2024']",
     "reference": "CIE 2024 test colour samples; 15 reflectances"},
    {"name": "VS NIST CQS 9.0", "package": "colour-science (BSD-3)", "object": "colour.quality.datasets.SDS_VS['NIST CQS 9.0']",
     "reference": "NIST Colour Quality Scale 9.0 samples (Davis & Ohno 2010); 15 reflectances"},
    {"name": "Smits 1999", "package": "colour-science (BSD-3)", "object": "colour.recovery.SDS_SMITS1999",
     "reference": "B. Smits (1999), An RGB-to-spectrum conversion for reflectances; 7 basis spectra"},
]

#: Illuminants (relative spectral power): CIE D65 and A (CIE 015:2004) from colour-science, and equal energy.
ILLUMINANTS = ["D65", "A"]


def _resample(wl_nm: np.ndarray, values: np.ndarray, to_nm: np.ndarray) -> np.ndarray:
    """Linear interpolation onto ``to_nm`` (nm), held constant outside the tabulated range."""
    return np.interp(to_nm, wl_nm, values)


@functools.lru_cache(maxsize=8)
def _tables(bands_key: Tuple[float, ...]) -> Tuple[np.ndarray, np.ndarray, Tuple[str, ...]]:
    """(reflectances (K, B), illuminants (2, B) each with mean 1, the source name of each reflectance)."""
    try:
        import warnings
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            import colour
            import colour.quality.datasets as cq
            import colour.recovery as cr
    except ImportError as e:  # pragma: no cover - setup.sh installs it
        raise ImportError("diffcassi.deadleaves needs the colour-science package (scripts/setup.sh installs it "
                          "into .venv; or `pip install colour-science`)") from e
    to_nm = np.asarray(bands_key, dtype=np.float64)
    sets = {
        "ColorChecker N Ohta": colour.SDS_COLOURCHECKERS["ColorChecker N Ohta"],
        "BabelColor Average": colour.SDS_COLOURCHECKERS["BabelColor Average"],
        "ISO 17321-1": colour.SDS_COLOURCHECKERS["ISO 17321-1"],
        "PMC": colour.SDS_COLOURCHECKERS["PMC"],
        "TCS CIE 1995": cq.SDS_TCS["CIE 1995"],
        "TCS CIE 2024": cq.SDS_TCS["CIE 2024"],
        "VS NIST CQS 9.0": cq.SDS_VS["NIST CQS 9.0"],
        "Smits 1999": cr.SDS_SMITS1999,
    }
    assert list(sets) == [s["name"] for s in SOURCES]
    refl, names = [], []
    for name, sds in sets.items():
        for sd in sds.values():
            refl.append(_resample(np.asarray(sd.wavelengths, float), np.asarray(sd.values, float), to_nm))
            names.append(name)
    r = np.clip(np.array(refl), 0.0, 1.0)
    ill = []
    for name in ILLUMINANTS:
        sd = colour.SDS_ILLUMINANTS[name]
        v = _resample(np.asarray(sd.wavelengths, float), np.asarray(sd.values, float), to_nm)
        ill.append(v / v.mean())
    return r, np.array(ill), tuple(names)


def reflectance_library(bands_nm: Sequence[float] = BANDS_NM) -> Tuple[np.ndarray, List[str]]:
    """The measured reflectances at ``bands_nm`` (K, B) in [0, 1] and the source set of each (names of :data:`SOURCES`)."""
    r, _, names = _tables(tuple(float(b) for b in bands_nm))
    return r.copy(), list(names)


def random_reflectance(rng: np.random.Generator, library: np.ndarray) -> np.ndarray:
    """A plausible reflectance (B,) in [0, 1]: a convex (Dirichlet) mixture of 1–3 library spectra times a smooth
    random perturbation exp(Σ_{j≤3} a_j cos(π j x + φ_j)), x ∈ [0, 1] across the bands, |a_j| ≲ 0.25."""
    k = int(rng.integers(1, 4))
    idx = rng.integers(0, library.shape[0], size=k)
    w = rng.dirichlet(np.ones(k))
    s = w @ library[idx]
    x = np.linspace(0.0, 1.0, library.shape[1])
    a, phi = rng.normal(0.0, 0.12, size=3), rng.uniform(0, 2 * np.pi, size=3)
    pert = a @ np.cos(np.pi * np.arange(1, 4)[:, None] * x + phi[:, None])
    s = s * np.exp(pert) * rng.uniform(0.6, 1.3)
    return np.clip(s, 0.0, 1.0)


def _fractal_noise(rng: np.random.Generator, size: int) -> np.ndarray:
    """A (size, size) 1/f^β noise field (β ∈ [1.5, 2.5], random phases), scaled to [0, 1]."""
    beta = rng.uniform(1.5, 2.5)
    fy = np.fft.fftfreq(size)[:, None]
    fx = np.fft.rfftfreq(size)[None, :]
    f = np.sqrt(fx * fx + fy * fy)
    f[0, 0] = 1.0
    amp = f ** (-beta / 2.0)  # power spectrum ∝ f^-β → amplitude ∝ f^-β/2
    amp[0, 0] = 0.0
    spec = amp * (rng.normal(size=amp.shape) + 1j * rng.normal(size=amp.shape))
    n = np.fft.irfft2(spec, s=(size, size))
    n -= n.min()
    m = n.max()
    return n / m if m > 0 else n


def _shape_mask(rng: np.random.Generator, yy: np.ndarray, xx: np.ndarray, cy: float, cx: float, r: float) -> np.ndarray:
    """Inside-test of a random disc, ellipse or convex polygon of radius ``r`` (pixels) centred at (cy, cx)."""
    kind = rng.integers(0, 3)
    dy, dx = yy - cy, xx - cx
    if kind == 0:  # disc
        return dy * dy + dx * dx <= r * r
    th = rng.uniform(0, np.pi)
    c, s = np.cos(th), np.sin(th)
    u, v = c * dx + s * dy, -s * dx + c * dy
    if kind == 1:  # ellipse, aspect 0.25–1
        a = rng.uniform(0.25, 1.0)
        return (u / r) ** 2 + (v / (a * r)) ** 2 <= 1.0
    # convex polygon: 3–8 vertices at sorted random angles on the circle of radius r (intersection of half-planes)
    n = int(rng.integers(3, 9))
    ang = np.sort(rng.uniform(0, 2 * np.pi, size=n))
    px, py = r * np.cos(ang), r * np.sin(ang)
    inside = np.ones(dx.shape, dtype=bool)
    for i in range(n):
        x0, y0, x1, y1 = px[i], py[i], px[(i + 1) % n], py[(i + 1) % n]
        inside &= (x1 - x0) * (v - y0) - (y1 - y0) * (u - x0) >= 0
    return inside


#: Texture kinds and their probabilities: flat, smooth gradient, fractal noise, stripes. Flat leaves are the most
#: common (natural scenes have large flat regions, where the first model failed; MODEL.md).
TEXTURE_PROBABILITIES = (0.4, 0.2, 0.25, 0.15)

#: The kinds of cube :func:`dead_leaves` makes: measured-spectra leaves, or sRGB leaves uplifted by Smits' method.
KINDS = ("spectral", "rgb")


def _texture(rng: np.random.Generator, yy: np.ndarray, xx: np.ndarray, noise: np.ndarray, r: float,
             probabilities: Sequence[float] = TEXTURE_PROBABILITIES) -> np.ndarray:
    """A texture in [0, 1] on the given pixel coordinates: flat, gradient, fractal noise or stripes."""
    kind = rng.choice(4, p=list(probabilities))
    if kind == 0:
        return np.zeros(yy.shape)
    th = rng.uniform(0, 2 * np.pi)
    proj = np.cos(th) * xx + np.sin(th) * yy
    if kind == 1:  # smooth gradient across the leaf
        t = (proj - proj.min()) / max(np.ptp(proj), 1e-9)
        return t ** rng.uniform(0.5, 2.0)
    if kind == 2:  # fractal noise, from a random offset of the image's noise field
        size = noise.shape[0]
        oy, ox = rng.integers(0, size, size=2)
        return noise[(yy.astype(int) + oy) % size, (xx.astype(int) + ox) % size]
    period = rng.uniform(2.5, max(3.0, r))  # stripes, 2.5 px up to the leaf radius
    t = 0.5 + 0.5 * np.sin(2 * np.pi * proj / period + rng.uniform(0, 2 * np.pi))
    if rng.random() < 0.5:
        t = (t > 0.5).astype(np.float64)
    return t


def random_srgb(rng: np.random.Generator) -> np.ndarray:
    """A random encoded sRGB colour (3,) in [0, 1]: uniform in the sRGB cube, then pulled towards its own grey by a
    random saturation factor U[0, 1] with p = 0.5 (photographs hold many weakly saturated colours)."""
    c = rng.uniform(0.0, 1.0, size=3)
    if rng.random() < 0.5:
        m = c.mean()
        c = m + rng.uniform(0.0, 1.0) * (c - m)
    return c


def _paint_leaves(rng: np.random.Generator, size: int, palette: List[np.ndarray], max_leaves: int,
                  rmin_px: Tuple[float, float] = (2.0, 8.0),
                  textures: Sequence[float] = TEXTURE_PROBABILITIES) -> np.ndarray:
    """The dead-leaves geometry: (C, size, size) painted front to back with leaves whose colours (C-vectors, C =
    bands or 3) come from ``palette``. Radii follow a power law (density ∝ r⁻³) between r_min and the cube's size,
    r_min log-uniform in ``rmin_px`` per cube (larger leaves: larger flat regions)."""
    nc = palette[0].shape[0]
    cube = np.zeros((nc, size, size))
    covered = np.zeros((size, size), dtype=bool)
    noise = _fractal_noise(rng, size)
    rmin, rmax, alpha = float(np.exp(rng.uniform(np.log(rmin_px[0]), np.log(rmin_px[1])))), 1.0 * size, 3.0
    a1, b1 = rmin ** (1 - alpha), rmax ** (1 - alpha)
    for _ in range(max_leaves):
        r = (a1 + rng.random() * (b1 - a1)) ** (1.0 / (1 - alpha))
        cy, cx = rng.uniform(-0.1 * size, 1.1 * size, size=2)
        y0, y1 = max(int(cy - r) - 1, 0), min(int(cy + r) + 2, size)
        x0, x1 = max(int(cx - r) - 1, 0), min(int(cx + r) + 2, size)
        if y0 >= y1 or x0 >= x1:
            continue
        yy, xx = np.mgrid[y0:y1, x0:x1].astype(np.float64)
        m = _shape_mask(rng, yy, xx, cy, cx, r) & ~covered[y0:y1, x0:x1]
        if not m.any():  # hidden behind the leaves already painted
            continue
        s1 = palette[int(rng.integers(len(palette)))] * rng.uniform(0.3, 1.0)
        s2 = s1 * rng.uniform(0.2, 0.9) if rng.random() < 0.6 else palette[int(rng.integers(len(palette)))] * rng.uniform(0.3, 1.0)
        t = _texture(rng, yy, xx, noise, r, textures)
        tm = t[m]
        cube[:, y0:y1, x0:x1][:, m] = (1 - tm)[None, :] * s1[:, None] + tm[None, :] * s2[:, None]
        covered[y0:y1, x0:x1] |= m
        if covered.all():
            break
    if not covered.all():
        cube[:, ~covered] = palette[0][:, None]
    return cube


def dead_leaves(seed: int, size: int = 64, bands_nm: Sequence[float] = BANDS_NM, max_leaves: int = 600,
                blur_probability: float = 0.5, illuminant_probability: float = 0.7, kind: str = "spectral",
                rmin_px: Tuple[float, float] = (2.0, 8.0),
                textures: Sequence[float] = TEXTURE_PROBABILITIES) -> np.ndarray:
    """One hyperspectral dead-leaves cube (B, size, size), float32, peak-normalised (max exactly 1), a pure
    function of ``seed`` (an int ≥ 0) and ``kind``. Leaves are painted front to back until the image is covered or
    ``max_leaves`` is reached (the rest is one background leaf); blur (p = ``blur_probability``) is a Gaussian of
    0.5–1.5 px.

    ``kind = "spectral"``: the leaves' colours are reflectances from the measured library (a palette of 3–10 per
    cube), the cube lit by a D65/A mixture (p = ``illuminant_probability``). ``kind = "rgb"``: the leaves are
    painted in encoded sRGB (a palette of 3–10 :func:`random_srgb` colours), blurred, quantised to 8 bits like a
    PNG and uplifted per pixel by Smits' method (:func:`diffcassi.uplift_srgb`, the uplift of the evaluation scenes): the
    spectra then lie on the same family as those of uplifted photographs, without using any photograph.

    ``rmin_px`` (px) is the range of the per-cube smallest leaf radius and ``textures`` the probabilities of flat,
    gradient, fractal and stripes leaves (the defaults are the training data's; the selection set of
    ``scripts/train_denoiser.py`` asks for larger, flatter leaves)."""
    if size < 4:
        raise ValueError(f"dead_leaves: size {size} too small (at least 4)")
    if kind not in KINDS:
        raise ValueError(f"dead_leaves: kind {kind!r} is not one of {KINDS}")
    lib, ill, _ = _tables(tuple(float(b) for b in bands_nm))
    rng = np.random.default_rng(int(seed))
    # A scene has a few materials: a palette of 3–10 colours that every leaf draws from (so a patch's spectra
    # span a low-dimensional set, as in natural scenes), each leaf with its own brightness (shading).
    n_palette = int(rng.integers(3, 11))
    if kind == "spectral":
        palette = [random_reflectance(rng, lib) for _ in range(n_palette)]
    else:
        palette = [random_srgb(rng) for _ in range(n_palette)]
    cube = _paint_leaves(rng, size, palette, max_leaves, rmin_px, textures)
    if kind == "spectral" and rng.random() < illuminant_probability:  # a mixture of D65 and A, mean 1
        w = rng.random()
        cube *= ((1 - w) * ill[0] + w * ill[1])[:, None, None]
    if rng.random() < blur_probability:  # depth of field: a Gaussian blur of 0.5–1.5 px
        from scipy.ndimage import gaussian_filter
        cube = gaussian_filter(cube, sigma=(0.0, *(2 * [rng.uniform(0.5, 1.5)])), mode="reflect")
    if kind == "rgb":
        from ._native import uplift_srgb
        srgb = np.round(np.clip(cube, 0.0, 1.0) * 255.0) / 255.0  # an 8-bit PNG's values
        srgb = np.ascontiguousarray(srgb.transpose(1, 2, 0), dtype=np.float32)  # (H, W, 3), as a PNG's values / 255
        cube = uplift_srgb(srgb, [float(b) for b in bands_nm]).transpose(2, 0, 1).astype(np.float64)
    peak = cube.max()
    if not peak > 0:  # all-black leaves only (vanishingly rare): a flat cube
        return np.full(cube.shape, 1.0, dtype=np.float32)
    return (cube / peak).astype(np.float32)


def dead_leaves_batch(seeds: Sequence[int], size: int = 64, bands_nm: Sequence[float] = BANDS_NM,
                      kind: str = "spectral") -> np.ndarray:
    """(N, B, size, size) float32: :func:`dead_leaves` for each seed."""
    return np.stack([dead_leaves(int(s), size, bands_nm, kind=kind) for s in seeds])


def sources_manifest(bands_nm: Sequence[float] = BANDS_NM) -> Dict[str, object]:
    """What the training data is made of, for the training manifest: the spectral sets (with the number of
    spectra taken from each), the illuminants, and the image files read (none)."""
    _, _, names = _tables(tuple(float(b) for b in bands_nm))
    sets = [dict(s, spectra=names.count(s["name"])) for s in SOURCES]
    return {"generator": "diffcassi.deadleaves", "spectral_sets": sets, "illuminants": ILLUMINANTS + ["equal energy"],
            "rgb_leaves": {"colours": "random sRGB (diffcassi.deadleaves.random_srgb), 8-bit quantised",
                           "uplift": "Smits 1999 with pbrt-v3 tables (diffcassi.uplift_srgb = src/scene/natural.rs)"},
            "kinds": list(KINDS), "image_files": [], "bands_nm": [float(b) for b in bands_nm]}
