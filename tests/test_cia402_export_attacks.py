"""Attack pass s16b: the CiA 402 path and ``edge-monitor export-trace`` (docs/RELIABILITY.md, "CiA 402 and
exported traces"). Each test says what happened before its fix."""

from __future__ import annotations

import json
import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

from edge_monitor.commands.replay import input_notes
from edge_monitor.sources.cia402_source import Cia402Decoder
from edge_monitor.sources.trace_export import TraceWriter
from protocol.signal_mapping import MappingError, load_mapping

from foreign_mappings import ROOT, mapping, record

EDS = (ROOT / "protocol" / "eds" / "cia402_drive.eds").read_text()
EM = [sys.executable, "-m", "edge_monitor.cli"]
HANG_GUARD_S = 600          # only against a hang: the commands take seconds


def _set(text: str, section: str, key: str, value: str) -> str:
    """``key=value`` in ``[section]`` of an EDS text."""
    head = text.index(f"[{section}]\n")
    at = text.index(f"\n{key}=", head) + 1
    return text[:at] + f"{key}={value}" + text[text.index("\n", at):]


def _decoder(tmp_path: Path, eds: str) -> Cia402Decoder:
    (tmp_path / "drive.eds").write_text(eds)
    path = mapping("cia402", tmp_path, joints=1)
    path.write_text(path.read_text().replace(str(ROOT / "protocol" / "eds" / "cia402_drive.eds"),
                                             str(tmp_path / "drive.eds")))
    return Cia402Decoder(load_mapping(path))


@pytest.mark.parametrize(("edit", "says"), [
    # before: canopen logged a warning and placed 6077h at bit 0: statuswords read as torques, no word said
    (lambda t: _set(t, "1A00sub1", "DefaultValue", "0x20200010"),
     "TPDO1 (mapping 1A00h): entry 1 (0x20200010) maps object 2020sub0, which the EDS does not describe"),
    (lambda t: _set(t, "1A00sub1", "DefaultValue", "0x00050010"), "declare it in [DummyUsage] as Dummy0005=1"),
    # before: "signal Velocity actual value: start bit 32, length 64 does not fit in 8 bytes", naming no node
    (lambda t: _set(t, "1A00sub3", "DefaultValue", "0x606C0040"),
     "node 1: TPDO1 (mapping 1A00h): maps 96 bits, more than a CAN frame's 64"),
    # before: 606Ch read from its low 16 bits: speeds wrapped, 17 cycles "found" in 3
    (lambda t: _set(t, "1A00sub3", "DefaultValue", "0x606C0010"),
     "object 606Csub0 of node 1 (TPDO 0x181) is mapped with 16 bits, its data type has 32"),
    # before: "KeyError: 'Subindex 0x04 was not found'"
    (lambda t: _set(t, "1A00sub0", "DefaultValue", "255"),
     "sub-index 0 says 255 mapped objects, entry 4 is not in the EDS: fix 1A00sub0"),
    # before: "is in no TPDO" only
    (lambda t: _set(t, "1800sub1", "DefaultValue", "$NODEID+0x80000180"), "TPDO1 is not valid (COB-ID bit 31)"),
    (lambda t: _set(t, "1A00sub0", "DefaultValue", "0"), "TPDO1 maps no object"),
    # before: each decoded as an integer of the mapped length (half the speeds beyond any robot's, dropped)
    (lambda t: _set(t, "606C", "DataType", "0x0008"), "606Csub0 of node 1 (TPDO 0x181) has data type REAL32"),
    (lambda t: _set(t, "606C", "DataType", "0x0011"), "has data type REAL64"),
    (lambda t: _set(t, "6077", "DataType", "0x0009"), "6077sub0 of node 1 (TPDO 0x181) has data type VISIBLE_STRING"),
    (lambda t: _set(t, "606C", "DataType", "0x000F"), "has data type DOMAIN"),
    (lambda t: _set(t, "2010", "DataType", "0x0011"), "joint.0.temperature: object 2010sub0"),
    (lambda t: _set(t, "6041", "DataType", "0x0009"), "statusword 6041h of node 1 (TPDO 0x181) has data type"),
    # before: "the EDS has no 608Fh" (it had, with 0 revolutions); a negative resolution flipped every speed's sign
    (lambda t: _set(t, "608Fsub2", "DefaultValue", "0"), "608Fh of node 1 is 65536 increments per 0 revolutions"),
    (lambda t: _set(t, "608Fsub1", "DefaultValue", "-65536"), "is -65536 increments per 1 revolutions"),
    # before: "cannot read EDS …: TypeError: unsupported operand type(s) for >>: 'NoneType' and 'int'" (canopen
    # leaves a value that is no number unset), naming neither the section nor the value
    (lambda t: _set(t, "1A00sub1", "DefaultValue", "abc"), "drive.eds: [1A00sub1] DefaultValue='abc' is not a number"),
    (lambda t: _set(t, "1A00sub0", "DefaultValue", "three"), "[1A00sub0] DefaultValue='three' is not a number"),
    (lambda t: _set(t, "1800sub1", "DefaultValue", "$NODEID+x"), "[1800sub1] DefaultValue='$NODEID+x' is not a number"),
    # before: "velocity_factor: … the EDS has no 608Fh encoder resolution" (it had one, not a number)
    (lambda t: _set(t, "608Fsub1", "DefaultValue", "lots"), "[608Fsub1] DefaultValue='lots' is not a number"),
    (lambda t: _set(t, "1A00sub1", "DefaultValue", ""), "[1A00sub1] has no value (DefaultValue empty)"),
    (lambda t: _set(t, "1800sub2", "DefaultValue", "sync"), "[1800sub2] DefaultValue='sync' is not a number"),
    # before: canopen's "eds file does not have a DeviceInfo section" and "velocity_factor: … is needed"
    (lambda t: "", "drive.eds is empty (0 bytes): give the drive's EDS/DCF"),
    (lambda t: "\n; nothing\n\n", "drive.eds is empty (no line but blanks and comments)"),
    (lambda t: "[Foo]\nbar=1\n", "drive.eds describes no object (no section such as [1000] or [1A00sub1])"),
])
def test_an_eds_whose_tpdos_cannot_be_decoded_is_refused_naming_why(tmp_path, edit, says):
    with pytest.raises(MappingError) as raised:
        _decoder(tmp_path, edit(EDS))
    assert says in str(raised.value)


def test_the_shipped_eds_still_decodes(tmp_path):
    decoder = _decoder(tmp_path, EDS)
    assert decoder.describe()[0]["gate"] == "statusword operation enabled"


@pytest.mark.parametrize("edit", [
    lambda t: _set(t, "1800sub4", "DefaultValue", ""),        # reserved: vendors leave it empty
    lambda t: _set(t, "1800sub3", "DefaultValue", "-"),       # inhibit time: not read here
    lambda t: _set(t, "1800sub5", "DefaultValue", "abc"),     # event timer: not read here
])
def test_values_the_agent_does_not_read_or_left_empty_do_not_refuse_an_eds(tmp_path, edit):
    """The check of an EDS's numbers refused a vendor file for a value nothing reads (an empty reserved entry, the
    event timer); only the values read (COB-ID, transmission type, the mapping, 6076h, 608Fh) are checked, and
    one left empty is not given."""
    assert _decoder(tmp_path, edit(EDS)).describe()[0]["gate"] == "statusword operation enabled"


def _third_tpdo(cob_id: str, entry: str) -> str:
    """The shipped EDS with a TPDO3 (1802h, 1A02h) of COB-ID ``cob_id`` mapping one object, ``entry``."""
    def var(section: str, name: str, data_type: str, value: str) -> str:
        return (f"[{section}]\nParameterName={name}\nObjectType=0x7\nDataType={data_type}\nAccessType=rw\n"
                f"PDOMapping=0\nDefaultValue={value}\n\n")
    text = ("[1802]\nParameterName=TPDO3 communication parameter\nObjectType=0x9\nSubNumber=3\n\n"
            + var("1802sub0", "Highest sub-index", "0x0005", "2") + var("1802sub1", "COB-ID", "0x0007", cob_id)
            + var("1802sub2", "Transmission type", "0x0005", "1")
            + "[1A02]\nParameterName=TPDO3 mapping parameter\nObjectType=0x9\nSubNumber=2\n\n"
            + var("1A02sub0", "Number of mapped objects", "0x0005", "1") + var("1A02sub1", "Mapped object 1", "0x0007", entry))
    return EDS.replace("[2010]\n", text + "[2010]\n", 1)


def test_the_mapping_of_a_tpdo_not_valid_is_not_read(tmp_path):
    """A TPDO whose COB-ID has bit 31 set is never sent: its mapping is not read, so a value there that is no
    number does not refuse the EDS; the same mapping in a valid TPDO does."""
    decoder = _decoder(tmp_path, _third_tpdo("$NODEID+0x80000380", "abc"))
    assert decoder.describe()[0]["gate"] == "statusword operation enabled"
    with pytest.raises(MappingError, match=r"\[1A02sub1\] DefaultValue='abc' is not a number"):
        _decoder(tmp_path, _third_tpdo("$NODEID+0x380", "abc"))


def test_samples_of_a_drive_not_enabled_are_said(tmp_path):
    """Before, samples dropped by the statusword gate were in `replay --json` only: a drive in fault for the
    whole capture gave "no cycle found … does the mapping's [cycles] fit the input?"."""
    stats = {"cycles": 0, "frames_total": 100, "unknown_id": 0,
             "details": {"not_enabled": 51236, "samples_dropped": {},
                         "cycle_finding": {"method": "motion (designed speed levels)", "before_first_cycle": 0}}}
    notes, nothing = input_notes("a b.blf", stats, None, "m.toml")
    assert notes == ["a b.blf: samples dropped: drive not in operation enabled (statusword 6041h) 51236"]
    assert nothing is not None and "51236 samples were dropped while the drive's statusword 6041h" in nothing
    assert "check-mapping 'a b.blf' --mapping m.toml" in nothing


@pytest.fixture(scope="module")
def slow_drives(tmp_path_factory):
    """CiA 402 drives at 100 Hz, the mapping saying so, and the replay's records."""
    tmp = tmp_path_factory.mktemp("rate100")
    log = tmp / "drives100.blf"
    subprocess.run([sys.executable, "-m", "sim_controller.cli", "record", "--out", str(log), "--joints", "1",
                    "--cycles", "3", "--rate", "100", "--profile", "cia402", "-q"], check=True, timeout=HANG_GUARD_S)
    m = mapping("cia402", tmp, speeds=(2.1, 8.7, 15.3, 21.9, 28.5, 35.1, 41.7, 82.2, 133.5, 184.7, 236.2, 287.1),
                joints=1)
    m.write_text("rate_hz = 100.0\n" + m.read_text())
    return tmp, log, m, _records(tmp / "log.jsonl", log, "--mapping", str(m))


def _records(jsonl: Path, *args: str) -> dict:
    subprocess.run([*EM, "replay", *args, "--jsonl", str(jsonl), "-q"], check=True, timeout=HANG_GUARD_S)
    return {(r["joint"], r["cycle"]): r for r in map(json.loads, jsonl.open())}


@pytest.mark.slow
def test_an_export_at_another_rate_replays_as_its_recording(slow_drives):
    """Before, the exported mapping had no rate_hz: the 100 Hz table replayed at 500 Hz gave cycles without a
    friction curve (wear None), said nowhere."""
    tmp, log, m, original = slow_drives
    out = tmp / "drives100.parquet"
    subprocess.run([*EM, "export-trace", str(log), "--mapping", str(m), "--out", str(out), "-q"], check=True,
                   timeout=HANG_GUARD_S)
    assert "rate_hz = 100.0" in out.with_suffix(".toml").read_text()
    again = _records(tmp / "trace.jsonl", str(out), "--mapping", str(out.with_suffix(".toml")))
    assert set(again) == set(original) and len(original) == 3
    for key, r in original.items():
        assert r["friction"]["torque"] and r["wear"]["estimate"] == pytest.approx(again[key]["wear"]["estimate"],
                                                                                  abs=1e-6)


@pytest.mark.slow
def test_an_export_beside_fifos_and_to_a_name_with_spaces(tmp_path):
    """Before, a FIFO at the fixed hidden name .NAME.partial.csv hung the export for ever (SIGTERM too), and
    the printed replay command broke at the spaces of its path."""
    log = record(tmp_path, "native", "native", cycles=2, joints=1)
    folder = tmp_path / "a folder ü"
    folder.mkdir()
    for name in (".run x.partial.csv", ".run x.partial.toml"):
        os.mkfifo(folder / name)
    done = subprocess.run([*EM, "export-trace", str(log), "--out", str(folder / "run x.csv")], capture_output=True,
                          text=True, timeout=HANG_GUARD_S)
    assert done.returncode == 0, done.stderr
    assert sorted(p.name for p in folder.iterdir()) == [".run x.partial.csv", ".run x.partial.toml", "run x.csv",
                                                        "run x.toml"]
    command = shlex.split(re.search(r"`(edge-monitor replay .*)`", done.stderr).group(1))
    replayed = subprocess.run([*EM, *command[1:], "-q"], capture_output=True, text=True, timeout=HANG_GUARD_S)
    assert replayed.returncode == 0, replayed.stderr


def test_a_mapping_that_cannot_be_written_leaves_no_table(tmp_path, monkeypatch, capsys):
    """Before, the table got its name first and the mapping was written after: a mapping that could not be
    written (a root-owned read-only one, a full disk) left the new table beside the old mapping."""
    import edge_monitor.cli

    log = record(tmp_path, "native", "native", cycles=2, joints=1)
    out = tmp_path / "out"
    out.mkdir()
    (out / "t.toml").write_text("# an old mapping\n")
    real = TraceWriter._fresh

    def no_space_for_the_mapping(self, suffix):
        if suffix == ".toml":
            raise OSError(28, "No space left on device")
        return real(self, suffix)
    monkeypatch.setattr(TraceWriter, "_fresh", no_space_for_the_mapping)
    assert edge_monitor.cli.main(["export-trace", str(log), "--out", str(out / "t.csv"), "--force", "-q"]) == 1
    assert "No space left on device" in capsys.readouterr().err
    assert sorted(p.name for p in out.iterdir()) == ["t.toml"] and (out / "t.toml").read_text() == "# an old mapping\n"


KILLED_AT_CLOSE = """
import os, signal, sys
from edge_monitor.sources import trace_export
trace_export.TraceWriter.close = lambda self, drop_open=False: os.kill(os.getpid(), signal.SIGKILL)
from edge_monitor.cli import main
main(sys.argv[1:])
"""


def test_hidden_files_a_killed_export_left_are_removed_and_only_those(tmp_path):
    """Before, an export killed with SIGKILL (or a power cut) left its hidden ``.NAME.<random>.partial.csv``
    for ever, one more per crash. Now the next export to the name removes those nobody holds the lock of,
    says so, and leaves alone one another export is writing and anything not a regular file."""
    import fcntl

    log = record(tmp_path, "native", "native", cycles=2, joints=1)
    out = tmp_path / "t.csv"
    killed = subprocess.run([sys.executable, "-c", KILLED_AT_CLOSE, "export-trace", str(log), "--out", str(out),
                             "-q"], capture_output=True, text=True, timeout=HANG_GUARD_S)
    assert killed.returncode == -9, killed.stderr
    left = sorted(p.name for p in tmp_path.glob(".t.*.partial.csv"))
    assert len(left) == 1 and not out.exists()
    os.mkfifo(tmp_path / ".t.0000fifo.partial.csv")
    busy = tmp_path / ".t.0000busy.partial.csv"
    busy.write_text("another export's rows\n")
    with busy.open() as held:
        fcntl.flock(held, fcntl.LOCK_EX)         # as a running export holds its own
        done = subprocess.run([*EM, "export-trace", str(log), "--out", str(out)], capture_output=True, text=True,
                              timeout=HANG_GUARD_S)
    assert done.returncode == 0, done.stderr
    assert "removed 1 hidden file(s) beside t.csv left by an export that did not finish" in done.stderr
    assert left[0] in done.stderr
    assert sorted(p.name for p in tmp_path.glob(".t.*")) == [".t.0000busy.partial.csv", ".t.0000fifo.partial.csv"]
    assert out.exists() and out.with_suffix(".toml").exists()
