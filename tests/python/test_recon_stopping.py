"""The discrepancy stop from Python (issue 22 item 3): ``diffcassi.reconstruct`` takes τ (``discrepancy``) and δ
(``noise_norm``) as ``diffcassi reconstruct`` does, stops where ‖y − Φθ‖₂ ≤ τδ and records ``stopping`` as
``reconstruct.json`` does; ``monte_carlo_noise_norm`` is the CLI's Monte-Carlo term of δ."""
import numpy as np
import pytest

import diffcassi


def problem(seed=3, noise=0.02):
    sp = diffcassi.System.preset("sp")
    settings = dict(bands_nm=list(np.linspace(450, 650, 6)), planes=6, rays=1)
    rng = np.random.default_rng(seed)
    truth = np.clip(0.5 + 0.2 * rng.standard_normal((16, 16, 6)), 0, 1).astype(np.float32)
    op = diffcassi.shift_operator(sp, 16, 16, **settings)
    clean = op.apply(truth)
    n = (noise * np.abs(clean).max() * rng.standard_normal(clean.shape)).astype(np.float32)
    return op, clean + n, float(np.linalg.norm(n.astype(np.float64)))


def test_discrepancy_stops_gap_tv_and_records_it():
    op, y, delta = problem()
    cube, rec = diffcassi.reconstruct(op, y, "gap-tv", iterations=200, discrepancy=1.0, noise_norm=delta)
    st = rec["stopping"]
    assert st["stopped_by"] == "discrepancy", st
    assert st["iterations_run"] == rec["iterations_run"] < 200
    assert st["discrepancy_tau"] == 1.0 and st["noise_norm"] == pytest.approx(delta)
    assert st["iteration_cap"] == 200
    assert st["discrepancy_threshold_relative"] == pytest.approx(delta / np.linalg.norm(y.astype(np.float64)), rel=1e-6)
    # The returned cube meets the rule; the one before it did not.
    r = np.linalg.norm((y - op.apply(cube)).astype(np.float64))
    assert r <= delta * (1 + 1e-5)
    assert rec["residuals"][-1] * np.linalg.norm(y.astype(np.float64)) > delta
    # Without δ the rule is off: the cap ends the run.
    _, off = diffcassi.reconstruct(op, y, "gap-tv", iterations=30)
    assert off["stopping"]["stopped_by"] == "iterations" and off["stopping"]["noise_norm"] == 0.0


def test_pnp_records_its_tv_phase_and_stop():
    sp = diffcassi.System.preset("sp")
    op = diffcassi.shift_operator(sp, 16, 16, bands_nm=list(np.linspace(450, 650, 28)), planes=28, rays=1)
    rng = np.random.default_rng(5)
    truth = np.clip(0.5 + 0.1 * rng.standard_normal((16, 16, 28)), 0, 1).astype(np.float32)
    y28 = op.apply(truth)
    # δ huge: the TV phase hands over after its first iteration, the network runs its 4 iterations.
    cube, rec = diffcassi.reconstruct(op, y28, "pnp-gap", iterations=10, tv_warmup=6, discrepancy=0.0, noise_norm=1e9, tolerance=0.0)
    st = rec["stopping"]
    assert st["tv_phase_iterations"] == 1 and st["iterations_run"] == 5 and st["stopped_by"] == "iterations"
    assert np.isfinite(cube).all()


def test_bad_stopping_settings_are_clear_errors():
    op, y, _ = problem()
    for k, v in (("discrepancy", -1.0), ("noise_norm", float("nan"))):
        with pytest.raises(diffcassi.DiffcassiError, match="stopping rule"):
            diffcassi.reconstruct(op, y, "gap-tv", **{k: v})
    with pytest.raises(diffcassi.DiffcassiValueError, match="planes_per_band"):
        diffcassi.monte_carlo_noise_norm(y, 20, 20, float("nan"))
    # Ray counts are integers ≥ 1 (1.5 was truncated to 1; −1 and 2**70 were bare OverflowErrors), and an
    # empty acquisition is refused (its norm was −0.0): a held-out battery.
    for bad in (1.5, -1, 0, 2 ** 70, float("nan"), True):
        with pytest.raises(diffcassi.DiffcassiValueError, match="acquisition_rays: expected an integer ≥ 1"):
            diffcassi.spread_noise_factor(bad, 1)
        with pytest.raises(diffcassi.DiffcassiValueError, match="operator_rays: expected an integer ≥ 1"):
            diffcassi.monte_carlo_noise_norm(y, 2, bad, 1.0)
    assert diffcassi.spread_noise_factor(np.int64(4), 4) == diffcassi.spread_noise_factor(4, 4)
    with pytest.raises(diffcassi.DiffcassiValueError, match="empty"):
        diffcassi.monte_carlo_noise_norm(np.ones((0, 2), np.float32), 2, 2, 1.0)


def test_monte_carlo_noise_norm_is_the_cli_model():
    y = np.full((4, 5), 2.0, np.float32)
    assert diffcassi.monte_carlo_noise_norm(y, 20, 20, 4.0) == pytest.approx(0.062 * np.sqrt((1 / 20 + 1 / 20) / 4) * np.sqrt(20 * 4.0))


def test_spread_estimate_from_python_stops_and_records_it():
    """δ from the data (the CLI's default): the exact operator's twin (another seed) re-estimates δ during
    the run; the rule stops where ‖y − Φθ‖ ≤ τδ̂ and the record says so; bad twin settings → errors."""
    sp = diffcassi.System.preset("sp")
    small = dict(bands_nm=[480.0, 530.0, 580.0, 630.0], planes=8, rays=4)
    x, _ = diffcassi.synthetic_scene(12, 12, seed=5, wavelengths_nm=small["bands_nm"])
    y = diffcassi.exact(sp, 12, 12, seed=1, **small).apply(x)
    op = diffcassi.exact(sp, 12, 12, seed=2, **small)
    twin = diffcassi.exact(sp, 12, 12, seed=3, **small)
    cube, rec = diffcassi.reconstruct(op, y, "gap-tv", iterations=150, tv_weight=0.02, discrepancy=1.0, noise_twin=twin,
                                      noise_factor=diffcassi.spread_noise_factor(4, 4))
    st = rec["stopping"]
    assert st["noise_estimator"] == "monte-carlo-spread" and st["stopped_by"] == "discrepancy", st
    per = st["noise_norm_per_estimate"]
    assert per[0][0] == 2 and all(b[0] - a[0] == 5 for a, b in zip(per, per[1:]))
    assert st["noise_norm"] == per[-1][1] > 0
    r = np.linalg.norm((y - op.apply(cube)).astype(np.float64))
    assert r <= per[-1][1] * (1 + 1e-5)
    # δ̂ tracks the truth residual ‖y − Φ_o x‖ (noiseless y: the Monte-Carlo mismatch alone).
    truth = np.linalg.norm((y - op.apply(x)).astype(np.float64))
    assert 0.5 * truth < per[-1][1] < 2 * truth
    assert diffcassi.spread_noise_factor(20, 20) == 1.0
    assert diffcassi.spread_noise_factor(20, 60) == pytest.approx(np.sqrt(2.0))
    with pytest.raises(diffcassi.DiffcassiValueError, match="noise_factor"):
        diffcassi.reconstruct(op, y, "gap-tv", iterations=3, noise_factor=1.0)
    with pytest.raises(diffcassi.DiffcassiError, match="other shapes"):
        diffcassi.reconstruct(op, y, "gap-tv", iterations=3, noise_twin=diffcassi.exact(sp, 10, 10, seed=3, **small))
    with pytest.raises(diffcassi.DiffcassiError, match="factor"):
        diffcassi.reconstruct(op, y, "gap-tv", iterations=3, noise_twin=twin, noise_factor=float("nan"))
    with pytest.raises(diffcassi.DiffcassiValueError, match="noise_twin"):
        diffcassi.reconstruct(op, y, "gap-tv", iterations=3, noise_twin="twin")
