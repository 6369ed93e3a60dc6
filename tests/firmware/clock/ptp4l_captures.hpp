// Management messages captured from linuxptp 3.1.1 (Debian bookworm's ptp4l and pmc) on this
// project's test rig, byte for byte: the truth the codec is tested against (never its own
// encoder). Capture set-up: ptp4l master and slave in two network namespaces over a veth pair,
// software time stamping, free_running 1 (tests/firmware/clock/test_ptp4l_real.cpp builds the
// same); requests from `pmc -z -u -b 0`, replies to GETs with an empty data field.
#pragma once

#include <cstdint>
#include <string_view>
#include <vector>

namespace storetrack::clock::test {

inline std::vector<std::uint8_t> from_hex(std::string_view hex) {
  std::vector<std::uint8_t> out;
  auto nibble = [](char c) {
    return static_cast<std::uint8_t>(c <= '9' ? c - '0' : (c | 0x20) - 'a' + 10);
  };
  for (std::size_t i = 0; i + 1 < hex.size(); i += 2)
    out.push_back(static_cast<std::uint8_t>(nibble(hex[i]) << 4 | nibble(hex[i + 1])));
  return out;
}

// `pmc -z -u -b 0 "GET PORT_DATA_SET" "GET TIME_STATUS_NP" "GET TIME_PROPERTIES_DATA_SET"`
// from pid 0x334b (pmc's sourcePortIdentity: clockIdentity 0, portNumber = its pid), sequenceIds
// 0, 1, 2, as received on a fake uds_address.
inline constexpr std::string_view kPmcGetPortDataSet =
    "0d020036000000000000000000000000000000000000000000000000334b0000047fffffffffffffffffffff"
    "00000000000100022004";
inline constexpr std::string_view kPmcGetTimeStatusNp =
    "0d020036000000000000000000000000000000000000000000000000334b0001047fffffffffffffffffffff"
    "0000000000010002c000";
inline constexpr std::string_view kPmcGetTimePropertiesDataSet =
    "0d020036000000000000000000000000000000000000000000000000334b0002047fffffffffffffffffffff"
    "00000000000100022003";

// The slave's replies (its clockIdentity 5af004.fffe.47b49f; master 8623d8.fffe.f00d3a, the
// EUI-64 of the master's veth MAC 86:23:d8:f0:0d:3a), requests with sequenceIds 100..103.
// PORT_DATA_SET: port 1 UNCALIBRATED (free_running: ptp4l's servo never locks), logAnnounce -2,
// announceReceiptTimeout 2, logSync -3, delayMechanism E2E, version 2.
inline constexpr std::string_view kSlavePortDataSetUncalibrated =
    "0d020050000000000000000000000000000000005af004fffe47b49f00010064047f00000000000000001234"
    "000002000001001c20045af004fffe47b49f000108000000000000000000fe02fd010002";
// TIME_STATUS_NP: master_offset 616 ns, ingress_time 1796236652230701337 ns, gmPresent 1.
inline constexpr std::string_view kSlaveTimeStatusNp =
    "0d020068000000000000000000000000000000005af004fffe47b49f00000065047f00000000000000001234"
    "0000020000010034c000000000000000026818ed83b7e4bf7119000000000000000000000000000000000000"
    "00000000000000018623d8fffef00d3a";
// TIME_STATUS_NP a second later: master_offset -316 ns (0xfffffffffffffec4).
inline constexpr std::string_view kSlaveTimeStatusNpNegative =
    "0d020068000000000000000000000000000000005af004fffe47b49f00000065047f00000000000000001234"
    "0000020000010034c000fffffffffffffec418ed83ba74e6db83000000000000000000000000000000000000"
    "00000000000000018623d8fffef00d3a";
// TIME_PROPERTIES_DATA_SET: currentUtcOffset 37 s, flags 0 (not traceable), timeSource 0xA0
// (internal oscillator).
inline constexpr std::string_view kSlaveTimePropertiesDataSet =
    "0d02003a000000000000000000000000000000005af004fffe47b49f00000066047f00000000000000001234"
    "00000200000100062003002500a0";
// GET of managementId 0x1234 (none such): MANAGEMENT_ERROR_STATUS, managementErrorId 0x0002
// (NO_SUCH_ID), managementId 0x1234.
inline constexpr std::string_view kSlaveErrorNoSuchId =
    "0d02003c000000000000000000000000000000005af004fffe47b49f00010067047f00000000000000001234"
    "00000200000200080002123400000000";
// After the master was killed: PORT_DATA_SET portState 4 LISTENING, while TIME_STATUS_NP still
// says gmPresent 1 with the lost master's identity (and ingress_time 0): gmPresent alone does
// not show a lost master, the port state does.
inline constexpr std::string_view kSlavePortDataSetListening =
    "0d020050000000000000000000000000000000005af004fffe47b49f00010064047f00000000000000001234"
    "000002000001001c20045af004fffe47b49f000104000000000000000000fe02fd010002";
inline constexpr std::string_view kSlaveTimeStatusNpMasterGone =
    "0d020068000000000000000000000000000000005af004fffe47b49f00000065047f00000000000000001234"
    "0000020000010034c00000000000000002d00000000000000000000000000000000000000000000000000000"
    "00000000000000018623d8fffef00d3a";

}  // namespace storetrack::clock::test
