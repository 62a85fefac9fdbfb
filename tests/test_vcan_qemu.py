"""SocketCAN for real: `sim-controller run` → vcan0 → `edge-monitor run` inside a qemu guest.

The host kernel has no CAN, so tools/vcan_qemu boots a Debian kernel (with can, can-raw, can-dev, vcan
modules) under qemu; the guest runs the project's own console scripts from the host's .venv (host /
mounted read-only over 9p) and writes its results to a writable 9p share read back here.

The guest run takes about two minutes under emulation, so it runs only with VCAN_QEMU=1
(`make test-vcan`, which CI runs after `make test`); it is skipped, with the reason, where qemu or the
kernel package cannot be had. The quick checks of the tool's pieces at the bottom always run.
"""

from __future__ import annotations

import importlib.util
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

TOOL = Path(__file__).resolve().parent.parent / "tools" / "vcan_qemu" / "vcan_qemu.py"
_spec = importlib.util.spec_from_file_location("vcan_qemu", TOOL)
vq = importlib.util.module_from_spec(_spec)
sys.modules["vcan_qemu"] = vq          # dataclasses resolve their module by name
_spec.loader.exec_module(vq)

WORKLOAD = vq.Workload(joints=1, cycles=3)
GUEST_TIMEOUT_S = 1500.0               # qemu is killed after this (measured: ~2 min here)
RUN_GUEST = os.environ.get("VCAN_QEMU") == "1"
guest_only = [pytest.mark.slow, pytest.mark.timeout(GUEST_TIMEOUT_S + 300),
              pytest.mark.skipif(not RUN_GUEST, reason="boots a qemu guest (~2 min): run with `make test-vcan`")]


@pytest.fixture(scope="module")
def guest():
    """One guest run shared by the tests below."""
    try:
        return vq.run_guest(WORKLOAD, timeout_s=GUEST_TIMEOUT_S)
    except vq.Unavailable as exc:
        pytest.skip(f"SocketCAN under qemu cannot run here: {exc}")


class TestGuestRun:
    pytestmark = guest_only

    def test_both_commands_ran_to_the_end(self, guest):
        assert guest.sim_rc == 0, guest.logs.get("sim.log")
        assert guest.agent_rc == 0, guest.logs.get("agent.log")
        # the agent stopped by itself (--idle-stop) after the simulator had finished
        assert guest.timings()["agent_done_s"] > guest.timings()["sim_done_s"]

    def test_every_frame_the_simulator_sent_reached_the_agent_intact(self, guest):
        agent = guest.agent
        assert agent, f"no status line in the agent's log:\n{guest.logs.get('agent.log')}"
        assert guest.faults and not any(guest.faults.values()), guest.faults    # a clean link: no injected faults
        assert guest.frames_sent and guest.frames_sent > 0
        assert agent["frames_total"] == guest.frames_sent, (agent, guest.frames_sent)
        assert agent["frames_ok"] == guest.frames_sent
        assert agent["crc_errors"] == 0 and agent["counter_lost"] == 0
        assert agent["queue_dropped"] == 0 and agent["queue_depth"] == 0

    def test_one_symptom_per_joint_per_completed_cycle(self, guest):
        # The simulator ran `cycles` cycles; the agent closes a cycle when the next one begins, and the
        # last one when the stream ends (--idle-stop), as replay does at the end of a file.
        assert len(guest.truth) == WORKLOAD.joints * WORKLOAD.cycles
        completed = {(j, c) for j in range(WORKLOAD.joints) for c in range(WORKLOAD.cycles)}
        keys = [(s["joint"], s["cycle"]) for s in guest.symptoms]
        assert len(keys) == len(set(keys)) and set(keys) == completed, keys
        assert guest.agent["cycles"] == guest.agent["symptoms"] == len(completed)
        assert all(s["friction"]["speeds"] == list(WORKLOAD.speeds) for s in guest.symptoms)

    def test_symptoms_equal_a_host_replay_of_the_same_run(self, guest, tmp_path: Path):
        """Same seed, same frames: the live SocketCAN path gives what a recorded log gives on the host."""
        log, symptoms = tmp_path / "run.blf", tmp_path / "symptoms.jsonl"
        (tmp_path / "agent.toml").write_text(WORKLOAD.agent_config())
        subprocess.run([sys.executable, "-m", "sim_controller.cli", "record", "--out", str(log), *WORKLOAD.sim_args()],
                       check=True, capture_output=True, timeout=300)
        replay = subprocess.run([sys.executable, "-m", "edge_monitor.cli", "replay", str(log), "--json",
                                 "--config", str(tmp_path / "agent.toml"), "--jsonl", str(symptoms)],
                                check=True, capture_output=True, text=True, timeout=300)
        assert json.loads(replay.stdout)["frames_total"] == guest.frames_sent
        host = {(s["joint"], s["cycle"]): s for s in vq.read_jsonl(symptoms)}
        assert sorted(host) == sorted((s["joint"], s["cycle"]) for s in guest.symptoms)
        for s in guest.symptoms:
            h = host[(s["joint"], s["cycle"])]
            # only the summation order may differ (blocks are cut where the frames happened to arrive)
            np.testing.assert_allclose(s["friction"]["torque"], h["friction"]["torque"], rtol=1e-9)
            np.testing.assert_allclose(s["friction"]["stderr"], h["friction"]["stderr"], rtol=1e-6)
            assert s["kl"]["n_samples"] == h["kl"]["n_samples"] > 0


# --- the tool's pieces (always run, no qemu) ------------------------------------------------------

def test_the_status_line_parser_reads_the_agents_real_status_line(tmp_path: Path):
    proc = subprocess.run([sys.executable, "-m", "edge_monitor.cli", "-v", "run", "--link", "virtual:vcan-status",
                           "--no-zenoh", "--duration", "0.5", "--state-dir", str(tmp_path)],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    matches = list(vq.STATUS_LINE.finditer(proc.stderr))
    assert matches, proc.stderr
    assert {k: int(v) for k, v in matches[-1].groupdict().items()}["frames_total"] == 0


def test_a_dynamically_linked_program_is_not_taken_for_a_static_busybox():
    assert not vq.is_static_elf(Path(os.path.realpath(sys.executable)))
    assert not vq.is_static_elf(TOOL)


def test_the_guest_has_no_network_and_reads_the_host_read_only(tmp_path: Path):
    kernel = vq.Kernel("6.1.0-0-amd64", tmp_path / "vmlinuz", {})
    cmd = vq.qemu_command("qemu-system-x86_64", kernel, tmp_path / "initrd", tmp_path / "results", tmp_path / "c.log")
    assert "-nodefaults" in cmd and not any(a in cmd for a in ("-nic", "-netdev", "-net"))
    root_share = next(a for a in cmd if "mount_tag=hostroot" in a)
    assert "path=/," in root_share and "readonly=on" in root_share


def test_modules_load_after_their_dependencies(tmp_path: Path):
    def ko(name: str, depends: str) -> Path:
        path = tmp_path / f"{name}.ko"
        path.write_bytes(b"\x7fELF junk\x00license=GPL\x00depends=" + depends.encode() + b"\x00name=x\x00")
        return path
    modules = {"vcan": ko("vcan", "can-dev"), "can_dev": ko("can-dev", ""), "can_raw": ko("can-raw", "can"),
               "can": ko("can", "")}
    kernel = vq.Kernel("test", tmp_path / "vmlinuz", modules)
    order = [p.name for p in vq.load_order(kernel, ("can_raw", "vcan"))]
    assert order == ["can.ko", "can-raw.ko", "can-dev.ko", "vcan.ko"]
    with pytest.raises(vq.Unavailable, match="module 9p not found"):
        vq.load_order(kernel, ("9p",))


def test_without_qemu_and_root_the_reason_says_what_to_install(monkeypatch):
    monkeypatch.setattr(vq, "find_tools", lambda: (None, "/bin/busybox"))
    monkeypatch.setattr(vq.os, "geteuid", lambda: 1000)
    monkeypatch.setattr(vq.shutil, "which", lambda name: f"/usr/bin/{name}")
    with pytest.raises(vq.Unavailable, match="qemu-system-x86 missing; install as root: apt-get install -y qemu-system-x86"):
        vq.ensure_tools({})
