"""Held-out battery, round 19 (prober B, finding 3): a wavelength given to `diffcassi.trace` outside a glass's
catalogue range, on a system read from a `.zmx` file, named the spec's `wavelength_policy` and a Rust enum
(`WavelengthPolicy::AllowExtrapolation`) instead of the file's own fix, the record `DCWP allow_extrapolation`,
which the docs promise and the load already named. The system now keeps where it came from
(`diffcassi::system::SystemOrigin`) and every later error names that file's fix."""
import numpy as np
import pytest

import diffcassi

SELLMEIER = "1.03961212 6.00069867E-03 2.31792344E-01 2.00179144E-02 1.01046945 103.560653"
ZMX = """VERS 190513 80 123457 L123457
MODE SEQ
NAME plate
UNIT MM X W X CM MR CPMM
ENPD 10
ENVD 20 1 0
GCAT ALLF
FTYP 0 0 1 1 0 0 0
XFLN 0
YFLN 0
WAVM 1 0.5875618 1
PWAV 1
SURF 0
  TYPE STANDARD
  CURV 0.0
  DISZ INFINITY
SURF 1
  STOP
  TYPE STANDARD
  CURV 0
  DISZ 10
  GLAS F2 0 0 1.5 60
SURF 2
  TYPE STANDARD
  CURV 0
  DISZ 5
SURF 3
  TYPE STANDARD
  CURV 0
  DISZ 0
"""


def write(folder, name):
    (folder / "ALLF.AGF").write_text(f"NM F2 2 0 1.5168 64.17 0 1\nCD {SELLMEIER}\nLD 0.35 2.0\n")
    (folder / name).write_text(ZMX)
    return folder / name


def trace_at(system, nm):
    return diffcassi.trace(system, np.zeros((1, 3)), np.array([[0.0, 0.0, 1.0]]), np.array([nm]))


def test_a_trace_wavelength_outside_a_glass_range_names_the_zmx_record(tmp_path):
    system = diffcassi.System.from_file(str(write(tmp_path, "plate.zmx")))
    trace_at(system, 350.0)
    with pytest.raises(ValueError) as e:
        trace_at(system, 349.99)
    msg = str(e.value)
    assert "349.99 nm" in msg and "glass F2" in msg and "`DCWP allow_extrapolation`" in msg, msg
    assert "wavelength_policy" not in msg and "WavelengthPolicy" not in msg, msg


def test_the_same_system_as_a_spec_names_the_spec_field(tmp_path):
    zmx = diffcassi.System.from_file(str(write(tmp_path, "PLATE.ZMX")))
    spec = diffcassi.System.from_string(zmx.to_toml(), "toml")
    with pytest.raises(ValueError, match="wavelength_policy"):
        trace_at(spec, 349.99)
