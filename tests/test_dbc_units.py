"""A DBC signal's unit is checked against the mapping's (found 2026-12: a torque in mNm or a speed in rpm or
deg/s was decoded as if in the mapping's N·m or rad/s, off by a factor without a word). Real DBCs, loaded
and encoded by cantools, decoded by the agent's DbcDecoder."""

from __future__ import annotations

import logging
import math

import cantools
import numpy as np
import pytest

from edge_monitor.sources.dbc_source import DbcDecoder
from protocol.signal_mapping import MappingError, mapping_from_dict
from protocol.units import same_unit


def _dbc(speed_unit: str, torque_unit: str, temperature_unit: str = "degC") -> str:
    return f"""VERSION ""
NS_ :
BS_:
BU_: C M
BO_ 256 Axis0: 8 C
 SG_ Speed : 0|16@1- (0.1,0) [-3276.8|3276.7] "{speed_unit}" M
 SG_ Torque : 16|16@1- (1,0) [-32768|32767] "{torque_unit}" M
 SG_ Temp : 32|16@1- (0.1,0) [-3276.8|3276.7] "{temperature_unit}" M
"""


def _decoder(tmp_path, dbc: str, speed: dict | None = None, torque: dict | None = None,
             temperature: dict | None = None) -> DbcDecoder:
    (tmp_path / "axis.dbc").write_text(dbc)
    joint = {"speed": {"message": "Axis0", "signal": "Speed", **(speed or {})},
             "torque": {"message": "Axis0", "signal": "Torque", **(torque or {})},
             "temperature": {"message": "Axis0", "signal": "Temp", **(temperature or {})},
             "reference_torque_nm": 10.0}
    mapping = mapping_from_dict({"kind": "dbc", "dbc": "axis.dbc", "cycles": {"speeds": [10.0]},
                                 "joint": {"0": joint}}, tmp_path / "axis.toml")
    return DbcDecoder(mapping)


def _decode(decoder: DbcDecoder, dbc: str, speed: float, torque: float, temp: float) -> tuple[float, float, float]:
    """The agent's speed [rad/s], torque [fraction of T_ref] and temperature [°C] of one frame cantools encodes."""
    payload = cantools.database.load_string(dbc).encode_message("Axis0", {"Speed": speed, "Torque": torque,
                                                                          "Temp": temp})
    data = np.frombuffer(payload, dtype=np.uint8).reshape(1, 8)
    out = decoder.decode(np.array([256]), data, np.array([8]), np.array([0.0]))
    return float(out.joints[0].speed[0]), float(out.joints[0].torque[0]), float(out.status[0].temperature[0])


def test_units_the_mapping_leaves_open_are_converted_from_the_dbcs_with_a_log_line(tmp_path, caplog):
    dbc = _dbc("rpm", "mNm", "K")
    with caplog.at_level(logging.INFO, logger="protocol.dbc_units"):
        decoder = _decoder(tmp_path, dbc)
    speed, torque, temp = _decode(decoder, dbc, speed=60.0, torque=5000.0, temp=300.0)
    assert speed == pytest.approx(2 * math.pi) and torque == pytest.approx(0.5) and temp == pytest.approx(26.85)
    converted = [r.getMessage() for r in caplog.records if "converted" in r.getMessage()]
    assert len(converted) == 3 and "joint.0.torque: Axis0.Torque is in 'mNm' (the DBC's unit" in converted[1]


@pytest.mark.parametrize(("speed_unit", "torque_unit", "mapping", "says"), [
    ("rpm", "mNm", {"torque": {"unit": "Nm"}},
     "joint.0.torque: signal Axis0.Torque is in 'mNm' (the DBC's unit), the mapping says unit = 'Nm': read as Nm "
     "its values would be 1000 times too large; set unit = \"mNm\" in joint.0.torque"),
    ("deg/s", "Nm", {"speed": {"unit": "rpm"}},
     "joint.0.speed: signal Axis0.Speed is in 'deg/s' (the DBC's unit), the mapping says unit = 'rpm': read as rpm "
     "its values would be 6 times too large; set unit = \"deg/s\" in joint.0.speed"),
    ("rad/s", "mNm", {"torque": {"unit": "Nm", "scale": -1}}, "unit = 'Nm', scale = -1: read as Nm its values"),
    ("rad/s", "A", {}, "signal Axis0.Torque is in 'A' (the DBC's unit), which is no torque unit the agent converts"),
    ("rad/s", "A", {"torque": {"unit": "Nm"}}, "if 'A' is another name of Nm, confirm it with scale = 1 in "
                                                "joint.0.torque"),
    ("rad/s", "%", {}, "torque in % of the rated torque needs rated_torque_nm"),
])
def test_a_unit_that_disagrees_with_the_mapping_is_refused_naming_signal_units_and_key(tmp_path, speed_unit,
                                                                                       torque_unit, mapping, says):
    with pytest.raises(MappingError) as error:
        _decoder(tmp_path, _dbc(speed_unit, torque_unit), **mapping)
    assert says in str(error.value) and str(error.value).startswith("mapping axis.toml: joint.0.")


@pytest.mark.parametrize(("speed_unit", "torque_unit", "mapping", "expected"), [
    ("U/min", "N.m", {"speed": {"unit": "rpm"}, "torque": {"unit": "Nm"}}, (2 * math.pi, 500.0)),  # other spellings
    ("rad/s", "mNm", {"torque": {"unit": "Nm", "scale": 0.001}}, (60.0, 0.5)),   # the mapping's scale converts
    ("rad/s", "A", {"torque": {"unit": "Nm", "scale": 1}}, (60.0, 500.0)),      # confirmed: A is taken as Nm
    ("", "", {"speed": {"unit": "rpm"}, "torque": {"unit": "mNm"}}, (2 * math.pi, 0.5)),  # no unit in the DBC
])
def test_units_that_agree_or_that_the_mapping_converts_are_read(tmp_path, speed_unit, torque_unit, mapping,
                                                                expected):
    dbc = _dbc(speed_unit, torque_unit)
    speed, torque, _ = _decode(_decoder(tmp_path, dbc, **mapping), dbc, speed=60.0, torque=5000.0, temp=40.0)
    assert (speed, torque) == pytest.approx(expected)


def test_a_dbc_without_units_is_read_in_the_mappings_with_one_info_line(tmp_path, caplog):
    dbc = _dbc("", "", "")
    with caplog.at_level(logging.INFO):
        decoder = _decoder(tmp_path, dbc, speed={"unit": "rpm"})
    assert _decode(decoder, dbc, speed=60.0, torque=2.0, temp=40.0) == pytest.approx((2 * math.pi, 2.0, 40.0))
    lines = [r.getMessage() for r in caplog.records if "gives no unit" in r.getMessage()]
    assert lines == ["mapping axis.toml: dbc: the DBC gives no unit for Axis0.Speed, Axis0.Temp, Axis0.Torque: "
                     "read in the units the mapping states (or its defaults)"]


def test_the_shipped_mapping_agrees_with_its_dbc():
    from protocol.signal_mapping import load_mapping
    from sim_controller.profiles import mapping_path
    DbcDecoder(load_mapping(mapping_path("foreign_robot")))


def test_the_simulators_dbc_profile_checks_the_same_units(tmp_path):
    from sim_controller.profiles import dbc_layout
    (tmp_path / "axis.dbc").write_text(_dbc("rpm", "mNm"))
    joint = {"speed": {"message": "Axis0", "signal": "Speed"}, "torque": {"message": "Axis0", "signal": "Torque",
                                                                          "unit": "Nm"}, "reference_torque_nm": 10.0}
    mapping = mapping_from_dict({"kind": "dbc", "dbc": "axis.dbc", "cycles": {"speeds": [10.0]},
                                 "joint": {"0": joint}}, tmp_path / "axis.toml")
    with pytest.raises(MappingError, match="set unit = \"mNm\" in joint.0.torque"):
        dbc_layout(mapping, 1)


def test_spellings_of_one_unit():
    assert same_unit("N.m", "Nm", "torque") and same_unit("U/min", "1/min", "speed") and same_unit("°C", "degC", "x")
    assert not same_unit("fraction", "Nm", "torque") and not same_unit("mNm", "Nm", "torque")
    assert same_unit("permille", "‰", "load") and not same_unit("K", "degC", "temperature")


@pytest.mark.parametrize("dbc", ["garbage", "missing", "directory"])
def test_the_simulators_dbc_profile_refuses_a_bad_dbc_as_the_agent_does(tmp_path, dbc):
    """A DBC that is garbage, missing or a directory was a cantools / FileNotFoundError / IsADirectoryError
    traceback from ``sim-controller record --profile dbc:MAPPING.toml``; now the agent's one line, exit 2."""
    import subprocess
    import sys

    from protocol.signal_mapping import load_mapping
    from sim_controller.profiles import dbc_layout
    (tmp_path / "axis.toml").write_text(
        'kind = "dbc"\ndbc = "axis.dbc"\n[cycles]\nfrom = "motion"\nspeeds = [10.0]\n[joint.0]\n'
        'reference_torque_nm = 10.0\nspeed = { message = "Axis0", signal = "Speed", unit = "rpm" }\n'
        'torque = { message = "Axis0", signal = "Torque", unit = "mNm" }\n')
    (tmp_path / "axis.dbc").write_text(_dbc("rpm", "mNm"))
    assert len(dbc_layout(load_mapping(str(tmp_path / "axis.toml")), 1).fast) == 1      # the good one
    (tmp_path / "axis.dbc").unlink()
    if dbc == "garbage":
        (tmp_path / "axis.dbc").write_text("not a dbc\n")
    elif dbc == "directory":
        (tmp_path / "axis.dbc").mkdir()
    mapping = load_mapping(str(tmp_path / "axis.toml"))
    with pytest.raises(MappingError) as agent:
        DbcDecoder(mapping)
    with pytest.raises(MappingError) as simulator:
        dbc_layout(mapping, 1)
    assert str(simulator.value) == str(agent.value)
    done = subprocess.run([sys.executable, "-m", "sim_controller.cli", "record", "-o", str(tmp_path / "x.blf"),
                           "--joints", "1", "--cycles", "1", "--profile", f"dbc:{tmp_path / 'axis.toml'}", "-q"],
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 2 and "Traceback" not in done.stderr, done.stderr[-2000:]
    assert str(agent.value) in done.stderr and not (tmp_path / "x.blf").exists()
