"""The learned hyperspectral denoiser (the prior of the plug-and-play solvers): its PyTorch definition.

``SpectralUNet`` (arch ``spectral-unet-v2``) is a small U-Net in the spirit of FFDNet/DRUNet (the noise level σ
enters as a constant extra input channel, so one network serves every σ of a plug-and-play schedule) behind a
*linear spectral path*: a learned 1×1 spectral encoder E (bands → K, the latent), the U-Net denoising the
K-channel latent with its own residual, a learned 1×1 decoder D (K → bands) and a learned 1×1 bypass G
(bands → bands), all three without bias or activation:

    z = E·x,    out = D·(z − U([z, σ])) + G·x.

Natural spectra span few dimensions, so most of a white noise's 28 bands are removed by the linear maps alone
(what a residual U-Net with ReLUs could not learn: src/recon/prior/MODEL.md, round 2's diagnosis); the U-Net
only has to carry K signed latent noise values. The Rust inference (``src/recon/prior/network.rs``) implements
the same graph and loads the same safetensors file; the two agree to 1e-4 of the peak (tested).

Graph (C = ``width``, K = ``latent``, all convolutions 3×3 with zero padding 1 and a bias unless said otherwise,
ReLU after each but the last; input height and width must be multiples of 4 — :func:`denoise` pads by edge
replication):

====================  ===============================================  ===================
name                  layer                                            resolution
====================  ===============================================  ===================
``lat_enc``           conv1×1 (bands → K), no bias: z = E·x            full
``head``              conv3×3 (K + 1 → C) on [z, σ], ReLU              full
``enc1``              conv3×3 (C → C), ReLU                            full
``down1``             conv2×2 stride 2, no padding (C → 2C), ReLU       1/2
``enc2a``/``enc2b``   conv3×3 (2C → 2C), ReLU, twice                   1/2
``down2``             conv2×2 stride 2, no padding (2C → 2C), ReLU      1/4
``mid_a``/``mid_b``   conv3×3 (2C → 2C), ReLU, twice                   1/4
``up2``               transposed conv2×2 stride 2 (2C → 2C), + enc2b   1/2
``dec2``              conv3×3 (2C → 2C), ReLU                          1/2
``up1``               transposed conv2×2 stride 2 (2C → C), + enc1     full
``dec1``              conv3×3 (C → C), ReLU                            full
``tail``              conv3×3 (C → K), no ReLU: the latent noise u     full
``lat_dec``           conv1×1 (K → bands), no bias, on z − u           full
``bypass``            conv1×1 (bands → bands), no bias, on x; added    full
====================  ===============================================  ===================

Inputs are cubes (N, bands, H, W) scaled to a peak of about 1 and σ the standard deviation of the noise on that
scale. State-dict keys are ``<name>.weight`` (and ``<name>.bias`` for the 3×3/2×2 layers); the safetensors file's
metadata records ``arch`` = ``"spectral-unet-v2"``, ``bands``, ``width`` and ``latent``.

The round-1/2 graph ``spectral-unet-v1`` (out = x − U([x, σ])) is v2 with K = bands, E = D = I and G = 0:
:func:`from_v1` converts its weights (used to start v2's training from them).
"""
from __future__ import annotations

from typing import Dict, Optional

try:
    import torch
    from torch import nn
    import torch.nn.functional as F
except ImportError as _e:  # pragma: no cover - depends on the environment
    raise ImportError("diffcassi.denoiser needs PyTorch: pip install torch") from _e

ARCH = "spectral-unet-v2"

#: What a weights file was trained for (metadata ``stage``; absent = ``gaussian``): a Gaussian denoiser, or
#: (round 6 of src/recon/prior/MODEL.md) a plug-and-play stage network trained on the iterates of ``pnp-gap``'s
#: multi-call schedule (σ its per-call value). :func:`load_weights` sets ``net.stage``.
STAGES = ("gaussian", "pnp")

#: The layers of the U-Net part, in graph order: (name, kind); kind "c3" conv3×3, "d2" conv2×2 stride 2,
#: "t2" transposed conv2×2 stride 2.
UNET_LAYERS = (("head", "c3"), ("enc1", "c3"), ("down1", "d2"), ("enc2a", "c3"), ("enc2b", "c3"), ("down2", "d2"),
               ("mid_a", "c3"), ("mid_b", "c3"), ("up2", "t2"), ("dec2", "c3"), ("up1", "t2"), ("dec1", "c3"),
               ("tail", "c3"))


class SpectralUNet(nn.Module):
    """See the module docs for the graph. ``forward(x, sigma)``: x (N, bands, H, W) with H, W multiples of 4,
    sigma a float or a tensor (N,) of noise levels. ``latent`` K defaults to ``bands``. A new network starts with
    E = D = I (the first K bands) and G = 0."""

    def __init__(self, bands: int = 28, width: int = 32, latent: Optional[int] = None):
        super().__init__()
        k = bands if latent is None else latent
        if not (bands >= 1 and width >= 1 and 1 <= k <= bands):
            raise ValueError(f"SpectralUNet: bands={bands}, width={width}, latent={k} (need 1 ≤ latent ≤ bands)")
        self.bands, self.width, self.latent = bands, width, k
        c, c2 = width, 2 * width
        self.lat_enc = nn.Conv2d(bands, k, 1, bias=False)
        self.head = nn.Conv2d(k + 1, c, 3, padding=1)
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
        self.tail = nn.Conv2d(c, k, 3, padding=1)
        self.lat_dec = nn.Conv2d(k, bands, 1, bias=False)
        self.bypass = nn.Conv2d(bands, bands, 1, bias=False)
        with torch.no_grad():
            eye = torch.eye(bands)[:k]
            self.lat_enc.weight.copy_(eye[:, :, None, None])
            self.lat_dec.weight.copy_(eye.T[:, :, None, None])
            self.bypass.weight.zero_()

    def forward(self, x: torch.Tensor, sigma) -> torch.Tensor:
        n, b, h, w = x.shape
        if b != self.bands:
            raise ValueError(f"SpectralUNet: the input has {b} bands, the network was built for {self.bands}")
        if h % 4 or w % 4:
            raise ValueError(f"SpectralUNet: height {h} and width {w} must be multiples of 4 (pad first)")
        s = torch.as_tensor(sigma, dtype=x.dtype, device=x.device).reshape(-1, 1, 1, 1).expand(n, 1, h, w)
        lat = self.lat_enc(x)
        z = F.relu(self.head(torch.cat([lat, s], dim=1)))
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
        return self.lat_dec(lat - self.tail(z)) + self.bypass(x)

    def metadata(self) -> Dict[str, str]:
        """The safetensors metadata of this network's weights file."""
        return {"arch": ARCH, "bands": str(self.bands), "width": str(self.width), "latent": str(self.latent)}


def from_v1(tensors: Dict[str, torch.Tensor], basis: Optional[torch.Tensor] = None, full_latent: bool = False) -> SpectralUNet:
    """A v2 network from the tensors of a ``spectral-unet-v1`` file (out = x − U([x, σ])). Without ``basis`` it is
    the same function (K = bands, E = D = I, G = 0). With an orthonormal ``basis`` V (bands, k), P = V·Vᵀ:

    * ``full_latent=False``: the latent is the span of V (K = k): E = Vᵀ, D = V, the U-Net's first layer reads the
      latent through V (head_x·V) and its last writes it (Vᵀ·tail), so out = P·(Px − U₁([Px, σ]));
    * ``full_latent=True``: K = bands, E = I, D = P, so out = P·(x − U₁([x, σ])) (v1's output projected).
    """
    bands = tensors["tail.weight"].shape[0]
    width = tensors["enc1.weight"].shape[0]
    v = torch.eye(bands) if basis is None else basis.to(torch.float32)
    if v.ndim != 2 or v.shape[0] != bands:
        raise ValueError(f"from_v1: basis of shape {tuple(v.shape)}, expected ({bands}, K)")
    sd = {k: t.clone().to(torch.float32) for k, t in tensors.items()}
    sd["bypass.weight"] = torch.zeros(bands, bands, 1, 1)
    if full_latent:
        net = SpectralUNet(bands=bands, width=width, latent=bands)
        sd["lat_enc.weight"] = torch.eye(bands)[:, :, None, None]
        sd["lat_dec.weight"] = (v @ v.T)[:, :, None, None]
    else:
        net = SpectralUNet(bands=bands, width=width, latent=v.shape[1])
        hw = sd["head.weight"]  # (C, bands + 1, 3, 3): the x part through V, the σ channel kept
        sd["head.weight"] = torch.cat([torch.einsum("cbij,bk->ckij", hw[:, :bands], v), hw[:, bands:]], dim=1)
        sd["tail.weight"] = torch.einsum("bk,bcij->kcij", v, sd["tail.weight"])
        sd["tail.bias"] = v.T @ sd["tail.bias"]
        sd["lat_enc.weight"] = v.T.contiguous()[:, :, None, None]
        sd["lat_dec.weight"] = v.contiguous()[:, :, None, None]
    net.load_state_dict(sd)
    return net


def pad_to_multiple(x: torch.Tensor, m: int = 4):
    """Pads (N, B, H, W) at the bottom and right by edge replication to multiples of ``m``; returns the padded
    tensor and the original (H, W)."""
    h, w = x.shape[-2:]
    ph, pw = (-h) % m, (-w) % m
    if ph or pw:
        x = F.pad(x, (0, pw, 0, ph), mode="replicate")
    return x, (h, w)


def _run_padded(net: SpectralUNet, x: torch.Tensor, sigma) -> torch.Tensor:
    """``net`` on (N, B, H, W) of any size: pads to multiples of 4 by edge replication, runs, crops."""
    xp, (h, w) = pad_to_multiple(x)
    return net(xp, sigma)[..., :h, :w]


#: The eight dihedral transforms of the self-ensemble, in the order both inferences average them: (k, flip) =
#: ``rot90`` by k quarter turns over (H, W), then (if flip) a reversal of the width axis.
DIHEDRAL = tuple((k, f) for k in range(4) for f in (False, True))
#: The four elements of :data:`DIHEDRAL` that keep H × W (no quarter turn or a half turn, each without and
#: with the width flip): what equivariant PnP draws among for a non-square cube.
DIHEDRAL_FLIPS = ((0, False), (0, True), (2, False), (2, True))
_M64 = (1 << 64) - 1


def _mix64(z: int) -> int:
    """SplitMix64's finaliser (``render::sampling::mix64``)."""
    z = (z + 0x9E3779B97F4A7C15) & _M64
    z = ((z ^ (z >> 30)) * 0xBF58476D1CE4E5B9) & _M64
    z = ((z ^ (z >> 27)) * 0x94D049BB133111EB) & _M64
    return z ^ (z >> 31)


def dihedral_draw(seed: int, call: int, square: bool = True):
    """The transform (quarter turns k, width flip) equivariant PnP applies at network call ``call`` (1-based) of
    stream ``seed``: the twin of ``recon::prior::dihedral::Dihedral::draw`` (uniform over :data:`DIHEDRAL` for a
    square cube, over :data:`DIHEDRAL_FLIPS` otherwise; counter-based)."""
    z = _mix64(_mix64(seed & _M64) ^ (call & _M64))
    return DIHEDRAL[z >> 61] if square else DIHEDRAL_FLIPS[z >> 62]


def transformed_denoise(net: SpectralUNet, x: torch.Tensor, sigma, transform) -> torch.Tensor:
    """g⁻¹·denoise(g·x) for ``transform`` g = (quarter turns k, width flip) on (N, B, H, W): one call of
    equivariant PnP (``recon::solve::prior_step::denoise_at_network_scale_transformed``)."""
    k, f = transform
    t = torch.rot90(x, k, dims=(2, 3))
    t = torch.flip(t, dims=(3,)) if f else t
    o = denoise(net, t, sigma)
    o = torch.flip(o, dims=(3,)) if f else o
    return torch.rot90(o, -k, dims=(2, 3))


def denoise(net: SpectralUNet, x: torch.Tensor, sigma, neutral: bool = False, ensemble: bool = False) -> torch.Tensor:
    """Denoises (N, B, H, W) of any size (peak about 1, σ on that scale): the inference every consumer uses; the
    Rust twin (``src/recon/prior/network.rs``) does the same steps.

    * ``neutral`` (round 5, src/recon/prior/MODEL.md; off by default like the Rust twin's, so that PnP's
      iterates are denoised as round 4 trained on them): **mean-colour neutralisation**. The network
      sees the cube with its mean spectrum replaced by a flat (grey) one of the same mean level,
      x − m + ḡ (m_b the band's spatial mean over the cube, ḡ the mean of m over the bands), and the output gets
      m − ḡ back. Constants commute with an additive noise, so the noise is unchanged; only the cube's overall
      colour moves to where the training data's colours are dense. Measured: the network distorts a saturated
      cube's mean colour (retina's orange: a constant cube of its mean spectrum comes back at 35.9 dB at σ 0.05,
      a per-band bias of 0.016), and neutralised it loses that bias (retina 34.53 → 40.00 dB at σ 0.05).
    * ``ensemble``: the geometric self-ensemble — the mean of the eight dihedral transforms (:data:`DIHEDRAL`)
      of the input, each denoised and transformed back (B. Lim et al., "Enhanced deep residual networks for
      single image super-resolution", CVPRW 2017; K. Zhang et al., DRUNet, TPAMI 2021); 8× the time.

    Pads to multiples of 4 by edge replication, runs ``net``, crops (per transform)."""
    if neutral:
        m = x.mean(dim=(2, 3), keepdim=True)
        g = m.mean(dim=1, keepdim=True)
        shift = m - g
        x = x - shift
    if ensemble:
        acc = None
        for k, f in DIHEDRAL:
            t = torch.rot90(x, k, dims=(2, 3))
            t = torch.flip(t, dims=(3,)) if f else t
            o = _run_padded(net, t, sigma)
            o = torch.flip(o, dims=(3,)) if f else o
            o = torch.rot90(o, -k, dims=(2, 3))
            acc = o if acc is None else acc + o
        out = acc / len(DIHEDRAL)
    else:
        out = _run_padded(net, x, sigma)
    return out + shift if neutral else out


# --- weights files (safetensors): the loader every consumer uses, with clear errors -----------------------------

def save_weights(net: SpectralUNet, path, extra_metadata: Optional[Dict[str, str]] = None) -> None:
    """Writes ``net``'s state dict to the safetensors file ``path`` with :meth:`SpectralUNet.metadata` (plus
    ``extra_metadata``, strings), atomically (:func:`diffcassi._files.write_staged`: never a half-written file, never
    over a folder, a pipe, a device or a link)."""
    from safetensors.torch import save_file
    from ._files import write_staged
    tensors = {k: v.detach().to("cpu", torch.float32).contiguous().clone() for k, v in net.state_dict().items()}
    for k, v in tensors.items():
        if not torch.isfinite(v).all():
            raise ValueError(f"save_weights: tensor {k} has non-finite values; {path} not written")
    meta = dict(net.metadata())
    meta.update({str(k): str(v) for k, v in (extra_metadata or {}).items()})
    write_staged("save_weights", path, lambda stage: save_file(tensors, stage, metadata=meta))


#: The largest weights file read: 1 GiB (as the Rust loader, ``recon::prior::network::MAX_WEIGHTS_BYTES``).
MAX_WEIGHTS_BYTES = 1 << 30


def check_weights_file(path: str, what: str, missing: type) -> None:
    """Refuses, before opening it, a weights ``path`` that is not a regular file of at most
    :data:`MAX_WEIGHTS_BYTES`: ``missing`` (an exception class) for a missing file or a folder, naming which, and
    for a FIFO, socket or device (``/dev/zero`` would be read until memory runs out, a FIFO would block) or a
    larger file. ``what`` names the file in the message (``denoiser weights``)."""
    import os
    import stat
    try:
        st = os.stat(path)
    except FileNotFoundError:
        raise missing(f"{what} {path}: no such file") from None
    except OSError as e:
        raise missing(f"{what} {path}: cannot read ({e.strerror})") from None
    if stat.S_ISDIR(st.st_mode):
        kind = IsADirectoryError if missing is FileNotFoundError else missing
        raise kind(f"{what} {path}: is a directory, not a weights file (safetensors)")
    if not stat.S_ISREG(st.st_mode):
        raise missing(f"{what} {path}: is not a regular file (a FIFO, socket or device such as /dev/zero)")
    if st.st_size > MAX_WEIGHTS_BYTES:
        raise missing(f"{what} {path}: {st.st_size} bytes, larger than the {MAX_WEIGHTS_BYTES} bytes (1 GiB) a "
                      "weights file may have")


def load_weights(path, bands: Optional[int] = None) -> SpectralUNet:
    """Loads a ``spectral-unet-v2`` safetensors file into a new :class:`SpectralUNet` (eval mode). Raises
    FileNotFoundError for a missing file, a folder, a FIFO or device, or a file over 1 GiB
    (:func:`check_weights_file`), and ValueError, naming the file and the problem, for a file that is not
    safetensors, has another architecture, band count (when ``bands`` is given), width or latent, misses or has extra
    tensors, has a tensor of the wrong shape, or holds NaN/inf."""
    import os
    from safetensors import safe_open
    path = os.fspath(path)
    check_weights_file(path, "denoiser weights", FileNotFoundError)
    try:
        with safe_open(path, framework="pt") as f:
            meta = f.metadata() or {}
            tensors = {k: f.get_tensor(k) for k in f.keys()}
    except Exception as e:  # safetensors raises its own error types for a bad header or truncated data
        raise ValueError(f"denoiser weights {path}: not a valid safetensors file ({e})") from None
    if meta.get("arch") != ARCH:
        raise ValueError(f"denoiser weights {path}: metadata arch is {meta.get('arch')!r}, expected {ARCH!r}")
    try:
        b, w, lat = int(meta["bands"]), int(meta["width"]), int(meta["latent"])
    except (KeyError, ValueError):
        raise ValueError(f"denoiser weights {path}: metadata bands/width/latent missing or not integers "
                         f"(bands={meta.get('bands')!r}, width={meta.get('width')!r}, "
                         f"latent={meta.get('latent')!r})") from None
    if b < 1 or w < 1 or not 1 <= lat <= b:
        raise ValueError(f"denoiser weights {path}: metadata bands={b}, width={w} must be positive and "
                         f"latent={lat} in 1…bands")
    if max(b, w, lat) > 4096:
        # The native loader's bound; and the network is laid out on the meta device below, so a width the
        # file's tensors do not hold is refused before any memory is allocated (width "99999999" asked
        # torch for 47 GB from a 4 MB file; a held-out battery, round 17).
        raise ValueError(f"denoiser weights {path}: metadata bands={b}, width={w}, latent={lat}: each must be ≤ 4096")
    if bands is not None and b != bands:
        raise ValueError(f"denoiser weights {path}: the network is for {b} bands, the cube has {bands}")
    with torch.device("meta"):
        want = SpectralUNet(bands=b, width=w, latent=lat).state_dict()
    missing, extra = sorted(set(want) - set(tensors)), sorted(set(tensors) - set(want))
    if missing or extra:
        raise ValueError(f"denoiser weights {path}: missing tensors {missing}, unexpected tensors {extra}")
    for k, v in tensors.items():
        if tuple(v.shape) != tuple(want[k].shape):
            raise ValueError(f"denoiser weights {path}: tensor {k} has shape {tuple(v.shape)}, "
                             f"expected {tuple(want[k].shape)} (bands={b}, width={w}, latent={lat})")
        if not torch.isfinite(v).all():
            raise ValueError(f"denoiser weights {path}: tensor {k} has NaN or infinite values")
    stage = meta.get("stage", "gaussian")
    if stage not in STAGES:
        raise ValueError(f"denoiser weights {path}: metadata stage is {stage!r}, expected one of {STAGES}")
    net = SpectralUNet(bands=b, width=w, latent=lat)
    net.load_state_dict({k: v.to(torch.float32) for k, v in tensors.items()})
    net.stage = stage
    return net.eval()
