"""The adversarial corpus (tests/corpus/README.md), each file through the real command as a user runs
it: the documented exit code and message, no traceback, within a time limit and bounded memory."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import hostile_files as hostile
import pytest

CORPUS = Path(__file__).resolve().parent / "corpus"


def _replay(*args: str) -> list[str]:
    return hostile.edge_monitor("replay", *args)


def _log(run: hostile.Run) -> dict:
    return json.loads(run.stdout)["log"]


CASES = {
    # name: (command (files of the corpus as {c}, a scratch folder as {t}), exit code, check)
    "bad_byte.log": (_replay("{c}/bad_byte.log", "--json"), 0,
                     lambda r: _log(r)["frames"] == 799 and _log(r)["skipped_records"] == 1),
    "bad_byte.asc": (_replay("{c}/bad_byte.asc", "--json"), 0,
                     lambda r: _log(r)["frames"] == 799 and _log(r)["skipped_records"] == 1),
    "garbage_lines.log": (_replay("{c}/garbage_lines.log", "--json"), 0,
                          lambda r: _log(r)["frames"] == 800 and _log(r)["skipped_records"] == 40),
    "garbage_lines.asc": (_replay("{c}/garbage_lines.asc", "--json"), 0, lambda r: _log(r)["frames"] == 800),
    "zlib_bomb.blf": (_replay("{c}/zlib_bomb.blf", "--json"), 0,
                      lambda r: _log(r)["skipped_records"] == 1 and _log(r)["frames"] >= 2457
                      and "inflates past" in _log(r)["skip_examples"][0]),
    "object_size_ffffffff.blf": (_replay("{c}/object_size_ffffffff.blf", "--json"), 0,
                                 lambda r: "4294967295" in _log(r)["truncated"] and 0 < _log(r)["frames"] < 2458),
    "inner_object_size_zero.blf": (_replay("{c}/inner_object_size_zero.blf", "--json"), 0,
                                   lambda r: _log(r)["frames"] == 2458 and _log(r)["skipped_records"] >= 1),
    "state_5000_digit_integer.json": (_replay("{c}/clean.blf", "--state-dir", "{t}/state"), 0,
                                      lambda r: "moved it to agent_state.json.rejected" in r.stderr),
    "state_nested_5000.json": (_replay("{c}/clean.blf", "--state-dir", "{t}/state"), 0,
                               lambda r: "moved it to agent_state.json.rejected" in r.stderr),
    "config_nested_5000.toml": (_replay("{c}/clean.blf", "--config", "{c}/config_nested_5000.toml"), 2,
                                lambda r: "nested too deeply" in r.stderr),
    "config_inline_tables_5000.toml": (_replay("{c}/clean.blf", "--config", "{c}/config_inline_tables_5000.toml"),
                                       2, lambda r: "nested too deeply" in r.stderr),
    "jsonl_unhashable_joint.jsonl": (_replay("{c}/clean.blf", "--jsonl", "{t}/s.jsonl"), 0,
                                     lambda r: "no symptom record of this agent" in r.stderr),
    "jsonl_hostile_tail.jsonl": (_replay("{c}/clean.blf", "--jsonl", "{t}/s.jsonl"), 0,
                                 lambda r: "torn line" in r.stderr and "no symptom record" in r.stderr),
    "fit_weights_sample_1e11.csv": (hostile.edge_monitor("fit-weights", "--healthy", "{c}/fit_weights_sample_1e11.csv",
                                                         "--faulty", "{c}/fit_weights_sample_1e11.csv"), 2,
                                    lambda r: "check the sample column" in r.stderr),
}


def test_the_corpus_and_its_table_agree():
    listed = {line.split("`")[1] for line in (CORPUS / "README.md").read_text().splitlines()
              if line.startswith("| `")}
    on_disk = {p.name for p in CORPUS.iterdir() if p.suffix not in (".py", ".md")}
    assert set(CASES) <= on_disk and on_disk - {"clean.blf", "clean.log", "clean.asc"} <= set(CASES)
    assert all(any(name in line for line in (CORPUS / "README.md").read_text().splitlines()) for name in on_disk)
    assert listed


@pytest.mark.parametrize("name", CASES, ids=list(CASES))
def test_each_hostile_file_gets_its_documented_answer(name, tmp_path):
    args, code, check = CASES[name]
    if name.startswith("state_"):
        (tmp_path / "state").mkdir()
        shutil.copy(CORPUS / name, tmp_path / "state" / "agent_state.json")
    if name.startswith("jsonl_"):
        shutil.copy(CORPUS / name, tmp_path / "s.jsonl")
    run = hostile.run_measured([a.format(c=CORPUS, t=tmp_path) for a in args], timeout=300)
    assert not run.timed_out and run.returncode == code, run.stderr[-3000:]
    assert "Traceback" not in run.stderr and check(run), run.stdout[-2000:] + run.stderr[-3000:]
    assert run.max_rss_mb < 800, run.max_rss_mb
    if name.startswith("jsonl_"):           # the file is JSON Lines again at its end: whole lines
        assert (tmp_path / "s.jsonl").read_bytes().endswith(b"\n")
