"""A sparse matrix applied by deterministic gathers (issue 41): the exact operator's table on any torch device.

:class:`GatherTable` keeps a matrix A (rows × cols) built from CSR arrays as **row buckets** (a sliced ELLPACK
layout): rows are grouped by their number of non-zeros c into buckets of width w(c) (the next step of a
quarter-octave ladder: w = c up to 8, then multiples of 2^(e−3) for 2^(e−1) < c ≤ 2^e, so w < 1.25·c and
there are at most 4 buckets per octave), each bucket a dense pair ``cols`` (r, w) int32 / ``vals`` (r, w).
``A @ x`` is, per bucket, ``(vals * x[:, cols]).sum(-1)`` — an ``index_select`` gather, a product and a sum
over the last dimension — and the buckets' results are put in row order by one more gather. No scatter, no
atomics: every output element is computed by one reduction in a fixed order, so two runs give identical
bits on a GPU and the result does not depend on scheduling; the CPU tests run the very same code.

Padding entries repeat the row's last column with value 0 (never an out-of-row column), so a non-finite
input propagates exactly as in a true sparse product. Rows without non-zeros read a zero slot.

``GatherTable.transposed(...)`` builds Aᵀ's table from A's CSR on the target device (a stable sort of the
column indices: within a row of Aᵀ the entries keep A's row order), so nothing of the transposition runs
on the host.

Values are stored as the *bits* of float32 (or float64) in an integer buffer, so ``module.to(dtype)`` (which
casts floating buffers) never rounds the table; they are viewed back and cast to the input's dtype at each
call. Memory: 8 bytes per stored (padded) entry with float32 values (int32 column + float32 value), plus
8 bytes per row (the row-order gather).
"""
from __future__ import annotations

from typing import List, Optional, Tuple

import torch
from torch import nn

#: Elements of one gathered block (batch × rows × width): larger buckets are applied in row slices so the
#: temporary stays ≤ 2²⁴ elements (64 MiB in float32).
_BLOCK = 1 << 24
#: On CUDA: 2²⁶ (256 MiB in float32), fewer launches.
_BLOCK_CUDA = 1 << 26


def ladder_widths(counts: torch.Tensor) -> torch.Tensor:
    """The bucket width of rows with ``counts`` non-zeros (int64 tensor, any device): c for c ≤ 8, else c rounded
    up to a multiple of 2^(e−3) where 2^(e−1) < c ≤ 2^e (w < 1.25·c; 4 widths per octave)."""
    step = torch.ones_like(counts)
    for k in range(3, 62):
        big = counts > (1 << k)
        if not bool(big.any()):
            break
        step = torch.where(big, torch.full_like(counts, 1 << (k - 2)), step)
    return (counts + step - 1) // step * step


class GatherTable(nn.Module):
    """A (rows × cols) sparse matrix as row buckets on a device; ``matmul(x)``: x (N, cols) → (N, rows).

    Built from CSR arrays (``indptr`` (rows + 1), ``indices``, ``values``; tensors or arrays, any device) on
    ``device``. ``values`` float32 or float64 (kept in their own precision).
    """

    def __init__(self, indptr: torch.Tensor, indices: torch.Tensor, values: torch.Tensor, shape: Tuple[int, int],
                 device: torch.device):
        super().__init__()
        rows, cols = int(shape[0]), int(shape[1])
        if cols >= 2 ** 31:
            raise ValueError(f"GatherTable: {cols} columns exceed int32 column indices")
        self.shape = (rows, cols)
        indptr = torch.as_tensor(indptr).to(device=device, dtype=torch.int64)
        indices = torch.as_tensor(indices).to(device=device, dtype=torch.int64)
        values = torch.as_tensor(values).to(device=device)
        if values.dtype not in (torch.float32, torch.float64):
            values = values.to(torch.float32)
        self.value_dtype = values.dtype
        bits = torch.int32 if values.dtype == torch.float32 else torch.int64
        counts = indptr[1:] - indptr[:-1]
        widths = ladder_widths(counts)
        where = torch.full((rows,), 0, dtype=torch.int64, device=device)
        self._buckets: List[Tuple[str, str, int]] = []
        offset, stored = 0, 0
        # Rows grouped by width (a stable sort: increasing row index within a bucket), rows without entries last.
        key = torch.where(counts > 0, widths, torch.full_like(widths, 1 << 62))
        key_sorted, by_width = torch.sort(key, stable=True)
        present, sizes = torch.unique_consecutive(key_sorted, return_counts=True)
        bounds = [0]
        for v in sizes.tolist():
            bounds.append(bounds[-1] + int(v))
        for i, w in enumerate(int(v) for v in present.tolist()):
            if w == 1 << 62:
                break
            rs = by_width[bounds[i]:bounds[i + 1]]
            r = int(rs.numel())
            start, cnt = indptr[rs], counts[rs]
            j = torch.arange(w, device=device, dtype=torch.int64)
            pos = start[:, None] + torch.minimum(j[None, :], cnt[:, None] - 1)
            c = indices[pos].to(torch.int32)
            v = torch.where(j[None, :] < cnt[:, None], values[pos], torch.zeros((), dtype=values.dtype, device=device))
            self.register_buffer(f"cols{i}", c.contiguous(), persistent=False)
            self.register_buffer(f"vals{i}", v.contiguous().view(bits), persistent=False)
            self._buckets.append((f"cols{i}", f"vals{i}", w))
            where[rs] = offset + torch.arange(r, device=device, dtype=torch.int64)
            offset += r
            stored += r * w
            del pos, c, v
        where[counts == 0] = offset  # the zero slot after the last bucket
        self.register_buffer("where", where, persistent=False)
        self.nnz = int(indices.numel())
        self.stored = stored

    @classmethod
    def transposed(cls, indptr: torch.Tensor, indices: torch.Tensor, values: torch.Tensor, shape: Tuple[int, int],
                   device: torch.device) -> "GatherTable":
        """The table of Aᵀ from A's CSR arrays, transposed on ``device`` (stable sort of the column indices)."""
        rows, cols = int(shape[0]), int(shape[1])
        indptr = torch.as_tensor(indptr).to(device=device, dtype=torch.int64)
        indices = torch.as_tensor(indices).to(device=device, dtype=torch.int64)
        values = torch.as_tensor(values).to(device=device)
        counts = indptr[1:] - indptr[:-1]
        sorted_cols, order = torch.sort(indices, stable=True)
        row_of = torch.repeat_interleave(torch.arange(rows, device=device, dtype=torch.int64), counts)
        t_indices = row_of[order]
        del row_of
        t_values = values[order]
        del order
        # Aᵀ's row pointers by binary search in the sorted columns (not bincount/cumsum: torch does not guarantee
        # those deterministic on CUDA, and refuses them under torch.use_deterministic_algorithms(True)).
        t_indptr = torch.searchsorted(sorted_cols, torch.arange(cols + 1, device=device, dtype=torch.int64))
        return cls(t_indptr, t_indices, t_values, (cols, rows), device)

    @property
    def padding(self) -> float:
        """Stored entries (with padding) per non-zero (1.0: none)."""
        return self.stored / self.nnz if self.nnz else 1.0

    def nbytes(self) -> int:
        """Bytes of the table's buffers."""
        return sum(int(b.numel()) * b.element_size() for b in self.buffers())

    @staticmethod
    def estimate_bytes(nnz: int, rows: int, value_bytes: int = 4) -> int:
        """Bytes of a table of ``nnz`` non-zeros and ``rows`` rows, at the ladder's worst-case padding (1.25)."""
        return int(1.25 * nnz * (4 + value_bytes)) + 8 * rows

    def matmul(self, x: torch.Tensor) -> torch.Tensor:
        """A x for a batch of columns x (N, cols) (contiguous, floating) → (N, rows), in x's dtype."""
        n = x.shape[0]
        x = x.contiguous()
        parts = []
        for cname, vname, w in self._buckets:
            cols: torch.Tensor = getattr(self, cname)
            vals = getattr(self, vname).view(self.value_dtype)
            if vals.dtype != x.dtype:
                vals = vals.to(x.dtype)
            r = cols.shape[0]
            step = max(1, (_BLOCK_CUDA if x.is_cuda else _BLOCK) // max(1, w * n))
            for s in range(0, r, step):
                c, v = cols[s:s + step], vals[s:s + step]
                g = torch.index_select(x, 1, c.reshape(-1)).view(n, c.shape[0], w)
                parts.append(g.mul_(v).sum(-1))  # g is a fresh gather: multiplied in place
        parts.append(x.new_zeros(n, 1))
        return torch.index_select(torch.cat(parts, 1), 1, self.where)

    def extra_repr(self) -> str:
        return (f"{self.shape[0]}×{self.shape[1]}, nnz={self.nnz}, {len(self._buckets)} buckets, "
                f"padding {self.padding:.3f}, {self.nbytes() / 1e6:.1f} MB on {self.where.device}")


class _GatherApply(torch.autograd.Function):
    """y = A x by gathers (x (N, cols)); backward gives Aᵀ g by Aᵀ's own gathers (itself this function, so
    second derivatives work)."""

    @staticmethod
    def forward(ctx, x, a, at):  # type: ignore[override]
        ctx.a, ctx.at = a, at
        return a.matmul(x)

    @staticmethod
    def backward(ctx, g):  # type: ignore[override]
        if not ctx.needs_input_grad[0]:
            return None, None, None
        return _GatherApply.apply(g, ctx.at, ctx.a), None, None


def gather_apply(x: torch.Tensor, a: GatherTable, at: GatherTable) -> torch.Tensor:
    """A x (differentiable; the backward is Aᵀ)."""
    return _GatherApply.apply(x, a, at)


def pair_from_csr(indptr, indices, values, shape: Tuple[int, int], device: torch.device,
                  band_major: Optional[Tuple[int, int]] = None) -> Tuple[GatherTable, GatherTable]:
    """(A, Aᵀ) tables on ``device`` from CSR arrays. ``band_major`` = (pixels, bands): the columns are cube
    entries in C order [pixel][band] (the library's export) and are renumbered band-major, b·pixels + q, so a
    (N, bands, H, W) cube is a contiguous (N, cols) operand and Aᵀ's result a (N, bands, H, W) cube."""
    indices = torch.as_tensor(indices).to(device=device, dtype=torch.int64)
    if band_major is not None:
        npix, nb = band_major
        indices = (indices % nb) * npix + indices // nb
    a = GatherTable(indptr, indices, values, shape, device)
    at = GatherTable.transposed(indptr, indices, values, shape, device)
    return a, at
