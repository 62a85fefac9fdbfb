"""Columns of a trace table that cannot be read as the mapping means them, each checked on both sides: a
mapped column the header has twice, or a value column of booleans or dates, is refused naming it (exit 2,
one line: the last test runs the commands); the same tiny table without the fault reads its samples; an
unmapped column twice is only warned about."""

from __future__ import annotations

import logging
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.csv as pcsv
import pyarrow.parquet as pq
import pytest

from edge_monitor.sources.trace_source import decoded_batches
from edge_monitor.sources.trace_table import TraceError
from protocol.signal_mapping import load_mapping

EM = [sys.executable, "-m", "edge_monitor.cli"]
SPEED, TORQUE = "J0 speed [rad/s]", "J0 torque [fraction]"
ROWS = 40
MAPPING = f"""kind = "trace"
rate_hz = 500.0
[trace]
separator = ";"
time_column = "time [s]"
[cycles]
from = "controller"
cycle = {{ column = "cycle" }}
segment = {{ column = "segment" }}
[joint.0]
speed = {{ column = "{SPEED}" }}
torque = {{ column = "{TORQUE}" }}
"""


def _table() -> pa.Table:
    """A tiny wide table of joint 0 at 500 Hz."""
    return pa.table({"time [s]": np.arange(1, ROWS + 1) * 0.002, SPEED: np.linspace(-3.0, 3.0, ROWS),
                     TORQUE: np.full(ROWS, 0.4), "cycle": np.zeros(ROWS), "segment": np.ones(ROWS)})


def _write(tmp: Path, name: str, table: pa.Table) -> tuple[Path, Path]:
    """``table`` as ``name`` (.csv or .parquet) and the mapping of its columns."""
    path = tmp / name
    if path.suffix == ".csv":
        pcsv.write_csv(table, path, write_options=pcsv.WriteOptions(delimiter=";"))
    else:
        pq.write_table(table, path)
    (tmp / "m.toml").write_text(MAPPING)
    return path, tmp / "m.toml"


def _samples(path: Path, mapping: Path) -> int:
    return sum(int(d.joints[0].time.size) for d in decoded_batches(path, load_mapping(str(mapping))))


def _refused(path: Path, mapping: Path, says: str) -> None:
    with pytest.raises(TraceError, match=re.escape(says)):
        _samples(path, mapping)


def _duplicated(name: str) -> pa.Table:
    table = _table()
    return table.append_column(name, pa.array(np.zeros(ROWS)))


@pytest.mark.parametrize("suffix", [".csv", ".parquet"])
def test_a_mapped_column_twice_in_the_header_is_refused(tmp_path, suffix):
    """Once a KeyError traceback (Parquet) or the first of the two read silently (CSV: joint 0 empty)."""
    path, mapping = _write(tmp_path, f"dup{suffix}", _duplicated(SPEED))
    _refused(path, mapping, "column 'J0 speed [rad/s]' appears twice in the table (columns 2, 6); rename one")
    good, _ = _write(tmp_path, f"good{suffix}", _table())
    assert _samples(good, mapping) == ROWS


@pytest.mark.parametrize("suffix", [".csv", ".parquet"])
def test_an_unmapped_column_twice_is_only_warned_about(tmp_path, suffix, caplog):
    path, mapping = _write(tmp_path, f"extra{suffix}", _duplicated("note").append_column("note", pa.array(
        np.ones(ROWS))))
    with caplog.at_level(logging.WARNING):
        assert _samples(path, mapping) == ROWS
    assert "'note' appear more than once in the table; the mapping does not read them" in caplog.text


@pytest.mark.parametrize(("suffix", "column", "kind"), [
    (".parquet", SPEED, "bool"), (".parquet", SPEED, "timestamp[ms]"), (".parquet", "cycle", "duration[s]"),
    (".parquet", TORQUE, "date32[day]"), (".csv", SPEED, "bool"),
])
def test_a_value_column_of_booleans_or_dates_is_refused(tmp_path, suffix, column, kind):
    """Once read as 0/1 or as the counts of its unit, without a word."""
    values = {"bool": pa.array(np.arange(ROWS) % 2 == 0), "timestamp[ms]": pa.array(range(ROWS), pa.timestamp("ms")),
              "duration[s]": pa.array(range(ROWS), pa.duration("s")),
              "date32[day]": pa.array(range(ROWS), pa.date32())}[kind]
    table = _table()
    table = table.set_column(table.schema.get_field_index(column), column, values)
    path, mapping = _write(tmp_path, f"typed{suffix}", table)
    _refused(path, mapping, f"column '{column}' is {kind}, not a number")


@pytest.mark.parametrize("kind", [pa.timestamp("us", tz="UTC"), pa.duration("ms")])
def test_the_time_column_may_still_be_a_timestamp_or_a_duration(tmp_path, kind):
    table = _table()
    ticks = pa.array((np.arange(1, ROWS + 1) * (2000 if kind.unit == "us" else 2)).astype(np.int64))
    table = table.set_column(0, "time [s]", ticks.cast(kind))
    path, mapping = _write(tmp_path, "stamped.parquet", table)
    assert _samples(path, mapping) == ROWS


def _bool_speed() -> pa.Table:
    return _table().set_column(1, SPEED, pa.array(np.arange(ROWS) % 2 == 0))


@pytest.mark.slow
@pytest.mark.parametrize(("name", "table", "says"), [
    ("dup.csv", _duplicated(SPEED), "column 'J0 speed [rad/s]' appears twice in the table (columns 2, 6)"),
    ("dup.parquet", _duplicated(SPEED), "column 'J0 speed [rad/s]' appears twice in the table (columns 2, 6)"),
    ("bool.parquet", _bool_speed(), "column 'J0 speed [rad/s]' is bool, not a number"),
])
def test_the_commands_say_it_in_one_line_with_exit_code_2(tmp_path, name, table, says):
    path, mapping = _write(tmp_path, name, table)
    for command in ("replay", "check-mapping"):
        done = subprocess.run([*EM, command, str(path), "--mapping", str(mapping), "-q"], capture_output=True,
                              text=True, timeout=120)
        assert "Traceback" not in done.stderr and done.returncode == 2, (done.returncode, done.stderr[-2000:])
        assert len(done.stderr.strip().splitlines()) == 1 and says in done.stderr, done.stderr
