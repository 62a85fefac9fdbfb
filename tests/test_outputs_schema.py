"""docs/OUTPUTS.md's symptom-record table against records the agent really produces: every field of a
record is documented, every documented field (unless marked optional) occurs in a record."""

from __future__ import annotations

import itertools
import json
import re
from pathlib import Path

import pytest

from edge_monitor.features.joint_model_learning import ModelConfig
from edge_monitor.features.kl_monitor import KLConfig
from edge_monitor.features.segmentation import PlateauConfig
from edge_monitor.features.wear import WearConfig
from edge_monitor.pipeline.agent import Agent
from edge_monitor.pipeline.agent_config import AgentConfig
from edge_monitor.pipeline.detectors import DecisionConfig
from edge_monitor.records import to_json

from synthetic_frames import make_frames

OUTPUTS = Path(__file__).resolve().parents[1] / "docs" / "OUTPUTS.md"
SPEEDS = (8.7, 41.7, 133.5)
LEAF_OBJECTS = ("skipped", "reasons")      # keyed by free-form names: documented as a whole


def documented_fields() -> dict[str, bool]:
    """``{field path: optional}`` from the table under "#### Symptom record fields"."""
    text = OUTPUTS.read_text(encoding="utf-8")
    section = text.split("#### Symptom record fields", 1)[1]
    rows = [line for line in section.split("\n\n", 3)[2].splitlines() if line.startswith("| `")]
    assert rows, "no field table found in docs/OUTPUTS.md"
    fields: dict[str, bool] = {}
    for row in rows:
        names, kind = row.split("|")[1:3]
        for name in re.findall(r"`([^`]+)`", names):
            for path in _expand(name):
                fields[path] = "optional" in kind
    return fields


def _expand(name: str) -> list[str]:
    """``a.{b,c}.{d,e}`` → the four paths."""
    parts = re.split(r"(\{[^}]*\})", name)
    choices = [p[1:-1].split(",") if p.startswith("{") else [p] for p in parts]
    return ["".join(combination) for combination in itertools.product(*choices)]


def record_fields(record: dict, prefix: str = "") -> set[str]:
    """Dotted paths of a record's leaves; ``decisions.<q>`` for every quantity."""
    out = set()
    for key, value in record.items():
        path = f"{prefix}{key}"
        if prefix in ("decisions.", "coverage."):
            path = prefix + "<q>"
        if isinstance(value, dict) and path not in LEAF_OBJECTS:
            out |= record_fields(value, path + ".")
        else:
            out.add(path)
    return out


def agent_records(pf: float | None = None) -> list[dict]:
    """Published symptom records (strict JSON, as on Zenoh and in JSONL) of a short synthetic run:
    learning cycles, then monitoring ones."""
    config = AgentConfig(segmentation=PlateauConfig(speeds=SPEEDS), kl=KLConfig(n_nominal_cycles=2),
                         model=ModelConfig(enabled=False), wear=WearConfig(prior_cycles=3),
                         decision=DecisionConfig(n_nominal=3, density="gauss", calibration_draws=16,
                                                 calibration_steps=400, pf=pf,
                                                 quantities=("wear", "kl_raw", "kl_weighted")))
    ids, data, dlc, ts = make_frames(7, joints=(0, 1), speeds=SPEEDS, wear=lambda j, c: 30.0 * j, seed=1)
    agent = Agent(config)
    symptoms = agent.update(ids, data, dlc, ts) + agent.finish()
    return [json.loads(to_json(symptom.to_dict())) for symptom in symptoms]


@pytest.fixture(scope="module")
def records() -> list[dict]:
    return agent_records() + agent_records(pf=0.01)


def test_every_field_of_a_real_record_is_documented(records):
    documented = documented_fields()
    seen = set().union(*(record_fields(r) for r in records))
    assert seen - set(documented) == set(), "fields the records carry that docs/OUTPUTS.md does not list"


def test_every_documented_field_occurs_in_a_real_record(records):
    documented = documented_fields()
    seen = set().union(*(record_fields(r) for r in records))
    required = {name for name, optional in documented.items() if not optional}
    assert required - seen == set(), "fields docs/OUTPUTS.md lists that no record carries"
    optional_seen = {name for name, optional in documented.items() if optional} & seen
    assert {"reasons", "decisions.<q>.reason", "decisions.<q>.calibration.pf",
            "kl.threshold_3sigma.raw"} <= optional_seen
    assert {"load.mean", "load.std", "skipped", "critical_wear"} <= seen


def test_the_documented_example_is_a_record_of_the_table():
    text = OUTPUTS.read_text(encoding="utf-8")
    example = text.split("Symptom record (`\"schema\": 1`)", 1)[1].split("```json", 1)[1].split("```", 1)[0]
    record = json.loads(example.replace(', "...": {}', ""))
    assert record_fields(record) <= set(documented_fields())
