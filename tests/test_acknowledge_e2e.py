"""Acknowledging an alarm across processes: frames over a pty slcan link → `edge-monitor run` (its own
process) raises a wear alarm → `edge-monitor acknowledge` (another process) over Zenoh → the agent's
"acknowledged" record, later symptoms with the statistic restarted, a new alarm on a new fault; puts
the agent's gate refuses (wildcard key, bad payload) are counted in its health.

The frames are made cycle by cycle and sent only when the test needs the next one (each cycle is
closed by the first frame of the next), so every phase waits for what the agent reports, never for
wall-clock time."""

from __future__ import annotations

import json
import re
import signal
import subprocess
import sys
from pathlib import Path

import pytest
from test_run_e2e import CONFIG as RUN_CONFIG
from test_run_e2e import send_frames

from edge_monitor.sinks.loopback import free_loopback_port as free_port
from edge_monitor.sinks.zenoh_publisher import SymptomSubscriber
from edge_monitor.sinks.zenoh_session import ZenohOptions, open_session
from protocol.links import PtyPair

from synthetic_frames import cycle_profile, make_frames
from waiting import wait_until

pytestmark = pytest.mark.slow

SPEEDS = (8.7, 41.7, 133.5)
TICKS = cycle_profile(SPEEDS)[0].size
#: test_run_e2e's agent, plus: small calibrations, no joint-model learning, no steady relearning (the
#: detectors decide from the 4th cycle on and keep their nominal), status every 0.5 s; the
#: asymptotic threshold (a calibration from 3 values honestly says the one for 10⁴ is far higher).
CONFIG = RUN_CONFIG.replace("status_interval_s = 1.0", "status_interval_s = 0.5") + """\
pf = 1e-3
calibration_draws = 16
calibration_steps = 400
steady_relearn = false
[alarms]
chatter_cycles = 2
[model]
enabled = false
"""
WORN = 60.0            # wear of the faulty gearbox (healthy: 0); the wear score jumps far beyond 3σ
WAIT_S = 60.0          # bound for what the agent reports; never a speed assertion


class Robot:
    """Sends synthetic cycles of joint 0 one at a time and follows the agent's records over Zenoh."""

    def __init__(self, link: str, subscriber: SymptomSubscriber) -> None:
        self.link, self.sub, self.cycle = link, subscriber, 0

    def run_cycle(self, wear: float) -> dict:
        """Send the next cycle (it closes the previous one); the previous cycle's symptom record."""
        send_frames(self.link, make_frames(1, joints=(0,), speeds=SPEEDS, wear=lambda j, c: wear, seed=100 + self.cycle,
                                           first_cycle=self.cycle, first_tick=self.cycle * TICKS))
        self.cycle += 1
        closed = self.cycle - 2
        if closed < 0:
            return {}
        assert wait_until(lambda: self.symptom(closed) is not None, WAIT_S), f"no symptom of cycle {closed}"
        return self.symptom(closed)

    def symptom(self, cycle: int) -> dict | None:
        return next((r for r in self.sub.records("symptom") if r["joint"] == 0 and r["cycle"] == cycle), None)

    def alarms(self, state: str) -> list[dict]:
        """The alarm records in ``state`` whose fault the wear detector is part of."""
        return [r for r in self.sub.records("alarm")
                if "wear" in [d["quantity"] for d in r["detectors"]] and r["state"] == state]

    def until(self, wear: float, done, cycles: int) -> dict:
        """Run cycles at ``wear`` until ``done(symptom)``; at most ``cycles`` of them."""
        for _ in range(cycles):
            record = self.run_cycle(wear)
            if record and done(record):
                return record
        raise AssertionError(f"not reached within {cycles} cycles; last symptom {record}")


def acknowledge_cli(endpoint: str, *extra: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "edge_monitor.cli", "acknowledge", "--robot", "cell7", "--joint", "0",
                           "--zenoh-connect", endpoint, "--timeout", str(WAIT_S), *extra],
                          capture_output=True, text=True, timeout=2 * WAIT_S)


def test_an_alarm_acknowledged_from_the_cli_restarts_the_statistic_and_a_new_fault_alarms_again(tmp_path: Path):
    cfg = tmp_path / "agent.toml"
    cfg.write_text(CONFIG)
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    state_dir = tmp_path / "state"
    with PtyPair() as pair:
        agent = subprocess.Popen(
            [sys.executable, "-m", "edge_monitor.cli", "run", "--link", f"slcan:{pair.b}", "--config", str(cfg),
             "--zenoh-listen", endpoint, "--state-dir", str(state_dir), "--allow-remote-acknowledge"],
            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        session = open_session(ZenohOptions(mode="peer", connect=[endpoint]))
        sub = SymptomSubscriber(session, "edge/cell7/**", history=True)
        try:
            assert wait_until(lambda: sub.agents, WAIT_S), "agent liveliness token not seen"
            robot = Robot(f"slcan:{pair.a}", sub)
            wear = lambda r: r["decisions"]["wear"]  # noqa: E731
            robot.until(0.0, lambda r: wear(r)["threshold"] is not None, 30)         # learned and calibrated
            raised = robot.until(WORN, lambda r: wear(r)["alarm"], 20)
            assert wait_until(lambda: len(robot.alarms("raised")) == 1, WAIT_S)
            healthy = robot.until(0.0, lambda r: True, 2)
            assert wear(healthy)["alarm"], "the alarm stays latched on healthy data until acknowledged"
            # puts the agent's gate refuses: counted in its health, nothing acknowledged
            session.put("edge/*/0/acknowledge", b"{}")
            session.put("edge/cell7/0/acknowledge", b'{"quantities": ["gearbox"]}')
            assert wait_until(lambda: any(h.get("acknowledge_refused_bad_key") == 1
                                          and h.get("acknowledge_refused_bad_payload") == 1
                                          for h in sub.records("health")), WAIT_S)
            assert robot.alarms("acknowledged") == []
            done = acknowledge_cli(endpoint, "--quantity", "wear", "--by", "alice", "--note", "probe knocked the arm")
            assert done.returncode == 0, done.stdout + done.stderr
            assert "wear alarm acknowledged" in done.stdout and "by alice" in done.stdout
            assert wait_until(lambda: robot.alarms("acknowledged"), WAIT_S)
            (event,) = robot.alarms("acknowledged")
            assert (event["by"], event["note"]) == ("alice", "probe knocked the arm")
            [evidence] = event["detectors"]
            assert evidence["quantity"] == "wear" and evidence["threshold"] == wear(raised)["threshold"]
            first_after = robot.cycle - 1                    # the open cycle: the first one after the restart
            quiet = [robot.run_cycle(0.0) for _ in range(3)][1:]   # [0] is the cycle acknowledged in
            for record in quiet:
                decision = wear(record)
                assert not decision["alarm"] and decision["threshold"] == wear(raised)["threshold"]
                assert decision["statistic"] < decision["threshold"]
                assert decision["change_cycle"] >= first_after     # the statistic restarted after the acknowledgement
            again = robot.until(WORN, lambda r: wear(r)["alarm"], 20)
            # more than chatter_cycles after the acknowledgement: a new fault, a new record
            assert wait_until(lambda: len(robot.alarms("raised")) == 2, WAIT_S)
            assert len({r["fault"] for r in robot.alarms("raised")}) == 2
            assert again["cycle"] > first_after
            assert wait_until(lambda: any(h.get("acknowledge_accepted") == 1 and h.get("alarms_acknowledged") == 1
                                          for h in sub.records("health")), WAIT_S)
            everything = acknowledge_cli(endpoint)                  # every latched quantity of the joint
            assert everything.returncode == 0 and re.search(r"wear\b.* alarms? acknowledged", everything.stdout), \
                everything.stdout + everything.stderr
            nothing = acknowledge_cli(endpoint)
            assert nothing.returncode == 0 and "nothing to acknowledge" in nothing.stdout, nothing.stderr
            agent.send_signal(signal.SIGTERM)
            out, _ = agent.communicate(timeout=WAIT_S)
        finally:
            if agent.poll() is None:
                agent.kill()
            sub.close()
            session.close()
    assert agent.returncode == 0, out
    assert "wear alarm ACKNOWLEDGED" in out and "acknowledgement refused" in out
    saved = json.loads((state_dir / "agent_state.json").read_text())["joints"]["0"]      # what a restart loads
    assert saved["acknowledgements"] >= 2 and all(saved["detectors"][q]["latched"] is None
                                                  for q in ("wear", "kl_raw", "kl_weighted"))
