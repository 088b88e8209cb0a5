"""Weights files that are not regular files (issue 39): a folder, a FIFO, ``/dev/zero`` and a file over 1 GiB are
refused before they are opened, naming the file and why — by the Rust loader (``diffcassi.denoise(weights=…)``,
``recon::prior::network``) and by the PyTorch loaders (``diffcassi.denoiser.load_weights``,
``diffcassi.unrolled``); ``load_unrolled(path, None)`` is a TypeError naming ``phi`` (it was an AttributeError
after the file was read)."""
import os
import time

import numpy as np
import pytest

import diffcassi

torch = pytest.importorskip("torch", reason="PyTorch not installed (DIFFCASSI_TORCH=skip)")
pytest.importorskip("safetensors.torch", reason="safetensors not installed (scripts/setup.sh installs it)")


@pytest.fixture()
def bad_files(tmp_path):
    """(path, the words its refusal must contain) for a folder, a FIFO, /dev/zero and a sparse 1 GiB + 1 byte file."""
    folder = tmp_path / "weights-folder"
    folder.mkdir()
    fifo = tmp_path / "weights.fifo"
    os.mkfifo(fifo)
    big = tmp_path / "big.safetensors"
    with open(big, "wb") as f:
        f.truncate((1 << 30) + 1)
    return [(str(folder), "is a directory"), (str(fifo), "not a regular file"), ("/dev/zero", "not a regular file"),
            (str(big), "1073741825 bytes")]


def test_rust_denoise_refuses_non_regular_weights(bad_files):
    cube = np.zeros((8, 8, 28), np.float32)
    for path, says in bad_files:
        t = time.monotonic()
        with pytest.raises(diffcassi.DiffcassiError) as e:
            diffcassi.denoise(cube, 0.1, weights=path)
        assert path in str(e.value) and says in str(e.value), str(e.value)
        assert time.monotonic() - t < 10


def test_torch_loaders_refuse_non_regular_weights(bad_files):
    from diffcassi.denoiser import load_weights
    from diffcassi.unrolled import read_metadata
    for path, says in bad_files:
        # A folder is an IsADirectoryError, the others FileNotFoundError: both OSErrors naming the file.
        with pytest.raises((FileNotFoundError, IsADirectoryError), match=says):
            load_weights(path)
        with pytest.raises(diffcassi.DiffcassiFileError, match=says):
            read_metadata(path)


def test_load_unrolled_names_phi(tmp_path):
    from diffcassi.unrolled import load_unrolled
    with pytest.raises(TypeError, match="phi.*NoneType"):
        load_unrolled(tmp_path / "any.safetensors", None)
