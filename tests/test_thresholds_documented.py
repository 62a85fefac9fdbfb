"""docs/DETECTION.md's table of thresholds says what the shipped table gives the shipped settings: every number of
every row, read as the agent reads it (so the docs cannot go stale when an entry is recomputed)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from edge_monitor.pipeline.decision_config import DecisionConfig
from edge_monitor.stats.threshold_table import lookup, tabulated_correlation

DOC = Path(__file__).resolve().parents[1] / "docs" / "DETECTION.md"
#: The table's targets: 10⁴, one per robot-week and the default budget [cycles].
TARGETS = (1e4, 50_400.0)
#: Row label → (quantity, stage, without motor temperature).
ROWS = {"wear score, warm-up": ("wear", "warm-up", False),
        "wear score, warm-up, a joint without motor temperature": ("wear", "warm-up", True),
        "kl_raw, warm-up": ("kl_raw", "warm-up", False), "kl_weighted, warm-up": ("kl_weighted", "warm-up", False),
        "joint vector, warm-up": ("joint", "warm-up", False),
        "joint vector, warm-up, a joint without motor temperature": ("joint", "warm-up", True),
        "wear score, steady": ("wear", "steady", False), "kl_raw, steady": ("kl_raw", "steady", False),
        "kl_weighted, steady": ("kl_weighted", "steady", False), "joint vector, steady": ("joint", "steady", False)}


def _documented() -> dict[str, list[list[float]]]:
    """Row label → per column (10⁴, week, default) the numbers before its ± (one per ρ for the joint vector)."""
    text = DOC.read_text(encoding="utf-8")
    table = text[text.index("| detector, stage | ARL0 10⁴"):]
    rows = {}
    for line in table.splitlines()[2:]:
        if not line.startswith("|"):
            break
        cells = [c.strip().strip("*") for c in line.strip("|").split("|")]
        label = re.sub(r" \(.*?\)", "", cells[0]).replace("`warm_up_law_friction`", "").strip(" ,")
        rows[label] = [[float(x) for x in cell.split("±")[0].split("/")] for cell in cells[1:4]]
    return rows


def _tabulated(quantity: str, stage: str, friction: bool, arl0: float) -> list[float]:
    d = DecisionConfig().detector_config(quantity, friction_temperature=friction)
    settings = d.gaussian_settings(stage)
    out = []
    for rho in ((0.0, 0.5, 0.9) if d.dim > 1 else (0.0,)):
        found = lookup(settings, arl0, tabulated_correlation(rho, d.dim))
        assert found is not None, (quantity, stage, friction, rho)
        out.append(found.threshold)
    return out


@pytest.mark.parametrize("label", sorted(ROWS))
def test_each_documented_threshold_is_the_shipped_tables(label: str) -> None:
    documented = _documented()
    assert label in documented, f"docs/DETECTION.md lost its row {label!r}"
    for column, arl0 in enumerate((*TARGETS, DecisionConfig().arl0)):
        tabulated = _tabulated(*ROWS[label], arl0)
        assert documented[label][column] == pytest.approx(tabulated, abs=0.0051), (label, arl0)


README = Path(__file__).resolve().parents[1] / "README.md"


#: The demo robot sends 2 joints: a year's budget split over their 8 detectors.
DEMO_JOINTS = 2


def _readme_demo_thresholds() -> tuple[list[tuple[dict[str, float], tuple[float, float]]], tuple[float, float]]:
    """The README's demo paragraph: the warm-up thresholds (kl_raw, kl_weighted, wear score; the joint vector's
    range) of the demo's robot, then of a 6-joint robot, and a 6-joint robot's steady range [nats]."""
    text = " ".join(README.read_text(encoding="utf-8").split())
    found = re.findall(r"are ([\d.]+) nats \(kl_raw\), ([\d.]+) \(kl_weighted\), ([\d.]+) \(the wear score\) and "
                       r"([\d.]+)(?:–([\d.]+))? \(joint vector\)", text)
    steady = re.search(r"in its steady stage, a 6-joint robot's are (\d+\.\d+)–(\d+\.\d+)", text)
    assert len(found) == 2 and steady, "README.md's demo paragraph no longer states the thresholds as this test reads them"
    stages = [(dict(zip(("kl_raw", "kl_weighted", "wear"), map(float, row[:3]))),
               (float(row[3]), float(row[4] or row[3]))) for row in found]
    return stages, (float(steady[1]), float(steady[2]))


def test_the_readme_states_the_shipped_thresholds_of_the_demo() -> None:
    """The demo's joints have a motor temperature; each number rounded to 0.1 nats, the joint vector's range
    (its learned ρ per joint) within the table's ρ = 0 … 0.9 entries, the steady range the table's extremes:
    first at the demo robot's share of the default budget, then at a 6-joint robot's."""
    stages, steady = _readme_demo_thresholds()
    decision = DecisionConfig()
    for (scalars, joint), arl0 in zip(stages, (decision.arl0_for(decision.cycles_per_day, DEMO_JOINTS),
                                               decision.arl0)):
        for quantity, stated in scalars.items():
            assert stated == pytest.approx(_tabulated(quantity, "warm-up", False, arl0)[0], abs=0.051), (quantity, arl0)
        by_rho = _tabulated("joint", "warm-up", False, arl0)
        assert min(by_rho) - 0.051 <= joint[0] <= joint[1] <= max(by_rho) + 0.051, (joint, by_rho, arl0)
    arl0 = decision.arl0
    steady_all = [h for q in ("wear", "kl_raw", "kl_weighted", "joint") for h in _tabulated(q, "steady", False, arl0)]
    assert steady == pytest.approx((min(steady_all), max(steady_all)), abs=0.051), (steady, steady_all)
