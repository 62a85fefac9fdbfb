"""studies.robots.run_robot_series (``tools/studies/healthy_fleet_study.py --from-series``: only the detectors,
over the per-cycle quantities studies.series keeps) finds what the whole agent on the fast path finds."""

from __future__ import annotations

from pathlib import Path

import pytest

from studies import series
from studies.robots import RunSpec, run_robot, run_robot_series

SCENARIO = """
[simulation]
joints = 2
cycles = 150

[[joint]]
index = 1
wear = [ { kind = "ramp", start = 95, end = 150, from = 0, to = 60 } ]
"""


@pytest.mark.slow
@pytest.mark.parametrize("motor_temperature", [True, False], ids=["motor temperature", "none"])
def test_the_detectors_over_kept_series_alarm_as_the_agent_does(tmp_path: Path, monkeypatch,
                                                                  motor_temperature: bool) -> None:
    """2 joints, 150 cycles, joint 1 wearing 0 → 60 from cycle 95, a target of 50 cycles: the same alarms
    (joint, cycle, quantity, wear) and the same monitored cycles per quantity from the series computed
    once and then read from the cache; except the wear score's warm-up, which the series start ≈ 10
    cycles later (a row is kept once the KL distances have values too), so the wear detector's first
    nominal is learned from later cycles. On a robot without motor temperature the detectors follow the
    lubricant temperature read from the friction, kept in the series for it."""
    monkeypatch.setattr(series, "CACHE", tmp_path / "cache")
    scenario = tmp_path / "wear.toml"
    scenario.write_text(SCENARIO)
    spec = RunSpec(seed=3, cycles=None, joints=2, overrides=(("decision.arl0_cycles", 50),), progress=0,
                   scenario=str(scenario), motor_temperature=motor_temperature)
    agent = run_robot(spec)
    detectors = run_robot_series(spec)
    assert list((tmp_path / "cache").iterdir())            # computed once, kept
    again = run_robot_series(spec)

    def alarms(run: dict) -> list[tuple]:
        return sorted((a["joint"], a["cycle"], a["quantity"], a["wear"]) for a in run["alarms"]
                      if a["quantity"] != "wear")

    assert alarms(agent) and alarms(agent) == alarms(detectors) == alarms(again)
    # the worn joint alarms; the healthy one may too: at a target of 50 cycles its ≈ 40 tested warm-up cycles
    # per detector expect ≈ 0.8 false alarms each (what matters here is that both paths raise the same ones)
    assert 1 in {a[0] for a in alarms(agent)} and agent["worn"] == detectors["worn"] == [1]
    for joint, counts in agent["monitored"].items():
        assert {q: n for q, n in counts.items() if q != "wear"} == \
            {q: n for q, n in detectors["monitored"][joint].items() if q != "wear"}


def test_the_kept_series_key_reads_a_toml_by_its_settings_without_the_decision_table(tmp_path: Path) -> None:
    """The series do not depend on comments nor on ``[decision]`` (the detectors are off when they are
    computed): neither changes a TOML file's part of the key; any other setting does."""
    base = '[kl]\nmin_speed = 10  # rad/s\n\n[decision]\nwarm_up_hold_margin = 6.0\n'
    variants = {"comment": base.replace("# rad/s", "# a longer comment"),
                "decision": base.replace("6.0", "2.0") + "allowance = 0.5\n",
                "kl": base.replace("10", "12")}
    key = {}
    for name, text in {"base": base, **variants}.items():
        path = tmp_path / f"{name}.toml"
        path.write_text(text, encoding="utf-8")
        key[name] = series.settings_bytes(path)
    assert key["comment"] == key["decision"] == key["base"] != key["kl"]
