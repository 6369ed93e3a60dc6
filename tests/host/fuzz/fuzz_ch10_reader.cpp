// libFuzzer target: the Chapter 10 reader (host/output chapter10_reader) on arbitrary files.
// Properties checked (abort when violated), beyond "no crash, no UB":
//  - parse() accounts for every byte: the whole packets lie end to end from offset 0, their
//    lengths sum to bytes_in_whole_packets <= file_bytes, and a stop reason is given exactly
//    when bytes are left over (truncated only then);
//  - every packet's data is data_length bytes and fits in its packet;
//  - a Message F0 packet that decodes accounts for its body: CSDW + 12-byte headers + messages
//    padded to 16 bits = the data length, with as many messages as the CSDW counts; a decode
//    failure always says why;
//  - the other decoders (Time F1, TMATS, FTI parameter block) return or refuse without UB;
//  - the raw channel and the recorded inputs: a refusal says why, a joined input never holds
//    more than its stated size, a complete one exactly that.
// The input is the file itself (the seeds are real files). When its checksums are wrong the
// harness also checks a copy whose header checksums (and 32-bit data checksums) it rewrote for
// every packet it can walk to, so the fuzzer also reaches the length checks and the data
// decoders behind the checksums.
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <span>
#include <string>
#include <vector>

#include "storetrack/bytes/byte_cursor.hpp"
#include "storetrack/output/chapter10_reader.hpp"

namespace {

namespace ch10 = storetrack::ch10read;

std::uint32_t get_le(const std::vector<std::uint8_t>& b, std::size_t at, int bytes) {
  storetrack::bytes::LittleEndianReader r{std::span(b).subspan(at)};
  return static_cast<std::uint32_t>(r.get_uint(static_cast<std::size_t>(bytes)));
}

void put_le(std::vector<std::uint8_t>& b, std::size_t at, std::uint32_t v, int bytes) {
  storetrack::bytes::LittleEndianWriter w{std::span(b).subspan(at)};
  w.put_uint(v, static_cast<std::size_t>(bytes));
}

// IRIG 106-17 11.2.1.1.10: the header checksum is the 16-bit sum of the first 11 header words;
// 11.2.3: the 32-bit data checksum sums the body (after any secondary header) in 32-bit words.
void fix_checksums(std::vector<std::uint8_t>& b) {
  std::size_t at = 0;
  while (b.size() - at >= 24 && get_le(b, at, 2) == 0xEB25) {
    std::uint32_t sum = 0;
    for (std::size_t i = 0; i < 22; i += 2)
      sum += get_le(b, at + i, 2);
    put_le(b, at + 22, sum & 0xFFFF, 2);
    const std::uint32_t length = get_le(b, at + 4, 4);
    if (length < 24 || length % 4 != 0 || b.size() - at < length) return;
    const std::uint8_t flags = b[at + 14];
    const std::size_t body_at = at + 24 + ((flags & 0x80) != 0 ? 12 : 0);
    if ((flags & 0x03) == 3 && at + length >= body_at + 4) {
      const std::size_t trailer_at = at + length - 4;
      std::uint32_t data_sum = 0;
      for (std::size_t i = body_at; i + 4 <= trailer_at; i += 4)
        data_sum += get_le(b, i, 4);
      put_le(b, trailer_at, data_sum, 4);
    }
    at += length;
  }
}

void check_message_f0(const ch10::Packet& packet) {
  std::string why;
  const auto messages = ch10::decode_message_f0(packet, &why);
  if (!messages) {
    if (why.empty()) std::abort();  // a refusal must say why
    return;
  }
  std::size_t bytes = 4;  // channel-specific data word
  for (const auto& m : *messages) {
    bytes += 12 + m.bytes.size() + (m.bytes.size() & 1);
    (void)ch10::decode_fti_block(m.bytes);
  }
  if (bytes != packet.data.size()) std::abort();
  if (messages->size() != get_le(packet.data, 0, 2)) std::abort();
}

void check_file(const ch10::File& f, std::size_t size) {
  if (f.file_bytes != size || f.bytes_in_whole_packets > size) std::abort();
  std::size_t next = 0;
  for (const auto& p : f.packets) {
    if (p.file_offset != next || p.packet_length < 24 || p.packet_length % 4 != 0) std::abort();
    if (p.data.size() != p.data_length || p.data_length > p.packet_length - 24) std::abort();
    if (!p.header_checksum_ok) std::abort();  // the reader stops at a bad header
    next += p.packet_length;
  }
  if (next != f.bytes_in_whole_packets) std::abort();
  if ((next == size) != f.stop_reason.empty()) std::abort();
  if (f.truncated && f.stop_reason.empty()) std::abort();
}

void check(const std::vector<std::uint8_t>& file) {
  const ch10::File f = ch10::parse(file);
  check_file(f, file.size());
  for (const auto& p : f.packets) {
    if (p.data_type == 0x30) check_message_f0(p);
    (void)ch10::decode_time_f1(p);
    (void)ch10::decode_tmats(p);
  }
  std::string why;
  (void)ch10::raw_observations(f, &why);
  std::string input_error;
  for (const auto& in : ch10::recorded_inputs(f, &input_error)) {
    if (in.bytes.size() > in.total_bytes) std::abort();
    if (in.complete != (in.bytes.size() == in.total_bytes)) std::abort();
  }
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::vector<std::uint8_t> file(data, data + size);
  check(file);
  std::vector<std::uint8_t> fixed = file;
  fix_checksums(fixed);
  if (fixed != file) check(fixed);
  return 0;
}
