"""SlicedKDE: samples moved at the window's end by ε·d (edge_monitor/stats/sliced_kde.py)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from edge_monitor.stats.kde_stream import StreamingKDE, symmetric_kl
from edge_monitor.stats.sliced_kde import SlicedKDE

LO, HI, N = -1.0, 1.0, 4096
D_MAX, ANCHORS = 0.08, 9


def _data(seed: int, n: int = 20_000, on_anchors: bool = False) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    y = np.concatenate([rng.normal(-0.2, 0.02, n // 2), rng.normal(0.25, 0.03, n - n // 2)])
    if on_anchors:
        d = rng.choice(np.linspace(-D_MAX, D_MAX, ANCHORS), size=n)
    else:
        d = rng.uniform(-D_MAX, D_MAX, size=n)
    return y, d


def _plain(values: np.ndarray, shift: float = 0.0) -> StreamingKDE:
    kde = StreamingKDE(LO, HI, 512)
    kde.update(values - shift)
    return kde


def test_without_a_correction_it_is_the_plain_kde() -> None:
    y, d = _data(1)
    sliced = SlicedKDE(LO, HI, N, D_MAX, ANCHORS)
    sliced.update(y, d)
    window, plain = sliced.collapse(0.0, LO, HI, 512), _plain(y)
    assert window.n_samples == plain.n_samples
    assert window.mean == pytest.approx(plain.mean, rel=1e-12)
    assert window.bandwidth == pytest.approx(plain.bandwidth, rel=1e-9)
    # two linear binnings (dx 4.9e-4 and 3.9e-3) against one: far below the KL level of real cycles (≈ 0.02)
    assert symmetric_kl(plain.density(), window.density(), plain.dx) < 1e-4


@pytest.mark.parametrize("eps", [-0.7, 0.3, 1.0])
def test_samples_on_anchors_move_exactly_by_eps_times_d(eps: float) -> None:
    y, d = _data(2, on_anchors=True)
    sliced = SlicedKDE(LO, HI, N, D_MAX, ANCHORS)
    sliced.update(y, d)
    window, exact = sliced.collapse(eps, LO, HI, 512), _plain(y - eps * d)
    assert window.mean == pytest.approx(exact.mean, abs=1e-12)
    assert window.bandwidth == pytest.approx(exact.bandwidth, rel=1e-9)
    corrected = symmetric_kl(exact.density(), window.density(), exact.dx)
    assert corrected < 1e-4
    # the other side: not moving them is far off
    assert symmetric_kl(exact.density(), _plain(y).density(), exact.dx) > 50 * corrected


def test_samples_between_anchors_spread_by_at_most_eps_times_the_spacing() -> None:
    """A sample between anchors is split over |ε|·Δd around its corrected position: the corrected
    density is the exact one smoothed by at most that much, so with Δd·|ε| well below the bandwidth
    the densities agree to a small KL, and the moments are exact."""
    y, d = _data(3)
    eps = 0.5
    sliced = SlicedKDE(LO, HI, N, D_MAX, ANCHORS)
    sliced.update(y, d)
    window, exact = sliced.collapse(eps, LO, HI, 512), _plain(y - eps * d)
    assert window.mean == pytest.approx(exact.mean, abs=1e-12)
    assert window.m2 == pytest.approx(exact.m2, rel=1e-9)
    spacing = 2 * D_MAX / (ANCHORS - 1)
    assert eps * spacing < exact.bandwidth        # the regime the agent works in (docs/KL_DETECTOR.md)
    corrected = symmetric_kl(exact.density(), window.density(), exact.dx)
    assert corrected < 5e-3
    assert symmetric_kl(exact.density(), _plain(y).density(), exact.dx) > 10 * corrected


def test_blocks_give_the_same_window_as_one_block() -> None:
    y, d = _data(4, n=5_000)
    whole, parts = SlicedKDE(LO, HI, N, D_MAX, ANCHORS), SlicedKDE(LO, HI, N, D_MAX, ANCHORS)
    whole.update(y, d)
    for i in range(0, y.size, 37):
        parts.update(y[i:i + 37], d[i:i + 37])
    np.testing.assert_allclose(parts.mass, whole.mass, rtol=0, atol=1e-9)
    np.testing.assert_allclose(parts.mean, whole.mean, rtol=1e-12)
    np.testing.assert_allclose(parts.m2, whole.m2, rtol=1e-9)


def test_bad_samples_are_counted_not_binned() -> None:
    sliced = SlicedKDE(LO, HI, N, D_MAX, ANCHORS)
    sliced.update(np.array([0.0, np.nan, 0.1, 5.0, -5.0, 0.2]), np.array([0.0, 0.0, np.inf, 0.0, 0.0, 1.0]))
    assert (sliced.n_nonfinite, sliced.n_above, sliced.n_below, sliced.n_clipped) == (2, 1, 1, 1)
    assert sliced.mass.sum() == pytest.approx(2.0)
    with pytest.raises(ValueError, match="coefficients"):
        sliced.update(np.zeros(3), np.zeros(2))


def test_state_round_trip_mid_window() -> None:
    y, d = _data(5, n=3_000)
    sliced = SlicedKDE(LO, HI, N, D_MAX, ANCHORS)
    sliced.update(y[:1000], d[:1000])
    restored = SlicedKDE.from_state(sliced.state_dict())
    for kde in (sliced, restored):
        kde.update(y[1000:], d[1000:])
    np.testing.assert_array_equal(restored.mass, sliced.mass)
    assert restored.collapse(0.4, LO, HI, 512).m2 == sliced.collapse(0.4, LO, HI, 512).m2
    state = sliced.state_dict()
    state["slices"][0] = {"offset": N - 1, "mass": [1.0, 1.0]}
    with pytest.raises(ValueError, match="slice 0"):
        SlicedKDE.from_state(state)


@settings(max_examples=60, deadline=None)
@given(values=st.lists(st.floats(-0.9, 0.9), min_size=2, max_size=200),
       coefficients=st.lists(st.floats(-0.2, 0.2), min_size=200, max_size=200),
       eps=st.floats(-1.0, 1.0))
def test_collapse_conserves_mass_and_the_exact_mean(values: list[float], coefficients: list[float],
                                                    eps: float) -> None:
    y = np.asarray(values)
    d = np.clip(np.asarray(coefficients[:y.size]), -D_MAX, D_MAX)
    sliced = SlicedKDE(LO, HI, 1024, D_MAX, ANCHORS)
    sliced.update(y, d)
    window = sliced.collapse(eps, LO, HI, 256, shift=0.05)
    assert window.mass.sum() + window.mass_outside == pytest.approx(y.size)
    assert window.mean == pytest.approx(float(np.mean(y - eps * d)) - 0.05, abs=1e-9)
