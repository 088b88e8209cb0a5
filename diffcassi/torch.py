"""PyTorch helpers for diffcassi (pure Python; ``torch`` is an optional dependency).

- :class:`CassiOperator`: the exported forward operator Φ (a diffcassi :class:`~diffcassi.Operator`, a
  :class:`~diffcassi.Transport`, a SciPy CSR matrix or a ``save_npz`` file) as a ``torch.nn.Module`` on any
  device and floating dtype: ``forward`` (B, bands, H, W) → (B, h, w), ``adjoint`` back, differentiable (the
  backward of ``forward`` is the adjoint, the backward of ``adjoint`` is ``forward``). The exported matrix is
  the full Φ (spectral interpolation, mask, light transport *and* the per-plane Airy blur), so no separate
  convolution is needed. The index arrays of a matrix from SciPy or a file are validated before any tensor
  is built. Applied by deterministic gathers (:mod:`diffcassi._gather`: the same code on CPU and CUDA tensors,
  identical bits from run to run); ``device=`` or ``.to(device)`` ('cpu', 'cuda', 'cuda:N').
- :class:`MatrixFreeCassiOperator` (``CassiOperator.from_operator(op, matrix_free=True)``): the same module
  interface computed by the Rust operator itself on CPU tensors, in place (no matrix: the operator's own
  memory); on a CUDA device, the table the library builds once, kept on the device (docs/python.md, "PyTorch
  on CUDA").
- :class:`CassiDataset`: scenes rendered on the fly through a :class:`~diffcassi.Transport` with the
  paper's augmentation (random crop, flips, 90° rotations) seeded per (seed, index, epoch); returns
  (acquisition, mask, truth, initialisation I = A ∘ f); works with ``DataLoader(num_workers > 0)``.

>>> import diffcassi, diffcassi.torch as dt, torch
>>> T = diffcassi.Transport(diffcassi.System.preset("sp"), 8, 8, bands_nm=[500, 520, 540], planes=6, rays=4)
>>> phi = dt.CassiOperator.from_operator(T.operator)
>>> phi(torch.rand(2, 3, 8, 8)).shape == (2, *T.detector_shape)
True
"""
from __future__ import annotations

import os
import zipfile
from typing import Any, Dict, List, Optional, Sequence, Tuple, Union

import numpy as np

try:
    import torch
    from torch import nn
    from torch.autograd.function import once_differentiable
except ImportError as _e:  # pragma: no cover - depends on the environment
    raise ImportError("diffcassi.torch needs PyTorch: pip install torch") from _e

import diffcassi
from . import _files, _gather

__all__ = ["CassiOperator", "MatrixFreeCassiOperator", "CassiDataset"]

_Error = diffcassi.DiffcassiValueError

#: Dtypes computed in float32 and returned in their own dtype (half precision has no sparse kernels on
#: the CPU, and the Rust operator is float32).
_HALF = (torch.float16, torch.bfloat16)


def _shape(name: str, value: Any, n: int) -> Tuple[int, ...]:
    """``value`` as a tuple of ``n`` integers ≥ 1, else a DiffcassiValueError naming ``name`` and the value."""
    try:
        t = tuple(value)
    except TypeError:
        raise _Error(f"{name}: expected a tuple of {n} integers ≥ 1, got {type(value).__name__} {value!r}") from None
    if len(t) != n or not all(isinstance(v, (int, np.integer)) and not isinstance(v, bool) and v >= 1 for v in t):
        raise _Error(f"{name}: expected a tuple of {n} integers ≥ 1, got {value!r}")
    return tuple(int(v) for v in t)


def _int_entries(what: str, value: Any, n: int, lo: int) -> Tuple[int, ...]:
    """``n`` integer entries ≥ ``lo`` (an integer array or sequence: a float such as 22.5 was truncated by ``int``,
    silently), else a DiffcassiValueError naming ``what`` and the value."""
    try:
        a = np.asarray(value)
    except (TypeError, ValueError):
        a = np.asarray(None)
    if a.dtype.kind not in "iu" or a.size != n or (a.size and a.min() < lo):
        raise _Error(f"{what}: expected {n} integers ≥ {lo}, got {value!r}")
    return tuple(int(v) for v in a.ravel())


#: The largest absolute row or column sum of a CSR operator: float32's range over the input limit ``_MAX_VALUE``.
_MAX_GAIN = 1e9


def _check_csr(indptr: Any, indices: Any, data: Any, shape: Any, cube_shape: Any, image_shape: Any,
               source: str) -> Tuple[np.ndarray, np.ndarray, np.ndarray, Tuple[int, int], Tuple[int, int, int], Tuple[int, int]]:
    """Validate a CSR matrix before any tensor is built from it (a column index out of range would make
    ``torch.sparse.mm`` read out of bounds): dtypes, lengths, ``indptr`` starting at 0, non-decreasing and
    ending at nnz, every column index in [0, cols), every value finite, the shape matching the cube and
    image shapes. Errors name ``source``, the array, the first bad position and its value."""
    cube = _shape("cube_shape", cube_shape, 3)
    image = _shape("image_shape", image_shape, 2)
    sh = _int_entries(f"{source}: shape", shape, 2, 0)
    rows, cols = sh
    (H, W, B), (h, w) = cube, image
    if rows != h * w or cols != H * W * B:
        raise _Error(f"{source}: matrix shape {sh} does not match image_shape {image} (h·w = {h * w} rows) and "
                     f"cube_shape {cube} (H·W·bands = {H * W * B} columns)")
    arrays = {}
    for name, a, kind in (("indptr", indptr, "i"), ("indices", indices, "i"), ("data", data, "f")):
        a = np.asarray(a)
        if a.ndim != 1:
            raise _Error(f"{source}: {name}: expected a 1-D array, got shape {a.shape}")
        if kind == "i" and a.dtype.kind not in "iu":
            raise _Error(f"{source}: {name}: expected an integer dtype, got {a.dtype}")
        if kind == "f" and a.dtype.kind != "f":
            raise _Error(f"{source}: {name}: expected a floating-point dtype, got {a.dtype}")
        arrays[name] = a
    ip, ix, dv = arrays["indptr"], arrays["indices"], arrays["data"]
    nnz = ix.size
    if ip.size != rows + 1:
        raise _Error(f"{source}: indptr: expected {rows + 1} entries (rows + 1), got {ip.size}")
    if dv.size != nnz:
        raise _Error(f"{source}: data: {dv.size} values but {nnz} indices")
    if ip[0] != 0:
        raise _Error(f"{source}: indptr[0] = {ip[0]}, expected 0")
    if ip[-1] != nnz:
        raise _Error(f"{source}: indptr[-1] = {ip[-1]}, expected nnz = {nnz} (the length of indices)")
    steps = np.diff(ip.astype(np.int64))
    if steps.size and steps.min() < 0:
        k = int(np.argmax(steps < 0))
        raise _Error(f"{source}: indptr is not non-decreasing: indptr[{k}] = {ip[k]} > indptr[{k + 1}] = {ip[k + 1]}")
    if nnz:
        lo, hi = ix.min(), ix.max()
        if lo < 0 or hi >= cols:
            k = int(np.argmax((ix < 0) | (ix >= cols)))
            raise _Error(f"{source}: indices[{k}] = {ix[k]} is outside the {cols} columns [0, {cols})")
        if not np.isfinite(dv).all():
            k = int(np.argmax(~np.isfinite(dv)))
            raise _Error(f"{source}: data[{k}] = {dv[k]} is not finite")
        # Inputs are bounded by ±_MAX_VALUE (float32's range / 10⁹): a row (Φ) or column (Φᵀ) whose absolute sum
        # stays within 10⁹ cannot overflow float32 (a matrix of 1e300 gave inf for float32 inputs).
        a64 = np.abs(dv.astype(np.float64))
        rows_of = np.repeat(np.arange(rows), steps)
        for what, sums in (("row", np.bincount(rows_of, weights=a64, minlength=rows)), ("column", np.bincount(ix, weights=a64, minlength=cols))):
            if sums.size and sums.max() > _MAX_GAIN:
                k = int(np.argmax(sums))
                raise _Error(f"{source}: {what} {k}'s absolute sum {sums[k]:.6g} exceeds {_MAX_GAIN:.0e}: its products with inputs "
                             f"up to ±{diffcassi._MAX_VALUE:.3e} would overflow float32; rescale the matrix")
    # float32 values (the library's export) are kept as they are; any other floating dtype as float64.
    dv = dv if dv.dtype == np.float32 else dv.astype(np.float64)
    return ip.astype(np.int64), ix.astype(np.int64), dv, (rows, cols), cube, image


def _float_input(name: str, t: Any, where: str) -> torch.Tensor:
    """A floating-point tensor, else a TypeError naming the argument, its type and dtype."""
    if not isinstance(t, torch.Tensor):
        raise TypeError(f"{where}: {name}: expected a torch.Tensor, got {type(t).__name__}")
    if not t.dtype.is_floating_point:
        raise TypeError(f"{where}: {name}: expected a floating-point tensor (float16, bfloat16, float32, float64), got {t.dtype}")
    return t


def _check_values(name: str, t: torch.Tensor, where: str) -> None:
    """On the CPU: every value finite and within ±``_MAX_RADIANCE`` (f32's range / 10⁹, the limit of
    ``Operator.apply``: beyond it the operator's sums overflow to inf), else a DiffcassiValueError naming the
    argument, the first bad index and its value. On a CUDA device nothing is checked here: a check is a host
    synchronisation in every call of a training loop (the unrolled networks check their input once, at the
    entry; docs/python.md, "Bad input on CUDA tensors")."""
    if t.device.type != "cpu" or t.numel() == 0:
        return
    d = t.detach()
    bad = ~torch.isfinite(d) | (d.abs() > _MAX_RADIANCE)
    if bool(bad.any()):
        k = np.unravel_index(int(torch.argmax(bad.flatten().to(torch.uint8))), tuple(d.shape))
        raise _Error(f"{where}: {name}: value {float(d[k]):e} at index {list(map(int, k))} is not finite or beyond "
                     f"±{_MAX_RADIANCE:.3e} (f32's range / 10⁹) that the operator's sums allow; rescale it")


def _cast_back(t: torch.Tensor, dtype: torch.dtype, what: str, where: str) -> torch.Tensor:
    """An operator's float32/float64 result cast back to the input's ``dtype``. float16 holds at most 65504: on the
    CPU a result beyond it is refused, naming the peak (a cast would write inf); bfloat16 has float32's range. On a
    CUDA device nothing is checked (a host synchronisation per call, as :func:`_check_values`; torch's GradScaler
    is the mixed-precision guard there)."""
    out = t.to(dtype)
    # The cast's own rounding decides (65 504.004 rounds to 65 504; from 65 520 on it is inf): inf where t is finite.
    if dtype == torch.float16 and t.device.type == "cpu" and t.numel() and bool(torch.isinf(out.detach()).any()):
        peak, top = float(t.detach().abs().amax()), float(torch.finfo(torch.float16).max)
        raise _Error(f"{where}: the {what} reaches {peak:.6g}, beyond float16's range (largest {top:.6g}); "
                     "pass float32, float64 or bfloat16 tensors, or scale the input down")
    return out


def _widen(t: torch.Tensor, name: str, where: str) -> torch.Tensor:
    """``t`` as float32 for the operator. A float16 input's gradient is cast back to float16 by autograd: on the
    CPU a gradient that would become inf there is refused, naming the argument (``_cast_back`` guards the
    forward results the same way)."""
    w = t.to(torch.float32)
    if t.dtype == torch.float16 and w.requires_grad and w.device.type == "cpu":
        def check(g: torch.Tensor) -> torch.Tensor:
            if bool(torch.isinf(g.to(torch.float16)).any()) and bool(torch.isfinite(g).all()):
                raise _Error(f"{where} backward: the gradient of {name} reaches {float(g.abs().amax()):.6g}, beyond float16's range "
                             f"(largest {float(torch.finfo(torch.float16).max):.6g}); use float32, float64 or bfloat16 tensors, or scale the loss down")
            return g
        w.register_hook(check)
    return w


def _batched(name: str, t: torch.Tensor, trailing: Tuple[int, ...], where: str) -> Tuple[torch.Tensor, bool]:
    """(B, *trailing) or (*trailing) → (B, *trailing) and whether it was a single item."""
    single = t.dim() == len(trailing)
    if single:
        t = t.unsqueeze(0)
    if t.dim() != len(trailing) + 1 or tuple(t.shape[1:]) != trailing:
        lead = ", ".join(str(v) for v in trailing)
        raise _Error(f"{where}: {name}: expected shape (batch, {lead}) or ({lead}), got {tuple(t.shape)}")
    return t, single


def _device(value: Any, where: str) -> torch.device:
    """``value`` as the device an operator can run on: 'cpu', or 'cuda'/'cuda:N' when torch has that CUDA
    device; anything else (e.g. 'meta', which holds no data to apply) a DiffcassiValueError naming it and,
    for CUDA, what is missing."""
    try:
        d = torch.device(value)
    except (RuntimeError, TypeError, ValueError):
        raise _Error(f"{where}: device: expected 'cpu', 'cuda' or 'cuda:N', got {type(value).__name__} {value!r}") from None
    if d.type == "cpu":
        return torch.device("cpu")
    if d.type != "cuda":
        raise _Error(f"{where}: device {str(d)!r}: the operator runs on 'cpu' or 'cuda' (its table is applied by "
                     f"gathers on a device that holds data; {d.type!r} is not one)")
    if not torch.cuda.is_available():
        build = f"CUDA {torch.version.cuda}" if torch.version.cuda else "none: a CPU-only build"
        raise _Error(f"{where}: device {str(d)!r}: no CUDA device is available to torch (torch {torch.__version__}, "
                     f"CUDA build: {build}; torch.cuda.is_available() is False); use device='cpu'")
    n = torch.cuda.device_count()
    idx = torch.cuda.current_device() if d.index is None else d.index
    if not 0 <= idx < n:
        raise _Error(f"{where}: device {str(d)!r}: torch sees {n} CUDA device(s) (cuda:0 … cuda:{n - 1})")
    return torch.device("cuda", idx)


class _TargetChecked(nn.Module):
    """``.to(device)`` and ``.cuda()`` check the target device first (a DiffcassiValueError for 'meta', a CUDA
    device torch does not have, …), naming the module and the call."""

    def to(self, *args, **kwargs):
        try:
            device = torch._C._nn._parse_to(*args, **kwargs)[0]
        except Exception:  # torch's own error follows from nn.Module.to
            device = None
        if device is not None:
            _device(device, f"{type(self).__name__}.to")
        return super().to(*args, **kwargs)

    def to_empty(self, *, device: Any, recurse: bool = True):
        # Checked as .to(device): to_empty(device="meta") was accepted and the next forward failed inside torch
        # ("Tensor.item() cannot be called on meta tensors"; a held-out battery, round 16).
        if device is not None:
            _device(device, f"{type(self).__name__}.to_empty")
        return super().to_empty(device=device, recurse=recurse)

    def cuda(self, device: Any = None):
        _device(torch.device("cuda") if device is None else torch.device("cuda", device) if isinstance(device, int) else device,
                f"{type(self).__name__}.cuda")
        return super().cuda(device)


class _DeviceChecked(_TargetChecked):
    """``.to()``, ``.cuda()``, ``.cpu()``, ``.half()`` … of an operator module: the target device is checked
    first, then :meth:`_moving_to` runs (the matrix-free operator builds or drops its device table there), then
    the tensors move."""

    @property
    def device(self) -> torch.device:  # pragma: no cover - overridden
        return torch.device("cpu")

    def _apply(self, fn, recurse=True):
        where = f"{type(self).__name__}.to"
        try:
            probe = fn(torch.empty(0, device=self.device))
        except Exception as e:
            if any(k in str(e).lower() for k in ("cuda", "nvidia")):
                _device("cuda", where)  # the clear message when torch has no CUDA device (e.g. a parent module's .to)
            raise _Error(f"{where}: cannot move the operator there: {e}") from None
        dev = _device(probe.device, where)
        self._moving_to(dev)
        return super()._apply(fn, recurse)

    def _moving_to(self, device: torch.device) -> None:
        pass


def _check_not_meta(name: str, t: torch.Tensor, where: str, device: torch.device, lead: str) -> None:
    """A 'meta' tensor holds no values: refused naming the argument (``lead``: where it and the module are), without
    advising a move to 'meta' (the operators and the renderer refuse that device themselves; they said "move the
    operator with .to('meta')" and "module.to(device)": a held-out battery, round 16)."""
    if t.device.type == "meta":
        raise _Error(f"{where}: {lead}; a 'meta' tensor holds no values to compute with, and the operators and the "
                     f"renderer run on 'cpu' or 'cuda' only (never 'meta'): pass {name} with data on {device}")


def _check_same_device(name: str, t: torch.Tensor, device: torch.device, where: str) -> None:
    _check_not_meta(name, t, where, device, f"{name} is on meta but the operator on {device}")
    if t.device != device:
        raise _Error(f"{where}: {name} is on {t.device} but the operator on {device}; move one with .to(device)")


def _operator_bands_nm(op: Any) -> Optional[List[float]]:
    """The band wavelengths (nm) of a diffcassi Operator or Transport: the Transport's, or the ``bands_nm`` its
    operator was built with (its pickling recipe), the library's default 450:650:28 when none was given; None
    when they cannot be told."""
    if isinstance(op, diffcassi.Transport):
        return [float(b) for b in op.bands_nm]
    try:
        kwargs = op.__reduce__()[1][2]
        given = kwargs.get("bands_nm")
        bands = int(op.cube_shape[2])
    except Exception:  # another object, or a recipe of another shape
        return None
    if given is None:
        return [float(b) for b in np.linspace(450.0, 650.0, 28)] if bands == 28 else None
    out = [float(b) for b in given]
    return out if len(out) == bands else None


class CassiOperator(_DeviceChecked):
    """Φ as a table applied by deterministic gathers (:mod:`diffcassi._gather`), on the CPU or a CUDA device.

    Built from CSR arrays (validated first); Φ and Φᵀ are kept as row-bucketed tables (buffers: they follow
    ``.to(device)``, or ``device=`` at construction; a 'meta' device or a CUDA device torch lacks is a
    DiffcassiValueError). Each output element is one reduction in a fixed order — no scatter, no atomics — so
    two runs give identical bits on a GPU as on the CPU. Values are kept in the matrix's precision (float32
    from the library's export) and cast to the input's dtype at each call (``.to(dtype)`` does not round them).

    Shapes: ``cube_shape`` = (H, W, bands), ``image_shape`` = (h, w). ``forward(x)``: x (B, bands, H, W) or
    (bands, H, W) (the layout MST/DAUHST code uses) → (B, h, w) or (h, w). ``adjoint(y)``: the reverse.
    """

    def __init__(self, indptr: np.ndarray, indices: np.ndarray, data: np.ndarray, shape: Tuple[int, int],
                 cube_shape: Tuple[int, int, int], image_shape: Tuple[int, int], _source: str = "CassiOperator",
                 device: Any = "cpu"):
        super().__init__()
        dev = _device(device, "CassiOperator")
        ip, ix, dv, (rows, cols), self.cube_shape, self.image_shape = _check_csr(indptr, indices, data, shape, cube_shape,
                                                                                  image_shape, _source)
        H, W, B = self.cube_shape
        #: The bands' wavelengths (nm) where known (:meth:`from_operator`; None from CSR arrays or SciPy):
        #: :func:`diffcassi.torch.load_unrolled` checks a network's against them.
        self.bands_nm: Optional[List[float]] = None
        self.phi_table, self.adjoint_table = _gather.pair_from_csr(torch.from_numpy(ip), torch.from_numpy(ix),
                                                                   torch.from_numpy(dv), (rows, cols), dev,
                                                                   band_major=(H * W, B))

    @property
    def device(self) -> torch.device:
        """The device of the tables (inputs must be on it)."""
        return self.phi_table.where.device

    @property
    def nnz(self) -> int:
        """Non-zeros of Φ."""
        return self.phi_table.nnz

    # ------------------------------------------------------------------ constructors
    @classmethod
    def from_operator(cls, op: Union["diffcassi.Operator", "diffcassi.Transport"], memory_gb: float = 4.0,
                      matrix_free: bool = False, device: Any = "cpu") -> Union["CassiOperator", "MatrixFreeCassiOperator"]:
        """From a diffcassi Operator (``diffcassi.exact(...)``, ``mapping_operator``, ``shift_operator``,
        ``Transport.operator``) or a Transport: the library's CSR export (refused, with the size, above
        ``memory_gb`` GB) — or, with ``matrix_free=True``, a :class:`MatrixFreeCassiOperator` that calls the
        Rust operator itself on CPU tensors (no matrix) and, on a CUDA device, keeps the table the library
        builds once on the device (refused above ``memory_gb`` GB). ``device``: where the module lives
        ('cpu', 'cuda', 'cuda:N'; also ``.to(device)`` later)."""
        if isinstance(op, diffcassi.Transport):
            op = op.operator
        if not isinstance(op, diffcassi.Operator):
            raise TypeError(f"CassiOperator.from_operator: op: expected a diffcassi.Operator or diffcassi.Transport, got {type(op).__name__}")
        if not isinstance(matrix_free, bool):
            raise TypeError(f"CassiOperator.from_operator: matrix_free: expected True or False, got {matrix_free!r}")
        dev = _device(device, "CassiOperator.from_operator")
        if matrix_free:
            return MatrixFreeCassiOperator(op, memory_gb=memory_gb, device=dev)
        indptr, indices, data, shape = op.to_csr_arrays(memory_gb)
        t = cls(indptr, indices, data, shape, op.cube_shape, op.image_shape, _source=f"{op!r}", device=dev)
        t.bands_nm = _operator_bands_nm(op)
        t.system = op.system  # the System it was built from (None for one read from a file): load_unrolled checks it
        return t

    @classmethod
    def from_scipy(cls, matrix: Any, cube_shape: Tuple[int, int, int], image_shape: Tuple[int, int],
                   device: Any = "cpu") -> "CassiOperator":
        """From a SciPy sparse matrix (converted to CSR; indices, indptr, values and shape validated first). A
        matrix carries no cube or image shape, so only h·w (rows) and H·W·bands (columns) can be checked: prefer
        :meth:`from_npz` of a diffcassi ``save_npz`` file, which checks the shapes themselves."""
        if not hasattr(matrix, "tocsr"):
            raise TypeError(f"CassiOperator.from_scipy: matrix: expected a scipy.sparse matrix, got {type(matrix).__name__}")
        m = matrix.tocsr()
        return cls(m.indptr, m.indices, m.data, m.shape, cube_shape, image_shape, _source="from_scipy: matrix", device=device)

    @classmethod
    def from_npz(cls, path: Union[str, os.PathLike], cube_shape: Tuple[int, int, int], image_shape: Tuple[int, int],
                 device: Any = "cpu") -> "CassiOperator":
        """From a ``save_npz`` file (NumPy only; no SciPy needed). The file's arrays are validated (keys,
        dtypes, indptr, column indices, values, shape: integers, never truncated) before any tensor is built: a
        damaged or tampered file is a DiffcassiValueError naming the path and the bad entry (a missing or
        unreadable file: a DiffcassiFileError). A file written by diffcassi's ``save_npz`` records the operator's
        ``cube_shape`` and ``image_shape``: the shapes given must equal them (a transposed image shape has the
        same h·w and scrambled every output); a file without them (SciPy's own) is checked by the products only."""
        name = os.fspath(path)
        # A regular file only: np.load waited forever on a named pipe (a held-out battery, round 6).
        _files.check_input_file("CassiOperator.from_npz", name)
        try:
            z = np.load(name, allow_pickle=False)
        except FileNotFoundError:
            raise diffcassi.DiffcassiFileError(f"{name}: no such file") from None
        except (OSError, ValueError, EOFError) as e:
            raise diffcassi.DiffcassiFileError(f"{name}: not a readable .npz file ({e})") from None
        if not isinstance(z, np.lib.npyio.NpzFile):
            raise _Error(f"{name}: a single .npy array, not a save_npz (.npz) archive")
        with z:
            missing = [k for k in ("format", "indptr", "indices", "data", "shape") if k not in z.files]
            if missing:
                raise _Error(f"{name}: missing {', '.join(missing)} (a scipy.sparse.save_npz CSR file has format, indptr, indices, data, shape)")
            # diffcassi's save_npz also records the operator's cube_shape and image_shape (SciPy ignores them).
            recorded = [k for k in ("cube_shape", "image_shape") if k in z.files]
            try:
                fmt = z["format"].item()
                arrays = {k: z[k] for k in ("indptr", "indices", "data", "shape", *recorded)}
            except (OSError, ValueError, EOFError, KeyError, zipfile.BadZipFile) as e:
                raise diffcassi.DiffcassiFileError(f"{name}: damaged archive ({e})") from None
            except MemoryError as e:  # an array header claiming terabytes
                raise diffcassi.DiffcassiFileError(f"{name}: damaged or tampered archive: an array larger than memory ({e})") from None
        fmt = fmt.decode() if isinstance(fmt, bytes) else fmt
        if fmt != "csr":
            raise _Error(f"{name}: format {fmt!r}, expected 'csr'")
        # Only the products h·w and H·W·bands show in the matrix: a wrongly factored shape (image (119, 22) for a
        # (22, 119) operator) would scramble every output silently. Checked against the file's record when it has one.
        for key, given, n in (("cube_shape", cube_shape, 3), ("image_shape", image_shape, 2)):
            if key in arrays:
                own = _int_entries(f"{name}: {key} (in the file)", arrays[key], n, 1)
                g = _shape(key, given, n)
                if g != own:
                    raise _Error(f"{name}: {key} {g} given, but the file was written for {key} {own} (the operator's own)")
        return cls(arrays["indptr"], arrays["indices"], arrays["data"], arrays["shape"], cube_shape, image_shape,
                   _source=name, device=device)

    # ------------------------------------------------------------------ application
    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """Φ x: x (B, bands, H, W) or (bands, H, W) → (B, h, w) or (h, w). Any floating dtype: float32 and
        float64 are computed in their own precision, float16 and bfloat16 in float32 and returned in their
        own dtype."""
        H, W, B = self.cube_shape
        where = "CassiOperator.forward"
        x, single = _batched("x", _float_input("x", x, where), (B, H, W), where)
        _check_same_device("x", x, self.device, where)
        _check_values("x", x, where)
        dtype = x.dtype
        if dtype in _HALF:
            x = _widen(x, "x", where)
        y = _gather.gather_apply(x.reshape(x.shape[0], B * H * W), self.phi_table, self.adjoint_table)
        y = _cast_back(y.reshape(x.shape[0], *self.image_shape), dtype, "acquisition Φx", where)
        return y[0] if single else y

    def adjoint(self, y: torch.Tensor) -> torch.Tensor:
        """Φᵀ y: y (B, h, w) or (h, w) → (B, bands, H, W) or (bands, H, W) (dtypes as :meth:`forward`)."""
        H, W, B = self.cube_shape
        where = "CassiOperator.adjoint"
        y, single = _batched("y", _float_input("y", y, where), self.image_shape, where)
        _check_same_device("y", y, self.device, where)
        _check_values("y", y, where)
        dtype = y.dtype
        if dtype in _HALF:
            y = _widen(y, "y", where)
        x = _gather.gather_apply(y.reshape(y.shape[0], self.image_shape[0] * self.image_shape[1]), self.adjoint_table, self.phi_table)
        x = _cast_back(x.reshape(y.shape[0], B, H, W), dtype, "cube Φᵀy", where)
        return x[0] if single else x

    def extra_repr(self) -> str:
        return f"cube={self.cube_shape}, image={self.image_shape}, nnz={self.nnz}, device={self.device}"


# ---------------------------------------------------------------------- matrix-free
def _rust_batch(op: "diffcassi.Operator", t: torch.Tensor, adjoint: bool) -> torch.Tensor:
    """Φ of a cube batch t (N, bands, H, W) → (N, h, w), or Φᵀ of an image batch t (N, h, w) → (N, bands, H, W)
    (a view of the operator's (N, H, W, bands) result), by the Rust operator on CPU float32 tensors: the
    tensor's buffer is handed to Rust as a NumPy view (no copy when its memory already has the operator's
    layout: a contiguous image batch, a channels-last cube; one NumPy re-layout otherwise — NumPy's
    transpose copy is ~25× faster than torch's ``.contiguous()`` here) and the result is written into a
    tensor preallocated for it; the GIL is released during the Rust call."""
    H, W, B = op.cube_shape
    h, w = op.image_shape
    src = t.detach().resolve_neg().numpy()  # shares the tensor's memory, with its strides (a negative view is materialised)
    if adjoint:
        out = torch.empty((src.shape[0], H, W, B), dtype=torch.float32)
        op._adjoint_batch(np.ascontiguousarray(src), out.numpy())
        return out.permute(0, 3, 1, 2)
    out = torch.empty((src.shape[0], h, w), dtype=torch.float32)
    op._apply_batch(np.ascontiguousarray(src.transpose(0, 2, 3, 1)), out.numpy())
    return out


class _RustApply(torch.autograd.Function):
    """y = Φ x (``adjoint=False``: x (N, bands, H, W) → y (N, h, w)) or x = Φᵀ y (``adjoint=True``) by the
    Rust operator; the backward of one is the other (itself a ``_RustApply``, so higher derivatives work)."""

    @staticmethod
    def forward(ctx, t, op, adjoint):  # type: ignore[override]
        ctx.op, ctx.adjoint = op, adjoint
        return _rust_batch(op, t, adjoint)

    @staticmethod
    def backward(ctx, g):  # type: ignore[override]
        if not ctx.needs_input_grad[0]:
            return None, None, None
        # Named as what it is (the Rust adjoint/apply would name it as its own input, `y` or `x`).
        _check_values("the upstream gradient (grad_output)", g, "MatrixFreeCassiOperator." + ("adjoint" if ctx.adjoint else "forward") + " backward")
        return _RustApply.apply(g, ctx.op, not ctx.adjoint), None, None


class MatrixFreeCassiOperator(_DeviceChecked):
    """Φ computed by the Rust operator itself (``CassiOperator.from_operator(op, matrix_free=True)``): the same
    ``forward`` (B, bands, H, W) → (B, h, w) and ``adjoint`` (B, h, w) → (B, bands, H, W) as
    :class:`CassiOperator`, differentiable the same way, with no matrix on the CPU: the memory is the
    operator's own (its traced transport), and the time the Rust ``apply``/``adjoint`` (the GIL released).

    **On a CUDA device** (``.to("cuda")``, ``.cuda()`` or ``device="cuda"``) "matrix-free" means: the
    operator's table, built once by the library (its CSR export) and kept on the device as the row-bucketed
    gather tables of :class:`CassiOperator` (Φ and Φᵀ; ≈ 8 bytes per stored entry each, padding ≤ 1.25, so
    ≤ 20 bytes per non-zero in all), applied there by deterministic gathers — no host copy of the cube or
    the image. The table is refused, naming its size, above ``memory_gb`` (the budget of
    :meth:`CassiOperator.from_operator`, default 4 GB; the library's export checks its own assembly, 20 bytes
    per non-zero, against the same budget). Moving back to the CPU drops it (the Rust operator again).

    On the CPU: float32 tensors are passed to Rust in place (a contiguous (B, h, w) image as it is; a cube
    in the layout (B, bands, H, W) is re-laid to the operator's (B, H, W, bands) — no copy when the tensor
    is a channels-last view, ``x = t.permute(0, 3, 1, 2)`` of a contiguous (B, H, W, bands) ``t``, one copy
    otherwise), the result is written into a tensor allocated once per call; float64, float16 and bfloat16
    are cast to float32 and the result back to their dtype (float32 precision either way). On CUDA: dtypes
    as :class:`CassiOperator` (float64 computed in float64 with the float32 table).
    """

    def __init__(self, op: Union["diffcassi.Operator", "diffcassi.Transport"], memory_gb: float = 4.0,
                 device: Any = "cpu"):
        super().__init__()
        if isinstance(op, diffcassi.Transport):
            op = op.operator
        if not isinstance(op, diffcassi.Operator):
            raise TypeError(f"MatrixFreeCassiOperator: op: expected a diffcassi.Operator or diffcassi.Transport, got {type(op).__name__}")
        diffcassi._budget(memory_gb)  # a DiffcassiValueError naming memory_gb when it is not a number ≥ 0
        self.memory_gb = float(memory_gb)
        self.op = op
        #: The bands' wavelengths (nm), from the operator's recipe (None where it cannot be told).
        self.bands_nm: Optional[List[float]] = _operator_bands_nm(op)
        self.cube_shape = tuple(op.cube_shape)
        self.image_shape = tuple(op.image_shape)
        self.phi_table: Optional[_gather.GatherTable] = None
        self.adjoint_table: Optional[_gather.GatherTable] = None
        dev = _device(device, "MatrixFreeCassiOperator")
        if dev.type == "cuda":
            self._moving_to(dev)

    @property
    def device(self) -> torch.device:
        """The CPU (the Rust operator), or the CUDA device holding the table."""
        return torch.device("cpu") if self.phi_table is None else self.phi_table.where.device

    def _moving_to(self, device: torch.device) -> None:
        if device.type == "cpu":
            self.phi_table = self.adjoint_table = None
            return
        if self.phi_table is None:  # else already on a CUDA device: nn.Module._apply moves the buffers
            self._build_table(device)

    def _build_table(self, device: torch.device) -> None:
        """The library's table of the operator as gather tables on ``device`` (the CUDA path; the tests call it
        with the CPU to run that path's code there)."""
        H, W, B = self.cube_shape
        budget = f"memory_gb = {self.memory_gb:g} (CassiOperator.from_operator(op, matrix_free=True, memory_gb=...))"
        try:
            indptr, indices, data, shape = self.op.to_csr_arrays(self.memory_gb)
        except diffcassi.DiffcassiValueError as e:
            raise _Error(f"MatrixFreeCassiOperator on {device}: the operator's table does not fit {budget}: {e}") from None
        need = (_gather.GatherTable.estimate_bytes(indices.size, shape[0])
                + _gather.GatherTable.estimate_bytes(indices.size, shape[1]))
        if need > self.memory_gb * 1e9:
            raise _Error(f"MatrixFreeCassiOperator on {device}: the device table of {indices.size:,} non-zeros needs up to "
                         f"{need / 1e9:.3g} GB (Φ and Φᵀ, ≤ 20 bytes per non-zero), above {budget}")
        self.phi_table, self.adjoint_table = _gather.pair_from_csr(
            torch.from_numpy(indptr), torch.from_numpy(indices), torch.from_numpy(data), shape, device, band_major=(H * W, B))

    def _prepare(self, name: str, t: torch.Tensor, where: str) -> Tuple[torch.Tensor, torch.dtype]:
        dev = self.device
        # Not "move the operator with .to('meta')", which is refused (round 16).
        _check_not_meta(name, t, where, dev, f"{name} is on meta: the matrix-free operator is on the CPU" if dev.type == "cpu"
                        else f"{name} is on meta but the operator on {dev}")
        if t.device != dev:
            if dev.type == "cpu":
                raise _Error(f"{where}: {name} is on {t.device}: the matrix-free operator is on the CPU, where it runs "
                             f"the Rust operator on the CPU; move the operator with .to({str(t.device)!r}) (its table is "
                             "then kept on that device) or the tensor with .cpu()")
            raise _Error(f"{where}: {name} is on {t.device} but the operator on {dev}; move one with .to(device)")
        if self.phi_table is None:  # the Rust operator: float32
            return (t if t.dtype == torch.float32 else _widen(t, name, where)), t.dtype
        return (_widen(t, name, where) if t.dtype in _HALF else t), t.dtype

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """Φ x: x (B, bands, H, W) or (bands, H, W) → (B, h, w) or (h, w)."""
        H, W, B = self.cube_shape
        where = "MatrixFreeCassiOperator.forward"
        x, single = _batched("x", _float_input("x", x, where), (B, H, W), where)
        _check_values("x", x, where)  # before _prepare's cast to float32 (1e300 named as given, not as inf)
        x, dtype = self._prepare("x", x, where)
        if self.phi_table is None:
            y = _RustApply.apply(x, self.op, False)
        else:
            y = _gather.gather_apply(x.reshape(x.shape[0], B * H * W), self.phi_table, self.adjoint_table)
            y = y.reshape(x.shape[0], *self.image_shape)
        y = _cast_back(y, dtype, "acquisition Φx", where)
        return y[0] if single else y

    def adjoint(self, y: torch.Tensor) -> torch.Tensor:
        """Φᵀ y: y (B, h, w) or (h, w) → (B, bands, H, W) or (bands, H, W)."""
        H, W, B = self.cube_shape
        where = "MatrixFreeCassiOperator.adjoint"
        y, single = _batched("y", _float_input("y", y, where), self.image_shape, where)
        _check_values("y", y, where)  # before _prepare's cast to float32 (1e300 named as given, not as inf)
        y, dtype = self._prepare("y", y, where)
        if self.phi_table is None:
            x = _RustApply.apply(y, self.op, True)
        else:
            x = _gather.gather_apply(y.reshape(y.shape[0], self.image_shape[0] * self.image_shape[1]), self.adjoint_table, self.phi_table)
            x = x.reshape(y.shape[0], B, H, W)
        x = _cast_back(x, dtype, "cube Φᵀy", where)
        return x[0] if single else x

    def extra_repr(self) -> str:
        where = "Rust on the CPU" if self.phi_table is None else f"table on {self.device}"
        return f"cube={self.cube_shape}, image={self.image_shape}, matrix-free ({self.op!r}; {where})"


# ---------------------------------------------------------------------- dataset
def _resample(cube: np.ndarray, from_nm: Sequence[float], to_nm: Sequence[float]) -> np.ndarray:
    """Linear interpolation in λ, constant beyond the range (the library's SpectralCube::resample rule)."""
    f, t = np.asarray(from_nm, dtype=np.float64), np.asarray(to_nm, dtype=np.float64)
    if f.shape == t.shape and np.array_equal(f, t):
        return cube
    # As the renderer (Renderer::check_scene, spectral_extrapolation): a scene whose bands all lie outside the
    # transport's is refused (its truth was its end band repeated, a held-out battery); bands more than one band
    # step beyond it warn. A one-band scene too: its band outside the transport's range (a 5000 nm scene rendered
    # as if inside, a later battery) is refused; inside, it is a flat spectrum by construction (no warning).
    if len(f) > 0 and len(t) > 0 and (t[-1] < f[0] or t[0] > f[-1]):
        which = f"scene's band ({f[0]:g} nm) lies" if len(f) == 1 else f"scene's bands ({f[0]:g} – {f[-1]:g} nm) lie"
        raise _Error(f"CassiDataset: the {which} outside the transport's ({t[0]:g} – {t[-1]:g} nm): nothing of its "
                     "spectrum would be rendered")
    if len(f) > 1 and len(t) > 1:
        step = (t[-1] - t[0]) / (len(t) - 1)
        beyond = np.maximum(f[0] - t, t - f[-1]).max()
        if beyond > step:
            import warnings
            warnings.warn(f"CassiDataset: the transport's bands reach {beyond:.1f} nm beyond the scene's "
                          f"({f[0]:.1f}–{f[-1]:.1f} nm): its spectrum is held constant there (its end band)", stacklevel=3)
    k = np.clip(np.searchsorted(f, t, side="right") - 1, 0, max(len(f) - 2, 0))
    k1 = np.minimum(k + 1, len(f) - 1)
    den = np.where(f[k1] > f[k], f[k1] - f[k], 1.0)
    wt = np.clip((t - f[k]) / den, 0.0, 1.0).astype(np.float32)
    return ((1 - wt) * cube[..., k] + wt * cube[..., k1]).astype(np.float32)


def _int_arg(name: str, v: Any, lo: int) -> int:
    if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < lo:
        raise _Error(f"CassiDataset: {name}: expected an integer ≥ {lo}, got {type(v).__name__} {v!r}")
    return int(v)


_I64 = 2 ** 63 - 1


def _epoch_arg(v: Any) -> int:
    """An epoch: an integer in 0..=2⁶³−1 (it is held in a shared int64 tensor), else a DiffcassiValueError."""
    e = _int_arg("epoch", v, 0)
    if e > _I64:
        raise _Error(f"CassiDataset: epoch: expected an integer in 0..={_I64}, got {e}")
    return e


def _epoch_cell(epoch: int) -> torch.Tensor:
    """The epoch as a 0-dim int64 tensor in shared memory: a forked DataLoader worker maps the same memory and a
    spawned one receives it by handle (torch.multiprocessing), so ``set_epoch`` reaches workers that already hold
    the dataset (``persistent_workers=True``; a plain attribute stayed at the value they were started with)."""
    return torch.tensor(epoch, dtype=torch.int64).share_memory_()


def _index_arg(index: Any, length: int) -> int:
    """A dataset index: a Python int, a NumPy integer or a 0-dim integer tensor in 0..length (no negative
    indices: the DataLoader's samplers give 0..length-1; a bool is refused as in every integer argument here),
    else a TypeError (not an integer) or an IndexError (out of range) naming CassiDataset and the index."""
    ok = isinstance(index, (int, np.integer)) and not isinstance(index, bool)
    if isinstance(index, torch.Tensor):
        ok = index.dim() == 0 and not index.dtype.is_floating_point and not index.dtype.is_complex and index.dtype != torch.bool
    if not ok:
        raise TypeError(f"CassiDataset: index: expected an integer (a Python int, a NumPy integer or a 0-dim integer tensor), "
                        f"got {type(index).__name__} {index!r}")
    i = int(index)
    if not 0 <= i < length:
        raise IndexError(f"CassiDataset: index {i} is out of range for a dataset of length {length} (0 ≤ index < {length})")
    return i


class CassiDataset(torch.utils.data.Dataset):
    """Training samples rendered on the fly: item ``index`` of epoch ``epoch`` takes scene ``index % len(scenes)``,
    a random ``size`` × ``size`` crop, a random horizontal/vertical flip and a random number of 90° rotations —
    every choice from ``numpy.random.default_rng([seed, index, epoch])`` — and renders it through a
    :class:`~diffcassi.Transport` (built once per process, lazily, so the dataset pickles to DataLoader workers).

    ``scenes``: a folder (``.exr``, ``.npy`` with ``<stem>_wavelengths_nm.npy``, or per-band PNG folders: the
    CLI's loaders), a list of paths, or a list of ``(cube (H, W, B) float32, wavelengths_nm)``. Cubes are
    resampled to the transport's bands. ``transport``: keywords of :class:`~diffcassi.Transport` (bands_nm,
    planes, rays, seed, mask_seed, ...). Each item is a tuple of float32 tensors
    ``(acquisition (h, w), mask (H, W), truth (bands, H, W), initialisation (bands, H, W))``. Cubes must hold real
    values (a complex, bool, object or string dtype is refused naming the scene); an index is an integer in
    0..length (a float or a bool is a TypeError, out of range an IndexError, both naming the index). The epoch
    (:meth:`set_epoch`) is shared with DataLoader workers, persistent ones included.
    """

    def __init__(self, scenes: Union[str, os.PathLike, List[Any]], system: Union[str, "diffcassi.System"], size: int,
                 length: Optional[int] = None, seed: int = 0, epoch: int = 0, transport: Optional[Dict[str, Any]] = None):
        if not isinstance(system, (str, diffcassi.System)):
            raise TypeError(f"CassiDataset: system: expected a preset name or a diffcassi.System, got {type(system).__name__}")
        self.system_spec = system if isinstance(system, str) else system.to_toml()
        self.system_is_preset = isinstance(system, str)
        self.size = _int_arg("size", size, 1)
        self.seed = _int_arg("seed", seed, 0)
        self._epoch = _epoch_cell(_epoch_arg(epoch))
        if transport is not None and not isinstance(transport, dict):
            raise TypeError(f"CassiDataset: transport: expected a dict of Transport keywords, got {type(transport).__name__}")
        self.transport_kwargs = dict(transport or {})
        if isinstance(scenes, (str, os.PathLike)):
            folder = os.fspath(scenes)
            if not os.path.isdir(folder):
                raise diffcassi.DiffcassiFileError(f"{folder}: no such folder")
            entries = sorted(os.listdir(folder))
            paths = [os.path.join(folder, e) for e in entries
                     if (e.endswith((".exr", ".npy")) and not e.endswith("_wavelengths_nm.npy")) or os.path.isdir(os.path.join(folder, e))]
            if not paths:
                raise diffcassi.DiffcassiFileError(f"{folder}: no scenes (.exr, .npy, or folders of .png)")
            scenes = paths
        self.scenes: List[Tuple[np.ndarray, List[float]]] = []
        if not isinstance(scenes, (list, tuple)):
            raise TypeError(f"CassiDataset: scenes: expected a folder, a list of paths or a list of (cube, wavelengths_nm), got {type(scenes).__name__}")
        if not scenes:
            raise _Error("CassiDataset: scenes: the list is empty")
        for i, s in enumerate(scenes):
            if isinstance(s, (str, os.PathLike)):
                name = os.fspath(s)
                cube, wl = diffcassi.load_scene(name)
            else:
                name = f"scenes[{i}]"
                if not (isinstance(s, (tuple, list)) and len(s) == 2):
                    raise _Error(f"CassiDataset: {name}: expected a path or a (cube (H, W, B) float32, wavelengths_nm) pair, got {type(s).__name__}")
                cube, wl = s
            dtype = getattr(cube, "dtype", None)
            if not isinstance(dtype, np.dtype):  # a list, or a tensor (torch dtypes are not NumPy's)
                dtype = np.asarray(cube).dtype
            # Real values only: a complex cube was cast with only NumPy's ComplexWarning (its imaginary part
            # dropped), bools, objects and strings are no radiances (diffcassi.Operator.apply refuses them too).
            if dtype.kind not in "fiu":
                raise _Error(f"CassiDataset: {name}: cube dtype {dtype} is not real: expected float32 (or another real "
                             "floating-point or integer dtype, converted to float32)")
            # A copy of the caller's array (np.array copies even a float32 C-contiguous one): the radiance check
            # below is made once, here, and a later in-place change of the caller's array would bypass it and
            # change the truths of later items silently (a held-out battery, round 21). A scene read from a file
            # is this dataset's own already.
            cube = np.ascontiguousarray(cube, dtype=np.float32) if isinstance(s, (str, bytes, os.PathLike)) \
                else np.array(cube, dtype=np.float32, order="C", copy=True)
            if cube.ndim != 3 or cube.shape[0] < self.size or cube.shape[1] < self.size or cube.shape[2] < 1:
                raise _Error(f"CassiDataset: {name}: scene of shape {cube.shape}: expected (H, W, B) with H, W ≥ size = {self.size} and B ≥ 1")
            w = np.asarray(wl, dtype=np.float64).ravel()
            if w.size != cube.shape[2]:
                raise _Error(f"CassiDataset: {name}: {cube.shape[2]} bands (shape {cube.shape}) but {w.size} wavelengths_nm; "
                             "give one wavelength per band")
            if not np.isfinite(w).all() or (w.size > 1 and not (np.diff(w) > 0).all()):
                raise _Error(f"CassiDataset: {name}: wavelengths_nm {w.tolist()} must be finite and strictly increasing")
            # The renderer's radiance limits, here rather than in a DataLoader worker at the first item.
            bad = ~np.isfinite(cube) | (cube < 0) | (cube > _MAX_RADIANCE)
            if bad.any():
                k = np.unravel_index(int(np.argmax(bad)), cube.shape)
                raise _Error(f"CassiDataset: {name}: value {cube[k]} at index {list(map(int, k))} is not a radiance: "
                             f"values must be finite, ≥ 0 and ≤ {_MAX_RADIANCE:.3e} (as `diffcassi render` requires)")
            self.scenes.append((cube, w.tolist()))
        self.length = len(self.scenes) if length is None else _int_arg("length", length, 0)
        self._state: Optional[Dict[str, Any]] = None
        self._pool_pid: Optional[int] = None
        #: Threads of each DataLoader worker's pool.
        self.worker_threads = 1

    def __getstate__(self):
        d = dict(self.__dict__)
        d["_state"] = None  # the Transport is rebuilt in each worker
        return d

    def __setstate__(self, state: Dict[str, Any]) -> None:
        self.__dict__.update(state)
        # A DataLoader worker started by spawn/forkserver receives the parent's shared cell by handle (torch's
        # reductions): already shared, kept, so set_epoch reaches it. pickle.loads and copy.deepcopy give a
        # private copy of the value: moved to shared memory, so the copy's own workers follow its set_epoch.
        self._epoch.share_memory_()

    def __copy__(self) -> "CassiDataset":
        # copy.copy gets its own epoch too (as deepcopy and pickling): set_epoch on a copy never moves the original.
        new = type(self).__new__(type(self))
        new.__dict__.update(self.__getstate__())
        new._epoch = _epoch_cell(self.epoch)
        return new

    @property
    def epoch(self) -> int:
        """The epoch of the augmentations (:meth:`set_epoch`; assigning it is the same)."""
        return int(self._epoch)

    @epoch.setter
    def epoch(self, epoch: int) -> None:
        self.set_epoch(epoch)

    def set_epoch(self, epoch: int) -> None:
        """Choose the epoch (its augmentations differ from every other epoch's). The value is held in shared
        memory, so it reaches DataLoader workers that already hold the dataset (``persistent_workers=True``,
        fork or spawn): items are those of ``num_workers=0`` for the same epoch. Call it between epochs, before
        ``iter(loader)``: items the workers prefetched before the call keep the old epoch. A copy
        (``copy.copy``, ``copy.deepcopy``, ``pickle``) has its own epoch, starting at this one's value."""
        self._epoch.fill_(_epoch_arg(epoch))

    def _ready(self) -> Dict[str, Any]:
        if self._state is None:
            system = (diffcassi.System.preset(self.system_spec) if self.system_is_preset
                      else diffcassi.System.from_string(self.system_spec))
            t = diffcassi.Transport(system, self.size, self.size, **self.transport_kwargs)
            # The paper's I = A ∘ f, by the library's mapping operator on the same detector and mask.
            m = diffcassi.mapping_operator(system, self.size, self.size, **self.transport_kwargs)
            self._state = {"transport": t, "mask": t.mask, "mapping": m}
        return self._state

    @property
    def transport(self) -> "diffcassi.Transport":
        return self._ready()["transport"]

    def __len__(self) -> int:
        return self.length

    def __getitem__(self, index: int):
        index = _index_arg(index, self.length)
        if torch.utils.data.get_worker_info() is not None and self._pool_pid != os.getpid():
            # A forked DataLoader worker inherits no live rayon threads: give it its own pool (1 thread per
            # worker; the workers are the parallelism). Results do not depend on the thread count.
            diffcassi.set_num_threads(self.worker_threads)
            self._pool_pid = os.getpid()
        st = self._ready()
        t = st["transport"]
        rng = np.random.default_rng([self.seed, index, self.epoch])
        cube, wl = self.scenes[index % len(self.scenes)]
        H, W, _ = cube.shape
        r0 = int(rng.integers(0, H - self.size + 1))
        c0 = int(rng.integers(0, W - self.size + 1))
        crop = cube[r0:r0 + self.size, c0:c0 + self.size]
        if rng.random() < 0.5:
            crop = crop[:, ::-1]
        if rng.random() < 0.5:
            crop = crop[::-1]
        crop = np.rot90(crop, int(rng.integers(0, 4)), axes=(0, 1))
        truth = np.ascontiguousarray(_resample(np.ascontiguousarray(crop), wl, t.bands_nm), dtype=np.float32)
        acq = t.apply(truth).astype(np.float32)
        init = st["mapping"].initialisation(acq)
        # Each item gets its own copy of the mask (H·W floats, small beside the cube): a shared array let an in-place
        # edit of one item's mask (an augmentation) change every later item's, whose acquisition was still rendered
        # with the transport's mask — an inconsistent pair, silently (a held-out battery, round 21).
        return (torch.from_numpy(acq), torch.from_numpy(st["mask"].copy()),
                torch.from_numpy(np.ascontiguousarray(truth.transpose(2, 0, 1))),
                torch.from_numpy(np.ascontiguousarray(init.transpose(2, 0, 1))))


# ---------------------------------------------------------------------------------------------------------
# End-to-end co-design (issue 24): the acquisition differentiable with respect to the optics, the mask and
# the scene. Rust does the work (`diffcassi::render::gradient`, docs/codesign.md); this block only wraps it.
# ---------------------------------------------------------------------------------------------------------

__all__.append("CassiRenderer")


def _f64(t: torch.Tensor) -> np.ndarray:
    """A tensor of any floating dtype (bfloat16 included) as a C-contiguous float64 array."""
    # resolve_conj/resolve_neg: a conjugate or negative view (x.conj().imag, torch._neg_view) has no numpy() of its own
    return np.ascontiguousarray(t.detach().resolve_conj().resolve_neg().to(device="cpu", dtype=torch.float64).numpy())


#: The dtypes wider than a cube's (the advice of a range error; float64 has none).
_WIDER = {torch.float16: "float32 or float64", torch.bfloat16: "float32 or float64", torch.float32: "float64"}


def _forward_advice(dtype: torch.dtype) -> str:
    """What to do when the acquisition exceeds ``dtype``'s range: a wider cube dtype if there is one (a float32
    cube was told "pass a float32 or float64 cube": a held-out battery, round 16), or a smaller cube."""
    wider = _WIDER.get(dtype)
    return f"pass a {wider} cube, or scale the cube down" if wider else "scale the cube down"


def _backward_advice(dtype: torch.dtype, upstream: float, cube: Optional[float]) -> str:
    """The cause of a gradient beyond ``dtype``'s range, and its cure: the gradient is the upstream gradient
    (grad_output, peak ``upstream``) times the transport and the mask (the cube gradient: ``cube`` None) or the
    cube (peak ``cube``) — the larger factor is named (an upstream gradient of 1e308 was told "scale the cube
    down", a float32 cube "pass a float32 or float64 cube": a held-out battery, round 16)."""
    facts = f"the upstream gradient (grad_output) peaks at {upstream:.3g}"
    if cube is not None:
        facts += f", the cube at {cube:.3g}"
    fix = ("scale the loss (the upstream gradient) down" if cube is None or not upstream < cube
           else "scale the cube down")
    wider = _WIDER.get(dtype)
    if wider:
        fix += f", or pass a {wider} cube"
    return f"{facts}: {fix}"


def _narrow(a: np.ndarray, dtype: torch.dtype, what: str, advice: Optional[str] = None) -> torch.Tensor:
    """A float64 result as a tensor of ``dtype``, refused (never inf) when its values exceed the dtype's range
    (float64's own too: a gradient that overflowed to inf in the VJP). ``advice``: the cause and the cure (by
    default those of a forward result, :func:`_forward_advice`)."""
    t = torch.from_numpy(a)
    if a.size:
        peak, top = float(np.abs(a).max()), float(torch.finfo(dtype).max)
        if not peak <= top:
            raise _Error(f"CassiRenderer: the {what} reaches {peak:.6g}, beyond {dtype}'s range (largest {top:.6g}); "
                         f"{advice or _forward_advice(dtype)}")
    return t.to(dtype)


def _check_logits_room(peak: float, logits: Optional[Tuple[torch.dtype, float]], advice: str) -> None:
    """Inside the render's backward, before any gradient is returned: the mask gradient (peak ``peak``) must stay
    within the range of the logits' dtype through the cast to it and the sigmoid's backward (× at most 0.25 / T).
    ``logits``: (the logits' dtype, the temperature T) when the mask is the module's own (``forward``), None for
    an explicit mask (:meth:`CassiRenderer.render`). The logits' hook refused it only after θ's and the cube's
    gradients had been accumulated (a held-out battery, round 16)."""
    if logits is None:
        return
    dtype, temperature = logits
    top = float(torch.finfo(dtype).max)
    if not (peak <= top and peak * 0.25 / temperature <= top):
        raise _Error(f"CassiRenderer backward: the gradient of mask_logits would leave {dtype}'s range (largest "
                     f"{top:.6g}): the mask gradient peaks at {peak:.6g}, times up to 0.25 / temperature = "
                     f"{0.25 / temperature:.6g} through the mask's sigmoid; {advice}")


def _check_mask_logits_grad(grad: torch.Tensor) -> None:
    """A backward hook of ``CassiRenderer.mask_logits``: a non-finite gradient is refused (autograd raises it
    from ``backward()``), never accumulated into ``.grad``. The render's backward checks first
    (:func:`_check_logits_room`); this remains for a gradient that reaches the logits another way."""
    if grad.numel() and not bool(torch.isfinite(grad).all()):
        raise _Error("CassiRenderer backward: the gradient of mask_logits is not finite (it leaves "
                     f"{grad.dtype}'s range through the mask's sigmoid); scale the loss or the cube down")


class _RenderFn(torch.autograd.Function):
    """acquisition = render(cube, mask; θ) with fixed Monte-Carlo samples; backward is the Rust VJP. Computed
    in float64 whatever the inputs' floating dtypes; results are range-checked before they are cast back."""

    @staticmethod
    def forward(ctx, cube, mask, theta, module, logits=None):  # type: ignore[override]
        r = module._renderer(theta)
        out = r.render(_f64(cube), _f64(mask))
        # The cube and the mask are saved through torch (not as NumPy arrays: a float64 cube's was a view of its
        # memory, and a cube modified in place before backward gave 3× the θ and mask gradients silently; a
        # held-out battery, round 16): torch's version counter refuses that, as for its own operations.
        ctx.save_for_backward(cube, mask)
        ctx.r, ctx.logits = r, logits
        ctx.dtypes = (cube.dtype, mask.dtype, theta.dtype)
        return _narrow(out, cube.dtype, "acquisition")

    @staticmethod
    @once_differentiable
    def backward(ctx, g):  # type: ignore[override]
        # First derivatives only (the Rust VJP's results are NumPy arrays: a second derivative was silently
        # zero; now torch refuses it). Only the gradients autograd asks for are computed (a frozen mask, cube or θ does not pay: no reverse
        # sweep without θ, the closed mask pixels' rays not traced without the mask); the others are None.
        want_cube, want_mask, want_theta = ctx.needs_input_grad[:3]
        if not (want_cube or want_mask or want_theta):
            return None, None, None, None, None
        cube, mask = ctx.saved_tensors  # raises if either was modified in place since the forward
        s, m, g64 = _f64(cube), _f64(mask), _f64(g)
        gp, gm, gs = ctx.r.vjp(s, m, g64, params=want_theta, mask_grad=want_mask, scene_grad=want_cube)
        dc, dm, dt = ctx.dtypes
        up = float(np.abs(g64).max()) if g64.size else 0.0
        peak = float(np.abs(s).max()) if s.size else 0.0
        # Every check before any gradient is returned: a raising backward leaves every .grad as it was (the
        # mask-logits hook raised after θ's and the cube's gradients had been accumulated: round 16).
        out = (None if gs is None else _narrow(gs, dc, "cube gradient", _backward_advice(dc, up, None)),
               None if gm is None else _narrow(gm, dm, "mask gradient", _backward_advice(dc, up, peak)),
               None if gp is None else _narrow(gp, dt, "θ gradient", _backward_advice(dt, up, peak)))
        if gm is not None and gm.size:
            _check_logits_room(float(np.abs(gm).max()), ctx.logits, _backward_advice(torch.float64, up, peak))
        return (*out, None, None)


#: The radiance limit of ``diffcassi render`` (f32 range / 10⁹), checked on the device path too.
_MAX_RADIANCE = diffcassi._MAX_VALUE


class _TableRenderFn(torch.autograd.Function):
    """acquisition = T (mask ⊙ cube) with T the renderer's linear map at the current θ (all mask pixels
    open), applied by the gather tables on the cube's device. Backward: the cube and mask gradients on the
    device (Tᵀ g, then ⊙ mask or summed ⊙ cube over batch and bands); θ's by the Rust VJP on the host (the
    cube, mask and upstream gradient are copied there for it — only when θ requires grad)."""

    @staticmethod
    def forward(ctx, cube, mask, theta, module, renderer, tables, logits=None):  # type: ignore[override]
        a, at = tables
        n = cube.shape[0]
        work = torch.float32 if cube.dtype in _HALF else cube.dtype
        xm = cube.to(work) * mask.to(work)
        y = _gather.gather_apply(xm.reshape(n, -1), a, at).reshape(n, *module.image_shape)
        ctx.save_for_backward(cube, mask)
        ctx.r, ctx.tables, ctx.work, ctx.theta_meta = renderer, tables, work, (theta.dtype, theta.device)
        ctx.logits = logits
        return y.to(cube.dtype)

    @staticmethod
    @once_differentiable
    def backward(ctx, g):  # type: ignore[override]
        # First derivatives only, as the CPU path's (θ's comes from the Rust VJP).
        want_cube, want_mask, want_theta = ctx.needs_input_grad[:3]
        cube, mask = ctx.saved_tensors
        a, at = ctx.tables
        gc = gm = gt = None
        if want_cube or want_mask:
            u = at.matmul(g.to(ctx.work).reshape(g.shape[0], -1)).reshape(cube.shape)
            if want_cube:
                gc = (u * mask.to(ctx.work)).to(cube.dtype)
            if want_mask:
                gm = (u * cube.to(ctx.work)).sum((0, 1))
                # Checked before any gradient is returned, as the CPU path's (round 16); one host synchronisation,
                # only when the mask is learned.
                if gm.numel():
                    up, peak = float(g.detach().abs().amax()), float(cube.detach().abs().amax())
                    _check_logits_room(float(gm.abs().amax()), ctx.logits, _backward_advice(ctx.work, up, peak))
                gm = gm.to(mask.dtype)
        if want_theta:
            gp, _, _ = ctx.r.vjp(_f64(cube), _f64(mask), _f64(g), params=True, mask_grad=False, scene_grad=False)
            dtype, device = ctx.theta_meta
            gt = torch.from_numpy(gp).to(device=device, dtype=dtype)
        return gc, gm, gt, None, None, None, None


_U64 = 2 ** 64 - 1


def _count(where: str, name: str, v: Any, lo: int) -> int:
    """An integer in lo..=2⁶⁴−1 (not a bool; not a float: 1.7 is refused, not truncated), else a
    DiffcassiValueError naming the argument and the value."""
    if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or not lo <= v <= _U64:
        raise _Error(f"{where}: {name}: expected an integer in {lo}..={_U64}, got {type(v).__name__} {v!r}")
    return int(v)


def _temperature(name: str, v: Any) -> float:
    """The mask's temperature: a finite real number > 0 (0 divides the logits by zero: NaN gradients; a negative
    value inverts the mask), else a DiffcassiValueError naming ``name`` and the value. One check for the
    constructor and the ``CassiRenderer.temperature`` setter (training anneals by assigning it)."""
    if isinstance(v, (bool, np.bool_)) or not isinstance(v, (int, float, np.integer, np.floating)):
        raise diffcassi.DiffcassiValueError(f"{name} = {v!r}: must be a finite number > 0, got {type(v).__name__}")
    try:
        f = float(v)
    except OverflowError:  # an int beyond the float64 range
        f = float("inf")
    if not (np.isfinite(f) and f > 0):
        raise diffcassi.DiffcassiValueError(f"{name} = {v!r}: must be a finite number > 0")
    lo, hi = _TEMPERATURE_RANGE
    if not lo * (1 - 1e-6) <= f <= hi * (1 + 1e-6):  # a float32 1e-6 is 9.99999997e-07
        raise diffcassi.DiffcassiValueError(f"{name} = {v!r}: must be in [{lo:g}, {hi:g}] (the float32 logits T·logit(m) "
                                            "underflow or overflow beyond it: inf gradients or a NaN mask)")
    return f


#: The temperatures a CassiRenderer takes: float32 logits T·logit(m) (|logit| ≤ 2.95 at construction) and the
#: gradients' 1/T stay far inside float32's range.
_TEMPERATURE_RANGE = (1e-6, 1e6)


def _free_names(free: Any) -> List[str]:
    """``free``: a parameter name or a list/tuple of non-empty names."""
    if isinstance(free, str):
        free = [free]
    if not isinstance(free, (list, tuple)) or not all(isinstance(f, str) for f in free):
        raise TypeError(f"CassiRenderer: free: expected a parameter name or a list of names (e.g. ['prism_tilt_x']), "
                        f"got {type(free).__name__} {free!r}")
    empty = [i for i, f in enumerate(free) if not f.strip()]
    if empty:
        raise _Error(f"CassiRenderer: free: name {empty[0]} is empty (got {list(free)!r})")
    return list(free)


def _mask_array(mask: Any, H: int, W: int, mask_seed: int) -> np.ndarray:
    """The initial mask: ``None`` (random binary from ``mask_seed``) or an (H, W) array/tensor of real values in [0, 1]."""
    if mask is None:
        return (np.random.default_rng(mask_seed).random((H, W)) < 0.5).astype(np.float64)
    if isinstance(mask, torch.Tensor):
        mask = mask.detach().resolve_conj().resolve_neg()
        mask = mask.cpu().numpy() if mask.dtype != torch.bfloat16 else mask.float().cpu().numpy()
    if not isinstance(mask, (np.ndarray, list, tuple)):
        raise TypeError(f"CassiRenderer: mask: expected None or an ({H}, {W}) array of values in [0, 1], got {type(mask).__name__} {mask!r}")
    a = np.asarray(mask)
    if not (a.dtype == np.bool_ or np.issubdtype(a.dtype, np.integer) or np.issubdtype(a.dtype, np.floating)):
        raise TypeError(f"CassiRenderer: mask: expected real values in [0, 1], got dtype {a.dtype}")
    return a.astype(np.float64)


class CassiRenderer(_TargetChecked):
    """The CASSI acquisition as a differentiable ``nn.Module`` for co-design.

    ``CassiRenderer(system, H, W, free=["prism_tilt_x"], mask=None, rays=4, planes=28, seed=0)``:
    ``forward(cube)`` maps scenes (N, B, H, W) (B = 28 bands 450–650 nm unless ``bands_nm`` says otherwise)
    to acquisitions (N, h, w) in the cube's dtype (float32, or float64 for ``gradcheck``). Autograd gives
    the gradients with respect to the cube, the mask and the free optical parameters.

    Parameters (``.parameters()`` yields both):

    - ``theta``: the free parameters' values in the spec's units (degrees, mm, …; names in ``.names``),
      float64. A value out of its valid range (a glass outside the catalogue's (n_d, V_d) span, a tilt
      with which no ray reaches the detector, a system that no longer builds) raises
      ``diffcassi.DiffcassiValueError`` naming it — never NaN.
    - ``mask_logits``: the learnable mask, continuous in [0, 1] as ``sigmoid(mask_logits / temperature)``.
      Lower ``temperature`` during training (e.g. geometrically from 1 to 0.05) to push it towards binary;
      ``straight_through=True`` renders the binarised mask (> 0.5) while the gradient is the sigmoid's
      (straight-through estimator). ``binary_mask()`` is the mask to build.

    The Monte-Carlo samples are fixed (``seed``): the gradient is that of the sampled acquisition, exact
    where no ray changes status; the detector and the entrance-pupil aim are fixed at construction.

    Only the gradients autograd needs are computed (``ctx.needs_input_grad``): freeze the mask
    (``r.mask_logits.requires_grad_(False)``) and the rays of closed mask pixels (value exactly 0, e.g.
    with ``straight_through=True``) are not traced; freeze ``theta`` and no ray is swept backwards; a cube
    that does not require grad gets no scene gradient. The gradients computed are bit-identical to those of
    the backward that computes all three.

    An object at infinity (``system.object_at_infinity``): give the scene's full angular extent across its
    width, ``scene_fov_deg`` (degrees, in (0, 180)), as :func:`diffcassi.render` takes it: pixels are uniform in
    field angle and each sample is the parallel ray of its field angles (direction ∝ (tan θx, tan θy, 1)) through
    the sample's entrance-pupil point, the forward renderer's rays. Required at infinity, refused for a finite
    object (a ``DiffcassiValueError`` naming the value, as for 0, 180 or NaN). As for a finite object, the rays are
    fixed in object space while ``theta`` moves (the pupil aim is that of construction).

    A system with a coded-mask surface (dual-disperser CASSI, presets ``ddsp``/``mddsp``) reads the mask where
    each ray crosses that surface: every scene pixel's rays are traced, and ∂/∂theta includes the crossing
    point's term for ``bilinear`` mask sampling (docs/codesign.md, "Dual-disperser CASSI").
    """

    def __init__(self, system: "diffcassi.System", H: int, W: int, free: Sequence[str] = ("prism_tilt_x",),
                 mask: Optional[np.ndarray] = None, rays: int = 4, planes: int = 28, seed: int = 0,
                 bands_nm: Optional[Sequence[float]] = None, airy: bool = True, temperature: float = 1.0,
                 straight_through: bool = False, mask_seed: int = 0, memory_gb: float = 4.0,
                 scene_fov_deg: Optional[float] = None):
        super().__init__()
        w = "CassiRenderer"
        diffcassi._budget(memory_gb)  # a DiffcassiValueError naming memory_gb when it is not a number ≥ 0
        #: The budget (GB) of the device table of a CUDA cube's render (see :meth:`forward`).
        self.memory_gb = float(memory_gb)
        #: Render CPU cubes through the table too (the CUDA path's code on the CPU; for tests and checks).
        self.table_on_cpu = False
        self._tables: Tuple[Any, ...] = ()
        if not isinstance(system, diffcassi.System):
            raise TypeError(f"{w}: system: expected a diffcassi.System, got {type(system).__name__}")
        H, W = _count(w, "H", H, 1), _count(w, "W", W, 1)
        rays, planes = _count(w, "rays", rays, 1), _count(w, "planes", planes, 1)
        seed, mask_seed = _count(w, "seed", seed, 0), _count(w, "mask_seed", mask_seed, 0)
        for name, v in (("airy", airy), ("straight_through", straight_through)):
            if not isinstance(v, (bool, np.bool_)):
                raise TypeError(f"{w}: {name}: expected True or False, got {type(v).__name__} {v!r}")
        temperature = _temperature("temperature", temperature)  # before the native renderer is built
        names = _free_names(free)
        # The native renderer first: it checks H × W × planes × rays against the budgets before anything is
        # allocated; the default random mask (H × W float64) was drawn before it (a held-out battery, round 8:
        # 87 TiB asked of NumPy for H = 10¹²).
        self._base = diffcassi._native.DiffRenderer(system, H, W, names, rays=rays, planes=planes, seed=seed,
                                                    bands_nm=bands_nm, airy=bool(airy), scene_fov_deg=scene_fov_deg)
        mask = _mask_array(mask, H, W, mask_seed)
        self.names: List[str] = list(self._base.names())
        self._system_sha256: str = system.prescription_sha256()
        self._system_name: str = system.name
        self.bands_nm: List[float] = list(self._base.bands_nm())
        self.image_shape: Tuple[int, int] = tuple(self._base.image_shape())
        self.H, self.W = H, W
        self.temperature = temperature
        self.straight_through = bool(straight_through)
        if mask.shape != (self.H, self.W):
            raise diffcassi.DiffcassiValueError(f"mask: expected shape ({self.H}, {self.W}), got {mask.shape}")
        if not np.all(np.isfinite(mask)) or mask.min() < 0 or mask.max() > 1:
            raise diffcassi.DiffcassiValueError("mask: values must be finite and in [0, 1]")
        # Logits of the mask clipped to [0.05, 0.95] (a binary mask starts at sigmoid(±2.94)).
        m = np.clip(mask, 0.05, 0.95)
        self.mask_logits = nn.Parameter(torch.from_numpy(self.temperature * np.log(m / (1 - m))).to(torch.float32))
        self.theta = nn.Parameter(torch.tensor(self._base.values(), dtype=torch.float64))
        self._cache: Tuple[Tuple[float, ...], Any] = (tuple(self._base.values()), self._base)

    def _renderer(self, theta: torch.Tensor):
        values = tuple(float(v) for v in theta.detach().cpu().reshape(-1))
        if values != self._cache[0]:
            bad = [f"{n} = {v}" for n, v in zip(self.names, values) if not np.isfinite(v)]
            if bad:
                raise diffcassi.DiffcassiValueError(f"free parameter {', '.join(bad)} is not finite")
            try:
                r = self._base.with_values(list(values))
            except diffcassi.DiffcassiValueError as e:
                if any(n in str(e) for n in self.names):
                    raise
                given = ", ".join(f"{n} = {v}" for n, v in zip(self.names, values))
                raise diffcassi.DiffcassiValueError(f"free parameter {given}: {e}") from None
            self._cache = (values, r)
        return self._cache[1]

    @property
    def temperature(self) -> float:
        """The mask's temperature T (``mask = sigmoid(mask_logits / T)``): set it to anneal the mask. Checked on
        every assignment as in the constructor — a real number in [1e-6, 1e6] (a Python or NumPy int or float, not a
        bool or a tensor); 0 made the gradients NaN, a negative value inverted the mask silently, 1e-40 gave inf
        gradients and 1e300 a NaN mask. Saved in ``state_dict`` (its ``_extra_state``) with the logits."""
        return self._temperature

    @temperature.setter
    def temperature(self, value: Any) -> None:
        self._temperature = _temperature("CassiRenderer.temperature", value)

    # The temperature travels with the state: an annealed renderer restored from a checkpoint renders as it did
    # (it was a plain attribute, and a restored renderer kept its constructor's: the acquisition moved by 4 %).
    # θ's meaning travels with it too: the free parameters' names and the system's prescription (SHA-256) — a
    # state of another free list or system loaded silently (θ of prism_tilt_x became prism_tilt_y: round 9).
    def get_extra_state(self) -> Dict[str, Any]:
        state = {"temperature": self._temperature, "free": list(self.names)}
        if getattr(self, "_system_sha256", None) is not None:
            state["system_sha256"] = self._system_sha256
        return state

    def set_extra_state(self, state: Any) -> None:
        self._check_extra_state(state)
        self.temperature = state["temperature"]

    def _check_extra_state(self, state: Any) -> None:
        if not (isinstance(state, dict) and "temperature" in state):
            raise diffcassi.DiffcassiValueError(f"CassiRenderer.load_state_dict: _extra_state: expected {{'temperature': T}}, got {state!r}")
        # A state from before the names and the system were saved has neither: loaded as before.
        if "free" in state and list(state["free"]) != list(self.names):
            raise diffcassi.DiffcassiValueError(f"CassiRenderer.load_state_dict: the state's θ is of the free parameters "
                                                f"{list(state['free'])}, this renderer's of {list(self.names)}: build the "
                                                "renderer with the state's free list")
        if "system_sha256" in state and state["system_sha256"] != getattr(self, "_system_sha256", state["system_sha256"]):
            raise diffcassi.DiffcassiValueError(f"CassiRenderer.load_state_dict: the state is of a system of prescription "
                                                f"SHA-256 {state['system_sha256']}, this renderer's system "
                                                f"{self._system_name!r} is another ({self._system_sha256}): build the "
                                                "renderer with the state's system")

    def _load_from_state_dict(self, state_dict, prefix, local_metadata, strict, missing_keys, unexpected_keys, error_msgs):
        # A checkpoint from before the temperature was saved keeps the module's own.
        state_dict.setdefault(prefix + "_extra_state", self.get_extra_state())
        self._check_extra_state(state_dict[prefix + "_extra_state"])  # before θ is copied: another θ is never loaded
        super()._load_from_state_dict(state_dict, prefix, local_metadata, strict, missing_keys, unexpected_keys, error_msgs)

    def _apply(self, fn, recurse=True):
        # θ holds optical parameters in the spec's units (mm, degrees): float64 always. `.half()`, `.bfloat16()`,
        # `.float()` move it with the module but never round it (float16 made a 33.34 mm radius 33.34375: the
        # acquisition moved by 2 %); the mask logits follow the module's dtype.
        theta = self.theta.detach().clone()
        grad = None if self.theta.grad is None else self.theta.grad.detach().clone()
        out = super()._apply(fn, recurse)
        if self.theta.dtype != torch.float64:
            self.theta.data = theta.to(device=self.theta.device, dtype=torch.float64)
            if grad is not None:
                self.theta.grad = grad.to(device=self.theta.device, dtype=torch.float64)
        return out

    def mask(self) -> torch.Tensor:
        """The continuous mask sigmoid(logits / temperature) in [0, 1], (H, W). Its logits' gradient is checked
        finite when it arrives (:func:`_check_mask_logits_grad`)."""
        p = self.mask_logits
        # Once per parameter object (a deepcopy or an unpickled module has a new one): the rendered mask's
        # gradient is range-checked in float64, but the sigmoid's own backward runs in the logits' float32 and
        # overflowed to inf for float64 cubes of 1e20 (an Adam step then made the logits non-finite; round 9).
        # Only on logits that require grad: a frozen mask (requires_grad_(False), the module's, under no_grad
        # or after a deepcopy/pickle) has no gradient to check, and torch refuses a hook there (every forward
        # raised: a held-out battery, round 16); the hook is registered when the logits are unfrozen.
        if p.requires_grad and getattr(self, "_checked_logits_id", None) != id(p):
            p.register_hook(_check_mask_logits_grad)
            self._checked_logits_id = id(p)
        return torch.sigmoid(p / self.temperature)

    def binary_mask(self) -> np.ndarray:
        """The mask to build: the continuous mask thresholded at 0.5."""
        return (self.mask().detach().cpu().numpy() > 0.5).astype(np.float32)

    def render(self, cube: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        """The acquisition of ``cube`` through an explicit ``mask`` (H, W) in [0, 1] (differentiable in both).
        ``cube``: a floating-point tensor (float16, bfloat16, float32, float64; another dtype is a TypeError
        naming it), computed in float64; the acquisition is returned in the cube's dtype, refused if it exceeds
        that dtype's range. Radiances must be ≤ 3.4·10²⁹ in magnitude, as ``diffcassi render`` requires. An empty
        batch (N = 0) is refused, on every device."""
        return self._render(cube, mask, None)

    def _render(self, cube: torch.Tensor, mask: torch.Tensor, logits: Optional[Tuple[torch.dtype, float]]) -> torch.Tensor:
        """:meth:`render`; ``logits``: (dtype, temperature) of the module's own mask (:meth:`forward`), whose
        gradient's range the backward checks before returning any gradient (:func:`_check_logits_room`)."""
        where = "CassiRenderer.render"
        _float_input("cube", cube, where)
        _float_input("mask", mask, where)
        for name, t in (("cube", cube), ("mask", mask)):  # not "module.to(device)": 'meta' is refused (round 16)
            _check_not_meta(name, t, where, self.theta.device, f"{name} is on meta, the module's θ on {self.theta.device}")
        if cube.dim() != 4 or tuple(cube.shape[1:]) != (len(self.bands_nm), self.H, self.W):
            raise diffcassi.DiffcassiValueError(f"cube: expected shape (N, {len(self.bands_nm)}, {self.H}, {self.W}), got {tuple(cube.shape)}")
        if tuple(mask.shape) != (self.H, self.W):
            raise diffcassi.DiffcassiValueError(f"mask: expected shape ({self.H}, {self.W}), got {tuple(mask.shape)}")
        if cube.shape[0] == 0:
            # On the CPU too (the native renderer said "scene has 0 values; expected (N, B, H, W) = (0, 2, 4, 4)",
            # which is what was given: a held-out battery, round 16).
            raise diffcassi.DiffcassiValueError(f"{where}: cube: the batch is empty (N = 0, shape {tuple(cube.shape)}): "
                                                "give at least one scene")
        m = mask.detach()
        if not bool(torch.isfinite(m).all()) or float(m.min()) < 0 or float(m.max()) > 1:
            raise diffcassi.DiffcassiValueError(f"{where}: mask: values must be finite and in [0, 1], got min {float(m.min())}, "
                                                f"max {float(m.max())}")
        if cube.device != mask.device or cube.device != self.theta.device:  # ('meta' refused above)
            raise diffcassi.DiffcassiValueError(f"{where}: cube is on {cube.device}, mask on {mask.device}, the module's θ on "
                                                f"{self.theta.device}: move them to one device (module.to(device))")
        if cube.device.type == "cuda" or self.table_on_cpu:
            return self._render_table(cube, mask, logits)
        # The batch against the budgets before its float64 copy and the render's buffers are allocated (the
        # constructor counts one scene; round 19: a batch of 4 peaked at 4× its estimate).
        self._base._check_batch(int(cube.shape[0]))
        return _RenderFn.apply(cube, mask, self.theta, self, logits)

    def table(self, device: Any = "cpu") -> Tuple["_gather.GatherTable", "_gather.GatherTable"]:
        """The gather tables (T, Tᵀ) of the linear map mask ⊙ cube → acquisition at the current θ on
        ``device``: built by the library (``DiffRenderer._csr``: the exact operator of a renderer with this
        renderer's system, settings, seed and detector, every mask pixel open) and cached until θ or the
        device changes. Refused above ``memory_gb``, and when θ moves the entrance pupil (the differentiable
        renderer keeps its construction-time aim; no table matches its render then)."""
        dev = _device(device, "CassiRenderer.table")
        r = self._renderer(self.theta)
        key = (self._cache[0], dev)
        if self._tables and self._tables[0] == key:
            return self._tables[1]
        self._tables = ()  # the old table is freed before the new one is built
        try:
            ip, ix, dv, shape = r._csr(diffcassi._budget(self.memory_gb))
        except diffcassi.DiffcassiValueError as e:
            raise diffcassi.DiffcassiValueError(f"CassiRenderer on {dev} (table budget memory_gb = {self.memory_gb:g}): {e}") from None
        if ix.size == 0:
            given = ", ".join(f"{n} = {v}" for n, v in zip(self.names, self._cache[0]))
            raise diffcassi.DiffcassiValueError(f"no ray reaches the detector at these parameter values ({given})")
        tables = _gather.pair_from_csr(torch.from_numpy(ip), torch.from_numpy(ix), torch.from_numpy(dv), shape, dev,
                                       band_major=(self.H * self.W, len(self.bands_nm)))
        self._tables = (key, tables)
        return tables

    def _render_table(self, cube: torch.Tensor, mask: torch.Tensor, logits: Optional[Tuple[torch.dtype, float]]) -> torch.Tensor:
        """The device path of :meth:`render` (see :meth:`forward`)."""
        c = cube.detach()
        if bool((~torch.isfinite(c)).any() | (c.abs().amax() > _MAX_RADIANCE)):
            raise diffcassi.DiffcassiValueError(f"CassiRenderer.render: cube: values must be finite and ≤ {_MAX_RADIANCE:.3e} in "
                                                "magnitude (f32 range / 10⁹, as `diffcassi render` requires)")
        tables = self.table(cube.device)
        y = _TableRenderFn.apply(cube, mask, self.theta, self, self._cache[1], tables, logits)
        if cube.dtype in _HALF and not bool(torch.isfinite(y.detach()).all()):
            raise _Error(f"CassiRenderer: the acquisition exceeds {cube.dtype}'s range (largest "
                         f"{float(torch.finfo(cube.dtype).max):.6g}); {_forward_advice(cube.dtype)}")
        return y


    def forward(self, cube: torch.Tensor) -> torch.Tensor:
        """The acquisition (N, h, w) of ``cube`` (N, bands, H, W) through the module's mask.

        **Where it runs.** A CPU cube: the Rust renderer in float64 (as :meth:`render`). A CUDA cube: the
        transport depends only on θ, not on the cube, so the host traces it once per θ (:meth:`table`, cached)
        and the acquisition is the table applied to mask ⊙ cube on the device by deterministic gathers, in the
        cube's precision (float16/bfloat16 in float32) — the cube and the acquisition never leave the device;
        the same as the CPU render to float32 rounding (the table is stored in float32). Its backward: the
        cube and mask gradients on the device (Tᵀ g); θ's gradient by the Rust VJP on the CPU, which copies
        the cube, the mask and the upstream gradient to the host (only when θ requires grad: freeze θ with
        ``r.theta.requires_grad_(False)`` to keep a training step on the device)."""
        _float_input("cube", cube, "CassiRenderer.forward")
        m = self.mask()
        if self.straight_through:
            m = m + ((m > 0.5).to(m.dtype) - m).detach()
        return self._render(cube, m.to(cube.dtype), (self.mask_logits.dtype, self.temperature))

    def mapping_jacobian(self, wavelengths_nm: Optional[Sequence[float]] = None):
        """The chief-ray mapping cube at the current parameters and its Jacobian: (positions (H, W, L, 2) mm,
        jacobian (H, W, L, 2, P), valid (H, W, L)); L defaults to the scene bands."""
        wl = self.bands_nm if wavelengths_nm is None else [float(w) for w in wavelengths_nm]
        return self._renderer(self.theta).mapping_jacobian(wl)

    def extra_repr(self) -> str:
        return f"free={self.names}, scene {self.H}×{self.W}, detector {self.image_shape[0]}×{self.image_shape[1]}"


# ---------------------------------------------------------------------------------------------------------
# The unrolled network (issue 22 item 5): GAP stages with learned denoisers around the exact operator. Defined in
# diffcassi/unrolled.py (graph, weights files); re-exported here beside the operator it wraps.
# ---------------------------------------------------------------------------------------------------------
from .unrolled import (StageDenoiser, UnrolledDAUHST, UnrolledGAP, load_unrolled, save_unrolled,  # noqa: E402
                       SpectralSpatialUNet, DegradationEstimator)

__all__ += ["UnrolledGAP", "StageDenoiser", "UnrolledDAUHST", "SpectralSpatialUNet", "DegradationEstimator",
            "load_unrolled", "save_unrolled"]
