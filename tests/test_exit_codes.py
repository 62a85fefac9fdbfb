"""Exit codes by the README's rule for every subcommand of both tools, table-driven: 2 for bad arguments or
values and invalid input files (with the subcommand's usage or a message naming the field), 1 for a runtime
failure of valid options (a link, file, port or router that cannot be opened, read or written). Never a
traceback. Every subcommand must appear in the table."""

from __future__ import annotations

import socket

import pytest

import edge_monitor.cli
import sim_controller.cli
from protocol.console import subcommands

MISSING = "/nonexistent-dir-of-the-test"
FAST = ["--joints", "1", "--cycles", "2", "--speeds", "20", "--plateau-time", "0.3"]


@pytest.fixture(scope="module")
def busy_port():
    """A loopback port something listens on (taken), and a closed one (nobody listens)."""
    taken = socket.create_server(("127.0.0.1", 0))
    closed = socket.create_server(("127.0.0.1", 0))
    closed_port = closed.getsockname()[1]
    closed.close()
    yield {"taken": str(taken.getsockname()[1]), "closed": str(closed_port)}
    taken.close()


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("inputs")
    (d / "bad.toml").write_text("[decision]\npf = 7\n")
    (d / "bad.csv").write_text("speed,temperature\n1,x\n")
    (d / "ok.csv").write_text("x\n1\n2\n3\n")
    rows = [f"{s},{t},0.5,1e300" for s in (1, 5, 20, 60, 150) for t in (25, 45)]
    (d / "huge.csv").write_text("speed,temperature,load,friction\n" + "\n".join(rows) + "\n")
    (d / "empty.blf").write_bytes(b"")
    (d / "latin.csv").write_bytes(b"\xff\xfespeed,temperature,load,friction\n")
    return {"bad_toml": str(d / "bad.toml"), "bad_csv": str(d / "bad.csv"), "ok_csv": str(d / "ok.csv"),
            "huge_csv": str(d / "huge.csv"), "latin_csv": str(d / "latin.csv"),
            "empty_blf": str(d / "empty.blf"), "dir": str(d)}


#: (tool, argv, expected exit code); {closed}/{taken} ports, {bad_toml}/{bad_csv}/{ok_csv}/{dir} files.
CASES = [
    # edge-monitor run
    ("edge", ["run", "--link", "can0", "--no-zenoh"], 2),
    ("edge", ["run", "-i", "nosuchbus", "-c", "x", "--no-zenoh"], 2),
    ("edge", ["run", "--link", "virtual:x", "--no-zenoh", "--config", "{bad_toml}"], 2),
    ("edge", ["run", "--link", "virtual:x", "--zenoh-connect", "not-an-endpoint"], 2),
    ("edge", ["run", "--link", "virtual:x", "--zenoh-listen", "tcp/127.0.0.1:99999"], 2),
    ("edge", ["run", "--link", "virtual:x", "--no-zenoh", "--rerun", "bogus"], 2),
    ("edge", ["run", "--link", f"slcan:{MISSING}/tty", "--no-zenoh", "--pf", "0.01"], 1),
    ("edge", ["run", "--link", "virtual:x", "--zenoh-mode", "client", "--zenoh-connect",
              "tcp/127.0.0.1:{closed}"], 1),
    # replay
    ("edge", ["replay", f"{MISSING}/run.blf"], 1),
    ("edge", ["replay", "{empty_blf}", "--rerun", "off"], 1),
    ("edge", ["replay", f"{MISSING}/run.blf", "--config", "{bad_toml}"], 2),
    ("edge", ["replay", f"{MISSING}/run.blf", "--rerun", "bogus"], 2),
    # demo
    ("edge", ["demo", "--joints", "9"], 2),
    ("edge", ["demo", "--cycles", "1"], 2),
    ("edge", ["demo", "--speedup", "-1", "--out", "{dir}/d"], 2),
    ("edge", ["demo", "--seed", "-1", "--out", "{dir}/d"], 2),
    ("edge", ["demo", "--nominal-cycles", "0", "--out", "{dir}/d"], 2),
    ("edge", ["demo", "--out", "{bad_csv}"], 2),
    ("edge", ["demo", "--link", "foo"], 2),
    # design, commission, fit-weights, glr, evaluate
    ("edge", ["design"], 2),
    ("edge", ["design", "--points", "0"], 2),
    ("edge", ["design", "--points", "2", "-o", f"{MISSING}/design.json"], 1),
    ("edge", ["commission", f"{MISSING}/nominal.csv"], 2),
    ("edge", ["commission", "{bad_csv}"], 2),
    ("edge", ["commission", "{huge_csv}", "-o", "{dir}/c.toml"], 2),
    ("edge", ["commission", "{latin_csv}", "-o", "{dir}/c.toml"], 2),
    ("edge", ["fit-weights", "--healthy", f"{MISSING}/h.csv", "--faulty", f"{MISSING}/f.csv"], 2),
    ("edge", ["fit-weights"], 2),
    ("edge", ["glr", "--nominal", "{ok_csv}", "--test", "{ok_csv}", "--pf", "1.5"], 2),
    ("edge", ["glr", "--nominal", f"{MISSING}/a.csv", "--test", "{ok_csv}"], 2),
    ("edge", ["glr", "--nominal", "{ok_csv}", "--test", "{ok_csv}", "--columns", "nope"], 2),
    ("edge", ["evaluate", "--factors", "nosuchfactor"], 2),
    # the consumers
    ("edge", ["view", "--rerun", "bogus"], 2),
    ("edge", ["view", "--duration", "-3", "--rerun", "off"], 2),
    ("edge", ["view", "--count", "0", "--rerun", "off"], 2),
    ("edge", ["view", "--robot", "a/b", "--rerun", "save:{dir}/v.rrd"], 2),
    ("edge", ["listen", "--joint", "-1"], 2),
    ("edge", ["listen", "--kind", "a/b"], 2),
    ("edge", ["listen", "--zenoh-connect", "not-an-endpoint"], 2),
    ("edge", ["listen", "--zenoh-mode", "client", "--zenoh-connect", "tcp/127.0.0.1:{closed}"], 1),
    ("edge", ["listen", "--kind", "health", "--count", "1", "--duration", "0.5", "--no-history"], 1),  # no agent
    ("edge", ["schema", "nosuchkind"], 2),
    ("edge", ["schema", "symptom", "-o", f"{MISSING}/symptom.json"], 1),
    ("edge", ["deploy", "nosuchfile"], 2),
    # operator requests
    ("edge", ["acknowledge", "--robot", "r1"], 2),
    ("edge", ["acknowledge", "--robot", "r1", "--joint", "0", "--zenoh-mode", "client", "--zenoh-connect",
              "tcp/127.0.0.1:{closed}", "--timeout", "2"], 1),
    # other controllers
    ("edge", ["check-mapping", f"{MISSING}/c.log", "--mapping", f"{MISSING}/m.toml"], 2),
    ("edge", ["check-mapping", f"{MISSING}/c.log"], 1),
    ("edge", ["export-trace", f"{MISSING}/run.blf", "--out", f"{MISSING}/x.csv"], 1),
    ("edge", ["export-trace", "{ok_csv}", "--out", "{dir}/x.csv"], 2),
    # the historian and its questions
    ("edge", ["historian"], 2),                                              # no database named
    ("edge", ["historian", "--db", "postgresql://u:secret@127.0.0.1/x"], 2),  # a password on the command line
    ("edge", ["historian", "import", "--db", "{dir}/h.db"], 2),              # nothing to import
    ("edge", ["historian", "import", f"{MISSING}/r1.jsonl", "--db", "{dir}/h.db"], 1),
    ("edge", ["historian", "--db", "{dir}/h.db", "--zenoh-mode", "client", "--zenoh-connect",
              "tcp/127.0.0.1:{closed}"], 1),
    ("edge", ["history", "--db", "{dir}/h.db", "--since", "yesterday"], 2),
    ("edge", ["history", "--db", f"{MISSING}/h.db"], 1),
    ("edge", ["history", "--zenoh-mode", "client", "--zenoh-connect", "tcp/127.0.0.1:{closed}"], 1),
    # the infrastructure
    ("edge", ["router", "--tls-cert", "x.pem"], 2),
    ("edge", ["router", "--config", f"{MISSING}/router.json5"], 2),
    ("edge", ["router", "--port", "{taken}"], 1),
    ("edge", ["router", "--port", "70000"], 2),
    ("edge", ["slcan-hub", "--port", "70000"], 2),
    ("edge", ["slcan-hub", "--port", "{taken}"], 1),
    ("edge", ["slcan-hub", "--max-buffer", "100"], 2),          # less than one slcan line
    # sim-controller
    ("sim", ["run", "--link", "can0", *FAST], 2),
    ("sim", ["run", "--link", f"slcan:{MISSING}/tty", *FAST], 1),
    ("sim", ["record", "--out", "x.txt", *FAST], 2),
    ("sim", ["record", "--out", f"{MISSING}/x.blf", *FAST], 1),
    ("sim", ["record", "--out", "x.blf", "--joints", "9"], 2),
    ("sim", ["record", "--out", "{dir}/t.blf", "--start-time", "3e11", *FAST], 2),
    ("sim", ["record", "--out", "{dir}/same.log", "--truth", "{dir}/same.log", *FAST], 2),
    ("sim", ["record", "--out", "{dir}/f.blf", "--profile", "dbc:no_such_mapping", *FAST], 2),
]

MAINS = {"edge": edge_monitor.cli.main, "sim": sim_controller.cli.main}


def exit_code(tool: str, argv: list[str]) -> int:
    try:
        return int(MAINS[tool](argv) or 0)
    except SystemExit as exc:           # argparse and the usage errors exit
        return int(exc.code or 0)


@pytest.mark.parametrize("tool, argv, expected", CASES, ids=[f"{t}-{' '.join(a)}" for t, a, _ in CASES])
def test_exit_code_of_a_bad_input(tool, argv, expected, busy_port, files, capsys, monkeypatch):
    monkeypatch.delenv("CAN_INTERFACE", raising=False)
    monkeypatch.delenv("CAN_CHANNEL", raising=False)
    argv = [a.format(**busy_port, **files) for a in argv]
    code = exit_code(tool, argv)
    err = capsys.readouterr().err
    assert code == expected, f"{tool} {' '.join(argv)} exited {code}, expected {expected}:\n{err}"
    assert "Traceback" not in err and err.strip(), err


def test_every_subcommand_has_a_row_in_the_table():
    for tool, build in (("edge", edge_monitor.cli.build_parser), ("sim", sim_controller.cli.build_parser)):
        covered = {argv[0] for t, argv, _ in CASES if t == tool}
        assert set(subcommands(build())) <= covered, f"{tool}: add rows for {set(subcommands(build())) - covered}"


def test_a_refused_demo_leaves_the_previous_demos_outputs(tmp_path, capsys):
    """Every option is checked before --out is touched (a bad value once deleted the last demo's symptoms)."""
    out = tmp_path / "demo"
    (out / "state").mkdir(parents=True)
    kept = [out / "symptoms.jsonl", out / "truth.jsonl", out / "state" / "agent_state.json"]
    for path in kept:
        path.write_text("{}\n")
    assert exit_code("edge", ["demo", "--nominal-cycles", "-5", "--out", str(out)]) == 2
    assert "--nominal-cycles -5" in capsys.readouterr().err
    assert all(path.exists() for path in kept)


def test_a_shipped_mapping_is_found_by_name_as_the_help_says(tmp_path, capsys):
    log = tmp_path / "foreign.blf"
    assert exit_code("sim", ["record", "--out", str(log), "--profile", "dbc:foreign_robot", "-q", *FAST]) == 0
    assert log.stat().st_size > 0


def test_a_log_the_agent_cannot_use_is_a_failure_that_says_why(tmp_path, capsys):
    """A foreign controller's log replayed without its mapping, and random text under a log's suffix:
    nothing monitored, exit 1 and the reason (both once "succeeded" with 0 cycles and no hint)."""
    foreign = tmp_path / "foreign.blf"
    assert exit_code("sim", ["record", "--out", str(foreign), "--profile", "dbc:foreign_robot", "-q", *FAST]) == 0
    assert exit_code("edge", ["replay", str(foreign), "--rerun", "off"]) == 1
    assert "--mapping" in capsys.readouterr().err
    noise = tmp_path / "noise.log"
    noise.write_bytes(bytes(range(256)) * 20)
    assert exit_code("edge", ["replay", str(noise), "--rerun", "off"]) == 1
    assert "is it a CAN log?" in capsys.readouterr().err


def test_what_the_input_lost_is_said_by_reason():
    from edge_monitor.commands.replay import input_notes

    stats = {"cycles": 3, "frames_total": 0, "unknown_id": 0, "malformed": 1,
             "details": {"samples_dropped": {"time_backwards": 469975, "not_finite": 0}}}
    notes, nothing = input_notes("run.csv", stats, None)
    assert notes == ["run.csv: samples dropped: time backwards 469975", "run.csv: frames not used: malformed 1"]
    assert nothing is None
