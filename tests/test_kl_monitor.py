"""Per-joint KL monitor: learning, wear response, bad input, windows, persistence, modes."""

from __future__ import annotations

import json

import numpy as np
import pytest

from edge_monitor.commands.fit_weights import simulate_cycles
from edge_monitor.disturbance_weights import WeightFunction
from edge_monitor.kl_monitor import (PROVISIONAL_GRID, SEGMENT_PRODUCTION, KLConfigError, KLMonitor, KLResult)

CONSTANT_TEMPERATURE = (40.0, 40.0)


def _feed(mon: KLMonitor, torque: np.ndarray, speed: np.ndarray, first_cycle: int = 0,
          n_blocks: int = 4) -> list[KLResult]:
    """Feed cycles block by block, as the agent does, and close each one."""
    results = []
    for c in range(torque.shape[0]):
        for tau, v in zip(np.array_split(torque[c], n_blocks), np.array_split(speed, n_blocks)):
            mon.add(tau, v)
        results.append(mon.end_cycle(first_cycle + c))
    return results


def _learned_monitor(rng: np.random.Generator, k: int = 10, temperature=CONSTANT_TEMPERATURE) -> KLMonitor:
    mon = KLMonitor(n_nominal_cycles=k)
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
    mon = KLMonitor(n_nominal_cycles=3)
    torque, speed, _ = simulate_cycles(4, 0.0, CONSTANT_TEMPERATURE, rng)
    assert mon.grid is None
    first = _feed(mon, torque[:1], speed)[0]
    assert first.reason == "learning 1/3" and first.threshold_3sigma is None
    grid = mon.grid
    assert grid is not None and grid.size == 512
    assert grid[0] < torque[0].min() and grid[-1] > torque[0].max()
    # the first cycle was re-binned, not lost: its density integrates to ~1 on the working grid
    assert first.density["cycle"].sum() * (grid[1] - grid[0]) == pytest.approx(1.0, abs=1e-3)
    rest = _feed(mon, torque[1:], speed, first_cycle=1)
    assert rest[1].reason == "learning 3/3"
    assert set(rest[1].threshold_3sigma) == {"raw", "weighted"}
    assert rest[2].reason is None and rest[2].raw >= 0 and rest[2].weighted >= 0
    assert rest[2].to_record() == {"raw": rest[2].raw, "weighted": rest[2].weighted}
    assert rest[2].density["nominal"] is not None
    # the grid stays fixed while monitoring
    np.testing.assert_array_equal(mon.grid, grid)


def _monitor_after(k: int = 2, rng_seed: int = 2) -> tuple[KLMonitor, np.ndarray]:
    rng = np.random.default_rng(rng_seed)
    mon = KLMonitor(n_nominal_cycles=k)
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
        mon = _monitor_after()[0] if learned else KLMonitor(n_nominal_cycles=2)
        with np.errstate(all="raise"):       # no division by zero, no log(0), no invalid op
            mon.add(torque, speed)
            result = mon.end_cycle(7)
        assert result.reason == reason
        assert result.raw is None and result.weighted is None
        assert result.to_record() == {"raw": None, "weighted": None}
        assert mon.learned is learned        # a bad cycle does not count as a learning cycle


def test_nan_samples_are_counted_and_the_rest_is_used() -> None:
    mon, speed = _monitor_after()
    torque, _, _ = simulate_cycles(1, 0.0, CONSTANT_TEMPERATURE, np.random.default_rng(3))
    tau = torque[0].copy()
    tau[::100] = np.nan
    v = speed.copy()
    v[1::100] = np.nan
    mon.add(tau, v)
    result = mon.end_cycle(3)
    assert result.reason is None and np.isfinite(result.raw) and np.isfinite(result.weighted)
    assert result.outside["raw"]["nonfinite"] == tau.size // 100
    assert result.outside["weighted"]["nonfinite"] == 2 * (tau.size // 100)
    assert result.n_samples == tau.size - tau.size // 100


def test_samples_outside_the_grid_are_reported_and_raise_kl() -> None:
    mon, speed = _monitor_after()
    torque, _, _ = simulate_cycles(2, 0.0, CONSTANT_TEMPERATURE, np.random.default_rng(4))
    normal = _feed(mon, torque[:1], speed)[0]
    shifted = torque[1] + 0.5                      # far beyond the working grid's margin
    mon.add(shifted, speed)
    result = mon.end_cycle(9)
    assert normal.outside["raw"]["above"] == 0
    assert result.outside["raw"]["above"] > 0.9 * shifted.size
    assert result.raw > 100 * normal.raw


def test_production_window_uses_only_segment_200_samples() -> None:
    rng = np.random.default_rng(5)
    torque, speed, _ = simulate_cycles(3, 0.0, CONSTANT_TEMPERATURE, rng)
    n = speed.size
    segment = np.where(np.arange(n) < n // 2, SEGMENT_PRODUCTION, 3)
    junk = rng.uniform(-1.5, 1.5, (3, n))          # samples outside segment 200 must not matter
    mixed = np.where(segment == SEGMENT_PRODUCTION, torque, junk)
    a = KLMonitor(n_nominal_cycles=2, window="production")
    b = KLMonitor(n_nominal_cycles=2, window="cycle")
    for c in range(3):
        a.add(mixed[c], speed, segment)
        b.add(torque[c, : n // 2], speed[: n // 2])
        ra, rb = a.end_cycle(c), b.end_cycle(c)
    assert ra.raw == rb.raw and ra.weighted == rb.weighted and ra.n_samples == n // 2
    # no segment information at all: nothing is production
    a.add(torque[0], speed)
    assert a.end_cycle(4).reason == "empty window: no samples in the production segment"


def test_state_round_trip_mid_learning_and_mid_cycle_gives_identical_results() -> None:
    rng = np.random.default_rng(6)
    torque, speed, _ = simulate_cycles(6, 5.0, CONSTANT_TEMPERATURE, rng)
    original = KLMonitor(n_nominal_cycles=3, weights=WeightFunction(0.01, 0.02))
    _feed(original, torque[:2], speed)
    original.add(torque[2, :4000], speed[:4000])                 # mid-cycle
    restored = KLMonitor.from_state(json.loads(json.dumps(original.state_dict())))
    for mon in (original, restored):
        mon.add(torque[2, 4000:], speed[4000:])
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
    with pytest.raises(KLConfigError):
        mon.add_mode("bad", np.ones(3))


def test_configuration_errors_name_the_field() -> None:
    with pytest.raises(KLConfigError, match="n_nominal_cycles"):
        KLMonitor(n_nominal_cycles=1)
    with pytest.raises(KLConfigError, match="window"):
        KLMonitor(window="shift")  # type: ignore[arg-type]
    with pytest.raises(KLConfigError, match="add_mode"):
        KLMonitor().add_mode("x", np.zeros(512))
    with pytest.raises(ValueError, match="speed"):
        KLMonitor().add(np.zeros(3), np.zeros(4))


def test_memory_is_bounded_by_the_grid() -> None:
    mon, speed = _monitor_after()
    torque, _, _ = simulate_cycles(1, 0.0, CONSTANT_TEMPERATURE, np.random.default_rng(9))
    for _ in range(20):                       # a cycle 20 times longer than usual
        mon.add(torque[0], speed)
    state = mon.state_dict()
    assert len(state["channels"]["raw"]["kde"]["mass"]) == 512 < PROVISIONAL_GRID
    assert mon.end_cycle(1).n_samples == 20 * speed.size
