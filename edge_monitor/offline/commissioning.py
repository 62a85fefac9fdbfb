"""Commissioning (offline): a joint's nominal friction model from a CSV of nominal friction data.

The CSV names the columns ``speed`` [rad/s], ``temperature`` [°C], ``load`` and ``friction``
(dimensionless); the identification itself (variable projection, covariance) is
:mod:`joint_model.identification`, shared with the agent's per-joint learning.
"""

from __future__ import annotations

import csv
import math
from pathlib import Path

import numpy as np

from joint_model.identification import (
    DATA_COLUMNS,
    CommissioningData,
    CommissioningResult,
    IdentificationDataError,
    identify,
    make_data,
)

#: Columns the CSV must name (extra columns are ignored).
CSV_COLUMNS: tuple[str, ...] = DATA_COLUMNS
#: A CSV that cannot be used (the message names the column/row and the fix).
CommissioningDataError = IdentificationDataError

__all__ = ["CSV_COLUMNS", "CommissioningData", "CommissioningDataError", "CommissioningResult", "identify",
           "load_csv", "make_data"]


def load_csv(path: str | Path) -> CommissioningData:
    """Read a CSV with a header containing ``speed, temperature, load, friction`` (extra columns ignored)."""
    try:
        with open(path, newline="", encoding="utf-8") as handle:
            reader = csv.DictReader(handle)
            header = [h.strip() for h in (reader.fieldnames or [])]
            missing = [c for c in CSV_COLUMNS if c not in header]
            if missing:
                raise CommissioningDataError(
                    f"{path}: missing column(s) {missing}; the header must name {list(CSV_COLUMNS)}")
            columns: dict[str, list[float]] = {c: [] for c in CSV_COLUMNS}
            for row_number, row in enumerate(reader, start=2):
                row = {k.strip(): v for k, v in row.items() if k is not None}
                for column in CSV_COLUMNS:
                    columns[column].append(_parse_number(row.get(column), column, row_number, path))
    except OSError as exc:
        raise CommissioningDataError(f"{path}: cannot read: {exc}") from None
    except UnicodeDecodeError as exc:
        raise CommissioningDataError(f"{path}: not UTF-8 text (byte {exc.start}): save the CSV as UTF-8") from None
    return make_data(**{c: np.array(columns[c]) for c in CSV_COLUMNS})


def _parse_number(raw: str | None, column: str, row_number: int, path: str | Path) -> float:
    try:
        value = float(raw)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        raise CommissioningDataError(f"{path}: row {row_number}, column '{column}': "
                                     f"expected a number, got {raw!r}") from None
    if not math.isfinite(value):
        raise CommissioningDataError(f"{path}: row {row_number}, column '{column}': must be finite, got {raw!r}")
    return value
