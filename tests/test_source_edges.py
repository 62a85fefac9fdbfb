"""Edges of the sources found by an attack pass (round s15), each checked on both sides: the bad input gets
a clear message (exit 2) or a counted drop, the good input still gives the same result. A small recording of
the simulator (text log) and its export as a trace table are made once per module."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import pytest

from foreign_mappings import record

pytestmark = pytest.mark.slow
EM = [sys.executable, "-m", "edge_monitor.cli"]
CYCLES = 6


def _em(*args: str, code: int = 0, says: str = "") -> subprocess.CompletedProcess:
    done = subprocess.run([*EM, *args], capture_output=True, text=True, timeout=300)
    assert "Traceback" not in done.stderr, done.stderr[-3000:]
    assert done.returncode == code, (done.returncode, done.stdout[-2000:], done.stderr[-2000:])
    assert says in done.stdout + done.stderr, (says, done.stdout[-2000:], done.stderr[-2000:])
    return done


def _replay(file: Path, *extra: str, code: int = 0) -> tuple[dict, list[tuple[int, int]], str]:
    """Summary, (joint, cycle) of the symptom records, stderr of ``edge-monitor replay FILE``."""
    jsonl = file.with_name(file.name + ".jsonl")
    jsonl.unlink(missing_ok=True)
    done = _em("replay", str(file), "--json", "--jsonl", str(jsonl), *extra, code=code)
    records = [r for r in map(json.loads, jsonl.open()) if "kind" not in r] if jsonl.exists() else []
    return json.loads(done.stdout), sorted((r["joint"], r["cycle"]) for r in records), done.stderr


@pytest.fixture(scope="module")
def rec(tmp_path_factory) -> dict[str, Path]:
    tmp = tmp_path_factory.mktemp("edges")
    log = record(tmp, "run", "native", cycles=CYCLES)
    _em("export-trace", str(log), "--out", str(tmp / "run.csv"), "-q")
    return {"dir": tmp, "log": log, "csv": tmp / "run.csv", "toml": tmp / "run.toml"}


def _cycle_start(csv: Path, cycle: int) -> float:
    """Time [s] of the first row of ``cycle`` in an exported table."""
    for line in csv.read_text().splitlines()[1:]:
        cells = line.split(";")
        if cells[9] == str(cycle):
            return float(cells[0])
    raise AssertionError(cycle)


# ------------------------------------------------------------------------------------------ 1: gaps in a table
@pytest.mark.parametrize("gap_s", [0.5, 0.02])
def test_a_gap_before_a_cycle_start_loses_no_later_cycle_of_a_table(rec, gap_s):
    """Rows (and frames) in [t3 − gap, t3 − 0.02 s) removed, t3 the start of cycle 3: the table finds the cycles
    the log with the same frames removed finds (a gap longer than CONFIRM_S used to hold every later mark)."""
    t3 = _cycle_start(rec["csv"], 3)
    lo, hi = t3 - gap_s, t3 - 0.02
    lines = rec["csv"].read_text().splitlines()
    kept = [lines[0], *(x for x in lines[1:] if not lo <= float(x.split(";", 1)[0]) < hi)]
    table = rec["dir"] / f"gap{gap_s}.csv"
    table.write_text("\n".join(kept) + "\n")
    log_lines = rec["log"].read_text().splitlines()
    gapped_log = rec["dir"] / f"gap{gap_s}.log"
    gapped_log.write_text("\n".join(x for x in log_lines if not lo <= float(x[1:x.index(")")]) < hi) + "\n")
    stats, traced, _ = _replay(table, "--mapping", str(rec["toml"]))
    log_stats, native, _ = _replay(gapped_log)
    assert stats["cycles"] == log_stats["cycles"] == CYCLES
    assert stats["details"]["cycle_finding"]["cycle_jumps"] <= 2
    assert [k for k in traced if k[1] != 2] == [k for k in native if k[1] != 2]   # cycle 2: the one the gap cut
    _em("check-mapping", str(table), "--mapping", str(rec["toml"]), code=0)
    full, whole, _ = _replay(rec["csv"], "--mapping", str(rec["toml"]))
    assert full["cycles"] == CYCLES and full["details"]["cycle_finding"]["cycle_jumps"] == 0 and len(whole) == 2 * CYCLES


# ------------------------------------------------------------------------------------------ 2: no cycle found
def test_a_mapped_replay_that_finds_no_cycle_says_why_and_fails(rec):
    """Cycle marks that are all x.5 once replayed to exit 0 with only "cycles 0": now exit 1, the counters
    and the check-mapping command to run; the same table with whole marks replays as before (exit 0)."""
    lines = rec["csv"].read_text().splitlines()
    halves = rec["dir"] / "halves.csv"
    halves.write_text("\n".join([lines[0], *(";".join([*c[:9], f"{c[9]}.5", c[10]])
                                             for c in (x.split(";") for x in lines[1:]))]) + "\n")
    stats, records, err = _replay(halves, "--mapping", str(rec["toml"]), code=1)
    assert stats["cycles"] == 0 and records == []
    assert "no cycle found" in err and "bad marks" in err and "samples before the first cycle" in err
    assert f"check-mapping {halves} --mapping {rec['toml']}" in err
    stats, records, err = _replay(rec["csv"], "--mapping", str(rec["toml"]))
    assert stats["cycles"] == CYCLES and "no cycle found" not in err


def test_the_no_cycle_note_is_kept_for_mapped_inputs_read_in_full():
    from edge_monitor.commands.replay import input_notes

    finding = {"method": "motion (designed speed levels)", "before_first_cycle": 900, "plateaus_ignored": 7,
               "cycles_found": 0}
    stats = {"cycles": 0, "frames_total": 1000, "unknown_id": 0, "details": {"cycle_finding": finding}}
    _, nothing = input_notes("a.blf", stats, None, "m.toml")
    assert nothing is not None and "samples before the first cycle 900, plateaus ignored 7" in nothing
    assert "check-mapping a.blf --mapping m.toml" in nothing
    assert input_notes("a.blf", {**stats, "cycles": 1}, None, "m.toml")[1] is None
    assert input_notes("a.blf", {**stats, "details": {}}, None)[1] is None          # our frames: no cycle finding

    class Cut:
        truncated, frames, skipped = "cut in a record", 1000, 0
    assert input_notes("a.blf", stats, Cut(), "m.toml")[1] is None                   # its only cycle left open


# ------------------------------------------------------------------------------------------ 3: export of a cut log
def test_a_cut_log_exports_without_its_cut_last_cycle(rec):
    """A BLF cut short leaves its last cycle unpublished; its table once published it (one cycle more)."""
    blf = record(rec["dir"], "run", "native", cycles=CYCLES, suffix=".blf")
    raw = blf.read_bytes()
    cut = rec["dir"] / "cut.blf"
    cut.write_bytes(raw[: len(raw) * 2 // 5])
    log_stats, native, _ = _replay(cut)
    done = _em("export-trace", str(cut), "--out", str(rec["dir"] / "cut.csv"))
    assert "is truncated: its last cycle" in done.stderr
    stats, traced, _ = _replay(rec["dir"] / "cut.csv", "--mapping", str(rec["dir"] / "cut.toml"))
    assert 0 < stats["cycles"] == log_stats["cycles"] < CYCLES and traced == native
    _em("export-trace", str(blf), "--out", str(rec["dir"] / "whole.csv"), "-q")                 # the whole log
    whole, records, _ = _replay(rec["dir"] / "whole.csv", "--mapping", str(rec["dir"] / "whole.toml"))
    assert whole["cycles"] == CYCLES and len(records) == 2 * CYCLES


# ------------------------------------------------------------------------------------------ 4, 9: Parquet column types
def _parquet(rec, name: str, edit) -> Path:
    """The exported table as Parquet, ``edit(table) -> table`` applied."""
    import pyarrow.csv as pcsv
    import pyarrow.parquet as pq
    table = pcsv.read_csv(rec["csv"], parse_options=pcsv.ParseOptions(delimiter=";"))
    path = rec["dir"] / f"{name}.parquet"
    pq.write_table(edit(table), path)
    return path


def test_parquet_columns_of_a_nested_type_are_refused_and_timestamps_read_as_seconds(rec):
    import pyarrow as pa
    import pyarrow.compute as pc

    def listed(table):
        speed = table.column("J0 speed [rad/s]").combine_chunks()
        column = pa.ListArray.from_arrays(pa.array(range(len(speed) + 1), pa.int32()), speed)
        return table.set_column(1, "J0 speed [rad/s]", column)

    def stamped(table):              # 2026-11-30 + the table's time, in µs
        micros = pc.cast(pc.add(pc.multiply(table.column("time [s]"), 1e6), 1.7964e15), pa.int64())
        return table.set_column(0, "time [s]", pc.cast(micros, pa.timestamp("us", tz="UTC")))

    good = _parquet(rec, "good", lambda t: t)
    stats, records, _ = _replay(good, "--mapping", str(rec["toml"]))
    assert stats["cycles"] == CYCLES and len(records) == 2 * CYCLES
    _em("replay", str(_parquet(rec, "listed", listed)), "--mapping", str(rec["toml"]), code=2,
        says="column 'J0 speed [rad/s]' is list<double>, not a number")
    stamped_stats, stamped_records, err = _replay(_parquet(rec, "stamped", stamped), "--mapping", str(rec["toml"]))
    assert "steps by" not in err and stamped_stats["cycles"] == CYCLES and stamped_records == records


# ------------------------------------------------------------------------------------------ 5: long output names
def test_export_trace_names_too_long_get_one_clear_line(rec, tmp_path):
    """300 characters: once an OSError traceback; 250: once "check that its folder is writable" although only
    the hidden .NAME.partial.csv was too long. A long name that fits still exports."""
    _em("export-trace", str(rec["log"]), "--out", str(tmp_path / f"{'a' * 300}.csv"), code=2,
        says="cannot be used as an output: File name too long")
    done = _em("export-trace", str(rec["log"]), "--out", str(tmp_path / f"{'b' * 250}.csv"), code=2,
               says="the table is written first under the hidden name")
    assert "writable" not in done.stderr and "bytes shorter" in done.stderr
    _em("export-trace", str(rec["log"]), "--out", str(tmp_path / f"{'c' * 230}.csv"), "-q")
    assert sorted(p.suffix for p in tmp_path.iterdir()) == [".csv", ".toml"]


# ------------------------------------------------------------------------------------------ 6, 7: DBC layouts
ROOT = Path(__file__).resolve().parents[1]


def _dbc_mapping(tmp_path: Path, edit) -> Path:
    """The shipped foreign-robot mapping (2 joints) on its DBC with ``edit(text) -> text`` applied."""
    from foreign_mappings import mapping
    (tmp_path / "robot.dbc").write_text(edit((ROOT / "protocol" / "dbc" / "foreign_robot.dbc").read_text()))
    path = mapping("foreign_robot", tmp_path)
    path.write_text(path.read_text().replace(str(ROOT / "protocol" / "dbc" / "foreign_robot.dbc"),
                                             str(tmp_path / "robot.dbc")))
    return path


@pytest.mark.parametrize(("edit", "says"), [
    (lambda t: t.replace("BO_ 529 AxisFeedback_1:", "BO_ 528 AxisFeedback_1:"),
     "joint.0 (AxisFeedback_0.MotorSpeed) and joint.1 (AxisFeedback_1.MotorSpeed): messages AxisFeedback_0 and "
     "AxisFeedback_1 have one frame id 0x210"),
    (lambda t: t.replace(" SG_ MotorTorque : 23|16@0-", " SG_ MotorTorque : 15|16@0-", 1),
     "signals AxisFeedback_0.MotorSpeed and MotorTorque overlap"),
    (lambda t: t.replace("BO_ 528 AxisFeedback_0: 8", "BO_ 528 AxisFeedback_0: 3"),
     "signal AxisFeedback_0.MotorTorque (start bit 23, 16 bits) does not fit in the message's 3 bytes"),
])
def test_a_dbc_whose_mapped_signals_collide_is_refused(rec, tmp_path, edit, says):
    """Two messages on one id (cantools only warns), overlapping or out-of-frame mapped signals: once decoded
    as garbage (two joints from the same frames); now exit 2 naming them."""
    from edge_monitor.sources.dbc_source import DbcDecoder
    from protocol.signal_mapping import MappingError, load_mapping
    with pytest.raises(MappingError, match=re.escape(says)):
        DbcDecoder(load_mapping(str(_dbc_mapping(tmp_path, edit))))
    _em("check-mapping", str(rec["log"]), "--mapping", str(_dbc_mapping(tmp_path, edit)), code=2, says=says)


def test_a_dbc_with_sloppy_signals_the_mapping_does_not_use_still_loads(tmp_path):
    """Unmapped signals beyond a short message (cantools strict=False) and multiplexed signals sharing bits
    under different multiplexer values are no collision."""
    from edge_monitor.sources.dbc_source import DbcDecoder
    from protocol.signal_mapping import load_mapping
    decoder = DbcDecoder(load_mapping(str(_dbc_mapping(tmp_path, lambda t: t.replace(
        "BO_ 528 AxisFeedback_0: 8", "BO_ 528 AxisFeedback_0: 4")))))
    assert decoder.describe()[1]["load"] == "AxisLoad.LoadTorque_1"


# ------------------------------------------------------------------------------------------ 8: gear ratio and side
@pytest.mark.parametrize(("keys", "says"), [
    ('gear_ratio = 120\n', 'gear_ratio: applies to joint-side signals only: add side = "joint"'),
    ('side = "motor"\ngear_ratio = 120\n', 'gear_ratio: applies to joint-side signals only'),
    ('side = "joint"\n', 'side = "joint": needs gear_ratio'),
])
def test_gear_ratio_and_joint_side_come_together(tmp_path, keys, says):
    """Once a ratio without side = "joint" was ignored and side = "joint" without a ratio used 1."""
    from protocol.signal_mapping import MappingError, load_mapping

    from foreign_mappings import mapping
    path = mapping("foreign_robot", tmp_path)
    text = path.read_text()
    path.write_text(text.replace("[joint.0]\n", f"[joint.0]\n{keys}", 1))
    with pytest.raises(MappingError, match=re.escape(says)):
        load_mapping(str(path))
    path.write_text(text.replace("[joint.0]\n", '[joint.0]\nside = "joint"\ngear_ratio = 120\n', 1))
    geared = load_mapping(str(path)).joints[0]
    path.write_text(text)
    plain = load_mapping(str(path)).joints[0]
    assert geared.speed is not None and plain.speed is not None
    assert geared.speed.factor == pytest.approx(120 * plain.speed.factor)


# ------------------------------------------------------------------------------------------ 10: replays onto a state
def _shifted(rec, name: str, start: float) -> Path:
    """The recording with its frame times moved to begin at ``start`` [s since 1970]."""
    lines = []
    for line in rec["log"].read_text().splitlines():
        stamp, rest = line[1:].split(")", 1)
        lines.append(f"({float(stamp) + start:.6f}){rest}")
    path = rec["dir"] / f"{name}.log"
    path.write_text("\n".join(lines) + "\n")
    return path


def test_an_older_log_replayed_onto_a_state_dir_is_warned_about(rec, tmp_path):
    """The same log replayed again onto its --state-dir was learned again as new cycles without a word."""
    first, later = _shifted(rec, "day1", 1.795e9), _shifted(rec, "day2", 1.795e9 + 86400)
    state = str(tmp_path / "state")
    _, _, err = _replay(first, "--state-dir", state)
    assert "fresh --state-dir" not in err and (tmp_path / "state" / "replayed_input.json").is_file()
    _, _, err = _replay(later, "--state-dir", state)                          # the next day's log: as before
    assert "fresh --state-dir" not in err
    _, _, err = _replay(first, "--state-dir", state)                          # an older one
    assert "day1.log begins at 2026-11-18T" in err and "before the end" in err and "fresh --state-dir" in err
    _, _, err = _replay(rec["log"], "--state-dir", str(tmp_path / "relative"))   # timed from its start: not compared
    _, _, err = _replay(rec["log"], "--state-dir", str(tmp_path / "relative"))
    assert "fresh --state-dir" not in err


# ------------------------------------------------------------------------------------------ minor ones
@pytest.mark.parametrize("index", ['0x2010', '"2010"', '"2010h"', '"0x2010"', "8208"])
def test_a_cia402_object_index_written_as_text_is_hex_as_the_tpdo_objects(tmp_path, index):
    """``index = "2010"`` was read as decimal 2010 (0x7DA) where TPDO objects "6041" are hex."""
    from protocol.signal_mapping import load_mapping

    from foreign_mappings import mapping
    path = mapping("cia402", tmp_path)
    path.write_text(path.read_text().replace("index = 0x2010", f"index = {index}"))
    temperature = load_mapping(str(path)).joints[0].temperature
    assert temperature is not None and temperature.index == 0x2010


def test_a_blf_shorter_than_its_header_and_a_header_only_table_are_said_to_be_so(rec, tmp_path):
    """A BLF cut under 72 bytes said "unpack requires a buffer of 72 bytes"; a CSV with its header only replayed
    to exit 0 and nothing. Both now say what they are; whole files still replay."""
    blf = tmp_path / "cut.blf"
    blf.write_bytes(b"LOGG" + bytes(40))
    _em("replay", str(blf), code=1, says="is truncated: 44 bytes, less than a BLF file header (72)")
    header = tmp_path / "header.csv"
    header.write_text(rec["csv"].read_text().splitlines()[0] + "\n")
    for command in ("replay", "check-mapping"):
        _em(command, str(header), "--mapping", str(rec["toml"]), code=2, says="is empty (a header, no rows)")


# ------------------------------------------------------------------------------------------ a trace at another rate
def test_a_trace_read_at_a_rate_other_than_its_rows_says_which_rate_to_state(rec):
    """Before, a mapping whose rate_hz was not the trace's rows' (here 250 Hz for a 500 Hz table) gave cycles
    without a friction curve and said nothing; now one warning names both rates and the setting, and the
    trace at its own rate gives none (test above: "steps by" is not in its stderr)."""
    mapping = rec["dir"] / "run_250.toml"
    text = rec["toml"].read_text()
    assert "rate_hz = 500.0" in text
    mapping.write_text(text.replace("rate_hz = 500.0", "rate_hz = 250.0"))
    _, _, err = _replay(rec["csv"], "--mapping", str(mapping))
    assert "steps by 0.002 s (500 Hz) in the median, but its samples are read at 250 Hz" in err
    assert "state the trace's rate in the mapping: rate_hz = 500" in err
    check = _em("check-mapping", "--mapping", str(mapping), str(rec["csv"]))
    assert "but its samples are read at 250 Hz" in check.stdout + check.stderr
