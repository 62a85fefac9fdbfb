"""The same simulated robot through our frames, CiA 402 drives and a foreign DBC: the simulator speaks each
(`sim-controller record --profile`), the agent decodes each (`edge-monitor replay --mapping`), and the
friction curves agree within the coarser wire resolution; cycles are found from the motion; check-mapping
accepts each profile and refuses wrong mappings with exit code 2."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import canopen
import numpy as np
import pytest

from edge_monitor.config import load_config
from edge_monitor.pipeline.agent import Agent
from edge_monitor.sources.cia402_source import Cia402Decoder
from edge_monitor.sources.foreign_source import open_source
from edge_monitor.sources.log_source import log_blocks
from protocol.signal_mapping import load_mapping

from foreign_mappings import SPEEDS, mapping, record

ROOT = Path(__file__).resolve().parents[1]

pytestmark = pytest.mark.slow
CYCLES = 4


def _sim(tmp: Path, name: str, profile: str) -> Path:
    return record(tmp, name, profile, suffix=".blf", cycles=CYCLES)


def _replay(log: Path, mapping_path: Path | None) -> tuple[dict, list[dict]]:
    jsonl = log.with_suffix(".jsonl")
    cmd = [sys.executable, "-m", "edge_monitor.cli", "replay", str(log), "--json", "--jsonl", str(jsonl), "-q"]
    if mapping_path is not None:
        cmd += ["--mapping", str(mapping_path)]
    stats = json.loads(subprocess.run(cmd, check=True, capture_output=True, text=True).stdout)
    return stats, [json.loads(line) for line in jsonl.open()]


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("profiles")
    cia, foreign = mapping("cia402", tmp), mapping("foreign_robot", tmp)
    logs = {"native": (_sim(tmp, "native", "native"), None), "cia402": (_sim(tmp, "cia402", "cia402"), cia),
            "foreign": (_sim(tmp, "foreign", f"dbc:{foreign}"), foreign)}
    return {name: (*_replay(log, m), log, m) for name, (log, m) in logs.items()}


def test_every_profile_gives_the_same_friction_curves(runs):
    native = {(r["joint"], r["cycle"]): r for r in runs["native"][1]}
    for name in ("cia402", "foreign"):
        stats, records, _, _ = runs[name]
        assert stats["cycles"] == CYCLES and stats["unknown_id"] == 0
        assert stats["details"]["cycle_finding"]["cycles_found"] == CYCLES
        assert {(r["joint"], r["cycle"]) for r in records} == set(native)
        for r in records:
            ref = native[(r["joint"], r["cycle"])]["friction"]
            assert len(r["friction"]["torque"]) == len(ref["torque"]) == len(SPEEDS)
            # resolution: ‰ of rated = 3.3e-4 of T_ref (cia402), 0.001 N·m / 30 N·m (foreign), averaged over a plateau
            np.testing.assert_allclose(r["friction"]["torque"], ref["torque"], atol=2e-4)
            np.testing.assert_allclose(r["friction"]["speeds"], ref["speeds"], atol=0.05)


def test_missing_signals_fall_back(runs):
    cia = runs["cia402"][1]
    foreign = runs["foreign"][1]
    assert all(r["load"]["mean"] is None for r in cia)             # CiA 402 has no load estimate
    assert all(r["load"]["mean"] is not None for r in foreign)      # the foreign DBC multiplexes one
    native_load = {(r["joint"], r["cycle"]): r["load"]["mean"] for r in runs["native"][1]}
    for r in foreign:   # a motion-found cycle starts at its first plateau, not at the controller's mark:
        # the status frames of the ramp before it fall into the previous cycle (a few of ≈ 500)
        assert r["load"]["mean"] == pytest.approx(native_load[(r["joint"], r["cycle"])], abs=2e-3)


def test_statusword_gates_samples_and_nothing_is_sent(runs):
    _, _, log, m = runs["cia402"]
    decoder = Cia402Decoder(load_mapping(m))
    ids, data, dlc, ts = next(iter(log_blocks(log, 20000)))
    node1 = ids == 0x181
    data = data.copy()
    data[np.flatnonzero(node1)[:100], 0] = 0x33          # "switched on", not "operation enabled"
    out = decoder.decode(ids, data, dlc, ts)
    assert decoder.c.not_enabled == 100
    assert out.joints[0].time.size == int(node1.sum()) - 100


def test_pdo_layout_decodes_as_canopen(runs):
    """The vectorised TPDO decoding equals canopen's own PdoMap.on_message for recorded frames."""
    _, _, log, m = runs["cia402"]
    mp = load_mapping(m)
    decoder = Cia402Decoder(mp)
    ids, data, dlc, ts = next(iter(log_blocks(log, 5000)))
    network = canopen.Network()                                  # never connected
    node = canopen.RemoteNode(1, str(mp.joints[0].eds))
    network.add_node(node)
    node.tpdo.read(from_od=True)
    speed, torque, _ = decoder.joints[0]
    rows = np.flatnonzero(ids == 0x181)[:50]
    for r in rows:
        network.notify(0x181, bytes(data[r][:dlc[r]]), float(ts[r]))
        assert node.tpdo[1]["Torque actual value"].raw == torque.bits.raw(data[r:r + 1])[0]
        assert node.tpdo[1]["Velocity actual value"].raw == speed.bits.raw(data[r:r + 1])[0]


def test_agent_takes_a_source_in_process(runs, tmp_path):
    _, _, log, m = runs["foreign"]
    cfg = load_config(None)
    agent = Agent(cfg, source=open_source(m, cfg))
    for block in log_blocks(log, 4096):
        agent.update(*block)
    agent.flush_source()
    agent.finish()
    assert agent.stats.cycles == CYCLES and agent.stats.symptoms == 2 * CYCLES


@pytest.mark.parametrize("name", ["native", "cia402", "foreign"])
def test_check_mapping_accepts_each_profile(runs, name):
    _, _, log, m = runs[name]
    cmd = [sys.executable, "-m", "edge_monitor.cli", "check-mapping", str(log), "--json"]
    if m is not None:
        cmd += ["--mapping", str(m)]
    done = subprocess.run(cmd, capture_output=True, text=True)
    assert done.returncode == 0, done.stdout + done.stderr
    report = json.loads(done.stdout)
    assert set(report["joints"]) == {"0", "1"} and not report["problems"]
    if m is not None:
        assert report["cycles"]["cycles_found"] == CYCLES
        assert report["joints"]["0"]["speed"]["rate_hz"] == pytest.approx(500, rel=0.01)


def _check(log: Path, m: Path) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "edge_monitor.cli", "check-mapping", str(log), "--mapping", str(m)],
                          capture_output=True, text=True)


def test_check_mapping_refuses_wrong_mappings(runs, tmp_path):
    _, _, log, m = runs["foreign"]
    text = m.read_text()
    cases = {
        "no_message": (text.replace('"AxisFeedback_1", signal = "MotorSpeed"', '"AxisFeedbak_1", signal = "MotorSpeed"'),
                       "message 'AxisFeedbak_1' is not in the DBC (did you mean AxisFeedback_1"),
        "no_signal": (text.replace('signal = "LoadTorque_0"', 'signal = "Load"'), "has no signal 'Load'"),
        "unit": (text.replace('unit = "rpm"', 'unit = "furlong/fortnight"', 1), "does not convert to rad/s"),
        "scale": (text.replace("reference_torque_nm = 30.0", "reference_torque_nm = 0.003", 1),
                  "torque reaches"),
        "joint_without_frames": (text + '\n[joint.2]\nreference_torque_nm = 20.0\n'
                                 'speed = { message = "AxisFeedback_2", signal = "MotorSpeed", unit = "rpm" }\n'
                                 'torque = { message = "AxisFeedback_2", signal = "MotorTorque", unit = "Nm" }\n',
                                 "joint 2: no samples"),
    }
    for name, (bad, message) in cases.items():
        path = tmp_path / f"{name}.toml"
        path.write_text(bad)
        done = _check(log, path)
        assert done.returncode == 2, (name, done.stdout, done.stderr)
        assert message in done.stdout + done.stderr, (name, done.stdout, done.stderr)
        assert "Traceback" not in done.stderr


def test_a_restarted_agent_numbers_found_cycles_on(runs, tmp_path):
    """State saved by an agent on a foreign source loads, and the cycle numbering goes on after a restart."""
    from edge_monitor.pipeline.state_store import StateStore
    _, _, log, m = runs["foreign"]
    cfg = load_config(None)
    blocks = list(log_blocks(log, 4096))
    first = Agent(cfg, state_store=StateStore(tmp_path), source=open_source(m, cfg))
    for block in blocks[:len(blocks) // 2]:
        first.update(*block)
    first.close()
    second = Agent(cfg, state_store=StateStore(tmp_path), source=open_source(m, cfg))
    assert second.stats.states_rejected == 0
    emitted = []
    for block in blocks[len(blocks) // 2:]:
        emitted += second.update(*block)
    emitted += second.flush_source() + second.finish()
    assert emitted and min(s.cycle for s in emitted) > max(first._last_emitted.values())


def test_the_configs_joints_are_the_monitored_ones_with_a_mapping(runs):
    """The config's ``joints`` splits the false-alarm budget over the joints it names, so a mapped source must
    monitor those only (it monitored every mapped joint: with ``joints = [1]`` two joints each at one joint's share
    of the budget). The other joint's samples are counted as filtered; a config naming no mapped joint is refused."""
    import dataclasses

    from protocol.signal_mapping import MappingError

    _, _, log, m = runs["foreign"]
    cfg = dataclasses.replace(load_config(None), joints=(1,))
    agent = Agent(cfg, source=open_source(m, cfg))
    symptoms = []
    for block in log_blocks(log, 4096):
        symptoms += agent.update(*block)
    symptoms += agent.flush_source() + agent.finish()
    assert {s.joint for s in symptoms} == {1} and agent.stats.cycles == CYCLES
    assert agent.health().counters["joint_filtered"] > 0
    with pytest.raises(MappingError, match=r"joints \[7\].*none in common"):
        open_source(m, dataclasses.replace(cfg, joints=(7,)))


@pytest.mark.parametrize("change, message", [
    ({"tpdo": [{"cob_id": 0x181, "objects": ["zzzz"]}]}, "not both"),      # an EDS and a TPDO list: which is sent?
    ({"node": True}, "node id"),                                           # a boolean is no node number
])
def test_a_cia402_joint_states_its_drive_one_way(change, message):
    """A CiA 402 joint with both an EDS and a written TPDO mapping had its ``tpdo`` ignored (even an invalid one);
    ``node = true`` was node 1. Both are refused naming the key; the shipped mapping still loads."""
    import tomllib

    from protocol.signal_mapping import MappingError, mapping_from_dict

    path = ROOT / "protocol" / "mappings" / "cia402.toml"
    data = tomllib.loads(path.read_text(encoding="utf-8"))
    assert mapping_from_dict(data, path).joints                    # as shipped: loads
    data["joint"]["0"].update(change)
    with pytest.raises(MappingError, match=message):
        mapping_from_dict(data, path)


def test_a_boolean_reference_joint_is_refused():
    import tomllib

    from protocol.signal_mapping import MappingError, mapping_from_dict

    path = ROOT / "protocol" / "mappings" / "foreign_robot.toml"
    data = tomllib.loads(path.read_text(encoding="utf-8"))
    data["cycles"]["reference_joint"] = True
    with pytest.raises(MappingError, match="reference_joint"):
        mapping_from_dict(data, path)


def test_joint_numbers_are_ascii_digits_and_a_byte_order_mark_is_read(tmp_path):
    """``[joint."٣"]`` (an Arabic-Indic three) was joint 3; a mapping saved with a byte-order mark (a Windows
    editor) was "not valid TOML" at line 1, column 1."""
    import shutil

    from protocol.signal_mapping import MappingError, load_mapping

    shipped = ROOT / "protocol" / "mappings" / "foreign_robot.toml"
    (tmp_path / "mappings").mkdir()
    shutil.copytree(ROOT / "protocol" / "dbc", tmp_path / "dbc")        # the mapping names its DBC relatively
    text = shipped.read_text(encoding="utf-8")
    marked = tmp_path / "mappings" / "bom.toml"
    marked.write_bytes(b"\xef\xbb\xbf" + text.encode("utf-8"))
    assert load_mapping(marked).joints.keys() == load_mapping(shipped).joints.keys()
    arabic = tmp_path / "mappings" / "arabic.toml"
    arabic.write_text(text.replace("[joint.3]", '[joint."\u0663"]'), encoding="utf-8")
    assert '[joint."\u0663"]' in arabic.read_text(encoding="utf-8")
    with pytest.raises(MappingError, match="joint"):
        load_mapping(arabic)
