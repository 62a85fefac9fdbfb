"""A trace file (CSV or Parquet) read as pyarrow record batches of the columns a mapping names, in bounded
memory (docs/CONNECTING.md).

CSV: the header is read here (Python's ``csv``, so quoted names work) and checked before pyarrow sees the
file: at most :data:`MAX_COLUMNS` columns, a header line of at most :data:`BLOCK_BYTES`; one pass over the
file then refuses a line longer than :data:`BLOCK_BYTES`, naming it (no trace table has one: it is damage,
e.g. a run of NUL bytes a crash left), checks the text of another encoding than UTF-8 and counts the lines of
a UTF-8 table that are not UTF-8 (more than :func:`most_undecodable` is no UTF-8 table). pyarrow then
reads the rows without quoting (a stray ``"`` damages its one cell, not the rest of the file) and converts
only the mapped columns; a row with the wrong number of cells, or not UTF-8 text, is skipped and counted
(:class:`SkippedRows`, :mod:`undecodable_lines`).
Parquet: only the mapped columns are read, text columns as dictionaries (a column of one long string
repeated a million times stays one string), and a row group whose mapped columns would unpack to more
than :data:`MAX_ROW_GROUP_BYTES` is refused, as is a mapped column of no number per row (:func:`not_a_number`).
Either: a mapped column the header has twice is refused (which is meant is unknown). A table that does not fit raises
:class:`TraceError` (exit code 2), one that cannot be read :class:`TraceUnreadable` (exit code 1).
"""

from __future__ import annotations

import codecs
import contextlib
import csv
import io
import logging
import os
import re
import sys
from collections import Counter, deque
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Iterator

from edge_monitor.sources.log_source import LogReport
from edge_monitor.sources.undecodable_lines import MARKER, MarkedLines, undecodable
from protocol.console import library_message
from protocol.files import NotARegularFile, open_regular
from protocol.signal_mapping import TraceFormat

log = logging.getLogger(__name__)

TRACE_SUFFIXES = (".csv", ".parquet", ".pq")
#: pyarrow reads a CSV in blocks of this size; a longer line is refused (no trace table has one).
BLOCK_BYTES = 4 << 20
#: Most columns a trace table may have (a vendor's trace of 8 axes × 100 signals has 800).
MAX_COLUMNS = 10_000
#: Largest unpacked size of the mapped columns of one Parquet row group [bytes].
MAX_ROW_GROUP_BYTES = 1 << 30
#: Rows per batch (≈ 0.5 MB per numeric column).
BATCH_ROWS = 1 << 16


class TraceError(ValueError):
    """A trace table that does not fit its mapping (the message names the column and the fix)."""


class TraceUnreadable(OSError):
    """A trace file that cannot be read: not a regular file (a FIFO, a device, a directory) or an I/O error."""


def is_trace_file(path: str) -> bool:
    return Path(path).suffix.lower() in TRACE_SUFFIXES


def _head(path: Path) -> bytes:
    """The first :data:`BLOCK_BYTES` of ``path`` if it names a regular file (checked without blocking on a
    FIFO or reading a device); pyarrow then opens it natively (its read-ahead threads never wait for Python)."""
    try:
        fd = open_regular(path)
        try:
            return os.read(fd, BLOCK_BYTES) if path.suffix.lower() == ".csv" else b""
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


def _codec(encoding: str) -> str:
    """pyarrow's name of ``encoding``: UTF-8 is read natively (a byte that is not UTF-8 is a conversion
    error), the others are transcoded."""
    return "utf8" if encoding.lower().replace("_", "-") == "utf-8" else encoding


def csv_header(path: Path, head: bytes, fmt: TraceFormat) -> list[str]:
    """The column names of the CSV whose first bytes are ``head`` (TraceError: no header line within
    :data:`BLOCK_BYTES`, more than :data:`MAX_COLUMNS` columns, not ``fmt.encoding`` text, or empty)."""
    if not head:
        raise TraceError(f"{path}: Empty CSV file: not a trace table")
    if _codec(fmt.encoding) == "utf8" and (end := head.find(b"\n")) >= 0:
        head = head[:end + 1]         # the rows' text is checked line by line (check_lines)
    try:
        text = codecs.getincrementaldecoder(fmt.encoding)().decode(head)
    except UnicodeError as exc:
        raise _not_text(path, fmt, exc) from None
    end = text.find("\n")
    if end < 0 and len(head) == BLOCK_BYTES:
        raise TraceError(f"{path}: its first line (the header) is longer than {BLOCK_BYTES >> 20} MiB: "
                         "not a trace table")
    line = re.split("[\r\n]", text, maxsplit=1)[0].lstrip("\ufeff")    # a lone CR ends a line too, as for pyarrow
    if line.count(fmt.separator) >= MAX_COLUMNS:
        raise TraceError(f"{path}: its header has more than {MAX_COLUMNS} columns "
                         f"({line.count(fmt.separator) + 1} {fmt.separator!r}-separated): not a trace table; "
                         "export the signals the mapping names")
    try:
        names = next(csv.reader([line], delimiter=fmt.separator, quotechar='"'), [])
    except csv.Error as exc:
        raise TraceError(f"{path}: its header line cannot be read as CSV ({exc}): not a trace table") from None
    if not names or names == [""]:
        raise TraceError(f"{path}: its first line is empty: a trace table starts with a header row")
    return [n.strip() for n in names]


def _not_text(path: Path, fmt: TraceFormat, exc: UnicodeError) -> TraceError:
    reason = exc.reason if isinstance(exc, UnicodeDecodeError) else str(exc)
    return TraceError(f"{path}: not {fmt.encoding} text ({reason}); a table from a Windows tool: "
                      "[trace] encoding = \"cp1252\" (or \"utf-16\")")


def _check_names(path: Path, names: list[str], wanted: list[str]) -> None:
    """TraceError naming the first mapped column that is not in the table (and some that are), or that the
    table has twice (which of the two is meant is unknown); a warning for columns it does not map twice."""
    for name in wanted:
        if name not in names:
            shown = names[:20] + (["…"] if len(names) > 20 else [])
            raise TraceError(f"{path}: column {name!r} is not in the table; its columns are {shown}")
    counts = Counter(names)
    for name in wanted:
        if counts[name] > 1:
            places = [i + 1 for i, n in enumerate(names) if n == name]
            times = "twice" if len(places) == 2 else f"{len(places)} times"
            raise TraceError(f"{path}: column {name!r} appears {times} in the table (columns "
                             f"{', '.join(map(str, places))}); rename one: which the mapping means is unknown")
    unused = [n for n, k in counts.items() if k > 1 and n not in wanted]
    if unused:
        log.warning("%s: column(s) %s appear more than once in the table; the mapping does not read them",
                    path, ", ".join(map(repr, unused[:5])) + (", …" if len(unused) > 5 else ""))


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


class SkippedRows:
    """pyarrow's ``invalid_row_handler``: a row with too few or too many cells, or a line that is not UTF-8
    (:data:`MARKER`: its description from :meth:`undecodable`), is skipped and counted."""

    def __init__(self) -> None:
        self.count = 0
        self.examples: list[str] = []
        self._undecodable: deque[str] = deque()

    def undecodable(self, line: int, description: str) -> None:
        """Line ``line`` is not UTF-8: it comes as a :data:`MARKER` row, in file order (the first few kept: pyarrow's
        row numbers skip blank lines, so the description, which has the file's line number, is what is shown)."""
        if len(self._undecodable) < 5:
            self._undecodable.append(description)

    def __call__(self, row: Any) -> str:
        self.count += 1
        text = (row.text or "")[:80]
        if text == MARKER.decode():
            described = self._undecodable.popleft() if self._undecodable else "a line not UTF-8 text"
            if len(self.examples) < 5:
                self.examples.append(described)
            return "skip"
        if len(self.examples) < 5:
            where = f"line {row.number}: " if row.number is not None else ""
            self.examples.append(f"{where}a row with {row.actual_columns} cells, {row.expected_columns} expected: "
                                     f"{text!r}")
        return "skip"

    def report_to(self, report: LogReport | None) -> None:
        if report is not None and self.count:
            report.skipped += self.count
            report.frames_skipped += self.count
            report.examples[:] = (report.examples + self.examples)[:5]
        self.count, self.examples = 0, []


def _size(n: int) -> str:
    return f"{n >> 20} MiB" if n % (1 << 20) == 0 else f"{n} bytes"


#: Lines not UTF-8 beyond which, at more than a tenth of the lines read, the table is refused at once.
SURELY_ENCODED = 1000


def most_undecodable(lines: int) -> int:
    """Most lines of a UTF-8 table of ``lines`` lines that may be other than UTF-8 (1 %, at least 10): stray bytes
    are skipped with their rows; more is a table in another encoding. Judged on the whole file: a burst of
    damage near its start is no other encoding."""
    return max(10, lines // 100)


def check_lines(path: Path, encoding: str) -> int:
    """One pass over the file in blocks: TraceError for the first line longer than :data:`BLOCK_BYTES`
    (naming it and the limit), UnicodeError where it is not ``encoding`` text. Other encodings than UTF-8
    are decoded here before pyarrow transcodes them: a decode error inside pyarrow's transcoder leaves one of
    its threads running, and the process may then abort at exit ("terminate called without an active
    exception"). In UTF-8, the number of lines that are not UTF-8 (TraceError beyond :func:`most_undecodable`
    of the file's lines)."""
    decoder = None if _codec(encoding) == "utf8" else codecs.getincrementaldecoder(encoding)()
    ended = 0            # lines ended before the current one
    length = 0           # bytes of the current line so far
    tail, bad, first_bad = b"", 0, ""      # UTF-8: the current line's bytes so far, lines not UTF-8, the first
    with open(path, "rb") as f:
        while True:
            block = f.read(BLOCK_BYTES)
            first = block.find(b"\n")
            if length + (len(block) if first < 0 else first) > BLOCK_BYTES:
                raise TraceError(f"{path}: line {ended + 1} is longer than {_size(BLOCK_BYTES)}, the longest "
                                 "line a trace table may have: not a row of a table (damage, e.g. bytes a crash "
                                 f"left); remove line {ended + 1} or export the table again")
            if decoder is None:
                data = tail + block
                cut = data.rfind(b"\n") + 1 if block else len(data)
                for number, _, _, what in undecodable(data[:cut], ended + 1):
                    bad, first_bad = bad + 1, first_bad or f"{what} in line {number}"
                    if bad > SURELY_ENCODED and 10 * bad > number:       # no stray bytes: stop reading
                        raise _other_encoding(path, bad, f"first {number}", first_bad)
                tail = data[cut:]
            elif block:
                decoder.decode(block)
            if not block:
                break
            if first < 0:
                length += len(block)
            else:
                ended += block.count(b"\n")
                length = len(block) - block.rfind(b"\n") - 1
    if decoder is not None:
        decoder.decode(b"", final=True)
    lines = ended + (length > 0)
    if bad > most_undecodable(lines):
        raise _other_encoding(path, bad, str(lines), first_bad)
    return bad


def _other_encoding(path: Path, bad: int, lines: str, first_bad: str) -> TraceError:
    """The error for a table in another encoding than UTF-8 (``lines``: "2001" or "first 1002")."""
    return TraceError(f"{path}: not UTF-8 text ({bad} of its {lines} lines are not, the first: {first_bad}); a "
                      "table from a Windows tool: [trace] encoding = \"cp1252\" (or \"utf-16\"), else export it "
                      "again as UTF-8")


def _csv_batches(path: Path, head: bytes, fmt: TraceFormat, columns: list[str], skipped: SkippedRows) -> Iterator[Any]:
    import pyarrow.csv as pcsv
    names = csv_header(path, head, fmt)
    _check_names(path, names, columns)
    undecodable_lines = check_lines(path, fmt.encoding)
    source: Any = str(path)            # read natively; a table with lines not UTF-8 has them replaced
    if undecodable_lines:
        log.warning("%s: %d line(s) are not UTF-8 text: their rows are skipped (export the table again as "
                    "UTF-8 to keep them)", path, undecodable_lines)
        source = io.BufferedReader(MarkedLines(path, BLOCK_BYTES, skipped.undecodable), BLOCK_BYTES)
    with _quiet_undecodable_rows(), contextlib.closing(source) if undecodable_lines else contextlib.nullcontext():
        reader = pcsv.open_csv(
            source, parse_options=pcsv.ParseOptions(delimiter=fmt.separator, quote_char=False,
                                                       invalid_row_handler=skipped),
            convert_options=pcsv.ConvertOptions(decimal_point=fmt.decimal, include_columns=columns),
            read_options=pcsv.ReadOptions(block_size=BLOCK_BYTES, encoding=_codec(fmt.encoding), use_threads=False,
                                          column_names=names, skip_rows=1))
        yield from reader


def _parquet_batches(path: Path, columns: list[str], time_column: str) -> Iterator[Any]:
    try:
        import pyarrow.parquet as pq
    except ImportError:
        raise TraceError("reading Parquet needs pyarrow: pip install 'joint-wear-monitor[traces]'") from None
    schema = pq.ParquetFile(str(path)).schema_arrow
    names = schema.names
    _check_names(path, names, columns)
    _check_types(path, schema, columns, time_column)
    table = pq.ParquetFile(str(path), read_dictionary=columns)     # text columns stay dictionaries
    meta = table.metadata
    wanted = [names.index(c) for c in columns]
    for g in range(meta.num_row_groups):
        group = meta.row_group(g)
        size = sum(group.column(i).total_uncompressed_size for i in wanted if i < group.num_columns)
        if size > MAX_ROW_GROUP_BYTES:
            raise TraceError(f"{path}: row group {g} holds {size / 2**20:.0f} MiB of the mapped columns, more than "
                             f"{MAX_ROW_GROUP_BYTES >> 20} MiB: write the table with smaller row groups")
    yield from table.iter_batches(batch_size=BATCH_ROWS, columns=columns)


def _check_types(path: Path, schema: Any, columns: list[str], time_column: str) -> None:
    """TraceError for a mapped Parquet column that holds no one number per row: a list, a struct, a map, or a
    value column of :func:`not_a_number` type (the time column may be a timestamp or a duration)."""
    import pyarrow as pa
    for name in columns:
        kind = schema.field(name).type
        if pa.types.is_nested(kind):
            shown = re.sub(r"\b(element|item): ", "", str(kind))
            raise TraceError(f"{path}: column {name!r} is {shown}, not a number: a trace table has one value per "
                             "row and column (write each element as its own column)")
        timed = name == time_column and (pa.types.is_timestamp(kind) or pa.types.is_duration(kind))
        if not timed and not_a_number(kind):
            raise TraceError(f"{path}: column {name!r} is {kind}, not a number: "
                             f"{not_a_number(kind)}")


def not_a_number(kind: Any) -> str:
    """Why a column of pyarrow type ``kind`` holds no numbers of ours (a bool, a date or time), else ""."""
    import pyarrow as pa
    if pa.types.is_dictionary(kind):
        kind = kind.value_type
    if pa.types.is_boolean(kind):
        return "true/false read as 1/0 would be wrong data; map the column of the quantity itself"
    if pa.types.is_temporal(kind):
        return ("a date, time or duration is no speed, torque, load, temperature or mark; map the column of the "
                "quantity itself (only the time column may be a timestamp or a duration)")
    return ""


def table_batches(path: Path, fmt: TraceFormat, columns: list[str], skipped: SkippedRows) -> Iterator[Any]:
    """pyarrow record batches of ``columns`` of the table (see the module docstring)."""
    try:
        import pyarrow as pa
    except ImportError:
        raise TraceError("reading trace tables needs pyarrow: pip install 'joint-wear-monitor[traces]'") from None
    head = _head(path)
    columns = list(dict.fromkeys(columns))
    try:
        if path.suffix.lower() == ".csv":
            yield from _csv_batches(path, head, fmt, columns, skipped)
        else:
            yield from _parquet_batches(path, columns, fmt.time_column)
    except OSError as exc:                   # pyarrow's I/O errors are OSErrors
        if exc.errno is None and path.suffix.lower() != ".csv":      # not the system's: a page that does not decode
            raise TraceError(f"{path}: a damaged Parquet file ({library_message(exc)}): it cannot be read to its "
                             "end; export or copy it again") from None
        raise TraceUnreadable(f"cannot read {path}: {library_message(exc)}") from None
    except UnicodeError as exc:              # a decode error, or UTF-16 without its byte-order mark
        raise _not_text(path, fmt, exc) from None
    except pa.ArrowException as exc:
        first = library_message(exc)
        hint = (f" (a line longer than {BLOCK_BYTES >> 20} MiB)" if "straddl" in first
                else "; damaged or cut short? export or copy it again" if path.suffix.lower() != ".csv" else "")
        raise TraceError(f"{path}: not a {path.suffix.lower()[1:]} table its mapping can read: {first}{hint}") from None

