"""A saved state is untrusted input: corrupted or hostile files are moved aside (whole-file problems)
or relearned per joint (a joint's models that do not load), with a warning and a counter — never a
traceback, never an unbounded allocation, never silently adopted (issue #12)."""

from __future__ import annotations

import copy
import json
import math
import os
import tracemalloc
from pathlib import Path
from typing import Any

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from test_agent_pipeline import SPEEDS, feed, small_config

from edge_monitor.errors import StateError
from edge_monitor.pipeline.agent import Agent
from edge_monitor.pipeline.state_store import STATE_FILE, StateStore
from edge_monitor.pipeline.state_validation import MAX_CYCLE, validate_state

from synthetic_frames import make_frames


@pytest.fixture(scope="module")
def frames():
    return make_frames(5, joints=(0, 1), speeds=SPEEDS, wear=lambda j, c: 0.0, seed=4)


@pytest.fixture(scope="module")
def saved(frames, tmp_path_factory) -> dict[str, Any]:
    """A real state after 4 cycles: both joints' detectors monitoring."""
    path = tmp_path_factory.mktemp("state")
    agent = Agent(small_config(), state_store=StateStore(path))
    split = len(frames[0]) * 4 // 5 + 77
    feed(agent, frames, stop=split)
    agent.close()
    state = json.loads((path / STATE_FILE).read_text())
    assert all(state["joints"][j]["detectors"]["wear"]["glr"] for j in ("0", "1"))    # monitoring
    return state


def _restart(tmp_path: Path, text: str, frames) -> tuple[Agent, list]:
    (tmp_path / STATE_FILE).write_text(text)
    agent = Agent(small_config(), state_store=StateStore(tmp_path))
    outs = feed(agent, frames, start=len(frames[0]) * 4 // 5 + 77) + agent.finish()
    return agent, outs


def test_a_real_state_is_valid(saved):
    assert validate_state(saved, small_config().robot) is saved


def _nested(depth: int) -> str:
    return '{"version": 1, "joints": {"0": ' + '{"a": ' * depth + "1" + "}" * depth + "}}"


WHOLE_FILE_ATTACKS = {
    "not JSON": lambda s: "garbage \x00\xff",
    "truncated": lambda s: json.dumps(s)[: len(json.dumps(s)) // 2],
    "a list": lambda s: "[1, 2]",
    "no version": lambda s: json.dumps({k: v for k, v in s.items() if k != "version"}),
    "another robot": lambda s: json.dumps({**s, "robot": "robot-b"}),
    "last_emitted 1e308": lambda s: json.dumps({**s, "last_emitted": {"0": 1e308}}),
    "last_emitted huge int": lambda s: json.dumps({**s, "last_emitted": {"0": 10 ** 400}}),
    "last_emitted negative": lambda s: json.dumps({**s, "last_emitted": {"0": -3}}),
    "NaN literal deep inside": lambda s: json.dumps(s).replace('"mass": [', '"mass": [NaN, ', 1),
    "Infinity literal": lambda s: json.dumps({**s, "ingest": {"cycle": float("inf")}}),
    "joint key not an index": lambda s: json.dumps({**s, "joints": {"x": {}}}),
    "joint outside 0 … 63": lambda s: json.dumps({**s, "joints": {"99": {}}}),
    "nesting 100 000 deep": lambda s: _nested(100_000),
    "a list of 10⁶ numbers": lambda s: json.dumps({**s, "extra": [0] * 1_000_000}),
    "a 5,000-digit integer": lambda s: json.dumps(s).replace('"last_emitted": {', '"last_emitted": {"9": '
                                                              + "9" * 5000 + ", ", 1),    # stopped the agent
    "no ingest": lambda s: json.dumps({k: v for k, v in s.items() if k != "ingest"}),   # skipped every cycle
    "ingest null": lambda s: json.dumps({**s, "ingest": None}),
    "ingest without its cycle": lambda s: json.dumps({**s, "ingest": {**s["ingest"], "cycle": None}}),
    "ingest behind last_emitted": lambda s: json.dumps({**s, "ingest": {**s["ingest"], "cycle": 1}}),
}


@pytest.mark.parametrize("attack", WHOLE_FILE_ATTACKS, ids=list(WHOLE_FILE_ATTACKS))
def test_an_unusable_state_file_is_moved_aside_and_the_agent_relearns(attack, saved, frames, tmp_path, caplog):
    with caplog.at_level("WARNING"):
        agent, outs = _restart(tmp_path, WHOLE_FILE_ATTACKS[attack](saved), frames)
    aside = list(tmp_path.glob(f"{STATE_FILE}.rejected-*"))
    assert len(aside) == 1, "the unusable file is kept for inspection, under another name"
    assert agent.stats.states_rejected == 1 and agent.health().to_dict()["states_rejected"] == 1
    assert any("learning afresh" in r.getMessage() for r in caplog.records)
    assert outs and all(o.decisions["wear"].state == "learning" for o in outs)     # relearning from scratch
    agent.close()
    assert validate_state(json.loads((tmp_path / STATE_FILE).read_text()), agent.config.robot)   # a fresh one


@pytest.mark.parametrize("ingest", ["kept", "removed"])
def test_the_same_frames_again_onto_a_state_without_its_numbering_are_not_all_skipped(saved, frames, tmp_path,
                                                                                    ingest):
    """A state with published cycles (last_emitted) but no "ingest" once numbered the same frames replayed
    again from 0 and skipped every cycle as published: now it is moved aside (counted) and the frames are
    learned afresh; the whole state numbers them after the ones published, as before."""
    state = copy.deepcopy(saved)
    if ingest == "removed":
        del state["ingest"]
    (tmp_path / STATE_FILE).write_text(json.dumps(state))
    agent = Agent(small_config(), state_store=StateStore(tmp_path))
    outs = feed(agent, frames) + agent.finish()
    assert agent.stats.states_rejected == (ingest == "removed") and agent.stats.duplicate_cycles_skipped == 0
    assert {o.joint for o in outs} == {0, 1}
    first = min(o.cycle for o in outs)
    assert first == 0 if ingest == "removed" else first > max(saved["last_emitted"].values())


def _joint0(state: dict[str, Any], *path: str) -> dict[str, Any]:
    node = state["joints"]["0"]
    for key in path:
        node = node[key]
    return node


def _find(node: Any, key: str) -> list[dict[str, Any]]:
    """Every dict below ``node`` that has ``key``."""
    found = []
    if isinstance(node, dict):
        if key in node:
            found.append(node)
        for value in node.values():
            found += _find(value, key)
    elif isinstance(node, list):
        for value in node:
            found += _find(value, key)
    return found


JOINT_ATTACKS = {   # each breaks one model of joint 0 only; sizes that would allocate gigabytes first
    "kde n_grid 1e9": ("n_grid", 10 ** 9, "slices"),      # the load-compensated capture of a KL channel
    "glr window 1e9": ("window", 10 ** 9, "density"),
    "threshold a string": ("threshold", "x", "density"),
    "density covariance zero": ("cov", [[0.0]], "means"),
    "counter a list": ("count", [], "density"),
}


@pytest.mark.parametrize("attack", JOINT_ATTACKS, ids=list(JOINT_ATTACKS))
def test_a_joint_whose_models_do_not_load_relearns_alone(attack, saved, frames, tmp_path, caplog):
    key, value, sibling = JOINT_ATTACKS[attack]
    state = copy.deepcopy(saved)
    targets = [node for node in _find(state["joints"]["0"], key) if sibling in node]
    assert targets, f"the state has no {key!r} to corrupt"
    for node in targets:
        node[key] = value
    with caplog.at_level("WARNING"):
        agent, outs = _restart(tmp_path, json.dumps(state), frames)
    assert not list(tmp_path.glob(f"{STATE_FILE}.rejected-*"))
    # the broken model is relearned (the whole joint, or only that component when it loads alone)
    warnings = [r.getMessage() for r in caplog.records if r.levelname == "WARNING"]
    assert warnings and all(m.startswith("joint 0") and "relearning" in m for m in warnings), warnings
    assert agent.stats.joint_states_rejected == (1 if any("saved models unusable" in m for m in warnings) else 0)
    by_joint = {o.joint: o for o in outs}
    broken = "kl" if key == "n_grid" else "wear"      # the KL feature, or the detectors
    assert by_joint[0].decisions["wear"].state == ("monitoring" if broken == "kl" else "learning")
    assert by_joint[1].decisions["wear"].state == "monitoring"      # joint 1 keeps what it learned
    if broken == "kl":
        assert by_joint[0].to_dict()["kl"]["raw"] is None    # the KL monitor learns its nominal again


def test_validate_state_names_the_problem(saved):
    robot = small_config().robot
    with pytest.raises(StateError, match=r"last_emitted\[0\]"):
        validate_state({**saved, "last_emitted": {"0": MAX_CYCLE + 1}}, robot)
    with pytest.raises(StateError, match="robot 'robot-b'"):
        validate_state({**saved, "robot": "robot-b"}, robot)
    with pytest.raises(StateError, match="not one of 0 … 63"):
        validate_state({**saved, "joints": {"64": {}}}, robot)
    with pytest.raises(StateError, match=r"published cycles up to \d+ \(last_emitted\) but no cycle numbering"):
        validate_state({k: v for k, v in saved.items() if k != "ingest"}, robot)
    assert validate_state({**saved, "ingest": None, "last_emitted": {}}, robot)     # nothing published yet
    bad = copy.deepcopy(saved)
    _joint0(bad)["maintenances"] = math.nan
    with pytest.raises(StateError, match=r"state\.joints\.0\.maintenances: nan"):
        validate_state(bad, robot)


def _leaf_paths(node: Any, prefix: tuple = ()) -> list[tuple]:
    out: list[tuple] = []
    if isinstance(node, dict):
        for key, value in node.items():
            out.append(prefix + (key,))
            out += _leaf_paths(value, prefix + (key,))
    elif isinstance(node, list) and node and all(isinstance(v, dict | list) for v in node):
        for i, value in enumerate(node):
            out += _leaf_paths(value, prefix + (i,))
    return out


JSON_VALUES = st.one_of(st.none(), st.booleans(), st.integers(-10 ** 20, 10 ** 20),
                        st.floats(allow_nan=True, allow_infinity=True), st.text(max_size=5),
                        st.lists(st.floats(-1e3, 1e3), max_size=4), st.just({}), st.just("delete"))


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.data())
def test_any_single_corruption_is_survived(saved, frames, tmp_path_factory, data):
    """Fuzz: one value anywhere in a real state replaced by any JSON value (or deleted); the agent
    starts, processes the next cycle and publishes it — whatever it had to relearn."""
    paths = _leaf_paths(saved)
    path = data.draw(st.sampled_from(paths))
    value = data.draw(JSON_VALUES)
    state = copy.deepcopy(saved)
    node = state
    for key in path[:-1]:
        node = node[key]
    if value == "delete":
        del node[path[-1]]
    else:
        node[path[-1]] = value
    tmp = tmp_path_factory.mktemp("fuzz")
    agent, outs = _restart(tmp, json.dumps(state), frames)       # must not raise
    assert {o.joint for o in outs} == {0, 1}


def test_joints_no_longer_configured_are_dropped_and_the_others_kept(saved, frames, tmp_path, caplog):
    """`joints = [0]` after learning joints 0 and 1: joint 1's saved models are forgotten (a warning),
    joint 0 keeps monitoring — the file is not rejected."""
    (tmp_path / STATE_FILE).write_text(json.dumps(saved))
    with caplog.at_level("WARNING"):
        agent = Agent(small_config(joints=(0,)), state_store=StateStore(tmp_path))
        outs = feed(agent, frames, start=len(frames[0]) * 4 // 5 + 77) + agent.finish()
    assert not list(tmp_path.glob(f"{STATE_FILE}.rejected-*")) and agent.stats.states_rejected == 0
    assert any("joints ['1'] dropped" in r.getMessage() for r in caplog.records)
    assert {o.joint for o in outs} == {0} and outs[-1].decisions["wear"].state == "monitoring"


def test_a_state_file_this_user_cannot_read_is_an_error_not_a_rejection(saved, tmp_path, monkeypatch):
    """Permissions are the operator's to fix: the learned models must not be moved aside for it."""
    import edge_monitor.pipeline.state_store as store_module

    (tmp_path / STATE_FILE).write_text(json.dumps(saved))
    real_access = store_module.os.access
    monkeypatch.setattr(store_module.os, "access",
                        lambda path, mode: False if str(path).endswith(STATE_FILE) else real_access(path, mode))
    with pytest.raises(StateError, match="not readable and writable"):
        StateStore(tmp_path)
    assert (tmp_path / STATE_FILE).exists() and not list(tmp_path.glob(f"{STATE_FILE}.rejected-*"))


def test_two_rejections_in_one_second_keep_both_files(tmp_path):
    for text in ("first", "second"):
        (tmp_path / STATE_FILE).write_text(text)
        assert StateStore(tmp_path).load() is None
    assert sorted(p.read_text() for p in tmp_path.glob(f"{STATE_FILE}.rejected-*")) == ["first", "second"]


# -- issue 28: a state path that lies ------------------------------------------------------------------
@pytest.mark.parametrize("kind", ["symlink to /dev/zero", "symlink to /dev/urandom", "FIFO", "700 MB sparse file",
                                  "directory"])
def test_a_state_path_that_is_no_regular_file_or_too_large_is_moved_aside_unread(tmp_path, kind):
    """A symlink to /dev/zero or /dev/urandom, or a 700 MB file, took more than 1.5 GB; a FIFO blocked
    forever. Now each is moved aside after one fstat, and the agent learns afresh."""
    path = tmp_path / STATE_FILE
    if kind.startswith("symlink"):
        path.symlink_to(kind.split()[-1])
    elif kind == "FIFO":
        os.mkfifo(path)
    elif kind == "directory":
        path.mkdir()
    else:
        with open(path, "wb") as fh:
            fh.truncate(700 << 20)
    tracemalloc.start()
    store = StateStore(tmp_path)
    assert store.load() is None
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert store.rejected == 1 and peak < 8 << 20
    assert not os.path.lexists(path) and len(list(tmp_path.glob(f"{STATE_FILE}.rejected-*"))) == 1


@settings(max_examples=80, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.data())
def test_any_bytes_in_the_state_file_leave_an_agent_that_starts(saved, tmp_path_factory, data):
    """Byte-level fuzz of a real state file (bytes replaced, cut, inserted): the agent starts, with the
    state or without it (moved aside and counted) — never an exception."""
    raw = bytearray(json.dumps(saved).encode())
    for _ in range(data.draw(st.integers(1, 6))):
        at = data.draw(st.integers(0, len(raw) - 1))
        action = data.draw(st.sampled_from(["replace", "cut", "insert"]))
        if action == "replace":
            raw[at] = data.draw(st.integers(0, 255))
        elif action == "cut":
            del raw[at:at + data.draw(st.integers(1, 200))]
        else:
            raw[at:at] = data.draw(st.sampled_from([b"9" * 40, b"[", b"{", b"NaN", b"\xff", b"1e400", b'"', b"\\"]))
    folder = tmp_path_factory.mktemp("bytes")
    (folder / STATE_FILE).write_bytes(bytes(raw))
    agent = Agent(small_config(), state_store=StateStore(folder))
    assert agent.stats.states_rejected in (0, 1)
    assert agent.health().counters["states_rejected"] == agent.stats.states_rejected
    agent.close()                      # and it saves a state it can read again
    assert StateStore(folder).load() is not None
