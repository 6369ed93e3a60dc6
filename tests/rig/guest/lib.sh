# Helpers for the in-VM tests (sourced). Each test: exit 0 pass, 1 fail ("FAIL: reason"),
# 77 skip ("SKIP: reason" - only for a project binary that is not built yet).
set -u
RIG_GUEST=$(cd "$(dirname "$0")" && pwd)
T=$(mktemp -d /tmp/vmtest.XXXXXX)
# Background helpers (monitors, pollers, a hung program) must not outlive their test; outside
# the VM (modbus on loopback) the scratch dir goes too.
cleanup() { pkill -P $$ 2>/dev/null; [ -n "${VMRIG_OUT:-}" ] || rm -rf "$T"; }
trap cleanup EXIT
# The VM's init brings up no network interface; loopback is needed (Modbus TCP, UDP tests).
[ -z "${VMRIG_OUT:-}" ] || ip link set lo up 2>/dev/null
fail() { echo "FAIL: $*"; exit 1; }
skip() { echo "SKIP: $*"; exit 77; }
# waitfor 'shell condition' [tries, 50 ms apart; default 200 = 10 s]
waitfor() { i=0; until sh -c "$1"; do i=$((i+1)); [ $i -lt "${2:-200}" ] || return 1; sleep 0.05; done; }
# need_bin OUTVAR ENVVAR program-name: OUTVAR=the build tree's binary (tests/rig/CMakeLists.txt
# passes the paths in STORETRACK_BIN_*); skips the test when the program is not built.
need_bin() {
  eval "p=\${$2:-}"
  [ -n "$p" ] || skip "$3 is not built in this tree (no CMake target $3)"
  [ -x "$p" ] || skip "$3 target exists but $p is missing (build it first)"
  eval "$1=\$p"
}
# gpiosim_new NAME NLINES [LABEL]: a live gpio-sim chip (with LABEL, a program can find it by
# that label after the chip was taken away and made again); sets GS_CHIP (gpiochipN), GS_SYS
# (sysfs dir holding sim_gpioK/{pull,value}) and GS_CFG (its configfs dir: `live` 0/1)
gpiosim_new() {
  modprobe gpio-sim || fail "modprobe gpio-sim"
  g=/sys/kernel/config/gpio-sim/$1
  GS_CFG=$g
  mkdir "$g" "$g/bank0" && echo "$2" > "$g/bank0/num_lines" &&
    { [ -z "${3:-}" ] || echo "$3" > "$g/bank0/label"; } && echo 1 > "$g/live" ||
    fail "gpio-sim chip $1 not created"
  GS_CHIP=$(cat "$g/bank0/chip_name")
  GS_SYS=/sys/devices/platform/$(cat "$g/dev_name")/$GS_CHIP
  [ -e "$GS_SYS/sim_gpio0/pull" ] || fail "no $GS_SYS/sim_gpio0/pull"
}
# vcan_up IF: a CAN FD capable virtual bus
vcan_up() {
  modprobe -a vcan can_raw || fail "modprobe vcan can_raw"
  ip link del "$1" 2>/dev/null  # an earlier test in this VM may have left it
  ip link add "$1" type vcan && ip link set "$1" mtu 72 && ip link set up "$1" || fail "vcan $1"
}
