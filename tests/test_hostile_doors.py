"""Issue 50, the new doors under attack: trace tables, CiA 402 drives, DBC frames, export-trace and two
agents on one state directory, as a hurried engineer or a hostile file would try them, through the real
commands. Each gives a clear one-line message with the documented exit code (2: an input or option that
does not fit, 1: a runtime failure) or a counted drop; never a traceback, a value made up from padding,
or data lost without a count. Resident memory stays bounded (peak from wait4)."""

from __future__ import annotations

import hashlib
import json
import re
import subprocess
import time
from pathlib import Path

import hostile_files as hostile
import numpy as np
import pytest
from test_hostile_traces import MAPPING as TRACE

from foreign_mappings import mapping, record

pytestmark = pytest.mark.slow
ROOT = Path(__file__).resolve().parents[1]
CYCLES = 4
#: Address space a hostile replay may take before an allocation fails: a guard for the machine, not the measure.
#: Address space is mostly reservations (glibc's 64 MB malloc arenas, mimalloc segments, thread stacks) whose count
#: depends on thread contention: the same replay peaked at 1.7 GB unlimited here and passed under 0.8 GB, and
#: failed under 1.5 GB on a loaded CI run. What the bugs below blew up was resident memory.
MEMORY_LIMIT = 4 << 30
#: Resident peak (MB) a replay of these tables may reach: they peak at 155-211 MB (``/usr/bin/time -v``), the
#: bugs at >= 2500 MB; the bound sits 3.6x above the first and 3.3x below the second.
RESIDENT_BOUND_MB = 768


def _sim(tmp: Path, name: str, profile: str) -> Path:
    return record(tmp, name, profile, cycles=CYCLES)


@pytest.fixture(scope="module")
def recs(tmp_path_factory) -> dict[str, Path]:
    tmp = tmp_path_factory.mktemp("doors")
    cia, foreign = mapping("cia402", tmp), mapping("foreign_robot", tmp)
    out = {"dir": tmp, "native": _sim(tmp, "native", "native"), "cia402": _sim(tmp, "cia402", "cia402"),
           "cia402.toml": cia, "foreign": _sim(tmp, "foreign", f"dbc:{foreign}"), "foreign.toml": foreign}
    done = hostile.run_measured(hostile.edge_monitor("export-trace", str(out["native"]), "--out", str(tmp / "nat.csv"),
                                                     "-q"))
    assert done.returncode == 0, done.stderr
    out["csv"], out["csv.toml"] = tmp / "nat.csv", tmp / "nat.toml"
    return out


def _run(*args: str, code: int, says: str = "", memory: int | None = None, timeout: float = 180) -> hostile.Run:
    run = hostile.run_measured(hostile.edge_monitor(*args), timeout=timeout, memory_limit=memory)
    assert not run.timed_out and "Traceback" not in run.stderr, run.stderr[-3000:]
    assert memory is None or run.max_rss_mb < RESIDENT_BOUND_MB, (run.max_rss_mb, args)
    assert run.returncode == code, (run.returncode, run.stdout[-2000:], run.stderr[-2000:])
    assert says in run.stdout + run.stderr, (says, run.stdout[-2000:], run.stderr[-2000:])
    return run


def _replay(table: Path, mapping_path: Path, *extra: str, memory: int | None = None, code: int = 0,
            says: str = "") -> dict:
    """The ``--json`` summary of a replay (exit code 1: no cycle found, the reason said)."""
    return json.loads(_run("replay", str(table), "--mapping", str(mapping_path), "--json", "-q", *extra, code=code,
                           says=says, memory=memory).stdout)


def _table(recs, name: str, edit) -> Path:
    """The exported table with ``edit(row_index, cells) -> cells`` applied to each data row."""
    lines = recs["csv"].read_text().splitlines()
    rows = [";".join(edit(i, line.split(";"))) for i, line in enumerate(lines[1:])]
    path = recs["dir"] / name
    path.write_text("\n".join([lines[0], *rows]) + "\n")
    return path


def _digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


# ------------------------------------------------------------------------------------------ export-trace
def test_export_trace_never_writes_over_its_input_or_an_existing_file(recs, tmp_path):
    log = tmp_path / "in.log"
    log.write_bytes(recs["native"].read_bytes())
    before = _digest(log)
    _run("export-trace", str(log), "--out", str(log), code=2, says="a trace table ends in .csv")
    _run("export-trace", str(log), "--out", str(tmp_path / "x.toml"), code=2, says="a trace table ends in .csv")
    precious = tmp_path / "precious.toml"
    precious.write_text("# the user's own mapping\n")
    _run("export-trace", str(log), "--out", str(tmp_path / "precious.csv"), code=2, says="exists; pass --force")
    assert precious.read_text() == "# the user's own mapping\n" and not (tmp_path / "precious.csv").exists()
    mine = tmp_path / "mine.toml"
    mine.write_text(recs["csv.toml"].read_text())
    _run("export-trace", str(log), "--mapping", str(mine), "--out", str(tmp_path / "mine.csv"), "--force", code=2,
         says="is --mapping")
    _run("export-trace", str(log), "--out", str(tmp_path / "typo" / "dir" / "t.csv"), code=2, says="does not exist")
    assert not (tmp_path / "typo").exists() and _digest(log) == before
    _run("export-trace", str(log), "--out", str(tmp_path / "precious.csv"), "--force", code=0)
    assert precious.read_text().startswith("# trace mapping of precious.csv")


@pytest.mark.parametrize("separator", ['"', "\n", ";;", ".", "-", "e"])
def test_export_trace_refuses_a_separator_its_own_mapping_could_not_read(recs, tmp_path, separator):
    _run("export-trace", str(recs["native"]), "--out", str(tmp_path / "t.csv"), "--separator", separator, code=2,
         says="--separator")
    assert list(tmp_path.iterdir()) == []


def test_a_table_exported_with_a_tab_replays_the_recording(recs, tmp_path):
    _run("export-trace", str(recs["native"]), "--out", str(tmp_path / "t.csv"), "--separator", "\t", code=0)
    assert _replay(tmp_path / "t.csv", tmp_path / "t.toml")["cycles"] == CYCLES


# ------------------------------------------------------------------------------------------ trace tables
def test_one_unterminated_quote_damages_one_cell_not_the_rest_of_the_table(recs):
    clean = _replay(recs["csv"], recs["csv.toml"])

    def quote(i, cells):
        if i == 100:
            cells[1] = '"' + cells[1]
        return cells
    stats = _replay(_table(recs, "quote.csv", quote), recs["csv.toml"])
    assert stats["log"]["frames"] == clean["log"]["frames"] and stats["cycles"] == clean["cycles"] == CYCLES


def test_cycle_marks_that_are_no_cycle_numbers_are_counted_not_published(recs):
    negative = _table(recs, "negative.csv", lambda i, c: [*c[:9], str(-1 - int(float(c[9]))), c[10]])
    stats = _replay(negative, recs["csv.toml"], code=1, says="no cycle found")
    finding = stats["details"]["cycle_finding"]
    assert stats["cycles"] == 0 and finding["cycles_found"] == 0 and finding["bad_marks"] > 1000
    _run("check-mapping", str(negative), "--mapping", str(recs["csv.toml"]), code=2, says="no cycle counter")
    for column, name in ((9, "cycle"), (10, "segment")):      # one absurd mark: counted, the rest published
        one = _table(recs, f"huge_{name}.csv", lambda i, c, k=column: [*c[:k], "1e30", *c[k + 1:]] if i == 5000 else c)
        stats = _replay(one, recs["csv.toml"])
        assert stats["cycles"] == CYCLES and stats["details"]["cycle_finding"]["bad_marks"] == 1


def test_a_row_counter_mapped_as_the_cycle_finds_no_fake_cycles(recs):
    """The class fixed for our frames (cycle_numbering): a cycle mark changes the cycle only as progress
    after a believable cycle length; a row counter (row // 20: 1 000 "cycles" of 40 ms) is a jump."""
    fake = _table(recs, "row_counter.csv", lambda i, c: [*c[:9], str(i // 20), c[10]])
    stats = _replay(fake, recs["csv.toml"])
    assert stats["cycles"] <= CYCLES and stats["details"]["cycle_finding"]["cycle_jumps"] > 500
    _run("check-mapping", str(fake), "--mapping", str(recs["csv.toml"]), code=2, says="no cycle counter")


def test_a_table_whose_time_does_not_advance_is_refused(recs):
    same = _table(recs, "same_time.csv", lambda i, c: ["1.0", *c[1:]])
    for command in ("replay", "check-mapping"):
        _run(command, str(same), "--mapping", str(recs["csv.toml"]), code=2, says="does not advance")


def test_a_parquet_cycle_beyond_int64_is_a_counted_mark(recs, tmp_path):
    import pyarrow as pa
    import pyarrow.csv as pcsv
    import pyarrow.parquet as pq
    table = pcsv.read_csv(recs["csv"], parse_options=pcsv.ParseOptions(delimiter=";"))
    cycle = table.column("cycle").to_numpy().astype(np.uint64)
    cycle[5000] = 2**63 + 5
    pq.write_table(table.set_column(table.schema.get_field_index("cycle"), "cycle", pa.array(cycle)),
                   tmp_path / "t.parquet")
    stats = _replay(tmp_path / "t.parquet", recs["csv.toml"])
    assert stats["cycles"] == CYCLES and stats["details"]["cycle_finding"]["bad_marks"] == 1


def test_memory_stays_bounded_for_a_huge_header_and_unmapped_or_text_parquet_columns(tmp_path):
    """Before: a 500 000-column header took 2.5 GB, then std::bad_alloc (exit 134); a Parquet file with an
    unmapped dictionary column of one 10 kB string unpacked to 2.5 GB. Now each stays under RESIDENT_BOUND_MB."""
    import pyarrow as pa
    import pyarrow.parquet as pq
    (tmp_path / "m.toml").write_text(TRACE)
    names = ["t", "v0", "tau0", "cycle", "segment"] + [f"x{i}" for i in range(500_000)]
    (tmp_path / "wide.csv").write_text(";".join(names) + "\n0.002;1;0.1;0;1" + ";" * 500_000 + "\n")
    for command in ("replay", "check-mapping"):
        _run(command, str(tmp_path / "wide.csv"), "--mapping", str(tmp_path / "m.toml"), code=2,
             says="more than 10000 columns", memory=MEMORY_LIMIT)
    n = 1_000_000
    bomb = pa.DictionaryArray.from_arrays(pa.array(np.zeros(n, dtype=np.int32)), pa.array(["y" * 10_000]))
    columns = {"t": np.arange(1, n + 1) / 500.0, "v0": np.full(n, 8.7), "tau0": np.full(n, 0.1),
               "cycle": (np.arange(n) // 20_000).astype(float), "segment": np.ones(n)}
    pq.write_table(pa.table({**columns, "junk": bomb}), tmp_path / "unmapped.parquet", store_schema=False)
    stats = _replay(tmp_path / "unmapped.parquet", tmp_path / "m.toml", memory=MEMORY_LIMIT)
    assert stats["log"]["frames"] == n
    pq.write_table(pa.table({**columns, "v0": bomb}), tmp_path / "mapped.parquet", store_schema=False)
    _run("replay", str(tmp_path / "mapped.parquet"), "--mapping", str(tmp_path / "m.toml"), code=2,
         says="is not numeric", memory=MEMORY_LIMIT)


def test_a_trace_mapping_on_frames_is_refused_in_one_line(recs):
    for args in (("replay", str(recs["native"])), ("run", "--link", "virtual:doors", "--no-zenoh", "--duration", "1"),
                 ("export-trace", str(recs["native"]), "--out", str(recs["dir"] / "never.csv"))):
        run = _run(*args, "--mapping", str(recs["csv.toml"]), code=2, says="is a trace mapping")
        assert len(run.stderr.strip().splitlines()) == 1


# ------------------------------------------------------------------------------------------ CiA 402, DBC
def _cut(log: Path, out: Path, ids: set[str], keep_bytes: int, every: int = 1) -> Path:
    """The candump log with the frames of ``ids`` cut to ``keep_bytes`` (every ``every``-th of them)."""
    lines, seen = [], 0
    for line in log.read_text().splitlines():
        match = re.match(r"(\(\S+\) \S+ )([0-9A-F]+)#([0-9A-F]*)(.*)", line)
        if match and match.group(2) in ids:
            seen += 1
            if seen % every == 0:
                line = f"{match.group(1)}{match.group(2)}#{match.group(3)[:2 * keep_bytes]}{match.group(4)}"
        lines.append(line)
    out.write_text("\n".join(lines) + "\n")
    return out


def _symptoms(log: Path, mapping_path: Path, code: int = 0, says: str = "") -> tuple[dict, list[dict]]:
    jsonl = log.with_suffix(".jsonl")
    stats = json.loads(_run("replay", str(log), "--mapping", str(mapping_path), "--json", "-q", "--jsonl", str(jsonl),
                            code=code, says=says).stdout)
    return stats, [json.loads(line) for line in jsonl.read_text().splitlines() if '"kind"' not in line]


def test_cia402_tpdos_shorter_than_their_mapping_are_dropped_and_counted(recs):
    """TPDO2 (position, motor temperature) cut to 1 byte once gave every symptom a motor temperature of
    0.0 °C, TPDO1 cut short a speed of 0 rad/s; now each short PDO is a counted malformed frame."""
    clean, clean_records = _symptoms(recs["cia402"], recs["cia402.toml"])
    text = recs["cia402"].read_text()
    tpdo2 = len(re.findall(r" 28[12]#", text))
    stats, records = _symptoms(_cut(recs["cia402"], recs["dir"] / "tpdo2.log", {"281", "282"}, 1),
                               recs["cia402.toml"])
    assert stats["malformed"] == tpdo2 and stats["cycles"] == clean["cycles"]
    assert all(r["operating"]["covariates"].get("motor_temperature") is None for r in records)
    assert all(r["operating"]["covariates"]["motor_temperature"] > 20 for r in clean_records)
    tpdo1 = len(re.findall(r" 181#", text)) // 3
    stats, records = _symptoms(_cut(recs["cia402"], recs["dir"] / "tpdo1.log", {"181"}, 4, every=3),
                               recs["cia402.toml"])
    assert stats["malformed"] == tpdo1 and stats["cycles"] == clean["cycles"]
    for a, b in zip(clean_records, records):      # the kept two thirds give the same curve within its noise
        np.testing.assert_allclose(a["friction"]["torque"], b["friction"]["torque"], atol=5e-4)


@pytest.mark.parametrize("rated", ["0", "-10000"])
def test_an_eds_rated_torque_no_motor_has_is_refused(recs, tmp_path, rated):
    eds = (ROOT / "protocol" / "eds" / "cia402_drive.eds").read_text()
    (tmp_path / "drive.eds").write_text(re.sub(r"(\[6076\][^\[]*DefaultValue=)10000", rf"\g<1>{rated}", eds))
    text = re.sub(r"(?m)^rated_torque_nm = .*$", "", recs["cia402.toml"].read_text())
    (tmp_path / "m.toml").write_text(re.sub(r'eds = "[^"]*"', f'eds = "{tmp_path / "drive.eds"}"', text))
    for command in ("check-mapping", "replay"):
        _run(command, str(recs["cia402"]), "--mapping", str(tmp_path / "m.toml"), code=2, says="6076h")


def test_a_dbc_status_frame_cut_to_its_multiplexer_gives_no_load(recs):
    stats, records = _symptoms(_cut(recs["foreign"], recs["dir"] / "axisload.log", {"2F0"}, 1), recs["foreign.toml"])
    assert stats["malformed"] == len(re.findall(r" 2F0#", recs["foreign"].read_text()))
    assert all(r["load"]["mean"] is None for r in records)


def test_a_dbc_speed_signal_mapped_as_the_cycle_counter_finds_no_cycles(recs, tmp_path):
    text = recs["foreign.toml"].read_text().replace(
        'from = "motion"', 'from = "controller"\ncycle = { message = "AxisFeedback_1", signal = "MotorSpeed" }\n'
                           'segment = { message = "AxisFeedback_1", signal = "AxisState" }')
    (tmp_path / "m.toml").write_text(text)
    stats, _ = _symptoms(recs["foreign"], tmp_path / "m.toml", code=1, says="no cycle found")
    assert stats["cycles"] == 0
    found = stats["details"]["cycle_finding"]
    assert found["bad_marks"] + found["cycle_jumps"] > 1000
    _run("check-mapping", str(recs["foreign"]), "--mapping", str(tmp_path / "m.toml"), code=2, says="no cycle counter")


def test_an_extended_id_dbc_message_decodes_extended_frames_only(recs, tmp_path):
    dbc = (ROOT / "protocol" / "dbc" / "foreign_robot.dbc").read_text()
    (tmp_path / "ext.dbc").write_text(dbc.replace("BO_ 528 AxisFeedback_0", f"BO_ {528 | 1 << 31} AxisFeedback_0"))
    text = re.sub(r'(?m)^dbc = .*$', f'dbc = "{tmp_path / "ext.dbc"}"', recs["foreign.toml"].read_text())
    (tmp_path / "m.toml").write_text(text)
    _run("check-mapping", str(recs["foreign"]), "--mapping", str(tmp_path / "m.toml"), code=2, says="joint 0: no samples")
    extended = recs["foreign"].read_text().replace(" 210#", " 00000210#")
    (tmp_path / "ext.log").write_text(extended)
    stats, records = _symptoms(tmp_path / "ext.log", tmp_path / "m.toml")
    assert stats["cycles"] == CYCLES and {r["joint"] for r in records} == {0, 1}


# ------------------------------------------------------------------------------------------ one state dir
def test_a_second_agent_on_one_state_directory_is_refused(tmp_path):
    state = tmp_path / "state"
    first = subprocess.Popen(hostile.edge_monitor("run", "--link", "virtual:first", "--no-zenoh", "--duration", "30",
                                                  "--state-dir", str(state), "-q"), stderr=subprocess.PIPE)
    try:
        deadline = time.monotonic() + 60
        while not (state / "agent_state.lock").exists() or not (state / "agent_state.lock").read_text().strip():
            assert time.monotonic() < deadline and first.poll() is None
            time.sleep(0.1)
        run = _run("run", "--link", "virtual:second", "--no-zenoh", "--duration", "1", "--state-dir", str(state),
                   code=1, says=f"is in use by another agent (pid {first.pid})")
        assert len(run.stderr.strip().splitlines()) == 1
        _run("replay", str(ROOT / "tests" / "corpus" / "clean.blf"), "--state-dir", str(state), code=1,
             says="in use by another agent")
    finally:
        first.terminate()
        assert first.wait(60) == 0
    _run("run", "--link", "virtual:third", "--no-zenoh", "--duration", "1", "--state-dir", str(state), "-q", code=0)
