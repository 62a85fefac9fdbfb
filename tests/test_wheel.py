"""The product as a user gets it: a wheel built from a clean clone (the committed files), installed in a
fresh venv, used outside the checkout. Headless first (no extras: its size is measured, the viewer and
the trace tables say which extra they need, the service files print), then with the viewer extra: it
records a log, replays it to JSONL with UTC times and to a recording that `rerun rrd verify` accepts,
starts a router and the agent against it, and `listen` prints the agent's symptoms; nothing it prints
names a source-tree path, and Rerun's usage reporting is off."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import zipfile
from datetime import datetime
from pathlib import Path

import jsonschema
import pytest

from edge_monitor.schemas import load_schema
from protocol.links import PtyPair

from waiting import wait_until

pytestmark = [pytest.mark.slow, pytest.mark.timeout(1800)]

REPO = Path(__file__).resolve().parents[1]
START_TIME = 1_795_000_000        # 2026-11-18T09:46:40Z: the recorded frames carry wall-clock time
SIM_FAST = ["--joints", "1", "--cycles", "3", "--speeds", "20", "--plateau-time", "0.3", "--seed", "5"]
FORBIDDEN = ("tools/", ".venv/bin", "edge_monitor/defaults", str(REPO))   # source-tree paths
#: The headless install's goal [MB]: the venv with the agent and its dependencies, without rerun-sdk (≈ 490 MB)
#: and pyarrow (≈ 170 MB); measured 287 MB with Python 3.11 (docs/OPERATIONS.md, "Installing it").
HEADLESS_MB = 300


def _git_archive(dest: Path) -> None:
    if shutil.which("git") is None or not (REPO / ".git").exists():
        pytest.skip("not a git checkout: no clean clone to build from")
    archive = subprocess.run(["git", "-C", str(REPO), "archive", "--format=tar", "HEAD"], capture_output=True,
                             check=True, timeout=120)
    dest.mkdir()
    subprocess.run(["tar", "-x", "-C", str(dest)], input=archive.stdout, check=True, timeout=120)


@pytest.fixture(scope="module")
def installed(tmp_path_factory) -> dict:
    """A fresh venv with the wheel of a clean clone installed; an environment that points at nothing else."""
    root = tmp_path_factory.mktemp("wheel")
    _git_archive(root / "clone")
    built = subprocess.run([sys.executable, "-m", "build", "--wheel", "--outdir", str(root / "dist"),
                            str(root / "clone")], capture_output=True, text=True, timeout=900)
    assert built.returncode == 0, built.stdout[-3000:] + built.stderr[-3000:]
    log = built.stdout + built.stderr
    for warning in ("SetuptoolsDeprecationWarning", "would be ignored", "License classifiers are deprecated"):
        assert warning not in log, f"the build warns: {warning}"
    wheel = next((root / "dist").glob("joint_wear_monitor-*.whl"))
    names = zipfile.ZipFile(wheel).namelist()
    assert any(n.endswith(".dist-info/licenses/LICENSE") for n in names)
    assert "edge_monitor/schemas/symptom.schema.json" in names and "protocol/dbc/robot_joints.dbc" in names
    assert not any(n.startswith(("tests/", "tools/", "studies/")) for n in names)
    venv = root / "venv"
    subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True, timeout=300)
    done = subprocess.run([str(venv / "bin" / "pip"), "install", "-q", str(wheel)], capture_output=True, text=True,
                          timeout=1200)
    assert done.returncode == 0, done.stderr[-3000:]
    home = root / "home"
    home.mkdir()
    env = {k: v for k, v in os.environ.items() if not k.startswith(("PYTHON", "CAN_", "VIRTUAL_ENV", "XDG_"))}
    env.update(PATH=f"{venv / 'bin'}{os.pathsep}{os.environ.get('PATH', '')}", HOME=str(home))
    work = root / "outside"
    work.mkdir()
    return {"bin": venv / "bin", "env": env, "work": work, "home": home, "printed": [], "wheel": wheel, "venv": venv}


def _with_viewer(installed: dict) -> None:
    """Add the viewer extra to the venv (once): what a desk, not an edge box, installs."""
    if not installed.get("viewer"):
        done = subprocess.run([str(installed["bin"] / "pip"), "install", "-q", f"{installed['wheel']}[viewer]"],
                              capture_output=True, text=True, timeout=1200)
        assert done.returncode == 0, done.stderr[-3000:]
        installed["viewer"] = True


def _size_mb(path: Path) -> float:
    return sum(p.stat().st_size for p in path.rglob("*") if p.is_file() and not p.is_symlink()) / 1e6


def test_the_headless_wheel_is_small_and_says_which_extra_a_feature_needs(installed):
    assert not installed.get("viewer"), "runs before the viewer extra is installed"
    size = _size_mb(installed["venv"])
    assert size <= HEADLESS_MB, f"the headless venv takes {size:.0f} MB"
    for module in ("rerun", "pyarrow"):
        probe = subprocess.run([str(installed["bin"] / "python"), "-c", f"import {module}"], capture_output=True,
                               env=installed["env"], timeout=120)
        assert probe.returncode != 0, f"{module} came with the headless install"
    _run(installed, "sim-controller", "record", "-o", "headless.blf", *SIM_FAST, "-q")
    replay = _run(installed, "edge-monitor", "replay", "headless.blf", "--json", "-q")
    assert json.loads(replay.stdout)["symptoms"] == 3
    for cmd, says in ((["replay", "headless.blf", "--rerun", "save:x.rrd"], "[viewer]"),
                      (["export-trace", "headless.blf", "--out", "t.csv"], "[traces]")):
        done = subprocess.run([str(installed["bin"] / "edge-monitor"), *cmd], cwd=installed["work"],
                              env=installed["env"], capture_output=True, text=True, timeout=300)
        assert done.returncode == 1 and says in done.stderr and "Traceback" not in done.stderr, done.stderr
    unit = _run(installed, "edge-monitor", "deploy", "edge-monitor.service").stdout
    assert "Type=notify" in unit and "ExecReload=" in unit


def _run(installed: dict, *cmd: str, timeout: float = 600) -> subprocess.CompletedProcess[str]:
    done = subprocess.run([str(installed["bin"] / cmd[0]), *cmd[1:]], cwd=installed["work"], env=installed["env"],
                          capture_output=True, text=True, timeout=timeout, stdin=subprocess.DEVNULL)
    installed["printed"].append(done.stdout + done.stderr)
    assert done.returncode == 0, f"{' '.join(cmd)}: exit {done.returncode}\n{done.stdout}\n{done.stderr}"
    return done


def _popen(installed: dict, *cmd: str) -> subprocess.Popen:
    return subprocess.Popen([str(installed["bin"] / cmd[0]), *cmd[1:]], cwd=installed["work"], env=installed["env"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, stdin=subprocess.DEVNULL)


def _utc(text: str) -> float:
    return datetime.fromisoformat(text.replace("Z", "+00:00")).timestamp()


def test_the_installed_wheel_records_and_replays_to_jsonl_with_utc_times_and_to_a_valid_recording(installed):
    _with_viewer(installed)
    _run(installed, "sim-controller", "record", "-o", "run.blf", *SIM_FAST, "--start-time", str(START_TIME), "-q")
    replay = _run(installed, "edge-monitor", "replay", "run.blf", "--jsonl", "symptoms.jsonl", "--json",
                  "--rerun", "save:run.rrd")
    summary = json.loads(replay.stdout)
    jsonschema.validate(summary, load_schema("summary"))
    lines = [json.loads(x) for x in (installed["work"] / "symptoms.jsonl").read_text().splitlines()]
    symptoms = [r for r in lines if "kind" not in r]
    assert len(symptoms) == summary["symptoms"] == 3
    for record in symptoms:
        jsonschema.validate(record, load_schema("symptom"))
        assert START_TIME < _utc(record["utc"]) < START_TIME + 3600      # the log's clock, not the replay's
    assert [_utc(r["utc"]) for r in symptoms] == sorted(_utc(r["utc"]) for r in symptoms)
    _run(installed, "rerun", "rrd", "verify", "run.rrd")
    analytics = json.loads((installed["home"] / ".config" / "rerun" / "analytics.json").read_text())
    assert analytics["analytics_enabled"] is False
    _no_source_paths(installed)


def test_the_installed_router_agent_and_listener_work_together(installed):
    router = _popen(installed, "edge-monitor", "router", "--port", "0")
    procs = [router]
    try:
        banner = router.stdout.readline().strip()
        assert banner.startswith("zenoh router listening on tcp/127.0.0.1:"), banner + router.stderr.read()
        endpoint = banner.rsplit(" ", 1)[1]
        client = ["--zenoh-mode", "client", "--zenoh-connect", endpoint]
        listener = _popen(installed, "edge-monitor", "listen", *client, "--kind", "symptom", "--count", "3",
                          "--duration", "600")
        procs.append(listener)
        with PtyPair() as pair:
            agent = _popen(installed, "edge-monitor", "run", "--link", f"slcan:{pair.b}", *client,
                           "--idle-stop", "3", "--json")
            procs.append(agent)
            assert wait_until(lambda: pair.is_open(pair.b) or agent.poll() is not None, 300), "agent did not start"
            assert agent.poll() is None, agent.stderr.read()
            _run(installed, "sim-controller", "run", "--link", f"slcan:{pair.a}", *SIM_FAST, "--speedup", "0", "-q")
            agent_out, agent_err = agent.communicate(timeout=300)
        assert agent.returncode == 0, agent_err
        out, err = listener.communicate(timeout=300)
        assert listener.returncode == 0, err
        installed["printed"] += [agent_out + agent_err, out + err]
        printed = [json.loads(x) for x in out.splitlines()]
        assert [r["cycle"] for r in printed] == [0, 1, 2] and {r["kind"] for r in printed} == {"symptom"}
        for record in printed:     # live: the bus stamps frames with the host clock on arrival
            assert abs(_utc(record["utc"]) - datetime.now().timestamp()) < 3600
        jsonschema.validate(json.loads(agent_out.splitlines()[-1]), load_schema("summary"))
    finally:
        for proc in procs:
            if proc.poll() is None:
                proc.terminate()
                proc.communicate(timeout=60)
    assert router.returncode == 0
    _no_source_paths(installed)


def _no_source_paths(installed: dict) -> None:
    for text in installed["printed"]:
        for path in FORBIDDEN:
            assert path not in text, f"the installed program printed a source-tree path ({path}):\n{text}"
