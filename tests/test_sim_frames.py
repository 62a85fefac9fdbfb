"""Simulator frame stream: encoders, stream structure, log writers, reproducibility by seed."""

from __future__ import annotations

import hashlib
import json

import can
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from test_sim_support import collect, decode

from protocol import frames as pf
from sim_controller.config import SimConfig
from sim_controller.controller import Controller
from sim_controller.faults import FaultSpec, FrameBlock
from sim_controller.log_writers import block_messages, open_block_writer
from sim_controller.output import record, sidecar_path

SMALL = dict(joints=2, cycles=2, speeds=(10.0, 100.0), plateau_time=0.3, pause_time=0.1)


@settings(max_examples=50, deadline=None)
@given(counter=st.integers(0, 10**6), mode=st.sampled_from(list(pf.Mode)), cycle=st.integers(0, 10**6),
       segment=st.integers(0, 255), tick=st.integers(0, 2**40))
def test_controller_status_block_matches_scalar_encoder(counter, mode, cycle, segment, tick):
    block = pf.encode_controller_status_block([counter], [int(mode)], cycle, [segment], [tick])
    assert block[0].tobytes() == pf.encode_controller_status(counter, int(mode), cycle, segment, tick)


@settings(max_examples=50, deadline=None)
@given(joint=st.integers(0, 7), counter=st.integers(0, 10**6), load=st.floats(-2.0, 2.0),
       std=st.floats(0.0, 0.6), temp=st.floats(-400.0, 400.0))
def test_joint_status_block_matches_scalar_encoder(joint, counter, load, std, temp):
    block = pf.encode_joint_status_block(joint, [counter], [load], std, [temp])
    assert block[0].tobytes() == pf.encode_joint_status(joint, counter, load, std, temp)


def test_stream_layout_counters_and_status_content():
    config = SimConfig(seed=3, **SMALL)
    controller = Controller(config)
    block = collect(controller.frames())
    decoded = decode(block)
    assert decoded.valid.all()
    assert np.all(np.diff(block.timestamps) > 0)
    n_ticks = int(round(controller.simulated_seconds * config.rate))
    motor = decoded.kind == pf.FrameKind.MOTOR_STATE
    status = decoded.kind == pf.FrameKind.CONTROLLER_STATUS
    joint_status = decoded.kind == pf.FrameKind.JOINT_STATUS
    assert motor.sum() == n_ticks * config.joints
    assert status.sum() == (n_ticks + 9) // 10 and joint_status.sum() == status.sum() * config.joints
    assert len(block) == controller.summary()["frames_sent"]
    for j in range(config.joints):
        counters = decoded.counter[motor & (decoded.joint == j)]
        assert np.array_equal(counters, np.arange(n_ticks) % 256)
    ticks = decoded.status_tick[status]
    assert np.array_equal(ticks, np.arange(0, n_ticks, 10))
    assert np.array_equal(decoded.counter[status], np.arange(status.sum()) % 16)
    # a status frame is followed by one JointStatus per joint, each right after its tick's motor frames
    first = np.flatnonzero(status)[0]
    assert list(block.ids[first - 2:first + 3]) == [0x100, 0x101, 0x080, 0x0A0, 0x0A1]
    segments = set(decoded.segment[status].tolist())
    assert segments == {0, 1, 2, pf.SEGMENT_PRODUCTION}
    assert set(decoded.mode[status].tolist()) == {pf.Mode.TEST_CYCLE, pf.Mode.PRODUCTION}
    assert set(decoded.cycle[status].tolist()) == {0, 1}
    truth = controller.truth_records()
    for j in range(config.joints):
        js = joint_status & (decoded.joint == j)
        first_cycle = js & np.isin(np.arange(len(block)), np.flatnonzero(js)[:10])
        assert decoded.load_estimate[first_cycle] == pytest.approx(truth[j]["load_estimate"], abs=pf.TORQUE_SCALE)
        assert decoded.load_std[js] == pytest.approx(config.load_std, abs=pf.LOAD_STD_SCALE)


@pytest.mark.parametrize("suffix", [".blf", ".log", ".asc"])
def test_block_writer_writes_the_same_bytes_as_python_can(tmp_path, suffix):
    block = collect(Controller(SimConfig(seed=1, start_time=1.7e9, **SMALL)).frames())
    fast, slow = tmp_path / f"fast{suffix}", tmp_path / f"slow{suffix}"
    writer = open_block_writer(fast)
    for i in range(0, len(block), 3000):
        writer.write_block(block.take(np.arange(i, min(i + 3000, len(block)))))
    writer.stop()
    logger = can.Logger(slow, **({"compression_level": 1} if suffix == ".blf" else {}))
    for message in block_messages(block):
        logger.on_message_received(message)
    logger.stop()
    if suffix == ".asc":        # the first line is the writer's wall-clock date
        assert fast.read_text().splitlines()[1:] == slow.read_text().splitlines()[1:]
    else:
        assert fast.read_bytes() == slow.read_bytes()
    back = list(can.LogReader(fast))
    assert len(back) == len(block)
    assert [m.arbitration_id for m in back[:50]] == block.ids[:50].tolist()
    assert bytes(back[-1].data) == block.data[-1].tobytes()


def _digest(path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def test_record_is_reproducible_by_seed(tmp_path):
    faults = FaultSpec.parse("drop=0.002,corrupt=0.002,duplicate=0.002,reorder=0.002,delay=0.002,"
                             "silence=0.0001,restart=0.5,stuck=0.0001")
    runs = {}
    for name, seed in (("a", 7), ("b", 7), ("c", 8)):
        config = SimConfig(seed=seed, faults=faults, **SMALL)
        record(config, tmp_path / f"{name}.blf", tmp_path / f"{name}.jsonl")
        record(config, tmp_path / f"{name}.log")
        runs[name] = (_digest(tmp_path / f"{name}.blf"), _digest(tmp_path / f"{name}.log"),
                      (tmp_path / f"{name}.jsonl").read_text())
    assert runs["a"] == runs["b"]
    assert runs["a"][0] != runs["c"][0] and runs["a"][1] != runs["c"][1] and runs["a"][2] != runs["c"][2]


def test_truth_file_format_and_parameter_sidecar(tmp_path):
    config = SimConfig(seed=2, **SMALL)
    summary = record(config, tmp_path / "x.log", tmp_path / "truth.jsonl")
    lines = [json.loads(s) for s in (tmp_path / "truth.jsonl").read_text().splitlines()]
    records, last = lines[:-1], lines[-1]
    assert [(r["joint"], r["cycle"]) for r in records] == [(j, c) for c in range(2) for j in range(2)]
    for r in records:
        assert {"joint", "cycle", "temperature", "load", "load_estimate", "wear", "speeds", "friction",
                "model_error"} <= set(r)
        assert len(r["friction"]) == len(r["model_error"]) == len(config.speeds)
        assert config.load_range[0] <= abs(r["load"]) <= config.load_range[1]
    assert set(last["faults"]) >= {"dropped", "corrupted", "duplicated", "reordered", "delayed", "silenced",
                                   "restarts", "stuck"}
    assert last["frames_sent"] == summary.frames_sent == sum(1 for _ in can.LogReader(tmp_path / "x.log"))
    params = json.loads(sidecar_path(tmp_path / "truth.jsonl").read_text())
    assert [p["joint"] for p in params["joints"]] == [0, 1]
    # two joints: individually varied friction parameters, recorded
    assert params["variation"] == pytest.approx(0.08)
    assert params["joints"][0]["friction"] != params["joints"][1]["friction"]


def test_single_joint_uses_the_exact_table():
    from joint_model.friction import DEFAULT_PARAMS
    assert Controller(SimConfig(joints=1)).joints[0].friction == DEFAULT_PARAMS
    varied = Controller(SimConfig(joints=1, variation=0.1)).joints[0].friction
    assert varied != DEFAULT_PARAMS
    ratio = varied.fc0 / DEFAULT_PARAMS.fc0
    assert 0.9 <= ratio <= 1.1


def test_frame_block_concat_of_nothing_is_empty():
    assert len(FrameBlock.concat([])) == 0
