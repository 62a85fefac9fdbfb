#!/usr/bin/env python3
"""Run every benchmark (tools/bench/bench_*.py) and assemble docs/BENCHMARKS.md from docs/benchmarks/*.md.

    .venv/bin/python tools/bench/bench_all.py            # run all, then assemble
    .venv/bin/python tools/bench/bench_all.py --assemble # only assemble the existing sections
    .venv/bin/python tools/bench/bench_all.py --only agent sim   # run some, then assemble all

Long ones: bench_live (10 min at bus saturation + 1 min), bench_detection (≈ 15 min the first time,
simulated sequences cached in the temp dir), bench_latency (≈ 4 min).

Peers compared against (KDEpy, river) and py-spy (profiles) come with `pip install -e '.[bench]'`.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
ORDER = ["protocol", "sim", "agent", "latency", "live", "detection", "wear", "kde", "glr", "calibration"]
HEADER = """# Benchmarks

Speed goals are measured here, never asserted in unit tests. Every figure is a ratio against a
baseline run in the same process (or the same command), because the build machine is shared and
noisy (2 cores). Re-run with `make bench` (or `.venv/bin/python tools/bench/bench_all.py`); each section
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
    ap.add_argument("--only", nargs="+", metavar="TOPIC", help="run only these (e.g. agent sim latency live detection)")
    args = ap.parse_args()
    if not args.assemble:
        scripts = [s for s in sorted((ROOT / "tools" / "bench").glob("bench_*.py"))
                   if s.name != Path(__file__).name and (not args.only or s.stem.removeprefix("bench_") in args.only)]
        started = time.monotonic()
        for k, script in enumerate(scripts, 1):
            print(f"== [{k}/{len(scripts)}] {script.name} (at {time.monotonic() - started:.0f} s)", flush=True)
            t = time.monotonic()
            rc = subprocess.call([sys.executable, str(script)], cwd=ROOT)
            print(f"== {script.name} done in {time.monotonic() - t:.0f} s" + (f", exit code {rc}" if rc else ""),
                  flush=True)
            if rc != 0:
                print(f"{script.name} failed with exit code {rc}", file=sys.stderr)
    assemble()
    print("wrote docs/BENCHMARKS.md")
    return 0


if __name__ == "__main__":
    sys.exit(main())
