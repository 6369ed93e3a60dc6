// Written against IRIG 106-17 Chapter 11 ("Recorder Data Packet Format"): 11.2.1 packet header,
// 11.2.2 packet body, 11.2.3 trailer; data formats Computer-Generated F1 (0x01), Time F1 (0x11),
// Message F0 (0x30). All multi-byte packet fields are little-endian.
#include "storetrack/output/chapter10_reader.hpp"

#include <algorithm>
#include <bit>
#include <chrono>
#include <cstdlib>
#include <fstream>
#include <iterator>
#include <stdexcept>

#include "storetrack/bytes/byte_cursor.hpp"

namespace storetrack::ch10read {
namespace {

// Fields at their documented offsets; the byte order is the common cursor's. A field past the
// span reads as 0 (callers check the lengths first; the fuzzer checks that they do).
std::uint32_t le(std::span<const std::uint8_t> b, std::size_t at, int width) {
  bytes::LittleEndianReader r(b.subspan(std::min(at, b.size())));
  return static_cast<std::uint32_t>(r.get_uint(static_cast<std::size_t>(width)));
}
std::uint64_t be_u(std::span<const std::uint8_t> b, std::size_t at, int width) {
  bytes::BigEndianReader r(b.subspan(std::min(at, b.size())));
  return r.get_uint(static_cast<std::size_t>(width));
}
double be_float(std::span<const std::uint8_t> b, std::size_t at) {
  return static_cast<double>(std::bit_cast<float>(static_cast<std::uint32_t>(be_u(b, at, 4))));
}
/// One big-endian field of a record: `width` bytes at offset `at`, stored into `out` (whose type
/// says what the bytes mean).
template <typename T>
struct BeField {
  std::size_t at;
  int width;
  T& out;
};
template <typename T>
BeField<T> be_field(std::size_t at, int width, T& out) {
  return {at, width, out};
}
/// Reads the fixed fields of one record; the caller has checked that `b` holds them all.
template <typename... T>
void read_be_fields(std::span<const std::uint8_t> b, BeField<T>... fields) {
  ((fields.out = static_cast<T>(be_u(b, fields.at, fields.width))), ...);
}
/// How a record decoder refuses: `why` into `error` (when the caller asked for it), no record.
template <typename Record>
std::optional<Record> refuse(std::string* error, std::string why) {
  if (error) *error = std::move(why);
  return std::nullopt;
}
int bcd_digit(std::uint32_t word, int shift, int bits) {
  return static_cast<int>((word >> shift) & ((1u << bits) - 1u));
}

}  // namespace

File parse(std::span<const std::uint8_t> bytes) {
  File f;
  f.file_bytes = bytes.size();
  std::size_t at = 0;
  while (at < bytes.size()) {
    if (bytes.size() - at < 24) {
      f.truncated = true;
      f.stop_reason = "file ends inside a packet header at offset " + std::to_string(at);
      break;
    }
    if (le(bytes, at, 2) != 0xEB25) {
      f.stop_reason = "no sync pattern 0xEB25 at offset " + std::to_string(at);
      break;
    }
    Packet p;
    p.file_offset = at;
    p.channel_id = static_cast<std::uint16_t>(le(bytes, at + 2, 2));
    p.packet_length = le(bytes, at + 4, 4);
    p.data_length = le(bytes, at + 8, 4);
    p.data_type_version = bytes[at + 12];
    p.sequence_number = bytes[at + 13];
    p.packet_flags = bytes[at + 14];
    p.data_type = bytes[at + 15];
    p.relative_time_counter =
        le(bytes, at + 16, 4) | (static_cast<std::uint64_t>(le(bytes, at + 20, 2)) << 32);
    std::uint32_t sum = 0;
    for (std::size_t i = 0; i < 22; i += 2)
      sum += le(bytes, at + i, 2);
    p.header_checksum_ok = (sum & 0xFFFFu) == le(bytes, at + 22, 2);
    if (!p.header_checksum_ok) {
      f.stop_reason = "header checksum mismatch at offset " + std::to_string(at);
      break;
    }
    const bool secondary = (p.packet_flags & 0x80) != 0;
    const std::size_t body_at = at + 24 + (secondary ? 12 : 0);
    const int ck = p.packet_flags & 0x03;
    p.data_checksum_bits = ck == 0 ? 0 : (ck == 1 ? 8 : (ck == 2 ? 16 : 32));
    const std::size_t trailer = static_cast<std::size_t>(p.data_checksum_bits / 8);
    if (p.packet_length % 4 != 0 || p.packet_length < (body_at - at) + p.data_length + trailer) {
      f.stop_reason = "inconsistent packet/data length at offset " + std::to_string(at);
      break;
    }
    if (bytes.size() - at < p.packet_length) {
      f.truncated = true;
      f.stop_reason = "file ends inside the packet at offset " + std::to_string(at);
      break;
    }
    const std::size_t trailer_at = at + p.packet_length - trailer;
    if (p.data_checksum_bits != 0) {
      // Sum over the body (data + filler) in units of the checksum width.
      const int w = p.data_checksum_bits / 8;
      std::uint64_t s = 0;
      for (std::size_t i = body_at; i + static_cast<std::size_t>(w) <= trailer_at; i += w)
        s += le(bytes, i, w);
      const std::uint64_t mask = w == 4 ? 0xFFFFFFFFull : ((1ull << (8 * w)) - 1);
      p.data_checksum_ok = (s & mask) == le(bytes, trailer_at, w);
    }
    p.data.assign(bytes.begin() + static_cast<std::ptrdiff_t>(body_at),
                  bytes.begin() + static_cast<std::ptrdiff_t>(body_at + p.data_length));
    at += p.packet_length;
    f.bytes_in_whole_packets = at;
    f.packets.push_back(std::move(p));
  }
  return f;
}

File read_file(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw std::runtime_error("cannot open Chapter 10 file '" + path + "'");
  std::vector<std::uint8_t> bytes((std::istreambuf_iterator<char>(in)),
                                  std::istreambuf_iterator<char>());
  return parse(bytes);
}

std::optional<TimeF1> decode_time_f1(const Packet& p) {
  if (p.data_type != 0x11 || p.data.size() < 10) return std::nullopt;
  const std::span<const std::uint8_t> d(p.data);
  TimeF1 t;
  t.csdw = le(d, 0, 4);
  t.time_source = static_cast<int>(t.csdw & 0xF);
  t.time_format = static_cast<int>((t.csdw >> 4) & 0xF);
  t.leap_year = (t.csdw >> 8) & 1;
  t.month_year_format = (t.csdw >> 9) & 1;
  const std::uint32_t w0 = le(d, 4, 2), w1 = le(d, 6, 2), w2 = le(d, 8, 2);
  t.millisecond = 10 * bcd_digit(w0, 0, 4) + 100 * bcd_digit(w0, 4, 4);
  t.second = bcd_digit(w0, 8, 4) + 10 * bcd_digit(w0, 12, 3);
  t.minute = bcd_digit(w1, 0, 4) + 10 * bcd_digit(w1, 4, 3);
  t.hour = bcd_digit(w1, 8, 4) + 10 * bcd_digit(w1, 12, 2);
  if (t.month_year_format) {
    if (p.data.size() < 12) return std::nullopt;
    const std::uint32_t w3 = le(d, 10, 2);
    t.day = bcd_digit(w2, 0, 4) + 10 * bcd_digit(w2, 4, 4);
    t.month = bcd_digit(w2, 8, 4) + 10 * bcd_digit(w2, 12, 1);
    t.year = bcd_digit(w3, 0, 4) + 10 * bcd_digit(w3, 4, 4) + 100 * bcd_digit(w3, 8, 4) +
             1000 * bcd_digit(w3, 12, 2);
    using namespace std::chrono;
    const sys_days days_since{year{t.year} / month{static_cast<unsigned>(t.month)} /
                              day{static_cast<unsigned>(t.day)}};
    t.utc_epoch_seconds = days_since.time_since_epoch().count() * 86400LL + t.hour * 3600LL +
                          t.minute * 60LL + t.second;
  } else {
    t.day_of_year = bcd_digit(w2, 0, 4) + 10 * bcd_digit(w2, 4, 4) + 100 * bcd_digit(w2, 8, 2);
  }
  return t;
}

std::optional<std::vector<Message>> decode_message_f0(const Packet& p, std::string* error) {
  auto fail = [error](const std::string& why) -> std::optional<std::vector<Message>> {
    if (error) *error = why;
    return std::nullopt;
  };
  if (p.data_type != 0x30) return fail("not a Message Data Format 0 packet");
  if (p.data.size() < 4) return fail("no channel-specific data word");
  const std::span<const std::uint8_t> d(p.data);
  const std::uint32_t csdw = le(d, 0, 4);
  const std::uint32_t count = csdw & 0xFFFF;
  if (((csdw >> 16) & 0x3) != 0) return fail("segmented messages are not expected");
  std::vector<Message> out;
  std::size_t at = 4;
  for (std::uint32_t i = 0; i < count; ++i) {
    if (d.size() - at < 12) return fail("intra-packet header past the data");
    Message m;
    m.intra_packet_time = le(d, at, 4) | (static_cast<std::uint64_t>(le(d, at + 4, 2)) << 32);
    const std::uint32_t iph = le(d, at + 8, 4);
    const std::size_t length = iph & 0xFFFF;
    m.subchannel = static_cast<std::uint16_t>((iph >> 16) & 0x3FFF);
    m.format_error = (iph >> 30) & 1;
    m.data_error = (iph >> 31) & 1;
    at += 12;
    // Messages are padded to 16 bits: an odd-length message needs its filler byte inside the
    // packet too, or `at` would step past the data.
    const std::size_t padded = length + (length & 1);
    if (d.size() - at < padded) {
      return fail(d.size() - at < length ? "message longer than the packet"
                                         : "message filler byte past the data");
    }
    m.bytes.assign(d.begin() + static_cast<std::ptrdiff_t>(at),
                   d.begin() + static_cast<std::ptrdiff_t>(at + length));
    at += padded;
    out.push_back(std::move(m));
  }
  if (at != d.size()) return fail("bytes after the last message");
  return out;
}

std::optional<std::string> decode_tmats(const Packet& p) {
  if (p.data_type != 0x01 || p.data.size() < 4) return std::nullopt;
  return std::string(p.data.begin() + 4, p.data.end());
}

std::optional<FtiBlock> decode_fti_block(std::span<const std::uint8_t> b, std::string* error) {
  // Layout version 3 of docs/fti-output.md: 166 bytes. The version is read first so that a block
  // of another layout is refused by its version, never decoded with this one's offsets.
  constexpr std::uint16_t kVersion = 3;
  constexpr std::size_t kBytes = 166;
  auto fail = [&](std::string why) { return refuse<FtiBlock>(error, std::move(why)); };
  if (b.size() < 20)
    return fail("FTI block of " + std::to_string(b.size()) + " bytes: no version field");
  const auto version = static_cast<std::uint16_t>(be_u(b, 18, 2));
  if (version != kVersion)
    return fail("FTI block version " + std::to_string(version) + ": this reader decodes version " +
                std::to_string(kVersion) + " only (docs/fti-output.md)");
  if (b.size() < kBytes)
    return fail("FTI block version 3 of " + std::to_string(b.size()) + " bytes, needs " +
                std::to_string(kBytes));
  FtiBlock f;
  read_be_fields(b, be_field(0, 8, f.exposure_mid_tai_ns), be_field(8, 4, f.trigger_seq),
                 be_field(12, 1, f.store_id), be_field(13, 1, f.cameras_used),
                 be_field(14, 1, f.marks_used), be_field(15, 1, f.pylon_marks_used),
                 be_field(16, 2, f.status));
  f.version = version;
  for (int i = 0; i < 6; ++i) {
    f.pose[i] = be_float(b, 20 + 4 * static_cast<std::size_t>(i));
    f.uncertainty[i] = be_float(b, 44 + 4 * static_cast<std::size_t>(i));
  }
  for (int i = 0; i < 15; ++i)
    f.correlation[i] = be_float(b, 68 + 4 * static_cast<std::size_t>(i));
  for (int i = 0; i < 5; ++i)
    f.budget[i] = be_float(b, 128 + 4 * static_cast<std::size_t>(i));
  f.coverage_factor = be_float(b, 148);
  f.clearance_m = be_float(b, 152);
  f.u_clearance_m = be_float(b, 156);
  f.clearance_lower_bound_m = be_float(b, 160);
  f.clearance_part = static_cast<std::uint16_t>(be_u(b, 164, 2));
  return f;
}

std::optional<RawObservation> decode_raw_observation(std::span<const std::uint8_t> b,
                                                     std::string* error) {
  // RawObservation version 2 (docs/icd.md): 34 bytes of fields, big-endian, then the message.
  constexpr std::size_t kFixed = 34;
  auto fail = [&](std::string why) { return refuse<RawObservation>(error, std::move(why)); };
  if (b.empty()) return fail("empty raw observation");
  RawObservation r;
  r.version = b[0];
  if (r.version != 2)
    return fail("raw observation version " + std::to_string(r.version) +
                ": this reader decodes version 2 only (version 1, 26 bytes of fields, has no "
                "host_mono_ns)");
  if (b.size() < kFixed)
    return fail("raw observation of " + std::to_string(b.size()) + " bytes, needs at least " +
                std::to_string(kFixed));
  read_be_fields(b, be_field(1, 1, r.source_kind), be_field(2, 8, r.arrival_tai_ns),
                 be_field(10, 4, r.source_address), be_field(14, 2, r.source_port),
                 be_field(16, 1, r.unit_id), be_field(17, 1, r.camera_id), be_field(18, 1, r.flags),
                 be_field(19, 1, r.decode_error), be_field(20, 4, r.received_bytes),
                 be_field(24, 8, r.host_mono_ns));
  const auto n = static_cast<std::size_t>(be_u(b, 32, 2));
  if (b.size() - kFixed != n)
    return fail("raw observation says " + std::to_string(n) + " message bytes, holds " +
                std::to_string(b.size() - kFixed));
  r.bytes.assign(b.begin() + kFixed, b.end());
  return r;
}

int channel_id_of(const File& file, const std::string& data_source) {
  for (const Packet& p : file.packets) {
    const auto tmats = decode_tmats(p);
    if (!tmats) continue;
    // R-1\DSI-n:<data_source>; names the channel R-1\TK1-n:<id>;
    const std::string key = "R-1\\DSI-";
    for (std::size_t at = tmats->find(key); at != std::string::npos;
         at = tmats->find(key, at + 1)) {
      const std::size_t colon = tmats->find(':', at);
      const std::size_t semi = tmats->find(';', at);
      if (colon == std::string::npos || semi == std::string::npos || semi < colon) break;
      if (tmats->compare(colon + 1, semi - colon - 1, data_source) != 0) continue;
      const std::string n = tmats->substr(at + key.size(), colon - at - key.size());
      const std::string tk = "R-1\\TK1-" + n + ":";
      const std::size_t t = tmats->find(tk);
      if (t == std::string::npos) return -1;
      return std::atoi(tmats->c_str() + t + tk.size());
    }
    return -1;  // the first setup record describes the file
  }
  return -1;
}

int raw_channel_id(const File& file) {
  return channel_id_of(file, "RAWOBS");
}

std::vector<RawObservation> raw_observations(const File& file, std::string* error) {
  std::vector<RawObservation> out;
  const int channel = raw_channel_id(file);
  if (channel < 0) {
    if (error) *error = "no raw channel in TMATS (no R-1\\DSI-n:RAWOBS)";
    return out;
  }
  for (const Packet& p : file.packets) {
    if (p.channel_id != channel || p.data_type != 0x30) continue;
    std::string why;
    const auto messages = decode_message_f0(p, &why);
    if (!messages) {
      if (error) *error = "raw packet at offset " + std::to_string(p.file_offset) + ": " + why;
      return out;
    }
    for (const Message& m : *messages) {
      auto r = decode_raw_observation(m.bytes, &why);
      if (!r) {
        if (error) *error = "raw packet at offset " + std::to_string(p.file_offset) + ": " + why;
        return out;
      }
      r->packet_offset = p.file_offset;
      r->intra_packet_time = m.intra_packet_time;
      r->subchannel = m.subchannel;
      r->data_error = m.data_error;
      r->format_error = m.format_error;
      out.push_back(std::move(*r));
    }
  }
  return out;
}

std::vector<RecordedInput> recorded_inputs(const File& file, std::string* error) {
  // Computer-Generated Data Format 0 (0x00): CSDW (reserved), then one RecordedInput version 1
  // (docs/icd.md): 48 bytes of fields, big-endian, then the name and the chunk.
  constexpr std::size_t kFixed = 48;
  std::vector<RecordedInput> out;
  auto fail = [&](const Packet& p, const std::string& why) {
    if (error) *error = "input packet at offset " + std::to_string(p.file_offset) + ": " + why;
    return out;
  };
  for (const Packet& p : file.packets) {
    if (p.data_type != 0x00) continue;
    if (p.data.size() < 4 + kFixed) return fail(p, "shorter than a recorded input");
    const std::span<const std::uint8_t> b = std::span<const std::uint8_t>(p.data).subspan(4);
    if (b[0] != 1) return fail(p, "recorded input version " + std::to_string(b[0]));
    std::array<std::uint8_t, 32> sha{};
    std::copy(b.begin() + 2, b.begin() + 34, sha.begin());
    const auto total = static_cast<std::uint32_t>(be_u(b, 34, 4));
    const auto offset = static_cast<std::uint32_t>(be_u(b, 38, 4));
    const auto chunk = static_cast<std::size_t>(be_u(b, 42, 4));
    const auto name_bytes = static_cast<std::size_t>(be_u(b, 46, 2));
    if (b.size() - kFixed != name_bytes + chunk) return fail(p, "lengths disagree with the packet");
    const auto name_at = b.begin() + kFixed;
    const auto data_at = name_at + static_cast<std::ptrdiff_t>(name_bytes);
    if (offset == 0) {
      RecordedInput in;
      in.channel_id = p.channel_id;
      in.kind = b[1];
      in.sha256 = sha;
      in.total_bytes = total;
      in.name.assign(name_at, data_at);
      out.push_back(std::move(in));
    } else if (out.empty() || out.back().complete || out.back().sha256 != sha ||
               out.back().bytes.size() != offset) {
      return fail(p, "chunk at " + std::to_string(offset) + " continues no input");
    }
    RecordedInput& in = out.back();
    in.bytes.insert(in.bytes.end(), data_at, data_at + static_cast<std::ptrdiff_t>(chunk));
    if (in.bytes.size() > in.total_bytes) return fail(p, "more bytes than the input's size");
    in.complete = in.bytes.size() == in.total_bytes;
  }
  return out;
}

}  // namespace storetrack::ch10read
