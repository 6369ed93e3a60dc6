# CAN FD, library level: the unit's CanFdLink -> vcan0 (mtu 72) -> the host's CanFdReceiver
# through Linux SocketCAN; ICD ids/lengths on the bus, injected malformed frames counted and
# dropped, interface down mid-stream survived and reported (tests/rig/drivers/test_rig_canfd.cpp).
. "$(dirname "$0")/lib.sh"
need_bin BIN STORETRACK_BIN_RIG_CANFD test_rig_canfd
vcan_up vcan0
STORETRACK_RIG_CAN_IF=vcan0 "$BIN" --gtest_brief=0 || fail "test_rig_canfd (see gtest output above)"
