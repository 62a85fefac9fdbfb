"""Per-joint KL monitor: learning, wear response, bad input, windows, persistence, modes."""

from __future__ import annotations

import json

import numpy as np
import pytest

from edge_monitor.commands.fit_weights import simulate_cycles
from edge_monitor.errors import ConfigError, StateMismatch
from edge_monitor.features.disturbance_weights import WeightFunction
from edge_monitor.features.kl_channel import PROVISIONAL_GRID
from edge_monitor.features.kl_monitor import KLConfig, KLMonitor, KLResult
from protocol.frames import SEGMENT_PRODUCTION

CONSTANT_TEMPERATURE = (40.0, 40.0)


def _feed(mon: KLMonitor, torque: np.ndarray, speed: np.ndarray, first_cycle: int = 0,
          n_blocks: int = 4) -> list[KLResult]:
    """Feed cycles block by block, as the agent does, and close each one."""
    results = []
    for c in range(torque.shape[0]):
        for tau, v in zip(np.array_split(torque[c], n_blocks), np.array_split(speed, n_blocks)):
            mon.update_samples(tau, v)
        results.append(mon.end_cycle(first_cycle + c))
    return results


def _learned_monitor(rng: np.random.Generator, k: int = 10, temperature=CONSTANT_TEMPERATURE) -> KLMonitor:
    mon = kl(n_nominal_cycles=k)
    torque, speed, _ = simulate_cycles(k, 0.0, temperature, rng)
    results = _feed(mon, torque, speed)
    assert [r.reason for r in results] == [f"learning {i}/{k}" for i in range(1, k + 1)]
    assert all(r.raw is None and r.weighted is None for r in results)
    assert mon.learned
    return mon


def _kl(mon: KLMonitor, rng: np.random.Generator, n: int, wear: float,
        temperature=CONSTANT_TEMPERATURE) -> np.ndarray:
    torque, speed, _ = simulate_cycles(n, wear, temperature, rng)
    results = _feed(mon, torque, speed)
    assert all(r.reason is None for r in results)
    return np.array([[r.raw, r.weighted] for r in results])


def _se_diff(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.sqrt(a.var(ddof=1) / a.size + b.var(ddof=1) / b.size))


def test_kl_raw_stays_nominal_without_wear_and_rises_with_wear() -> None:
    rng = np.random.default_rng(20261122)
    mon = _learned_monitor(rng)
    n = 30
    nominal_a = _kl(mon, rng, n, 0.0)[:, 0]
    nominal_b = _kl(mon, rng, n, 0.0)[:, 0]
    # Quiet side: two independent wear-0 batches have the same mean. By the CLT the difference of
    # the means is ~N(0, SE²); |z| > 4 happens with probability 6e-5 if nothing changed.
    assert abs(nominal_a.mean() - nominal_b.mean()) < 4 * _se_diff(nominal_a, nominal_b)
    # ... and sit below the simple μ0 + 3σ0 threshold learned from the nominal cycles
    threshold = mon.channels["raw"].threshold
    assert np.concatenate([nominal_a, nominal_b]).mean() < threshold
    # Alarm side: the mean rises with wear at constant temperature. Each step must be a significant
    # increase: z > 3 (probability 1.3e-3 per step of passing by chance if the mean did not rise).
    # Levels 0/20/30/45 are spaced so that the expected z of every step is >> 3 (wear acts as
    # fsϖ·ϖ, about 0.018 torque at 20 against a model error of 0.0057 per level).
    means = [nominal_b]
    for wear in (20.0, 30.0, 45.0):
        means.append(_kl(mon, rng, n, wear)[:, 0])
    for lower, higher in zip(means, means[1:]):
        assert higher.mean() - lower.mean() > 3 * _se_diff(lower, higher)
    assert means[-1].mean() > threshold


def test_learning_sets_grid_from_the_first_cycle_and_reports_thresholds() -> None:
    rng = np.random.default_rng(1)
    mon = kl(n_nominal_cycles=3)
    torque, speed, _ = simulate_cycles(4, 0.0, CONSTANT_TEMPERATURE, rng)
    assert mon.grid is None
    first = _feed(mon, torque[:1], speed)[0]
    assert first.reason == "learning 1/3" and first.threshold_3sigma is None
    grid = mon.grid
    assert grid is not None and grid.size == 512
    centred = torque[0] - torque[0].mean()          # the grid holds the centred torque (center=True)
    assert grid[0] < centred.min() and grid[-1] > centred.max()
    # the first cycle was re-binned, not lost: its density integrates to ~1 on the working grid
    assert first.density["cycle"].sum() * (grid[1] - grid[0]) == pytest.approx(1.0, abs=1e-3)
    rest = _feed(mon, torque[1:], speed, first_cycle=1)
    assert rest[1].reason == "learning 3/3"
    assert set(rest[1].threshold_3sigma) == {"raw", "weighted"}
    assert rest[2].reason is None and rest[2].raw >= 0 and rest[2].weighted >= 0
    section = rest[2].to_section()
    assert (section["raw"], section["weighted"]) == (rest[2].raw, rest[2].weighted)
    assert rest[2].density["nominal"] is not None
    # the grid stays fixed while monitoring
    np.testing.assert_array_equal(mon.grid, grid)


def _monitor_after(k: int = 2, rng_seed: int = 2) -> tuple[KLMonitor, np.ndarray]:
    """A monitor learned on ``k`` cycles, keeping standstill samples (the tests count samples)."""
    rng = np.random.default_rng(rng_seed)
    mon = kl(n_nominal_cycles=k, min_speed=0.0)
    torque, speed, _ = simulate_cycles(k, 0.0, CONSTANT_TEMPERATURE, rng)
    _feed(mon, torque, speed)
    return mon, speed


@pytest.mark.parametrize("torque, speed, reason", [
    (np.full(12, 0.3), np.full(12, 20.0), "cycle too short: 12 samples < 1000"),
    (np.full(5000, 0.3), np.linspace(-50, 50, 5000), "constant data"),
    (np.full(5000, np.nan), np.full(5000, 20.0), "cycle too short: 0 samples < 1000 (5000 non-finite skipped)"),
    (np.linspace(0.2, 0.4, 5000), np.zeros(5000), "constant data (weighted)"),
    (np.array([]), np.array([]), "empty window: no samples"),
])
def test_bad_cycles_get_a_reason_and_no_numeric_error(torque: np.ndarray, speed: np.ndarray, reason: str) -> None:
    for learned in (False, True):
        mon = _monitor_after()[0] if learned else kl(n_nominal_cycles=2, min_speed=0.0)
        with np.errstate(all="raise"):       # no division by zero, no log(0), no invalid op
            mon.update_samples(torque, speed)
            result = mon.end_cycle(7)
        assert result.reason == reason
        assert result.raw is None and result.weighted is None
        section = result.to_section()
        assert (section["raw"], section["weighted"]) == (None, None)
        assert mon.learned is learned        # a bad cycle does not count as a learning cycle


def test_slow_samples_are_left_out_and_counted() -> None:
    """Below ``min_speed`` (default 10 rad/s: standstill and the Stribeck region) the samples are left
    out of both densities, counted in the section, and NaN speeds still count as non-finite."""
    rng = np.random.default_rng(5)
    mon = kl(n_nominal_cycles=2)
    assert mon.min_speed == 10.0
    torque, speed, _ = simulate_cycles(3, 0.0, CONSTANT_TEMPERATURE, rng)
    still = np.abs(speed) < 10.0
    assert 0 < still.sum() < speed.size
    results = _feed(mon, torque, speed)
    assert all(r.standstill == still.sum() for r in results)
    assert all(r.n_samples == speed.size - still.sum() for r in results)
    assert results[-1].to_section()["standstill"] == still.sum()
    v = speed.copy()
    moving = np.flatnonzero(~still)[:10]
    v[moving] = np.nan
    mon.update_samples(torque[0], v)
    result = mon.end_cycle(3)
    assert result.standstill == still.sum() and result.outside["weighted"]["nonfinite"] == 10
    mon.update_samples(np.full(2000, 0.3), np.zeros(2000))
    assert mon.end_cycle(4).reason == "joint too slow: all 2000 samples slower than kl.min_speed = 10 rad/s"


def test_nan_samples_are_counted_and_the_rest_is_used() -> None:
    mon, speed = _monitor_after()
    torque, _, _ = simulate_cycles(1, 0.0, CONSTANT_TEMPERATURE, np.random.default_rng(3))
    tau = torque[0].copy()
    tau[::100] = np.nan
    v = speed.copy()
    v[1::100] = np.nan
    mon.update_samples(tau, v)
    result = mon.end_cycle(3)
    assert result.reason is None and np.isfinite(result.raw) and np.isfinite(result.weighted)
    assert result.outside["raw"]["nonfinite"] == tau.size // 100
    assert result.outside["weighted"]["nonfinite"] == 2 * (tau.size // 100)
    assert result.n_samples == tau.size - tau.size // 100


@pytest.mark.parametrize("center", [False, True])
def test_samples_outside_the_grid_are_reported_and_raise_kl(center: bool) -> None:
    rng = np.random.default_rng(4)
    mon = kl(n_nominal_cycles=2, center=center, min_speed=0.0)
    torque, speed, _ = simulate_cycles(4, 0.0, CONSTANT_TEMPERATURE, rng)
    _feed(mon, torque[:2], speed)
    normal = _feed(mon, torque[2:3], speed)[0]
    # uncentred: a shift of +0.5 leaves the working grid; centred, a shift is removed, so stretch
    # the cycle about its mean instead (a change of shape the centring must not hide)
    moved = torque[3] + 0.5 if not center else torque[3].mean() + 6.0 * (torque[3] - torque[3].mean())
    mon.update_samples(moved, speed)
    result = mon.end_cycle(9)
    assert normal.outside["raw"]["above"] == 0
    # every sample beyond the working grid is counted; mass is counted by (capture or working) bin,
    # so only samples within one bin (≤ 2e-4 before the ×6 stretch, i.e. 1.2e-3) of a grid end may
    # land on either side
    located = moved - (moved.mean() if center else 0.0)
    grid = mon.grid
    beyond = np.count_nonzero((located < grid[0]) | (located > grid[-1]))
    ambiguous = np.count_nonzero(np.minimum(abs(located - grid[0]), abs(located - grid[-1])) < 1.2e-3)
    out = result.outside["raw"]["above"] + result.outside["raw"]["below"]
    assert beyond > 0.2 * moved.size and abs(out - beyond) <= ambiguous + 1
    assert result.raw > 100 * normal.raw


def test_production_window_uses_only_segment_200_samples() -> None:
    rng = np.random.default_rng(5)
    torque, speed, _ = simulate_cycles(3, 0.0, CONSTANT_TEMPERATURE, rng)
    n = speed.size
    segment = np.where(np.arange(n) < n // 2, SEGMENT_PRODUCTION, 3)
    junk = rng.uniform(-1.5, 1.5, (3, n))          # samples outside segment 200 must not matter
    mixed = np.where(segment == SEGMENT_PRODUCTION, torque, junk)
    a = kl(n_nominal_cycles=2, window="production", min_speed=0.0)
    b = kl(n_nominal_cycles=2, window="cycle", min_speed=0.0)
    for c in range(3):
        a.update_samples(mixed[c], speed, segment)
        b.update_samples(torque[c, : n // 2], speed[: n // 2])
        ra, rb = a.end_cycle(c), b.end_cycle(c)
    assert ra.raw == rb.raw and ra.weighted == rb.weighted and ra.n_samples == n // 2
    # no segment information at all: nothing is production
    a.update_samples(torque[0], speed)
    assert a.end_cycle(4).reason == "empty window: no samples in the production segment"


def test_state_round_trip_mid_learning_and_mid_cycle_gives_identical_results() -> None:
    rng = np.random.default_rng(6)
    torque, speed, _ = simulate_cycles(6, 5.0, CONSTANT_TEMPERATURE, rng)
    original = kl(n_nominal_cycles=3, alpha=0.01, beta=0.02)
    _feed(original, torque[:2], speed)
    original.update_samples(torque[2, :4000], speed[:4000])                 # mid-cycle
    restored = KLMonitor.from_state(original.config, json.loads(json.dumps(original.state_dict())))
    for mon in (original, restored):
        mon.update_samples(torque[2, 4000:], speed[4000:])
        mon.end_cycle(2)
    a = _feed(original, torque[3:], speed, first_cycle=3)
    b = _feed(restored, torque[3:], speed, first_cycle=3)
    assert [(r.raw, r.weighted, r.reason) for r in a] == [(r.raw, r.weighted, r.reason) for r in b]
    assert restored.weights == WeightFunction(0.01, 0.02)


def test_reset_relearns_the_nominal_model() -> None:
    mon, speed = _monitor_after()
    mon.reset()
    assert not mon.learned and mon.grid is None
    torque, _, _ = simulate_cycles(1, 30.0, CONSTANT_TEMPERATURE, np.random.default_rng(7))
    assert _feed(mon, torque, speed)[0].reason == "learning 1/2"


def test_nearest_mode_isolates_a_stored_wear_mode() -> None:
    rng = np.random.default_rng(8)
    mon = _learned_monitor(rng, k=5)
    worn, speed, _ = simulate_cycles(6, 40.0, CONSTANT_TEMPERATURE, rng)
    # the mode density: average of cycles recorded in the known mode (here wear 40)
    mode_density = np.mean([r.density["cycle"] for r in _feed(mon, worn[:3], speed)], axis=0)
    mon.add_mode("wear40", mode_density)
    assert {r.nearest_mode for r in _feed(mon, worn[3:], speed)} == {"wear40"}
    healthy, _, _ = simulate_cycles(3, 0.0, CONSTANT_TEMPERATURE, rng)
    assert {r.nearest_mode for r in _feed(mon, healthy, speed)} == {"nominal"}
    with pytest.raises(ValueError):
        mon.add_mode("bad", np.ones(3))


def test_configuration_errors_name_the_field() -> None:
    with pytest.raises(ConfigError, match="kl.n_nominal_cycles"):
        kl(n_nominal_cycles=1)
    with pytest.raises(ConfigError, match="kl.window"):
        kl(window="shift")
    with pytest.raises(ConfigError, match="kl.n_grid"):
        kl(n_grid=16)
    with pytest.raises(ValueError, match="add_mode"):
        KLMonitor(KLConfig()).add_mode("x", np.zeros(512))
    with pytest.raises(ValueError, match="speed"):
        KLMonitor(KLConfig()).update_samples(np.zeros(3), np.zeros(4))


def test_memory_is_bounded_by_the_grid() -> None:
    mon, speed = _monitor_after()
    torque, _, _ = simulate_cycles(1, 0.0, CONSTANT_TEMPERATURE, np.random.default_rng(9))
    mon.update_samples(torque[0], speed)
    size_one_cycle = len(json.dumps(mon.state_dict()))
    for _ in range(19):                       # a cycle 20 times longer than usual
        mon.update_samples(torque[0], speed)
    state = mon.state_dict()
    # raw channel (centred): fixed capture grid over the wire range (stored from the first to the
    # last occupied bin); weighted: the working grid
    assert state["channels"]["raw"]["kde"]["n_grid"] == PROVISIONAL_GRID
    assert len(state["channels"]["raw"]["kde"]["mass"]) <= PROVISIONAL_GRID
    assert len(state["channels"]["weighted"]["kde"]["mass"]) <= 512
    # same mass bins, only the numbers in them change: the state does not grow with the cycle
    assert len(json.dumps(state)) < 1.1 * size_one_cycle
    assert mon.end_cycle(1).n_samples == 20 * speed.size


# -- centring: invariance to a per-cycle load (gravity) torque --------------------------------------
LOAD_SPREAD = (0.3, 0.7)      # simulator default |τl| ~ U(0.3, 0.7), a location shift per cycle


def test_centring_removes_a_pure_shift_up_to_the_binning_error() -> None:
    """A cycle equal to the nominal cycle shifted by a constant has KL ≈ 0.

    Bound (raw channel): a sample binned linearly at fraction f between two points of step dx
    contributes K(x − y) + ½·f(1 − f)·dx²·K''(x − y) + O(dx³), i.e. an extra variance in [0, dx²/4]
    per binning. The sample passes two binnings (capture grid, then working grid), so the two
    densities differ by Δp = ½·Σ aᵢ·cᵢ·K''ᵢ with |cᵢ| ≤ δ = (dx_c² + dx_w²)/4. By Cauchy–Schwarz
    and ∫K''²/K = 3/h⁴ for a Gaussian of std h, the χ² distance ∫Δp²/p ≤ ¾·δ²/h⁴; the symmetric
    KL equals χ² to second order, so KL ≤ 2·¾·δ²/h⁴ (factor 2 for higher-order terms).
    Weighted channel: its values w·(τ − m_t) are shift-invariant in exact arithmetic (m_t: causal
    running mean) and are binned once on the working grid; but the first learning cycle was binned
    on the provisional grid and re-binned when the grid was fixed, so the same bound applies with
    the weighted values' h and working step.
    """
    rng = np.random.default_rng(11)
    torque, speed, _ = simulate_cycles(1, 10.0, CONSTANT_TEMPERATURE, rng)
    cycle = torque[0]
    mon = kl(n_nominal_cycles=2)
    _feed(mon, np.stack([cycle, cycle]), speed)            # nominal density = this cycle's density
    n = cycle.size
    h = (4.0 / (3.0 * n)) ** 0.2 * cycle.std(ddof=1)      # normal reference rule, as the KDE uses
    dx_capture = 2 * 1.6384 / (PROVISIONAL_GRID - 1)
    dx_work = mon.grid[1] - mon.grid[0]
    delta = (dx_capture ** 2 + dx_work ** 2) / 4
    bound = 2 * 0.75 * delta ** 2 / h ** 4
    weighted = WeightFunction()(speed) * (cycle - np.cumsum(cycle) / np.arange(1, n + 1))
    h_weighted = (4.0 / (3.0 * n)) ** 0.2 * weighted.std(ddof=1)
    delta_weighted = (dx_capture ** 2 + mon.channels["weighted"].dx ** 2) / 4
    bound_weighted = 2 * 0.75 * delta_weighted ** 2 / h_weighted ** 4
    for shift in (1e-5, 0.0137, 0.31415, -0.2718, 0.9):
        result = _feed(mon, (cycle + shift)[None, :], speed)[0]
        assert result.raw <= bound, (shift, result.raw, bound)
        assert result.weighted <= bound_weighted, (shift, result.weighted, bound_weighted)
    # the bound is far below the nominal level of KL between different healthy cycles
    other, _, _ = simulate_cycles(1, 10.0, CONSTANT_TEMPERATURE, rng)
    assert _feed(mon, other, speed)[0].raw > 1000 * bound


def _spearman(a: np.ndarray, b: np.ndarray) -> float:
    ra, rb = np.argsort(np.argsort(a)), np.argsort(np.argsort(b))
    return float(np.corrcoef(ra, rb)[0, 1])


@pytest.mark.parametrize("center", [True, False])
def test_load_spread_centred_stays_nominal_and_sees_wear_uncentred_sees_the_load(center: bool) -> None:
    rng = np.random.default_rng(20261123)
    k, n = 10, 40
    mon = kl(n_nominal_cycles=k, center=center)
    torque, speed, _ = simulate_cycles(k, 0.0, CONSTANT_TEMPERATURE, rng, gravity=LOAD_SPREAD)
    _feed(mon, torque, speed)
    nominal_mean = torque.mean()
    batches = {}
    for label, wear, gravity in (("h0 fixed", 0.0, None), ("h0 load", 0.0, LOAD_SPREAD),
                                 ("h1 load", 35.0, LOAD_SPREAD)):
        torque, _, _ = simulate_cycles(n, wear, CONSTANT_TEMPERATURE, rng, gravity=gravity)
        batches[label] = (np.array([[r.raw, r.weighted] for r in _feed(mon, torque, speed)]), torque.mean(axis=1))
    h0, load = batches["h0 load"]
    # Under independence, Spearman's ρ of n pairs has sd 1/√(n − 1); |ρ| > 4/√(n − 1) has
    # probability < 1e-4.
    rho_limit = 4 / np.sqrt(n - 1)
    distance = np.abs(load - nominal_mean)     # how far this cycle's load is from the nominal ones
    if not center:
        # the old failure: kl.raw follows the per-cycle load, not the machine's condition
        assert _spearman(h0[:, 0], distance) > rho_limit
        return
    h0_fixed = batches["h0 fixed"][0]
    h1 = batches["h1 load"][0]
    thresholds = {name: mon.channels[name].threshold for name in ("raw", "weighted")}  # μ0 + 3σ0
    for j, name in enumerate(("raw", "weighted")):
        # quiet: centred KL does not depend on the load (ρ test) and its mean equals the mean at a
        # fixed load (CLT: |z| > 4 has probability 6e-5)
        assert abs(_spearman(h0[:, j], distance)) < rho_limit, name
        assert abs(h0[:, j].mean() - h0_fixed[:, j].mean()) < 4 * _se_diff(h0[:, j], h0_fixed[:, j]), name
        # alarm: wear 35 under the same load spread raises the mean significantly (z > 4) and
        # above the μ0 + 3σ0 threshold
        assert h1[:, j].mean() - h0[:, j].mean() > 4 * _se_diff(h0[:, j], h1[:, j]), name
        assert h1[:, j].mean() > thresholds[name], name


def test_a_state_learned_with_another_config_is_refused_naming_the_change() -> None:
    rng = np.random.default_rng(12)
    torque, speed, _ = simulate_cycles(3, 0.0, CONSTANT_TEMPERATURE, rng)
    old = kl(n_nominal_cycles=2, center=False)
    _feed(old, torque[:2], speed)
    state = json.loads(json.dumps(old.state_dict()))
    restored = KLMonitor.from_state(old.config, state)
    a, b = _feed(old, torque[2:], speed)[0], _feed(restored, torque[2:], speed)[0]
    assert (a.raw, a.weighted) == (b.raw, b.weighted)
    np.testing.assert_array_equal(restored.grid, old.grid)
    with pytest.raises(StateMismatch, match="center False → True"):
        KLMonitor.from_state(KLConfig(n_nominal_cycles=2, center=True), state)


def kl(**settings) -> KLMonitor:
    """A monitor with ``KLConfig(**settings)``."""
    return KLMonitor(KLConfig(**settings))
