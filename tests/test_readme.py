"""The README's command blocks run as written: each ```sh block is executed with bash, in order, in one
scratch folder (later blocks use the files of earlier ones), with `.venv/bin/` meaning this installation
and the loopback ports moved to free ones. A block that cannot run here says why in a
`<!-- readme-test: skip — REASON -->` comment right above it (e.g. it needs hardware)."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import tempfile
from pathlib import Path

import pytest

from edge_monitor.sinks.loopback import free_loopback_port

pytestmark = [pytest.mark.slow, pytest.mark.timeout(1800)]

README = Path(__file__).resolve().parents[1] / "README.md"
BLOCK = re.compile(r"(?:<!-- readme-test: skip — (?P<reason>[^>]+?) -->\n)?```sh\n(?P<code>.*?)```", re.S)
PORTS = ("7500", "7448")        # the loopback ports the README uses


def blocks() -> list[tuple[str | None, str]]:
    return [(m["reason"], m["code"]) for m in BLOCK.finditer(README.read_text(encoding="utf-8"))]


def test_every_block_is_run_or_says_why_not():
    found = blocks()
    assert found and all(reason is None or len(reason) > 10 for reason, _ in found)
    assert sum(reason is None for reason, _ in found) >= 3


def test_the_readme_commands_run_as_written(tmp_path):
    bin_dir = str(Path(sys.executable).parent) + "/"
    ports = {port: str(free_loopback_port()) for port in PORTS}
    for index, (reason, code) in enumerate(blocks()):
        if reason is not None:
            continue
        script = code.replace(".venv/bin/", bin_dir)
        for old, new in ports.items():
            script = re.sub(rf"\b{old}\b", new, script)
        returncode, output = _run_block(script, tmp_path)
        assert returncode == 0, f"README block {index} failed (exit {returncode}):\n{code}\n{output[-4000:]}"
        assert "Traceback" not in output, output[-4000:]
    symptoms = (tmp_path / "symptoms.jsonl").read_text().splitlines()
    assert len(symptoms) == 80 and '"utc":"2026-11-18T' in symptoms[0]    # 40 cycles, 2 joints, wall time
    assert len((tmp_path / "seen.jsonl").read_text().splitlines()) == 4
    assert "[friction]" in (tmp_path / "friction.toml").read_text()


def _run_block(script: str, cwd: Path) -> tuple[int, str]:
    """Run one block with bash in a process group of its own; whatever it left running is ended after it.
    The output goes to a file, not a pipe: a background job a failed block left behind would otherwise hold
    the pipe open and the test would wait for it until its timeout instead of reporting the failure."""
    with tempfile.TemporaryFile(mode="w+", encoding="utf-8", errors="replace") as out:
        proc = subprocess.Popen(["bash", "-e", "-c", script], cwd=cwd, stdout=out, stderr=subprocess.STDOUT,
                                text=True, stdin=subprocess.DEVNULL, start_new_session=True)
        try:
            proc.wait(timeout=1500)
        finally:
            try:
                os.killpg(proc.pid, signal.SIGTERM)
            except ProcessLookupError:
                pass
            if proc.poll() is None:
                proc.kill()
                proc.wait()
        out.seek(0)
        return proc.returncode, out.read()
