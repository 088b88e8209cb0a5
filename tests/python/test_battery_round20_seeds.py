"""Held-out battery, round 20 (prober C, finding 3): a seed ≥ 2⁶⁴ was refused with `seed: expected an integer
≥ 0 or None, got int 18446744073709551616` — a message that refuses a value it says is allowed. Every seed
refusal (the render keywords `seed`, `mask_seed`, `noise_seed` of `render`, `Transport`, `exact`,
`mapping_operator`; `study`'s; `CassiRenderer`'s) now states the range `0..=18446744073709551615`, as
`synthetic_scene` did (one description in the bindings, `arrays::SEED`)."""
import numpy as np
import pytest

import diffcassi

RANGE = "0..=18446744073709551615"


@pytest.fixture(scope="module")
def sp():
    return diffcassi.System.preset("sp")


@pytest.fixture(scope="module")
def scene():
    return diffcassi.synthetic_scene(8, 8, 0)


def refused(f, name, value):
    with pytest.raises(diffcassi.DiffcassiValueError) as e:
        f()
    msg = str(e.value)
    assert f"{name}: expected an integer in {RANGE}" in msg, msg
    assert "≥ 0" not in msg, msg
    assert str(value) in msg, msg


@pytest.mark.parametrize("value", [2**64, 2**70, -1])
def test_render_seed_keywords_state_the_range(sp, scene, value):
    cube, wl = scene
    small = dict(rays=1, planes=28)
    refused(lambda: diffcassi.render(sp, cube, wl, seed=value, **small), "seed", value)
    refused(lambda: diffcassi.render(sp, cube, wl, mask_seed=value, **small), "mask_seed", value)
    refused(lambda: diffcassi.render(sp, cube, wl, noise={"noise": "shot", "noise_seed": value}, **small), "noise_seed", value)
    refused(lambda: diffcassi.Transport(sp, 8, 8, seed=value, **small), "seed", value)
    refused(lambda: diffcassi.exact(sp, 8, 8, seed=value, **small), "seed", value)
    refused(lambda: diffcassi.mapping_operator(sp, 8, 8, seed=value, **small), "seed", value)


@pytest.mark.parametrize("value", [2**64, -1])
def test_cassi_renderer_and_study_seeds_state_the_range(sp, tmp_path, value):
    torch_mod = pytest.importorskip("diffcassi.torch")
    refused(lambda: torch_mod.CassiRenderer(sp, 8, 8, ["prism_tilt_x"], seed=value), "seed", value)
    refused(lambda: torch_mod.CassiRenderer(sp, 8, 8, ["prism_tilt_x"], mask_seed=value), "mask_seed", value)
    for key in ["seed", "mask_seed", "equivariant_seed"]:
        refused(lambda: diffcassi.study(tmp_path / "st", **{key: value}), key, value)
    assert not (tmp_path / "st").exists()


def test_the_range_is_the_one_synthetic_scene_states_and_its_ends_are_accepted(sp, scene):
    with pytest.raises(diffcassi.DiffcassiValueError) as e:
        diffcassi.synthetic_scene(4, 4, 2**64)
    assert f"expected an integer in {RANGE}" in str(e.value)
    cube, wl = scene
    top = diffcassi.render(sp, cube, wl, seed=2**64 - 1, mask_seed=np.uint64(2**64 - 1), rays=1, planes=28)[1]
    assert top["seed"] == 2**64 - 1


@pytest.mark.parametrize("value", [2**64, 2**70, 0])
def test_count_keywords_state_their_range(sp, scene, value):
    # The same contradiction for counts: `rays=2**70` said "expected an integer ≥ 1" (a usize: 1..=2⁶⁴ − 1).
    # (0 passes the type and is refused by the library's own check, naming the keyword.)
    cube, wl = scene
    for kw in ("rays", "planes"):
        args = dict(rays=1, planes=28)
        args[kw] = value
        with pytest.raises(diffcassi.DiffcassiValueError) as e:
            diffcassi.render(sp, cube, wl, **args)
        msg = str(e.value)
        assert kw in msg, msg
        if value > 0:
            assert f"{kw}: expected an integer in 1..=18446744073709551615" in msg, msg
