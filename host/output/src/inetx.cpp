#include "storetrack/output/inetx.hpp"

#include <arpa/inet.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <unistd.h>

#include <array>
#include <cerrno>
#include <charconv>

#include "storetrack/bytes/byte_cursor.hpp"
#include "storetrack/time/time.hpp"

namespace storetrack::output {

int encode_inetx_packet(const msg::FtiSample& sample, std::uint32_t stream_id,
                        std::uint32_t sequence, std::span<std::uint8_t> out) {
  if (out.size() < kInetxPacketBytes) return -ENOSPC;
  std::int64_t t = sample.exposure_mid_tai_ns;
  std::int64_t secs = t / time::kNsPerSecond;
  std::int64_t ns = t % time::kNsPerSecond;
  if (ns < 0) {
    ns += time::kNsPerSecond;
    --secs;
  }
  const bool valid = (sample.status & msg::fti_status::kValid) != 0;
  bytes::BigEndianWriter w(out.first(kInetxHeaderBytes));
  w.put_u32(kInetxControlWord);
  w.put_u32(stream_id);
  w.put_u32(sequence);
  w.put_u32(static_cast<std::uint32_t>(kInetxPacketBytes));
  w.put_u32(static_cast<std::uint32_t>(secs));
  w.put_u32(static_cast<std::uint32_t>(ns));
  w.put_u32(valid ? 0u : kInetxPifDataError);
  static_assert(kInetxHeaderBytes == 7 * 4);
  if (!w.ok() || w.remaining() != 0) return -ENOSPC;
  if (encode_fti_parameter_block(sample, out.subspan(kInetxHeaderBytes)) < 0) return -ENOSPC;
  return static_cast<int>(kInetxPacketBytes);
}

int decode_inetx_header(std::span<const std::uint8_t> in, InetxHeader& h) {
  if (in.size() < kInetxHeaderBytes) return -EINVAL;
  bytes::BigEndianReader r(in);
  h.control_word = r.get_u32();
  h.stream_id = r.get_u32();
  h.sequence = r.get_u32();
  h.packet_length = r.get_u32();
  h.ptp_seconds = r.get_u32();
  h.ptp_nanoseconds = r.get_u32();
  h.pif = r.get_u32();
  if (h.packet_length != in.size()) return -EINVAL;
  return 0;
}

bool parse_ipv4_endpoint(const std::string& text, std::string& address, std::uint16_t& port) {
  const auto colon = text.rfind(':');
  if (colon == std::string::npos || colon == 0) return false;
  address = text.substr(0, colon);
  const char* first = text.data() + colon + 1;
  const char* last = text.data() + text.size();
  unsigned value = 0;
  auto [ptr, ec] = std::from_chars(first, last, value);
  if (ec != std::errc{} || ptr != last || value == 0 || value > 65535) return false;
  in_addr a{};
  if (inet_pton(AF_INET, address.c_str(), &a) != 1) return false;
  port = static_cast<std::uint16_t>(value);
  return true;
}

InetxSender::~InetxSender() {
  close();
}

int InetxSender::open(const std::string& destination, std::uint32_t stream_id, int multicast_ttl,
                      const std::string& interface_address) {
  close();
  std::string address;
  std::uint16_t port = 0;
  if (!parse_ipv4_endpoint(destination, address, port)) return -EINVAL;
  sockaddr_in dst{};
  dst.sin_family = AF_INET;
  dst.sin_port = htons(port);
  inet_pton(AF_INET, address.c_str(), &dst.sin_addr);
  fd_ = ::socket(AF_INET, SOCK_DGRAM | SOCK_CLOEXEC, 0);
  if (fd_ < 0) return -errno;
  const bool multicast = (ntohl(dst.sin_addr.s_addr) >> 28) == 0xE;
  if (multicast) {
    const unsigned char ttl = static_cast<unsigned char>(multicast_ttl);
    const unsigned char loop = 1;
    setsockopt(fd_, IPPROTO_IP, IP_MULTICAST_TTL, &ttl, sizeof ttl);
    setsockopt(fd_, IPPROTO_IP, IP_MULTICAST_LOOP, &loop, sizeof loop);
    if (!interface_address.empty()) {
      in_addr ifa{};
      if (inet_pton(AF_INET, interface_address.c_str(), &ifa) != 1) {
        close();
        return -EINVAL;
      }
      setsockopt(fd_, IPPROTO_IP, IP_MULTICAST_IF, &ifa, sizeof ifa);
    }
  }
  // sendto() rather than connect(): a connected UDP socket would report ICMP "port
  // unreachable" from a recorder that is not listening yet as send errors.
  destination_ = dst;
  stream_id_ = stream_id;
  sequence_ = 0;
  return 0;
}

int InetxSender::send(const msg::FtiSample& sample) {
  if (fd_ < 0) return -EBADF;
  std::array<std::uint8_t, kInetxPacketBytes> buf{};
  const int n = encode_inetx_packet(sample, stream_id_, sequence_, buf);
  ++sequence_;  // the sequence counts packets attempted, so a receiver sees send failures as gaps
  const ssize_t sent =
      ::sendto(fd_, buf.data(), static_cast<std::size_t>(n), MSG_DONTWAIT,
               reinterpret_cast<const sockaddr*>(&destination_), sizeof destination_);
  if (sent != n) {
    ++counters_.send_errors;
    return sent < 0 ? -errno : -EIO;
  }
  ++counters_.packets_sent;
  return 0;
}

void InetxSender::close() {
  if (fd_ >= 0) ::close(fd_);
  fd_ = -1;
}

}  // namespace storetrack::output
