"""Disturbance-rejecting weights and the ``edge-monitor fit-weights`` command."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from edge_monitor.commands.fit_weights import CycleModel, fit, simulate_cycles
from edge_monitor.features.disturbance_weights import (
    DEFAULT_ALPHA,
    DEFAULT_BETA,
    WeightFitError,
    WeightFunction,
    fit_index_weights,
    fit_weight_function,
)


def test_weight_function_shape() -> None:
    w = WeightFunction()
    v = np.array([-300.0, -28.0, 0.0, 28.0, 300.0, 1e6])
    values = w(v)       # cosh overflows at 1e6·β to inf: the limit 0, no NaN
    assert values[2] == 0.0 and values[-1] == 0.0
    assert values[0] == values[-2] and values[1] == values[3]          # even in v (uses |v|)
    assert np.all((values >= 0) & (values < 1))
    expected = np.tanh(DEFAULT_ALPHA * 28.0) / np.cosh(DEFAULT_BETA * 28.0)
    assert values[3] == pytest.approx(expected)
    # the published weights emphasise low-to-intermediate speeds
    assert w(28.0) > w(2.0) and w(28.0) > w(150.0)


def test_weight_function_rejects_bad_parameters() -> None:
    with pytest.raises(ValueError, match="alpha"):
        WeightFunction(alpha=-1.0)
    with pytest.raises(ValueError, match="beta"):
        WeightFunction(beta=float("nan"))


def test_index_weights_are_mean_change_over_variance() -> None:
    rng = np.random.default_rng(1)
    n = 4000
    change = np.array([0.0, 1.0, 1.0, -2.0])
    std = np.array([1.0, 1.0, 2.0, 1.0])
    healthy = rng.normal(0.0, std, (n, 4))
    faulty = rng.normal(change, std, (n, 4))
    w = fit_index_weights(healthy, faulty)
    expected = change / (2 * std**2)
    expected /= np.abs(expected).max()
    # standard error of each estimated ratio is below 0.03 for n = 4000 per class; 0.1 is > 3 SE
    np.testing.assert_allclose(w, expected, atol=0.1)
    assert np.abs(w).max() == pytest.approx(1.0)


def test_index_weights_reject_unusable_batches() -> None:
    with pytest.raises(WeightFitError, match="n_elements"):
        fit_index_weights(np.zeros((5, 3)), np.zeros((5, 4)))
    with pytest.raises(WeightFitError, match=">= 2 batches"):
        fit_index_weights(np.zeros((1, 3)), np.zeros((5, 3)))
    with pytest.raises(WeightFitError, match="no mean change"):
        fit_index_weights(np.ones((4, 3)), np.ones((4, 3)))


@settings(max_examples=8, deadline=None)
@given(alpha=st.floats(3e-3, 5e-2), ratio=st.floats(1.5, 6.0), scale=st.floats(0.1, 10.0))
def test_fit_weight_function_recovers_the_generating_function(alpha: float, ratio: float, scale: float) -> None:
    beta = alpha * ratio
    v = np.concatenate([np.linspace(1, 300, 200), -np.linspace(1, 300, 200)])
    # odd index weights (negative at negative speed, as a wear change of odd friction) with any scale
    w = scale * np.sign(v) * WeightFunction(alpha, beta)(v)
    a_hat, b_hat = fit_weight_function(v, w)
    # noiseless data: the fitted shape must reproduce the generating one. (α itself is not always
    # identifiable: when β·v_peak is large, tanh(α·v) ≈ α·v over the support and α merges with c.)
    truth = WeightFunction(alpha, beta)(v)
    fitted = WeightFunction(a_hat, b_hat)(v)
    c = np.dot(fitted, truth) / np.dot(fitted, fitted)
    assert np.max(np.abs(c * fitted - truth)) < 1e-3 * truth.max()
    if beta * 300 < 5:     # slow decay over the speed range: both parameters are determined
        assert a_hat == pytest.approx(alpha, rel=1e-2) and b_hat == pytest.approx(beta, rel=1e-2)


@pytest.mark.slow
def test_fitted_weights_on_simulated_runs_emphasise_low_to_intermediate_speeds() -> None:
    rng = np.random.default_rng(2)
    healthy, speed, _ = simulate_cycles(60, 0.0, (30.0, 70.0), rng)
    faulty, _, _ = simulate_cycles(60, 35.0, (30.0, 70.0), rng)
    alpha, beta = fit_weight_function(speed, fit_index_weights(healthy, faulty))
    w = WeightFunction(alpha, beta)
    peak_speed = np.linspace(1, 300, 3000)[np.argmax(w(np.linspace(1, 300, 3000)))]
    # wear shows first at 0 … 150 rad/s (docs/ALGORITHMS.md §1); the weight must peak there and be
    # small at the top speed, where temperature moves the viscous slope and wear hardly acts
    assert 10.0 < peak_speed < 150.0
    assert w(287.1) < 0.25 * w(peak_speed)


def test_cycle_model_profile() -> None:
    model = CycleModel()
    speed, level = model.speed_profile()
    plateau = int(model.plateau_s * model.rate_hz)
    for k, v in enumerate(model.levels):
        in_level = speed[level == k]
        assert np.count_nonzero(in_level == v) >= plateau      # + the ramp's end sample
        assert np.count_nonzero(in_level == -v) >= plateau
        assert np.all(np.abs(in_level) <= v)


def _cli(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "edge_monitor.cli", "fit-weights", *args],
                          capture_output=True, text=True, timeout=300)


@pytest.mark.slow
def test_cli_fits_from_simulation_and_from_the_written_csv_files(tmp_path: Path) -> None:
    out_sim = tmp_path / "weights_sim.json"
    done = _cli("--simulate", "--cycles", "4", "--seed", "3", "--write-csv", str(tmp_path), "-o", str(out_sim))
    assert done.returncode == 0, done.stderr
    sim = json.loads(out_sim.read_text())
    assert {"alpha", "beta", "index_weights", "speeds"} <= set(sim)
    assert (tmp_path / "healthy.csv").exists() and (tmp_path / "faulty.csv").exists()

    done = _cli("--healthy", str(tmp_path / "healthy.csv"), "--faulty", str(tmp_path / "faulty.csv"))
    assert done.returncode == 0, done.stderr
    from_csv = json.loads(done.stdout)
    # the CSV keeps torque to 1e-6 (noise std 2e-3): the fit must agree closely with the in-memory one
    assert from_csv["alpha"] == pytest.approx(sim["alpha"], rel=0.02)
    assert from_csv["beta"] == pytest.approx(sim["beta"], rel=0.02)
    assert len(from_csv["index_weights"]) == len(sim["index_weights"])


@pytest.mark.slow
def test_cli_reports_bad_input_with_exit_code_2(tmp_path: Path) -> None:
    done = _cli()
    assert done.returncode == 2 and "--healthy" in done.stderr
    bad = tmp_path / "bad.csv"
    bad.write_text("cycle,torque\n0,0.1\n")
    done = _cli("--healthy", str(bad), "--faulty", str(bad))
    assert done.returncode == 2 and "missing column" in done.stderr


def test_centred_fit_ignores_a_per_cycle_load() -> None:
    """fit(center=True) works on τ_t − m_t, which a per-cycle constant leaves unchanged (up to
    round-off): the fitted α, β with and without a load spread U(0.3, 0.7) agree to 1e-6."""
    rng = np.random.default_rng(4)
    healthy, speed, _ = simulate_cycles(20, 0.0, (30.0, 70.0), rng)
    faulty, _, _ = simulate_cycles(20, 35.0, (30.0, 70.0), rng)
    loads = rng.uniform(0.3, 0.7, size=(2, 20, 1))
    plain = fit(healthy, faulty, speed)
    loaded = fit(healthy + loads[0], faulty + loads[1], speed)
    assert plain["center"] is True
    assert loaded["alpha"] == pytest.approx(plain["alpha"], rel=1e-6)
    assert loaded["beta"] == pytest.approx(plain["beta"], rel=1e-6)
    # uncentred, the load spread dominates the per-sample variance and changes the fit
    uncentred = fit(healthy + loads[0], faulty + loads[1], speed, center=False)
    assert uncentred["center"] is False
    assert uncentred["alpha"] != pytest.approx(plain["alpha"], rel=1e-3) or \
        uncentred["beta"] != pytest.approx(plain["beta"], rel=1e-3)
