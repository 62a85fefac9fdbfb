"""Experiment design (docs/ALGORITHMS.md §3): speeds minimising the Cramér–Rao bound of wear, and the CLI."""

from __future__ import annotations

import json
import math
import subprocess
import sys

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from edge_monitor.features.wear_information import crlb_wear, marginal_fisher_wear
from edge_monitor.offline.experiment_design import DesignError, DesignPoint, batch_crlb_wear, design_speeds

POINT = DesignPoint()


def test_batch_bound_equals_the_scalar_bound():
    rng = np.random.default_rng(3)
    designs = np.sort(rng.uniform(1, 280, size=(20, 3)), axis=1)
    batch = batch_crlb_wear(designs, POINT)
    scalar = [crlb_wear(d, 40.0, 35.0, 0.5, 0.1) for d in designs]
    np.testing.assert_allclose(batch, scalar, rtol=1e-9)
    assert np.isinf(batch_crlb_wear(np.array([[50.0, 50.0]]), POINT))[0]


def test_two_point_design_is_the_global_optimum_of_a_fine_grid():
    result = design_speeds(2)
    g = np.arange(1.0, 280.0 + 1e-9, 0.5)
    a, b = np.meshgrid(g, g, indexing="ij")
    pairs = np.column_stack([a.ravel(), b.ravel()])
    pairs = pairs[pairs[:, 1] - pairs[:, 0] >= 5.0]
    brute = float(np.min(batch_crlb_wear(pairs, POINT)))
    assert result.wear_crlb <= brute * (1 + 1e-9)
    assert result.speeds[1] - result.speeds[0] >= 5.0 - 1e-6


@settings(max_examples=8, deadline=None)
@given(n_points=st.integers(2, 5), speed_max=st.floats(120.0, 300.0), separation=st.floats(0.0, 20.0),
       temperature=st.floats(30.0, 70.0), wear=st.floats(10.0, 60.0))
def test_design_is_feasible_and_beats_random_feasible_designs(n_points, speed_max, separation, temperature, wear):
    result = design_speeds(n_points, temperature=temperature, wear=wear, speed_max=speed_max,
                           min_separation=separation)
    v = np.array(result.speeds)
    assert v.size == n_points and np.all(np.diff(v) >= separation - 1e-6)
    assert v[0] >= 1.0 - 1e-9 and v[-1] <= speed_max + 1e-9
    assert result.wear_crlb == pytest.approx(crlb_wear(v, temperature, wear, 0.5, 0.1), rel=1e-9)
    # 2000 random feasible designs from another seed: none is better.
    rng = np.random.default_rng(99)
    slack = speed_max - 1.0 - (n_points - 1) * separation
    random = 1.0 + np.sort(rng.uniform(0, slack, (2000, n_points)), axis=1) + separation * np.arange(n_points)
    point = DesignPoint(temperature=temperature, wear=wear)
    assert result.wear_crlb <= float(np.min(batch_crlb_wear(random, point))) * (1 + 1e-9)


def test_design_beats_badly_chosen_speeds_and_more_points_help():
    bad = crlb_wear([82.0, 133.0], 40.0, 35.0, 0.5, 0.1)
    bounds = [design_speeds(n).wear_crlb for n in (2, 3, 4)]
    assert bounds[0] < bad / 3  # the design point's bound is several times smaller
    assert bounds[0] > bounds[1] > bounds[2]


def test_single_point_design_minimises_the_marginal_bound():
    result = design_speeds(1)
    assert len(result.speeds) == 1 and 1.0 <= result.speeds[0] <= 280.0
    expected = 1.0 / marginal_fisher_wear(result.speeds[0], 35.0, 0.5, 0.1)
    assert result.wear_crlb == pytest.approx(expected, rel=1e-12)
    # Better than every speed of an independent grid (same seeded Monte Carlo criterion).
    for speed in np.arange(1.0, 280.0, 7.0):
        assert result.wear_crlb <= 1.0 / marginal_fisher_wear(speed, 35.0, 0.5, 0.1) * (1 + 1e-9)


def test_design_is_deterministic():
    assert design_speeds(3, seed=4).speeds == design_speeds(3, seed=4).speeds


@pytest.mark.parametrize("kwargs, field", [
    ({"n_points": 0}, "--points"),
    ({"n_points": 2, "speed_min": 200.0, "speed_max": 100.0}, "--speed-min"),
    ({"n_points": 60, "min_separation": 5.0}, "--min-separation"),
    ({"n_points": 2, "noise_std": 0.0}, "--noise-std"),
    ({"n_points": 2, "temperature": math.nan}, "--temperature"),
])
def test_invalid_settings_are_refused_naming_the_option(kwargs, field):
    with pytest.raises(DesignError, match=field):
        design_speeds(**kwargs)


def run_cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "edge_monitor.cli", "design", *args],
                          capture_output=True, text=True, timeout=120)


def test_cli_json_and_out_file(tmp_path):
    out = tmp_path / "design.json"
    proc = run_cli("--points", "2", "--temperature", "45", "--json", "--out", str(out))
    assert proc.returncode == 0, proc.stderr
    printed = json.loads(proc.stdout)
    assert printed == json.loads(out.read_text())
    assert {"speeds", "wear_crlb", "wear_std", "design_point"} <= set(printed)
    expected = design_speeds(2, temperature=45.0)
    assert printed["speeds"] == pytest.approx(expected.speeds, abs=1e-6)
    assert printed["wear_crlb"] == pytest.approx(expected.wear_crlb, rel=1e-9)
    assert printed["wear_std"] == pytest.approx(math.sqrt(expected.wear_crlb), rel=1e-9)
    assert printed["design_point"]["temperature"] == 45.0


def test_cli_refuses_infeasible_separation():
    proc = run_cli("--points", "10", "--speed-min", "1", "--speed-max", "20", "--min-separation", "5", "--json")
    assert proc.returncode == 2
    assert "--min-separation" in proc.stderr and proc.stdout == ""


def test_simulator_reads_the_design_file(tmp_path):
    """The file of ``design --out`` is what ``sim-controller --speeds-from`` loads."""
    config = pytest.importorskip("sim_controller.config", reason="simulator not present in this tree")
    out = tmp_path / "design.json"
    proc = run_cli("--points", "3", "--out", str(out))
    assert proc.returncode == 0, proc.stderr
    assert list(config.load_speeds_file(out)) == pytest.approx(design_speeds(3).speeds, abs=1e-6)
