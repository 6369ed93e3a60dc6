#!/bin/sh
# Bring can0 up as CAN FD by hand (boards without systemd-networkd; needs CAP_NET_ADMIN / root).
# Same settings as hw/can/80-storetrack-can0.network.
set -e
IF=${1:-can0}
ip link set "$IF" down 2>/dev/null || true
ip link set "$IF" type can bitrate 1000000 sample-point 0.8 dbitrate 5000000 dsample-point 0.75 \
  fd on restart-ms 100
ip link set "$IF" txqueuelen 256
ip link set "$IF" up
ip -details link show "$IF"
