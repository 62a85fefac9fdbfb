#!/usr/bin/env python3
"""Run every benchmark (tools/bench_*.py) and assemble docs/BENCHMARKS.md from docs/benchmarks/*.md.

    .venv/bin/python tools/bench_all.py            # run all, then assemble
    .venv/bin/python tools/bench_all.py --assemble # only assemble the existing sections

Peers compared against (KDEpy, river) come with `pip install -e '.[bench]'`.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
ORDER = ["protocol", "sim", "agent", "wear", "kde", "glr"]
HEADER = """# Benchmarks

Speed goals are measured here, never asserted in unit tests. Every figure is a ratio against a
baseline run in the same process (or the same command), because the build machine is shared and
noisy (2 cores). Re-run with `make bench` (or `.venv/bin/python tools/bench_all.py`); each section
below is written by its script into `docs/benchmarks/<topic>.md`.

"""


def assemble() -> str:
    parts = [HEADER]
    sections = {p.stem: p for p in (ROOT / "docs" / "benchmarks").glob("*.md")}
    for name in ORDER + sorted(set(sections) - set(ORDER)):
        if name in sections:
            parts.append(sections[name].read_text().strip() + "\n\n")
    text = "".join(parts)
    (ROOT / "docs" / "BENCHMARKS.md").write_text(text)
    return text


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--assemble", action="store_true", help="only assemble docs/BENCHMARKS.md")
    args = ap.parse_args()
    if not args.assemble:
        for script in sorted((ROOT / "tools").glob("bench_*.py")):
            if script.name == Path(__file__).name:
                continue
            print(f"== {script.name}", flush=True)
            rc = subprocess.call([sys.executable, str(script)], cwd=ROOT)
            if rc != 0:
                print(f"{script.name} failed with exit code {rc}", file=sys.stderr)
    assemble()
    print("wrote docs/BENCHMARKS.md")
    return 0


if __name__ == "__main__":
    sys.exit(main())
