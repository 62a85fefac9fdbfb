#!/bin/busybox sh
# /init of the SocketCAN test guest (tools/vcan_qemu/vcan_qemu.py builds the initramfs around it).
#
# The guest is a Debian kernel with a busybox initramfs. It
#   1. loads the virtio, 9p and CAN modules listed in /lib/modules/load-order (dependencies first),
#   2. mounts the host's / read-only (9p tag "hostroot") on /host and the host's writable results
#      directory (9p tag "results") on /results,
#   3. creates vcan0 and raises the socket receive buffers (under emulation the agent is slow),
#   4. runs the project's own console scripts from the host's .venv, chrooted into /host:
#      `edge-monitor run --link socketcan:vcan0` in the background, then, once its CAN socket is bound,
#      `sim-controller run --link socketcan:vcan0` in the foreground; the agent stops by itself after
#      --idle-stop seconds without frames,
#   5. writes the exit codes and timings to /results/status and powers off.
# Everything the host checks is written to /results: status, truth.jsonl, symptoms.jsonl, sim.log,
# agent.log. /results/job.env (written by the host) sets the variables used below.

/bin/busybox --install -s /bin
export PATH=/bin

uptime_s() { cut -d' ' -f1 /proc/uptime; }

# A failure is written where the host looks for it, then the guest powers off (the host reports it).
fail() {
    echo "VCAN-QEMU: FAILED: $*"
    [ -d /results ] && echo "failed=$*" >> /results/status
    sync
    poweroff -f
}

mkdir -p /proc /sys /dev /host /results
mount -t proc proc /proc
mount -t sysfs sysfs /sys
mount -t devtmpfs devtmpfs /dev

# --- 1. kernel modules (virtio PCI + 9p for the shares, can + can-raw + can-dev + vcan) ----------
while read -r module; do
    insmod "/lib/modules/$module" || fail "insmod $module"
done < /lib/modules/load-order

# --- 2. the host's file systems ------------------------------------------------------------------
# msize: bigger 9p messages make Python's many small reads (imports) much faster.
mount -t 9p -o trans=virtio,version=9p2000.L,msize=262144,ro,cache=loose hostroot /host \
    || fail "mount the host's / over 9p"
mount -t 9p -o trans=virtio,version=9p2000.L,msize=262144 results /results \
    || fail "mount the results share over 9p"
echo "boot_s=$(uptime_s)" > /results/status
. /results/job.env

# Inside the chroot: the guest's own /proc, /sys and /dev. The results share is bound over its own
# (read-only) view at the host's path RESULTS_DIR, so paths are the same inside and outside the guest
# and no other host directory is hidden; HOME, TMPDIR and the agent's state live there too.
mount -t proc proc /host/proc
mount -t sysfs sysfs /host/sys
mount -t devtmpfs devtmpfs /host/dev
mount -o bind /results "/host$RESULTS_DIR" || fail "bind the results share at $RESULTS_DIR"
mkdir -p /results/tmp /results/state

# --- 3. the CAN bus ------------------------------------------------------------------------------
ip link add dev vcan0 type vcan || fail "ip link add dev vcan0 type vcan"
ip link set vcan0 up || fail "ip link set vcan0 up"
# The agent processes a few hundred frames/s under emulation; its notifier thread can be starved
# while a block is processed, so the socket must hold a whole run (about 1 KiB per frame in the kernel).
echo "$RMEM_BYTES" > /proc/sys/net/core/rmem_max
echo "$RMEM_BYTES" > /proc/sys/net/core/rmem_default
echo 100000 > /proc/sys/net/core/netdev_max_backlog

# A host command runs with a clean environment (HOST_ENV), chrooted into the host's /, in $TMPDIR:
#   timeout SECONDS env -i $HOST_ENV chroot /host /bin/sh -c 'cd "$TMPDIR" && exec "$@"' in_tmp COMMAND ARGS...
HOST_ENV="PATH=$VENV_BIN:/usr/local/bin:/usr/bin:/bin HOME=$RESULTS_DIR/tmp TMPDIR=$RESULTS_DIR/tmp
          LANG=C.UTF-8 PYTHONDONTWRITEBYTECODE=1 PYTHONUNBUFFERED=1 OPENBLAS_NUM_THREADS=1"

# --- 4. agent, then simulator --------------------------------------------------------------------
echo "VCAN-QEMU: starting the agent"
timeout "$STEP_TIMEOUT_S" env -i $HOST_ENV chroot /host /bin/sh -c 'cd "$TMPDIR" && exec "$@"' in_tmp \
    "$VENV_BIN/edge-monitor" run -v --link socketcan:vcan0 --no-zenoh --config "$RESULTS_DIR/agent.toml" \
    --jsonl "$RESULTS_DIR/symptoms.jsonl" --state-dir "$RESULTS_DIR/state" --idle-stop "$IDLE_STOP_S" \
    > /results/agent.log 2>&1 &
agent_pid=$!

# The agent's raw CAN socket shows in the kernel's receiver lists once bound (an empty list prints
# "(vcan0: no entry)"): only then may the simulator send (a frame sent earlier reaches no socket).
agent_bound() { cat /proc/net/can/rcvlist_* 2>/dev/null | grep vcan0 | grep -qv 'no entry'; }
waited=0
until agent_bound; do
    kill -0 "$agent_pid" 2>/dev/null || fail "the agent exited before opening vcan0 (see agent.log)"
    [ "$waited" -ge "$STEP_TIMEOUT_S" ] && fail "the agent did not open vcan0 within $STEP_TIMEOUT_S s"
    sleep 1
    waited=$((waited + 1))
done
echo "agent_ready_s=$(uptime_s)" >> /results/status

echo "VCAN-QEMU: starting the simulator"
timeout "$STEP_TIMEOUT_S" env -i $HOST_ENV chroot /host /bin/sh -c 'cd "$TMPDIR" && exec "$@"' in_tmp \
    "$VENV_BIN/sim-controller" run --link socketcan:vcan0 $SIM_ARGS --truth "$RESULTS_DIR/truth.jsonl" \
    > /results/sim.log 2>&1
echo "sim_rc=$?" >> /results/status
echo "sim_done_s=$(uptime_s)" >> /results/status

wait "$agent_pid"
echo "agent_rc=$?" >> /results/status
echo "agent_done_s=$(uptime_s)" >> /results/status

# --- 5. hand back -------------------------------------------------------------------------------
echo "done=1" >> /results/status
sync
echo "VCAN-QEMU: done"
poweroff -f
