"""Round 16 of the held-out battery (2 Dec 2026): what its probers found in Python's rendering and
reconstruction (docs/robustness.md, "round 16"); the Rust side is tests/bad_input_round16.rs, the torch
modules' tests/python/test_battery_round16_torch.py."""
import warnings

import numpy as np
import pytest

import diffcassi


def _scene(n=16, bands=4):
    wl = list(np.linspace(450.0, 650.0, bands))
    return diffcassi.synthetic_scene(n, n, 0, wl)[0], wl


def test_a_read_noise_acquisition_summing_below_zero_is_not_called_zero():
    """The zero-acquisition warning tested the total: read noise summing to ≤ 0 with every pixel lit was
    warned "zero everywhere"."""
    sp = diffcassi.System.preset("sp")
    cube, wl = _scene()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        y, info = diffcassi.render(sp, cube, wl, planes=8, rays=2,
                                   noise={"noise": "read", "electrons_per_unit": 10, "read_noise_e": 1000, "noise_seed": 0})
    assert float(np.sum(y, dtype=np.float64)) <= 0.0, "the case needs a total ≤ 0"
    assert np.all(y != 0)
    assert not [w for w in caught if "zero everywhere" in str(w.message)]


def test_an_adc_step_beyond_what_an_acquisition_holds_is_refused():
    """An exposure of 1e-150 e⁻ per unit with the ADC on rendered zeros whose noise norm δ was infinite."""
    sp = diffcassi.System.preset("sp")
    cube, wl = _scene()
    with pytest.raises(diffcassi.DiffcassiValueError, match="one ADC step"):
        diffcassi.render(sp, cube, wl, planes=8, rays=2,
                         noise={"noise": "shot,adc", "adc_bits": 8, "full_well_e": 1e9, "electrons_per_unit": 1e-150})


def test_pnp_of_a_zero_acquisition_is_zero_and_a_diverged_solve_warns():
    """PnP made ±0.01 from a zero acquisition (the network's biases at the fallback scale); an acquisition
    the operator cannot produce diverged in silence."""
    sp = diffcassi.System.preset("sp")
    cube, wl = _scene()
    op = diffcassi.shift_operator(sp, 16, 16, bands_nm=wl)
    zero = np.zeros(op.image_shape, np.float32)
    x, rec = diffcassi.reconstruct(op, zero, "pnp-gap")
    assert np.all(x == 0)
    ex = diffcassi.exact(sp, 16, 16, bands_nm=wl, planes=8, rays=2, seed=1)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        x, rec = diffcassi.reconstruct(ex, np.ones(ex.image_shape, np.float32), "gap-tv", iterations=30)
    if rec["final_residual"] > 1.0:
        assert any("worse than a zero cube" in str(c.message) for c in caught), [str(c.message) for c in caught]
        assert any("worse than a zero cube" in s for s in rec["stopping"]["warnings"])
    # An ordinary acquisition: no warning.
    y, _ = diffcassi.render(sp, cube, wl, planes=8, rays=2, bands_nm=wl)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        x, rec = diffcassi.reconstruct(ex, y, "gap-tv", iterations=10)
    assert rec["stopping"]["warnings"] == []
    assert not [c for c in caught if "reconstruct:" in str(c.message)]
