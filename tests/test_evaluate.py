"""``edge-monitor evaluate`` (docs/EVALUATION.md): designs, surrogate models, SNR and scope, the §7
baselines, the simulator's payload mass error, bad input refused, and one small end-to-end run."""

from __future__ import annotations

import json
import logging
import math
import os
import signal
import subprocess
import sys
import time
import warnings
from pathlib import Path

import numpy as np
import pytest

from edge_monitor.cli import build_parser, main
from edge_monitor.commands.evaluate import _settings
from edge_monitor.offline.baselines import (
    BaselineError,
    data_likelihood,
    distribution_peak,
    fit_speed_only_nominal,
    speed_only_parameters,
)
from edge_monitor.offline.evaluation.design import (
    DesignError,
    central_composite,
    check_estimable,
    fractional_factorial,
    quadratic_matrix,
    quadratic_terms,
    resolution,
    validation_design,
)
from edge_monitor.offline.evaluation.factors import FACTORS, select_factors, sim_settings
from edge_monitor.offline.evaluation.runner import replication
from edge_monitor.offline.evaluation.scope import scope_matrix, snr
from edge_monitor.offline.evaluation.surrogate import Surrogate, fit_surrogate, validation_fit
from sim_controller.config import SimConfig, SimConfigError
from sim_controller.cycle_mode import cycle_signals

ROOT = Path(__file__).resolve().parents[1]

# ---------------------------------------------------------------------------------------------- design


def test_central_composite_has_45_runs_for_6_factors():
    d = central_composite(6)
    assert d.shape == (45, 6)
    factorial = d[np.all(np.abs(d) == 1, axis=1)]
    centre = d[np.all(d == 0, axis=1)]
    stars = d[(np.count_nonzero(d, axis=1) == 1)]
    assert len(factorial) == 32 and len(centre) == 1 and len(stars) == 12
    assert set(np.abs(stars).sum(axis=1)) == {2.0}
    assert central_composite(5).shape == (27, 5) and central_composite(3).shape == (11, 3)
    assert central_composite(4).shape == (25, 4)       # the 2^(4−1) fraction aliases interactions in pairs
    for n in range(2, 7):
        check_estimable(central_composite(n))


@pytest.mark.parametrize("n", [3, 4, 5, 6])
def test_half_fraction_has_resolution_n(n):
    f = fractional_factorial(n)
    assert f.shape == (2 ** (n - 1), n)
    assert resolution(f) == n
    assert len({tuple(r) for r in f}) == len(f)


def test_resolution_vi_keeps_main_effects_and_interactions_orthogonal():
    phi = quadratic_matrix(fractional_factorial(6))[:, 1:1 + 6 + 15]       # main effects and products
    gram = phi.T @ phi
    assert np.allclose(gram, np.diag(np.diag(gram)))


def test_coded_and_natural_levels_map_linearly():
    t = FACTORS["temperature"]
    assert t.natural(-2) == pytest.approx(30.0) and t.natural(2) == pytest.approx(70.0)
    assert t.natural(0) == pytest.approx(50.0) and t.unit_step == pytest.approx(10.0)
    x = np.linspace(-2, 2, 9)
    assert np.allclose(t.coded(t.natural(x)), x)
    assert FACTORS["p2p_delay"].natural(1) == pytest.approx(62.5)
    custom = select_factors(["wear", "temperature"], {"temperature": (40.0, 60.0)})
    assert custom[1].natural(2) == pytest.approx(60.0)


def test_sim_settings_fix_every_factor_for_the_point():
    factors = select_factors(["wear", "wear_other", "temperature", "p2p_delay", "payload_error"])
    s = sim_settings(factors, [2, -2, 1, -1, 2], joint=1, joints=3)
    assert [w.initial for w in s["wear"]] == [0.0, 50.0, 0.0]
    assert s["temperature_range"] == (60.0, 60.0)
    assert s["p2p_delay"] == pytest.approx((0.0375, 0.0375))
    assert s["payload_error"] == pytest.approx(0.10)
    assert "load_range" not in s                       # load keeps the simulator's per-cycle draw
    held = sim_settings(select_factors(["wear", "load"]), [0, 2], joint=0, joints=2)
    assert held["temperature_range"] == (50.0, 50.0) and held["load_range"] == (0.7, 0.7)
    assert [w.initial for w in held["wear"]] == [25.0, 25.0]
    SimConfig(joints=3, **s)                           # valid simulator settings


def test_validation_design_uses_other_levels_evenly():
    v = validation_design(5, 12, seed=3)
    assert v.shape == (12, 5)
    for col in v.T:
        values, counts = np.unique(col, return_counts=True)
        assert list(values) == [-1.5, -0.5, 0.5, 1.5] and set(counts) == {3}


def test_a_design_too_small_for_the_surrogate_is_refused():
    with pytest.raises(DesignError, match="10 coefficients"):
        check_estimable(fractional_factorial(3))
    with pytest.raises(DesignError, match="rank"):
        check_estimable(np.vstack([fractional_factorial(3)] * 3))
    check_estimable(central_composite(3))

# ---------------------------------------------------------------------------------------------- surrogate


def _quadratic(n: int, seed: int = 0) -> tuple[np.ndarray, list[str]]:
    rng = np.random.default_rng(seed)
    names = [f"x{i}" for i in range(n)]
    return rng.normal(size=len(quadratic_terms(names))), names


@pytest.mark.parametrize("n", [3, 4, 6])
def test_surrogate_recovers_a_quadratic_exactly(n):
    theta, names = _quadratic(n)
    design = central_composite(n)
    model = fit_surrogate(design, quadratic_matrix(design) @ theta, names)
    assert np.allclose(model.theta, theta, atol=1e-10)
    assert model.gamma == pytest.approx(0.0, abs=1e-20)
    val = validation_design(n, 8, seed=1)
    assert validation_fit(model, val, quadratic_matrix(val) @ theta) == pytest.approx(100.0)
    assert model.terms[:2] == ("1", "x0") and "x0*x1" in model.terms and f"x{n - 1}^2" in model.terms


def test_validation_fit_drops_when_the_model_misses_structure():
    names = ["f", "d"]
    design = central_composite(2)
    model = fit_surrogate(design, design[:, 0] + 0.5 * design[:, 1], names)
    val = validation_design(2, 8, seed=2)
    good = validation_fit(model, val, val[:, 0] + 0.5 * val[:, 1])
    bad = validation_fit(model, val, val[:, 0] + 0.5 * val[:, 1] + np.sin(5 * val[:, 1]))
    assert good == pytest.approx(100.0) and bad < 90.0


def test_normalised_coefficients_and_influence():
    names = ["f", "d"]
    design = central_composite(2)
    q = 2.0 * design[:, 0] + 3.0 * design[:, 1] - 1.0 * design[:, 1] ** 2
    model = fit_surrogate(design, q, names)
    assert model.normalised()["d"] == pytest.approx(1.5)
    assert model.normalised()["d^2"] == pytest.approx(-0.5)
    assert model.influence() == {"d": pytest.approx(1.5)}
    assert model.dominant() == ("d", True)


def test_a_dominant_disturbance_within_the_noise_is_flagged():
    rng = np.random.default_rng(5)
    design = central_composite(3)
    noise = rng.normal(0, 0.5, len(design))
    names = ["f", "a", "b"]
    weak = fit_surrogate(design, 5.0 * design[:, 0] + 0.01 * design[:, 1] + noise, names)
    strong = fit_surrogate(design, 5.0 * design[:, 0] + 3.0 * design[:, 1] + noise, names)
    assert weak.dominant()[1] is False
    assert strong.dominant() == ("a", True)


def test_the_dominant_disturbance_is_tested_against_the_runner_up():
    rng = np.random.default_rng(7)
    design = np.vstack([central_composite(3)] * 4)             # replicated: enough residual dof
    noise = rng.normal(0, 0.5, len(design))
    names = ["f", "a", "b"]
    tie = fit_surrogate(design, 5.0 * design[:, 0] + 3.0 * design[:, 1] + 2.9 * design[:, 2] + noise, names)
    assert tie.dominant()[1] is False                          # both far from 0, not from each other
    assert tie.runner_up() in ("a", "b") and tie.runner_up() != tie.dominant()[0]
    clear = fit_surrogate(design, 5.0 * design[:, 0] + 3.0 * design[:, 1] + 0.5 * design[:, 2] + noise, names)
    assert clear.dominant() == ("a", True) and clear.runner_up() == "b"


def test_without_residual_dof_the_dominance_is_not_testable():
    design = np.array([[-1, -1], [1, -1], [-1, 1], [1, 1], [2, 0], [0, 2]], dtype=float)
    model = fit_surrogate(design, 2.0 * design[:, 0] + 3.0 * design[:, 1] + 0.1 * design[:, 1] ** 2, ["f", "d"])
    assert model.dominant() == ("d", None)

# ---------------------------------------------------------------------------------------------- SNR and scope


def _linear(a: float, b: float, noise: float) -> Surrogate:
    """q = a·f + b·d with residual std ``noise``, as a fitted surrogate."""
    terms = tuple(quadratic_terms(["f", "d"]))
    theta = np.zeros(len(terms))
    theta[1], theta[2] = a, b
    return Surrogate(("f", "d"), terms, theta, np.zeros((len(terms), len(terms))), noise ** 2, 7)


def test_snr_matches_the_closed_form_of_a_linear_surrogate():
    model = _linear(a=2.0, b=1.0, noise=0.1)
    expected = 2.0 * 1.0 / math.sqrt((1.0 * 0.25) ** 2 + 0.1 ** 2)
    assert snr(model, draws=200_000, noise_std=0.1) == pytest.approx(expected, rel=0.02)
    assert snr(model, draws=200_000) == pytest.approx(2.0 / 0.25, rel=0.02)


def test_a_strong_fault_effect_has_scope_a_dominant_disturbance_does_not():
    strong = scope_matrix(_linear(a=5.0, b=0.2, noise=0.05), 1, draws=5000, noise_std=0.05)
    assert strong.inside[:, -1].all()                         # the whole fault range, every spread
    assert strong.max_sigma() == pytest.approx(1.0)
    weak = scope_matrix(_linear(a=0.1, b=5.0, noise=0.05), 1, draws=5000, noise_std=0.05)
    assert (weak_max := weak.max_sigma()) is not None and weak_max < 0.2
    assert not weak.inside[weak.sigmas >= 0.2].any()
    # linear model: the test needs a·Δ ≥ 2·z(0.99)·√(b²σ² + γ)
    sigma = strong.sigmas[10]
    need = 2 * 2.3263 * math.sqrt((0.2 * sigma) ** 2 + 0.05 ** 2) / 5.0
    first = strong.min_delta()[10]
    assert first is not None and need <= first <= need + 2 * (strong.deltas[1] - strong.deltas[0])
    assert not strong.inside[:, 0].any()                      # Δ = 0: Pd = Pf


def test_a_fault_that_lowers_q_is_detected_on_its_side():
    down = scope_matrix(_linear(a=-5.0, b=0.2, noise=0.05), 1, draws=5000, noise_std=0.05)
    assert down.inside[:, -1].all()

# ---------------------------------------------------------------------------------------------- baselines


def _speed_only(v: np.ndarray, fc: float, fs: float, vs: float, fv: float) -> np.ndarray:
    return fc + fs * np.exp(-((v / vs) ** 1.36)) + fv * v


def test_parameter_change_baseline_on_synthetic_curves():
    rng = np.random.default_rng(0)
    v = np.array([2.1, 8.7, 15.3, 21.9, 28.5, 35.1, 41.7, 82.2, 133.5, 184.7, 236.2, 287.1])
    truth = (3.4e-2, 4.6e-2, 10.0, 3.7e-4)
    assert np.allclose(speed_only_parameters(v, _speed_only(v, *truth), 10.0), [3.4e-2, 4.6e-2, 3.7e-4])
    curves = [(v, _speed_only(v, *truth) + rng.normal(0, 2e-3, v.size)) for _ in range(40)]
    nominal = fit_speed_only_nominal(curves)
    assert nominal.vs == pytest.approx(10.0, rel=0.15)
    healthy = [nominal.chi2(v, _speed_only(v, *truth) + rng.normal(0, 2e-3, v.size)) for _ in range(200)]
    assert 1.5 < np.mean(healthy) < 5.0                       # ≈ χ²₃: mean 3
    worn = nominal.chi2(v, _speed_only(v, truth[0] + 0.01, *truth[1:]) + rng.normal(0, 2e-3, v.size))
    assert worn > 50


def test_baselines_refuse_or_skip_degenerate_input():
    grid = np.linspace(-1, 1, 11)
    with warnings.catch_warnings():
        warnings.simplefilter("error")                          # no RuntimeWarning from a division by 0
        assert math.isnan(distribution_peak(grid, np.zeros_like(grid)))
    v = np.linspace(1.0, 100.0, 5)
    with pytest.raises(BaselineError, match="only 0 of 4 nominal friction curves could be fitted"):
        fit_speed_only_nominal([(v, np.full_like(v, np.nan))] * 4)


def test_distribution_peak_and_data_likelihood_of_normal_densities():
    grid = np.linspace(-8, 8, 4001)
    sd = 0.5
    p = np.exp(-0.5 * (grid / sd) ** 2) / (sd * math.sqrt(2 * math.pi))
    assert distribution_peak(grid, p) == pytest.approx(1 - 1 / (math.sqrt(2 * math.pi) * sd), rel=1e-4)
    p0 = np.exp(-0.5 * grid ** 2) / math.sqrt(2 * math.pi)
    assert data_likelihood(grid, p0, p0) == pytest.approx(0.5 * math.log(2 * math.pi * math.e), rel=1e-4)
    shifted = np.exp(-0.5 * (grid - 1) ** 2) / math.sqrt(2 * math.pi)
    assert data_likelihood(grid, shifted, p0) == pytest.approx(0.5 * math.log(2 * math.pi * math.e) + 0.5, rel=1e-3)
    half = np.where(grid < 0, p0, 0.0)                        # half the mass off the grid counts, at the floor
    assert data_likelihood(grid, half, p0) > data_likelihood(grid, p0, p0) + 5

# ---------------------------------------------------------------------------------------------- simulator


def test_payload_error_biases_the_controllers_load_estimate():
    with pytest.raises(SimConfigError, match="payload_error"):
        SimConfig(payload_error=0.6)
    config = SimConfig(joints=2, cycles=1, seed=4, load_std=0.0, payload_error=0.1, speeds=(20.0, 100.0))
    truth = next(iter(cycle_signals(config))).truth
    for t in truth:
        assert t["load_estimate"] == pytest.approx(1.1 * t["load"])

# ---------------------------------------------------------------------------------------------- command line


@pytest.mark.parametrize("argv, message", [
    (["--detectors", "wear,nonsense"], "unknown detector 'nonsense'"),
    (["--factors", "wear,humidity"], "unknown factor 'humidity'"),
    (["--factors", "temperature,load"], "must include the fault 'wear'"),
    (["--range", "temperature=20:70"], "outside what the simulator supports (30 … 80 °C)"),
    (["--range", "payload_error=-60:10"], "outside what the simulator supports"),
    (["--range", "temperature=70:30"], "need LOW < HIGH"),
    (["--factors", "wear"], "at least one disturbance"),
    (["--joint", "6"], "--joint must be 0 … 5"),
    (["--test-cycles", "0"], "--test-cycles must be ≥ 2, got 0"),
    (["--scope-draws", "0"], "--scope-draws must be 1000 … 100000, got 0"),
    (["--scope-draws", "1000000"], "--scope-draws must be 1000 … 100000"),
    (["--snr-draws", "10000000"], "--snr-draws must be 1000 … 1000000"),
    (["--jobs", "65"], "--jobs must be 1 … 64"),
    (["--validation", "-1"], "--validation must be ≥ 0"),
    (["--seeds", "0"], "--seeds must be 1 … 20"),
])
def test_bad_input_is_refused_with_the_reason(argv, message, capsys, tmp_path):
    assert main(["evaluate", "--quick", "--out", str(tmp_path / "out"), *argv]) == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err and "usage: edge-monitor evaluate" in err
    assert not (tmp_path / "out").exists()


def test_a_design_file_too_small_for_the_surrogate_is_refused(capsys, tmp_path):
    design = tmp_path / "design.csv"
    design.write_text("wear,temperature,payload_error\n" + "\n".join(
        ",".join(str(int(x)) for x in row) for row in fractional_factorial(3)) + "\n")
    assert main(["evaluate", "--quick", "--design", str(design), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert "4 runs but the second-order surrogate of 3 factors has 10 coefficients" in err


def test_a_design_row_with_extra_cells_is_refused_naming_the_line(capsys, tmp_path):
    design = tmp_path / "design.csv"
    rows = [",".join(str(int(x)) for x in row) for row in central_composite(3)]
    rows[2] += ",1,1,1"                                        # would have been reshaped into an extra run
    design.write_text("wear,temperature,payload_error\n" + "\n".join(rows) + "\n")
    assert main(["evaluate", "--quick", "--design", str(design), "--out", str(tmp_path / "out")]) == 2
    assert "line 4 has 6 cells; every run needs exactly 3" in capsys.readouterr().err


def _parsed(*argv: str):
    return build_parser().parse_args(["evaluate", "--quick", *argv])


def test_jobs_are_capped_and_the_design_is_named(caplog, tmp_path):
    with caplog.at_level(logging.INFO):
        settings = _settings(_parsed("--jobs", "64"))
    assert settings.jobs <= min(os.cpu_count() or 1, len(settings.design) + len(settings.validation))
    assert "--jobs 64 capped" in caplog.text
    assert settings.describe()["design_name"] == "central composite"
    design = tmp_path / "mine.csv"
    design.write_text("wear,temperature,payload_error\n" + "\n".join(
        ",".join(str(int(x)) for x in row) for row in central_composite(3)) + "\n")
    assert _settings(_parsed("--design", str(design))).describe()["design_name"] == "own (mine.csv)"


def test_a_validation_count_that_is_not_a_multiple_of_4_is_warned_about(caplog):
    with caplog.at_level(logging.WARNING):
        _settings(_parsed("--validation", "6"))
    assert "not a multiple of 4" in caplog.text
    caplog.clear()
    with caplog.at_level(logging.WARNING):
        _settings(_parsed("--validation", "8"))
    assert "not a multiple of 4" not in caplog.text


def test_replication_summarises_snr_influence_and_dominance_across_seeds():
    def run(seed, snr_value, temp, load):
        return {"settings": {"seed": seed}, "ranking_by_snr": ["a"],
                "detectors": {"a": {"snr": snr_value, "dominant_disturbance": "load" if load > temp else "temperature",
                                    "surrogate": {"influence": {"temperature": temp, "load": load}}}}}
    rep = replication([run(1, 2.42, 0.72, 0.53), run(2, 1.35, 1.18, 0.58)])
    assert rep["seeds"] == [1, 2] and rep["best_snr"] == ["a", "a"]
    a = rep["detectors"]["a"]
    assert a["snr"]["mean"] == pytest.approx(1.885) and (a["snr"]["min"], a["snr"]["max"]) == (1.35, 2.42)
    assert a["influence"]["load"]["per_seed"] == [0.53, 0.58]
    assert a["dominant_disturbance"] == ["temperature", "temperature"]


def test_an_output_path_that_is_a_file_is_refused(capsys, tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("not a folder")
    assert main(["evaluate", "--quick", "--out", str(blocker)]) == 1
    assert f"--out: {blocker} is not a directory" in capsys.readouterr().err


def test_an_output_folder_that_cannot_be_created_is_a_runtime_failure(capsys, tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("not a folder")
    assert main(["evaluate", "--quick", "--out", str(blocker / "out")]) == 1
    assert "--out: cannot create" in capsys.readouterr().err


@pytest.mark.slow
def test_quick_evaluation_end_to_end(tmp_path):
    out = tmp_path / "report"
    proc = subprocess.run([sys.executable, "-m", "edge_monitor.cli", "evaluate", "--quick", "--out", str(out),
                           "--json", "--jobs", "2", "--validation", "3"],
                          capture_output=True, text=True, cwd=ROOT, timeout=600)
    assert proc.returncode == 0, proc.stderr
    result = json.loads(proc.stdout)
    assert json.loads((out / "evaluation.json").read_text()) == result
    assert [f["name"] for f in result["settings"]["factors"]] == ["wear", "temperature", "payload_error"]
    assert len(result["points"]) == 11 + 3
    for name in ("coefficients", "influence", "snr", "scope_wear", "scope_kl_weighted", "scope_param_change"):
        assert (out / f"{name}.png").read_bytes()[:4] == b"\x89PNG"
    dets = result["detectors"]
    assert set(dets) == {"wear", "wear_score", "kl_raw", "kl_weighted", "param_change", "dist_peak",
                         "data_likelihood"}
    assert dets["wear"]["surrogate"]["fault_effect"] > 0          # wear raises the wear estimate
    for e in dets.values():
        assert set(e["scope"]) == {"temperature", "payload_error"}
        assert len(e["scope"]["temperature"]["inside"]) == 30
    assert result["ranking_by_snr"][0] in dets
    report = (out / "REPORT.md").read_text()
    assert "Best average performance (SNR)" in report and "moved most by" in report and "scope_wear.png" in report
    assert "11-run central composite design" in report


def _children(pid: int) -> list[int]:
    """Processes whose parent is ``pid`` (from /proc)."""
    out = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                stat = (entry / "stat").read_text()
            except OSError:
                continue
            if int(stat.rsplit(")", 1)[1].split()[1]) == pid:
                out.append(int(entry.name))
    return out


@pytest.mark.slow
@pytest.mark.skipif(not Path("/proc").is_dir(), reason="needs /proc")
@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_an_interrupt_stops_the_workers_at_once(sig, tmp_path):
    log_path = tmp_path / "log"
    with log_path.open("w") as log_file:
        proc = subprocess.Popen([sys.executable, "-m", "edge_monitor.cli", "-v", "evaluate", "--quick", "--jobs", "2",
                                 "--test-cycles", "40", "--out", str(tmp_path / "out")],
                                stdout=subprocess.DEVNULL, stderr=log_file, cwd=ROOT, start_new_session=True,
                                # Ctrl-C must reach it even when the suite runs in a background job, which a
                                # non-interactive shell starts with SIGINT ignored (the child would inherit that)
                                preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    pgid = proc.pid                                            # its own session: process group = its pid
    try:
        deadline = time.monotonic() + 120
        workers: list[int] = []
        while time.monotonic() < deadline and proc.poll() is None and not (
                workers and "design + " in log_path.read_text()):   # its log says the simulation is under way
            workers = _children(proc.pid)                      # the pool's worker processes
            time.sleep(0.1)
        assert proc.poll() is None, log_path.read_text()
        assert workers, "no worker processes started"
        os.killpg(pgid, sig) if sig == signal.SIGINT else os.kill(proc.pid, sig)
        assert proc.wait(timeout=60) == (130 if sig == signal.SIGINT else 143)
        err = log_path.read_text()
        said = "interrupted" if sig == signal.SIGINT else "terminated (SIGTERM)"
        assert f"edge-monitor evaluate: {said}" in err and "Traceback" not in err
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline:
            try:
                os.killpg(pgid, 0)
            except ProcessLookupError:
                break
            time.sleep(0.1)
        with pytest.raises(ProcessLookupError):                # nothing of the group survives
            os.killpg(pgid, 0)
    finally:
        if proc.poll() is None:
            os.killpg(pgid, signal.SIGKILL)
            proc.wait()
