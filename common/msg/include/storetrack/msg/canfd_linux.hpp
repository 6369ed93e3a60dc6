// Conversion between the codec's plain CanFdFrame and Linux SocketCAN's struct canfd_frame
// (the socket code itself lives with the firmware link and host ingest engineers).
#pragma once

#include <linux/can.h>

#include <cstring>

#include "storetrack/msg/canfd_codec.hpp"

namespace storetrack::msg {

static_assert(sizeof(CanFdFrame::data) == CANFD_MAX_DLEN);

/// For write(2) on a CAN_RAW socket with CAN_RAW_FD_FRAMES: extended id, bit-rate switch on.
inline canfd_frame to_linux(const CanFdFrame& f) {
  canfd_frame out{};
  out.can_id = (f.can_id & CAN_EFF_MASK) | CAN_EFF_FLAG;
  out.len = f.len <= CANFD_MAX_DLEN ? f.len : CANFD_MAX_DLEN;
  out.flags = CANFD_BRS;
  std::memcpy(out.data, f.data, out.len);
  return out;
}

/// From read(2): false for frames that cannot be ours (standard id, RTR or error frames).
inline bool from_linux(const canfd_frame& in, CanFdFrame& out) {
  if ((in.can_id & CAN_EFF_FLAG) == 0 || (in.can_id & (CAN_RTR_FLAG | CAN_ERR_FLAG)) != 0)
    return false;
  if (in.len > CANFD_MAX_DLEN) return false;
  out.can_id = in.can_id & CAN_EFF_MASK;
  out.len = in.len;
  std::memset(out.data, 0, sizeof(out.data));
  std::memcpy(out.data, in.data, in.len);
  return true;
}

}  // namespace storetrack::msg
