// iNET-X over UDP: a 28-byte big-endian header (control word, stream id, sequence number, packet
// length, PTP seconds and nanoseconds of the exposure, payload information field) followed by
// the FTI parameter block. Byte-by-byte layout: docs/fti-output.md.
#pragma once

#include <netinet/in.h>

#include <cstddef>
#include <cstdint>
#include <span>
#include <string>

#include "storetrack/msg/messages.hpp"
#include "storetrack/output/fti_parameter_block.hpp"

namespace storetrack::output {

inline constexpr std::uint32_t kInetxControlWord = 0x11000000;  // iNET-X version 1.1
inline constexpr std::size_t kInetxHeaderBytes = 28;
inline constexpr std::size_t kInetxPacketBytes = kInetxHeaderBytes + kFtiParameterBlockBytes;
/// Payload information field bit 31: the sample is not a valid pose (status bit 0 clear).
inline constexpr std::uint32_t kInetxPifDataError = 0x8000'0000u;

/// One packet; the PTP time is the exposure mid-point (TAI, the PTP timescale). Returns the
/// byte count or -ENOSPC.
int encode_inetx_packet(const msg::FtiSample& sample, std::uint32_t stream_id,
                        std::uint32_t sequence, std::span<std::uint8_t> out);

struct InetxHeader {
  std::uint32_t control_word, stream_id, sequence, packet_length, ptp_seconds, ptp_nanoseconds, pif;
};
/// 0, or -EINVAL when too short / length field disagrees with the datagram size.
int decode_inetx_header(std::span<const std::uint8_t> in, InetxHeader& header);

struct InetxSenderCounters {
  std::uint64_t packets_sent = 0;
  std::uint64_t send_errors = 0;
};

/// UDP sender; multicast destinations (224.0.0.0/4) get TTL and loopback set.
class InetxSender {
 public:
  InetxSender() = default;
  ~InetxSender();
  InetxSender(const InetxSender&) = delete;
  InetxSender& operator=(const InetxSender&) = delete;

  /// destination "a.b.c.d:port"; interface_address (optional) selects the multicast interface.
  /// Returns 0 or -errno (-EINVAL for a malformed destination).
  int open(const std::string& destination, std::uint32_t stream_id, int multicast_ttl = 1,
           const std::string& interface_address = "");
  /// Encodes and sends one sample; returns 0 or -errno (counted).
  int send(const msg::FtiSample& sample);
  void close();

  const InetxSenderCounters& counters() const { return counters_; }
  std::uint32_t next_sequence() const { return sequence_; }

 private:
  int fd_ = -1;
  sockaddr_in destination_{};
  std::uint32_t stream_id_ = 0;
  std::uint32_t sequence_ = 0;
  InetxSenderCounters counters_;
};

/// Splits "host:port" (IPv4); false when malformed.
bool parse_ipv4_endpoint(const std::string& text, std::string& address, std::uint16_t& port);

}  // namespace storetrack::output
