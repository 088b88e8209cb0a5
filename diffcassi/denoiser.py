"""The learned hyperspectral denoiser (the prior of the plug-and-play solvers): its PyTorch definition.

``SpectralUNet`` is a small residual U-Net over all bands at once (spectral–spatial: every convolution mixes
all bands), in the spirit of FFDNet/DRUNet: the noise level σ enters as a constant extra input channel, so one
network serves every σ of a plug-and-play schedule. The Rust inference (``src/recon/prior/``) implements the same
graph layer by layer and loads the same safetensors file; the two agree to 1e-4 of the peak (tested).

Graph (C = ``width``, all convolutions 3×3 with zero padding 1 and a bias unless said otherwise, ReLU after each
but the last; input height and width must be multiples of 4 — :func:`denoise` pads by edge replication):

====================  ===============================================  ===================
name                  layer                                            resolution
====================  ===============================================  ===================
``head``              conv3×3 (bands + 1 → C), ReLU                    full
``enc1``              conv3×3 (C → C), ReLU                            full
``down1``             conv2×2 stride 2, no padding (C → 2C), ReLU       1/2
``enc2a``/``enc2b``   conv3×3 (2C → 2C), ReLU, twice                   1/2
``down2``             conv2×2 stride 2, no padding (2C → 2C), ReLU      1/4
``mid_a``/``mid_b``   conv3×3 (2C → 2C), ReLU, twice                   1/4
``up2``               transposed conv2×2 stride 2 (2C → 2C), + enc2b   1/2
``dec2``              conv3×3 (2C → 2C), ReLU                          1/2
``up1``               transposed conv2×2 stride 2 (2C → C), + enc1     full
``dec1``              conv3×3 (C → C), ReLU                            full
``tail``              conv3×3 (C → bands), no ReLU                     full
====================  ===============================================  ===================

Output = input − tail (the network predicts the noise). Inputs are cubes (N, bands, H, W) scaled to a peak of
about 1 and σ the standard deviation of the noise on that scale. State-dict keys are ``<name>.weight`` and
``<name>.bias``; the safetensors file's metadata records ``bands``, ``width`` and ``arch`` =
``"spectral-unet-v1"``.
"""
from __future__ import annotations

from typing import Dict, Optional

import torch
from torch import nn
import torch.nn.functional as F

ARCH = "spectral-unet-v1"


class SpectralUNet(nn.Module):
    """See the module docs for the graph. ``forward(x, sigma)``: x (N, bands, H, W) with H, W multiples of 4,
    sigma a float or a tensor (N,) of noise levels."""

    def __init__(self, bands: int = 28, width: int = 32):
        super().__init__()
        self.bands, self.width = bands, width
        c, c2 = width, 2 * width
        self.head = nn.Conv2d(bands + 1, c, 3, padding=1)
        self.enc1 = nn.Conv2d(c, c, 3, padding=1)
        self.down1 = nn.Conv2d(c, c2, 2, stride=2)
        self.enc2a = nn.Conv2d(c2, c2, 3, padding=1)
        self.enc2b = nn.Conv2d(c2, c2, 3, padding=1)
        self.down2 = nn.Conv2d(c2, c2, 2, stride=2)
        self.mid_a = nn.Conv2d(c2, c2, 3, padding=1)
        self.mid_b = nn.Conv2d(c2, c2, 3, padding=1)
        self.up2 = nn.ConvTranspose2d(c2, c2, 2, stride=2)
        self.dec2 = nn.Conv2d(c2, c2, 3, padding=1)
        self.up1 = nn.ConvTranspose2d(c2, c, 2, stride=2)
        self.dec1 = nn.Conv2d(c, c, 3, padding=1)
        self.tail = nn.Conv2d(c, bands, 3, padding=1)

    def forward(self, x: torch.Tensor, sigma) -> torch.Tensor:
        n, b, h, w = x.shape
        if b != self.bands:
            raise ValueError(f"SpectralUNet: the input has {b} bands, the network was built for {self.bands}")
        if h % 4 or w % 4:
            raise ValueError(f"SpectralUNet: height {h} and width {w} must be multiples of 4 (pad first)")
        s = torch.as_tensor(sigma, dtype=x.dtype, device=x.device).reshape(-1, 1, 1, 1).expand(n, 1, h, w)
        z = F.relu(self.head(torch.cat([x, s], dim=1)))
        e1 = F.relu(self.enc1(z))
        z = F.relu(self.down1(e1))
        z = F.relu(self.enc2a(z))
        e2 = F.relu(self.enc2b(z))
        z = F.relu(self.down2(e2))
        z = F.relu(self.mid_a(z))
        z = F.relu(self.mid_b(z))
        z = self.up2(z) + e2
        z = F.relu(self.dec2(z))
        z = self.up1(z) + e1
        z = F.relu(self.dec1(z))
        return x - self.tail(z)

    def metadata(self) -> Dict[str, str]:
        """The safetensors metadata of this network's weights file."""
        return {"arch": ARCH, "bands": str(self.bands), "width": str(self.width)}


def pad_to_multiple(x: torch.Tensor, m: int = 4):
    """Pads (N, B, H, W) at the bottom and right by edge replication to multiples of ``m``; returns the padded
    tensor and the original (H, W)."""
    h, w = x.shape[-2:]
    ph, pw = (-h) % m, (-w) % m
    if ph or pw:
        x = F.pad(x, (0, pw, 0, ph), mode="replicate")
    return x, (h, w)


def denoise(net: SpectralUNet, x: torch.Tensor, sigma) -> torch.Tensor:
    """Denoises (N, B, H, W) of any size: pads to multiples of 4 by edge replication, runs ``net``, crops."""
    xp, (h, w) = pad_to_multiple(x)
    return net(xp, sigma)[..., :h, :w]


# --- weights files (safetensors): the loader every consumer uses, with clear errors -----------------------------

def save_weights(net: SpectralUNet, path, extra_metadata: Optional[Dict[str, str]] = None) -> None:
    """Writes ``net``'s state dict to the safetensors file ``path`` with :meth:`SpectralUNet.metadata` (plus
    ``extra_metadata``, strings), atomically (a temporary file renamed over ``path``: never a half-written file)."""
    import os
    from safetensors.torch import save_file
    tensors = {k: v.detach().to(torch.float32).contiguous().clone() for k, v in net.state_dict().items()}
    for k, v in tensors.items():
        if not torch.isfinite(v).all():
            raise ValueError(f"save_weights: tensor {k} has non-finite values; {path} not written")
    meta = dict(net.metadata())
    meta.update({str(k): str(v) for k, v in (extra_metadata or {}).items()})
    tmp = f"{path}.tmp{os.getpid()}"
    save_file(tensors, tmp, metadata=meta)
    os.replace(tmp, path)


def load_weights(path, bands: Optional[int] = None) -> SpectralUNet:
    """Loads a ``spectral-unet-v1`` safetensors file into a new :class:`SpectralUNet` (eval mode). Raises
    FileNotFoundError for a missing file and ValueError, naming the file and the problem, for a file that is not
    safetensors, has another architecture, band count (when ``bands`` is given) or width, misses or has extra
    tensors, has a tensor of the wrong shape, or holds NaN/inf."""
    import os
    from safetensors import safe_open
    path = os.fspath(path)
    if not os.path.isfile(path):
        raise FileNotFoundError(f"denoiser weights {path}: no such file")
    try:
        with safe_open(path, framework="pt") as f:
            meta = f.metadata() or {}
            tensors = {k: f.get_tensor(k) for k in f.keys()}
    except Exception as e:  # safetensors raises its own error types for a bad header or truncated data
        raise ValueError(f"denoiser weights {path}: not a valid safetensors file ({e})") from None
    if meta.get("arch") != ARCH:
        raise ValueError(f"denoiser weights {path}: metadata arch is {meta.get('arch')!r}, expected {ARCH!r}")
    try:
        b, w = int(meta["bands"]), int(meta["width"])
    except (KeyError, ValueError):
        raise ValueError(f"denoiser weights {path}: metadata bands/width missing or not integers "
                         f"(bands={meta.get('bands')!r}, width={meta.get('width')!r})") from None
    if b < 1 or w < 1:
        raise ValueError(f"denoiser weights {path}: metadata bands={b}, width={w} must be positive")
    if bands is not None and b != bands:
        raise ValueError(f"denoiser weights {path}: the network is for {b} bands, the cube has {bands}")
    net = SpectralUNet(bands=b, width=w)
    want = net.state_dict()
    missing, extra = sorted(set(want) - set(tensors)), sorted(set(tensors) - set(want))
    if missing or extra:
        raise ValueError(f"denoiser weights {path}: missing tensors {missing}, unexpected tensors {extra}")
    for k, v in tensors.items():
        if tuple(v.shape) != tuple(want[k].shape):
            raise ValueError(f"denoiser weights {path}: tensor {k} has shape {tuple(v.shape)}, "
                             f"expected {tuple(want[k].shape)} (bands={b}, width={w})")
        if not torch.isfinite(v).all():
            raise ValueError(f"denoiser weights {path}: tensor {k} has NaN or infinite values")
    net.load_state_dict({k: v.to(torch.float32) for k, v in tensors.items()})
    return net.eval()
