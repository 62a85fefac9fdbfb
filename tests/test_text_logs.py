"""Text logs read as hostile (edge_monitor/sources/text_logs.py): gzip-compressed logs cut short or bombed,
PCAN traces (.trc) with bad lines or cut short, BLF headers that lie, and files in which nothing is readable.

Each finding of the attack pass is checked on both sides: the bad input is reported (a counted drop, a
``truncated`` reason or one error line with exit 1), and the intact input still reads whole.
"""

from __future__ import annotations

import gzip
import json
import subprocess
import sys
import tracemalloc
from pathlib import Path

import can
import hostile_files as hostile
import pytest
from hypothesis import given
from hypothesis import strategies as st

from edge_monitor.sources.log_source import LogReadError, LogReport, log_blocks_with_position
from edge_monitor.sources.text_logs import MAX_LINE_BYTES, TextLines
from sim_controller.config import SimConfig
from sim_controller.output import record

CYCLES = 3


@pytest.fixture(scope="module")
def logs(tmp_path_factory) -> dict[str, Path]:
    """The same 3-cycle run as .log, .asc, .blf and .trc (written by python-can from the .blf)."""
    folder = tmp_path_factory.mktemp("text_logs")
    out = {suffix: folder / f"run.{suffix}" for suffix in ("log", "asc", "blf")}
    for path in out.values():
        record(SimConfig(joints=2, cycles=CYCLES, seed=5), path)
    out["trc"] = folder / "run.trc"
    writer = can.Logger(str(out["trc"]))
    for msg in can.LogReader(str(out["blf"])):
        writer.on_message_received(msg)
    writer.stop()
    return out


@pytest.fixture(scope="module")
def complete(logs, tmp_path_factory) -> list[dict]:
    """The symptoms a replay of the complete .log publishes."""
    code, _, _, symptoms = replay(logs["log"], tmp_path_factory.mktemp("complete"))
    assert code == 0 and len(symptoms) == 2 * CYCLES
    return symptoms


def read_all(path: Path) -> tuple[int, LogReport]:
    report = LogReport()
    frames = sum(len(block[0]) for block, _ in log_blocks_with_position(path, 4096, report))
    return frames, report


def replay(path: Path, tmp: Path) -> tuple[int, dict, str, list[dict]]:
    """Exit code, ``--json`` summary, stderr and symptom records of ``edge-monitor replay``."""
    jsonl = tmp / f"{path.name}.jsonl"
    proc = subprocess.run([sys.executable, "-m", "edge_monitor.cli", "replay", str(path), "--json",
                           "--jsonl", str(jsonl)], capture_output=True, text=True, timeout=600)
    assert "Traceback" not in proc.stderr
    summary = json.loads(proc.stdout) if proc.stdout.strip() else {}
    records = jsonl.read_text().splitlines() if jsonl.exists() else []
    return proc.returncode, summary, proc.stderr, [r for r in map(json.loads, records) if "kind" not in r]


def assert_cut_cycle_left_open(symptoms: list[dict], complete: list[dict]) -> None:
    """The cycles before the cut are published as from the complete log; the cut one is not."""
    cycles = sorted({s["cycle"] for s in symptoms})
    assert 1 <= len(cycles) < CYCLES and cycles == list(range(len(cycles)))
    expected = {(s["joint"], s["cycle"]): s["friction"] for s in complete}
    assert all(s["friction"] == expected[(s["joint"], s["cycle"])] for s in symptoms)


# -- gzip-compressed logs ---------------------------------------------------------------------------------


@pytest.mark.parametrize("suffix", ["log", "asc"])
def test_a_compressed_log_cut_short_is_truncated_not_a_hang(logs, complete, tmp_path, suffix):
    """A .log.gz / .asc.gz cut short once ran forever: gzip raised EOFError at the same place again and again."""
    clean, _ = read_all(logs[suffix])
    whole = tmp_path / f"run.{suffix}.gz"
    whole.write_bytes(gzip.compress(logs[suffix].read_bytes()))
    frames, report = read_all(whole)
    assert frames == clean and report.truncated is None and report.skipped == 0
    cut = tmp_path / f"cut.{suffix}.gz"
    cut.write_bytes(whole.read_bytes()[: whole.stat().st_size // 2])
    frames, report = read_all(cut)
    assert 0 < frames < clean and report.truncated.startswith("compressed stream ends early")
    code, summary, _, symptoms = replay(cut, tmp_path)
    assert code == 0 and summary["log"]["truncated"].startswith("compressed stream ends early")
    assert_cut_cycle_left_open(symptoms, complete)


def test_a_gzip_bomb_line_is_read_in_bounded_memory(tmp_path):
    """8 MiB of NUL bytes in 8 KiB of gzip: one line skipped in pieces, never held whole; the lines after it read."""
    bomb = tmp_path / "bomb.log.gz"
    bomb.write_bytes(gzip.compress(b"(0.0) can0 123#00\n" + b"\0" * (8 << 20) + b"\n(0.1) can0 123#01\n"))
    report = LogReport()
    tracemalloc.start()
    try:
        lines = list(TextLines(bomb, report))
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert lines == ["(0.0) can0 123#00\n", "(0.1) can0 123#01\n"] and report.skipped == 1
    assert peak < 64 * MAX_LINE_BYTES + (1 << 20)


# -- PCAN traces ------------------------------------------------------------------------------------------


def test_a_trace_reads_the_same_frames_as_the_other_formats(logs):
    trc, report = read_all(logs["trc"])
    assert trc == read_all(logs["blf"])[0] and report.skipped == 0 and report.truncated is None


def test_bad_trace_lines_are_skipped_and_counted(logs, tmp_path):
    """A non-UTF-8 byte stopped the trace as "truncated" (0 skipped); lines python-can cannot parse were
    dropped uncounted. A status record (ST) is no frame and no damage."""
    clean, _ = read_all(logs["trc"])
    lines = logs["trc"].read_bytes().splitlines(keepends=True)
    at = [i for i, line in enumerate(lines) if b" DT " in line][len(lines) // 2]
    lines[at] = lines[at][:10] + b"\xff" + lines[at][11:]                       # costs its own frame
    lines[at + 5: at + 5] = [b"hello world\r\n", b"    7    1.000 XX  1  0100 Rx -  8  00\r\n",
                             b"    8    1.000 DT  1  zz Rx -  8  00\r\n", b"    9    1.000 ST  1  - Rx -  0\r\n"]
    damaged = tmp_path / "bad.trc"
    damaged.write_bytes(b"".join(lines))
    frames, report = read_all(damaged)
    assert frames == clean - 1 and report.truncated is None
    assert report.skipped == report.frames_skipped == 4, report.examples


def test_a_trace_cut_short_is_truncated_and_its_cut_cycle_not_published(logs, complete, tmp_path):
    data = logs["trc"].read_bytes()
    cut = tmp_path / "cut.trc"
    cut.write_bytes(data[: len(data) * 2 // 3 + 7])        # mid-line, mid-cycle
    _, report = read_all(cut)
    assert report.truncated == "the last line has no line end"
    code, summary, _, symptoms = replay(cut, tmp_path)
    assert code == 0 and summary["log"]["truncated"]
    assert_cut_cycle_left_open(symptoms, complete)


def test_an_overlong_trace_line_is_skipped_in_pieces(logs, tmp_path):
    lines = logs["trc"].read_bytes().splitlines(keepends=True)
    damaged = tmp_path / "long.trc"
    damaged.write_bytes(b"".join(lines[:40] + [b"\0" * (1 << 20) + b"\r\n"] + lines[40:]))
    frames, report = read_all(damaged)
    assert frames == read_all(logs["trc"])[0] and report.skipped == 1


# -- BLF headers that lie ---------------------------------------------------------------------------------


@pytest.mark.parametrize("header_size", [0x74C09C90, 40])
def test_a_blf_header_size_the_file_cannot_have_is_a_clear_error(logs, tmp_path, header_size):
    """A header size beyond the file made python-can read the whole file as header: 0 frames, exit 0, no word."""
    raw = bytearray(logs["blf"].read_bytes())
    raw[4:8] = header_size.to_bytes(4, "little")
    damaged = tmp_path / "header.blf"
    damaged.write_bytes(bytes(raw))
    with pytest.raises(LogReadError, match="damaged BLF header: header size"):
        read_all(damaged)
    code, _, err, _ = replay(damaged, tmp_path)
    assert code == 1 and "damaged BLF header" in err and len(err.strip().splitlines()) == 1
    assert read_all(logs["blf"])[0] > 0                                  # the intact header still reads


# -- nothing readable -------------------------------------------------------------------------------------


def _not_a_log(kind: str, logs: dict[str, Path], folder: Path) -> Path:
    if kind == "random.trc":
        (folder / kind).write_bytes(hostile.with_garbage_lines(b"\n" * 8, 60, seed=3)[0])
    elif kind == "candump.asc":
        (folder / kind).write_bytes(logs["log"].read_bytes()[:20000])
    elif kind == "candump.asc.gz":
        (folder / kind).write_bytes(gzip.compress(logs["log"].read_bytes()[:20000]))
    else:                                                   # a sparse file: one endless line of NUL bytes
        with open(folder / kind, "wb") as f:
            f.truncate(1 << 20)
    return folder / kind


@pytest.mark.parametrize("kind", ["random.trc", "candump.asc", "candump.asc.gz", "sparse.trc"])
def test_a_text_log_in_which_nothing_is_readable_is_a_failure(logs, tmp_path, kind):
    """Exit 0 with 0 frames for .asc, .trc and .asc.gz, where .log and .blf said "is it a CAN log?"."""
    code, summary, err, _ = replay(_not_a_log(kind, logs, tmp_path), tmp_path)
    assert code == 1 and summary["frames_total"] == 0
    assert f"nothing in {tmp_path / kind} is readable" in err and "is it a CAN log?" in err


def test_a_readable_compressed_log_is_no_failure(logs, tmp_path):
    """The other side: a whole gzip-compressed .log replays every cycle, exit 0."""
    packed = tmp_path / "run.log.gz"
    packed.write_bytes(gzip.compress(logs["log"].read_bytes()))
    code, summary, err, symptoms = replay(packed, tmp_path)
    assert code == 0 and summary["cycles"] == CYCLES and "is it a CAN log?" not in err
    assert summary["log"]["truncated"] is None and len(symptoms) == 2 * CYCLES


def test_a_compressed_blf_reads_whole_and_a_cut_one_is_truncated(logs, tmp_path):
    """A .blf.gz is judged by what it unpacks to, not by its size on disk (which is smaller than the BLF header's
    file size: a complete one was reported truncated and its last frames dropped); cut short, it is truncated."""
    whole_frames, _ = read_all(logs["blf"])
    packed = tmp_path / "run.blf.gz"
    packed.write_bytes(gzip.compress(logs["blf"].read_bytes()))
    frames, report = read_all(packed)
    assert (frames, report.truncated, report.skipped) == (whole_frames, None, 0)
    cut = tmp_path / "cut.blf.gz"
    cut.write_bytes(packed.read_bytes()[: packed.stat().st_size // 2])
    frames, report = read_all(cut)
    assert 0 < frames < whole_frames and report.truncated


# ------------------------------------------------------------------------------------------ property
class _Count:
    """A report that counts skipped lines (:class:`edge_monitor.sources.text_logs.Report`)."""

    def __init__(self) -> None:
        self.frames, self.skipped = 0, 0

    def skip(self, reason: str, frames: int = 1) -> None:
        self.skipped += frames


_LINE = st.one_of(
    st.text(st.characters(blacklist_categories=("Cs",), blacklist_characters="\r\n\x0b\x0c\x1c\x1d\x1e\x85\u2028\u2029"),
            max_size=60).map(lambda t: ("ok", t.encode("utf-8"))),
    st.binary(min_size=1, max_size=8).map(lambda b: ("bad", b"x" + b"\xff" + b.replace(b"\n", b"."))),
    st.integers(MAX_LINE_BYTES + 1, 3 * MAX_LINE_BYTES).map(lambda n: ("long", b"y" * n)),
)


@given(lines=st.lists(_LINE, max_size=12), gz=st.booleans())
def test_every_line_is_either_read_as_written_or_counted(tmp_path_factory, lines, gz):
    """Any mix of text lines, lines with an undecodable byte and overlong lines, plain or gzip-compressed:
    each valid line comes out as written, in order; every other one is counted once; nothing else comes out."""
    path = tmp_path_factory.mktemp("lines") / ("t.log.gz" if gz else "t.log")
    content = b"".join(raw + b"\n" for _, raw in lines)
    path.write_bytes(gzip.compress(content) if gz else content)
    report = _Count()
    reader = TextLines(path, report)
    try:
        read = list(reader)
        cut = reader.cut_short(asc=False)
    finally:
        reader.close()
    assert read == [raw.decode("utf-8") + "\n" for kind, raw in lines if kind == "ok"]
    assert report.skipped == sum(kind != "ok" for kind, _ in lines)
    assert cut is None
