"""A recording as a wide trace table (CSV or Parquet) and the ``trace`` mapping that reads it back.

What a robot vendor's trace tool would export, made from what the agent takes in: per controller tick
one row, ``time [s|ms]``, then per joint ``J<j> speed [rad/s]``, ``J<j> torque [fraction]`` and, where
the source has them, ``J<j> load [fraction]`` and ``J<j> temperature [degC]`` (in the rows of the status
frames, empty elsewhere), and the ``cycle`` and ``segment`` labels in force. Replayed with the written
mapping (cycles from those columns) it gives the symptoms of the recording (tests/test_trace_source.py).
The rows of the cycle in progress are held until the next cycle starts: a recording cut short leaves its cut
last cycle out of the table (``close(drop_open=True)``), as its replay leaves it unpublished. A cycle longer
than :data:`HOLD_VALUES` values is written as it goes (then it cannot be left out).
"""


from __future__ import annotations

import fcntl
import json
import logging
import os
import secrets
import stat
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from edge_monitor.sources.samples import IngestBlock

log = logging.getLogger(__name__)
#: Values (rows × columns) of the cycle in progress held back before they are written anyway (≈ 64 MiB).
HOLD_VALUES = 8 << 20


class TraceWriter:
    """Writes the runs of :class:`IngestBlock` s as rows (see the module docstring). The rows go to a hidden
    ``.<name>.<random>.partial<suffix>`` beside ``path``, which :meth:`close` renames to ``path`` (the mapping
    likewise, written first) and :meth:`discard` deletes: an export cut short (Ctrl-C, SIGTERM, a full disk)
    leaves no half table under the final name (a Parquet file without its footer cannot be read at all), and
    a table never stands beside a mapping it did not come with. Each hidden file is locked (``flock``) while it
    is written, so those a killed export left are told apart and removed (:func:`remove_stale_partials`)."""

    def __init__(self, path: str | Path, joints: list[int], rate_hz: float, separator: str = ";",
                 time_unit: str = "s", status: bool = True) -> None:
        self.path, self.joints, self.rate_hz = Path(path), joints, rate_hz
        self.separator, self.time_unit, self.status = separator, time_unit, status
        self.parquet = self.path.suffix.lower() in (".parquet", ".pq")
        # the hidden names' shape (for a name-length check); the files are made fresh (_fresh): never a FIFO or
        # another file already there under a fixed name
        self.partial = self.path.with_name(f".{self.path.stem}.XXXXXXXX.partial{self.path.suffix}")
        self.mapping_path = self.path.with_suffix(".toml")
        self.mapping_partial = self.path.with_name(f".{self.path.stem}.XXXXXXXX.partial.toml")
        self._made: list[Path] = []
        self._locks: list[int] = []         # a descriptor of each hidden file, holding its flock
        self._writer: Any = None
        self.rows = 0
        self.dropped_rows = 0               # rows of a cut last cycle left out (close(drop_open=True))
        self._held: list[dict[str, NDArray[np.float64]]] = []   # rows of the cycle in progress
        self._held_cycle: int | None = None
        self._held_values = 0

    def columns(self) -> list[str]:
        names = [f"time [{self.time_unit}]"]
        for j in self.joints:
            names += [f"J{j} speed [rad/s]", f"J{j} torque [fraction]"]
            if self.status:
                names += [f"J{j} load [fraction]", f"J{j} temperature [degC]"]
        return names + ["cycle", "segment"]

    def write(self, block: IngestBlock) -> None:
        for run in block.runs:
            if run.cycle is None or not run.samples:
                continue
            ticks = np.unique(np.concatenate([s.tick for s in run.samples.values()]))
            cols: dict[str, NDArray[np.float64]] = {}
            segment = np.full(ticks.size, -1.0)
            for j in self.joints:
                speed, torque = np.full(ticks.size, np.nan), np.full(ticks.size, np.nan)
                s = run.samples.get(j)
                if s is not None:
                    at = np.searchsorted(ticks, s.tick)
                    speed[at], torque[at] = s.speed, s.torque
                    segment[at] = np.maximum(segment[at], s.segment)
                cols[f"J{j} speed [rad/s]"], cols[f"J{j} torque [fraction]"] = speed, torque
                if self.status:
                    load, temperature = np.full(ticks.size, np.nan), np.full(ticks.size, np.nan)
                    st = run.joint_status.get(j)
                    if st is not None and st.load_estimate.size:
                        at = np.rint(np.linspace(0, ticks.size - 1, st.load_estimate.size)).astype(np.int64)
                        load[at], temperature[at] = st.load_estimate, st.motor_temperature
                    cols[f"J{j} load [fraction]"], cols[f"J{j} temperature [degC]"] = load, temperature
            scale = 1e3 if self.time_unit == "ms" else 1.0
            cols[f"time [{self.time_unit}]"] = ticks / self.rate_hz * scale
            cols["cycle"], cols["segment"] = np.full(ticks.size, float(run.cycle)), segment
            self._hold(run.cycle, cols)

    def _hold(self, cycle: int, cols: dict[str, NDArray[np.float64]]) -> None:
        """Hold the rows of the cycle in progress; write the held rows once another cycle starts (or they
        pass :data:`HOLD_VALUES`)."""
        if cycle != self._held_cycle:
            self._release()
            self._held_cycle = cycle
        self._held.append(cols)
        self._held_values += len(cols) * len(cols["cycle"])
        if self._held_values > HOLD_VALUES:
            log.warning("cycle %d passes %d values: written before it ends (a cut log could not leave it out)",
                        cycle, HOLD_VALUES)
            self._release()

    def _release(self) -> None:
        for cols in self._held:
            self._append(cols)
        self._held, self._held_values = [], 0

    def _append(self, cols: dict[str, NDArray[np.float64]]) -> None:
        import pyarrow as pa
        table = pa.table({name: pa.array(cols[name], from_pandas=True) for name in self.columns()})
        if self._writer is None:
            self.partial = self._fresh(self.path.suffix)
            if self.parquet:
                import pyarrow.parquet as pq
                self._writer = pq.ParquetWriter(str(self.partial), table.schema)
            else:
                import pyarrow.csv as pcsv
                self._writer = pcsv.CSVWriter(str(self.partial), table.schema,
                                              write_options=pcsv.WriteOptions(delimiter=self.separator))
        self._writer.write_table(table)
        self.rows += table.num_rows

    def close(self, drop_open: bool = False) -> None:
        """Finish the table and its mapping and give both their names (nothing is written without rows; the
        mapping is written first, so a table never stands beside another's mapping); ``drop_open``: the
        recording was cut short, leave the rows of its last cycle (held back) out."""
        if drop_open:
            self.dropped_rows = sum(len(cols["cycle"]) for cols in self._held)
            self._held, self._held_values = [], 0
        self._release()
        if self._writer is not None:
            self._writer.close()
            self._writer = None
            self.mapping_partial = self._fresh(".toml")
            self.mapping_partial.write_text(self.mapping_text(), encoding="utf-8")
            self.partial.replace(self.path)
            self.mapping_partial.replace(self.mapping_path)
            self._made = []
        self._unlock()

    def _fresh(self, suffix: str) -> Path:
        """A new empty hidden file beside the table, made with O_EXCL (whatever lies there, a FIFO left under a
        name, is never opened) and the umask's permissions (as the table would have)."""
        while True:
            path = self.path.with_name(f".{self.path.stem}.{secrets.token_hex(4)}.partial{suffix}")
            try:
                fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
            except FileExistsError:
                continue
            fcntl.flock(fd, fcntl.LOCK_EX)      # new and ours alone: granted at once; held until renamed or deleted
            self._locks.append(fd)
            self._made.append(path)
            return path

    def _unlock(self) -> None:
        for fd in self._locks:
            os.close(fd)
        self._locks = []

    def discard(self) -> None:
        """Stop and delete what was written (an export that did not finish)."""
        try:
            if self._writer is not None:
                self._writer.close()
        except Exception:     # noqa: BLE001 — the file goes anyway; the error that stopped the export is reported
            pass
        self._writer, self._held = None, []
        for made in self._made:
            made.unlink(missing_ok=True)
        self._made = []
        self._unlock()

    def stale_partials(self) -> list[Path]:
        """Hidden files of this table's name that no export is writing (none holds their lock): what an export
        killed with SIGKILL, or a machine that lost power, left behind."""
        stem = self.path.stem
        found = [p for pattern in (f".{stem}.*.partial{self.path.suffix}", f".{stem}.*.partial.toml")
                 for p in self.path.parent.glob(pattern)]
        return [p for p in found if p not in self._made and _unlocked_regular_file(p)]

    def mapping_text(self) -> str:
        """The ``trace`` mapping of this table (cycles from its cycle/segment columns)."""
        lines = [f"# trace mapping of {self.path.name} (edge-monitor export-trace)", 'kind = "trace"',
                 f"rate_hz = {float(self.rate_hz)!r}   # the recording's tick rate (its rows' time step)", "",
                 "[trace]", 'layout = "wide"', f"separator = {json.dumps(self.separator)}",
                 f'time_column = "time [{self.time_unit}]"', f'time_unit = "{self.time_unit}"', "",
                 "[cycles]", 'from = "controller"', 'cycle = { column = "cycle" }', 'segment = { column = "segment" }',
                 ""]
        for j in self.joints:
            lines += [f"[joint.{j}]", f'speed = {{ column = "J{j} speed [rad/s]" }}',
                      f'torque = {{ column = "J{j} torque [fraction]" }}']
            if self.status:
                lines += [f'load = {{ column = "J{j} load [fraction]" }}',
                          f'temperature = {{ column = "J{j} temperature [degC]" }}']
            lines.append("")
        return "\n".join(lines)


def _unlocked_regular_file(path: Path) -> bool:
    """Whether ``path`` is a regular file (a symlink is not followed; a FIFO is opened without blocking and then
    refused) that nobody holds a ``flock`` on."""
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK)
    except OSError:
        return False
    try:
        if not stat.S_ISREG(os.fstat(fd).st_mode):
            return False
        fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
        return True
    except OSError:
        return False
    finally:
        os.close(fd)
