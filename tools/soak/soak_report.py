"""Reconciliation of a soak (tools/soak/soak.py): frames, faults, symptoms and resources, with the rules
of docs/RELIABILITY.md ("A real soak")."""

from __future__ import annotations

import json
import logging
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from soak_link import Key, LinkLedger

log = logging.getLogger("soak.report")

#: Largest |symptom t − truth t_end| of a cycle mapped right: the agent's cycle runs from one status
#: frame (every 10 ticks) to the next cycle's, and link faults may drop its last frames [s].
TIME_TOLERANCE_S = 0.2


@dataclass
class Sample:
    t: float            # wall time, s
    rss_mb: float       # resident set of the agent's main process
    cpu_s: float        # CPU time of the agent's process group (with its calibration worker)


@dataclass
class LifeRecord:
    """One agent process: how it ended and what it reported."""

    index: int
    pid: int
    started: float
    ended: float | None = None
    killed: bool = False
    counters: dict[str, Any] = field(default_factory=dict)    # last health record, or the final summary
    samples: list[Sample] = field(default_factory=list)

    def get(self, key: str) -> int:
        return int(self.counters.get(key) or 0)

    @property
    def accounted(self) -> int:
        """Frames it reported: processed, dropped from its queue, discarded unprocessed at its stop."""
        return self.get("frames_total") + self.get("queue_dropped") + self.get("discarded_at_stop")


@dataclass
class SimRecord:
    """One simulator process: its truth summary and per-(joint, cycle) end times."""

    index: int
    frames_sent: int = 0
    send_errors: int = 0            # sends that raised (the frame may have reached the link anyway)
    faults: dict[str, int] = field(default_factory=dict)
    t_end: dict[tuple[int, int], float] = field(default_factory=dict)
    complete: bool = False          # its summary line was written (stopped in order)

    @classmethod
    def from_truth(cls, index: int, path: Path) -> SimRecord:
        rec = cls(index)
        if not path.exists():
            return rec
        for line in path.read_text(encoding="utf-8").splitlines():
            row = json.loads(line)
            if "frames_sent" in row:
                rec.frames_sent, rec.faults, rec.complete = int(row["frames_sent"]), row["faults"], True
                rec.send_errors = int(row.get("send_errors", 0))
            elif "cycle" in row:
                rec.t_end[(int(row["joint"]), int(row["cycle"]))] = float(row["t_end"])
        return rec


def frame_report(ledger: LinkLedger, lives: list[LifeRecord], sims: list[SimRecord]) -> dict[str, Any]:
    """Frames sent, received and where the others went; ``frames_unaccounted`` sums every violation."""
    sent = sum(s.frames_sent for s in sims)
    on_link = sum(r.frames for r in ledger.runs)
    # a send that raised (serial write timeout) may still have put its frame on the link: accounted
    failed_on_link = sum(min(max(r.frames - s.frames_sent, 0), s.send_errors) for s, r in zip(sims, ledger.runs))
    lost_in_kill = overcounted = final_residual = 0
    for life, rec in zip(ledger.lives, lives):
        residual = life.read + life.unread - rec.accounted
        if rec.killed:
            lost_in_kill += max(residual, 0)
            overcounted += max(-residual, 0)
        else:
            final_residual += abs(residual)
    violations = {"sent_vs_link": abs(sent + failed_on_link - on_link), "link_overflow": ledger.frames_overflow,
                  "unattributed": ledger.frames_unattributed, "lost_midlife": ledger.undelivered_midlife,
                  "stopped_agent_residual": final_residual, "killed_agent_overcount": overcounted}
    return {"frames_sent": sent, "frames_received": sum(r.get("frames_total") for r in lives),
            "frames_unaccounted": sum(violations.values()), "frames_during_downtime": ledger.frames_downtime,
            "frames_lost_in_kill": lost_in_kill, "frames_on_link": on_link,
            "send_errors": sum(s.send_errors for s in sims), "send_errors_on_link": failed_on_link,
            "frames_queue_dropped": sum(r.get("queue_dropped") for r in lives),
            "frames_by_simulator_run": [[s.frames_sent, r.frames] for s, r in zip(sims, ledger.runs)],
            "frames_by_agent_life": [{"read": life.read, "unread": life.unread, "reported": rec.accounted,
                                      "killed": rec.killed} for life, rec in zip(ledger.lives, lives)],
            "frames_unaccounted_by_rule": violations}


def fault_report(ledger: LinkLedger, lives: list[LifeRecord], sims: list[SimRecord]) -> dict[str, Any]:
    """Injected faults (CRC-visible corruption + duplicates), what a perfect receiver saw on the link,
    what the agent lives counted and what they must have counted after the frames they processed."""
    totals: dict[str, int] = {}
    for s in sims:
        for k, v in s.faults.items():
            totals[k] = totals.get(k, 0) + int(v)
    expected = sum(life.faults_in_first(rec.get("frames_total")) for life, rec in zip(ledger.lives, lives))
    return {"faults_injected": totals.get("corrupted", 0) + totals.get("duplicated", 0),
            "faults_detected": sum(r.get("crc_errors") + r.get("repeated") for r in lives),
            "faults_detectable": expected, "faults_on_link": sum(r.faults for r in ledger.runs),
            "faults_by_kind": totals}


def read_symptom_lines(path: Path, robot: str) -> tuple[dict[tuple[int, int], dict], int, int | None]:
    """(first record per (joint, cycle), number of records, misses) of a JSONL file of symptoms."""
    first: dict[tuple[int, int], dict] = {}
    count, misses = 0, None
    if not path.exists():
        return first, count, misses
    for line in path.read_text(encoding="utf-8").splitlines():
        try:
            row = json.loads(line)
        except ValueError:
            continue
        if "misses" in row:
            misses = row["misses"]
        elif row.get("robot") == robot and "kind" not in row:
            count += 1
            first.setdefault((int(row["joint"]), int(row["cycle"])), row)
    return first, count, misses


def symptom_report(ledger: LinkLedger, lives: list[LifeRecord], sims: list[SimRecord], joints: int,
                   jsonl: Path, received: Path, robot: str) -> dict[str, Any]:
    """Expected symptoms against the JSONL file and the independent subscriber."""
    complete = ledger.complete_cycles([rec.get("frames_total") for rec in lives])
    offsets = ledger.numbering()
    boundary = ledger.cycles_touched() - set(complete)
    expected, unmapped = _agent_keys(complete, offsets, joints)
    edge, _ = _agent_keys(boundary, offsets, joints)
    in_file, _, _ = read_symptom_lines(jsonl, robot)
    got, lines, misses = read_symptom_lines(received, robot)
    origin = {(j, raw + offsets[run]): (run, raw) for run, raw in complete if run in offsets for j in range(joints)}
    return {"symptoms_expected": len(expected), "symptoms_received": len(expected & set(got)),
            "symptoms_duplicates": lines - len(got), "symptoms_boundary_received": len(set(got) & (edge - expected)),
            "symptoms_unexpected": len(set(got) - expected - edge),
            "symptoms_expected_marked_partial": sum(1 for k in expected if got.get(k, {}).get("partial")),
            "symptoms_unmapped": unmapped, "symptoms_zenoh_misses": misses,
            "jsonl_missing": len(expected - set(in_file)),
            "cycles_lost": len(expected - set(in_file) - set(got)),
            "cycle_time_mismatches": _time_mismatches(in_file, origin, sims)}


def _agent_keys(cycles: Any, offsets: dict[int, int], joints: int) -> tuple[set[tuple[int, int]], int]:
    """(joint, agent cycle number) of (run, raw cycle) keys; and how many keys had no known offset."""
    out: set[tuple[int, int]] = set()
    unmapped = 0
    for run, raw in cycles:
        if raw < 0:
            continue
        if run not in offsets:
            unmapped += 1
            continue
        out.update((j, raw + offsets[run]) for j in range(joints))
    return out, unmapped


def _time_mismatches(records: dict[tuple[int, int], dict], origin: dict[tuple[int, int], Key],
                     sims: list[SimRecord]) -> int:
    """Expected cycles whose symptom time does not match the simulator's end of that cycle (a wrong
    cycle mapping would show here)."""
    bad = 0
    for key, rec in records.items():
        if key not in origin or rec.get("t") is None:
            continue
        run, raw = origin[key]
        t_end = sims[run].t_end.get((key[0], raw)) if run < len(sims) else None
        if t_end is None or abs(float(rec["t"]) - t_end) > TIME_TOLERANCE_S:
            bad += 1
    return bad


def resource_report(lives: list[LifeRecord], wall_s: float, warmup_s: float,
                    last_s: float = 3600.0) -> dict[str, Any]:
    """RSS at start and end, its slope (least squares within each agent life after ``warmup_s``, lives
    pooled: restarts do not count as growth) over the whole run and over its last ``last_s`` seconds
    (when the run is at least twice that long: the caches have filled by then), CPU of the agent's
    process groups over the wall time."""
    kept = [[s for s in life.samples if s.t - life.started >= warmup_s] for life in lives]
    flat = [s for group in kept for s in group]
    every = [s for life in lives for s in life.samples]
    cpu = sum(life.samples[-1].cpu_s for life in lives if life.samples)
    slope = _pooled_slope(kept)
    out = {"rss_mb_start": round((flat or every)[0].rss_mb, 1) if every else None,
           "rss_mb_end": round(every[-1].rss_mb, 1) if every else None,
           "rss_slope_mb_per_hour": None if slope is None else round(slope * 3600.0, 2),
           "cpu_percent": round(100.0 * cpu / wall_s, 1) if wall_s > 0 else None,
           "resource_samples": len(every)}
    if every and every[-1].t - every[0].t >= 2 * last_s:
        since = every[-1].t - last_s
        late = _pooled_slope([[s for s in group if s.t >= since] for group in kept])
        out["rss_slope_last_s"] = last_s
        out["rss_slope_last_mb_per_hour"] = None if late is None else round(late * 3600.0, 2)
        out["rss_mb_last_start"] = round(min((s for s in flat if s.t >= since), key=lambda s: s.t).rss_mb, 1)
    return out


def write_samples(lives: list[LifeRecord], path: Path) -> None:
    """The RSS/CPU samples as CSV: wall time, seconds since the first sample, agent life, RSS [MB], CPU [s]."""
    every = [(life.index, s) for life in lives for s in life.samples]
    t0 = every[0][1].t if every else 0.0
    rows = ["t,elapsed_s,life,rss_mb,cpu_s"] + [f"{s.t:.3f},{s.t - t0:.1f},{i},{s.rss_mb:.2f},{s.cpu_s:.2f}"
                                                 for i, s in every]
    path.write_text("\n".join(rows) + "\n", encoding="utf-8")


def _pooled_slope(groups: list[list[Sample]]) -> float | None:
    """Least-squares slope of rss over t with one intercept per group [MB/s]; None with < 3 samples."""
    sxy = sxx = 0.0
    n = 0
    for group in groups:
        if len(group) < 2:
            continue
        mt = sum(s.t for s in group) / len(group)
        mr = sum(s.rss_mb for s in group) / len(group)
        sxy += sum((s.t - mt) * (s.rss_mb - mr) for s in group)
        sxx += sum((s.t - mt) ** 2 for s in group)
        n += len(group)
    return sxy / sxx if n >= 3 and sxx > 0 else None
