#!/usr/bin/env python3
"""SocketCAN for real: boot a Debian kernel under qemu and stream the simulator to the agent over vcan0.

The host kernel has no CAN. This tool fetches Debian's ``linux-image-amd64`` kernel (it has ``can``,
``can-raw``, ``can-dev`` and ``vcan`` as modules), builds a busybox initramfs around
``guest_init.sh`` and boots it with qemu (TCG, ``-cpu max``). The guest mounts the host's ``/``
read-only over 9p and runs the project's own ``.venv`` console scripts — ``edge-monitor run`` and
``sim-controller run``, both with ``--link socketcan:vcan0`` — and writes their outputs to a writable
9p share that this tool reads back into a :class:`GuestResult`.

Needs ``qemu-system-x86_64``, a static busybox and Debian's apt (installed with apt-get when missing
and running as root). The kernel is cached under ``.cache/vcan_qemu/`` (git-ignored).
:class:`Unavailable` says why the run cannot be done here; :class:`GuestFailure` why it failed.

    .venv/bin/python tools/vcan_qemu/vcan_qemu.py            # run once, print a summary (exit 1 on failure)
    .venv/bin/python tools/vcan_qemu/vcan_qemu.py --json     # the summary as JSON
"""

from __future__ import annotations

import argparse
import json
import logging
import lzma
import os
import re
import shlex
import shutil
import struct
import subprocess
import sys
import tarfile
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

log = logging.getLogger("vcan_qemu")

ROOT = Path(__file__).resolve().parents[2]
CACHE = ROOT / ".cache" / "vcan_qemu"
INIT_SCRIPT = Path(__file__).with_name("guest_init.sh")
KERNEL_META_PACKAGE = "linux-image-amd64"      # depends on the current linux-image-<abi>-amd64
APT_PACKAGES = ("qemu-system-x86", "busybox-static")
# Module directories (under lib/modules/<version>/kernel) extracted from the kernel package.
MODULE_DIRS = ("drivers/virtio/", "net/9p/", "fs/9p/", "fs/netfs/", "fs/fscache/", "net/can/", "drivers/net/can/")
# Modules the guest needs; their dependencies (from each module's own modinfo) are loaded first.
GUEST_MODULES = ("virtio_pci", "9pnet_virtio", "9p", "can_raw", "vcan")
CONSOLE_TAIL_LINES = 40
STATUS_LINE = re.compile(r"status: (?P<frames_total>\d+) frames \([^)]*\), ok (?P<frames_ok>\d+), crc (?P<crc_errors>\d+), "
                         r"lost (?P<counter_lost>\d+), out of sequence (?P<wrong_sequence>\d+), "
                         r"queue (?P<queue_depth>\d+) \(dropped (?P<queue_dropped>\d+)\), "
                         r"cycles (?P<cycles>\d+), symptoms (?P<symptoms>\d+), alarms (?P<alarms>\d+)")


class Unavailable(RuntimeError):
    """qemu, busybox or the kernel cannot be had on this machine (the run is skipped, not failed)."""


class GuestFailure(RuntimeError):
    """The guest run did not complete (timeout, a guest step failed, results missing)."""


@dataclass(frozen=True)
class Workload:
    """What the guest runs: a short simulator run, paced, into the live agent."""

    joints: int = 1
    cycles: int = 3
    speeds: tuple[float, ...] = (8.7, 41.7, 133.5)   # rad/s, motor side
    plateau_s: float = 0.8        # ≥ settle 0.25 + min_steady 0.3 + guard 0.02 of the agent's segmentation
    speedup: float = 1.0          # simulator pacing (× real time)
    seed: int = 0
    idle_stop_s: float = 20.0     # the agent stops after this long without frames
    step_timeout_s: int = 900     # guest-side bound for each command [s]
    rmem_bytes: int = 64 << 20    # guest socket receive buffer: holds a whole run

    def sim_args(self) -> list[str]:
        """The simulation options (shared by `sim-controller run` and `record`)."""
        return ["--joints", str(self.joints), "--cycles", str(self.cycles), "--seed", str(self.seed),
                "--speeds", ",".join(f"{v:g}" for v in self.speeds), "--plateau-time", f"{self.plateau_s:g}"]

    def agent_config(self) -> str:
        speeds = ", ".join(f"{v:g}" for v in self.speeds)
        # no per-joint model learning: the 3 cycles would all be spent learning it, and the KL path
        # (whose sample counts the host comparison checks) would never run
        return (f'robot = "vcan-guest"\nstatus_interval_s = 10.0\n[segmentation]\nspeeds = [{speeds}]\n'
                '[model]\nenabled = false\n')


@dataclass
class GuestResult:
    """What came back from the guest (counts from the simulator's truth file and the agent's last status line)."""

    status: dict[str, str]
    frames_sent: int | None
    faults: dict[str, int]
    agent: dict[str, int]
    symptoms: list[dict] = field(repr=False)
    truth: list[dict] = field(repr=False)
    wall_s: float = 0.0
    logs: dict[str, str] = field(default_factory=dict, repr=False)

    @property
    def sim_rc(self) -> int | None:
        return _int_or_none(self.status.get("sim_rc"))

    @property
    def agent_rc(self) -> int | None:
        return _int_or_none(self.status.get("agent_rc"))

    def timings(self) -> dict[str, float]:
        """Guest uptimes at each step [s] and the host's wall time of the whole run."""
        out = {k: float(v) for k, v in self.status.items() if k.endswith("_s")}
        out["host_wall_s"] = round(self.wall_s, 1)
        return out

    def summary(self) -> dict:
        return {"status": self.status, "frames_sent": self.frames_sent, "faults": self.faults, "agent": self.agent,
                "symptoms": len(self.symptoms), "symptom_keys": sorted((s["joint"], s["cycle"]) for s in self.symptoms),
                "timings": self.timings()}


def _int_or_none(text: str | None) -> int | None:
    try:
        return int(text) if text is not None else None
    except ValueError:
        return None


# --- host packages ----------------------------------------------------------------------------------

def is_static_elf(path: Path) -> bool:
    """True if ``path`` is an ELF64 executable without a program interpreter (statically linked)."""
    with open(path, "rb") as fh:
        head = fh.read(64)
        if head[:4] != b"\x7fELF" or head[4] != 2:
            return False
        phoff, = struct.unpack_from("<Q", head, 32)
        phentsize, phnum = struct.unpack_from("<HH", head, 54)
        fh.seek(phoff)
        table = fh.read(phentsize * phnum)
    return all(struct.unpack_from("<I", table, i * phentsize)[0] != 3 for i in range(phnum))   # 3 = PT_INTERP


def find_tools() -> tuple[str | None, str | None]:
    """(qemu-system-x86_64, static busybox) paths, None where missing."""
    qemu = shutil.which("qemu-system-x86_64")
    busybox = next((p for p in ("/bin/busybox", "/usr/bin/busybox", shutil.which("busybox"))
                    if p and Path(p).is_file() and is_static_elf(Path(p))), None)
    return qemu, busybox


def _apt(*args: str, timeout: float = 600) -> subprocess.CompletedProcess:
    env = dict(os.environ, DEBIAN_FRONTEND="noninteractive")
    return subprocess.run(list(args), capture_output=True, text=True, timeout=timeout, env=env, check=False)


def _apt_update_once(state: dict) -> None:
    if not state.get("updated") and os.geteuid() == 0:
        proc = _apt("apt-get", "update", "-qq")
        state["updated"] = True
        if proc.returncode != 0:
            log.warning("apt-get update failed: %s", proc.stderr.strip().splitlines()[-1:] or proc.returncode)


def ensure_tools(apt_state: dict) -> tuple[str, str]:
    """qemu and a static busybox, installed with apt-get if missing (root only); else :class:`Unavailable`."""
    qemu, busybox = find_tools()
    if qemu and busybox:
        return qemu, busybox
    missing = [p for p, have in zip(APT_PACKAGES, (qemu, busybox)) if not have]
    if shutil.which("apt-get") is None:
        raise Unavailable(f"{', '.join(missing)} missing and no apt-get to install them")
    if os.geteuid() != 0:
        raise Unavailable(f"{', '.join(missing)} missing; install as root: apt-get install -y {' '.join(missing)}")
    log.info("installing %s", " ".join(missing))
    proc = _apt("apt-get", "install", "-y", "-qq", "--no-install-recommends", *missing)
    if proc.returncode != 0:
        _apt_update_once(apt_state)
        proc = _apt("apt-get", "install", "-y", "-qq", "--no-install-recommends", *missing)
    qemu, busybox = find_tools()
    if not (qemu and busybox):
        tail = (proc.stderr.strip().splitlines() or ["?"])[-1]
        raise Unavailable(f"apt-get install {' '.join(missing)} failed ({tail})")
    return qemu, busybox


# --- kernel -----------------------------------------------------------------------------------------

@dataclass(frozen=True)
class Kernel:
    """A kernel image and the subset of its modules the guest needs, extracted from a Debian package."""

    version: str
    vmlinuz: Path
    modules: dict[str, Path]         # module name (dashes as underscores) -> .ko file


def _module_name(path: Path) -> str:
    return path.name.split(".ko")[0].replace("-", "_")


def load_kernel(directory: Path) -> Kernel | None:
    """The kernel extracted in ``directory`` (with its completion stamp), or None."""
    if not (directory / "complete").is_file():
        return None
    vmlinuz = next(iter(sorted((directory / "boot").glob("vmlinuz-*"))), None)
    if vmlinuz is None:
        return None
    modules = {_module_name(p): p for p in (directory / "modules").glob("*.ko")}
    return Kernel(vmlinuz.name.removeprefix("vmlinuz-"), vmlinuz, modules)


def cached_kernel(cache: Path) -> Kernel | None:
    """The newest complete kernel under ``cache`` (no network needed once one is there)."""
    kernels = [k for d in sorted(cache.glob("linux-image-*")) if (k := load_kernel(d)) is not None]
    return kernels[-1] if kernels else None


def resolve_kernel_package(apt_state: dict) -> str:
    """The concrete kernel package the ``linux-image-amd64`` meta-package depends on."""
    if shutil.which("apt-cache") is None or shutil.which("apt-get") is None:
        raise Unavailable("no apt (Debian's package tools) to fetch the kernel package")
    for attempt in range(2):
        proc = _apt("apt-cache", "depends", KERNEL_META_PACKAGE, timeout=120)
        names = re.findall(r"Depends: (linux-image-\S+)", proc.stdout)
        if names:
            return names[0]
        if attempt == 0:
            _apt_update_once(apt_state)
    raise Unavailable(f"apt knows no {KERNEL_META_PACKAGE} (run apt-get update as root?)")


def fetch_kernel(cache: Path, apt_state: dict) -> Kernel:
    """Download the kernel package with apt-get, extract vmlinuz and the needed modules into ``cache``."""
    cached = cached_kernel(cache)
    if cached is not None:
        return cached
    cache.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=cache) as tmp:
        package, deb = download_kernel(Path(tmp), apt_state)
        target = cache / package
        shutil.rmtree(target, ignore_errors=True)
        extract_kernel(deb, target)
    kernel = load_kernel(target)
    if kernel is None:
        raise Unavailable(f"{package}: no vmlinuz in the package")
    return kernel


def download_kernel(directory: Path, apt_state: dict) -> tuple[str, Path]:
    """(package name, .deb) fetched with apt-get download; stale package lists are updated once (root)."""
    sandbox = ["-o", "APT::Sandbox::User=root"] if os.geteuid() == 0 else []
    while True:
        package = resolve_kernel_package(apt_state)
        proc = subprocess.run(["apt-get", *sandbox, "download", package], cwd=directory, capture_output=True,
                              text=True, timeout=900, check=False)
        debs = list(directory.glob("*.deb"))
        if proc.returncode == 0 and debs:
            return package, debs[0]
        if apt_state.get("updated") or os.geteuid() != 0:
            tail = (proc.stderr.strip().splitlines() or ["?"])[-1]
            raise Unavailable(f"apt-get download {package} failed ({tail})")
        _apt_update_once(apt_state)


def extract_kernel(deb: Path, target: Path) -> None:
    """vmlinuz to ``target/boot``, the modules of ``MODULE_DIRS`` (decompressed) to ``target/modules``."""
    (target / "boot").mkdir(parents=True)
    (target / "modules").mkdir()
    proc = subprocess.Popen(["dpkg-deb", "--fsys-tarfile", str(deb)], stdout=subprocess.PIPE)
    try:
        with tarfile.open(fileobj=proc.stdout, mode="r|*") as tar:
            for member in tar:
                if not member.isfile():
                    continue
                name = member.name.removeprefix("./")
                if re.fullmatch(r"boot/vmlinuz-[^/]+", name):
                    out = target / name
                elif "/kernel/" in name and any(f"/kernel/{d}" in name for d in MODULE_DIRS) \
                        and re.search(r"\.ko(\.xz)?$", name):
                    out = target / "modules" / Path(name).name.removesuffix(".xz")
                else:
                    continue
                extracted = tar.extractfile(member)
                if extracted is None:
                    continue
                data = extracted.read()
                out.write_bytes(lzma.decompress(data) if name.endswith(".xz") else data)
    finally:
        proc.wait()
    if proc.returncode != 0:
        raise Unavailable(f"dpkg-deb --fsys-tarfile {deb.name} failed")
    (target / "complete").write_text(deb.name + "\n")


def module_dependencies(path: Path) -> list[str]:
    """The ``depends=`` field of a module's .modinfo (names with underscores)."""
    match = re.search(rb"(?:^|\x00)depends=([^\x00]*)\x00", path.read_bytes())
    if match is None:
        return []
    return [m.replace("-", "_") for m in match.group(1).decode().split(",") if m]


def load_order(kernel: Kernel, wanted: tuple[str, ...] = GUEST_MODULES) -> list[Path]:
    """The .ko files to insmod, dependencies first."""
    order: list[Path] = []
    seen: set[str] = set()

    def visit(name: str) -> None:
        if name in seen:
            return
        seen.add(name)
        if name not in kernel.modules:
            raise Unavailable(f"kernel {kernel.version}: module {name} not found (built in or missing?)")
        for dep in module_dependencies(kernel.modules[name]):
            visit(dep)
        order.append(kernel.modules[name])

    for name in wanted:
        visit(name)
    return order


# --- initramfs and qemu -----------------------------------------------------------------------------

def build_initramfs(kernel: Kernel, busybox: str, workdir: Path) -> Path:
    """A newc cpio archive: static busybox, ``guest_init.sh`` as /init, the modules and their load order."""
    stage = workdir / "initramfs"
    for d in ("bin", "lib/modules", "dev", "proc", "sys", "host", "results"):
        (stage / d).mkdir(parents=True, exist_ok=True)
    shutil.copy2(busybox, stage / "bin" / "busybox")
    shutil.copy2(INIT_SCRIPT, stage / "init")
    (stage / "init").chmod(0o755)
    order = load_order(kernel)
    for ko in order:
        shutil.copy2(ko, stage / "lib" / "modules" / ko.name)
    (stage / "lib" / "modules" / "load-order").write_text("".join(ko.name + "\n" for ko in order))
    archive = workdir / "initramfs.cpio"
    names = sorted(str(p.relative_to(stage)) for p in stage.rglob("*"))
    with open(archive, "wb") as out:
        subprocess.run([busybox, "cpio", "-o", "-H", "newc", "-R", "0:0"], cwd=stage, input="\n".join(names).encode(),
                       stdout=out, stderr=subprocess.DEVNULL, check=True)
    return archive


def qemu_command(qemu: str, kernel: Kernel, initrd: Path, results: Path, console: Path,
                 smp: int = 2, memory_mb: int = 2048) -> list[str]:
    """The qemu command line: TCG (``-cpu max`` has x86-64-v2 for numpy), serial console to a file,
    the host's / read-only and ``results`` writable over virtio 9p, no network, exit on reboot."""
    accel = os.environ.get("VCAN_QEMU_ACCEL", "tcg")
    return [
        qemu, "-accel", accel, "-cpu", "max", "-smp", str(smp), "-m", str(memory_mb),
        "-nodefaults", "-display", "none", "-no-reboot", "-serial", f"file:{console}",
        "-kernel", str(kernel.vmlinuz), "-initrd", str(initrd),
        "-append", "console=ttyS0 panic=-1 loglevel=4",
        "-virtfs", "local,path=/,mount_tag=hostroot,security_model=none,readonly=on,multidevs=remap",
        "-virtfs", f"local,path={results},mount_tag=results,security_model=none",
    ]


def write_job(results: Path, workload: Workload, venv_bin: Path) -> None:
    """The guest's job.env (shell variables) and the agent's config, in the results share."""
    for path in (results.resolve(), venv_bin):
        if any(c.isspace() for c in str(path)):
            raise GuestFailure(f"{path}: the guest script takes paths without white space")
    sim_args = [*workload.sim_args(), "--speedup", f"{workload.speedup:g}"]
    env = {"VENV_BIN": str(venv_bin), "RESULTS_DIR": str(results.resolve()), "SIM_ARGS": " ".join(sim_args),
           "IDLE_STOP_S": f"{workload.idle_stop_s:g}", "STEP_TIMEOUT_S": str(workload.step_timeout_s),
           "RMEM_BYTES": str(workload.rmem_bytes)}
    (results / "job.env").write_text("".join(f"{k}={shlex.quote(v)}\n" for k, v in env.items()))
    (results / "agent.toml").write_text(workload.agent_config())


def _tail(path: Path, lines: int = CONSOLE_TAIL_LINES) -> str:
    try:
        return "\n".join(path.read_text(errors="replace").splitlines()[-lines:])
    except OSError:
        return "(none)"


def boot(qemu_cmd: list[str], console: Path, timeout_s: float) -> None:
    """Run qemu until the guest powers off; kill it and raise :class:`GuestFailure` on timeout."""
    log.info("booting: %s", shlex.join(qemu_cmd))
    proc = subprocess.Popen(qemu_cmd, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            text=True)
    try:
        out, _ = proc.communicate(timeout=timeout_s)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.communicate()
        raise GuestFailure(f"the qemu guest did not finish within {timeout_s:.0f} s and was killed; "
                           f"last console lines:\n{_tail(console)}") from None
    if proc.returncode != 0:
        raise GuestFailure(f"qemu exited with {proc.returncode}: {out.strip()[-2000:]}\nconsole:\n{_tail(console)}")


# --- results ----------------------------------------------------------------------------------------

def read_jsonl(path: Path) -> list[dict]:
    if not path.is_file():
        return []
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()]


def parse_results(results: Path, console: Path) -> GuestResult:
    """Read the files the guest wrote; :class:`GuestFailure` if it did not get to the end."""
    status_file = results / "status"
    status = dict(line.split("=", 1) for line in status_file.read_text().splitlines() if "=" in line) \
        if status_file.is_file() else {}
    logs = {name: (results / name).read_text(errors="replace") for name in ("sim.log", "agent.log")
            if (results / name).is_file()}
    if status.get("done") != "1":
        reason = status.get("failed", "no completion marker in the results")
        raise GuestFailure(f"the guest run failed: {reason}\nconsole:\n{_tail(console)}\n"
                           + "".join(f"--- {k} (tail)\n{v[-3000:]}\n" for k, v in logs.items()))
    truth = read_jsonl(results / "truth.jsonl")
    summary: dict[str, Any] = next((r for r in reversed(truth) if "frames_sent" in r), {})
    statuses = list(STATUS_LINE.finditer(logs.get("agent.log", "")))
    agent = {k: int(v) for k, v in statuses[-1].groupdict().items()} if statuses else {}
    return GuestResult(status=status, frames_sent=summary.get("frames_sent"), faults=summary.get("faults", {}),
                       agent=agent, symptoms=read_jsonl(results / "symptoms.jsonl"),
                       truth=[r for r in truth if "cycle" in r], logs=logs)


def run_guest(workload: Workload = Workload(), timeout_s: float = 1500.0, keep: Path | None = None,
              venv_bin: Path = ROOT / ".venv" / "bin") -> GuestResult:
    """Prepare (packages, kernel, initramfs), boot, and read the results back."""
    start = time.monotonic()
    for script in ("edge-monitor", "sim-controller"):
        if not (venv_bin / script).is_file():
            raise GuestFailure(f"{venv_bin / script} missing: run `make .venv/.installed` first")
    apt_state: dict = {}
    qemu, busybox = ensure_tools(apt_state)
    kernel = fetch_kernel(CACHE, apt_state)
    workdir = Path(tempfile.mkdtemp(prefix="vcan_qemu-")) if keep is None else keep
    workdir.mkdir(parents=True, exist_ok=True)
    try:
        results, console = workdir / "results", workdir / "console.log"
        results.mkdir(exist_ok=True)
        write_job(results, workload, venv_bin)
        initrd = build_initramfs(kernel, busybox, workdir)
        boot(qemu_command(qemu, kernel, initrd, results, console), console, timeout_s)
        result = parse_results(results, console)
        result.wall_s = time.monotonic() - start
        result.logs["console"] = _tail(console, 200)
        return result
    finally:
        if keep is None:
            shutil.rmtree(workdir, ignore_errors=True)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--json", action="store_true", help="print the summary as JSON")
    parser.add_argument("--timeout", type=float, default=1500.0, help="kill qemu after this many seconds")
    parser.add_argument("--keep", type=Path, help="keep the initramfs, console log and results in this directory")
    parser.add_argument("--cycles", type=int, default=Workload.cycles)
    parser.add_argument("--joints", type=int, default=Workload.joints)
    parser.add_argument("--speedup", type=float, default=Workload.speedup)
    parser.add_argument("-v", "--verbose", action="store_true")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING, format="%(name)s: %(message)s")
    workload = Workload(joints=args.joints, cycles=args.cycles, speedup=args.speedup)
    try:
        result = run_guest(workload, timeout_s=args.timeout, keep=args.keep)
    except Unavailable as exc:
        print(f"vcan_qemu: unavailable here: {exc}", file=sys.stderr)
        return 2
    except GuestFailure as exc:
        print(f"vcan_qemu: {exc}", file=sys.stderr)
        return 1
    summary = result.summary()
    if args.json:
        print(json.dumps(summary, indent=2))
    else:
        print(f"frames sent {result.frames_sent}, agent {result.agent}, symptoms {summary['symptom_keys']}")
        print(f"timings {summary['timings']}")
    ok = result.sim_rc == 0 and result.agent_rc == 0 and result.frames_sent == result.agent.get("frames_total")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
