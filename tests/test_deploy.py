"""The service files: the systemd unit (verified by `systemd-analyze verify` and scored by `systemd-analyze
security` where it exists, always parsed), its logrotate snippet and CAN bring-up (shipped in the package,
printed by `edge-monitor deploy`), and the container file (no container engine here: its base image, user,
paths, entrypoint, health check and build context are checked). Every command line in them must parse
with the real CLI."""

from __future__ import annotations

import json
import os
import re
import shlex
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from edge_monitor.cli import build_parser
from edge_monitor.sinks.loopback import free_loopback_port

ROOT = Path(__file__).resolve().parents[1]
DEPLOY, SHIPPED = ROOT / "deploy", ROOT / "edge_monitor" / "deploy"
UNIT, ENV, CONTAINER = DEPLOY / "edge-monitor.service", DEPLOY / "edge-monitor.env", DEPLOY / "Containerfile"
LOGROTATE, NETWORK, BRING_UP = SHIPPED / "edge-monitor.logrotate", SHIPPED / "80-can0.network", SHIPPED / "can-bring-up.sh"


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


def test_the_unit_tells_systemd_when_data_stops_reloads_and_follows_its_can_device():
    unit = unit_sections(UNIT)
    service = {k: v[-1] for k, v in unit["Service"].items()}
    assert service["Type"] == "notify" and float(service["WatchdogSec"]) > 0
    assert service["ExecReload"] == "/bin/kill -HUP $MAINPID"       # SIGHUP: the JSONL output reopens its path
    link = env_file()["EDGE_MONITOR_LINK"]
    assert link.startswith("socketcan:")
    device = f"sys-subsystem-net-devices-{link.split(':', 1)[1]}.device"
    assert unit["Unit"]["BindsTo"] == [device] and device in unit["Unit"]["After"][0].split()


def test_the_unit_is_hardened_and_talks_ip_only_to_this_box_and_the_router():
    service = unit_sections(UNIT)["Service"]
    one = {k: v[-1] for k, v in service.items()}
    for key in ("MemoryDenyWriteExecute", "ProtectClock", "ProtectKernelLogs", "PrivateDevices", "ProtectSystem",
                "NoNewPrivileges", "RestrictNamespaces"):
        assert one[key] in ("yes", "strict"), key
    assert "@system-service" in service["SystemCallFilter"] and any(v.startswith("~") for v in service["SystemCallFilter"])
    assert one["IPAddressDeny"] == "any"
    router = env_file()["EDGE_MONITOR_ZENOH"].split("/")[1].rsplit(":", 1)[0]
    allowed = " ".join(service["IPAddressAllow"]).split()
    assert router in allowed or (router.startswith("127.") and "localhost" in allowed)


@pytest.mark.skipif(shutil.which("systemd-analyze") is None, reason="systemd-analyze is not installed here")
def test_systemd_analyze_security_scores_the_unit_low(tmp_path):
    """Before issue 50: 4.3 ("OK"); now 1.4 with systemd 252 (docs/RELIABILITY.md)."""
    text = UNIT.read_text().replace("/opt/edge-monitor/bin/edge-monitor", str(Path(sys.executable).parent /
                                                                            "edge-monitor"))
    unit = tmp_path / "edge-monitor.service"
    unit.write_text(text.replace("EnvironmentFile=/etc/", "EnvironmentFile=-/etc/"))
    done = subprocess.run(["systemd-analyze", "security", "--offline=yes", "--no-pager", str(unit)],
                          capture_output=True, text=True, timeout=120)
    if "--offline" in done.stderr:
        pytest.skip("this systemd-analyze has no --offline")
    score = float(done.stdout.split("Overall exposure level for edge-monitor.service:")[1].split()[0])
    assert score <= 2.0, done.stdout[-3000:]


def test_no_write_and_execute_memory_is_needed(tmp_path):
    """MemoryDenyWriteExecute=yes: the agent (numpy, scipy, zenoh, canopen) runs under the kernel's own
    refusal of writable-executable memory (prctl PR_SET_MDWE, Linux ≥ 6.3), publishing over Zenoh."""
    import ctypes
    libc = ctypes.CDLL(None, use_errno=True)
    probe = subprocess.run([sys.executable, "-c", "import ctypes, sys; sys.exit(ctypes.CDLL(None).prctl(65, 1, 0, 0, 0))"])
    if probe.returncode != 0 or not hasattr(libc, "prctl"):
        pytest.skip("this kernel has no PR_SET_MDWE")
    script = ("import ctypes, sys; assert ctypes.CDLL(None).prctl(65, 1, 0, 0, 0) == 0; "
              "from edge_monitor.cli import main; sys.exit(main(sys.argv[1:]))")
    port = free_loopback_port()
    done = subprocess.run([sys.executable, "-c", script, "replay", str(ROOT / "tests" / "corpus" / "clean.blf"),
                           "--json", "-q", "--mapping", str(ROOT / "protocol" / "mappings" / "cia402.toml")],
                          capture_output=True, text=True, timeout=300)
    assert "Traceback" not in done.stderr, done.stderr[-2000:]
    done = subprocess.run([sys.executable, "-c", script, "run", "--link", "virtual:mdwe", "--duration", "2",
                           "--zenoh-listen", f"tcp/127.0.0.1:{port}", "--json", "-q"],
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0 and json.loads(done.stdout)["health"]["health_published"] >= 1, done.stderr[-2000:]


def test_logrotate_and_the_can_bring_up_fit_the_unit(tmp_path):
    unit = {k: v[-1] for k, v in unit_sections(UNIT)["Service"].items()}
    jsonl = shlex.split(unit["ExecStart"])[shlex.split(unit["ExecStart"]).index("--jsonl") + 1]
    rotate = LOGROTATE.read_text()
    assert rotate.split("{")[0].strip().splitlines()[-1].strip() == jsonl
    assert "systemctl reload edge-monitor.service" in rotate and "delaycompress" in rotate
    assert "jsonl_max_bytes = 0" in rotate            # one rotation at a time: logrotate's or the agent's
    if shutil.which("logrotate"):
        conf = tmp_path / "r.conf"
        conf.write_text(rotate.replace(jsonl, str(tmp_path / "s.jsonl")))
        done = subprocess.run(["logrotate", "-d", "-s", str(tmp_path / "state"), str(conf)], capture_output=True,
                              text=True, timeout=60)
        assert done.returncode == 0 and "error" not in done.stderr.lower(), done.stderr
    network = unit_sections(NETWORK)
    iface = env_file()["EDGE_MONITOR_LINK"].split(":", 1)[1]
    assert network["Match"]["Name"] == [iface] and int(network["CAN"]["BitRate"][0]) == 1_000_000
    assert 'BITRATE="${2:-1000000}"' in BRING_UP.read_text() and os.access(BRING_UP, os.X_OK)
    assert subprocess.run(["sh", "-n", str(BRING_UP)], timeout=30).returncode == 0


def test_the_wheel_ships_the_service_files_and_prints_them(tmp_path):
    for name in ("edge-monitor.service", "edge-monitor.env"):
        assert (DEPLOY / name).resolve() == (SHIPPED / name).resolve()    # deploy/ links to what is shipped
    listed = subprocess.run([sys.executable, "-m", "edge_monitor.cli", "deploy", "--list"], capture_output=True,
                            text=True, timeout=60, check=True).stdout.split()
    for path in SHIPPED.iterdir():
        assert path.name in listed
        printed = subprocess.run([sys.executable, "-m", "edge_monitor.cli", "deploy", path.name], capture_output=True,
                                 timeout=60, check=True).stdout
        assert printed == path.read_bytes()
    assert {"agent.toml", "mappings/cia402.toml", "eds/cia402_drive.eds", "dbc/foreign_robot.dbc"} <= set(listed)


def test_the_container_pins_its_base_builds_from_the_wheel_only_and_checks_the_data():
    steps = container_instructions()
    image = dict(steps)["FROM"]
    assert re.fullmatch(r"python:3\.\d+-slim@sha256:[0-9a-f]{64}", image), image
    user = [v for k, v in steps if k == "USER"][-1]
    uid, _, gid = user.partition(":")
    assert uid not in ("0", "root") and gid not in ("", "0", "root")
    assert "--gid 0" not in dict(steps)["RUN"] and f"--gid {gid}" in dict(steps)["RUN"]
    check = json.loads(dict(steps)["HEALTHCHECK"].split("CMD", 1)[1])
    assert "--require-data-flowing" in check
    ignore = [line for line in (ROOT / ".dockerignore").read_text().splitlines() if line and not line.startswith("#")]
    assert ignore == ["*", "!dist/joint_wear_monitor-*.whl"]
