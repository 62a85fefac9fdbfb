"""Trace tables: a recording exported as CSV (`edge-monitor export-trace`) replays to the same symptoms as
the recording; long tables with `;`, times in ms and units in the headers; tables that do not fit their
mapping get a clear error (exit 2)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.csv as pcsv
import pytest

from foreign_mappings import SPEEDS

pytestmark = pytest.mark.slow
EM = [sys.executable, "-m", "edge_monitor.cli"]
CONFIG = """
[kl]
n_nominal_cycles = 2
[model]
enabled = false
[decision]
n_nominal = 3
density = "gauss"
steady_relearn = false
quantities = ["wear", "kl_raw"]
"""


def _symptoms(path: Path) -> list[dict]:
    """The symptom records of a JSONL output (alarm and advisory events carry a "kind")."""
    return [r for r in map(json.loads, path.open()) if "kind" not in r]


def _replay(tmp: Path, file: Path, *extra: str) -> tuple[dict, list[dict]]:
    jsonl = tmp / f"{file.stem}-{len(extra)}.jsonl"
    done = subprocess.run([*EM, "replay", str(file), "--json", "--jsonl", str(jsonl), "--config",
                           str(tmp / "agent.toml"), "-q", *extra], capture_output=True, text=True, check=True)
    return json.loads(done.stdout), _symptoms(jsonl)


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("trace")
    (tmp / "agent.toml").write_text(CONFIG)
    log = tmp / "run.blf"
    subprocess.run([sys.executable, "-m", "sim_controller.cli", "record", "--out", str(log), "--joints", "2",
                    "--cycles", "10", "--seed", "2", "--speeds", ",".join(map(str, SPEEDS)),
                    "--wear-ramp", "1:3:10:0:60", "-q"], check=True)
    return tmp, log


def test_exported_csv_replays_to_the_same_symptoms(recording):
    tmp, log = recording
    stats, native = _replay(tmp, log)
    csv = tmp / "run.csv"
    subprocess.run([*EM, "export-trace", str(log), "--out", str(csv), "-q"], check=True)
    assert csv.read_text().splitlines()[0].startswith('"time [s]";"J0 speed [rad/s]"')
    trace_stats, traced = _replay(tmp, csv, "--mapping", str(csv.with_suffix(".toml")))
    assert trace_stats["alarms"] == stats["alarms"] and trace_stats["cycles"] == stats["cycles"]
    assert len(traced) == len(native)
    for a, b in zip(native, traced):
        assert (a["joint"], a["cycle"]) == (b["joint"], b["cycle"])
        np.testing.assert_allclose(a["friction"]["torque"], b["friction"]["torque"], rtol=1e-9)
        for section in ("wear", "kl"):
            for key, value in a[section].items():
                if isinstance(value, float):
                    assert b[section][key] == pytest.approx(value, rel=1e-6, abs=1e-12), (section, key)
        assert {q: d["alarm"] for q, d in a["decisions"].items()} == {q: d["alarm"] for q, d in b["decisions"].items()}


def test_long_table_in_ms_with_semicolons_and_units_in_headers(recording, tmp_path):
    tmp, log = recording
    wide = tmp / "wide.csv"
    subprocess.run([*EM, "export-trace", str(log), "--out", str(wide), "-q"], check=True)
    table = pcsv.read_csv(wide, parse_options=pcsv.ParseOptions(delimiter=";"))
    time_ms = table.column("time [s]").to_numpy() * 1e3
    rows = []
    for j in (0, 1):
        speed = table.column(f"J{j} speed [rad/s]").to_numpy(zero_copy_only=False) * 60 / (2 * np.pi)
        rows.append(pa.table({"t [ms]": time_ms, "axis": [f"A{j + 1}"] * len(time_ms), "speed [rpm]": speed,
                              "torque [Nm]": table.column(f"J{j} torque [fraction]").to_numpy(zero_copy_only=False)
                              * 50.0}))
    long = tmp_path / "long.csv"
    pcsv.write_csv(pa.concat_tables(rows).sort_by("t [ms]"), long, write_options=pcsv.WriteOptions(delimiter=";"))
    (tmp_path / "long.toml").write_text(f"""
kind = "trace"
[trace]
layout = "long"
separator = ";"
time_column = "t [ms]"
time_unit = "ms"
joint_column = "axis"
[cycles]
from = "motion"
speeds = [{", ".join(map(str, SPEEDS))}]
[joint.0]
key = "A1"
reference_torque_nm = 50.0
speed = {{ column = "speed [rpm]" }}
torque = {{ column = "torque [Nm]" }}
[joint.1]
key = "A2"
reference_torque_nm = 50.0
speed = {{ column = "speed [rpm]" }}
torque = {{ column = "torque [Nm]" }}
""")
    (tmp_path / "agent.toml").write_text(CONFIG)
    stats, records = _replay(tmp_path, long, "--mapping", str(tmp_path / "long.toml"))
    _, native = _replay(tmp, log)
    assert stats["cycles"] == 10
    ref = {(r["joint"], r["cycle"]): r["friction"]["torque"] for r in native}
    for r in records:
        np.testing.assert_allclose(r["friction"]["torque"], ref[(r["joint"], r["cycle"])], atol=1e-4)


def test_a_table_that_does_not_fit_its_mapping(recording, tmp_path):
    tmp, log = recording
    csv = tmp / "bad.csv"
    subprocess.run([*EM, "export-trace", str(log), "--out", str(csv), "-q"], check=True)
    mapping = csv.with_suffix(".toml")
    mapping.write_text(mapping.read_text().replace('"J1 speed [rad/s]"', '"J1 velocity [rad/s]"'))
    done = subprocess.run([*EM, "replay", str(csv), "--mapping", str(mapping)], capture_output=True, text=True)
    assert done.returncode == 2 and "column 'J1 velocity [rad/s]' is not in the table" in done.stderr
    done = subprocess.run([*EM, "replay", str(csv)], capture_output=True, text=True)
    assert done.returncode == 2 and "needs --mapping" in done.stderr


@pytest.mark.parametrize("suffix", [".csv", ".parquet"])
@pytest.mark.parametrize("stop, code", [(KeyboardInterrupt, 130), (OSError(28, "No space left on device"), 1)])
def test_an_export_cut_short_leaves_no_half_table(recording, tmp_path, monkeypatch, capsys, suffix, stop, code):
    """Ctrl-C (or SIGTERM) or a full disk after the first rows: no table under --out, no partial file, no
    mapping (before, the half table stayed under its name, a Parquet one unreadable without its footer, and a
    second export refused to write over it); the next export then writes the whole table."""
    import edge_monitor.cli
    from edge_monitor.sources.trace_export import TraceWriter

    _, log = recording
    out = tmp_path / f"cut{suffix}"
    real_write, calls = TraceWriter.write, []

    def write_then_stop(self, block):
        real_write(self, block)
        calls.append(1)
        if len(calls) == 2:
            raise stop
    monkeypatch.setattr(TraceWriter, "write", write_then_stop)
    assert edge_monitor.cli.main(["export-trace", str(log), "--out", str(out), "-q"]) == code
    assert len(calls) == 2 and sorted(p.name for p in tmp_path.iterdir()) == []
    assert "export-trace" in capsys.readouterr().err
    monkeypatch.setattr(TraceWriter, "write", real_write)
    assert edge_monitor.cli.main(["export-trace", str(log), "--out", str(out), "-q"]) == 0
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([out.name, out.with_suffix(".toml").name])
    import pyarrow.parquet as pq

    table = pq.read_table(out) if suffix == ".parquet" else pcsv.read_csv(
        out, parse_options=pcsv.ParseOptions(delimiter=";"))
    assert table.num_rows > 0
