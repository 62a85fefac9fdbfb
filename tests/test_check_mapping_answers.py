"""Issue 50: check-mapping, the commissioning tool, never says "mapping OK" where the agent would publish
nothing or nonsense: no cycle found, values no robot has in either direction (a reference torque, a
velocity factor or a speed off by orders of magnitude), a trigger that never fires, an E2E profile on a
message without one, --seconds that reads nothing, two joints on one drive or signal, an E2E counter
signal that does not exist. Its advice for ``[cycles] speeds`` works before the speeds are known and
lists the test cycle's levels in its order, without the production motion's speed."""

from __future__ import annotations

import re
from pathlib import Path

import hostile_files as hostile
import pytest

from foreign_mappings import SPEEDS, mapping, record

pytestmark = pytest.mark.slow


def _sim(tmp: Path, name: str, profile: str, speeds=SPEEDS) -> Path:
    return record(tmp, name, profile, speeds=speeds, seed=5)


@pytest.fixture(scope="module")
def caps(tmp_path_factory) -> dict[str, Path]:
    tmp = tmp_path_factory.mktemp("commissioning")
    cia, foreign = mapping("cia402", tmp), mapping("foreign_robot", tmp)
    return {"dir": tmp, "cia402": _sim(tmp, "cia402", "cia402"), "cia402.toml": cia,
            "foreign": _sim(tmp, "foreign", f"dbc:{foreign}"), "foreign.toml": foreign}


def _check(capture: Path, mapping_path: Path | None, *extra: str) -> hostile.Run:
    args = ["check-mapping", str(capture), *extra] + (["--mapping", str(mapping_path)] if mapping_path else [])
    run = hostile.run_measured(hostile.edge_monitor(*args), timeout=180)
    assert not run.timed_out and "Traceback" not in run.stderr, run.stderr[-3000:]
    return run


def _refused(run: hostile.Run, says: str) -> None:
    assert run.returncode == 2, (run.returncode, run.stdout[-2000:], run.stderr[-2000:])
    assert says in run.stdout + run.stderr and "mapping OK" not in run.stdout, (says, run.stdout, run.stderr)


def _variant(caps, base: str, name: str, edit) -> Path:
    path = caps["dir"] / f"{name}.toml"
    path.write_text(edit(caps[f"{base}.toml"].read_text()))
    return path


def test_the_shipped_mappings_still_pass(caps):
    for name in ("cia402", "foreign"):
        run = _check(caps[name], caps[f"{name}.toml"])
        assert run.returncode == 0 and run.stdout.strip().endswith("mapping OK"), run.stdout


WRONG_NUMBERS = {
    # name: (base, edit, what the refusal says)
    "reference_torque_denormal": ("foreign", lambda t: t.replace("reference_torque_nm = 30.0", "reference_torque_nm = 1e-320", 1),
                                  "reference_torque_nm: must be > 0 N·m, a robot motor's"),
    "velocity_factor_tiny": ("cia402", lambda t: t.replace("# velocity_factor = 9.587379924285257e-05",
                                                           "velocity_factor = 1e-300", 1), "velocity_factor"),
    "speeds_huge": ("foreign", lambda t: re.sub(r"(?m)^speeds = .*$", "speeds = [1e308]", t), "speeds: positive rad/s up to"),
    "torque_too_small": ("foreign", lambda t: t.replace("reference_torque_nm = 30.0", "reference_torque_nm = 90000.0", 1),
                         "torque never exceeds"),
    "torque_too_large": ("foreign", lambda t: t.replace("reference_torque_nm = 30.0", "reference_torque_nm = 0.003", 1),
                         "torque reaches"),
    "speed_too_small": ("cia402", lambda t: t.replace("# velocity_factor = 9.587379924285257e-05",
                                                      "velocity_factor = 1e-9", 1), "speed never exceeds"),
    "trigger_never_fires": ("foreign", lambda t: t.replace('from = "motion"', 'from = "trigger"\nvalue = 99\n'
                                                            'trigger = { message = "AxisFeedback_0", signal = "AxisState" }'),
                            "no whole cycle found"),
    "two_joints_one_drive": ("cia402", lambda t: t.replace("node = 2", "node = 1"), "two joints cannot be one"),
    "two_joints_one_signal": ("foreign", lambda t: t.replace('message = "AxisFeedback_1", signal = "MotorSpeed"',
                                                             'message = "AxisFeedback_0", signal = "MotorSpeed"'),
                              "two joints cannot be one"),
    "e2e_counter_nope": ("foreign", lambda t: t + '[[e2e]]\nmessage = "AxisFeedback_0"\nprofile = 5\ndata_id = 7\n'
                                                  'counter_signal = "Nope"\n', "counter_signal 'Nope' is not a signal"),
    "e2e_on_a_message_without": ("foreign", lambda t: t + '[[e2e]]\nmessage = "AxisLoad"\nprofile = 5\ndata_id = 7\n',
                                 "failing their E2E check"),
}


@pytest.mark.parametrize("name", sorted(WRONG_NUMBERS))
def test_a_mapping_no_robot_fits_is_refused(caps, name):
    base, edit, says = WRONG_NUMBERS[name]
    _refused(_check(caps[base], _variant(caps, base, name, edit)), says)


@pytest.mark.parametrize("seconds", ["nan", "-1", "0", "inf"])
def test_seconds_that_read_nothing_are_a_usage_error(caps, seconds):
    _refused(_check(caps["foreign"], caps["foreign.toml"], "--seconds", seconds), "--seconds")


def test_a_capture_shorter_than_a_cycle_finds_no_whole_cycle(caps):
    _refused(_check(caps["foreign"], caps["foreign.toml"], "--seconds", "5"), "no whole cycle found")


def test_the_speeds_advice_works_before_speeds_are_stated_and_keeps_the_cycle_order(caps, tmp_path):
    """The simulator's test cycle holds each level +v then −v, then a production motion that cruises at
    150 rad/s in one direction: the advice lists the levels as designed, in their (not sorted) order."""
    designed = (41.7, 8.7, 133.5)
    log = _sim(tmp_path, "unsorted", "cia402", speeds=designed)
    text = re.sub(r"(?m)^speeds = .*$\n", "", caps["cia402.toml"].read_text())
    (tmp_path / "m.toml").write_text(text)
    run = _check(log, tmp_path / "m.toml")
    _refused(run, "[cycles] speeds is missing: set speeds = [")
    found = re.search(r"set speeds = \[([^\]]*)\]", run.stdout).group(1)
    assert [float(v) for v in found.split(",")] == pytest.approx(designed, abs=0.3)
    assert "production motion left out: [150" in run.stdout
