"""Trace tables (CSV or Parquet) as a source: what robot vendors' trace tools export (docs/CONNECTING.md).

A ``kind = "trace"`` mapping names the columns. Wide tables have one row per time and one column per
joint and quantity (``[joint.N] speed = { column = "A1 speed [rpm]" }``; a unit in brackets in the
header is used when the mapping states none); long tables have one row per joint and time, a joint column
(``[trace] joint_column``) whose value is each joint's ``key``, and one column per quantity. Time in s or
ms (``[trace] time_unit``), any one-character separator (``;`` is common), ``,`` as decimal mark if
stated. Empty cells are missing values: a row without speed or torque is no sample; load and temperature
may be sparse. Cycle marks come from mapped ``cycle``/``segment`` or ``trigger`` columns, or from the
motion. Read in batches with pyarrow (``pyarrow.csv``; Parquet needs ``pip install
joint-wear-monitor[parquet]`` where rerun-sdk did not bring pyarrow).
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any, Iterator

import numpy as np
from numpy.typing import NDArray

from edge_monitor.pipeline.log_source import LogReport
from edge_monitor.pipeline.samples import DecodedSamples, JointColumns, StatusColumns
from protocol.signal_mapping import SignalMapping, SignalRef, TraceFormat, load_mapping

log = logging.getLogger(__name__)

TRACE_SUFFIXES = (".csv", ".parquet", ".pq")


class TraceError(ValueError):
    """A trace table that does not fit its mapping (the message names the column and the fix)."""


def is_trace_file(path: str) -> bool:
    return Path(path).suffix.lower() in TRACE_SUFFIXES


def _batches(path: Path, fmt: TraceFormat) -> Iterator[Any]:
    """pyarrow record batches of the table."""
    if path.suffix.lower() == ".csv":
        import pyarrow.csv as pcsv
        reader = pcsv.open_csv(str(path), parse_options=pcsv.ParseOptions(delimiter=fmt.separator),
                               convert_options=pcsv.ConvertOptions(decimal_point=fmt.decimal),
                               read_options=pcsv.ReadOptions(block_size=1 << 22))
        yield from reader
        return
    try:
        import pyarrow.parquet as pq
    except ImportError:
        raise TraceError("reading Parquet needs pyarrow: pip install 'joint-wear-monitor[parquet]'") from None
    yield from pq.ParquetFile(str(path)).iter_batches(batch_size=1 << 16)


def _column(batch: Any, name: str, where: str) -> NDArray[np.float64]:
    names = batch.schema.names
    if name not in names:
        raise TraceError(f"{where}: column {name!r} is not in the table; its columns are {names}")
    array = batch.column(names.index(name))
    try:
        return np.asarray(array.to_numpy(zero_copy_only=False), dtype=np.float64)
    except (TypeError, ValueError):
        raise TraceError(f"{where}: column {name!r} is not numeric (decimal mark? [trace] decimal = \",\")") from None


def _values(batch: Any, ref: SignalRef, where: str) -> NDArray[np.float64]:
    return _column(batch, str(ref.column), where) * ref.factor + ref.offset


def decoded_batches(path: str | Path, mapping: SignalMapping) -> Iterator[DecodedSamples]:
    """The table as :class:`DecodedSamples`, one per batch of rows."""
    fmt = mapping.trace or TraceFormat()
    scale = 1e-3 if fmt.time_unit == "ms" else 1.0
    for batch in _batches(Path(path), fmt):
        time = _column(batch, fmt.time_column, mapping.where("trace.time_column")) * scale
        rows_of: dict[int, NDArray[np.bool_]] = {}
        if fmt.layout == "long":
            keys = batch.column(batch.schema.names.index(fmt.joint_column)).to_pylist() \
                if fmt.joint_column in batch.schema.names else None
            if keys is None:
                raise TraceError(f"{mapping.where('trace.joint_column')}: column {fmt.joint_column!r} is not in "
                                 f"the table; its columns are {batch.schema.names}")
            text = np.asarray([str(k) for k in keys])
            rows_of = {j: text == (jm.key if jm.key is not None else str(j)) for j, jm in mapping.joints.items()}
        out = DecodedSamples()
        for j, jm in mapping.joints.items():
            where = mapping.where(f"joint.{j}")
            rows = rows_of.get(j, np.ones(time.size, dtype=bool))
            assert jm.speed is not None and jm.torque is not None
            speed, torque = _values(batch, jm.speed, f"{where}.speed"), _values(batch, jm.torque, f"{where}.torque")
            ok = rows & np.isfinite(time) & np.isfinite(speed) & np.isfinite(torque)
            out.joints[j] = JointColumns(time[ok], speed[ok], torque[ok])
            status = {q: _values(batch, ref, f"{where}.{q}") for q in ("load", "temperature")
                      if (ref := getattr(jm, q)) is not None}
            if status:
                has = rows & np.isfinite(time) & np.any([np.isfinite(v) for v in status.values()], axis=0)
                nan = np.full(int(has.sum()), np.nan)
                out.status[j] = StatusColumns(time[has], status["load"][has] if "load" in status else nan,
                                              status["temperature"][has] if "temperature" in status else nan)
        for name in ("cycle", "segment", "trigger"):
            ref = getattr(mapping.cycles, name)
            if ref is not None:
                values = _values(batch, ref, mapping.where(f"cycles.{name}"))
                ok = np.isfinite(values) & np.isfinite(time)
                out.marks[name] = (time[ok], values[ok])
        yield out


def replay_trace(agent: Any, path: str, mapping_path: str | None) -> LogReport:
    """Feed a trace table to ``agent`` (whose source was opened from the same mapping)."""
    if not mapping_path:
        raise TraceError(f"{path}: a trace table needs --mapping (a kind = \"trace\" mapping naming its columns)")
    mapping = load_mapping(mapping_path)
    if mapping.kind != "trace":
        raise TraceError(f"{path}: --mapping {mapping_path} is a {mapping.kind} mapping; "
                         "a table needs kind = \"trace\"")
    if not Path(path).exists():
        raise FileNotFoundError(f"trace file {path} not found")
    report = LogReport()
    for decoded in decoded_batches(path, mapping):
        report.frames += sum(int(c.time.size) for c in decoded.joints.values())
        agent.update_ingested(agent.ingest.update_samples(decoded))
    return report
