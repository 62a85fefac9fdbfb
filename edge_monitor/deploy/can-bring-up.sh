#!/bin/sh
# Bring a SocketCAN interface up by hand (or from a boot script) at the robot bus's bit rate, without
# systemd-networkd (docs/OPERATIONS.md, "The CAN interface"). Run as root: can-bring-up.sh can0 1000000
set -eu
IFACE="${1:-can0}"
BITRATE="${2:-1000000}"
ip link set "$IFACE" down 2>/dev/null || true
# restart-ms: the driver restarts the interface 100 ms after a bus-off instead of leaving it down
ip link set "$IFACE" type can bitrate "$BITRATE" restart-ms 100
ip link set "$IFACE" txqueuelen 1000
ip link set "$IFACE" up
ip -details -statistics link show "$IFACE"
