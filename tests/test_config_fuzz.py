"""Fuzz of the agent's config loading (issue #12): any value for any key, and any text as a TOML
file, gives either a valid configuration or a ConfigError naming the field — never another
exception, and no accepted size beyond its bound."""

from __future__ import annotations

import copy
import re
import tomllib
from importlib import resources
from typing import Any

import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from edge_monitor.config import config_from_mapping, load_config
from edge_monitor.errors import ConfigError
from edge_monitor.stats.glr import MAX_WINDOW
from edge_monitor.stats.kde_stream import MAX_GRID

DEFAULTS = tomllib.loads(resources.files("edge_monitor").joinpath("defaults/agent.toml").read_text())


def _paths(table: dict[str, Any], prefix: tuple[str, ...] = ()) -> list[tuple[str, ...]]:
    out = []
    for key, value in table.items():
        out.append(prefix + (key,))
        if isinstance(value, dict):
            out += _paths(value, prefix + (key,))
    return out


PATHS = _paths(DEFAULTS) + [("joints",), ("robot",), ("status_interval_s",), ("no_such_key",), ("state_dir",),
                            ("jsonl",)]
VALUES = st.one_of(st.none(), st.booleans(), st.integers(-10 ** 30, 10 ** 30), st.sampled_from([10 ** 400, -10 ** 400]),
                   st.floats(allow_nan=True, allow_infinity=True), st.text(max_size=8),
                   st.lists(st.integers(-5, 100), max_size=5), st.dictionaries(st.text(max_size=3), st.integers(),
                                                                              max_size=2))


@settings(max_examples=400, deadline=None)
@given(path=st.sampled_from(PATHS), value=VALUES)
@example(path=("segmentation",), value={"\n": 0})    # found by CI: the key was echoed raw, splitting the line
@example(path=("joint",), value={"\u00b2": 0})       # "²".isdigit() is True, int("²") raises
@example(path=("segmentation", "tolerance_abs"), value=10 ** 400)   # beyond a float: OverflowError
@example(path=("decision", "arl0_cycles"), value=10 ** 400)
def test_any_value_for_any_key_is_accepted_within_bounds_or_refused_by_name(path, value):
    doc = copy.deepcopy(DEFAULTS)
    node = doc
    for key in path[:-1]:
        node = node.setdefault(key, {})
    if value is None:
        node.pop(path[-1], None)
    else:
        node[path[-1]] = value
    try:
        cfg = config_from_mapping(doc)
    except ConfigError as exc:
        assert str(exc) and "\n" not in str(exc).strip()
        return
    assert 1 <= cfg.decision.window <= MAX_WINDOW
    assert 64 <= cfg.kl.n_grid <= MAX_GRID
    assert cfg.joints is None or 0 < len(cfg.joints) <= 64
    assert all(p is None or (isinstance(p, str) and p.strip() and "\0" not in p) for p in (cfg.state_dir, cfg.jsonl))


@pytest.mark.parametrize("key", ["state_dir", "jsonl"])
@pytest.mark.parametrize(("value", "says"), [
    (5, "expected a path (text), got 5"), (["a"], "expected a path (text), got ['a']"), (True, "got True"),
    ("", "expected a path (text), got ''"), ({"a": 1}, "got {'a': 1}"), ("a\0b", "holds a NUL character"),
])
def test_a_path_valued_key_that_is_no_path_is_refused_by_name(key, value, says):
    """``state_dir = 5`` was a TypeError traceback (``["a"]`` too), ``jsonl = 5`` wrote to a file named 5.0."""
    with pytest.raises(ConfigError, match=re.escape(f"config.{key}: ") + ".*" + re.escape(says)):
        config_from_mapping({key: value})
    assert getattr(config_from_mapping({key: "out/x"}), key) == "out/x"
    assert getattr(config_from_mapping({}), key) is None


@settings(max_examples=100, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(text=st.text(max_size=200))
def test_any_text_as_a_config_file_loads_or_is_refused(tmp_path, text):
    path = tmp_path / "agent.toml"
    path.write_text(text, encoding="utf-8")
    try:
        load_config(path)
    except ConfigError as exc:
        assert str(path) in str(exc) or ":" in str(exc)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(depth=st.integers(1, 6000), kind=st.sampled_from(["array", "table", "dotted"]))
def test_a_config_nested_to_any_depth_loads_or_is_a_config_error(tmp_path, depth, kind):
    """5,000 levels was a RecursionError (exit 1, not a configuration error)."""
    import hostile_files
    text = ("[" + ".".join(["a"] * depth) + "]\nb = 1\n" if kind == "dotted"
            else hostile_files.deep_toml(depth, kind))
    path = tmp_path / "deep.toml"
    path.write_text(text)
    try:
        load_config(path)
    except ConfigError as exc:
        assert "\n" not in str(exc)
