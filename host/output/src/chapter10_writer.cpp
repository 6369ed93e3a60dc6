// IRIG 106-17 Chapter 10 (Digital Recording Standard) and Chapter 11 (Recorder Data Packet
// Format) writer; section numbers below are those of Chapter 11 (106-17), where the packet
// formats live since 106-17.
#include "storetrack/output/chapter10_writer.hpp"

#include <fcntl.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <chrono>
#include <cstdio>
#include <cstring>
#include <filesystem>

#include "storetrack/bytes/byte_cursor.hpp"
#include "storetrack/digest/sha256.hpp"
#include "storetrack/output/fti_parameter_block.hpp"

namespace storetrack::output {
namespace {

constexpr std::uint16_t kSync = 0xEB25;                // 11.2.1.1 a
constexpr std::uint8_t kDataTypeVersion106_17 = 0x08;  // 11.2.1.1 e: RCC 106-17
constexpr std::uint8_t kTypeComputerF0 = 0x00;         // Computer-Generated Data, Format 0
constexpr std::uint8_t kTypeTmats = 0x01;              // Computer-Generated Data, Format 1
constexpr std::uint8_t kTypeTimeF1 = 0x11;             // Time Data, Format 1
constexpr std::uint8_t kTypeMessageF0 = 0x30;          // Message Data, Format 0
constexpr std::uint8_t kFlagsChecksum32 = 0x03;        // packet flags bits 1-0 = 11
constexpr std::size_t kHeaderBytes = 24;
constexpr std::uint8_t kTmatsCh10Version106_17 = 0x0C;  // TMATS CSDW bits 7-0

// Chapter 10 packet structure is little-endian (11.2): `n` more bytes at the end of `v` and a
// writer over exactly them.
bytes::LittleEndianWriter grow(std::vector<std::uint8_t>& v, std::size_t n) {
  v.resize(v.size() + n);
  return bytes::LittleEndianWriter(std::span(v).last(n));
}
std::uint8_t bcd2(int value) {
  return static_cast<std::uint8_t>(((value / 10) % 10) << 4 | (value % 10));
}

std::int64_t floor_div(std::int64_t a, std::int64_t b) {
  std::int64_t q = a / b;
  if ((a % b != 0) && ((a < 0) != (b < 0))) --q;
  return q;
}

// A recorded input's name is cut to the schema's bound; the content is split into chunks.
constexpr std::size_t kMaxInputNameBytes = 1024;
constexpr std::size_t kInputChunkBytes = 192 * 1024;  // + name + header < the 256 KiB tail bound
static_assert(kInputChunkBytes + kMaxInputNameBytes <= msg::kRecordedInputMaxTailBytes);

// Computer-Generated Data Format 0 bodies (CSDW = 0, reserved) of one input: one RecordedInput
// record per chunk, each with the SHA-256 of the whole file.
void input_bodies(const RecordedInputFile& in, std::vector<std::vector<std::uint8_t>>& out) {
  const digest::Sha256 sha = digest::sha256(in.bytes);
  const std::string name = in.name.substr(0, kMaxInputNameBytes);
  std::size_t at = 0;
  do {
    const std::size_t n = std::min(kInputChunkBytes, in.bytes.size() - at);
    msg::RecordedInput r{};
    r.kind = static_cast<std::uint8_t>(in.kind);
    r.sha256 = sha;
    r.total_bytes = static_cast<std::uint32_t>(in.bytes.size());
    r.chunk_offset = static_cast<std::uint32_t>(at);
    r.chunk_bytes = static_cast<std::uint32_t>(n);
    r.name_bytes = static_cast<std::uint16_t>(name.size());
    std::vector<std::uint8_t> tail(name.begin(), name.end());
    tail.insert(tail.end(), in.bytes.begin() + static_cast<std::ptrdiff_t>(at),
                in.bytes.begin() + static_cast<std::ptrdiff_t>(at + n));
    std::vector<std::uint8_t> body(4 + msg::payload_size(r), 0);  // CSDW 0, then the record
    bytes::BigEndianWriter w{std::span(body).subspan(4)};
    msg::pack_payload(r, tail, w);  // sizes are consistent by construction
    out.push_back(std::move(body));
    at += n;
  } while (at < in.bytes.size());
}

}  // namespace

const char* to_string(RecordedInputKind kind) {
  switch (kind) {
    case RecordedInputKind::kCalibration:
      return "calibration";
    case RecordedInputKind::kPylonSurvey:
      return "pylon survey";
    case RecordedInputKind::kStoreSurvey:
      return "store survey";
    case RecordedInputKind::kHostConfig:
      return "host configuration";
    case RecordedInputKind::kInitialMarks:
      return "initial marks";
    case RecordedInputKind::kCommandLine:
      return "command line";
    case RecordedInputKind::kClearanceGeometry:
      return "clearance geometry";
    case RecordedInputKind::kClearanceMesh:
      return "clearance mesh";
  }
  return "unknown";
}

UtcCalendar utc_calendar_from_tai(time::TaiNs t_tai) {
  const std::int64_t utc_ns = t_tai - time::kTaiMinusUtcSeconds * time::kNsPerSecond;
  const std::int64_t secs = floor_div(utc_ns, time::kNsPerSecond);
  const std::int64_t sub_ns = utc_ns - secs * time::kNsPerSecond;
  using namespace std::chrono;
  const sys_days day{floor<days>(sys_seconds{seconds{secs}})};
  const year_month_day ymd{day};
  const std::int64_t sod = secs - duration_cast<seconds>(day.time_since_epoch()).count();
  UtcCalendar c{};
  c.year = static_cast<int>(ymd.year());
  c.month = static_cast<int>(static_cast<unsigned>(ymd.month()));
  c.day = static_cast<int>(static_cast<unsigned>(ymd.day()));
  c.hour = static_cast<int>(sod / 3600);
  c.minute = static_cast<int>((sod / 60) % 60);
  c.second = static_cast<int>(sod % 60);
  c.millisecond = static_cast<int>(sub_ns / 1'000'000);
  return c;
}

Chapter10Writer::~Chapter10Writer() {
  close();
}

std::uint64_t Chapter10Writer::rtc_of(time::TaiNs t_tai) const {
  if (start_tai_ns_ == kRtcEpochFirstSample) return 0;
  // 10 MHz counter, 48 bits (11.2.1.1 i).
  const std::int64_t ticks = floor_div(t_tai - start_tai_ns_, 100);
  return static_cast<std::uint64_t>(ticks) & 0xFFFF'FFFF'FFFFull;
}

std::string Chapter10Writer::tmats_text() const {
  // TMATS (IRIG 106 Chapter 9) attributes, ASCII, one "CODE:value;" per line.
  std::string t;
  auto line = [&t](const std::string& code, const std::string& value) {
    t += code + ":" + value + ";\r\n";
  };
  line("G\\PN", config_.program_name);
  line("G\\TA", config_.test_point);
  line("G\\106", "17");
  line("G\\DSI\\N", "1");
  line("G\\DSI-1", "STORETRACK");
  line("G\\DST-1", "STO");
  line("G\\COM",
       "storetrack host: store pose relative to the pylon with GUM uncertainty; message layout "
       "docs/fti-output.md (FTI parameter block v" +
           std::to_string(kFtiParameterBlockVersion) + ", big-endian, " +
           std::to_string(kFtiParameterBlockBytes) + " bytes)");
  line("R-1\\ID", "STORETRACK");
  line("R-1\\RID", "STORETRACK-HOST");
  const bool raw = config_.raw_observations;
  line("R-1\\N", raw ? "3" : "2");
  line("R-1\\TK1-1", std::to_string(config_.time_channel_id));
  line("R-1\\CHE-1", "T");
  line("R-1\\DSI-1", "TIME");
  line("R-1\\CDT-1", "TIMIN");
  line("R-1\\TTF-1", "1");
  line("R-1\\TK1-2", std::to_string(config_.message_channel_id));
  line("R-1\\CHE-2", "T");
  line("R-1\\DSI-2", "FTISAMPLE");
  line("R-1\\CDT-2", "MSGIN");
  line("R-1\\CDLN-2", "FTISAMPLE");
  if (raw) {
    // Every observation message as received (RawObservation records, docs/fti-output.md).
    line("R-1\\TK1-3", std::to_string(config_.raw_channel_id));
    line("R-1\\CHE-3", "T");
    line("R-1\\DSI-3", "RAWOBS");
    line("R-1\\CDT-3", "MSGIN");
    line("R-1\\CDLN-3", "RAWOBS");
  }
  for (const auto& s : config_.stores) {
    line("G\\COM", "channel " + std::to_string(config_.message_channel_id) + " subchannel " +
                       std::to_string(s.store_id) + " = store " + s.name);
  }
  if (raw) {
    line("G\\COM", "channel " + std::to_string(config_.raw_channel_id) +
                       " = every observation message received (RawObservation v" +
                       std::to_string(msg::kRawObservationVersion) +
                       ", big-endian, docs/icd.md), subchannel = sending unit id");
  }
  for (const auto& in : config_.inputs) {
    line("G\\COM", "channel " + std::to_string(config_.inputs_channel_id) + " input " +
                       to_string(in.kind) + " '" + in.name.substr(0, kMaxInputNameBytes) + "' " +
                       std::to_string(in.bytes.size()) + " bytes sha256 " +
                       digest::to_hex(digest::sha256(in.bytes)));
  }
  for (std::string comment : config_.comments) {
    std::replace(comment.begin(), comment.end(), ';', ',');
    line("G\\COM", comment);
  }
  return t;
}

Chapter10FileOps posix_chapter10_file_ops() {
  return {::write, ::fdatasync, ::ftruncate, ::close, ::fsync};
}

std::string numbered_chapter10_path(const std::string& path, int number) {
  const std::filesystem::path p(path);
  char digits[16];
  std::snprintf(digits, sizeof digits, ".%03d", number);
  return (p.parent_path() / (p.stem().string() + digits + p.extension().string())).string();
}

int Chapter10Writer::open(const std::string& path, const Chapter10Config& config,
                          time::TaiNs rtc_epoch_tai_ns) {
  close();
  config_ = config;
  config_.max_messages_per_packet =
      std::clamp(config_.max_messages_per_packet, 1, kMaxChapter10MessagesPerPacket);
  start_tai_ns_ = rtc_epoch_tai_ns;
  counters_ = {};
  sequence_.assign(65536, 0);
  last_time_packet_utc_s_ = INT64_MIN;
  last_sample_tai_ns_ = INT64_MIN;
  config_.max_raw_messages_per_packet =
      std::clamp(config_.max_raw_messages_per_packet, 1, kMaxChapter10MessagesPerPacket);
  config_.max_held_raw_messages = std::max(config_.max_held_raw_messages, 1);
  pending_body_.clear();
  pending_messages_ = 0;
  pending_raw_body_.clear();
  pending_raw_.clear();
  input_bodies_.clear();
  for (const auto& in : config_.inputs)
    input_bodies(in, input_bodies_);
  requested_path_ = path;
  files_.clear();
  next_number_ = 1;
  current_utc_s_ = INT64_MIN;
  failed_reopen_utc_s_ = INT64_MIN;
  const int rc = create_file(config_.existing == Chapter10Existing::kNumberNewFile ? 0 : -1);
  if (rc != 0) return rc;
  if (const int r = write_file_header(true); r != 0) {
    // It holds no sample (at most the TMATS, when only its fdatasync failed): the file this
    // open() created is removed, so a host restarted again and again on a full disk leaves no
    // trail of empty numbered files, and the requested path is free once the disk has room.
    close_file();
    if (::unlink(files_.back().c_str()) == 0) files_.pop_back();
    return r;
  }
  opened_ = true;
  return 0;
}

// number 0: the requested path, then the numbered names; -1: the requested path or -EEXIST.
int Chapter10Writer::create_file(int number) {
  const bool refuse_existing = number < 0;
  number = std::max(number, 0);
  std::string candidate;
  for (;;) {
    candidate = number == 0 ? requested_path_ : numbered_chapter10_path(requested_path_, number);
    // O_EXCL: an existing recording is never opened for writing, let alone truncated.
    fd_ = ::open(candidate.c_str(), O_WRONLY | O_CREAT | O_EXCL | O_APPEND | O_CLOEXEC, 0644);
    if (fd_ >= 0) break;
    if (errno != EEXIST || refuse_existing) return -errno;
    if (++number > kMaxChapter10FileNumber) return -EEXIST;
  }
  if (number > 0) next_number_ = number + 1;
  if (number > 0 && files_.empty()) ++counters_.numbered_instead_of_existing;
  files_.push_back(candidate);
  ++counters_.files_opened;
  file_bytes_ = 0;
  file_data_packets_ = 0;
  // The new directory entry must survive a power loss as well as the packets.
  std::filesystem::path dir = std::filesystem::path(candidate).parent_path();
  if (dir.empty()) dir = ".";
  const int dfd = ::open(dir.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
  if (dfd < 0 || ops_.fsync_directory(dfd) != 0) ++counters_.directory_sync_errors;
  if (dfd >= 0) ::close(dfd);
  return 0;
}

// TMATS first; a continuation file also repeats the current time packet so its RTCs map to
// absolute time without the previous file. Not when the packet it continues with is itself the
// next second's time packet: the file would start with a second it holds no sample of.
int Chapter10Writer::write_file_header(bool repeat_time_packet) {
  // Computer-Generated Data Format 1 (setup record): CSDW bit 9 SRCC = 0, bit 8 format = 0
  // (ASCII TMATS), bits 7-0 Chapter 10 version.
  std::vector<std::uint8_t> body;
  grow(body, 4).put_u32(kTmatsCh10Version106_17);
  const std::string tmats = tmats_text();
  body.insert(body.end(), tmats.begin(), tmats.end());
  bool written = false;
  if (int rc = append(build_packet(0, kTypeTmats, 0, body), written); rc != 0) return rc;
  // The inputs follow the setup record in every file, so each file alone can be reprocessed.
  for (const auto& input : input_bodies_) {
    if (int rc =
            append(build_packet(config_.inputs_channel_id, kTypeComputerF0, 0, input), written);
        rc != 0)
      return rc;
    ++counters_.input_packets;
  }
  if (!repeat_time_packet || last_time_packet_utc_s_ == INT64_MIN) return 0;
  const std::int64_t s = last_time_packet_utc_s_;
  const time::TaiNs tai = (s + time::kTaiMinusUtcSeconds) * time::kNsPerSecond;
  if (int rc = append(build_packet(config_.time_channel_id, kTypeTimeF1, rtc_of(tai), time_body(s)),
                      written);
      rc != 0)
    return rc;
  ++counters_.time_packets;
  return 0;
}

int Chapter10Writer::start_continuation_file(bool repeat_time_packet) {
  if (current_utc_s_ == failed_reopen_utc_s_) return -EAGAIN;  // one failed try per second
  int rc = create_file(next_number_);
  if (rc == 0) {
    ++counters_.continuation_files;
    rc = write_file_header(repeat_time_packet);
    if (rc != 0) abandon_file();
  } else {
    ++counters_.open_errors;
  }
  if (rc != 0) failed_reopen_utc_s_ = current_utc_s_;
  return rc;
}

// Closes a failed file (it ends at its last whole packet); a continuation file that never got a
// sample is removed again so a lasting fault leaves no trail of empty files.
void Chapter10Writer::abandon_file() {
  if (fd_ < 0) return;
  const bool empty_continuation = file_data_packets_ == 0 && files_.size() > 1;
  close_file();
  if (empty_continuation && ::unlink(files_.back().c_str()) == 0) {
    files_.pop_back();
    next_number_ = std::max(1, next_number_ - 1);
  }
}

int Chapter10Writer::close_file() {
  if (fd_ < 0) return 0;
  const int rc = ops_.close(fd_) == 0 ? 0 : -errno;
  if (rc != 0) ++counters_.close_errors;
  fd_ = -1;
  return rc;
}

std::vector<std::uint8_t> Chapter10Writer::build_packet(std::uint16_t channel_id,
                                                        std::uint8_t data_type, std::uint64_t rtc,
                                                        const std::vector<std::uint8_t>& body) {
  const std::size_t data_length = body.size();
  const std::size_t padded = (data_length + 3) & ~std::size_t{3};  // filler to 32 bits
  const std::size_t trailer = config_.data_checksum ? 4 : 0;
  const std::size_t packet_length = kHeaderBytes + padded + trailer;
  std::vector<std::uint8_t> packet(packet_length, 0);
  bytes::LittleEndianWriter w(packet);
  w.put_u16(kSync);
  w.put_u16(channel_id);
  w.put_u32(static_cast<std::uint32_t>(packet_length));
  w.put_u32(static_cast<std::uint32_t>(data_length));
  w.put_u8(kDataTypeVersion106_17);
  w.put_u8(sequence_[channel_id]++);
  w.put_u8(config_.data_checksum ? kFlagsChecksum32 : 0x00);  // no secondary header, RTC
  w.put_u8(data_type);
  w.put_uint(rtc, 6);  // 48-bit relative time counter
  // Header checksum: 16-bit sum of the 11 little-endian 16-bit words before it.
  bytes::LittleEndianReader header_words(std::span<const std::uint8_t>(packet).first(22));
  std::uint16_t header_sum = 0;
  for (int i = 0; i < 11; ++i)
    header_sum = static_cast<std::uint16_t>(header_sum + header_words.get_u16());
  w.put_u16(header_sum);
  w.put_bytes(body);
  w.put_zeros(padded - data_length);  // filler
  if (config_.data_checksum) {
    // 32-bit arithmetic sum of the 32-bit little-endian words of the body including filler.
    bytes::LittleEndianReader body_words(
        std::span<const std::uint8_t>(packet).subspan(kHeaderBytes, padded));
    std::uint32_t sum = 0;
    for (std::size_t i = 0; i < padded / 4; ++i)
      sum += body_words.get_u32();
    w.put_u32(sum);
  }
  return packet;
}

// One packet onto the current file. A failed write is cut back to the last whole packet, so the
// file never holds partial bytes that later packets would follow. `written`: the packet is in the
// file (then only its fdatasync can have failed).
int Chapter10Writer::append(const std::vector<std::uint8_t>& packet, bool& written) {
  written = false;
  std::size_t done = 0;
  int rc = 0;
  while (done < packet.size()) {
    const ssize_t n = ops_.write(fd_, packet.data() + done, packet.size() - done);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) {
      rc = n < 0 ? -errno : -EIO;
      break;
    }
    done += static_cast<std::size_t>(n);
  }
  if (rc != 0) {
    ++counters_.write_errors;
    if (ops_.ftruncate(fd_, static_cast<off_t>(file_bytes_)) != 0)
      ++counters_.truncate_errors;
    else if (done > 0)
      ++counters_.truncations;
    return rc;
  }
  written = true;
  file_bytes_ += packet.size();
  ++counters_.packets_written;
  counters_.bytes_written += packet.size();
  if (config_.sync == Chapter10Sync::kEveryPacket && ops_.fdatasync(fd_) != 0) {
    ++counters_.sync_errors;
    return -errno;
  }
  return 0;
}

// The packet goes to the current file; when that fails, the file is closed and the packet gets
// one more try at the start of a continuation file. `messages`: samples the packet carries.
// Returns 0, or the first error met (also when the continuation file then took the packet).
int Chapter10Writer::write_packet(std::uint16_t channel_id, std::uint8_t data_type,
                                  std::uint64_t rtc, const std::vector<std::uint8_t>& body,
                                  int messages, Payload payload) {
  if (!opened_) return -EBADF;
  const std::vector<std::uint8_t> packet = build_packet(channel_id, data_type, rtc, body);
  int rc = 0;
  bool written = false;
  if (fd_ >= 0) {
    rc = append(packet, written);
    if (rc != 0) abandon_file();  // after an fdatasync error the file is not trusted either
  }
  if (!written) {
    if (const int r = start_continuation_file(payload != Payload::kTime); r != 0) {
      if (rc == 0) rc = -EIO;  // no usable file since an earlier failure
    } else if (const int r2 = append(packet, written); r2 != 0) {
      abandon_file();
      failed_reopen_utc_s_ = current_utc_s_;
      if (rc == 0) rc = r2;
    }
  }
  const auto n = static_cast<std::uint64_t>(messages);
  if (written) {
    if (payload == Payload::kSamples) {
      ++file_data_packets_;
      ++counters_.message_packets;
      counters_.messages_written += n;
    } else if (payload == Payload::kRaw) {
      ++file_data_packets_;
      ++counters_.raw_packets;
      counters_.raw_messages_written += n;
    } else if (payload == Payload::kTime) {
      ++counters_.time_packets;
    }
  } else {
    ++counters_.packets_dropped;
    if (payload == Payload::kRaw) {
      ++counters_.raw_packets_dropped;
      counters_.raw_messages_dropped += n;
    } else {
      counters_.messages_dropped += n;
    }
  }
  return rc;
}

std::vector<std::uint8_t> Chapter10Writer::time_body(std::int64_t utc_second) const {
  const time::TaiNs tai = (utc_second + time::kTaiMinusUtcSeconds) * time::kNsPerSecond;
  const UtcCalendar c = utc_calendar_from_tai(tai);
  std::vector<std::uint8_t> body;
  // CSDW: bits 3-0 SRC = 1 (external: PTP), bits 7-4 FMT = 4 (UTC), bit 8 LY, bit 9 DATE = 1
  // (month and year format), bits 11-10 ITS = 0.
  const bool leap = (c.year % 4 == 0 && c.year % 100 != 0) || c.year % 400 == 0;
  bytes::LittleEndianWriter w = grow(body, 12);
  w.put_u32(0x1u | (0x4u << 4) | (leap ? 1u << 8 : 0u) | (1u << 9));
  // Month/year format: four 16-bit words of BCD digits.
  w.put_u16(static_cast<std::uint16_t>(bcd2(c.millisecond / 10) | (bcd2(c.second) << 8)));
  w.put_u16(static_cast<std::uint16_t>(bcd2(c.minute) | (bcd2(c.hour) << 8)));
  w.put_u16(static_cast<std::uint16_t>(bcd2(c.day) | (bcd2(c.month) << 8)));
  w.put_u16(static_cast<std::uint16_t>(bcd2(c.year % 100) | (bcd2(c.year / 100) << 8)));
  return body;
}

int Chapter10Writer::write_time_packet(std::int64_t utc_second) {
  const time::TaiNs tai = (utc_second + time::kTaiMinusUtcSeconds) * time::kNsPerSecond;
  return write_packet(config_.time_channel_id, kTypeTimeF1, rtc_of(tai), time_body(utc_second), 0,
                      Payload::kTime);
}

int Chapter10Writer::write(const msg::FtiSample& sample) {
  if (!opened_) return -EBADF;
  const time::TaiNs t = sample.exposure_mid_tai_ns;
  int rc = 0;
  const bool release_held_raw = start_tai_ns_ == kRtcEpochFirstSample;
  if (release_held_raw) set_epoch_from(t);
  if (last_sample_tai_ns_ != INT64_MIN && t < last_sample_tai_ns_) ++counters_.samples_out_of_order;
  last_sample_tai_ns_ = t;
  const std::int64_t utc_s =
      floor_div(t - time::kTaiMinusUtcSeconds * time::kNsPerSecond, time::kNsPerSecond);
  current_utc_s_ = utc_s;
  if (utc_s != last_time_packet_utc_s_) {
    // A new second: close the running message packet so time packets stay in time order.
    if (int r = flush_samples(); r != 0) rc = r;
    if (int r = write_time_packet(utc_s); r != 0) rc = r;
    last_time_packet_utc_s_ = utc_s;
  }
  // The observations held until the first sample fixed the time base, after its time packet.
  if (release_held_raw) {
    if (int r = flush_raw(false); r != 0) rc = r;
  }
  if (pending_messages_ > 0 && t - pending_first_tai_ns_ > config_.max_packet_span_ns) {
    if (int r = flush_samples(); r != 0) rc = r;
  }
  if (pending_messages_ == 0) pending_first_tai_ns_ = t;
  // Intra-packet header (11.2.1.1, Message Data F0): 8-byte time stamp (48-bit RTC in the low
  // bytes), then the intra-packet data header: bits 15-0 message length, bits 29-16 subchannel,
  // bit 30 format error, bit 31 data error (set when the sample is not a valid pose).
  bytes::LittleEndianWriter w = grow(pending_body_, 12);
  w.put_u64(rtc_of(t));
  const bool valid = (sample.status & msg::fti_status::kValid) != 0;
  w.put_u32(static_cast<std::uint32_t>(kFtiParameterBlockBytes) |
            (static_cast<std::uint32_t>(sample.store_id & 0x3FFF) << 16) | (valid ? 0u : 1u << 31));
  static_assert(kFtiParameterBlockBytes % 2 == 0, "Chapter 10 messages need no filler byte");
  pending_body_.resize(pending_body_.size() + kFtiParameterBlockBytes);
  encode_fti_parameter_block(sample, std::span(pending_body_).last(kFtiParameterBlockBytes));
  ++pending_messages_;
  if (pending_messages_ >= config_.max_messages_per_packet) {
    if (int r = flush_samples(); r != 0) rc = r;
  }
  return rc;
}

void Chapter10Writer::set_epoch_from(time::TaiNs t) {
  start_tai_ns_ =
      floor_div(t - time::kTaiMinusUtcSeconds * time::kNsPerSecond, time::kNsPerSecond) *
          time::kNsPerSecond +
      time::kTaiMinusUtcSeconds * time::kNsPerSecond;
}

int Chapter10Writer::write_raw(const msg::RawObservation& record,
                               std::span<const std::uint8_t> message) {
  if (!opened_) return -EBADF;
  if (!config_.raw_observations || message.size() != record.message_bytes ||
      message.size() > msg::kRawObservationMaxTailBytes) {
    ++counters_.raw_refused;
    return -EINVAL;
  }
  int rc = 0;
  const time::TaiNs t = record.arrival_tai_ns;
  if (!pending_raw_.empty() && start_tai_ns_ != kRtcEpochFirstSample &&
      t - pending_raw_.front().arrival > config_.max_packet_span_ns) {
    if (int r = flush_raw(false); r != 0) rc = r;
  }
  // Intra-packet header as for the samples: the 8-byte time stamp (filled in at flush), then
  // bits 15-0 message length, bits 29-16 subchannel = the unit the message claims, bit 30 format
  // error = the message was longer than the receive buffer (truncated), bit 31 data error = the
  // receiver refused it. An odd-length message is followed by its filler byte.
  const std::size_t length = msg::payload_size(record);
  pending_raw_.push_back({pending_raw_body_.size(), t, message.size()});
  bytes::LittleEndianWriter w = grow(pending_raw_body_, 12);
  w.put_u64(0);
  const bool accepted = (record.flags & msg::raw_observation_flags::kAccepted) != 0;
  const bool truncated = (record.flags & msg::raw_observation_flags::kTruncated) != 0;
  w.put_u32(static_cast<std::uint32_t>(length) | (std::uint32_t{record.unit_id} << 16) |
            (truncated ? 1u << 30 : 0u) | (accepted ? 0u : 1u << 31));
  const std::size_t at = pending_raw_body_.size();
  pending_raw_body_.resize(at + length + (length & 1), 0);
  bytes::BigEndianWriter bw{std::span(pending_raw_body_).subspan(at, length)};
  msg::pack_payload(record, message, bw);  // sizes checked above
  const auto held = pending_raw_.size();
  if (start_tai_ns_ == kRtcEpochFirstSample) {
    // No sample yet fixed the time base: hold (bounded), then take it from the observations.
    if (held >= static_cast<std::size_t>(config_.max_held_raw_messages)) {
      if (int r = flush_raw(true); r != 0) rc = r;
    }
  } else if (held >= static_cast<std::size_t>(config_.max_raw_messages_per_packet)) {
    if (int r = flush_raw(false); r != 0) rc = r;
  }
  return rc;
}

// Writes the held observations in packets of at most max_raw_messages_per_packet. Without an
// RTC epoch they stay held unless `force` (then the first arrival sets the epoch).
int Chapter10Writer::flush_raw(bool force) {
  if (!opened_ || pending_raw_.empty()) return 0;
  int rc = 0;
  if (start_tai_ns_ == kRtcEpochFirstSample) {
    if (!force) return 0;
    // No sample at all (yet): the observations' arrival sets the time base and its time packet.
    const time::TaiNs t = pending_raw_.front().arrival;
    set_epoch_from(t);
    const std::int64_t utc_s =
        floor_div(t - time::kTaiMinusUtcSeconds * time::kNsPerSecond, time::kNsPerSecond);
    current_utc_s_ = utc_s;
    if (int r = write_time_packet(utc_s); r != 0) rc = r;
    last_time_packet_utc_s_ = utc_s;
  }
  const std::size_t total = pending_raw_.size();
  const auto per_packet = static_cast<std::size_t>(config_.max_raw_messages_per_packet);
  for (std::size_t first = 0; first < total; first += per_packet) {
    const std::size_t last = std::min(total, first + per_packet);  // one past
    const std::size_t from = pending_raw_[first].offset;
    const std::size_t to = last < total ? pending_raw_[last].offset : pending_raw_body_.size();
    std::uint64_t message_bytes = 0;
    for (std::size_t i = first; i < last; ++i) {
      bytes::LittleEndianWriter stamp{
          std::span(pending_raw_body_).subspan(pending_raw_[i].offset, 8)};
      stamp.put_u64(rtc_of(pending_raw_[i].arrival));
      message_bytes += pending_raw_[i].message_bytes;
    }
    std::vector<std::uint8_t> body;
    body.reserve(to - from + 4);
    grow(body, 4).put_u32(static_cast<std::uint32_t>(last - first));  // CSDW: count, complete
    body.insert(body.end(), pending_raw_body_.begin() + static_cast<std::ptrdiff_t>(from),
                pending_raw_body_.begin() + static_cast<std::ptrdiff_t>(to));
    const std::uint64_t written_before = counters_.raw_packets;
    if (int r = write_packet(config_.raw_channel_id, kTypeMessageF0,
                             rtc_of(pending_raw_[first].arrival), body,
                             static_cast<int>(last - first), Payload::kRaw);
        r != 0 && rc == 0)
      rc = r;
    if (counters_.raw_packets != written_before) counters_.raw_bytes_written += message_bytes;
  }
  pending_raw_body_.clear();
  pending_raw_.clear();
  return rc;
}

int Chapter10Writer::flush() {
  const int rc = flush_samples();
  const int r = flush_raw(true);
  return rc != 0 ? rc : r;
}

int Chapter10Writer::flush_samples() {
  if (!opened_ || pending_messages_ == 0) return 0;
  std::vector<std::uint8_t> body;
  body.reserve(pending_body_.size() + 4);
  // CSDW: bits 15-0 message count (<= kMaxChapter10MessagesPerPacket by open()), bits 17-16
  // packet type 00 = complete messages.
  grow(body, 4).put_u32(static_cast<std::uint32_t>(pending_messages_));
  body.insert(body.end(), pending_body_.begin(), pending_body_.end());
  const int rc =
      write_packet(config_.message_channel_id, kTypeMessageF0, rtc_of(pending_first_tai_ns_), body,
                   pending_messages_, Payload::kSamples);
  pending_body_.clear();
  pending_messages_ = 0;
  return rc;
}

int Chapter10Writer::close() {
  if (!opened_) return close_file();
  int rc = flush();
  if (fd_ >= 0 && ops_.fdatasync(fd_) != 0) {
    ++counters_.sync_errors;
    if (rc == 0) rc = -errno;
  }
  if (const int r = close_file(); r != 0 && rc == 0) rc = r;
  opened_ = false;
  return rc;
}

}  // namespace storetrack::output
