"""edge-monitor schema: print the JSON Schema of a published record or of the commands' summary.

Kinds: symptom, alarm, advisory, friction, health (the Zenoh records and JSONL lines; the "kind" and
"key" that edge-monitor listen adds in front are declared in them), state (the reply of the
edge/<robot>/<joint>/state queryable), summary (run/replay/demo --json), history and fleet (the
historian's answers on edge/history/**, edge-monitor history --format json). A consumer in any language
validates against these (JSON Schema draft 2020-12) and needs nothing else of this package.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from edge_monitor.schemas import KINDS, schema_text
from protocol.console import EXIT_FAILURE


def add_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    parser = subparsers.add_parser("schema", help="print the JSON Schema of a published record",
                                   description=__doc__)
    parser.add_argument("kind", choices=KINDS, help="which record")
    parser.add_argument("-o", "--out", metavar="PATH", help="write it to this file instead of standard output")
    parser.set_defaults(func=run)
    return parser


def run(args: argparse.Namespace) -> int:
    text = schema_text(args.kind)
    if args.out is None:
        sys.stdout.write(text)
        return 0
    try:
        Path(args.out).write_text(text, encoding="utf-8")
    except OSError as exc:
        print(f"edge-monitor schema: cannot write {args.out}: {exc.strerror}", file=sys.stderr)
        return EXIT_FAILURE
    return 0
