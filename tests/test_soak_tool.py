"""tools/soak/soak.py as a user runs it: simulator, agent, Zenoh router and subscriber as separate processes
over the pty slcan link, with every kind of chaos; and its link ledger on synthetic frames."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from synthetic_frames import make_frames

TOOLS = Path(__file__).resolve().parent.parent / "tools" / "soak"
SOAK = TOOLS / "soak.py"
sys.path.insert(0, str(TOOLS))

from soak import CHAOS_KINDS, chaos_plan  # noqa: E402
from soak_link import LinkLedger, PtyLinkTap  # noqa: E402

LINE = 22     # bytes of one slcan frame line


@pytest.mark.slow
@pytest.mark.timeout(1200)
def test_a_60_s_soak_with_every_kind_of_chaos_accounts_for_every_frame_and_cycle():
    proc = subprocess.run([sys.executable, str(SOAK), "--duration", "60", "--json", "--seed", "3"],
                          capture_output=True, text=True, timeout=1100)
    report = json.loads(proc.stdout)
    context = proc.stdout + proc.stderr[-3000:]
    assert proc.returncode == 0 and report["ok"], context
    assert report["frames_unaccounted"] == 0 and report["cycles_lost"] == 0, context
    assert report["symptoms_received"] == report["symptoms_expected"] > 0, context
    assert report["symptoms_unexpected"] == 0 and report["symptoms_expected_marked_partial"] == 0, context
    assert all(report["restarts"][kind] >= 1 for kind in CHAOS_KINDS), report["restarts"]
    assert report["frames_received"] > 0 and report["frames_during_downtime"] > 0, context
    # every injected fault is either counted by the agent or fell where no agent could see it
    assert report["faults_by_kind"]["corrupted"] > 0 and report["faults_by_kind"]["dropped"] > 0
    assert report["faults_on_link"] == report["faults_injected"], context
    assert report["faults_detected"] == report["faults_detectable"] <= report["faults_injected"], context
    assert set(report) >= {"link", "duration_s", "frames_sent", "frames_received", "frames_unaccounted",
                           "faults_injected", "faults_detected", "rss_mb_start", "rss_mb_end",
                           "rss_slope_mb_per_hour", "cpu_percent", "symptoms_expected", "symptoms_received",
                           "restarts", "cycles_lost"}


def test_the_chaos_plan_is_seeded_and_holds_every_kind():
    plan = chaos_plan(60.0, 60.0, seed=3)
    assert sorted(kind for _, kind in plan) == sorted(CHAOS_KINDS)
    assert plan == chaos_plan(60.0, 60.0, seed=3) != chaos_plan(60.0, 60.0, seed=4)
    assert all(6.0 <= t <= 51.0 for t, _ in plan) and [t for t, _ in plan] == sorted(t for t, _ in plan)
    assert len(chaos_plan(1800.0, 120.0, seed=1)) == 15


def _lines(ids: np.ndarray, data: np.ndarray) -> bytes:
    return b"".join(b"t%03X8%s\r" % (int(i), bytes(d).hex().upper().encode()) for i, d in zip(ids, data))


def test_the_ledger_splits_a_kill_into_read_unread_and_downtime_frames_and_finds_whole_cycles():
    ids, data, _, _ = make_frames(6, joints=(0,), speeds=(8.7, 41.7, 133.5), seed=2)
    data = data.copy()
    data[10, 3] ^= 0x10                                   # one corrupted frame, read by the first life
    status = np.flatnonzero(ids == 0x080)
    cycle = (data[status].view("<u8").reshape(-1) >> np.uint64(16)) & np.uint64(0xFFFF)
    first = {int(c): int(status[np.argmax(cycle == c)]) for c in np.unique(cycle)}
    killed, resumed = first[2] + 100, (first[2] + first[3]) // 2
    ledger = LinkLedger()
    tap = PtyLinkTap("/dev/pts/x", ledger, window=1 << 20)
    tap.announce("agent_started")
    tap.announce("sim_started")
    tap.queued("/dev/pts/x", _lines(ids[:killed + 50], data[:killed + 50]))
    tap.undelivered("/dev/pts/x", LINE * killed, LINE * (killed + 50))     # unread when it died
    tap.closed("/dev/pts/x")
    tap.lost("/dev/pts/x", _lines(ids[killed + 50:resumed], data[killed + 50:resumed]), "closed")
    tap.announce("agent_started")
    tap.queued("/dev/pts/x", _lines(ids[resumed:], data[resumed:]))
    tap.pump()
    life0, life1 = ledger.lives
    assert (life0.read, life0.unread, life1.read) == (killed, 50, len(ids) - resumed)
    assert ledger.frames_downtime == resumed - killed - 50 and ledger.runs[0].frames == len(ids)
    assert life0.faults_in_first(killed) == 1 == ledger.runs[0].faults and life0.faults_in_first(10) == 0
    # life 0 saw cycles 0 and 1 whole; life 1 joined in cycle 2, saw 3 and 4 whole (5 never ended)
    assert set(ledger.complete_cycles([life0.read, life1.read])) == {(0, 0), (0, 1), (0, 3), (0, 4)}
    # had life 0 reported only the frames before cycle 2 began, cycle 1's close was not yet processed
    assert (0, 1) not in ledger.complete_cycles([first[2], life1.read])
    assert ledger.numbering() == {0: 0}


def test_the_pump_hands_over_only_what_was_queued_when_it_began():
    """The bridge thread queues while the soak's loop pumps; a pump that drained until the queue was
    empty kept the loop (and the RSS samples it took) away for an hour on a loaded machine. Here every
    event handled queues one more, as a bridge faster than the ledger does: the pump still returns."""
    ids, data, _, _ = make_frames(1, joints=(0,), speeds=(8.7, 41.7, 133.5), seed=3)
    chunk = _lines(ids[:10], data[:10])
    ledger = LinkLedger()
    tap = PtyLinkTap("/dev/pts/x", ledger, window=1 << 20)
    tap.announce("agent_started")
    tap.announce("sim_started")
    handled = 0

    def frames(*args, **kwargs):
        nonlocal handled
        handled += 1
        tap.queued("/dev/pts/x", chunk)                   # the bridge queues meanwhile
        return original(*args, **kwargs)

    original, ledger.frames = ledger.frames, frames
    for _ in range(5):
        tap.queued("/dev/pts/x", chunk)
    tap.pump()
    assert handled == 5 and len(tap._events) == 5          # the new ones wait for the next pump
    tap.pump()
    assert handled == 10 and ledger.lives[0].read == 100


@pytest.mark.parametrize("on_link, send_errors, unaccounted", [(100, 0, 0), (101, 0, 1), (101, 1, 0), (101, 3, 0),
                                                               (103, 1, 2), (99, 1, 1)])
def test_a_failed_send_may_explain_an_extra_frame_on_the_link_but_no_more(on_link: int, send_errors: int,
                                                                         unaccounted: int) -> None:
    """A send that raised (serial write timeout) may still have put its frame on the link: up to
    ``send_errors`` extra frames are accounted, never a missing frame and never more than that."""
    from soak_link import SimRun
    from soak_report import SimRecord, frame_report

    ledger = LinkLedger()
    ledger.runs.append(SimRun(0, frames=on_link))
    report = frame_report(ledger, [], [SimRecord(0, frames_sent=100, send_errors=send_errors, complete=True)])
    assert report["frames_unaccounted_by_rule"]["sent_vs_link"] == unaccounted, report
    assert report["send_errors_on_link"] == min(max(on_link - 100, 0), send_errors)
