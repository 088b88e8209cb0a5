"""Round 20 of the held-out battery: reconstruction checked independently (metrics, operators, solvers)."""
import numpy as np
import pytest

import diffcassi


def test_metrics_name_the_wavelength_list_whose_length_disagrees_with_its_cube():
    # Before: "truth: 1280 values for a 16×16×4 cube" (the band count taken from the list, the array blamed).
    t = np.random.default_rng(0).random((16, 16, 5)).astype(np.float32)
    with pytest.raises(ValueError, match=r"truth_wavelengths_nm: 4 wavelengths given for the truth's 5 bands"):
        diffcassi.metrics(t, t, [450, 500, 550, 600], [450, 500, 550, 600, 650])
    e = np.ascontiguousarray(t[..., :4])
    with pytest.raises(ValueError, match=r"estimate_wavelengths_nm: 3 wavelengths given for the estimate's 4 bands"):
        diffcassi.metrics(t, e, [450, 500, 550, 600, 650], [450, 500, 550])
    # Right lengths still evaluate (resampled to the estimate's bands).
    m = diffcassi.metrics(t, e, [450, 500, 550, 600, 650], [450, 500, 550, 600])
    assert m["wavelengths_nm"] == [450, 500, 550, 600]
    assert np.isfinite(m["rmse"])
