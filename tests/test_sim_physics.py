"""Simulator physics: friction model at reference points, friction from simulated plateaus,
thermal time constant, wear scenarios, speed tracking."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import stats
from scipy.optimize import curve_fit
from test_sim_support import collect, decode, joint_signals, plateau_means

from protocol import frames as pf
from sim_controller.config import SimConfig
from sim_controller.controller import Controller
from sim_controller.test_cycle import build_cycle
from sim_controller.thermal import ThermalModel
from sim_controller.wear_scenarios import WearEvent, WearProfile

TABLE = dict(fc0=3.11e-2, fcl=2.34e-2, fs0=-2.50e-2, fsl=1.26e-1, fsxi=1.60e-3, fv0=1.30e-4, fvxi=1.32e-3,
             vs0=-24.81, vsl=9.22, vsxi=0.98, xi_vo=20.71, alpha=1.36, fsw=9.02e-4, fvw=-5.15e-7, vsw=2.19)


def hand_friction(v: float, load: float, xi: float, wear: float) -> float:
    """docs/ALGORITHMS.md §1 written out term by term with the §1 table (independent of friction_model)."""
    p = TABLE
    coulomb = p["fc0"] + p["fcl"] * abs(load)
    load_stribeck = p["fsl"] * abs(load) * math.exp(-((v / p["vsl"]) ** p["alpha"]))
    temp_stribeck = (p["fs0"] + p["fsxi"] * xi) * math.exp(-((v / (p["vs0"] + p["vsxi"] * xi)) ** p["alpha"]))
    viscous = (p["fv0"] + p["fvxi"] * math.exp(-xi / p["xi_vo"])) * v
    wear_part = 0.0
    if wear > 0:
        wear_part = p["fsw"] * wear * math.exp(-((v / (wear * p["vsw"])) ** p["alpha"])) + p["fvw"] * wear * v
    return coulomb + load_stribeck + temp_stribeck + viscous + wear_part


def small_config(**kw) -> SimConfig:
    base = dict(joints=1, cycles=2, seed=11, speeds=(2.1, 21.9, 82.2, 287.1), plateau_time=0.8, pause_time=0.1)
    base.update(kw)
    return SimConfig(**base)


def test_truth_friction_matches_hand_computed_formula_at_reference_points():
    config = small_config(cycles=3, speeds=(2.1, 15.3, 41.7, 133.5, 287.1),
                          wear=(WearProfile(events=(WearEvent("ramp", 0, 2, 0.0, 35.0),)),),
                          temperature_range=(35.0, 70.0))
    controller = Controller(config)
    for _ in controller.frames():
        pass
    records = controller.truth_records()
    assert [r["wear"] for r in records] == [0.0, 17.5, 35.0]
    for r in records:
        for v, model in zip(r["speeds"], r["friction"]):
            expected = hand_friction(v, r["load"], r["temperature"], r["wear"])
            assert model == pytest.approx(expected, rel=1e-12, abs=1e-15)


def _plateau_residuals(config: SimConfig):
    """(residual of (τ⁺−τ⁻)/2 vs the truth model, truth model error, averaging std) per joint/cycle/level."""
    controller = Controller(config)
    decoded = decode(collect(controller.frames()))
    truth = {(r["joint"], r["cycle"]): r for r in controller.truth_records()}
    cycle_ticks = build_cycle(config.speeds, config.rate, config.plateau_time, config.acceleration,
                              config.pause_time, 0.05, config.production_speed).n
    quant = pf.TORQUE_SCALE / math.sqrt(12.0)
    out = []
    for j in range(config.joints):
        sig = joint_signals(decoded, j)
        for k, v in enumerate(config.speeds):
            plus, minus = plateau_means(sig, v, config.rate), plateau_means(sig, -v, config.rate)
            assert len(plus) == len(minus) == config.cycles, (j, v)
            for (tp, n_p, start), (tm, n_m, _) in zip(plus, minus):
                # the cycle a plateau belongs to: cycles are ≈ equal length (p2p delay varies by ≤ 50 ms)
                cycle = int(start // (cycle_ticks - 0.05 * config.rate))
                rec = truth[(j, cycle)]
                sigma = math.sqrt((config.torque_noise**2 + quant**2) * (1 / n_p + 1 / n_m)) / 2
                out.append(((tp - tm) / 2 - rec["friction"][k], rec["model_error"][k], sigma))
    return np.array(out)


def test_plateau_friction_equals_model_without_model_error():
    res = _plateau_residuals(small_config(joints=2, variation=0.0, friction_model_error=0.0))
    # Only the averaging noise remains: |residual| < 5σ for each of the 16 data (P(miss) < 1e-5)
    assert np.all(np.abs(res[:, 0]) < 5 * res[:, 2]), res


def test_plateau_friction_carries_the_model_error_with_the_configured_spread():
    sigma_m = 5.70e-3
    config = small_config(joints=3, cycles=4, speeds=(2.1, 8.7, 21.9, 41.7, 82.2, 184.7, 287.1), seed=5)
    res = _plateau_residuals(config)
    # datum = model + model error + averaging noise
    assert np.all(np.abs(res[:, 0] - res[:, 1]) < 5 * res[:, 2])
    # the spread of the residuals is σm: (n−1)s²/σm² ~ χ²(n−1); two-sided 99.9 % bounds
    n = res.shape[0]
    s2 = np.var(res[:, 0], ddof=1)
    lo, hi = stats.chi2.ppf([0.0005, 0.9995], n - 1) / (n - 1)
    assert lo * sigma_m**2 < s2 < hi * sigma_m**2, (n, math.sqrt(s2))


def test_speed_tracks_reference_on_plateaus():
    config = small_config(speed_noise=0.0, torque_noise=0.0)
    sig = joint_signals(decode(collect(Controller(config).frames())), 0)
    for v in config.speeds:
        for sign in (1, -1):
            inside = np.abs(sig.speed - sign * v) < 0.5
            assert inside.sum() > 2 * 0.7 * config.rate   # two cycles of ≥ 0.7 s at that speed


def test_thermal_model_step_is_exact_exponential():
    model = ThermalModel(temperature=30.0, ambient=30.0, time_constant=3.04 * 3600, heating=4.0, time_acceleration=60)
    t = np.arange(1, 200) * 20.0
    temps = np.array([model.advance(20.0, 5.0) for _ in t])
    (tau, final), _ = curve_fit(lambda t, tau, final: final + (30.0 - final) * np.exp(-t / tau), t, temps,
                                p0=(100.0, 40.0))
    # exact discretisation: the fit recovers τ/A to floating-point accuracy
    assert tau == pytest.approx(3.04 * 3600 / 60, rel=1e-6)
    assert final == pytest.approx(30.0 + 4.0 * 5.0, rel=1e-6)


def test_controller_temperature_relaxes_with_the_configured_time_constant():
    tau_h = 3.04
    config = small_config(cycles=15, heating=0.0, ambient=30.0, start_temperature=70.0, min_temperature=0.0,
                          time_acceleration=200.0, speeds=(20.0,), plateau_time=0.2)
    controller = Controller(config)
    for _ in controller.frames():
        pass
    rec = controller.truth_records()
    t = np.array([r["t_start"] for r in rec])
    temp = np.array([r["temperature"] for r in rec])
    (tau,), _ = curve_fit(lambda t, tau: 30.0 + 40.0 * np.exp(-t / tau), t, temp, p0=(50.0,))
    assert tau * config.time_acceleration / 3600 == pytest.approx(tau_h, rel=1e-6)


def test_thermal_model_heats_towards_ambient_plus_losses():
    config = small_config(cycles=20, time_acceleration=300.0, speeds=(133.5, 287.1))   # τ/A ≈ 5 cycles
    controller = Controller(config)
    for _ in controller.frames():
        pass
    temp = [r["temperature"] for r in controller.truth_records()]
    assert temp[0] == 30.0 and temp[1] < temp[3] < temp[6] and np.mean(temp[-5:]) > 35.0   # losses heat it
    assert temp[-1] < 30.0 + config.heating * 0.2 * 287.1                  # bounded by |τf|·v < 0.2·v


def test_wear_scenarios_compose_ramp_exponential_step_replacement():
    profile = WearProfile(initial=2.0, events=(
        WearEvent("ramp", 10, 20, 2.0, 12.0),
        WearEvent("exponential", 30, 40, 12.0, 60.0, tau=3.0),
        WearEvent("replacement", 45),
        WearEvent("step", 50, to=20.0),
    ))
    w = [profile.wear(c) for c in range(60)]
    assert w[0] == 2.0 and w[15] == pytest.approx(7.0) and w[25] == 12.0
    assert w[30] == 12.0 and w[40] == 60.0 and 12.0 < w[35] < 36.0    # convex: below the chord midpoint
    assert w[44] == 60.0 and w[45] == 0.0 and w[49] == 0.0 and w[50] == 20.0
    assert [c for c in range(60) if profile.maintenance(c)] == [45]


def test_replacement_is_declared_in_truth_and_as_stopped_mode():
    config = small_config(cycles=3, speeds=(20.0,), plateau_time=0.3,
                          wear=(WearProfile(initial=40.0, events=(WearEvent("replacement", 2),)),))
    controller = Controller(config)
    decoded = decode(collect(controller.frames()))
    rec = controller.truth_records()
    assert [r["wear"] for r in rec] == [40.0, 40.0, 0.0]
    assert [r["maintenance"] for r in rec] == [False, False, True]
    status = decoded.kind == pf.FrameKind.CONTROLLER_STATUS
    stopped_cycles = set(decoded.cycle[status & (decoded.mode == pf.Mode.STOPPED)].tolist())
    assert stopped_cycles == {2}
