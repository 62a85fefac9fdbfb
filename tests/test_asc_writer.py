"""The vectorised .asc formatter writes exactly python-can's ASCWriter lines (same rounding)."""

from __future__ import annotations

import numpy as np
import pytest

from sim_controller.log_writers import _asc_lines_python, asc_lines


@pytest.mark.parametrize("scale", [1e-3, 1.0, 9.99, 10.0, 99.9999, 1234.5, 1e5, 5e8])
def test_asc_lines_equal_python_formatting(scale: float) -> None:
    rng = np.random.default_rng(int(scale * 7) % 1000)
    n = 5000
    rel = np.sort(rng.uniform(0, scale, n))
    # halves at the 7th decimal, digit-count boundaries, zero
    rel[:8] = [0.0, 5e-7, 1.5e-6, 9.9999995, 0.1234565, 9.9999999, 99.9999996, 0.0000004]
    rel = np.sort(rel)
    ids = rng.integers(0, 0x800, n)
    data = rng.integers(0, 256, (n, 8), dtype=np.uint8)
    assert asc_lines(rel, ids, data, 1) == _asc_lines_python(rel, ids, data, 1)


def test_asc_lines_falls_back_for_extended_ids_and_huge_times() -> None:
    data = np.zeros((2, 8), dtype=np.uint8)
    for rel, ids in ((np.array([0.5, 1.5]), np.array([0x800, 0x1])), (np.array([2e9, 3e9]), np.array([1, 2]))):
        assert asc_lines(rel, ids, data, 2) == _asc_lines_python(rel, ids, data, 2)
    assert asc_lines(np.zeros(0), np.zeros(0, np.int64), np.zeros((0, 8), np.uint8), 1) == ""
