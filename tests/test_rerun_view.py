"""Rerun sink: recordings written to disk and read back with rerun.chunk.RrdReader."""

from __future__ import annotations

import math
import subprocess
import sys
from collections import Counter

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from edge_monitor.sinks.rerun_view import CRITICAL_WEAR, FRICTION_SCALE, RerunSetupError, RerunSink, cycle_colors

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
            "kl": {"raw": 0.01 * cycle, "weighted": None if cycle % 2 else 0.02 * cycle},
            "decisions": {q: {"state": "monitoring" if monitoring else "learning",
                              "statistic": float(cycle) if monitoring else None,
                              "threshold": 11.3 if monitoring else None, "alarm": monitoring and cycle > 11,
                              "change_cycle": None, "delta": None,
                              "miss_probability": 0.5 if monitoring else None} for q in QUANTITIES},
            "alarm": monitoring and cycle > 11,
            "density": {"grid": [0.0, 0.05, 0.1, 0.15], "nominal": [0.2, 1.0, 0.6, 0.1],
                        "cycle": [0.1, 0.8, 0.9, 0.2]}}


def expected_rows(records: list[dict], per_record_density: bool) -> Counter:
    """Rows the sink must write: one per record and entity whose value is present."""
    expected: Counter = Counter()
    for r in records:
        base = f"/robot/{r['robot']}/joint/{r['joint']}"
        for sub in ("wear/estimate", "wear/upper", "wear/lower", "wear/critical", "temperature", "kl/raw",
                    "friction/curve"):
            expected[f"{base}/{sub}"] += 1
        if r["kl"]["weighted"] is not None:
            expected[f"{base}/kl/weighted"] += 1
        for q, d in r["decisions"].items():
            if d["statistic"] is not None:
                expected[f"{base}/glr/{q}/statistic"] += 1
                expected[f"{base}/glr/{q}/threshold"] += 1
                expected[f"{base}/miss/{q}"] += 1
        if per_record_density:
            expected[f"{base}/density/nominal"] += 1
            expected[f"{base}/density/cycle"] += 1
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
    expected = expected_rows(records, per_record_density=True)
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
    assert counts["/robot/r1/joint/0/density/nominal"] == 3 and counts["/robot/r1/joint/0/density/cycle"] == 3


def test_batch_path_writes_the_same_rows_as_record_by_record(tmp_path):
    records = [symptom(robot, j, c) for robot in ("a", "b") for j in range(3) for c in range(40)]
    path = tmp_path / "batch.rrd"
    sink = RerunSink.open(f"save:{path}")
    sink.log_symptoms(records[::-1])   # any order, any number of robots and joints
    sink.close()
    counts = rows_by_entity(path)
    counts.pop("/__properties", None)
    # the batch path draws the density of the newest cycle per joint only (latest-at is what is shown)
    expected = expected_rows(records, per_record_density=False)
    for robot in ("a", "b"):
        for j in range(3):
            expected[f"/robot/{robot}/joint/{j}/density/nominal"] = 1
            expected[f"/robot/{robot}/joint/{j}/density/cycle"] = 1
    assert counts == expected
    from rerun.chunk import RrdReader

    assert len(RrdReader(str(path)).blueprints()) == 1   # one layout for all six joints of the block


def test_values_and_colours_read_back(tmp_path):
    from rerun.chunk import RrdReader

    path = tmp_path / "values.rrd"
    records = [symptom("r1", 0, c) for c in range(10)]
    sink = RerunSink.open(f"save:{path}", )
    sink.log_symptoms(records)
    sink.log_alarm({"schema": 1, "robot": "r1", "joint": 0, "cycle": 9, "quantity": "kl_raw", "state": "cleared",
                    "statistic": 3.0, "threshold": 11.3, "miss_probability": None, "change_cycle": None})
    sink.close()
    values: dict[str, list] = {}
    for chunk in RrdReader(str(path)).stream():
        batch = chunk.to_record_batch()
        for column in ("Scalars:scalars", "Points2D:positions", "Points2D:colors", "TextLog:text"):
            if column in batch.schema.names and not chunk.is_static:
                values.setdefault(f"{chunk.entity_path}:{column}", []).extend(batch.column(column).to_pylist())
    upper = np.array(values["/robot/r1/joint/0/wear/upper:Scalars:scalars"]).ravel()
    assert np.allclose(upper, [r["wear"]["estimate"] + 2 * r["wear"]["std"] for r in records])
    assert values["/robot/r1/joint/0/wear/critical:Scalars:scalars"][0] == [CRITICAL_WEAR]
    positions = values["/robot/r1/joint/0/friction/curve:Points2D:positions"]
    assert len(positions) == len(records) and all(len(p) == 4 for p in positions)
    last = np.array(positions[-1])
    assert np.allclose(last[:, 0], records[-1]["friction"]["speeds"], rtol=1e-6)
    assert np.allclose(-last[:, 1] / FRICTION_SCALE, records[-1]["friction"]["torque"], rtol=1e-6)
    colors = values["/robot/r1/joint/0/friction/curve:Points2D:colors"]
    assert colors[0] != colors[-1] and len(set(colors[0])) == 1   # one colour per cycle, changing with cycle
    (text,) = values["/robot/r1/joint/0/alarms:TextLog:text"]
    assert text[0].startswith("cycle 9: kl_raw alarm cleared")


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
    monkeypatch.delenv("DISPLAY", raising=False)
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
