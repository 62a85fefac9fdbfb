"""Rerun sink: recordings written to disk and read back with rerun.chunk.RrdReader and the rerun CLI
(`rerun rrd verify`, `rerun rrd stats`): a compact recording (few chunks, one blueprint, static data
static), wear bounds, friction sign."""

from __future__ import annotations

import logging
import math
import shutil
import subprocess
import sys
from collections import Counter
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from edge_monitor.sinks.rerun_view import (
    CRITICAL_WEAR,
    FRICTION_SCALE,
    IMMEDIATE,
    SAVE_BATCHING,
    Y_UP,
    Batching,
    RerunSetupError,
    RerunSink,
    cycle_colors,
    wear_bounds,
)

from recordings import rows_by_entity

pytestmark = pytest.mark.timeout(60)

QUANTITIES = ("wear", "kl_raw", "kl_weighted", "joint")
LEARNING_CYCLES = 5


def symptom(robot: str, joint: int, cycle: int, levels: int = 4) -> dict:
    """A schema-1 record: detectors learn for LEARNING_CYCLES cycles; KL weighted missing on odd cycles."""
    monitoring = cycle >= LEARNING_CYCLES
    speeds = np.linspace(2.0, 280.0, levels)
    return {"schema": 1, "robot": robot, "joint": joint, "cycle": cycle, "t": 25.0 * cycle,
            "friction": {"speeds": speeds.tolist(), "torque": (0.03 + 1e-4 * speeds + 1e-5 * cycle).tolist(),
                         "stderr": [1e-3] * levels},
            "wear": {"estimate": 0.5 * cycle, "std": 2.0, "temperature": 40.0 + cycle % 5},
            "kl": {"raw": 0.01 * cycle, "weighted": None if cycle % 2 else 0.02 * cycle,
                   **({"temperature": {"value": 38.0 + 0.1 * cycle, "reference": 38.0, "source": "thermal_model"}}
                      if monitoring else {})},
            "decisions": {q: {"state": "monitoring" if monitoring else "learning",
                              "statistic": float(cycle) if monitoring else None,
                              "threshold": 11.3 if monitoring else None, "alarm": monitoring and cycle > 11,
                              "change_cycle": None, "delta": None,
                              "miss_probability": 0.5 if monitoring else None} for q in QUANTITIES},
            "alarm": monitoring and cycle > 11,
            "density": {"grid": [0.0, 0.05, 0.1, 0.15], "nominal": [0.2, 1.0, 0.6, 0.1],
                        "cycle": [0.1, 0.8, 0.9, 0.2]}}


def expected_rows(records: list[dict], blocks: int = 1) -> Counter:
    """Rows the sink must write: one per record and entity whose value is present; the critical level
    at the first and last cycle of each of a joint's ``blocks``; the nominal density once per joint (it
    does not change)."""
    expected: Counter = Counter()
    joints = {(r["robot"], r["joint"]) for r in records}
    for robot, joint in joints:
        n = sum(1 for r in records if (r["robot"], r["joint"]) == (robot, joint))
        expected[f"/robot/{robot}/joint/{joint}/wear/critical"] = min(n, 2 * blocks)
        expected[f"/robot/{robot}/joint/{joint}/density/nominal"] = 1
    for r in records:
        base = f"/robot/{r['robot']}/joint/{r['joint']}"
        for sub in ("wear/estimate", "wear/upper", "wear/lower", "temperature", "kl/raw", "friction/curve",
                    "density/cycle"):
            expected[f"{base}/{sub}"] += 1
        if r["kl"]["weighted"] is not None:
            expected[f"{base}/kl/weighted"] += 1
        if "temperature" in r["kl"]:
            expected[f"{base}/temperature/compensation"] += 1
        for q, d in r["decisions"].items():
            if d["statistic"] is not None:
                expected[f"{base}/glr/{q}/statistic"] += 1
                expected[f"{base}/glr/{q}/threshold"] += 1
                expected[f"{base}/miss/{q}"] += 1
    return expected


def test_saved_recording_has_expected_entities_and_rows(tmp_path):
    path = tmp_path / "run.rrd"
    records = [symptom("r1", j, c) for c in range(30) for j in (1, 2)]
    sink = RerunSink.open(f"save:{path}", recording_id="test-run")
    for record in records:
        sink.log_symptom(record)
    sink.log_alarm({"schema": 1, "robot": "r1", "joint": 2, "cycle": 12, "quantity": "wear", "state": "raised",
                    "statistic": 12.0, "threshold": 11.3, "miss_probability": 0.5, "change_cycle": 6})
    sink.log_health({"frames_total": 1000, "frames_per_second": 3010.5, "queue_depth": 3, "ok": True}, robot="r1")
    sink.close()
    assert sink.errors == 0 and sink.records_logged == len(records)

    counts = rows_by_entity(path)
    expected = expected_rows(records)
    expected["/robot/r1/joint/2/alarms"] = 1
    for name in ("frames_total", "frames_per_second", "queue_depth"):
        expected[f"/robot/r1/agent/health/{name}"] = 1
    counts.pop("/__properties", None)
    assert counts == expected


def test_density_as_numpy_arrays_draws_like_lists(tmp_path):
    """In-process sinks get the cycle's density as numpy arrays (the live agent), viewers get JSON lists."""
    path = tmp_path / "arrays.rrd"
    records = [symptom("r1", 0, c) for c in range(3)]
    for record in records:
        record["density"] = {k: np.asarray(v) for k, v in record["density"].items()}
    sink = RerunSink.open(f"save:{path}")
    for record in records:
        sink.log_symptom(record)
    sink.close()
    assert sink.errors == 0
    counts = rows_by_entity(path)
    assert counts["/robot/r1/joint/0/density/nominal"] == 1 and counts["/robot/r1/joint/0/density/cycle"] == 3


def test_batch_path_writes_the_same_rows_as_record_by_record(tmp_path):
    records = [symptom(robot, j, c) for robot in ("a", "b") for j in range(3) for c in range(40)]
    path = tmp_path / "batch.rrd"
    sink = RerunSink.open(f"save:{path}")
    sink.log_symptoms(records[::-1])   # any order, any number of robots and joints
    sink.close()
    counts = rows_by_entity(path)
    counts.pop("/__properties", None)
    assert counts == expected_rows(records)
    from rerun.chunk import RrdReader

    assert len(RrdReader(str(path)).blueprints()) == 1   # one layout for all six joints of the block


def test_values_and_colours_read_back(tmp_path):

    path = tmp_path / "values.rrd"
    records = [symptom("r1", 0, c) for c in range(10)]
    sink = RerunSink.open(f"save:{path}")
    sink.log_symptoms(records)
    kl_raw = {"quantity": "kl_raw", "cycle": 6, "statistic": 13.0, "threshold": 11.3, "miss_probability": 0.1,
              "change_cycle": 4, "cause": None, "crossings": 1}
    sink.log_alarm({"schema": 1, "robot": "r1", "joint": 0, "cycle": 9, "quantity": "kl_raw", "state": "cleared",
                    "statistic": None, "threshold": None, "miss_probability": None, "change_cycle": None,
                    "fault": "r1/0/6", "open": False, "detectors": [kl_raw, {**kl_raw, "quantity": "wear"}]})
    sink.close()
    values = _values(path)
    upper = np.array(values["/robot/r1/joint/0/wear/upper:Scalars:scalars"]).ravel()
    assert np.allclose(upper, [r["wear"]["estimate"] + 2 * r["wear"]["std"] for r in records])
    assert values["/robot/r1/joint/0/wear/critical:Scalars:scalars"] == [[CRITICAL_WEAR], [CRITICAL_WEAR]]
    positions = values["/robot/r1/joint/0/friction/curve:Points2D:positions"]
    assert len(positions) == len(records) and all(len(p) == 4 for p in positions)
    last = np.array(positions[-1])
    assert np.allclose(last[:, 0], records[-1]["friction"]["speeds"], rtol=1e-6)
    # the logged y is +torque ‰ (not negated); a static transform flips Rerun's downward 2D y axis
    assert np.allclose(last[:, 1] / FRICTION_SCALE, records[-1]["friction"]["torque"], rtol=1e-6)
    statics = _static_values(path)
    assert statics["/robot/r1/joint/0/friction/curve:Transform3D:scale"] == [[list(Y_UP)]]
    strip = np.array(values["/robot/r1/joint/0/density/cycle:LineStrips2D:strips"][-1][0])
    assert (strip[:, 1] >= 0).all() and strip[:, 1].max() > 0
    colors = values["/robot/r1/joint/0/friction/curve:Points2D:colors"]
    assert colors[0] != colors[-1] and len(set(colors[0])) == 1   # one colour per cycle, changing with cycle
    (text,) = values["/robot/r1/joint/0/alarms:TextLog:text"]
    assert text[0] == "cycle 9: fault r1/0/6 cleared — kl_raw; wear"


def _values(path: Path, static: bool = False) -> dict[str, list]:
    """Per ``entity:column``, the values of the temporal (or static) rows of a recording."""
    from rerun.chunk import RrdReader

    values: dict[str, list] = {}
    for chunk in RrdReader(str(path)).stream():
        if chunk.is_static != static:
            continue
        batch = chunk.to_record_batch()
        for column in batch.schema.names:
            if ":" in column and not column.startswith("rerun."):
                values.setdefault(f"{chunk.entity_path}:{column}", []).extend(batch.column(column).to_pylist())
    return values


def _static_values(path: Path) -> dict[str, list]:
    return _values(path, static=True)


def test_off_does_not_import_rerun():
    code = ("import sys\n"
            "from edge_monitor.sinks.rerun_view import RerunSink\n"
            "sink = RerunSink.open('off')\n"
            "sink.log_symptom({'robot': 'r', 'joint': 0, 'cycle': 0})\n"
            "sink.log_alarm({}); sink.log_health({'x': 1}); sink.close()\n"
            "print('rerun' in sys.modules, sink.enabled)\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    assert out.stdout.split() == ["False", "False"]


def test_spawn_without_display_falls_back(tmp_path, monkeypatch, caplog):
    caplog.set_level(logging.WARNING, logger="edge_monitor.sinks.rerun_view")   # whatever levels earlier
    monkeypatch.delenv("DISPLAY", raising=False)                                 # tests' CLI runs left
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    path = tmp_path / "fallback.rrd"
    sink = RerunSink.open("spawn", fallback_save=str(path))
    assert sink.spec == f"save:{path}" and "no display" in sink.fallback_reason
    sink.log_symptom(symptom("r1", 0, 0))
    sink.close()
    assert rows_by_entity(path)["/robot/r1/joint/0/wear/estimate"] == 1
    off = RerunSink.open("spawn")
    assert off.spec == "off" and not off.enabled
    assert any("no display" in r.message for r in caplog.records)


def test_bad_specs_and_paths_give_clear_errors(tmp_path):
    with pytest.raises(RerunSetupError, match="use off, save:PATH"):
        RerunSink.open("file:x.rrd")
    with pytest.raises(RerunSetupError, match="needs a path"):
        RerunSink.open("save:")
    blocker = tmp_path / "a-file"
    blocker.write_text("")
    with pytest.raises(RerunSetupError, match="writable path"):
        RerunSink.open(f"save:{blocker}/x.rrd")


def test_malformed_records_are_counted_not_raised(tmp_path):
    sink = RerunSink.open(f"save:{tmp_path / 'bad.rrd'}")
    sink.log_symptoms([{"cycle": 1}, {"robot": "r1", "joint": "x", "cycle": 2}])
    sink.log_symptom({"robot": "r1", "joint": 0})                # no cycle
    sink.log_alarm({"robot": "r1"})
    sink.log_symptom(symptom("r1", 0, 3))                          # good records still drawn
    sink.close()
    assert sink.errors == 4 and sink.records_logged == 1


_maybe_number = st.one_of(st.none(), st.just(math.nan), st.floats(-1e6, 1e6))


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(wear=_maybe_number, std=_maybe_number, kl=_maybe_number, statistic=_maybe_number,
       speeds=st.lists(_maybe_number, max_size=6), torque=st.lists(_maybe_number, max_size=6))
def test_partial_records_draw_without_errors(tmp_path, wear, std, kl, statistic, speeds, torque):
    sink = RerunSink.open(f"save:{tmp_path / 'partial.rrd'}")
    record = {"robot": "r1", "joint": 0, "cycle": 4, "t": None,
              "friction": {"speeds": speeds, "torque": torque, "stderr": []},
              "wear": {"estimate": wear, "std": std, "temperature": None}, "kl": {"raw": kl, "weighted": kl},
              "decisions": {"wear": {"state": "monitoring", "statistic": statistic, "threshold": 10.0,
                                     "miss_probability": None}}}
    sink.log_symptom(record)
    sink.close()
    assert sink.errors == 0 and sink.records_logged == 1


def test_cycle_colours_run_from_dark_to_yellow():
    colors = cycle_colors(np.array([0, 500, 1000, 5000]), span=1000)
    assert colors.dtype == np.uint8 and colors.shape == (4, 3)
    assert colors[0].tolist() == [68, 1, 84] and colors[2].tolist() == [253, 231, 37]
    assert colors[3].tolist() == colors[2].tolist()   # saturates after the span


# ------------------------------------------------------------------------------- a compact recording


def _rerun_cli() -> str:
    executable = shutil.which("rerun", path=str(Path(sys.executable).parent)) or shutil.which("rerun")
    if executable is None:
        pytest.skip("the rerun executable is not installed")
    return executable


def _demo_like_records(joints: int = 2, cycles: int = 130, grid: int = 512) -> list[dict]:
    """What the demo's agent draws, in its order: every joint of cycle 0, then of cycle 1, … with the
    cycle's torque density on a 512-point grid (the nominal density is learned once)."""
    x = np.linspace(-0.2, 0.2, grid)
    nominal = np.exp(-0.5 * (x / 0.05) ** 2)
    records = []
    for c in range(cycles):
        for j in range(joints):
            record = symptom("demo-robot", j, c)
            record["density"] = {"grid": x, "nominal": nominal, "cycle": np.exp(-0.5 * ((x - 1e-4 * c) / 0.05) ** 2)}
            records.append(record)
    return records


def test_demo_sized_recording_is_compact_and_verifies(tmp_path):
    """The agent hands the sink one record at a time; a recording file still gets one chunk per entity
    (not one per record): `rerun rrd stats` does not call it unoptimised, `rerun rrd verify` passes, the
    blueprint is in it once, static data once."""
    from rerun.chunk import RrdReader

    records = _demo_like_records()
    sizes, chunks = {}, {}
    for name, batching in (("blocks", SAVE_BATCHING), ("immediate", IMMEDIATE)):
        path = tmp_path / f"{name}.rrd"
        sink = RerunSink.open(f"save:{path}", recording_id="demo", batching=batching, compact=False)
        for i, record in enumerate(records):
            sink.log_symptom(record)
            if i % 6 == 5:
                sink.log_health({"frames_total": 1000 * i, "frames_per_second": 3000.0, "queue_depth": i % 7,
                                 "time": 1.8e9 + i}, robot="demo-robot")
        sink.log_alarm({"robot": "demo-robot", "joint": 1, "cycle": 105, "quantity": "wear", "state": "raised",
                        "statistic": 12.0, "threshold": 11.3, "miss_probability": 0.01, "change_cycle": 96})
        sink.close()
        assert sink.errors == 0 and sink.records_logged == len(records) and sink.alarms_logged == 1
        sizes[name] = path.stat().st_size
        chunks[name] = sum(1 for _ in RrdReader(str(path)).stream())
        if name == "blocks":
            assert sink.blueprints_sent == 1 and len(RrdReader(str(path)).blueprints()) == 1
            assert rows_by_entity(path)["/robot/demo-robot/joint/1/wear/estimate"] == 130
            statics = Counter(chunk.entity_path for chunk in RrdReader(str(path)).stream() if chunk.is_static)
            assert max(statics.values()) == 1                        # static data logged once per entity
            assert statics["/robot/demo-robot/joint/0/wear/critical"] == 1
            assert rows_by_entity(path)["/robot/demo-robot/joint/0/wear/critical"] == 2   # not one per cycle
            cli = _rerun_cli()
            verify = subprocess.run([cli, "rrd", "verify", str(path)], capture_output=True, text=True, timeout=120,
                                    env={"RERUN_ANALYTICS": "0", "PATH": "/usr/bin:/bin"})
            assert verify.returncode == 0, verify.stdout + verify.stderr
            stats = subprocess.run([cli, "rrd", "stats", str(path)], capture_output=True, text=True, timeout=120,
                                   env={"RERUN_ANALYTICS": "0", "PATH": "/usr/bin:/bin"})
            assert stats.returncode == 0 and "Optimization check" in stats.stdout + stats.stderr, stats.stderr
            assert "unoptimized" not in (stats.stdout + stats.stderr).lower()
    print("chunks", chunks, "bytes", sizes)
    # one chunk per entity instead of one per record and entity
    assert chunks["blocks"] <= 200 and chunks["immediate"] > 10 * chunks["blocks"], chunks
    assert sizes["blocks"] < sizes["immediate"] / 2, sizes


def test_blueprint_is_sent_once_and_again_only_for_a_new_joint(tmp_path):
    from rerun.chunk import RrdReader

    path = tmp_path / "fleet.rrd"
    sink = RerunSink.open(f"save:{path}", batching=Batching(records=100, seconds=None))
    sink.log_health({"frames_total": 1}, robot="r1")          # health alone sends no layout
    sink.flush()
    assert sink.blueprints_sent == 0
    for c in range(20):
        for j in range(3):
            sink.log_symptom(symptom("r1", j, c))
    sink.flush()
    sink.log_symptoms([symptom("r1", j, 20) for j in range(3)])
    sink.flush()
    assert sink.blueprints_sent == 1                          # later blocks of the same joints: no resend
    sink.log_symptom(symptom("r2", 0, 0))                     # a robot joins later
    sink.close()
    assert sink.blueprints_sent == 2 and len(RrdReader(str(path)).blueprints()) == 2


def test_blocks_are_drawn_by_count_and_by_age(tmp_path):
    import time

    now = [0.0]
    sink = RerunSink(None, "test")                            # off: nothing buffered, nothing drawn
    sink.log_symptom(symptom("r1", 0, 0))
    assert sink.records_logged == 0
    counted = RerunSink.open(f"save:{tmp_path / 'count.rrd'}", batching=Batching(records=3, seconds=None))
    counted.log_symptoms([symptom("r1", 0, 0), symptom("r1", 0, 1)])
    assert counted.records_logged == 0
    counted.log_symptom(symptom("r1", 0, 2))
    assert counted.records_logged == 3
    counted.close()

    import rerun as rr

    rec = rr.RecordingStream("test", recording_id="aged")
    rec.save(str(tmp_path / "aged.rrd"))
    aged = RerunSink(rec, "save", batching=Batching(records=1000, seconds=10.0), clock=lambda: now[0])
    aged.log_symptom(symptom("r1", 0, 0))
    now[0] = 5.0
    aged.log_symptom(symptom("r1", 0, 1))
    assert aged.records_logged == 0
    now[0] = 10.5                       # the oldest has waited 10 s: the next record draws the block…
    aged.log_symptom(symptom("r1", 0, 2))
    assert aged.records_logged == 3
    aged.log_symptom(symptom("r1", 0, 3))
    now[0] = 21.0                       # … and without one the block thread does
    deadline = time.monotonic() + 30.0
    while aged.records_logged < 4 and time.monotonic() < deadline:
        time.sleep(0.05)
    assert aged.records_logged == 4
    aged.close()
    assert rows_by_entity(tmp_path / "aged.rrd")["/robot/r1/joint/0/wear/estimate"] == 4


def test_wear_bounds_are_one_sided_where_wear_is_not_identifiable(tmp_path):
    healthy = {"estimate": 3.0, "std": 200.0, "temperature": 40.0, "upper_95": 19.0, "identifiable": False}
    worn = {"estimate": 50.0, "std": 4.0, "temperature": 41.0, "upper_95": 57.0, "identifiable": True}
    wide = {"estimate": 60.0, "std": 30.0, "temperature": 41.0}      # no identifiability field: ±2σ, clipped
    records = []
    for c, wear in enumerate((healthy, worn, wide)):
        record = symptom("r1", 0, c)
        record["wear"] = wear
        records.append(record)
    upper, lower = wear_bounds(records)
    assert upper.tolist() == [19.0, 58.0, 100.0] and lower.tolist() == [0.0, 42.0, 0.0]
    path = tmp_path / "bounds.rrd"
    sink = RerunSink.open(f"save:{path}")
    sink.log_symptoms(records)
    sink.close()
    values = _values(path)
    assert np.ravel(values["/robot/r1/joint/0/wear/upper:Scalars:scalars"]).tolist() == [19.0, 58.0, 100.0]
    assert np.ravel(values["/robot/r1/joint/0/wear/lower:Scalars:scalars"]).tolist() == [0.0, 42.0, 0.0]
    assert max(np.ravel(values["/robot/r1/joint/0/wear/upper:Scalars:scalars"])) <= 100.0   # never ±400
    names = _static_values(path)["/robot/r1/joint/0/wear/upper:SeriesLines:names"]
    assert "95 % one-sided" in names[0][0]


def test_one_bad_record_in_a_block_costs_only_itself(tmp_path):
    """Records are drawn in blocks per (robot, joint); a record that cannot be drawn is isolated and
    counted, the rest of its block is still drawn."""
    sink = RerunSink.open(f"save:{tmp_path / 'block.rrd'}")
    bad = symptom("r1", 0, 5)
    bad["friction"] = [1]                                         # not a table: drawing it fails
    sink.log_symptoms([symptom("r1", 0, c) for c in range(5)] + [bad] + [symptom("r1", 0, 6)])
    sink.close()
    assert sink.errors == 1 and sink.records_logged == 6
