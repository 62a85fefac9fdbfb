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

import codecs
import logging
import os
import sys
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Iterator

import numpy as np
from numpy.typing import NDArray

from edge_monitor.sources.log_source import LogReport
from edge_monitor.sources.samples import DecodedSamples, JointColumns, StatusColumns
from protocol.files import NotARegularFile, open_regular
from protocol.signal_mapping import SignalMapping, SignalRef, TraceFormat, load_mapping

log = logging.getLogger(__name__)

TRACE_SUFFIXES = (".csv", ".parquet", ".pq")
#: pyarrow reads a CSV in blocks of this size; a longer line is an error (no trace table has one).
BLOCK_BYTES = 4 << 20
#: Median time steps [s] no trace of a robot joint has: slower than 10 Hz, faster than 100 kHz (the
#: agent needs >= 100 Hz); a table outside states its time in the other unit (ms read as s or back).
SLOWEST_STEP_S, FASTEST_STEP_S = 0.1, 1e-5


class TraceError(ValueError):
    """A trace table that does not fit its mapping (the message names the column and the fix)."""


class TraceUnreadable(OSError):
    """A trace file that cannot be read: not a regular file (a FIFO, a device, a directory) or an I/O error."""


def is_trace_file(path: str) -> bool:
    return Path(path).suffix.lower() in TRACE_SUFFIXES


def _regular(path: Path) -> str:
    """``path`` if it names a regular file (checked without blocking on a FIFO or reading a device);
    pyarrow then opens it natively (its read-ahead threads never wait for Python)."""
    try:
        fd = open_regular(path)
        try:
            head = os.read(fd, BLOCK_BYTES) if path.suffix.lower() == ".csv" else b"\n"
        finally:
            os.close(fd)
    except FileNotFoundError:
        raise FileNotFoundError(f"trace file {path} not found") from None
    except NotARegularFile as exc:
        raise TraceUnreadable(f"{path}: {exc.reason}") from None
    except IsADirectoryError:
        raise TraceUnreadable(f"{path}: it is a directory, not a regular file") from None
    except OSError as exc:
        raise TraceUnreadable(f"cannot read {path}: {exc.strerror or exc}") from None
    if len(head) == BLOCK_BYTES and b"\n" not in head:     # pyarrow may crash on such a header
        raise TraceError(f"{path}: its first line (the header) is longer than {BLOCK_BYTES >> 20} MiB: "
                         "not a trace table")
    return str(path)


@contextmanager
def _quiet_undecodable_rows() -> Iterator[None]:
    """pyarrow decodes a malformed row's text for the row handler and reports a row that is not text
    as "Exception ignored" (with a traceback) before failing the table; the failure says it already."""
    previous = sys.unraisablehook

    def hook(unraisable: Any) -> None:
        if not isinstance(unraisable.exc_value, UnicodeDecodeError):
            previous(unraisable)

    sys.unraisablehook = hook
    try:
        yield
    finally:
        sys.unraisablehook = previous


class _SkippedRows:
    """pyarrow's ``invalid_row_handler``: a row with too few or too many cells is skipped and counted."""

    def __init__(self) -> None:
        self.count = 0
        self.examples: list[str] = []

    def __call__(self, row: Any) -> str:
        self.count += 1
        if len(self.examples) < 5:
            text = (row.text or "")[:80]
            self.examples.append(f"a row with {row.actual_columns} cells, {row.expected_columns} expected: "
                                 f"{text!r}")
        return "skip"

    def report_to(self, report: LogReport | None) -> None:
        if report is not None and self.count:
            report.skipped += self.count
            report.frames_skipped += self.count
            report.examples[:] = (report.examples + self.examples)[:5]
        self.count, self.examples = 0, []


def _codec(encoding: str) -> str:
    """pyarrow's name of ``encoding``: UTF-8 is read natively (a byte that is not UTF-8 is a conversion
    error), the others are transcoded."""
    return "utf8" if encoding.lower().replace("_", "-") == "utf-8" else encoding


def _decode_through(file: str, encoding: str) -> None:
    """Decode the whole file in blocks (UnicodeError where it is not ``encoding`` text) before pyarrow
    transcodes it: a decode error inside pyarrow's transcoder leaves one of its threads running, and the
    process may then abort at exit ("terminate called without an active exception")."""
    decoder = codecs.getincrementaldecoder(encoding)()
    with open(file, "rb") as f:
        while block := f.read(BLOCK_BYTES):
            decoder.decode(block)
    decoder.decode(b"", final=True)


def _batches(path: Path, fmt: TraceFormat, skipped: _SkippedRows) -> Iterator[Any]:
    """pyarrow record batches of the table; TraceError (exit 2) where it is no table, TraceUnreadable
    (exit 1) where it cannot be read."""
    import pyarrow as pa
    file = _regular(path)
    try:
        if path.suffix.lower() == ".csv":
            import pyarrow.csv as pcsv
            if _codec(fmt.encoding) != "utf8":
                _decode_through(file, fmt.encoding)
            with _quiet_undecodable_rows():
                reader = pcsv.open_csv(
                    file, parse_options=pcsv.ParseOptions(delimiter=fmt.separator, invalid_row_handler=skipped),
                    convert_options=pcsv.ConvertOptions(decimal_point=fmt.decimal),
                    read_options=pcsv.ReadOptions(block_size=BLOCK_BYTES, encoding=_codec(fmt.encoding),
                                                  use_threads=False))
                _ = reader.schema.names              # the header decoded here, inside the error handling
                yield from reader
            return
        try:
            import pyarrow.parquet as pq
        except ImportError:
            raise TraceError("reading Parquet needs pyarrow: pip install 'joint-wear-monitor[parquet]'") from None
        table = pq.ParquetFile(file)
        _ = table.schema_arrow.names
        yield from table.iter_batches(batch_size=1 << 16)
    except OSError as exc:                   # pyarrow's I/O errors are OSErrors
        raise TraceUnreadable(f"cannot read {path}: {exc}") from None
    except UnicodeError as exc:              # a decode error, or UTF-16 without its byte-order mark
        reason = exc.reason if isinstance(exc, UnicodeDecodeError) else str(exc)
        raise TraceError(f"{path}: not {fmt.encoding} text ({reason}); a table from a Windows tool: "
                         "[trace] encoding = \"cp1252\" (or \"utf-16\")") from None
    except pa.ArrowException as exc:
        first = (str(exc).strip().splitlines() or [""])[0][:300]
        hint = (f" (a line longer than {BLOCK_BYTES >> 20} MiB)" if "straddl" in first else "")
        raise TraceError(f"{path}: not a {path.suffix.lower()[1:]} table its mapping can read: {first}{hint}") from None


def _column(batch: Any, name: str, where: str, decimal: str = ".") -> NDArray[np.float64]:
    """Column ``name`` as floats; empty cells NaN. pyarrow reads a column as text when one cell of the
    batch is no number: those cells become NaN (the sample stream counts them as dropped) unless half or
    more of the cells are text, which is a column that is not numeric (TraceError)."""
    names = batch.schema.names
    if name not in names:
        raise TraceError(f"{where}: column {name!r} is not in the table; its columns are {names}")
    array = batch.column(names.index(name))
    cells = array.to_numpy(zero_copy_only=False)
    if cells.dtype != object:
        try:
            return np.asarray(cells, dtype=np.float64)
        except (TypeError, ValueError):                # dates, times, durations: no number of ours
            raise TraceError(f"{where}: column {name!r} is not numeric (it holds {array.type})") from None
    values, text = _numbers_of_text(cells, decimal)
    if text and text.count >= int(np.isfinite(values).sum()):
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
        if cell is None or not (cell := str(cell).strip()):
            continue
        try:
            values[i] = float(cell.replace(decimal, ".") if decimal != "." else cell)
        except ValueError:
            text.add(cell)
    return values, text


def _values(batch: Any, ref: SignalRef, where: str, decimal: str = ".") -> NDArray[np.float64]:
    return _column(batch, str(ref.column), where, decimal) * ref.factor + ref.offset


def _check_time_step(time: NDArray[np.float64], fmt: TraceFormat, where: str) -> None:
    """TraceError if the median step of the first batch's times is no robot trace's (a unit off by 1000)."""
    ticks = np.unique(time[np.isfinite(time)])
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


def decoded_batches(path: str | Path, mapping: SignalMapping,
                    report: LogReport | None = None) -> Iterator[DecodedSamples]:
    """The table as :class:`DecodedSamples`, one per batch of rows (rows with the wrong number of cells
    are skipped and counted in ``report``; empty and non-finite cells are left as NaN: the sample stream
    counts what it drops)."""
    fmt = mapping.trace or TraceFormat()
    scale = 1e-3 if fmt.time_unit == "ms" else 1.0
    skipped = _SkippedRows()
    first = True
    for batch in _batches(Path(path), fmt, skipped):
        skipped.report_to(report)
        time = _column(batch, fmt.time_column, mapping.where("trace.time_column"), fmt.decimal) * scale
        if first:
            _check_time_step(time, fmt, mapping.where("trace.time_column"))
            first = False
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


def replay_trace(agent: Any, path: str, mapping_path: str | None) -> LogReport:
    """Feed a trace table to ``agent`` (whose source was opened from the same mapping)."""
    if not mapping_path:
        raise TraceError(f"{path}: a trace table needs --mapping (a kind = \"trace\" mapping naming its columns)")
    mapping = load_mapping(mapping_path)
    if mapping.kind != "trace":
        raise TraceError(f"{path}: --mapping {mapping_path} is a {mapping.kind} mapping; "
                         "a table needs kind = \"trace\"")
    report = LogReport()
    for decoded in decoded_batches(path, mapping, report):
        report.frames += sum(int(c.time.size) for c in decoded.joints.values())
        agent.update_ingested(agent.ingest.update_samples(decoded))
    return report
