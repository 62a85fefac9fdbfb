"""Trace tables (CSV or Parquet) as a source: what robot vendors' trace tools export (docs/CONNECTING.md).

A ``kind = "trace"`` mapping names the columns. Wide tables have one row per time and one column per
joint and quantity (``[joint.N] speed = { column = "A1 speed [rpm]" }``; a unit in brackets in the
header is used when the mapping states none); long tables have one row per joint and time, a joint column
(``[trace] joint_column``) whose value is each joint's ``key``, and one column per quantity. Time in s or
ms (``[trace] time_unit``), any one-character separator (``;`` is common), ``,`` as decimal mark if
stated. Empty cells are missing values: a row without speed or torque is no sample; load and temperature
may be sparse. Cycle marks come from mapped ``cycle``/``segment`` or ``trigger`` columns, or from the
motion. Read in batches of the mapped columns only, in bounded memory, by :mod:`trace_table` (pyarrow:
``pip install 'joint-wear-monitor[traces]'``). A Parquet time column of timestamp or duration type is read in
its own unit (``time_unit`` applies to numbers).
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any, Callable, Iterator

import numpy as np
from numpy.typing import NDArray

from edge_monitor.sources.log_source import LogReport
from edge_monitor.sources.samples import DecodedSamples, JointColumns, StatusColumns
from edge_monitor.sources.trace_table import SkippedRows, TraceError, not_a_number, table_batches
from protocol.signal_mapping import SignalMapping, SignalRef, TraceFormat, load_mapping

log = logging.getLogger(__name__)

#: Median time steps [s] no trace of a robot joint has: slower than 10 Hz, faster than 100 kHz (the
#: agent needs >= 100 Hz); a table outside states its time in the other unit (ms read as s or back).
SLOWEST_STEP_S, FASTEST_STEP_S = 0.1, 1e-5
#: How far the rows' median time step may be from 1/rate_hz before a warning (jitter and dropped rows stay inside).
RATE_TOLERANCE = 0.1


def _column(batch: Any, name: str, where: str, decimal: str = ".") -> NDArray[np.float64]:
    """Column ``name`` as floats; empty cells NaN. pyarrow reads a column as text when one cell of the
    batch is no number: those cells become NaN (the sample stream counts them as dropped) unless half or
    more of the cells are text, which is a column that is not numeric (TraceError), as is a column of
    booleans, dates or times. A dictionary column (Parquet text) is converted once per distinct value."""
    names = batch.schema.names
    if name not in names:
        raise TraceError(f"{where}: column {name!r} is not in the table; its columns are {names[:20]}")
    array = batch.column(names.index(name))
    if why := not_a_number(array.type):          # a bool or a date read as a number would be wrong data
        raise TraceError(f"{where}: column {name!r} is {array.type}, not a number: {why}")
    if hasattr(array, "dictionary"):
        values = _floats(array.dictionary, name, where, decimal, array.indices.null_count)
        index = array.indices.to_numpy(zero_copy_only=False)
        return np.where(np.isfinite(index), values[np.nan_to_num(index).astype(np.int64)], np.nan) \
            if values.size else np.full(len(array), np.nan)
    return _floats(array, name, where, decimal)


def _floats(array: Any, name: str, where: str, decimal: str, empty: int = 0) -> NDArray[np.float64]:
    cells = array.to_numpy(zero_copy_only=False)
    if cells.dtype != object:
        try:
            return np.asarray(cells, dtype=np.float64)
        except (TypeError, ValueError):                # dates, times, durations: no number of ours
            raise TraceError(f"{where}: column {name!r} is not numeric (it holds {array.type})") from None
    values, text = _numbers_of_text(cells, decimal)
    if text and text.count >= int(np.isfinite(values).sum()) + empty:
        raise TraceError(f"{where}: column {name!r} is not numeric ({text.example!r} in {text.count} of "
                         f"{values.size} rows; decimal mark? [trace] decimal = \",\")")
    if text:
        log.warning("%s: %d cells of column %r are not numbers (e.g. %r): read as missing values",
                    where, text.count, name, text.example)
    return values


class _TextCells:
    """The cells of a column that are text, not numbers: how many and the first."""

    def __init__(self) -> None:
        self.count, self.example = 0, ""

    def __bool__(self) -> bool:
        return self.count > 0

    def add(self, cell: str) -> None:
        if not self.count:
            self.example = cell[:40]
        self.count += 1


def _numbers_of_text(cells: NDArray[Any], decimal: str) -> tuple[NDArray[np.float64], _TextCells]:
    """Floats of a column pyarrow left as text (None and blank cells NaN), and the cells that are text."""
    values = np.full(cells.size, np.nan)
    text = _TextCells()
    for i, cell in enumerate(cells):
        if cell is None or not (cell := str(cell).strip().strip('"').strip()):   # a quoted number: its number
            continue
        try:
            values[i] = float(cell.replace(decimal, ".") if decimal != "." else cell)
        except ValueError:
            text.add(cell)
    return values, text


#: Seconds per unit of a timestamp or duration column.
_UNIT_S = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "ns": 1e-9}


def _seconds(batch: Any, name: str) -> NDArray[np.float64] | None:
    """Column ``name`` in seconds if it is a timestamp (since 1970, UTC) or a duration column, else None."""
    import pyarrow as pa
    names = batch.schema.names
    if name not in names:
        return None
    kind = batch.schema.field(name).type
    if not (pa.types.is_timestamp(kind) or pa.types.is_duration(kind)):
        return None
    counts = batch.column(names.index(name)).cast(pa.int64()).to_numpy(zero_copy_only=False)
    return np.asarray(counts, dtype=np.float64) * _UNIT_S[kind.unit]


def _time(batch: Any, fmt: TraceFormat, where: str) -> NDArray[np.float64]:
    """The time column [s]: numbers in ``fmt.time_unit``, or a timestamp or duration column (its own unit)."""
    seconds = _seconds(batch, fmt.time_column)
    if seconds is not None:
        return seconds
    with np.errstate(invalid="ignore", over="ignore"):     # a damaged value: not finite, dropped and counted later
        return _column(batch, fmt.time_column, where, fmt.decimal) * (1e-3 if fmt.time_unit == "ms" else 1.0)


def _values(batch: Any, ref: SignalRef, where: str, decimal: str = ".") -> NDArray[np.float64]:
    with np.errstate(invalid="ignore", over="ignore"):     # as in _time
        return _column(batch, str(ref.column), where, decimal) * ref.factor + ref.offset


def _check_time_step(time: NDArray[np.float64], fmt: TraceFormat, where: str, rate_hz: float | None = None) -> None:
    """TraceError if the median step of the first batch's times is no robot trace's (a unit off by 1000),
    or if its times do not advance at all (every row at one time); a warning if it is not the tick ``rate_hz``
    [Hz] the samples' times are converted at (more than :data:`RATE_TOLERANCE` off)."""
    finite = time[np.isfinite(time)]
    ticks = np.unique(finite)
    if finite.size >= 10 and ticks.size < 2:
        raise TraceError(f"{where}: the time column does not advance (all of the first {finite.size} rows at "
                         f"{finite[0]:.6g}): a trace needs the time of each sample")
    if ticks.size < 10:
        return
    step = float(np.median(np.diff(ticks)))
    if step > SLOWEST_STEP_S:
        hint = ' (in ms? [trace] time_unit = "ms")' if fmt.time_unit != "ms" else ""
        raise TraceError(f"{where}: the time column steps by {step:.4g} s ({1 / step:.3g} Hz) in the median; "
                         f"the agent needs samples at >= 100 Hz{hint}")
    if step < FASTEST_STEP_S:
        hint = ' (in s? [trace] time_unit = "s")' if fmt.time_unit == "ms" else ""
        raise TraceError(f"{where}: the time column steps by {step:.4g} s ({1 / step:.3g} Hz) in the median: "
                         f"no robot trace is that fast{hint}")
    if rate_hz is not None and abs(step * rate_hz - 1.0) > RATE_TOLERANCE:
        log.warning("%s: the time column steps by %.4g s (%.4g Hz) in the median, but its samples are read at "
                    "%.4g Hz: the plateaus come out too short or too long and cycles may have no friction curve; "
                    "state the trace's rate in the mapping: rate_hz = %.4g", where, step, 1 / step, rate_hz,
                    1 / step)


def mapped_columns(mapping: SignalMapping) -> list[str]:
    """The columns a trace mapping reads (time, joint column, every mapped quantity and mark), in order."""
    fmt = mapping.trace or TraceFormat()
    refs = [getattr(jm, q) for jm in mapping.joints.values() for q in ("speed", "torque", "load", "temperature")]
    refs += [getattr(mapping.cycles, name) for name in ("cycle", "segment", "trigger")]
    names = [fmt.time_column] + ([fmt.joint_column] if fmt.layout == "long" and fmt.joint_column else [])
    return list(dict.fromkeys(names + [str(r.column) for r in refs if r is not None]))


def _joint_rows(batch: Any, fmt: TraceFormat, mapping: SignalMapping) -> dict[int, NDArray[np.bool_]]:
    """Rows of each joint of a long table: its joint column equals the joint's key (compared as text without
    quotes, a dictionary column once per distinct value)."""
    import pyarrow as pa
    import pyarrow.compute as pc
    column = batch.column(batch.schema.names.index(fmt.joint_column))
    dictionary = hasattr(column, "dictionary")
    values = pc.utf8_trim(pc.cast(column.dictionary if dictionary else column, pa.string()), '" ')   # "A1": A1
    out = {}
    for j, jm in mapping.joints.items():
        match = pc.fill_null(pc.equal(values, jm.key if jm.key is not None else str(j)), False)
        if dictionary:
            match = pc.fill_null(pc.take(match, column.indices), False)
        out[j] = np.asarray(match.to_numpy(zero_copy_only=False), dtype=bool)
    return out


def decoded_batches(path: str | Path, mapping: SignalMapping, report: LogReport | None = None,
                    rate_hz: float | None = None) -> Iterator[DecodedSamples]:
    """The table as :class:`DecodedSamples`, one per batch of rows (rows with the wrong number of cells
    are skipped and counted in ``report``; empty and non-finite cells are left as NaN: the sample stream
    counts what it drops); ``rate_hz``: the tick rate its times are read at, checked against its rows' step."""
    fmt = mapping.trace or TraceFormat()
    skipped = SkippedRows()
    first, read = True, 0
    for batch in table_batches(Path(path), fmt, mapped_columns(mapping), skipped):
        skipped.report_to(report)
        read += batch.num_rows
        time = _time(batch, fmt, mapping.where("trace.time_column"))
        if first:
            _check_time_step(time, fmt, mapping.where("trace.time_column"), rate_hz)
            first = False
        rows_of = _joint_rows(batch, fmt, mapping) if fmt.layout == "long" else {}
        out = DecodedSamples()
        for j, jm in mapping.joints.items():
            where = mapping.where(f"joint.{j}")
            rows = rows_of.get(j, np.ones(time.size, dtype=bool))
            assert jm.speed is not None and jm.torque is not None
            speed = _values(batch, jm.speed, f"{where}.speed", fmt.decimal)
            torque = _values(batch, jm.torque, f"{where}.torque", fmt.decimal)
            ok = rows & (np.isfinite(speed) | np.isfinite(torque))        # a row with neither: no sample
            out.joints[j] = JointColumns(time[ok], speed[ok], torque[ok])
            status = {q: _values(batch, ref, f"{where}.{q}", fmt.decimal) for q in ("load", "temperature")
                      if (ref := getattr(jm, q)) is not None}
            if status:
                has = rows & np.isfinite(time) & np.any([np.isfinite(v) for v in status.values()], axis=0)
                nan = np.full(int(has.sum()), np.nan)
                out.status[j] = StatusColumns(time[has], status["load"][has] if "load" in status else nan,
                                              status["temperature"][has] if "temperature" in status else nan)
        for name in ("cycle", "segment", "trigger"):
            ref = getattr(mapping.cycles, name)
            if ref is not None:
                values = _values(batch, ref, mapping.where(f"cycles.{name}"), fmt.decimal)
                ok = np.isfinite(values) & np.isfinite(time)
                out.marks[name] = (time[ok], values[ok])
        yield out
    skipped.report_to(report)
    if report is not None and report.skipped:
        log.warning("%s: %d row(s) skipped: the wrong number of cells, or not UTF-8 text (first: %s)", path,
                    report.skipped, report.examples[0])
    if read == 0 and not (report is not None and report.skipped):
        raise TraceError(f"{path} is empty (a header, no rows): was its recording stopped before it wrote anything?")


def replay_trace(agent: Any, path: str, mapping_path: str | None,
                 see_times: Callable[[NDArray[np.float64]], None] | None = None) -> LogReport:
    """Feed a trace table to ``agent`` (whose source was opened from the same mapping); ``see_times`` gets the
    sample times [s] of each batch in order."""
    if not mapping_path:
        raise TraceError(f"{path}: a trace table needs --mapping (a kind = \"trace\" mapping naming its columns)")
    mapping = load_mapping(mapping_path)
    if mapping.kind != "trace":
        raise TraceError(f"{path}: --mapping {mapping_path} is a {mapping.kind} mapping; "
                         "a table needs kind = \"trace\"")
    report = LogReport()
    for decoded in decoded_batches(path, mapping, report, agent.config.rate_hz):
        report.frames += sum(int(c.time.size) for c in decoded.joints.values())
        if see_times is not None:
            times = np.concatenate([c.time for c in decoded.joints.values()] or [np.zeros(0)])
            see_times(np.sort(times[np.isfinite(times)]))
        agent.update_ingested(agent.ingest.update_samples(decoded))
    return report
