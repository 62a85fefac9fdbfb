"""Streaming KDE on a fixed grid and symmetric KL distance (edge_monitor.stats.kde_stream)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.stats import gaussian_kde

from edge_monitor.stats.kde_stream import (
    GridError,
    KDEDataError,
    StreamingKDE,
    choose_grid,
    normal_reference_bandwidth,
    symmetric_kl,
)


def _mixture(rng: np.random.Generator, n: int, n_modes: int) -> np.ndarray:
    centres = rng.uniform(-1.0, 1.0, n_modes)
    widths = rng.uniform(0.02, 0.3, n_modes)
    pick = rng.integers(0, n_modes, n)
    return rng.normal(centres[pick], widths[pick])


@settings(max_examples=15, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), n_modes=st.integers(1, 6), n=st.integers(2000, 20000))
def test_density_matches_scipy_gaussian_kde_within_one_percent_of_peak(seed: int, n_modes: int, n: int) -> None:
    rng = np.random.default_rng(seed)
    y = _mixture(rng, n, n_modes)
    lo, hi = choose_grid(float(y.min()), float(y.max()), margin=0.25)
    kde = StreamingKDE(lo, hi, 512)
    for block in np.array_split(y, 5):
        kde.update(block)
    # same samples and same bandwidth: scipy's factor multiplies the ddof=1 standard deviation
    reference = gaussian_kde(y, bw_method=kde.bandwidth / y.std(ddof=1))(kde.grid)
    ours = kde.density()
    assert np.max(np.abs(ours - reference)) <= 0.01 * reference.max()


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), cuts=st.lists(st.integers(0, 3000), max_size=6))
def test_blocks_give_the_same_state_as_one_block(seed: int, cuts: list[int]) -> None:
    rng = np.random.default_rng(seed)
    y = rng.normal(0.1, 0.05, 3000)
    w = rng.uniform(0.0, 2.0, 3000)
    whole, parts = StreamingKDE(-0.1, 0.3, 128), StreamingKDE(-0.1, 0.3, 128)
    whole.update(y, w)
    for ys, ws in zip(np.split(y, sorted(cuts)), np.split(w, sorted(cuts))):
        parts.update(ys, ws)
    np.testing.assert_allclose(parts.mass, whole.mass, rtol=1e-9, atol=1e-9)
    assert parts.mean == pytest.approx(whole.mean, rel=1e-9)
    assert parts.std == pytest.approx(whole.std, rel=1e-9)
    assert (parts.n_below, parts.n_above, parts.n_samples) == (whole.n_below, whole.n_above, whole.n_samples)


def test_moments_and_bandwidth_follow_the_normal_reference_rule() -> None:
    y = np.random.default_rng(3).normal(2.0, 0.5, 10_000)
    kde = StreamingKDE(0.0, 4.0)
    kde.update(y)
    assert kde.mean == pytest.approx(y.mean(), rel=1e-12)
    assert kde.std == pytest.approx(y.std(ddof=1), rel=1e-12)
    assert kde.bandwidth == pytest.approx((4 / (3 * 10_000)) ** 0.2 * y.std(ddof=1), rel=1e-12)


def test_integer_weights_equal_repeated_samples() -> None:
    rng = np.random.default_rng(4)
    y = rng.normal(0.0, 1.0, 500)
    reps = rng.integers(1, 4, 500)
    weighted, repeated = StreamingKDE(-5, 5, 256), StreamingKDE(-5, 5, 256)
    weighted.update(y, reps.astype(float))
    repeated.update(np.repeat(y, reps))
    np.testing.assert_allclose(weighted.mass, repeated.mass, atol=1e-9)
    assert weighted.mean == pytest.approx(repeated.mean, rel=1e-12)
    np.testing.assert_allclose(weighted.density(bandwidth=0.3), repeated.density(bandwidth=0.3), atol=1e-12)


def test_linear_binning_conserves_mass_and_first_moment() -> None:
    y = np.random.default_rng(5).uniform(-1, 1, 1000)
    kde = StreamingKDE(-1.0, 1.0, 64)
    kde.update(np.append(y, [-1.0, 1.0]))       # grid ends are inside
    assert kde.mass.sum() == pytest.approx(1002, rel=1e-12)
    assert np.dot(kde.grid, kde.mass) / kde.mass.sum() == pytest.approx(np.append(y, [-1, 1]).mean(), abs=1e-12)
    assert kde.n_outside == 0


def test_a_small_block_touches_only_the_bins_it_occupies_and_the_top_edge_folds_back() -> None:
    """Binning works on the block's own span: bins outside it stay untouched, and a sample at the top
    grid point (whose upper neighbour is past the end) keeps all its mass on the grid."""
    kde = StreamingKDE(-1.0, 1.0, 16384)
    kde.update(np.array([0.1, 0.10001, 0.1002]))
    occupied = np.flatnonzero(kde.mass)
    assert kde.mass.sum() == pytest.approx(3.0, rel=1e-12) and occupied.max() - occupied.min() <= 3
    top = StreamingKDE(-1.0, 1.0, 8)
    top.update(np.array([1.0, 1.0 - 1e-15, 0.9999]))
    assert top.mass.sum() == pytest.approx(3.0, rel=1e-12) and top.mass[-1] > 2.9


def test_samples_outside_the_grid_are_counted_and_lower_the_density_mass() -> None:
    rng = np.random.default_rng(6)
    kde = StreamingKDE(-1.0, 1.0, 512)
    kde.update(rng.normal(0, 0.1, 9000))
    kde.update(np.full(600, -3.0))
    kde.update(np.full(400, 5.0))
    assert (kde.n_below, kde.n_above, kde.n_outside) == (600, 400, 1000)
    # in-grid fraction 0.9. The rule bandwidth uses all finite samples (the far outliers widen it),
    # so fix h = 0.05 here: then the kernel mass spilling over the grid ends is < 1e-12.
    assert kde.density(bandwidth=0.05).sum() * kde.dx == pytest.approx(0.9, abs=1e-9)
    assert kde.density().sum() * kde.dx < 0.9


def test_nonfinite_samples_are_counted_and_skipped() -> None:
    y = np.array([0.1, np.nan, 0.2, np.inf, -np.inf, 0.3])
    kde = StreamingKDE(0.0, 1.0, 64)
    kde.update(y)
    assert kde.n_nonfinite == 3 and kde.n_samples == 3
    assert kde.mean == pytest.approx(0.2)
    assert np.all(np.isfinite(kde.density()))


@pytest.mark.parametrize("samples", [[], [0.5], [0.5] * 100, [np.nan] * 10])
def test_degenerate_windows_raise_a_typed_error(samples: list[float]) -> None:
    kde = StreamingKDE(0.0, 1.0, 64)
    kde.update(np.asarray(samples, dtype=float))
    with pytest.raises(KDEDataError):
        kde.density()


def test_state_round_trips_through_json() -> None:
    kde = StreamingKDE(-1.0, 1.0, 128)
    kde.update(np.random.default_rng(7).normal(0, 0.3, 1000))
    kde.update(np.array([7.0, np.nan]))
    clone = StreamingKDE.from_state(json.loads(json.dumps(kde.state_dict())))
    np.testing.assert_array_equal(clone.density(), kde.density())
    assert (clone.n_above, clone.n_nonfinite, clone.bandwidth) == (kde.n_above, kde.n_nonfinite, kde.bandwidth)


def test_state_stores_only_the_occupied_bins_and_reads_full_grid_states() -> None:
    kde = StreamingKDE(-1.6384, 1.6384, 16384)
    assert StreamingKDE.from_state(kde.state_dict()).mass.sum() == 0 and kde.state_dict()["mass"] == []
    kde.update(np.random.default_rng(9).normal(0.3, 0.01, 2000))
    state = kde.state_dict()
    assert 0 < len(state["mass"]) < 1000              # ±6σ = 0.12 → about 600 bins of 2e-4
    np.testing.assert_array_equal(StreamingKDE.from_state(state).mass, kde.mass)
    full = {**state, "mass": kde.mass.tolist()}       # format before trimming: whole grid, no offset
    del full["mass_offset"]
    np.testing.assert_array_equal(StreamingKDE.from_state(full).mass, kde.mass)
    with pytest.raises(ValueError, match="mass"):
        StreamingKDE.from_state({**state, "mass_offset": 16380})


def test_regrid_keeps_moments_and_moves_mass_by_less_than_a_bin() -> None:
    y = np.random.default_rng(8).normal(0.2, 0.05, 5000)
    wide = StreamingKDE(-1.6384, 1.6384, 16384)
    wide.update(y)
    lo, hi = choose_grid(*wide.occupied_range(), margin=0.25)
    narrow = wide.regrid(lo, hi, 512)
    direct = StreamingKDE(lo, hi, 512)
    direct.update(y)
    assert narrow.mass.sum() == pytest.approx(5000, rel=1e-12)
    assert narrow.bandwidth == direct.bandwidth
    peak = direct.density().max()
    assert np.max(np.abs(narrow.density() - direct.density())) < 0.01 * peak


def test_choose_grid_margins_and_errors() -> None:
    assert choose_grid(0.0, 1.0, margin=0.25) == (-0.25, 1.25)
    assert choose_grid(0.5, 0.5, margin=0.25, min_margin=0.1) == (0.4, 0.6)
    assert choose_grid(-1.6, 1.6, margin=0.25, bounds=(-1.6384, 1.6384)) == (-1.6384, 1.6384)
    with pytest.raises(GridError):
        choose_grid(0.5, 0.5)
    with pytest.raises(GridError):
        StreamingKDE(1.0, 1.0)


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), scale=st.floats(1e-3, 1e3))
def test_symmetric_kl_is_a_nonnegative_symmetric_scale_invariant_distance(seed: int, scale: float) -> None:
    rng = np.random.default_rng(seed)
    a, b = StreamingKDE(-3, 3, 256), StreamingKDE(-3, 3, 256)
    a.update(rng.normal(0, 0.5, 2000))
    b.update(rng.normal(rng.uniform(-1, 1), rng.uniform(0.2, 1), 2000))
    pa, pb = a.density(), b.density()
    q = symmetric_kl(pa, pb, a.dx)
    assert q >= 0 and np.isfinite(q)
    assert symmetric_kl(pb, pa, a.dx) == pytest.approx(q, rel=1e-12)
    assert symmetric_kl(pa, pa, a.dx) == 0.0
    # rescaling the quantity (densities / c, dx · c) leaves the KL unchanged with the relative floor
    assert symmetric_kl(pa / scale, pb / scale, a.dx * scale) == pytest.approx(q, rel=1e-9)


def test_symmetric_kl_with_disjoint_supports_is_finite_and_grows_as_the_floor_shrinks() -> None:
    p0 = np.zeros(100)
    p1 = np.zeros(100)
    p0[10:20], p1[60:70] = 1.0, 1.0
    with np.errstate(all="raise"):
        loose = symmetric_kl(p0, p1, 0.1, floor=1e-3)
        tight = symmetric_kl(p0, p1, 0.1, floor=1e-9)
        assert symmetric_kl(np.zeros(5), np.zeros(5), 1.0) == 0.0
    # each support contributes 1·log(1/ε)·(10 bins · 0.1)
    assert loose == pytest.approx(2 * np.log(1e3))
    assert tight == pytest.approx(2 * np.log(1e9))


def test_normal_reference_bandwidth_formula() -> None:
    assert normal_reference_bandwidth(1000, 2.0) == pytest.approx(2.0 * (4 / 3000) ** 0.2)
