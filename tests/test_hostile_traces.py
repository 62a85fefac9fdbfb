"""Hostile trace tables, mapping files, DBCs and EDSs (issues 28 and 30), through the real commands as a
user runs them: each ends with a clear message and the documented exit code (2 a file that does not fit,
1 one that cannot be read) or a counted drop, never a traceback, in bounded time and memory. Plus a
hypothesis test of the CSV decoder and the sample stream's bounds, in process."""

from __future__ import annotations

import io
import json
import os
import re
from pathlib import Path

import hostile_files as hostile
import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from edge_monitor.config import load_config
from edge_monitor.sources import trace_table
from edge_monitor.sources.foreign_source import open_source
from edge_monitor.sources.log_source import LogReport
from edge_monitor.sources.samples import DecodedSamples, JointColumns
from edge_monitor.sources.trace_source import decoded_batches
from edge_monitor.sources.trace_table import TraceError, TraceUnreadable
from protocol.signal_mapping import load_mapping, mapping_from_dict

ROOT = Path(__file__).resolve().parents[1]
MAPPING = """kind = "trace"
[trace]
separator = ";"
time_column = "t"
[cycles]
from = "controller"
cycle = { column = "cycle" }
segment = { column = "segment" }
[joint.0]
speed = { column = "v0" }
torque = { column = "tau0" }
"""
HEADER = b"t;v0;tau0;cycle;segment\n"


def _rows(n: int = 3000) -> list[bytes]:
    """A 500 Hz table of one joint: two cycles of three 1 s levels."""
    t = np.arange(1, n + 1) / 500.0
    level = (np.arange(n) // 500) % 3
    return [b"%.3f;%.2f;%.4f;%d;%d\n" % (ti, 8.7 * (k + 1), 0.1 + 0.01 * k, i // 1500, k + 1)
            for i, (ti, k) in enumerate(zip(t, level))]


def _cells(rows: list[bytes], column: int, value: bytes, every: int) -> list[bytes]:
    out = []
    for i, row in enumerate(rows):
        cells = row.rstrip(b"\n").split(b";")
        if i % every == 0:
            cells[column] = value
        out.append(b";".join(cells) + b"\n")
    return out


ROWS = _rows()
TABLES: dict[str, bytes] = {
    "empty.csv": b"",
    "truncated.csv": HEADER + b"".join(ROWS)[:-9],
    "short_rows.csv": HEADER + b"".join(r if i % 50 else b"0.5;1\n" for i, r in enumerate(ROWS)),
    "nan_inf.csv": HEADER + b"".join(_cells(ROWS, 1, b"inf", 7)),
    "absurd_values.csv": HEADER + b"".join(_cells(ROWS, 2, b"1e308", 5)),
    "time_backwards.csv": HEADER + b"".join(ROWS[:1500]) + b"".join(reversed(ROWS[1500:])),
    "time_absurd.csv": HEADER + b"".join(_cells(ROWS, 0, b"1e300", 3)),
    "latin1_header.csv": HEADER.replace(b"tau0", b"tau0 [\xb0]") + b"".join(ROWS),
    "huge_header.csv": b"x;" * (3 << 20),
    "text_cell.csv": HEADER + b"".join(_cells(ROWS, 1, b"abc", 1000)),
    "text_column.csv": HEADER + b"".join(_cells(ROWS, 1, b"abc", 2)),
    "time_in_ms.csv": HEADER + b"".join(b"%d;" % round(float(r.split(b";")[0]) * 1e3) + r.split(b";", 1)[1]
                                        for r in _rows(3000)[::3]),
    # a 5 MiB line (line 1002: the header, 1000 rows, then it) of one cell, and of five cells (once read as a
    # number, inf); before, the first was skipped as a row of the wrong length, the second read as a sample
    "long_line.csv": HEADER + b"".join(ROWS[:1000]) + b"\0" * (5 << 20) + b"\n" + b"".join(ROWS[1000:]),
    "long_row.csv": HEADER + b"".join(ROWS[:1000]) + b"2.001;" + b"9" * (5 << 20) + b";0.1;0;1\n"
                    + b"".join(ROWS[1000:]),
    # one stray byte that is not UTF-8 in row 1200 (line 1202): that row is skipped and counted (the table was
    # refused as "not utf-8 text"); a table of Latin-1 rows under a plain header is still refused
    "stray_byte.csv": HEADER + b"".join(ROWS[:1200]) + ROWS[1200].replace(b";", b";\xff", 1) + b"".join(ROWS[1201:]),
    "latin1_rows.csv": HEADER + b"".join(r.replace(b";", b"\xb0;", 1) for r in ROWS),
}
# name: (exit code, what stderr says / the counted drop in the summary)
EXPECTED = {
    "empty.csv": (2, "Empty CSV file"),
    "truncated.csv": (0, lambda s: s["log"]["skipped_records"] == 1),
    "short_rows.csv": (0, lambda s: s["log"]["skipped_records"] == 60
                       and s["log"]["skip_examples"][0] == "line 2: a row with 2 cells, 5 expected: '0.5;1'"),
    "nan_inf.csv": (0, lambda s: s["details"]["samples_dropped"]["not_finite"] == 429),
    "absurd_values.csv": (0, lambda s: s["details"]["samples_dropped"]["out_of_range"] == 600),
    "time_backwards.csv": (0, lambda s: s["details"]["samples_dropped"]["time_backwards"] == 1499),
    "time_absurd.csv": (0, lambda s: s["details"]["samples_dropped"]["bad_time"] == 1000),
    "latin1_header.csv": (2, 'encoding = "cp1252"'),
    "huge_header.csv": (2, "longer than 4 MiB"),
    "text_cell.csv": (0, lambda s: s["details"]["samples_dropped"]["not_finite"] == 3),
    "text_column.csv": (2, "is not numeric"),
    "time_in_ms.csv": (2, 'time_unit = "ms"'),
    "long_line.csv": (2, "line 1002 is longer than 4 MiB, the longest line a trace table may have"),
    "long_row.csv": (2, "line 1002 is longer than 4 MiB, the longest line a trace table may have"),
    "stray_byte.csv": (0, lambda s: s["log"]["skipped_records"] == 1 and s["log"]["frames"] == len(ROWS) - 1
                       and s["log"]["skip_examples"] == ["line 1202: not UTF-8 text (byte 0xff at byte 7): "
                                                         "'2.402;\\xff26.10;0.1200;0;3'"]),
    "latin1_rows.csv": (2, "not UTF-8 text (1001 of its first 1002 lines are not, the first: byte 0xb0 at byte 6 in "
                           "line 2)"),
}


def _check(run: hostile.Run, code: int, expect) -> None:
    assert not run.timed_out and "Traceback" not in run.stderr, run.stderr[-2000:]
    assert run.returncode == code, (run.returncode, run.stderr[-1000:])
    if callable(expect):
        assert expect(json.loads(run.stdout)), run.stdout[-3000:]
    else:
        assert expect in run.stderr, run.stderr[-1000:]
    assert run.max_rss_mb < 800, run.max_rss_mb


@pytest.fixture(scope="module")
def corpus(tmp_path_factory) -> Path:
    d = tmp_path_factory.mktemp("hostile_traces")
    (d / "trace.toml").write_text(MAPPING)
    for name, data in TABLES.items():
        (d / name).write_bytes(data)
    return d


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(TABLES))
def test_a_hostile_table_gives_a_clear_error_or_a_counted_drop(corpus, name):
    run = hostile.run_measured(hostile.edge_monitor("replay", str(corpus / name), "--mapping",
                                                    str(corpus / "trace.toml"), "--json", "-q"), timeout=120)
    _check(run, *EXPECTED[name])


@pytest.mark.slow
@pytest.mark.parametrize("kind", ["fifo", "dev_zero", "directory", "missing"])
def test_a_table_that_is_no_regular_file_cannot_be_read(corpus, tmp_path, kind):
    path = tmp_path / "table.csv"
    if kind == "fifo":
        os.mkfifo(path)
    elif kind == "dev_zero":
        path.symlink_to("/dev/zero")
    elif kind == "directory":
        path.mkdir()
    for command in ("replay", "check-mapping"):
        run = hostile.run_measured(hostile.edge_monitor(command, str(path), "--mapping", str(corpus / "trace.toml")),
                                   timeout=60)
        _check(run, 1, "not found" if kind == "missing" else "not a regular file")


def _parquet(path: Path, damage: str) -> None:
    """The table of :data:`ROWS` as Parquet (row groups of 500 rows), then damaged: cut in half, 200 bytes in
    its middle overwritten (a data page that does not decompress), a page header overwritten (it does not
    deserialize), replaced by a CSV, or emptied; "none" leaves it whole."""
    import pyarrow.csv as pcsv
    import pyarrow.parquet as pq
    table = pcsv.read_csv(io.BytesIO(HEADER + b"".join(ROWS)), parse_options=pcsv.ParseOptions(delimiter=";"))
    pq.write_table(table, path, row_group_size=500)
    raw = path.read_bytes()
    middle, page = len(raw) // 3, pq.ParquetFile(path).metadata.row_group(3).column(1).data_page_offset
    path.write_bytes({"none": raw, "truncated": raw[: len(raw) // 2], "csv": HEADER + ROWS[0], "empty": b"",
                      "middle": raw[:middle] + b"\xab" * 200 + raw[middle + 200:],
                      "page_header": raw[:page] + b"\0" * 64 + raw[page + 64:]}[damage])


@pytest.mark.slow
@pytest.mark.parametrize(("damage", "says"), [("truncated", "not a parquet table"), ("csv", "not a parquet table"),
                                              ("empty", "not a parquet table"), ("middle", "a damaged Parquet file")])
def test_a_parquet_that_is_not_one_is_a_usage_error(corpus, tmp_path, damage, says):
    _parquet(tmp_path / "trace.parquet", damage)
    run = hostile.run_measured(hostile.edge_monitor("replay", str(tmp_path / "trace.parquet"), "--mapping",
                                                    str(corpus / "trace.toml")), timeout=60)
    _check(run, 2, says)
    assert str(tmp_path / "trace.parquet") in run.stderr and len(run.stderr.strip().splitlines()) == 1, run.stderr


@pytest.mark.parametrize("damage", ["middle", "page_header"])
def test_a_parquet_damaged_inside_is_refused_as_damaged_and_a_whole_one_reads(tmp_path, damage):
    """Bytes overwritten inside a Parquet file were "cannot read …" (exit 1, an I/O failure) and a page header
    that does not deserialize gave a message of two lines; now one line naming the file as damaged (exit 2),
    like a "Parquet" cut short."""
    mapping = _trace_mapping(tmp_path)
    _parquet(tmp_path / "whole.parquet", "none")
    assert sum(d.joints[0].time.size for d in decoded_batches(tmp_path / "whole.parquet", mapping)) == len(ROWS)
    _parquet(tmp_path / "damaged.parquet", damage)
    with pytest.raises(TraceError) as raised:
        for _ in decoded_batches(tmp_path / "damaged.parquet", mapping):
            pass
    message = str(raised.value)
    assert message.startswith(f"{tmp_path / 'damaged.parquet'}: a damaged Parquet file (")
    assert message.endswith("export or copy it again") and "\n" not in message and message.isprintable()


UTF16 = ("\n".join(line.decode() for line in [HEADER.rstrip(b"\n")] + [r.rstrip(b"\n") for r in ROWS]) + "\n").encode("utf-16")
NOT_UTF16 = {
    "utf8_without_bom": HEADER + b"".join(ROWS),
    "truncated": UTF16[:-1],
    "lone_surrogate": UTF16[: len(UTF16) // 4 * 2] + b"\x00\xd8\x41\x00" + UTF16[len(UTF16) // 4 * 2:],
}


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(NOT_UTF16))
def test_a_table_that_is_not_its_stated_encoding_is_a_usage_error_without_an_abort(corpus, tmp_path, name):
    """A decode error inside pyarrow's transcoder could abort the process at exit (exit 134,
    "terminate called without an active exception"); the text is now checked before pyarrow reads it."""
    (tmp_path / "utf16.toml").write_text(MAPPING.replace("[trace]\n", '[trace]\nencoding = "utf-16"\n'))
    (tmp_path / "table.csv").write_bytes(NOT_UTF16[name])
    for _ in range(3):                       # the abort came in about one exit of eight
        run = hostile.run_measured(hostile.edge_monitor("replay", str(tmp_path / "table.csv"), "--mapping",
                                                        str(tmp_path / "utf16.toml")), timeout=60)
        _check(run, 2, "not utf-16 text")


@pytest.mark.slow
def test_a_utf16_table_is_read(corpus, tmp_path):
    (tmp_path / "utf16.toml").write_text(MAPPING.replace("[trace]\n", '[trace]\nencoding = "utf-16"\n'))
    (tmp_path / "table.csv").write_bytes(UTF16)
    run = hostile.run_measured(hostile.edge_monitor("replay", str(tmp_path / "table.csv"), "--mapping",
                                                    str(tmp_path / "utf16.toml"), "--json", "-q"), timeout=120)
    _check(run, 0, lambda s: s["log"]["frames"] == len(ROWS) and s["log"]["skipped_records"] == 0)


FOREIGN = (ROOT / "protocol" / "mappings" / "foreign_robot.toml").read_text().replace(
    '"../', f'"{ROOT / "protocol"}/')
CIA = (ROOT / "protocol" / "mappings" / "cia402.toml").read_text().replace('"../', f'"{ROOT / "protocol"}/')
DBC = (ROOT / "protocol" / "dbc" / "foreign_robot.dbc").read_bytes()
EDS = (ROOT / "protocol" / "eds" / "cia402_drive.eds").read_bytes()
MAPPINGS = {
    # name: (mapping text, {file name: bytes or a FIFO (None)}, what the error says)
    "gear_ratio_list": (FOREIGN.replace("[joint.0]\n", "[joint.0]\ngear_ratio = [1]\n"), {}, "gear_ratio: must be > 0"),
    "gear_ratio_zero": (FOREIGN.replace("[joint.0]\n", "[joint.0]\ngear_ratio = 0\n"), {}, "gear_ratio: must be > 0"),
    "reference_torque_negative": (FOREIGN.replace("reference_torque_nm = 30.0", "reference_torque_nm = -3", 1), {},
                                  "reference_torque_nm: must be > 0"),
    "scale_text": (FOREIGN.replace('unit = "rpm" }', 'unit = "rpm", scale = "x" }', 1), {}, "scale: a non-zero"),
    "speeds_scalar": (re.sub(r"(?m)^speeds = .*$", "speeds = 5", FOREIGN), {}, "speeds: a list"),
    "missing_signal": (FOREIGN.replace('"MotorSpeed"', '"MotorSped"', 1), {}, "has no signal 'MotorSped'"),
    "joint_99": (FOREIGN.replace("[joint.1]", "[joint.99]"), {}, "N = 0 … 7"),
    "e2e_data_ids_large": (FOREIGN + '[[e2e]]\nmessage = "AxisFeedback_0"\nprofile = 2\ndata_ids = ['
                           + ", ".join(["999"] * 16) + "]\n", {}, "data IDs 0 … 255"),
    "tpdo_not_a_table": (CIA.replace(f'eds = "{ROOT}/protocol/eds/cia402_drive.eds"', "tpdo = [5]", 1), {},
                         "tpdo[0]: an inline table"),
    "dbc_garbage": (re.sub(r'(?m)^dbc = .*$', 'dbc = "x.dbc"', FOREIGN), {"x.dbc": bytes(range(256)) * 40},
                    "cannot load"),
    "dbc_3_mib": (re.sub(r'(?m)^dbc = .*$', 'dbc = "x.dbc"', FOREIGN),
                  {"x.dbc": DBC + b'\nCM_ "' + b"y" * (3 << 20) + b'";\n'}, "more than the 2097152"),
    "dbc_fifo": (re.sub(r'(?m)^dbc = .*$', 'dbc = "x.dbc"', FOREIGN), {"x.dbc": None}, "it is a FIFO"),
    "eds_garbage": (CIA.replace(f"{ROOT}/protocol/eds/cia402_drive.eds", "x.eds"), {"x.eds": bytes(range(256)) * 40},
                    "describes no object (no section such as [1000] or [1A00sub1]): not an EDS/DCF"),
    "eds_5_mib": (CIA.replace(f"{ROOT}/protocol/eds/cia402_drive.eds", "x.eds"),
                  {"x.eds": EDS + b"\n; " + b"z" * (5 << 20) + b"\n"}, "more than the 4194304"),
    "eds_fifo": (CIA.replace(f"{ROOT}/protocol/eds/cia402_drive.eds", "x.eds"), {"x.eds": None}, "it is a FIFO"),
    "eds_default_not_a_number": (CIA.replace(f"{ROOT}/protocol/eds/cia402_drive.eds", "x.eds"),
                                 {"x.eds": EDS.replace(b"DefaultValue=0x60410010", b"DefaultValue=abc")},
                                 "x.eds: [1A00sub1] DefaultValue='abc' is not a number: write an integer"),
    "eds_empty": (CIA.replace(f"{ROOT}/protocol/eds/cia402_drive.eds", "x.eds"), {"x.eds": b""},
                  "x.eds is empty (0 bytes): give the drive's EDS/DCF"),
    "eds_without_6077": (CIA.replace(f"{ROOT}/protocol/eds/cia402_drive.eds", "x.eds"),
                         {"x.eds": EDS.replace(b"0x60770010", b"0x60410010")}, "object 6077sub0 of node 1 is in no TPDO"),
}


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(MAPPINGS))
def test_a_hostile_mapping_dbc_or_eds_is_a_usage_error_naming_it(tmp_path, name):
    text, files, says = MAPPINGS[name]
    for file, data in files.items():
        os.mkfifo(tmp_path / file) if data is None else (tmp_path / file).write_bytes(data)
    (tmp_path / "m.toml").write_text(text)
    capture = tmp_path / "empty.log"
    capture.write_text("")
    run = hostile.run_measured(hostile.edge_monitor("check-mapping", str(capture), "--mapping",
                                                    str(tmp_path / "m.toml")), timeout=60)
    _check(run, 2, says)
    if name.startswith("eds_"):
        assert len(run.stderr.strip().splitlines()) == 1, run.stderr


@pytest.mark.slow
@pytest.mark.parametrize("command", ["replay", "run"])
def test_a_mapping_that_is_a_fifo_or_a_device_is_refused_at_once(tmp_path, command):
    os.mkfifo(tmp_path / "fifo.toml")
    (tmp_path / "zero.toml").symlink_to("/dev/zero")
    for mapping in ("fifo.toml", "zero.toml"):
        args = (["replay", str(tmp_path / "x.blf")] if command == "replay"
                else ["run", "--link", "virtual:hostile", "--no-zenoh", "--duration", "1"])
        run = hostile.run_measured(hostile.edge_monitor(*args, "--mapping", str(tmp_path / mapping)), timeout=60)
        _check(run, 2, "not a regular file")


# ------------------------------------------------------------------------------------------- in process
def _trace_mapping(tmp_path: Path):
    (tmp_path / "m.toml").write_text(MAPPING)
    return load_mapping(tmp_path / "m.toml")


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(st.binary(max_size=3000) | st.lists(st.sampled_from(ROWS[:20] + [b"nan;;\n", b"\xff;1\n", b'"\n', b";;;;;;\n",
                                                                         b"1e400;1;1;1;1\n", b"-0;-inf;x;1;1\n"]),
                                               max_size=40).map(lambda rows: HEADER + b"".join(rows)))
@example(b"\r\x00")           # a lone CR in the header line was a csv.Error traceback (2026-12-01)
def test_any_bytes_as_a_csv_trace_decode_to_samples_or_a_clear_error(tmp_path, data):
    """Whatever the bytes, the decoder yields samples (which the sample stream takes without an
    exception) or raises TraceError / TraceUnreadable, nothing else."""
    path = tmp_path / "any.csv"
    path.write_bytes(data)
    mapping = _trace_mapping(tmp_path)
    source = open_source(mapping, load_config(None))
    try:
        for decoded in decoded_batches(path, mapping):
            source.update_samples(decoded)
        source.flush()
    except (TraceError, TraceUnreadable):
        pass


def test_a_table_whose_lines_end_in_a_lone_cr_is_read_like_pyarrow_reads_it(tmp_path):
    """Old Mac line ends: the header ends at the first CR, as pyarrow's rows do."""
    path = tmp_path / "cr.csv"
    path.write_bytes(HEADER.replace(b"\n", b"\r") + b"".join(r.replace(b"\n", b"\r") for r in ROWS[:5]))
    mapping = _trace_mapping(tmp_path)
    assert sum(len(d.joints[0].time) for d in decoded_batches(path, mapping) if 0 in d.joints) == 5


def test_a_header_name_longer_than_the_csv_field_limit_is_refused_clearly(tmp_path):
    """Python's csv module refuses a field over 131 072 characters; the header's reader says so in one line."""
    path = tmp_path / "long.csv"
    path.write_bytes(b"t;" + b"v" * 200_000 + b"\n0;1\n")
    with pytest.raises(TraceError, match="its header line cannot be read as CSV .*field larger than field limit"):
        list(decoded_batches(path, _trace_mapping(tmp_path)))


@pytest.mark.parametrize(("lines", "refused"), [
    ([b"x" * 64], None),                          # the longest line allowed (the limit is 64 bytes here)
    ([b"x" * 65], 2),
    ([b"x" * 10, b"x" * 200], 3),                 # runs over three blocks
    ([b"x" * 60, b"x" * 64, b"x" * 64], None),
    ([b"x" * 60, b"x" * 64, b"x" * 30 + b"\0" * 40], 4),
], ids=["at_limit", "over_limit", "three_blocks", "lines_at_limit_across_blocks", "last_line_without_end"])
def test_a_line_longer_than_the_limit_is_refused_naming_it(tmp_path, monkeypatch, lines, refused):
    monkeypatch.setattr(trace_table, "BLOCK_BYTES", 64)
    path = tmp_path / "t.csv"
    path.write_bytes(b"t;v0\n" + b"\n".join(lines) + (b"" if refused == 4 else b"\n"))
    if refused is None:
        trace_table.check_lines(path, "utf-8")
    else:
        with pytest.raises(TraceError, match=f"line {refused} is longer than 64 bytes, the longest line .*"
                                             f"remove line {refused}"):
            trace_table.check_lines(path, "utf-8")


@pytest.mark.parametrize("block", [4 << 20, 64], ids=["one_block", "blocks_of_64_bytes"])
def test_rows_that_are_not_utf8_are_skipped_and_counted_and_the_rest_is_read(tmp_path, monkeypatch, block):
    """A stray byte that is not UTF-8 refused the whole table ("not utf-8 text"); now its row is skipped and
    counted with its line, the byte and where in the line, like a row of the wrong length, wherever a block ends,
    and with the file's line numbers where blank lines (which pyarrow's row numbers leave out) come before."""
    monkeypatch.setattr(trace_table, "BLOCK_BYTES", block)
    mapping = _trace_mapping(tmp_path)
    rows = ROWS[:600]
    damaged = list(rows)
    damaged[10] = damaged[10].replace(b";", b";\xff", 1)            # line 12, in a mapped cell
    damaged[300] = b"\xfe\xfe;1\r\n"                               # line 302: also of the wrong length
    damaged[-1] = damaged[-1].rstrip(b"\n") + b"\xc3"             # the last line, cut in a character
    for name, table, read, examples in [
        ("whole.csv", rows, 600, []),
        ("damaged.csv", damaged, 597, ["line 12: not UTF-8 text (byte 0xff at byte 7): '0.022;\\xff8.70;0.1000;0;1'",
                                       "line 302: not UTF-8 text (byte 0xfe at byte 1): '\\xfe\\xfe;1'",
                                       "line 601: not UTF-8 text (byte 0xc3 at byte 23): '1.200;17.40;0.1100;0;2\\xc3'"]),
        ("blank_line.csv", damaged[:5] + [b"\n"] + damaged[5:], 597,
         ["line 13: not UTF-8 text (byte 0xff at byte 7): '0.022;\\xff8.70;0.1000;0;1'",
          "line 303: not UTF-8 text (byte 0xfe at byte 1): '\\xfe\\xfe;1'",
          "line 602: not UTF-8 text (byte 0xc3 at byte 23): '1.200;17.40;0.1100;0;2\\xc3'"]),
    ]:
        (tmp_path / name).write_bytes(HEADER + b"".join(table))
        report = LogReport()
        assert sum(d.joints[0].time.size for d in decoded_batches(tmp_path / name, mapping, report)) == read
        assert (report.skipped, report.examples) == (len(examples), examples)


def test_a_table_of_many_lines_not_utf8_is_refused_naming_the_first(tmp_path):
    """More than 1 % of the file's lines (at least 10) not UTF-8 is a table in another encoding, not stray
    bytes: 14 lines spread over 2000 and a burst of 11 at the start (a bad sector) are skipped, 25 are refused."""
    mapping = _trace_mapping(tmp_path)
    rows = ROWS[:2000]

    def latin1(row: bytes) -> bytes:
        return row.replace(b";", b"\xb0;", 1)
    for name, table, read in [("spread.csv", [latin1(r) if i % 150 == 5 else r for i, r in enumerate(rows)], 1986),
                              ("burst.csv", [latin1(r) for r in rows[:11]] + rows[11:], 1989)]:
        (tmp_path / name).write_bytes(HEADER + b"".join(table))
        report = LogReport()
        assert sum(d.joints[0].time.size for d in decoded_batches(tmp_path / name, mapping, report)) == read, name
        assert report.skipped == 2000 - read
    (tmp_path / "latin1.csv").write_bytes(HEADER + b"".join(latin1(r) for r in rows[:25]) + b"".join(rows[25:]))
    with pytest.raises(TraceError, match=r"latin1.csv: not UTF-8 text \(25 of its 2001 lines are not, the first: "
                                         r"byte 0xb0 at byte 6 in line 2\); .* else export it again as UTF-8"):
        list(decoded_batches(tmp_path / "latin1.csv", mapping))


@pytest.mark.parametrize("name", ["table.csv", "table.parquet", "stray_byte.csv"])
def test_the_replay_summary_of_a_table_counts_its_samples(tmp_path, monkeypatch, capsys, name):
    """The summary line of a table's replay said "frames 0 (ok 0, crc errors 0, lost 0) … 0 frames/s" (a
    table has no CAN frames) although every row was read; now "samples N" as `--json` `log.frames`."""
    from edge_monitor.cli import main as edge_monitor
    monkeypatch.chdir(tmp_path)
    (tmp_path / "m.toml").write_text(MAPPING)
    if name == "table.parquet":
        _parquet(tmp_path / name, "none")
    else:
        (tmp_path / name).write_bytes(TABLES.get(name, HEADER + b"".join(ROWS)))
    read = len(ROWS) - (name == "stray_byte.csv")
    capsys.readouterr()
    assert edge_monitor(["replay", name, "--mapping", "m.toml", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["log"]["frames"] == read
    assert edge_monitor(["replay", name, "--mapping", "m.toml"]) == 0
    lines = capsys.readouterr().out.splitlines()
    counts = [line for line in lines if line.startswith(("samples ", "frames "))]
    assert len(counts) == 1 and re.fullmatch(rf"samples {read}, cycles 2, symptoms \d+, \d+ samples/s", counts[0]), lines
    assert ("log: 1 unreadable row(s) skipped" in lines) == (name == "stray_byte.csv"), lines


def test_signalling_nan_times_and_values_of_a_damaged_parquet_are_counted_without_a_numpy_warning(tmp_path):
    """A bit flip can turn a float into a signalling NaN: multiplying it by the time unit or a signal's factor
    printed numpy's "RuntimeWarning: invalid value encountered in multiply" with a source line. Now such a
    sample is dropped and counted like any other bad time, and a table without one drops nothing."""
    import warnings

    import pyarrow as pa
    import pyarrow.parquet as pq
    mapping = _trace_mapping(tmp_path)
    snan = np.array([0x7FF0000000000001], dtype=np.uint64).view(np.float64)[0]
    n = 40_000
    columns = {"t": np.arange(1, n + 1) / 500.0, "v0": np.full(n, 8.7), "tau0": np.full(n, 0.1),
               "cycle": (np.arange(n) // 20_000).astype(float), "segment": np.ones(n)}
    for damaged in (False, True):
        table = {k: v.copy() for k, v in columns.items()}
        if damaged:
            table["t"][100:103] = snan
            table["tau0"][500] = snan
        path = tmp_path / f"damaged{damaged}.parquet"
        pq.write_table(pa.table(table), path)
        source = open_source(mapping, load_config(None))
        with warnings.catch_warnings():
            warnings.simplefilter("error")          # a numpy RuntimeWarning fails the test
            for decoded in decoded_batches(path, mapping):
                source.update_samples(decoded)
            source.flush()
        dropped = sum(source.counters()["samples_dropped"].values())
        assert (dropped >= 3) if damaged else (dropped == 0), source.counters()["samples_dropped"]


def test_a_5_mib_line_refuses_the_table_and_short_rows_stay_counted_drops(tmp_path, caplog):
    mapping = _trace_mapping(tmp_path)
    path = tmp_path / "table.csv"
    path.write_bytes(TABLES["long_row.csv"])
    with pytest.raises(TraceError, match=r"table.csv: line 1002 is longer than 4 MiB"):
        list(decoded_batches(path, mapping))
    path.write_bytes(TABLES["short_rows.csv"])
    report = LogReport()
    samples = sum(c.time.size for d in decoded_batches(path, mapping, report) for c in d.joints.values())
    assert (samples, report.skipped) == (len(ROWS) - 60, 60)
    assert report.examples[1] == "line 52: a row with 2 cells, 5 expected: '0.5;1'"
    assert "60 row(s) skipped: the wrong number of cells, or not UTF-8 text (first: line 2:" in caplog.text


def test_samples_whose_time_does_not_advance_are_bounded_and_counted():
    """Times that never advance at a plateau speed (a plateau that never ends) once held every sample
    (30 million rows: 2.75 GB, 291 s); the buffer now keeps 4 × max_pending_s of samples."""
    mapping = mapping_from_dict({"kind": "trace", "cycles": {"from": "motion", "speeds": [8.7, 41.7]},
                                 "joint": {"0": {"speed": {"column": "v"}, "torque": {"column": "tau"}}}})
    source = open_source(mapping, load_config(None))
    n = 50_000
    for _ in range(20):
        source.update_samples(DecodedSamples(joints={0: JointColumns(np.ones(n), np.full(n, 8.7), np.full(n, 0.1))}))
    stream = source.stream
    assert stream.pending_samples() <= 4 * stream.max_pending
    assert stream.dropped["pending_full"] == 20 * n - stream.pending_samples()
    assert source.counters()["samples_dropped"]["pending_full"] > 0


# ------------------------------------------------------------------------ the health record's schema
def _undeclared(record: dict) -> list[str]:
    from edge_monitor.schemas import load_schema
    schema = load_schema("health")
    patterns = [re.compile(p) for p in schema.get("patternProperties", {})]
    return sorted(k for k in record if k not in schema["properties"] and not any(p.match(k) for p in patterns))


@pytest.mark.slow
def test_every_counter_of_a_real_run_and_replay_is_declared_in_the_health_schema(corpus, tmp_path):
    """The health record of a real `run` (with the live loop's counters) and the `details` of the run
    summaries of a native and a foreign replay carry no key the health schema does not declare."""
    run = hostile.run_measured(hostile.edge_monitor("run", "--link", "virtual:health-schema", "--no-zenoh",
                                                    "--duration", "1", "--json"), timeout=120)
    assert run.returncode == 0, run.stderr[-2000:]
    assert _undeclared(json.loads(run.stdout)["health"]) == []
    trace = hostile.run_measured(hostile.edge_monitor("replay", str(corpus / "nan_inf.csv"), "--mapping",
                                                      str(corpus / "trace.toml"), "--json", "-q"), timeout=120)
    assert _undeclared(json.loads(trace.stdout)["details"]) == []
    blf = ROOT / "tests" / "corpus" / "clean.blf"
    native = hostile.run_measured(hostile.edge_monitor("replay", str(blf), "--json", "-q"), timeout=120)
    assert _undeclared(json.loads(native.stdout)["details"]) == []
