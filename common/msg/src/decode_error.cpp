#include "storetrack/msg/decode_error.hpp"

namespace storetrack::msg {

const char* to_string(DecodeError e) {
  switch (e) {
    case DecodeError::kNone:
      return "ok";
    case DecodeError::kTooShort:
      return "too short";
    case DecodeError::kBadMagic:
      return "bad magic / not a storetrack frame";
    case DecodeError::kBadVersion:
      return "unsupported version";
    case DecodeError::kBadLength:
      return "inconsistent length";
    case DecodeError::kBadCrc:
      return "CRC mismatch";
    case DecodeError::kUnknownType:
      return "unknown message type";
    case DecodeError::kOutOfRange:
      return "value out of range";
  }
  return "invalid DecodeError";
}

}  // namespace storetrack::msg
