"""``edge-monitor view`` as a user runs it: a separate process subscribed over Zenoh, saving a recording."""

from __future__ import annotations

import signal
import subprocess
import sys
import time
import warnings
from collections import Counter
from pathlib import Path

import pytest

from edge_monitor import cli
from edge_monitor.sinks.loopback import free_loopback_port as free_port
from edge_monitor.sinks.zenoh_publisher import SymptomPublisher
from edge_monitor.sinks.zenoh_session import ZenohOptions, open_session

from recordings import rows_by_entity

pytestmark = pytest.mark.timeout(90)
START_TIMEOUT_S = 30.0   # process start-up bound (imports rerun + zenoh); not a speed assertion


def symptom(robot: str, joint: int, cycle: int) -> dict:
    return {"schema": 1, "robot": robot, "joint": joint, "cycle": cycle, "t": 20.0 * cycle,
            "friction": {"speeds": [2.0, 50.0, 200.0], "torque": [0.06, 0.04, 0.1], "stderr": [1e-3] * 3},
            "wear": {"estimate": 0.2 * cycle, "std": 1.0, "temperature": 45.0},
            "kl": {"raw": 0.1, "weighted": 0.05},
            "decisions": {"wear": {"state": "monitoring", "statistic": 1.0 + cycle, "threshold": 9.0,
                                   "alarm": cycle > 8, "change_cycle": None, "delta": None,
                                   "miss_probability": 0.3}},
            "alarm": cycle > 8}


def start_view(port: int, rrd: Path, *extra: str) -> subprocess.Popen:
    process = subprocess.Popen(
        [sys.executable, "-m", "edge_monitor.cli", "view", "--zenoh-connect", f"tcp/127.0.0.1:{port}",
         "--rerun", f"save:{rrd}", *extra], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    line = _readline(process, START_TIMEOUT_S)
    assert "subscribed to" in line, (line, process.stderr.read() if process.poll() is not None else "")
    return process


def _readline(process: subprocess.Popen, timeout: float) -> str:
    import selectors

    selector = selectors.DefaultSelector()
    selector.register(process.stdout, selectors.EVENT_READ)
    ready = selector.select(timeout)
    selector.close()
    return process.stdout.readline() if ready else ""


def _partial_rows(path: Path) -> Counter:
    """Rows of a recording still being written (no footer yet); empty when not readable yet."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        try:
            return rows_by_entity(path)
        except Exception:
            return Counter()


def _wait_for_rows(view: subprocess.Popen, rrd: Path, entity: str, rows: int, timeout: float = 30.0) -> None:
    """Until the view has drawn ``rows`` rows of ``entity`` (its backlog query answered, so its subscriber
    is declared at the publisher: Zenoh delivers a link's messages in order)."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline and view.poll() is None:
        if _partial_rows(rrd)[entity] >= rows:
            return
        time.sleep(0.2)


@pytest.fixture
def agent_session():
    port = free_port()
    session = open_session(ZenohOptions(listen=[f"tcp/127.0.0.1:{port}"]))
    yield port, session
    session.close()


@pytest.mark.slow
def test_view_draws_backlog_and_live_records_of_a_fleet(agent_session, tmp_path):
    port, session = agent_session
    rrd = tmp_path / "fleet.rrd"
    backlog, live = 15, 10
    with SymptomPublisher(session, "alpha", joints=[0, 1]) as alpha, \
            SymptomPublisher(session, "beta", joints=[3]) as beta:
        publishers = {"alpha": (alpha, [0, 1]), "beta": (beta, [3])}
        for cycle in range(backlog):                      # before the view exists: recovered from caches
            for publisher, joints in publishers.values():
                for joint in joints:
                    publisher.publish_symptom(symptom(publisher.robot, joint, cycle))
        alpha.publish_alarm({"schema": 1, "robot": "alpha", "joint": 1, "cycle": 9, "quantity": "wear",
                             "state": "raised", "statistic": 10.0, "threshold": 9.0, "miss_probability": 0.3,
                             "change_cycle": 5})
        total = 3 * (backlog + live)
        view = start_view(port, rrd, "--count", str(total), "--duration", "60")
        _wait_for_rows(view, rrd, "/robot/beta/joint/3/wear/estimate", backlog)   # subscription routed
        for cycle in range(backlog, backlog + live):     # while it runs
            for publisher, joints in publishers.values():
                for joint in joints:
                    publisher.publish_symptom(symptom(publisher.robot, joint, cycle))
        out, err = view.communicate(timeout=60)
    assert view.returncode == 0, err
    assert f"{total} symptoms from 2 robot(s) (alpha, beta), 3 joint(s), 1 alarm records" in out
    counts = rows_by_entity(rrd)
    for robot, joint in (("alpha", 0), ("alpha", 1), ("beta", 3)):
        base = f"/robot/{robot}/joint/{joint}"
        assert counts[f"{base}/wear/estimate"] == backlog + live
        assert counts[f"{base}/friction/curve"] == backlog + live
        assert counts[f"{base}/glr/wear/statistic"] == backlog + live
    assert counts["/robot/alpha/joint/1/alarms"] == 1


@pytest.mark.slow
def test_view_filters_one_robot_and_stops_on_sigint(agent_session, tmp_path):
    port, session = agent_session
    rrd = tmp_path / "one.rrd"
    with SymptomPublisher(session, "alpha", joints=[0]) as alpha, \
            SymptomPublisher(session, "beta", joints=[0]) as beta:
        for cycle in range(5):
            alpha.publish_symptom(symptom("alpha", 0, cycle))
            beta.publish_symptom(symptom("beta", 0, cycle))
        view = start_view(port, rrd, "--robot", "beta", "--duration", "60")
        _wait_for_rows(view, rrd, "/robot/beta/joint/0/wear/estimate", 5)
        view.send_signal(signal.SIGINT)
        out, err = view.communicate(timeout=30)
    assert view.returncode == 0, err
    assert "5 symptoms from 1 robot(s) (beta)" in out
    counts = rows_by_entity(rrd)
    assert counts["/robot/beta/joint/0/wear/estimate"] == 5
    assert not any(path.startswith("/robot/alpha") for path in counts)


def test_view_rejects_bad_endpoint_and_sink(tmp_path, capsys):
    assert cli.main(["view", "--zenoh-connect", "127.0.0.1:7447", "--rerun", f"save:{tmp_path}/x.rrd"]) == 2
    assert "--zenoh-connect" in capsys.readouterr().err
    assert cli.main(["view", "--rerun", "window"]) == 2
    assert "use off, save:PATH" in capsys.readouterr().err


def test_view_stops_after_duration_with_nothing_published(tmp_path, capsys):
    rrd = tmp_path / "empty.rrd"
    assert cli.main(["view", "--rerun", f"save:{rrd}", "--duration", "0.3"]) == 0
    assert "0 symptoms from 0 robot(s)" in capsys.readouterr().out
    assert rrd.exists()
