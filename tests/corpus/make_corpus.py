#!/usr/bin/env python3
"""Write the adversarial corpus of this folder (tests/corpus/README.md lists each file): small hostile
files of the kinds issue 28 found, made deterministically from a short simulator recording.

    .venv/bin/python tests/corpus/make_corpus.py          # rewrites the files in place
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path[:0] = [str(HERE.parent.parent), str(HERE.parent)]

import can  # noqa: E402
import hostile_files as hostile  # noqa: E402

from sim_controller.config import SimConfig  # noqa: E402
from sim_controller.output import record  # noqa: E402

#: Frame lines kept of the text logs (the corpus stays small).
TEXT_LINES = 800


def recording(suffix: str, folder: Path) -> bytes:
    """One joint, one short cycle (2,458 frames); a BLF in containers of 16 KiB (several of them)."""
    path = folder / f"tiny.{suffix}"
    record(SimConfig(joints=1, cycles=1, seed=1, speeds=(8.7,), plateau_time=0.3), path)
    if suffix != "blf":
        return path.read_bytes()
    small = folder / "small.blf"
    writer = can.BLFWriter(str(small), channel=1)
    writer.max_container_size = 16 << 10
    with can.LogReader(str(path)) as reader:
        for message in reader:
            writer.on_message_received(message)
    writer.stop()
    return small.read_bytes()


def short_text(raw: bytes, suffix: str) -> bytes:
    lines = raw.splitlines(keepends=True)
    frames = hostile.frame_line_indices(lines, suffix)
    kept = lines[:frames[TEXT_LINES - 1] + 1]
    return b"".join(kept + ([b"End TriggerBlock\n"] if suffix == "asc" else []))


def main() -> int:
    files: dict[str, bytes] = {}
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        blf = recording("blf", folder)
        files["clean.blf"] = blf
        for suffix in ("log", "asc"):
            text = short_text(recording(suffix, folder), suffix)
            files[f"clean.{suffix}"] = text
            files[f"bad_byte.{suffix}"] = hostile.with_bad_byte(text, suffix)
            files[f"garbage_lines.{suffix}"] = hostile.with_garbage_lines(text, 40, seed=28)[0]
    middle = len(hostile.blf_objects(blf)) // 2
    files["zlib_bomb.blf"] = hostile.with_object_before(
        blf, middle, hostile.container(hostile.zlib_bomb(64 << 20), claimed=64 << 20))
    files["object_size_ffffffff.blf"] = hostile.with_object_size(blf, middle, 0xFFFFFFFF)
    inner = hostile.container(b"LOBJ" + bytes(12) + b"LOBJ" + bytes(28), claimed=48, method=0)
    files["inner_object_size_zero.blf"] = hostile.with_object_before(blf, 0, inner)    # no tail before it
    files["state_5000_digit_integer.json"] = hostile.state_with_long_integer().encode()
    files["state_nested_5000.json"] = ('{"version": 1, "robot": "robot1", "joints": {"0": '
                                       + '{"a": ' * 5000 + "1" + "}" * 5000 + "}}").encode()
    files["config_nested_5000.toml"] = hostile.deep_toml(5000).encode()
    files["config_inline_tables_5000.toml"] = hostile.deep_toml(5000, "table").encode()
    files["jsonl_unhashable_joint.jsonl"] = b'{"robot":"robot1","joint":[1],"cycle":1}\n'
    files["jsonl_hostile_tail.jsonl"] = b"".join([
        b'{"schema":1,"robot":"robot1","joint":0,"cycle":0}\n', b'{"robot":{"x":1},"joint":0,"cycle":1}\n',
        b'{"robot":"robot1","joint":true,"cycle":2}\n', b"[" * 3000 + b"]" * 3000 + b"\n",
        b'{"robot":"robot1","joint":0,"cycle":' + b"9" * 5000 + b"}\n", b"null\n",
        b'{"schema":1,"robot":"robot1","joint":0,"cyc' + b"x" * 20000])          # torn, 20 kB
    files["fit_weights_sample_1e11.csv"] = b"cycle,sample,speed,torque\n0,0,1,0.1\n0,100000000000,1,0.1\n"
    for name, data in sorted(files.items()):
        (HERE / name).write_bytes(data)
        print(f"{name:36} {len(data):>8} bytes")
    return 0


if __name__ == "__main__":
    sys.exit(main())
