#include "storetrack/capture/replay_frame_source.hpp"

#include <algorithm>
#include <cerrno>
#include <charconv>
#include <cstring>
#include <ctime>
#include <filesystem>
#include <fstream>
#include <limits>
#include <sstream>
#include <stdexcept>

#include "storetrack/capture/pgm.hpp"
#include "storetrack/csv/fields.hpp"
#include "storetrack/json/text_file.hpp"
#include "storetrack/time/saturating.hpp"

namespace storetrack::capture {
namespace fs = std::filesystem;

namespace {

int column(const std::vector<std::string>& header, std::initializer_list<const char*> names) {
  for (const char* n : names) {
    for (std::size_t i = 0; i < header.size(); ++i) {
      if (header[i] == n) return static_cast<int>(i);
    }
  }
  return -1;
}

// The whole field as a decimal integer in [lo, hi]: std::stoul took "12abc" as 12, " -1" as
// 4294967295 and 4294967296 as 0 after the cast.
template <typename T>
bool whole_integer(const std::string& field, T lo, T hi, T& out) {
  const char* end = field.data() + field.size();
  const auto [stop, ec] = std::from_chars(field.data(), end, out);
  return !field.empty() && ec == std::errc() && stop == end && out >= lo && out <= hi;
}

}  // namespace

std::vector<ReplayRecord> parse_trigger_csv(const std::string& text) {
  std::vector<ReplayRecord> out;
  std::istringstream in(text);
  std::string line;
  int line_no = 0;
  std::vector<std::string> header;
  int c_file = -1, c_seq = -1, c_mono = -1, c_tai = -1, c_exp = -1;
  while (std::getline(in, line)) {
    ++line_no;
    if (!line.empty() && line.back() == '\r') line.pop_back();
    if (line.empty() || line[0] == '#') continue;
    const std::vector<std::string> f = csv::split_fields(line);
    if (header.empty()) {  // the header names the columns (any order, extra columns ignored)
      header = f;
      c_file = column(header, {"file"});
      c_seq = column(header, {"trigger_seq"});
      c_mono = column(header, {"exposure_start_mono_ns", "reported_start_mono_ns"});
      c_tai = column(header, {"exposure_start_tai_ns", "reported_start_tai_ns"});
      c_exp = column(header, {"exposure_ns"});
      if (c_file < 0 || c_seq < 0 || c_mono < 0 || c_tai < 0 || c_exp < 0) {
        throw std::runtime_error(
            "triggers.csv line " + std::to_string(line_no) +
            ": header must name file, trigger_seq, exposure_start_mono_ns (or "
            "reported_start_mono_ns), exposure_start_tai_ns (or reported_start_tai_ns), "
            "exposure_ns");
      }
      continue;
    }
    if (f.size() != header.size()) {
      throw std::runtime_error("triggers.csv line " + std::to_string(line_no) + ": expected " +
                               std::to_string(header.size()) + " comma-separated fields");
    }
    ReplayRecord r;
    r.file = f[static_cast<std::size_t>(c_file)];
    const auto field = [&](int c) -> const std::string& { return f[static_cast<std::size_t>(c)]; };
    // Exposure starts are clock readings (ns since boot, since the TAI epoch): never negative.
    constexpr std::int64_t kMaxNs = std::numeric_limits<std::int64_t>::max();
    constexpr std::uint32_t kMaxU32 = std::numeric_limits<std::uint32_t>::max();
    if (!whole_integer<std::uint32_t>(field(c_seq), 0, kMaxU32, r.trigger_seq) ||
        !whole_integer<std::int64_t>(field(c_mono), 0, kMaxNs, r.exposure_start_mono_ns) ||
        !whole_integer<std::int64_t>(field(c_tai), 0, kMaxNs, r.exposure_start_tai_ns) ||
        !whole_integer<std::uint32_t>(field(c_exp), 0, kMaxU32, r.exposure_ns)) {
      throw std::runtime_error("triggers.csv line " + std::to_string(line_no) +
                               ": bad number in '" + line +
                               "' (whole decimal integers; times >= 0)");
    }
    out.push_back(r);
  }
  return out;
}

ReplayFrameSource::ReplayFrameSource(ReplayConfig config) : config_(std::move(config)) {}

int ReplayFrameSource::start() {
  error_.clear();
  records_.clear();
  paths_.clear();
  const fs::path dir(config_.directory);
  std::error_code ec;
  if (!fs::is_directory(dir, ec)) {
    error_ = config_.directory + ": not a directory";
    return -ENOENT;
  }
  const fs::path index = dir / "triggers.csv";
  if (fs::exists(index, ec)) {
    try {
      records_ = parse_trigger_csv(jsonfile::read_text_file(index.string()));
    } catch (const jsonfile::FileReadError& e) {
      error_ = e.what();
      return -EIO;
    } catch (const std::exception& e) {
      error_ = index.string() + ": " + e.what();
      return -EINVAL;
    }
  } else {
    std::vector<std::string> files;
    for (const auto& entry : fs::directory_iterator(dir, ec)) {
      if (entry.path().extension() == ".pgm") files.push_back(entry.path().filename().string());
    }
    std::sort(files.begin(), files.end());
    for (std::size_t i = 0; i < files.size(); ++i) {
      ReplayRecord r;
      r.file = files[i];
      r.trigger_seq = static_cast<std::uint32_t>(i);
      r.exposure_start_mono_ns = static_cast<std::int64_t>(i) * config_.default_period_ns;
      r.exposure_start_tai_ns = r.exposure_start_mono_ns;
      r.exposure_ns = config_.default_exposure_ns;
      records_.push_back(r);
    }
  }
  if (records_.empty()) {
    error_ = config_.directory + ": no frames (no triggers.csv lines and no *.pgm files)";
    return -ENODATA;
  }
  std::uintmax_t largest = 0;
  for (const ReplayRecord& r : records_) {
    const fs::path p = dir / r.file;
    const std::uintmax_t size = fs::file_size(p, ec);
    if (ec) {
      error_ = p.string() + ": " + ec.message();
      return -ENOENT;
    }
    largest = std::max(largest, size);
    paths_.push_back(p.string());
  }
  file_buffer_.assign(static_cast<std::size_t>(largest), 0);
  pixels_.assign(static_cast<std::size_t>(largest), 0);
  next_ = 0;
  loops_ = 0;
  loop_offset_ns_ = 0;
  pace_start_mono_ns_ = time::monotonic_now_ns();
  return 0;
}

int ReplayFrameSource::acquire(frame::FrameView& frame, int /*timeout_ms*/) {
  if (paths_.empty()) return -ENOTCONN;
  if (in_use_) return -EBUSY;  // one frame at a time: the buffer is reused
  if (next_ >= records_.size()) {
    if (!config_.loop) return -ENODATA;
    next_ = 0;
    ++loops_;
    // Time stamps are anywhere in [0, INT64_MAX] (a file's): the sums saturate, not overflow.
    const std::int64_t span_ns =
        time::saturating_add_ns(time::saturating_sub_ns(records_.back().exposure_start_mono_ns,
                                                        records_.front().exposure_start_mono_ns),
                                config_.default_period_ns);
    loop_offset_ns_ = time::saturating_add_ns(loop_offset_ns_, span_ns);
  }
  const std::size_t i = next_++;
  if (config_.rate_hz > 0.0) {  // real-time pacing against the monotonic clock
    const std::uint64_t k = loops_ * records_.size() + i;
    const auto due = pace_start_mono_ns_ +
                     static_cast<std::int64_t>(static_cast<double>(k) * 1e9 / config_.rate_hz);
    timespec ts{static_cast<time_t>(due / time::kNsPerSecond),
                static_cast<long>(due % time::kNsPerSecond)};
    while (clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &ts, nullptr) == EINTR) {
    }
  }
  const long n = read_file_into(paths_[i].c_str(), file_buffer_);
  if (n < 0) return static_cast<int>(n);
  PgmHeader h;
  const std::span<const std::uint8_t> bytes(file_buffer_.data(), static_cast<std::size_t>(n));
  if (int rc = parse_pgm_header(bytes, h); rc < 0) return rc;
  const std::size_t count = static_cast<std::size_t>(h.width) * static_cast<std::size_t>(h.height);
  const std::uint8_t* src = file_buffer_.data() + h.data_offset;
  if (h.bytes_per_pixel() == 1) {
    std::memcpy(pixels_.data(), src, count);
    frame.format = frame::PixelFormat::kMono8;
    frame.bits_per_pixel = 8;
    frame.stride_bytes = h.width;
  } else {
    // A pixel above maxval is no P5 file, and would exceed the frame's significant bits.
    std::uint32_t brightest = 0;
    for (std::size_t p = 0; p < count; ++p) {  // big-endian on disk -> little-endian
      pixels_[2 * p] = src[2 * p + 1];
      pixels_[2 * p + 1] = src[2 * p];
      brightest = std::max(brightest, std::uint32_t{src[2 * p]} << 8 | src[2 * p + 1]);
    }
    if (brightest > static_cast<std::uint32_t>(h.maxval)) return -EINVAL;
    int bits = 9;
    while ((1 << bits) - 1 < h.maxval)
      ++bits;
    frame.format = frame::PixelFormat::kMono16;
    frame.bits_per_pixel = bits;
    frame.stride_bytes = 2 * h.width;
  }
  const ReplayRecord& r = records_[i];
  frame.pixels = pixels_.data();
  frame.width = h.width;
  frame.height = h.height;
  // A looped replay continues the sequence and the clock instead of repeating them.
  const std::uint32_t seq_span = records_.back().trigger_seq - records_.front().trigger_seq + 1;
  frame.sequence = r.trigger_seq + static_cast<std::uint32_t>(loops_) * seq_span;
  frame.timestamp_mono_ns = time::saturating_add_ns(r.exposure_start_mono_ns, loop_offset_ns_);
  frame.exposure_ns = r.exposure_ns;
  frame.buffer_index = static_cast<int>(i);
  last_tai_ns_ = time::saturating_add_ns(r.exposure_start_tai_ns, loop_offset_ns_);
  in_use_ = true;
  return 0;
}

int ReplayFrameSource::release(const frame::FrameView& /*frame*/) {
  in_use_ = false;
  return 0;
}

}  // namespace storetrack::capture
