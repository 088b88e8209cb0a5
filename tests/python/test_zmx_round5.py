"""What a held-out battery found in the Python layer of the .zmx reader (round 5; docs/robustness.md):
`System.from_file` said "no such file" for a named pipe, /dev/zero and /dev/null (it now names what they are,
at once, through the library's input check), and `first_order()` gave an afocal system's EFL as -inf (now None:
the output policy allows no inf)."""
import os
import pathlib

import pytest

import diffcassi

FIXTURES = pathlib.Path(__file__).resolve().parents[1] / "fixtures" / "zmx"


def test_from_file_names_a_fifo_and_a_device(tmp_path):
    fifo = tmp_path / "fifo.zmx"
    os.mkfifo(fifo)
    with pytest.raises(diffcassi.DiffcassiFileError, match=r"fifo.zmx.*named pipe \(FIFO\)"):
        diffcassi.System.from_file(fifo)
    for dev in ["/dev/zero", "/dev/null"]:
        with pytest.raises(diffcassi.DiffcassiFileError, match=f"{dev}.*character device"):
            diffcassi.System.from_file(dev)
    with pytest.raises(diffcassi.DiffcassiFileError, match="no such file"):
        diffcassi.System.from_file(tmp_path / "missing.zmx")


def test_afocal_first_order_is_none_not_inf():
    s = diffcassi.System.from_file(FIXTURES / "grating_flat_transmission_optiland.zmx")
    fo = s.first_order()
    assert fo["efl_mm"] is None
    assert all(v is None or (isinstance(v, float) and abs(v) < float("inf")) for v in fo.values()), fo
    focal = diffcassi.System.from_file(FIXTURES / "asphere_thorlabs_ACL3026U.zmx").first_order()
    assert isinstance(focal["efl_mm"], float)
