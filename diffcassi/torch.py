"""PyTorch helpers for diffcassi (pure Python; ``torch`` is an optional dependency).

- :class:`CassiOperator`: the exported forward operator Φ (a diffcassi :class:`~diffcassi.Operator`, a
  :class:`~diffcassi.Transport`, a SciPy CSR matrix or a ``save_npz`` file) as a ``torch.nn.Module`` on any
  device and dtype: ``forward`` (B, bands, H, W) → (B, h, w), ``adjoint`` back, differentiable (the backward
  of ``forward`` is the adjoint, the backward of ``adjoint`` is ``forward``). The exported matrix is the full
  Φ (spectral interpolation, mask, light transport *and* the per-plane Airy blur), so no separate
  convolution is needed.
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
import warnings
from typing import Any, Dict, List, Optional, Sequence, Tuple, Union

import numpy as np

try:
    import torch
    from torch import nn
except ImportError as _e:  # pragma: no cover - depends on the environment
    raise ImportError("diffcassi.torch needs PyTorch: pip install torch") from _e

import diffcassi

__all__ = ["CassiOperator", "CassiDataset"]


class _SparseApply(torch.autograd.Function):
    """y = A x for a batch of columns x (N, n) with A sparse CSR; backward gives Aᵀ g."""

    @staticmethod
    def forward(ctx, x, a, at):  # type: ignore[override]
        ctx.a, ctx.at = a, at
        return torch.sparse.mm(a, x.t()).t()

    @staticmethod
    def backward(ctx, g):  # type: ignore[override]
        gx = torch.sparse.mm(ctx.at, g.t().contiguous()).t() if ctx.needs_input_grad[0] else None
        return gx, None, None


class CassiOperator(nn.Module):
    """Φ as torch sparse CSR tensors (registered buffers: follow ``.to(device)``; values are cast to the input's
    dtype at each call).

    Shapes: ``cube_shape`` = (H, W, bands), ``image_shape`` = (h, w). ``forward(x)``: x (B, bands, H, W) or
    (bands, H, W) (the layout MST/DAUHST code uses) → (B, h, w) or (h, w). ``adjoint(y)``: the reverse.
    """

    def __init__(self, indptr: np.ndarray, indices: np.ndarray, data: np.ndarray, shape: Tuple[int, int],
                 cube_shape: Tuple[int, int, int], image_shape: Tuple[int, int]):
        super().__init__()
        rows, cols = int(shape[0]), int(shape[1])
        (H, W, B), (h, w) = cube_shape, image_shape
        if rows != h * w or cols != H * W * B:
            raise ValueError(f"CassiOperator: matrix shape {shape} does not match image {image_shape} and cube {cube_shape}")
        self.cube_shape = (int(H), int(W), int(B))
        self.image_shape = (int(h), int(w))
        crow = torch.as_tensor(np.asarray(indptr, dtype=np.int64))
        col = torch.as_tensor(np.asarray(indices, dtype=np.int64))
        val = torch.as_tensor(np.asarray(data, dtype=np.float64))
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)  # "sparse CSR support is in beta"
            a = torch.sparse_csr_tensor(crow, col, val, size=(rows, cols))
            at = a.t().to_sparse_csr()
        self.register_buffer("crow", crow)
        self.register_buffer("col", col)
        self.register_buffer("val", val)
        self.register_buffer("crow_t", at.crow_indices())
        self.register_buffer("col_t", at.col_indices())
        self.register_buffer("val_t", at.values())
        self._size = (rows, cols)

    # ------------------------------------------------------------------ constructors
    @classmethod
    def from_operator(cls, op: Union["diffcassi.Operator", "diffcassi.Transport"], memory_gb: float = 4.0) -> "CassiOperator":
        """From a diffcassi Operator (``diffcassi.exact(...)``, ``mapping_operator``, ``shift_operator``,
        ``Transport.operator``) or a Transport: the library's CSR export (refused, with the size, above
        ``memory_gb`` GB)."""
        if isinstance(op, diffcassi.Transport):
            op = op.operator
        indptr, indices, data, shape = op.to_csr_arrays(memory_gb)
        return cls(indptr, indices, data, shape, op.cube_shape, op.image_shape)

    @classmethod
    def from_scipy(cls, matrix: Any, cube_shape: Tuple[int, int, int], image_shape: Tuple[int, int]) -> "CassiOperator":
        """From a SciPy sparse matrix (converted to CSR)."""
        m = matrix.tocsr()
        return cls(m.indptr, m.indices, m.data, m.shape, cube_shape, image_shape)

    @classmethod
    def from_npz(cls, path: Union[str, os.PathLike], cube_shape: Tuple[int, int, int], image_shape: Tuple[int, int]) -> "CassiOperator":
        """From a ``save_npz`` file (NumPy only; no SciPy needed)."""
        with np.load(path) as z:
            fmt = z["format"].item()
            fmt = fmt.decode() if isinstance(fmt, bytes) else fmt
            if fmt != "csr":
                raise ValueError(f"{path}: format {fmt!r}, expected 'csr'")
            return cls(z["indptr"], z["indices"], z["data"], tuple(z["shape"]), cube_shape, image_shape)

    # ------------------------------------------------------------------ application
    def _matrices(self, like: torch.Tensor):
        dt = like.dtype
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)
            return self._build(dt)

    def _build(self, dt):
        a = torch.sparse_csr_tensor(self.crow, self.col, self.val.to(dt), size=self._size)
        at = torch.sparse_csr_tensor(self.crow_t, self.col_t, self.val_t.to(dt), size=(self._size[1], self._size[0]))
        return a, at

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """Φ x: x (B, bands, H, W) or (bands, H, W) → (B, h, w) or (h, w)."""
        H, W, B = self.cube_shape
        single = x.dim() == 3
        if single:
            x = x.unsqueeze(0)
        if x.dim() != 4 or tuple(x.shape[1:]) != (B, H, W):
            raise ValueError(f"CassiOperator.forward: x: expected shape (batch, {B}, {H}, {W}), got {tuple(x.shape)}")
        a, at = self._matrices(x)
        cols = x.permute(0, 2, 3, 1).reshape(x.shape[0], H * W * B)
        y = _SparseApply.apply(cols, a, at).reshape(x.shape[0], *self.image_shape)
        return y[0] if single else y

    def adjoint(self, y: torch.Tensor) -> torch.Tensor:
        """Φᵀ y: y (B, h, w) or (h, w) → (B, bands, H, W) or (bands, H, W)."""
        H, W, B = self.cube_shape
        single = y.dim() == 2
        if single:
            y = y.unsqueeze(0)
        if y.dim() != 3 or tuple(y.shape[1:]) != self.image_shape:
            raise ValueError(f"CassiOperator.adjoint: y: expected shape (batch, {self.image_shape[0]}, {self.image_shape[1]}), got {tuple(y.shape)}")
        a, at = self._matrices(y)
        x = _SparseApply.apply(y.reshape(y.shape[0], -1), at, a).reshape(y.shape[0], H, W, B).permute(0, 3, 1, 2)
        return x[0] if single else x

    def extra_repr(self) -> str:
        return f"cube={self.cube_shape}, image={self.image_shape}, nnz={int(self.val.numel())}"


# ---------------------------------------------------------------------- dataset
def _resample(cube: np.ndarray, from_nm: Sequence[float], to_nm: Sequence[float]) -> np.ndarray:
    """Linear interpolation in λ, constant beyond the range (the library's SpectralCube::resample rule)."""
    f, t = np.asarray(from_nm, dtype=np.float64), np.asarray(to_nm, dtype=np.float64)
    if f.shape == t.shape and np.array_equal(f, t):
        return cube
    k = np.clip(np.searchsorted(f, t, side="right") - 1, 0, max(len(f) - 2, 0))
    k1 = np.minimum(k + 1, len(f) - 1)
    den = np.where(f[k1] > f[k], f[k1] - f[k], 1.0)
    wt = np.clip((t - f[k]) / den, 0.0, 1.0).astype(np.float32)
    return ((1 - wt) * cube[..., k] + wt * cube[..., k1]).astype(np.float32)


class CassiDataset(torch.utils.data.Dataset):
    """Training samples rendered on the fly: item ``index`` of epoch ``epoch`` takes scene ``index % len(scenes)``,
    a random ``size`` × ``size`` crop, a random horizontal/vertical flip and a random number of 90° rotations —
    every choice from ``numpy.random.default_rng([seed, index, epoch])`` — and renders it through a
    :class:`~diffcassi.Transport` (built once per process, lazily, so the dataset pickles to DataLoader workers).

    ``scenes``: a folder (``.exr``, ``.npy`` with ``<stem>_wavelengths_nm.npy``, or per-band PNG folders: the
    CLI's loaders), a list of paths, or a list of ``(cube (H, W, B) float32, wavelengths_nm)``. Cubes are
    resampled to the transport's bands. ``transport``: keywords of :class:`~diffcassi.Transport` (bands_nm,
    planes, rays, seed, mask_seed, ...). Each item is a tuple of float32 tensors
    ``(acquisition (h, w), mask (H, W), truth (bands, H, W), initialisation (bands, H, W))``.
    """

    def __init__(self, scenes: Union[str, os.PathLike, List[Any]], system: Union[str, "diffcassi.System"], size: int,
                 length: Optional[int] = None, seed: int = 0, epoch: int = 0, transport: Optional[Dict[str, Any]] = None):
        self.system_spec = system if isinstance(system, str) else system.to_toml()
        self.system_is_preset = isinstance(system, str)
        self.size = int(size)
        self.seed, self.epoch = int(seed), int(epoch)
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
        for s in scenes:
            if isinstance(s, (str, os.PathLike)):
                cube, wl = diffcassi.load_scene(os.fspath(s))
            else:
                cube, wl = s
            cube = np.ascontiguousarray(cube, dtype=np.float32)
            if cube.ndim != 3 or cube.shape[0] < self.size or cube.shape[1] < self.size:
                raise diffcassi.DiffcassiValueError(f"scene of shape {cube.shape}: expected (H, W, B) with H, W ≥ size = {self.size}")
            self.scenes.append((cube, list(wl)))
        self.length = len(self.scenes) if length is None else int(length)
        self._state: Optional[Dict[str, Any]] = None
        self._pool_pid: Optional[int] = None
        #: Threads of each DataLoader worker's pool.
        self.worker_threads = 1

    def __getstate__(self):
        d = dict(self.__dict__)
        d["_state"] = None  # the Transport is rebuilt in each worker
        return d

    def set_epoch(self, epoch: int) -> None:
        """Choose the epoch (its augmentations differ from every other epoch's)."""
        self.epoch = int(epoch)

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
        if not 0 <= index < self.length:
            raise IndexError(index)
        if torch.utils.data.get_worker_info() is not None and self._pool_pid != os.getpid():
            # A forked DataLoader worker inherits no live rayon threads: give it its own pool (1 thread per
            # worker; the workers are the parallelism). Results do not depend on the thread count.
            diffcassi.set_num_threads(self.worker_threads)
            self._pool_pid = os.getpid()
        st = self._ready()
        t = st["transport"]
        rng = np.random.default_rng([self.seed, int(index), self.epoch])
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
        return (torch.from_numpy(acq), torch.from_numpy(st["mask"]),
                torch.from_numpy(np.ascontiguousarray(truth.transpose(2, 0, 1))),
                torch.from_numpy(np.ascontiguousarray(init.transpose(2, 0, 1))))
