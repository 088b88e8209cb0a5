"""An unrolled network with the exact operator inside: K stages of GAP, each followed by a learned denoiser
(issue 22 item 5; the reference paper's pipeline with the exact model Φ instead of the idealised shift).

The data steps use Φ and Φᵀ of a :class:`diffcassi.torch.CassiOperator` — in training and on the CPU the
matrix-free form (``CassiOperator.from_operator(op, matrix_free=True)``: the Rust operator itself, the renderer's
light transport with the mask, the spectral interpolation and the Airy blur); on a GPU the same operator moved with
``.to("cuda")`` (its table kept on the device). The network is made on the operator's device and follows it (and
its own dtype: ``.to(torch.float64)``). Nothing of the operator is learned: only the denoisers and one step size
per stage.

Graph (``stages`` = K, ``width`` = C; d = Φ Φᵀ 𝟙 the GAP preconditioner of ``src/recon/gap.rs``, entries
≤ 1e-6·max d get D⁻¹ = 0 like the Rust solvers)::

    c  = 2^⌊log₂ max(|y|, |y| d⁻¹)⌋  per sample; y ← y / c      exact (a power of two): the output is c · (…) bit
                                                              for bit the unscaled graph's, and y ⊘ d stays within
                                                              the operators' ±3.4·10²⁹ for every accepted y
    x₀ = Φᵀ(y ⊘ d)                                            the GAP initialisation (no TV, no learning)
    s  = mean|x₀|  per sample (x₀ = 0: the output is 0)        the scale: the whole network is
                                                              positively homogeneous, N(a·y) = a·N(y), a ≥ 0
    for k = 1 … K:
        v_k = x_{k−1} + λ_k Φᵀ((y − Φ x_{k−1}) ⊘ d)           GAP data step, λ_k learned (starts at 1)
        x_k = s · D_k(v_k / s)                                 stage denoiser, own weights per stage
    output c · x_K

    D_k(v) = v + L_k v + U_k(v)
        L_k: a linear 1×1 convolution bands → bands (no bias): the linear spectral path (MODEL.md's round-2
             diagnosis: a ReLU-only residual graph must carry every signed per-band value through ReLUs and
             fails to learn spectral structure);
        U_k: a light residual U-Net, all convolutions with a bias, ReLU after each but the last:
             head 3×3 (bands → C) → e1;  down 2×2/2 (C → 2C);  enc 3×3 (2C → 2C) → e2;  down 2×2/2 (2C → 2C);
             mid 3×3 (2C → 2C);  up 2×2/2 transposed (2C → 2C) + e2;  dec2 3×3 (2C → 2C);
             up 2×2/2 transposed (2C → C) + e1;  dec1 3×3 (C → C);  tail 3×3 (C → bands, no ReLU).
        L_k and tail start at zero, so the untrained network is exactly plain GAP with an identity prior
        (K iterations from x₀) — "GAP-TV-free defaults".

The denoisers pad their input at the bottom and right by edge replication to multiples of 4 and crop back, so
any scene size works (training and evaluation here: 128×128). Output: the cube estimate (N, bands, H, W).

Weights: safetensors with the metadata ``arch`` = ``unrolled-gap-v1``, ``system``, ``stages``, ``bands``,
``width``, ``height``/``width_px`` (the training scene size), ``bands_nm``, ``planes``, ``rays``, the seeds and the
mask's SHA-256; :func:`load_unrolled` checks them against the operator it is given.

>>> import diffcassi, diffcassi.torch as dt, torch
>>> T = diffcassi.Transport(diffcassi.System.preset("sp"), 8, 8, bands_nm=[500, 540, 580], planes=6, rays=2)
>>> phi = dt.CassiOperator.from_operator(T.operator, matrix_free=True)
>>> net = dt.UnrolledGAP(phi, stages=2, width=4)
>>> net(torch.rand(1, *phi.image_shape)).shape
torch.Size([1, 3, 8, 8])
"""
from __future__ import annotations

import hashlib
import json
import math
import os
from typing import Any, Callable, Dict, Optional, Sequence, Tuple

import numpy as np
try:
    import torch
    from torch import nn
    import torch.nn.functional as F
except ImportError as _e:  # pragma: no cover - depends on the environment
    raise ImportError("diffcassi.unrolled needs PyTorch: pip install torch") from _e

import diffcassi
from ._files import write_staged

#: The largest |y| the networks take: the operators' limit (``diffcassi._MAX_VALUE``, ``limits::MAX_SCENE_VALUE``).
_MAX_VALUE = diffcassi._MAX_VALUE
from .denoiser import check_weights_file, pad_to_multiple

ARCH = "unrolled-gap-v1"
#: The second architecture (issue 43): DAUHST/PADUT-like stages, see :class:`UnrolledDAUHST`.
ARCH_V2 = "unrolled-dauhst-v2"

__all__ = ["ARCH", "ARCH_V2", "ARCHS", "StageDenoiser", "UnrolledGAP", "UnrolledDAUHST", "SpectralSpatialUNet",
           "DegradationEstimator", "activation_bytes", "check_network_size", "save_unrolled", "load_unrolled", "mask_sha256", "system_sha256", "read_metadata"]

_Error = diffcassi.DiffcassiValueError
#: Band wavelengths that differ by more than this are other wavelengths (the Rust loader's WAVELENGTH_TOLERANCE_NM).
_WAVELENGTH_TOLERANCE_NM = 0.01


def _what(v: Any) -> str:
    """A value's type for messages, with a tensor's dtype (``Tensor of dtype torch.int64``)."""
    return f"Tensor of dtype {v.dtype}" if isinstance(v, torch.Tensor) else type(v).__name__


def _path(where: str, path: Any) -> str:
    """A file path as a string: str, bytes (decoded as the file system does) or os.PathLike; else a TypeError."""
    try:
        return os.fsdecode(os.fspath(path))
    except TypeError:
        raise TypeError(f"{where}: path: expected a str, bytes or os.PathLike, got {type(path).__name__}") from None


def _bands_nm(where: str, value: Any, bands: int) -> list:
    """Metadata ``bands_nm`` (a list, or its JSON text) as floats: ``bands`` finite, increasing wavelengths."""
    v = value
    if isinstance(v, str):
        try:
            v = json.loads(v)
        except json.JSONDecodeError:
            raise _Error(f"{where}: metadata bands_nm = {value!r} is not a JSON list of wavelengths") from None
    if isinstance(v, np.ndarray):
        v = v.tolist()
    if not isinstance(v, (list, tuple)) or not all(isinstance(b, (int, float)) and not isinstance(b, bool) for b in v):
        raise _Error(f"{where}: metadata bands_nm = {value!r}: expected a list of {bands} wavelengths (nm)")
    v = [float(b) for b in v]
    if len(v) != bands:
        raise _Error(f"{where}: metadata bands_nm has {len(v)} wavelengths, the network {bands} bands")
    if not all(math.isfinite(b) and b > 0 for b in v) or any(b >= c for b, c in zip(v, v[1:])):
        raise _Error(f"{where}: metadata bands_nm = {v}: expected finite, positive, increasing wavelengths (nm)")
    return v


class StageDenoiser(nn.Module):
    """One stage's denoiser D(v) = v + L v + U(v) (see the module docs): a linear 1×1 spectral path beside a light
    two-level residual U-Net; both start at zero (D = identity)."""

    def __init__(self, bands: int, width: int = 16):
        super().__init__()
        c, c2 = width, 2 * width
        self.linear = nn.Conv2d(bands, bands, 1, bias=False)
        self.head = nn.Conv2d(bands, c, 3, padding=1)
        self.down1 = nn.Conv2d(c, c2, 2, stride=2)
        self.enc2 = nn.Conv2d(c2, c2, 3, padding=1)
        self.down2 = nn.Conv2d(c2, c2, 2, stride=2)
        self.mid = nn.Conv2d(c2, c2, 3, padding=1)
        self.up2 = nn.ConvTranspose2d(c2, c2, 2, stride=2)
        self.dec2 = nn.Conv2d(c2, c2, 3, padding=1)
        self.up1 = nn.ConvTranspose2d(c2, c, 2, stride=2)
        self.dec1 = nn.Conv2d(c, c, 3, padding=1)
        self.tail = nn.Conv2d(c, bands, 3, padding=1)
        for m in (self.linear, self.tail):
            nn.init.zeros_(m.weight)
            if m.bias is not None:
                nn.init.zeros_(m.bias)

    def forward(self, v: torch.Tensor) -> torch.Tensor:
        x, (h, w) = pad_to_multiple(v, 4)
        e1 = F.relu(self.head(x))
        z = F.relu(self.down1(e1))
        e2 = F.relu(self.enc2(z))
        z = F.relu(self.down2(e2))
        z = F.relu(self.mid(z))
        z = self.up2(z) + e2
        z = F.relu(self.dec2(z))
        z = self.up1(z) + e1
        z = F.relu(self.dec1(z))
        return v + self.linear(v) + self.tail(z)[..., :h, :w]


def operator_device(phi: nn.Module) -> torch.device:
    """The device an operator module computes on: its ``device`` attribute (the diffcassi operators'), else that of
    its first parameter or buffer, else the CPU."""
    dev = getattr(phi, "device", None)
    if isinstance(dev, torch.device):
        return dev
    for t in list(phi.parameters()) + list(phi.buffers()):
        return t.device
    return torch.device("cpu")


def _int_at_least(name: str, v: Any, lo: int) -> int:
    if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < lo:
        raise _Error(f"UnrolledGAP: {name}: expected an integer ≥ {lo}, got {type(v).__name__} {v!r}")
    return int(v)


def _check_size(what: str, stages: int, width: int, stage: Callable[[], Sequence[nn.Module]]) -> None:
    """Refuse a network whose float32 weights exceed the memory budget (``diffcassi.set_limits``) before any is
    allocated: one stage is built on the ``meta`` device (no memory) to count its parameters. ``stages=10**9`` took
    all the machine's memory, ``width=10**6`` asked torch for 32 TB (a held-out battery, round 8)."""
    with torch.device("meta"):
        per_stage = sum(p.numel() for m in stage() for p in m.parameters())
    need = 4.0 * per_stage * stages
    limit = float(diffcassi.get_limits()["max_memory_gb"]) * 1e9
    if need > limit:
        raise _Error(f"{what}: stages = {stages}, width = {width}: {stages} × {per_stage} float32 parameters "
                     f"({need / 1e9:.3g} GB) exceed the memory budget of {limit / 1e9:.3g} GB; use fewer stages or a smaller "
                     "width, or raise the budget (diffcassi.set_limits(max_memory_gb=…))")


#: Activation floats per padded pixel per sample per stage, a·width + b·bands + c, kept for the backward pass of a
#: forward under grad, and the fraction f of one stage's count live at the peak of a forward without grad (one
#: stage's intermediates at a time, besides the 3 cube-sized tensors x, y/c, v). The graph's count (module docs:
#: UnrolledGAP's U-Net keeps e1, its ReLU and the up-path sums, the data step and residual paths a few cubes;
#: UnrolledDAUHST's spectral–spatial blocks ≈ 24 C floats each at their level: layer norms, q/k/v and their
#: normalisations, the FFN's 2C GELUs) scales as these terms; the coefficients are fitted to the peak resident
#: memory of forward + backward on the CPU at 64²–256², batches 1–4 (float32, torch 2.15) and rounded up: the
#: estimate is 0.98–1.27× the measured peak (docs/python.md, "Memory of the unrolled networks").
_ACT_COEF = {ARCH: (4.5, 4.0, 0.0, 1.2), ARCH_V2: (72.0, 14.0, 16.0, 0.25)}


def activation_bytes(arch: str, bands: int, width: int, stages: int, height: int, width_px: int, batch: int,
                     grad: bool = True, dtype_bytes: int = 4) -> float:
    """Estimated peak memory (bytes) of the activations of one ``forward`` of an unrolled network of architecture
    ``arch`` (:data:`ARCH` or :data:`ARCH_V2`) on ``batch`` acquisitions of a ``height`` × ``width_px`` scene —
    with ``grad`` those kept for ``backward`` (every stage's), else one stage's at a time. The weights are not
    included (:func:`_check_size` counts them). The networks check it against the memory budget
    (``diffcassi.set_limits(max_memory_gb=…)``) before running, as ``CassiRenderer`` does; ``train_unrolled.py``
    checks a training step with it before tracing anything."""
    a, b, c, f = _ACT_COEF[arch]
    # The denoisers pad to multiples of 4 (edge replication).
    px = float(-(-int(height) // 4) * 4) * float(-(-int(width_px) // 4) * 4)
    per_stage = (a * width + b * bands + c) * px * float(batch) * dtype_bytes
    if grad:
        return per_stage * float(stages)
    return per_stage * f + 3.0 * bands * px * float(batch) * dtype_bytes


def _check_activations(net: nn.Module, who: str, y: torch.Tensor) -> None:
    """Refuse a ``forward`` whose activations (:func:`activation_bytes`; those kept for backward when grad is on
    and the network or y requires it) exceed the memory budget — before any stage runs. ``UnrolledDAUHST`` at 128²
    with batch 2 took 0.82 GB under a 0.3 GB budget, and 512² with batch 8 ran until the OOM killer (a held-out
    battery, round 21)."""
    grad = torch.is_grad_enabled() and (y.requires_grad or any(p.requires_grad for p in net.parameters()))
    H, W = int(net.phi.cube_shape[0]), int(net.phi.cube_shape[1])
    n = int(y.shape[0])
    elt = max(4, torch.empty((), dtype=y.dtype).element_size()) if y.dtype.is_floating_point else 4
    need = activation_bytes(net.arch, net.bands, net.width, net.stages, H, W, n, grad=grad, dtype_bytes=elt)
    limit = float(diffcassi.get_limits()["max_memory_gb"]) * 1e9
    if need > limit:
        raise _Error(f"{who}.forward: batch {n} of {H}×{W} × {net.bands} bands, stages = {net.stages}, width = "
                     f"{net.width}: its activations{' (kept for backward)' if grad else ''} need an estimated "
                     f"{need / 1e9:.3g} GB, over the memory budget of {limit / 1e9:.3g} GB; use a smaller batch (split "
                     "it), or raise the budget (diffcassi.set_limits(max_memory_gb=…))")


def _pow2_scale(y: torch.Tensor, dinv: torch.Tensor) -> torch.Tensor:
    """The network's internal scale c of acquisitions ``y`` (N, h, w): per sample the power of two at or below the
    peak of |y| and |y|·d⁻¹ (the largest values the data steps hand the operator), shape (N, 1, 1), detached; 1
    for a sample whose peak is 0 (a dark frame) or below the dtype's normal range.

    The networks are positively homogeneous, N(a·y) = a·N(y), and a power of two scales every floating-point
    operation exactly (no rounding: the operator's sums, the scale s = mean|x₀|, v/s, the gradients), so
    ``c · N(y / c)`` is N(y) bit for bit while the data steps run on values of order 1 — within the operators'
    ±``_MAX_VALUE`` limit for every y the entry check accepts, however large d⁻¹ (y ⊘ d overflowed that limit
    for |y| ≳ 10²⁴ at d⁻¹ ≈ 3·10⁵: round 7). No host synchronisation (device-side bit arithmetic)."""
    with torch.no_grad():
        a = y.abs()
        # |y|·d⁻¹ may pass float32's range (a peak of 3.4·10²⁹ and d⁻¹ > 10⁹): clamped, so c stays finite.
        peak = torch.maximum(a.flatten(1).amax(1), (a * dinv.to(a.dtype)).flatten(1).amax(1))
        peak = peak.clamp(max=torch.finfo(a.dtype).max)
        if a.dtype == torch.float32:
            c = (peak.view(torch.int32) & 0x7F800000).view(torch.float32)  # the exponent alone: 2^⌊log₂ peak⌋
        elif a.dtype == torch.float64:
            c = (peak.view(torch.int64) & 0x7FF0000000000000).view(torch.float64)
        else:  # float16/bfloat16: exact powers of two from exp2 of an integer
            c = torch.exp2(torch.floor(torch.log2(peak)))
        c = torch.where((c > 0) & torch.isfinite(c), c, torch.ones_like(c))  # 0 (dark) or subnormal peak: unscaled
        return c.view(-1, 1, 1)


#: Half-precision network dtypes: the data steps (the operator's work, float32 there anyway) run in float32.
_HALF = (torch.float16, torch.bfloat16)


def _work_dtype(dtype: torch.dtype) -> torch.dtype:
    """The dtype of a network's data steps: float32 for a float16/bfloat16 network (its denoisers run in their
    own dtype, their inputs cast to it), else the network's."""
    return torch.float32 if dtype in _HALF else dtype


class _Float32Dinv(nn.Module):
    """``.half()``/``.bfloat16()``/``.to(float16)`` keep the ``dinv`` buffer (GAP's D⁻¹, up to ~10⁶) in float32: in
    float16 it became inf, and every input was refused with an error that blamed the data ("adjoint: y: value inf
    at index …"; a held-out battery, round 16). The data steps run in float32 for such a network (:func:`_work_dtype`)."""

    def _apply(self, fn, recurse=True):
        dinv = self.dinv
        out = super()._apply(fn, recurse)
        if self.dinv.dtype in _HALF:
            self.dinv = dinv.to(device=self.dinv.device, dtype=torch.float32)
        return out


class UnrolledGAP(_Float32Dinv):
    """K GAP stages with learned denoisers around a fixed operator ``phi`` (a :class:`~diffcassi.torch.CassiOperator`
    or :class:`~diffcassi.torch.MatrixFreeCassiOperator`: anything with ``forward``, ``adjoint``, ``cube_shape``
    (H, W, bands) and ``image_shape``). ``forward(y)``: acquisitions (N, h, w) or (h, w) → cubes
    (N, bands, H, W) or (bands, H, W). The operator is not a parameter (it is not saved with the weights). A
    float16/bfloat16 network (``.half()``) runs its denoisers in that dtype and its data steps in float32 (the
    operator computes in float32 either way; GAP's D⁻¹ exceeds float16's range); the output is in its dtype."""

    def __init__(self, phi: nn.Module, stages: int = 6, width: int = 16):
        super().__init__()
        for attr in ("forward", "adjoint", "cube_shape", "image_shape"):
            if not hasattr(phi, attr):
                raise TypeError(f"UnrolledGAP: phi: expected a diffcassi.torch.CassiOperator (or its matrix-free form), "
                                f"got {type(phi).__name__} without `{attr}`")
        self.stages = _int_at_least("stages", stages, 1)
        self.width = _int_at_least("width", width, 1)
        self.bands = int(phi.cube_shape[2])
        _check_size("UnrolledGAP", self.stages, self.width, lambda: [StageDenoiser(self.bands, self.width)])
        self.phi = phi
        # Everything is made on the operator's device (a CUDA operator: the whole network there).
        dev = operator_device(phi)
        self.denoisers = nn.ModuleList(StageDenoiser(self.bands, self.width) for _ in range(self.stages)).to(dev)
        #: λ_k, the GAP step of each stage (1: the Rust solvers' default).
        self.steps = nn.Parameter(torch.ones(self.stages, device=dev))
        with torch.no_grad():
            d = phi(phi.adjoint(torch.ones(tuple(phi.image_shape), dtype=torch.float32, device=dev)))
            d = d.to(torch.float32)
            if not bool(torch.isfinite(d).all()) or float(d.max()) <= 0:
                raise _Error("UnrolledGAP: phi: Φ Φᵀ 𝟙 is not finite and positive anywhere (an operator that reaches no pixel)")
            # Pixels no voxel reaches get D⁻¹ = 0 (as src/recon/gap.rs).
            dinv = torch.where(d > 1e-6 * d.max(), 1.0 / d, torch.zeros_like(d))
        self.register_buffer("dinv", dinv, persistent=False)

    @property
    def device(self) -> torch.device:
        """The device of the network's parameters (the operator's; ``.to(device)`` moves both)."""
        return self.steps.device

    def _data_step(self, x: torch.Tensor, y: torch.Tensor, lam: torch.Tensor) -> torch.Tensor:
        return x + lam * self.phi.adjoint((y - self.phi(x)) * self.dinv)

    def initial(self, y: torch.Tensor) -> torch.Tensor:
        """x₀ = Φᵀ(y ⊘ d) of acquisitions (N, h, w)."""
        return self.phi.adjoint(y * self.dinv)

    def forward(self, y: torch.Tensor) -> torch.Tensor:
        if not isinstance(y, torch.Tensor) or not y.dtype.is_floating_point:
            raise TypeError(f"UnrolledGAP.forward: y: expected a floating-point torch.Tensor, got {_what(y)}")
        # A y that is not finite, or beyond ±{_MAX_VALUE:.3e} (f32's range / 10⁹, Operator.apply's limit: the operator's
        # sums overflow past it, NaN by the last stage), is refused once here, before any stage — one host
        # synchronisation a call on CUDA, where the operators themselves do not check (docs/python.md).
        if y.device.type != "meta" and not bool((torch.isfinite(y) & (y.abs() <= _MAX_VALUE)).all()):  # (meta: the device check below)
            raise _Error(f"UnrolledGAP.forward: y holds NaN or infinite values, or values beyond ±{_MAX_VALUE:.3e} "
                         "(f32's range / 10⁹, the operators' limit); rescale it")
        h, w = self.phi.image_shape
        single = y.dim() == 2
        if single:
            y = y.unsqueeze(0)
        if y.dim() != 3 or tuple(y.shape[1:]) != (h, w):
            raise _Error(f"UnrolledGAP.forward: y: expected shape (batch, {h}, {w}) or ({h}, {w}), got {tuple(y.shape)}")
        if y.device != self.steps.device:
            raise _Error(f"UnrolledGAP.forward: y is on {y.device} but the network on {self.steps.device}; "
                         "move one with .to(device)")
        _check_activations(self, "UnrolledGAP", y)
        pdt = self.steps.dtype  # the network's dtype (float32 unless .to(dtype) changed it)
        work = _work_dtype(pdt)  # float32 data steps for a float16/bfloat16 network (round 16)
        y = y.to(work)
        # The network runs on y / c, c a power of two (_pow2_scale): N(y) = c·N(y/c) bit for bit, and y ⊘ d stays
        # within the operators' limit for every y the entry check accepts (it overflowed for |y| ≳ 10²⁴).
        c = _pow2_scale(y, self.dinv)
        y = y / c
        x = self.initial(y)
        # s = mean|x₀| (= mean(x₀) for an acquisition ≥ 0, the trained case): N(a·y) = a·N(y) for a > 0, and an
        # x₀ of zero (a dark frame) reconstructs as zero — a scale of 1 there let the stages' biases through, a
        # bright cube from a black acquisition (a held-out battery). As src/recon/unrolled.rs. Not detached: the
        # network depends on s, so ∂/∂y (a renderer upstream, co-design) must go through it (it was detached: the
        # y-gradient was off by ~1 % once the weights are trained; the parameters' gradients are the same either way).
        s = x.flatten(1).abs().mean(1).view(-1, 1, 1, 1)
        live = s > 0
        s = torch.where(live, s, torch.ones_like(s))
        for k, den in enumerate(self.denoisers):
            v = self._data_step(x, y, self.steps[k])
            x = s * den((v / s).to(pdt)).to(work)
        x = (torch.where(live, x, torch.zeros_like(x)) * c.unsqueeze(1)).to(pdt)
        return x[0] if single else x

    def metadata(self) -> Dict[str, str]:
        """The architecture part of the weights file's metadata."""
        return {"arch": ARCH, "stages": str(self.stages), "bands": str(self.bands), "width": str(self.width)}

    def extra_repr(self) -> str:
        n = sum(p.numel() for p in self.parameters())
        return f"stages={self.stages}, bands={self.bands}, width={self.width}, {n} parameters"


# ---------------------------------------------------------------------------------------------------------------
# unrolled-dauhst-v2 (issue 43): DAUHST/PADUT-like stages around the same exact operator.

def _gap_dinv(phi: nn.Module, dev: torch.device, who: str) -> torch.Tensor:
    """D⁻¹ of GAP's preconditioner d = Φ Φᵀ 𝟙 (entries ≤ 1e-6·max d: 0, as src/recon/gap.rs), float32 on ``dev``."""
    with torch.no_grad():
        d = phi(phi.adjoint(torch.ones(tuple(phi.image_shape), dtype=torch.float32, device=dev))).to(torch.float32)
        if not bool(torch.isfinite(d).all()) or float(d.max()) <= 0:
            raise _Error(f"{who}: phi: Φ Φᵀ 𝟙 is not finite and positive anywhere (an operator that reaches no pixel)")
        return torch.where(d > 1e-6 * d.max(), 1.0 / d, torch.zeros_like(d))


class LayerNorm2d(nn.Module):
    """Layer normalisation over the channels of every pixel (N, C, H, W), with a learned affine map."""

    def __init__(self, c: int):
        super().__init__()
        self.weight = nn.Parameter(torch.ones(c))
        self.bias = nn.Parameter(torch.zeros(c))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return F.layer_norm(x.permute(0, 2, 3, 1), (x.shape[1],), self.weight, self.bias, 1e-6).permute(0, 3, 1, 2)


class SpectralAttention(nn.Module):
    """Spectral-wise multi-head self-attention (MST's S-MSA): the tokens are the channels, so the attention map is
    C/heads × C/heads per head whatever the image size (cost linear in H·W). Queries and keys are L2-normalised over
    the pixels, with a learned temperature per head; a depth-wise 3×3 convolution of the values adds position."""

    def __init__(self, c: int, heads: int):
        super().__init__()
        self.heads = heads
        self.qkv = nn.Conv2d(c, 3 * c, 1, bias=False)
        self.temperature = nn.Parameter(torch.ones(heads, 1, 1))
        self.proj = nn.Conv2d(c, c, 1)
        self.pos = nn.Conv2d(c, c, 3, padding=1, groups=c)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        n, c, h, w = x.shape
        q, k, v = self.qkv(x).chunk(3, dim=1)
        split = lambda t: t.reshape(n, self.heads, c // self.heads, h * w)  # noqa: E731
        q, k, vv = F.normalize(split(q), dim=-1), F.normalize(split(k), dim=-1), split(v)
        attn = torch.softmax((q @ k.transpose(-2, -1)) * self.temperature, dim=-1)
        out = (attn @ vv).reshape(n, c, h, w)
        return self.proj(out) + self.pos(v)


class SpectralSpatialBlock(nn.Module):
    """x + S-MSA(LN x), then + FFN(LN x): 1×1 (C → 2C), GELU, depth-wise 3×3, GELU, 1×1 (2C → C)."""

    def __init__(self, c: int, heads: int):
        super().__init__()
        self.n1, self.attn = LayerNorm2d(c), SpectralAttention(c, heads)
        self.n2 = LayerNorm2d(c)
        self.ffn = nn.Sequential(nn.Conv2d(c, 2 * c, 1), nn.GELU(), nn.Conv2d(2 * c, 2 * c, 3, padding=1, groups=2 * c),
                                 nn.GELU(), nn.Conv2d(2 * c, c, 1))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        x = x + self.attn(self.n1(x))
        return x + self.ffn(self.n2(x))


class SpectralSpatialUNet(nn.Module):
    """One stage's prior P(v, σ) = v + L v + U([v, σ]): L a linear 1×1 spectral convolution (bands → bands, no
    bias), U a three-level U-Net of :class:`SpectralSpatialBlock` (widths C, 2C, 4C), the noise level σ entering as a constant input channel (DAUHST's conditioning). Embedding
    3×3 (bands + 1 → C); level 1 block; 4×4/2 down (C → 2C); level 2 block; 4×4/2 down (2C → 4C); two bottleneck
    blocks; 2×2/2 transposed up (4C → 2C), concatenation with level 2, 1×1 fuse (4C → 2C), block; the same to C;
    3×3 out (C → bands). L and the out convolution start at zero: P = identity until trained. Pads to multiples of
    4 (edge replication) and crops back: any size. Attention heads: 1, 2, 4 at the three levels (head dimension C,
    MST's rule)."""

    def __init__(self, bands: int, width: int = 24):
        super().__init__()
        c = width
        heads = lambda ch: ch // c  # noqa: E731
        self.linear = nn.Conv2d(bands, bands, 1, bias=False)
        self.embed = nn.Conv2d(bands + 1, c, 3, padding=1)
        self.enc1 = SpectralSpatialBlock(c, heads(c))
        self.down1 = nn.Conv2d(c, 2 * c, 4, stride=2, padding=1)
        self.enc2 = SpectralSpatialBlock(2 * c, heads(2 * c))
        self.down2 = nn.Conv2d(2 * c, 4 * c, 4, stride=2, padding=1)
        self.mid = nn.Sequential(SpectralSpatialBlock(4 * c, heads(4 * c)), SpectralSpatialBlock(4 * c, heads(4 * c)))
        self.up2 = nn.ConvTranspose2d(4 * c, 2 * c, 2, stride=2)
        self.fuse2 = nn.Conv2d(4 * c, 2 * c, 1)
        self.dec2 = SpectralSpatialBlock(2 * c, heads(2 * c))
        self.up1 = nn.ConvTranspose2d(2 * c, c, 2, stride=2)
        self.fuse1 = nn.Conv2d(2 * c, c, 1)
        self.dec1 = SpectralSpatialBlock(c, heads(c))
        self.out = nn.Conv2d(c, bands, 3, padding=1)
        for m in (self.linear, self.out):
            nn.init.zeros_(m.weight)
            if m.bias is not None:
                nn.init.zeros_(m.bias)

    def forward(self, v: torch.Tensor, sigma: torch.Tensor) -> torch.Tensor:
        x, (h, w) = pad_to_multiple(v, 4)
        s = sigma.view(-1, 1, 1, 1).to(x.dtype).expand(x.shape[0], 1, x.shape[2], x.shape[3])
        e1 = self.enc1(self.embed(torch.cat([x, s], 1)))
        e2 = self.enc2(self.down1(e1))
        z = self.mid(self.down2(e2))
        z = self.dec2(self.fuse2(torch.cat([self.up2(z), e2], 1)))
        z = self.dec1(self.fuse1(torch.cat([self.up1(z), e1], 1)))
        return v + self.linear(v) + self.out(z)[..., :h, :w]


#: softplus⁻¹(1): the step estimate's initial bias (μ = 1, GAP's step).
_SOFTPLUS_INV_1 = math.log(math.e - 1.0)
#: The noise-level estimate's initial value (σ on the cube's scale, the scale s = mean|x₀|).
SIGMA_INIT = 0.05


class DegradationEstimator(nn.Module):
    """DAUHST's degradation estimate for one stage: a small CNN on [x/s, r/s] (the iterate and the back-projected
    residual r = Φᵀ((y − Φx) ⊘ d), 2·bands channels): 3×3/2 (→ 32), ReLU, 3×3/2 (32 → 32), ReLU, global mean, 1×1
    (32 → 32), ReLU, 1×1 (32 → 2) → (μ, σ) = softplus(·). The last layer starts at weights 0 and biases giving μ = 1
    (GAP's step) and σ = :data:`SIGMA_INIT`. Scale-free (inputs divided by s) and size-free (global mean)."""

    def __init__(self, bands: int, hidden: int = 32):
        super().__init__()
        self.conv = nn.Sequential(nn.Conv2d(2 * bands, hidden, 3, stride=2, padding=1), nn.ReLU(),
                                  nn.Conv2d(hidden, hidden, 3, stride=2, padding=1), nn.ReLU())
        self.mlp = nn.Sequential(nn.Linear(hidden, hidden), nn.ReLU(), nn.Linear(hidden, 2))
        nn.init.zeros_(self.mlp[2].weight)
        with torch.no_grad():
            self.mlp[2].bias.copy_(torch.tensor([_SOFTPLUS_INV_1, math.log(math.expm1(SIGMA_INIT))]))

    def forward(self, x: torch.Tensor, r: torch.Tensor) -> Tuple[torch.Tensor, torch.Tensor]:
        z = self.conv(torch.cat([x, r], 1)).mean(dim=(2, 3))
        mu, sigma = F.softplus(self.mlp(z)).unbind(1)
        return mu, sigma


class UnrolledDAUHST(_Float32Dinv):
    """``unrolled-dauhst-v2``: K stages of a learned-step GAP data step and a noise-conditioned spectral–spatial
    prior around a fixed operator ``phi`` (as :class:`UnrolledGAP`: anything with ``forward``, ``adjoint``,
    ``cube_shape``, ``image_shape``; the operator is not a parameter and not saved). Graph (d = Φ Φᵀ 𝟙)::

        y ← y / c (c a power of two, as UnrolledGAP: exact, keeps y ⊘ d within the operators' limit)
        x₀ = Φᵀ(y ⊘ d);  s = mean|x₀| per sample (x₀ = 0: output 0)   N(a·y) = a·N(y) exactly, a ≥ 0
        for k = 1 … K:
            r_k = Φᵀ((y − Φ x_{k−1}) ⊘ d)                                 exact Φ and Φᵀ in every stage
            (μ_k, σ_k) = E_k(x_{k−1}/s, r_k/s)                            DegradationEstimator (own weights)
            v_k = x_{k−1} + μ_k r_k                                       GAP data step, learned per sample
            x_k = s · P_k(v_k/s, σ_k)                                     SpectralSpatialUNet (own weights)
        output c · x_K

    Untrained (zero L, out and estimator outputs μ = 1) it is exactly K plain GAP steps. ``forward(y)``:
    (N, h, w) or (h, w) → (N, bands, H, W) or (bands, H, W). ``forward(y, return_estimates=True)`` also returns
    the per-stage (μ, σ), shape (K, N) each."""

    arch = ARCH_V2

    def __init__(self, phi: nn.Module, stages: int = 3, width: int = 24):
        super().__init__()
        for attr in ("forward", "adjoint", "cube_shape", "image_shape"):
            if not hasattr(phi, attr):
                raise TypeError(f"UnrolledDAUHST: phi: expected a diffcassi.torch.CassiOperator (or its matrix-free "
                                f"form), got {type(phi).__name__} without `{attr}`")
        self.stages = _int_at_least("stages", stages, 1)
        self.width = _int_at_least("width", width, 1)
        self.bands = int(phi.cube_shape[2])
        _check_size("UnrolledDAUHST", self.stages, self.width,
                    lambda: [DegradationEstimator(self.bands), SpectralSpatialUNet(self.bands, self.width)])
        self.phi = phi
        dev = operator_device(phi)
        self.estimators = nn.ModuleList(DegradationEstimator(self.bands) for _ in range(self.stages)).to(dev)
        self.priors = nn.ModuleList(SpectralSpatialUNet(self.bands, self.width) for _ in range(self.stages)).to(dev)
        self.register_buffer("dinv", _gap_dinv(phi, dev, "UnrolledDAUHST"), persistent=False)

    @property
    def device(self) -> torch.device:
        return self.priors[0].linear.weight.device

    def forward(self, y: torch.Tensor, return_estimates: bool = False):
        if not isinstance(y, torch.Tensor) or not y.dtype.is_floating_point:
            raise TypeError(f"UnrolledDAUHST.forward: y: expected a floating-point torch.Tensor, got {_what(y)}")
        # A y that is not finite, or beyond ±{_MAX_VALUE:.3e} (f32's range / 10⁹, Operator.apply's limit: the operator's
        # sums overflow past it, NaN by the last stage), is refused once here, before any stage — one host
        # synchronisation a call on CUDA, where the operators themselves do not check (docs/python.md).
        if y.device.type != "meta" and not bool((torch.isfinite(y) & (y.abs() <= _MAX_VALUE)).all()):  # (meta: the device check below)
            raise _Error(f"UnrolledDAUHST.forward: y holds NaN or infinite values, or values beyond ±{_MAX_VALUE:.3e} "
                         "(f32's range / 10⁹, the operators' limit); rescale it")
        h, w = self.phi.image_shape
        single = y.dim() == 2
        if single:
            y = y.unsqueeze(0)
        if y.dim() != 3 or tuple(y.shape[1:]) != (h, w):
            raise _Error(f"UnrolledDAUHST.forward: y: expected shape (batch, {h}, {w}) or ({h}, {w}), got {tuple(y.shape)}")
        pdev, pdt = self.device, self.priors[0].linear.weight.dtype
        if y.device != pdev:
            raise _Error(f"UnrolledDAUHST.forward: y is on {y.device} but the network on {pdev}; move one with .to(device)")
        _check_activations(self, "UnrolledDAUHST", y)
        work = _work_dtype(pdt)  # float32 data steps for a float16/bfloat16 network (UnrolledGAP; round 16)
        y = y.to(work)
        # On y / c, c a power of two: N(y) = c·N(y/c) bit for bit, y ⊘ d within the operators' limit (_pow2_scale).
        c = _pow2_scale(y, self.dinv)
        y = y / c
        x = self.phi.adjoint(y * self.dinv)
        # s = mean|x₀|, differentiable; an x₀ of zero reconstructs as zero (UnrolledGAP.forward says why).
        s = x.flatten(1).abs().mean(1).view(-1, 1, 1, 1)
        live = s > 0
        s = torch.where(live, s, torch.ones_like(s))
        mus, sigmas = [], []
        for est, prior in zip(self.estimators, self.priors):
            r = self.phi.adjoint((y - self.phi(x)) * self.dinv)
            mu, sigma = est((x / s).to(pdt), (r / s).to(pdt))
            v = x + mu.view(-1, 1, 1, 1).to(work) * r
            x = s * prior((v / s).to(pdt), sigma).to(work)
            mus.append(mu)
            sigmas.append(sigma)
        x = (torch.where(live, x, torch.zeros_like(x)) * c.unsqueeze(1)).to(pdt)
        out = x[0] if single else x
        if return_estimates:
            return out, (torch.stack(mus), torch.stack(sigmas))
        return out

    def metadata(self) -> Dict[str, str]:
        return {"arch": ARCH_V2, "stages": str(self.stages), "bands": str(self.bands), "width": str(self.width)}

    def extra_repr(self) -> str:
        n = sum(p.numel() for p in self.parameters())
        return f"stages={self.stages}, bands={self.bands}, width={self.width}, {n} parameters"


UnrolledGAP.arch = ARCH
#: Architecture tag → network class (the weights files' ``arch``).
ARCHS = {ARCH: UnrolledGAP, ARCH_V2: UnrolledDAUHST}


def make_unrolled(arch: str, phi: nn.Module, stages: int, width: int) -> nn.Module:
    """A new network of architecture ``arch`` (a key of :data:`ARCHS`) around ``phi``."""
    if arch not in ARCHS:
        raise _Error(f"unrolled network: arch {arch!r} is not one of {sorted(ARCHS)}")
    return ARCHS[arch](phi, stages=stages, width=width)


def check_network_size(arch: str, bands: int, stages: int, width: int) -> None:
    """Refuse, before any operator is traced, a network of architecture ``arch`` whose float32 weights exceed the
    memory budget (the check the networks' constructors make; ``train_unrolled.py`` makes it before tracing its
    operators: ``--bands 100000`` was refused only after both were traced, a held-out battery, round 21)."""
    if arch not in ARCHS:
        raise _Error(f"unrolled network: arch {arch!r} is not one of {sorted(ARCHS)}")
    what = ARCHS[arch].__name__
    bands = _int_at_least("bands", bands, 1)
    stages, width = _int_at_least("stages", stages, 1), _int_at_least("width", width, 1)
    if arch == ARCH_V2:
        _check_size(what, stages, width, lambda: [DegradationEstimator(bands), SpectralSpatialUNet(bands, width)])
    else:
        _check_size(what, stages, width, lambda: [StageDenoiser(bands, width)])


def count_parameters(net: nn.Module) -> int:
    """The learned parameters of a network (the operator has none)."""
    return sum(p.numel() for p in net.parameters())


def mask_sha256(mask: Any) -> str:
    """SHA-256 of a mask as float32 C-order bytes (the weights file records the training mask's)."""
    return hashlib.sha256(np.ascontiguousarray(mask, dtype=np.float32).tobytes()).hexdigest()


def system_sha256(system: Any) -> str:
    """SHA-256 of a :class:`diffcassi.System`'s prescription (``System.prescription_sha256``, the library's
    ``diffcassi::spec::system_sha256``: its JSON with solved and picked-up values left out — they follow from the
    rest — and other floats to 12 significant digits, so that the last bit of a platform's libm does not change
    it): the weights record the training system's, so a system renamed or edited is told apart from the preset."""
    return system.prescription_sha256()


def save_unrolled(net: nn.Module, path: Any, metadata: Dict[str, Any]) -> None:
    """Writes ``net``'s weights (:class:`UnrolledGAP` or :class:`UnrolledDAUHST`; not the operator) to the
    safetensors file ``path`` with the network's ``metadata()`` plus ``metadata`` (must name ``system``; a v2
    network also ``mask_sha256``; values stored as strings, non-strings as JSON), atomically
    (:func:`diffcassi._files.write_staged`); refuses non-finite weights (nothing written)."""
    from safetensors.torch import save_file
    path = _path("save_unrolled", path)
    if not isinstance(metadata, dict):
        raise TypeError(f"save_unrolled: metadata: expected a dict, got {type(metadata).__name__}")
    if "system" not in metadata:
        raise _Error(f"save_unrolled: {path}: metadata must name the system the network was trained for")
    if isinstance(net, UnrolledDAUHST) and "mask_sha256" not in metadata:
        raise _Error(f"save_unrolled: {path}: metadata must record the training mask's mask_sha256 ({ARCH_V2})")
    tensors = {k: v.detach().to(torch.float32).contiguous().clone() for k, v in net.state_dict().items()
               if not k.startswith("phi.")}
    for k, v in tensors.items():
        if not torch.isfinite(v).all():
            raise _Error(f"save_unrolled: tensor {k} has non-finite values; {path} not written")
    meta = net.metadata()
    # The network's own keys (arch, stages, bands, width) are its architecture: a caller's value would write a file
    # that does not load (`{"stages": 5}` for 3 stages); values are strings or finite JSON numbers, lists, dicts
    # (None became 'null', NaN an unreadable 'NaN').
    text = lambda v: v if isinstance(v, str) else json.dumps(v)  # noqa: E731
    clash = sorted(str(k) for k, v in metadata.items() if str(k) in meta and text(v) != meta[str(k)])
    if clash:
        raise _Error(f"save_unrolled: {path}: metadata {clash} differ from the network's own (its architecture: {net.metadata()}); "
                     "drop them or give the network's values")
    for k, v in metadata.items():
        if v is None:
            raise _Error(f"save_unrolled: {path}: metadata {k!r} is None; give a value or leave the key out")
        if not isinstance(v, str):
            try:
                json.dumps(v, allow_nan=False)
            except (TypeError, ValueError) as e:
                raise _Error(f"save_unrolled: {path}: metadata {k!r} = {v!r} is not a string or finite JSON value ({e})") from None
    if "bands_nm" in metadata:  # the Rust loader compares them band by band: a file it would refuse is not written
        _bands_nm(f"save_unrolled: {path}", metadata["bands_nm"], int(meta["bands"]))
    meta.update({str(k): text(v) for k, v in metadata.items()})
    mode = 0o666 & ~_umask()

    def write(stage: str) -> None:
        save_file(tensors, stage, metadata=meta)
        os.chmod(stage, mode)  # safetensors creates 0600; a file is created as open() would (0666 & ~umask)

    write_staged("save_unrolled", path, write)


def _umask() -> int:
    """The process's umask (from /proc where it is, else set and restored)."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError, IndexError):
        pass
    um = os.umask(0o022)
    os.umask(um)
    return um


def read_metadata(path: Any) -> Dict[str, str]:
    """The metadata of an unrolled-network weights file (a DiffcassiFileError if missing, a DiffcassiValueError if it
    is not safetensors or not one of :data:`ARCHS`)."""
    return _read(path)[0]


def _read(path: Any):
    from safetensors import safe_open
    path = _path("unrolled weights", path)
    check_weights_file(path, "unrolled weights", diffcassi.DiffcassiFileError)
    try:
        with safe_open(path, framework="pt") as f:
            meta = f.metadata() or {}
            tensors = {k: f.get_tensor(k) for k in f.keys()}
    except Exception as e:  # safetensors raises its own error types for a bad header or truncated data
        raise _Error(f"unrolled weights {path}: not a valid safetensors file ({e})") from None
    if meta.get("arch") not in ARCHS:
        raise _Error(f"unrolled weights {path}: metadata arch is {meta.get('arch')!r}, expected one of {sorted(ARCHS)}")
    return meta, tensors


def load_unrolled(path: Any, phi: nn.Module, system: Any = None, mask: Any = None) -> nn.Module:
    """Loads an unrolled-network safetensors file (``unrolled-gap-v1`` → :class:`UnrolledGAP`,
    ``unrolled-dauhst-v2`` → :class:`UnrolledDAUHST`) into a new network around ``phi`` (eval mode).

    Checked, each failure a DiffcassiValueError naming the file and the problem (a missing file, a folder, a FIFO or
    device, a file over 1 GiB: a DiffcassiFileError; ``phi`` not an operator module: a TypeError naming it): the
    format and ``arch``; ``stages``, ``bands``, ``width`` integers ≥ 1; ``bands`` equal to ``phi``'s band count;
    ``system`` equal to the system the weights were trained for — a preset name (then its name and, where the
    file records one, the preset's prescription, :func:`system_sha256`), or a :class:`diffcassi.System` (its name
    *and* prescription, where the file records it); ``mask`` (when given)
    equal to the training mask (SHA-256); every tensor present with its shape, finite, and no other.

    ``system`` defaults to the system ``phi``'s operator was built from, where it knows it (``exact``,
    ``mapping_operator``, ``shift_operator``; not an operator read from a file), and a ``system`` named that is
    not that one is refused. For ``unrolled-dauhst-v2`` the
    system is **required** and a mismatch is **refused** (an error, not a warning): a network trained for one
    system is never run on another system's acquisition; so is a v1 network whose operator names its system."""
    if not hasattr(phi, "cube_shape"):
        # Checked before the file is read (phi=None raised AttributeError after it, issue 39).
        raise TypeError(f"load_unrolled: phi: expected a diffcassi.torch.CassiOperator (or its matrix-free form), "
                        f"got {type(phi).__name__} without `cube_shape`")
    path = _path("load_unrolled", path)
    meta, tensors = _read(path)
    arch = meta["arch"]
    try:
        stages, bands, width = int(meta["stages"]), int(meta["bands"]), int(meta["width"])
    except (KeyError, ValueError):
        raise _Error(f"unrolled weights {path}: metadata stages/bands/width missing or not integers "
                     f"(stages={meta.get('stages')!r}, bands={meta.get('bands')!r}, width={meta.get('width')!r})") from None
    if min(stages, bands, width) < 1:
        raise _Error(f"unrolled weights {path}: metadata stages={stages}, bands={bands}, width={width} must be ≥ 1")
    # The network is built before its tensors are compared: bound its size first (a 12 KB file claiming
    # stages=20000 or width=3000 allocated gigabytes, a held-out battery). The Rust loader's stage range, and
    # stages × width² ≤ 2²² (64 stages of width 256; ours: 2–3 stages of width ≤ 64).
    if stages > 64 or stages * width * width > 1 << 22:
        raise _Error(f"unrolled weights {path}: metadata stages={stages}, width={width}: stages must be in 1..=64 and "
                     f"stages × width² ≤ {1 << 22} (the largest network this loader builds)")
    have = int(phi.cube_shape[2])
    if bands != have:
        raise _Error(f"unrolled weights {path}: the network is for {bands} bands, the operator has {have}")
    if "bands_nm" in meta:
        trained = _bands_nm(f"unrolled weights {path}", meta["bands_nm"], bands)
        here = getattr(phi, "bands_nm", None)  # CassiOperator / MatrixFreeCassiOperator: where known
        if here is not None and len(here) == bands:
            k = next((k for k in range(bands) if abs(trained[k] - float(here[k])) > _WAVELENGTH_TOLERANCE_NM), None)
            if k is not None:
                raise _Error(f"unrolled weights {path}: metadata bands_nm: band {k} is {trained[k]:g} nm, the operator's "
                             f"is {float(here[k]):g} nm (tolerance {_WAVELENGTH_TOLERANCE_NM} nm): trained for other "
                             "wavelengths (refused)")
    # The operator's own system, where it knows it (one built by exact, mapping_operator or shift_operator):
    # weights for another system are refused, as `reconstruct --weights` refuses them (an msp operator ran sp's
    # v1 weights in silence; a held-out battery, round 15) — and so is a `system` that is not the operator's.
    op_system = getattr(phi, "system", None) or getattr(getattr(phi, "op", None), "system", None)
    given = system if isinstance(system, str) else system.name if isinstance(system, diffcassi.System) else None
    if system is None:
        system = op_system
    if system is None and arch == ARCH_V2:
        raise _Error(f"unrolled weights {path}: name the system of the acquisition (system='sp', … or a "
                     f"diffcassi.System): a {ARCH_V2} network is refused for any system but {meta.get('system')!r}")
    if system is not None:
        name = system if isinstance(system, str) else getattr(system, "name", None)
        if not isinstance(name, str):
            raise TypeError(f"load_unrolled: system: expected a preset name or a diffcassi.System, got {type(system).__name__}")
        if meta.get("system") != name:
            raise _Error(f"unrolled weights {path}: trained for system {meta.get('system')!r}, not {name!r} (refused)")
        # A preset name stands for that preset's prescription, as the Rust side checks it (a name that is no
        # preset can only be checked by name: pass the diffcassi.System itself).
        built = system
        if isinstance(system, str) and "system_sha256" in meta:
            try:
                built = diffcassi.System.preset(system)
            except diffcassi.DiffcassiValueError:
                built = None
        if not isinstance(built, (str, type(None))) and "system_sha256" in meta and meta["system_sha256"] != system_sha256(built):
            raise _Error(f"unrolled weights {path}: trained for another prescription of system {name!r} "
                         f"(system SHA-256 {meta['system_sha256']}, this one {system_sha256(built)}; refused)")
        if "system_sha256" not in meta and not isinstance(system, str):
            # No prescription recorded (the committed v1 weights): the name stands for the preset of that name, as
            # `reconstruct --weights` takes it — a System of that name with another prescription is warned about.
            try:
                preset = diffcassi.System.preset(name)
            except diffcassi.DiffcassiValueError:
                preset = None
            if preset is not None and system_sha256(preset) != system_sha256(system):
                import warnings
                warnings.warn(f"unrolled weights {path}: metadata system_sha256 not recorded: only the system's name "
                              f"{name!r} is checked, and the diffcassi.System given is not the preset {name!r} (prescription "
                              f"SHA-256 {system_sha256(system)[:12]}…, the preset's {system_sha256(preset)[:12]}…): the "
                              "network was presumably trained for the preset", UserWarning, stacklevel=2)
    if op_system is not None and given is not None and given != op_system.name:
        # The system named fits the weights but is not the operator's (checked after the weights' own check).
        raise _Error(f"unrolled weights {path}: system={given!r} is not the system the operator was built from "
                     f"({op_system.name!r}; refused): the network would run on another system's acquisition")
    if mask is not None and meta.get("mask_sha256") not in (None, mask_sha256(mask)):
        raise _Error(f"unrolled weights {path}: trained with another mask (SHA-256 {meta.get('mask_sha256')}, "
                     f"this one {mask_sha256(mask)})")
    net = make_unrolled(arch, phi, stages, width)
    want = {k: v for k, v in net.state_dict().items() if not k.startswith("phi.")}
    missing, extra = sorted(set(want) - set(tensors)), sorted(set(tensors) - set(want))
    if missing or extra:
        raise _Error(f"unrolled weights {path}: missing tensors {missing}, unexpected tensors {extra}")
    for k, v in tensors.items():
        if tuple(v.shape) != tuple(want[k].shape):
            raise _Error(f"unrolled weights {path}: tensor {k} has shape {tuple(v.shape)}, expected "
                         f"{tuple(want[k].shape)} (stages={stages}, bands={bands}, width={width})")
        if not torch.isfinite(v).all():
            raise _Error(f"unrolled weights {path}: tensor {k} has NaN or infinite values")
    dev = net.device
    net.load_state_dict({k: v.to(device=dev, dtype=torch.float32) for k, v in tensors.items()}, strict=False)
    return net.eval()
