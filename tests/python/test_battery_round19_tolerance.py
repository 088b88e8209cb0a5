"""Round 19 of the held-out battery (3 Dec 2026): ``render(tolerance_um=...)`` checked the ray budget at the
default 20 rays per pixel and plane — which the tolerance replaces — before it chose its rays, refusing renders
whose choice fits (the CLI's ``--tolerance-um`` did the same; both now check the fewest rays a tolerance may
choose first, then its choice)."""
import numpy as np
import pytest

import diffcassi

from conftest import random_cube

WL = np.linspace(450, 650, 28)


@pytest.fixture
def default_limits():
    yield
    diffcassi.set_limits()


def test_a_tolerance_is_checked_at_the_rays_it_chooses(tmp_path, default_limits):
    ap = diffcassi.System.preset("ap")
    n, planes = 32, 4
    cube = random_cube(n, n, len(WL), seed=3)
    # 32 × 32 × 4 planes × 1 ray = 4096 rays: the choice at 30 µm (the default 20 rays would be 81 920).
    diffcassi.set_limits(max_rays=4096)
    acq, info = diffcassi.render(ap, cube, WL, planes=planes, tolerance_um=30.0, calibration_cache=str(tmp_path / "c"))
    assert info["rays_per_pixel"] == 1 and np.isfinite(acq).all() and acq.sum() > 0
    diffcassi.set_limits(max_rays=4095)
    with pytest.raises(diffcassi.DiffcassiValueError, match="4096 rays to trace, over the budget of 4095"):
        diffcassi.render(ap, cube, WL, planes=planes, tolerance_um=30.0, calibration_cache=str(tmp_path / "c"))
