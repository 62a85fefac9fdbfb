"""Issue 50, tried as an integrator would: an output path in a folder that does not exist is refused (a
typo never makes a directory tree), `commission` says when its data cannot identify the eleven
parameters, the summary table marks a cut alarms column, and the help a wheel user reads explains its
docs/ references once and names no source-tree folder."""

from __future__ import annotations

import json
import subprocess
import sys
import tomllib
from pathlib import Path

import numpy as np
import pytest
from test_commissioning import nominal_dataset, write_csv

from edge_monitor.cli import build_parser
from edge_monitor.commands.common import summary_table
from edge_monitor.offline.commissioning import make_data
from edge_monitor.pipeline.decision_config import DecisionConfig
from protocol.console import DOCS_NOTE, subcommands

ROOT = Path(__file__).resolve().parents[1]
BLF = ROOT / "tests" / "corpus" / "clean.blf"


def _edge(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "edge_monitor.cli", *args], cwd=cwd, capture_output=True, text=True,
                          timeout=300)


@pytest.mark.parametrize("args, code", [
    (["replay", str(BLF), "--jsonl", "typo/a/s.jsonl"], 1),
    (["replay", str(BLF), "--state-dir", "typo/b/state"], 1),
    (["replay", str(BLF), "--rerun", "save:typo/c/x.rrd"], 1),
    (["demo", "--out", "typo/d/demo"], 2),
    (["export-trace", str(BLF), "--out", "typo/e/t.csv"], 2),
])
def test_an_output_in_a_missing_folder_is_refused_and_no_folder_is_made(tmp_path, args, code):
    done = _edge(*args, "-q", cwd=tmp_path)
    assert done.returncode == code, done.stderr
    assert "does not exist" in done.stderr and "Traceback" not in done.stderr
    assert len(done.stderr.strip().splitlines()) <= 6 and not (tmp_path / "typo").exists()


def test_a_state_directory_is_made_inside_a_folder_that_exists(tmp_path):
    done = _edge("replay", str(BLF), "--state-dir", "state", "-q", cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    assert (tmp_path / "state" / "agent_state.json").is_file()


def test_commission_warns_when_its_data_cannot_identify_the_model(tmp_path):
    """The README's example fitted 11 parameters to 16 points without a word; now it warns, and says so
    in the report and the TOML it writes. Well-spread data (480 points) gives no warning."""
    data = nominal_dataset(3)
    write_csv(tmp_path / "full.csv", data)
    pick = np.random.default_rng(0).choice(data.n, 16, replace=False)
    write_csv(tmp_path / "few.csv", make_data(data.speed[pick], data.temperature[pick], data.load[pick],
                                              data.friction[pick]))
    full = _edge("commission", "full.csv", "--report", "full.json", cwd=tmp_path)
    assert full.returncode == 0 and "WARNING" not in full.stderr, full.stderr
    assert json.loads((tmp_path / "full.json").read_text())["identified"] is True
    few = _edge("commission", "few.csv", "--report", "few.json", "-o", "few.toml", cwd=tmp_path)
    assert few.returncode == 0 and "WARNING: 16 points for 11 parameters" in few.stderr, few.stderr
    report = json.loads((tmp_path / "few.json").read_text())
    assert report["identified"] is False and "16 points" in report["warning"]
    text = (tmp_path / "few.toml").read_text()
    assert text.startswith("# WARNING (edge-monitor commission): 16 points") and tomllib.loads(text)["friction"]


def test_the_summary_table_marks_a_cut_alarms_column():
    stats = {"alarms": [{"joint": 1, "quantity": "kl_weighted", "cycle": 100 + i} for i in range(6)]}
    table = summary_table({1: {"cycle": 5, "wear": {}, "decisions": {}}}, stats, DecisionConfig())
    row = table.splitlines()[1]
    assert "kl_weighted@100, kl_weighted@101, kl_weight…" in row
    short = summary_table({1: {"cycle": 5, "wear": {}, "decisions": {}}}, {"alarms": stats["alarms"][:1]},
                          DecisionConfig())
    assert "kl_weighted@100 " in short.splitlines()[1] and "…" not in short


def test_help_explains_docs_references_once_and_names_no_source_folder():
    parser = build_parser()
    for name, sub in {"edge-monitor": parser, **subcommands(parser)}.items():
        text = sub.format_help()
        assert "protocol/mappings" not in text and "tests/" not in text, name
        if "docs/" in text.replace(DOCS_NOTE, ""):
            assert text.count(DOCS_NOTE.split(";")[0]) == 1, name
