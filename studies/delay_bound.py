"""Detection delay against its bound (docs/DETECTION.md, "Detection delay against the bound").

For a change from a known healthy density f₀ to a known worn one f₁ of a per-cycle quantity, CUSUM is
optimal (Lorden): no test with the same run length to false alarm finds the change sooner. Here f₀ and f₁ are
known as no agent can know them: each robot is simulated twice with the same seed, once healthy and once with
wear on four of its joints, so per joint and cycle the healthy course of its three detector inputs (wear score,
log kl_raw, log kl_weighted) — their temperature and load drift included — and the effect of the wear on them
are both known:

* f₀ at cycle k: N(μ₀(k), Σ₀), μ₀ the healthy run's values smoothed over ±:data:`HEALTHY_HALF_WIDTH` cycles, Σ₀
  the covariance of what is left around it;
* f₁ at cycle k: N(μ₀(k) + Δ(k), Σ₀), Δ the worn run less the healthy one, smoothed over ±:data:`WEAR_HALF_WIDTH`;
* the oracle CUSUM Sₖ = max(0, Sₖ₋₁ + log f₁(xₖ)/f₀(xₖ)) on the worn run's values xₖ, alarming at log ARL0
  (Lorden: its run length to a false alarm is then at least ARL0, the agent's target).

The agent is its own detectors (:func:`studies.bank_replay.replay_bank`) on the worn run. Ramps on joints 0–3:
slow (0 → 50 over 600 cycles), medium (150), fast (40) and a step to 20, starting in one of four situations:
in the warm-up (cycle 300), in the steady stage (cycle 1100), right after an overnight stop (16 h before cycle
1100) and right after a load change (0.3–0.7 → 0.5–0.9 at cycle 1100). Joints 4 and 5 stay healthy.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from scipy.ndimage import uniform_filter1d

from edge_monitor.pipeline.decision_config import DecisionConfig
from studies.bank_replay import new_bank, replay_bank
from studies.series import CACHE, Series, robot_series

#: Half-width [cycles] of the smoothing of the healthy course, and of the wear's effect.
HEALTHY_HALF_WIDTH = 15
WEAR_HALF_WIDTH = 5
#: The wear on joints 0–3: name, cycles the ramp takes (0: a step), the wear it reaches.
RAMPS = (("slow", 600, 50.0), ("medium", 150, 50.0), ("fast", 40, 50.0), ("step", 0, 20.0))
#: Where the wear starts [cycle] and what happens there.
SITUATIONS: dict[str, tuple[int, str]] = {
    "warm-up": (300, ""),
    "steady": (1100, ""),
    "after a stop": (1100, "[[timeline]]\ncycle = 1100\nstop_hours = 16.0\n"),
    "after a load change": (1100, "[[timeline]]\ncycle = 1100\nload_range = [0.5, 0.9]\n"),
}
INPUTS = ("wear_score", "kl_raw", "kl_weighted")


@dataclass(frozen=True)
class Delay:
    """One worn joint in one situation: cycles from the wear's start to the first alarm, and the true wear then,
    of the agent and of the oracle CUSUM (None: no alarm within the run)."""

    situation: str
    ramp: str
    joint: int
    agent: int | None
    agent_wear: float | None
    agent_quantity: str | None
    oracle: int | None
    oracle_wear: float | None


def scenario(situation: str, worn: bool) -> Path:
    """The scenario file of ``situation``, with the wear (``worn``) or without; written once under the cache."""
    start, events = SITUATIONS[situation]
    lines = ["[simulation]", "joints = 6", f"cycles = {start + 650}", "load_range = [0.3, 0.7]", "", events]
    if worn:
        for joint, (_, length, top) in enumerate(RAMPS):
            event = (f'{{ kind = "step", start = {start}, to = {top} }}' if length == 0 else
                     f'{{ kind = "ramp", start = {start}, end = {start + length}, from = 0, to = {top} }}')
            lines += ["[[joint]]", f"index = {joint}", f"wear = [ {event} ]", ""]
    name = f"delay-{situation.replace(' ', '_')}-{'worn' if worn else 'healthy'}.toml"
    path = CACHE.parent / "delay_bound" / name
    path.parent.mkdir(parents=True, exist_ok=True)
    text = "\n".join(lines)
    if not path.exists() or path.read_text() != text:
        path.write_text(text)
    return path


def inputs(rows: list[dict[str, Any]]) -> tuple[np.ndarray, np.ndarray]:
    """(cycles, values N × 3) of a joint's rows, the KL distances as logs."""
    cycles = np.array([int(r["cycle"]) for r in rows])
    values = np.array([[r["wear_score"], math.log(r["kl_raw"]), math.log(r["kl_weighted"])] for r in rows])
    return cycles, values


def oracle_alarm(healthy: list[dict[str, Any]], worn: list[dict[str, Any]], start: int, arl0: float) -> int | None:
    """The first cycle at or after ``start`` − 100 at which the oracle CUSUM reaches log ``arl0`` (see the module
    docstring), or None."""
    hc, h = inputs(healthy)
    wc, x = inputs(worn)
    common = np.intersect1d(hc, wc)
    h, x = h[np.isin(hc, common)], x[np.isin(wc, common)]
    mu0 = uniform_filter1d(h, 2 * HEALTHY_HALF_WIDTH + 1, axis=0, mode="nearest")
    around = (common >= start - 300) & (common < start + 650)
    sigma = np.cov((h - mu0)[around], rowvar=False)
    precision = np.linalg.inv(sigma)
    delta = uniform_filter1d(x - h, 2 * WEAR_HALF_WIDTH + 1, axis=0, mode="nearest")
    r0, r1 = x - mu0, x - mu0 - delta
    llr = 0.5 * (np.einsum("ni,ij,nj->n", r0, precision, r0) - np.einsum("ni,ij,nj->n", r1, precision, r1))
    s, h_alarm = 0.0, math.log(arl0)
    for cycle, step in zip(common, llr):
        if cycle < start - 100:
            continue
        s = max(0.0, s + float(step))
        if s >= h_alarm:
            return int(cycle)
    return None


def agent_alarm(worn: list[dict[str, Any]], decision: DecisionConfig, start: int) -> tuple[int, str] | None:
    """The agent's first alarm on the worn joint's rows at or after ``start`` (cycle, quantity), or None; one
    before (a false alarm on the still healthy joint) is acknowledged, as an operator would."""
    bank = new_bank(decision)
    for step in replay_bank(bank, worn):
        if step.raised and step.cycle >= start:
            return step.cycle, step.raised[0].quantity
        for alarm in step.raised:
            bank.detectors[alarm.quantity].acknowledge()
    return None


def situation_delays(seed: int, situation: str, decision: DecisionConfig) -> list[Delay]:
    """The delays of the four worn joints of one robot in ``situation``."""
    start, _ = SITUATIONS[situation]
    cycles = start + 650
    healthy: Series = robot_series(seed, cycles, 6, str(scenario(situation, worn=False)))
    worn: Series = robot_series(seed, cycles, 6, str(scenario(situation, worn=True)))
    out = []
    for joint, (ramp, _, _) in enumerate(RAMPS):
        wear = {int(r["cycle"]): float(r["wear"]) for r in worn[joint]}
        agent = agent_alarm(worn[joint], decision, start)
        oracle = oracle_alarm(healthy[joint], worn[joint], start, decision.arl0)
        out.append(Delay(situation, ramp, joint,
                         None if agent is None else agent[0] - start, None if agent is None else wear[agent[0]],
                         None if agent is None else agent[1],
                         None if oracle is None else oracle - start, None if oracle is None else wear[oracle]))
    return out
