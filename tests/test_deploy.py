"""The service files in deploy/: the systemd unit (verified by `systemd-analyze verify` where it exists,
always parsed) and the container file (no container engine here: its user, paths, entrypoint and health
check are checked). Every command line in them must parse with the real CLI."""

from __future__ import annotations

import json
import shlex
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from edge_monitor.cli import build_parser

DEPLOY = Path(__file__).resolve().parents[1] / "deploy"
UNIT, ENV, CONTAINER = DEPLOY / "edge-monitor.service", DEPLOY / "edge-monitor.env", DEPLOY / "Containerfile"


def unit_sections(path: Path) -> dict[str, dict[str, list[str]]]:
    """systemd's INI dialect: sections of keys, a key may repeat, '#' and ';' start comments."""
    sections: dict[str, dict[str, list[str]]] = {}
    current = None
    for raw in path.read_text().splitlines():
        line = raw.strip()
        if not line or line[0] in "#;":
            continue
        if line.startswith("["):
            current = sections.setdefault(line.strip("[]"), {})
            continue
        key, sep, value = line.partition("=")
        assert sep and current is not None, f"{path.name}: not a key=value line: {raw!r}"
        current.setdefault(key.strip(), []).append(value.strip())
    return sections


def env_file() -> dict[str, str]:
    pairs = [line.split("=", 1) for line in ENV.read_text().splitlines() if line.strip() and not line.startswith("#")]
    return {k: v for k, v in pairs}


def parses(argv: list[str]) -> None:
    """The edge-monitor parser accepts ``argv`` (argparse exits on anything it rejects)."""
    build_parser().parse_args(argv)


def test_the_unit_runs_the_agent_as_a_hardened_service_with_its_own_state_folder():
    unit = unit_sections(UNIT)
    service = {k: v[-1] for k, v in unit["Service"].items()}
    assert service["DynamicUser"] == "yes" or service.get("User") not in (None, "root")
    assert service["StateDirectory"] == "edge-monitor" and service["ProtectSystem"] == "strict"
    assert service["Restart"] == "on-failure" and service["RestartPreventExitStatus"] == "2"
    assert service["KillSignal"] == "SIGTERM" and service["NoNewPrivileges"] == "yes"
    assert unit["Install"]["WantedBy"] == ["multi-user.target"]
    command = shlex.split(service["ExecStart"])
    assert command[0].endswith("/bin/edge-monitor") and command[1] == "run"
    env = env_file()
    argv = [env.get(a[2:-1], a) if a.startswith("${") else a for a in command[1:]]
    parses(argv)
    options = dict(zip(argv[1::2], argv[2::2]))
    # ProtectSystem=strict makes everything read-only but the folders systemd gives the service
    assert options["--state-dir"] == "/var/lib/" + service["StateDirectory"]
    assert Path(options["--jsonl"]).parent == Path("/var/log") / service["LogsDirectory"]
    assert Path(options["--config"]).parent == Path("/etc") / service["ConfigurationDirectory"]
    assert set(env) == {a[2:-1] for a in command if a.startswith("${")}


@pytest.mark.skipif(shutil.which("systemd-analyze") is None, reason="systemd-analyze is not installed here")
def test_systemd_analyze_verify_accepts_the_unit(tmp_path):
    # verify checks that ExecStart's program exists: point it at this installation's edge-monitor
    text = UNIT.read_text().replace("/opt/edge-monitor/bin/edge-monitor", str(Path(sys.executable).parent /
                                                                            "edge-monitor"))
    text = text.replace("EnvironmentFile=/etc/", "EnvironmentFile=-/etc/")
    unit = tmp_path / "edge-monitor.service"
    unit.write_text(text)
    done = subprocess.run(["systemd-analyze", "verify", str(unit)], capture_output=True, text=True, timeout=120)
    complaints = [line for line in (done.stdout + done.stderr).splitlines() if str(unit) in line]
    assert done.returncode == 0 and not complaints, done.stdout + done.stderr


def container_instructions() -> list[tuple[str, str]]:
    """(INSTRUCTION, arguments) with continuation lines joined and comments dropped."""
    joined = CONTAINER.read_text().replace("\\\n", " ")
    return [(line.split(None, 1)[0].upper(), line.split(None, 1)[1].strip())
            for line in joined.splitlines() if line.strip() and not line.lstrip().startswith("#")]


def test_the_container_runs_the_agent_as_a_non_root_user_with_a_health_check():
    steps = container_instructions()
    kinds = [k for k, _ in steps]
    assert kinds[0] == "FROM" and "joint_wear_monitor-" in dict(steps)["COPY"]
    user = [v for k, v in steps if k == "USER"][-1]
    assert user not in ("root", "0") and not user.startswith("0:")
    entrypoint = json.loads(dict(steps)["ENTRYPOINT"])
    cmd = json.loads(dict(steps)["CMD"])
    assert entrypoint[:2] == ["edge-monitor", "run"]
    parses(entrypoint[1:] + cmd)
    options = dict(zip(entrypoint[2::2], entrypoint[3::2]))
    volume = json.loads(dict(steps)["VOLUME"])[0]
    assert options["--state-dir"].startswith(volume + "/") and options["--jsonl"].startswith(volume + "/")
    health = dict(steps)["HEALTHCHECK"]
    check = json.loads(health.split("CMD", 1)[1])
    assert check[0] == "edge-monitor" and "listen" in check and check[check.index("--kind") + 1] == "health"
    parses(check[1:])
    # the health check listens where the agent listens, and gives up before Docker's timeout
    assert check[check.index("--zenoh-connect") + 1] == options["--zenoh-listen"]
    timeout = float(health.split("--timeout=", 1)[1].split("s", 1)[0])
    assert float(check[check.index("--duration") + 1]) < timeout
    assert dict(steps)["STOPSIGNAL"] == "SIGTERM"
