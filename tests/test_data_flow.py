"""A service that says when data stops (issue 50): `edge-monitor run` as systemd runs it (a NOTIFY_SOCKET
datagram socket of the test, WATCHDOG_USEC) with frames over a pty slcan link. While frames come: READY=1,
WATCHDOG=1 pings, health records say data_flowing with per-joint sample counts, and the container's health
check (`listen --require-data-flowing`) passes. Once no frame came for data_timeout_s: the pings stop (so
systemd's WatchdogSec restarts the agent), the status says NO DATA, health says data_flowing false and
the health check fails with exit code 1."""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import jsonschema
import pytest
from test_run_e2e import send_frames

from edge_monitor.pipeline.data_flow import DataFlow
from edge_monitor.pipeline.service_notify import ServiceNotifier
from edge_monitor.schemas import load_schema
from edge_monitor.sinks.loopback import free_loopback_port
from edge_monitor.sources.samples import CycleRun, IngestBlock, JointSamples
from protocol.links import PtyPair

from synthetic_frames import make_frames
from waiting import wait_until

TIMEOUT_S = 2.0          # data_timeout_s of the agent under test
WATCHDOG_S = 1.0         # WatchdogSec: the agent pings every 0.5 s while data flows


class NotifySocket:
    """The test's side of NOTIFY_SOCKET: every datagram with its arrival time."""

    def __init__(self, path: Path) -> None:
        self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        self.sock.bind(str(path))
        self.sock.settimeout(0.2)
        self.messages: list[tuple[float, str]] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._read, daemon=True)
        self._thread.start()

    def _read(self) -> None:
        while not self._stop.is_set():
            try:
                self.messages.append((time.monotonic(), self.sock.recv(4096).decode()))
            except TimeoutError:
                continue

    def pings(self, since: float = 0.0) -> list[float]:
        return [t for t, m in list(self.messages) if t >= since and "WATCHDOG=1" in m.split("\n")]

    def said(self, text: str) -> bool:
        return any(text in m for _, m in list(self.messages))

    def close(self) -> None:
        self._stop.set()
        self._thread.join(5)
        self.sock.close()


def _health_check(endpoint: str) -> subprocess.CompletedProcess:
    """The container's HEALTHCHECK command against the agent's endpoint."""
    return subprocess.run([sys.executable, "-m", "edge_monitor.cli", "-q", "listen", "--zenoh-connect", endpoint,
                           "--kind", "health", "--count", "1", "--duration", "20", "--no-history",
                           "--require-data-flowing"], capture_output=True, text=True, timeout=60)


@pytest.mark.slow
def test_watchdog_and_health_check_follow_the_data(tmp_path):
    cfg = tmp_path / "agent.toml"
    cfg.write_text(f"robot = \"cell3\"\nstatus_interval_s = 0.5\ndata_timeout_s = {TIMEOUT_S}\n")
    endpoint = f"tcp/127.0.0.1:{free_loopback_port()}"
    notify = NotifySocket(tmp_path / "notify")
    env = {**os.environ, "NOTIFY_SOCKET": str(tmp_path / "notify"), "WATCHDOG_USEC": str(int(WATCHDOG_S * 1e6))}
    frames = make_frames(3, joints=(0, 1), seed=3)
    with PtyPair() as pair:
        agent = subprocess.Popen([sys.executable, "-m", "edge_monitor.cli", "run", "--link", f"slcan:{pair.b}",
                                  "--config", str(cfg), "--zenoh-listen", endpoint, "--jsonl",
                                  str(tmp_path / "s.jsonl")], env=env, stderr=subprocess.PIPE, text=True)
        try:
            assert wait_until(lambda: notify.said("READY=1"), 60), agent.stderr
            sender = threading.Thread(target=send_frames, args=(f"slcan:{pair.a}", frames, 4000.0))
            sender.start()
            assert wait_until(lambda: len(notify.pings()) >= 3, 30)
            flowing = _health_check(endpoint)
            assert flowing.returncode == 0, flowing.stderr
            record = json.loads(flowing.stdout)
            jsonschema.validate(record, load_schema("health"))
            assert record["data_flowing"] is True and record["data_flow"]["frames"] > 0
            assert set(record["data_flow"]["samples"]) == {"0", "1"}
            sender.join()
            stopped = time.monotonic()
            # no frame since `stopped`: after data_timeout_s no more pings, whatever the load on this machine
            assert wait_until(lambda: notify.said("STATUS=NO DATA"), 30)
            quiet_from = time.monotonic()
            time.sleep(3 * WATCHDOG_S)
            assert notify.pings(since=quiet_from) == []
            assert notify.pings(since=stopped + TIMEOUT_S + WATCHDOG_S) == []
            dead = _health_check(endpoint)
            assert dead.returncode == 1 and "no data flowing at cell3" in dead.stderr, dead.stderr
            assert json.loads(dead.stdout)["data_flowing"] is False
            agent.send_signal(signal.SIGTERM)
            assert agent.wait(60) == 0
            assert notify.said("STOPPING=1")
            assert "no data: no sample for more than 2 s" in agent.stderr.read()
        finally:
            if agent.poll() is None:
                agent.kill()
                agent.wait()
            notify.close()


def _block(joint_samples: dict[int, int]) -> IngestBlock:
    import numpy as np
    samples = {j: JointSamples(np.arange(n), np.zeros(n), np.zeros(n), np.ones(n, dtype=np.int64))
               for j, n in joint_samples.items()}
    return IngestBlock([CycleRun(cycle=0, samples=samples, joint_status={})])


def test_data_flow_counts_per_interval_and_times_out():
    flow = DataFlow(timeout_s=10.0, started=100.0)
    assert flow.flowing(109.0)                          # the first timeout_s after the start: waiting
    assert not flow.flowing(111.0)                      # nothing came
    flow.add(111.0, 40, _block({0: 12, 2: 5}))
    first = flow.interval(112.0)
    assert first["data_flowing"] and first["data_flow"]["frames"] == 40
    assert first["data_flow"]["samples"] == {"0": 12, "2": 5} and first["data_flow"]["since_sample_s"] == 1.0
    flow.add(113.0, 7, _block({}))                      # frames nothing decodes: no sample
    second = flow.interval(125.0)
    assert second["data_flow"]["frames"] == 7 and second["data_flow"]["samples"] == {"0": 0, "2": 0}
    assert not second["data_flowing"] and second["data_flow"]["since_frame_s"] == 12.0
    assert DataFlow(timeout_s=0.0, started=0.0).flowing(1e9)     # 0: never judged


def test_the_notifier_pings_while_flowing_and_stays_silent_without_systemd(tmp_path):
    notify = NotifySocket(tmp_path / "n")
    try:
        notifier = ServiceNotifier({"NOTIFY_SOCKET": str(tmp_path / "n"), "WATCHDOG_USEC": "2000000"})
        notifier.ready("up")
        for now in (0.0, 0.5, 1.0, 1.5, 2.0):            # twice per WatchdogSec
            notifier.watchdog(now, True, "ok")
        notifier.watchdog(2.5, False, "NO DATA")
        notifier.watchdog(5.0, False, "NO DATA")
        assert wait_until(lambda: len(notify.messages) >= 5, 10)
        messages = [m for _, m in notify.messages]
        assert messages[0].startswith("READY=1") and sum("WATCHDOG=1" in m for m in messages) == 3
        assert messages[-1] == "STATUS=NO DATA"
        abstract = ServiceNotifier({"NOTIFY_SOCKET": "@edge-monitor-test-none", "WATCHDOG_USEC": "1"})
        assert abstract.address.startswith("\0") and not abstract.send("READY=1") and abstract.errors == 1
        silent = ServiceNotifier({})
        assert not silent.enabled and not silent.send("READY=1") and silent.watchdog_s is None
    finally:
        notify.close()
