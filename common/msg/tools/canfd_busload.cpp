// storetrack-canfd-busload: CAN FD (and classic CAN) bus load of the MarkObservations traffic,
// computed from the frames the real codec produces, bit by bit (ISO 11898-1:2015):
//  - CAN FD, 29-bit identifier, bit-rate switch: the arbitration phase (SOF .. BRS) and the
//    end of frame (ACK slot, ACK delimiter, 7 EOF, 3 intermission) run at the nominal rate,
//    ESI .. CRC delimiter at the data rate;
//  - dynamic stuff bits (after 5 equal bits) counted exactly on the actual bit sequence from SOF
//    to the end of the data field, and bounded by the worst case floor((n - 1) / 4);
//  - CRC field: 4-bit stuff count (Gray code + parity), CRC-17 (<= 16 data bytes) or CRC-21,
//    fixed stuff bits before the stuff count and after every 4th bit (6 resp. 7).
//  - classic CAN: 29-bit id, 8 data bytes, CRC-15 (computed), dynamic stuffing up to the CRC.
// Usage:
//   storetrack-canfd-busload                    print the markdown block
//   storetrack-canfd-busload --check-icd FILE   exit 1 when FILE's block differs
//   storetrack-canfd-busload --update-icd FILE  rewrite FILE's block
#include <array>
#include <cmath>
#include <cstdarg>
#include <cstdint>
#include <cstdio>
#include <fstream>
#include <map>
#include <random>
#include <sstream>
#include <string>
#include <vector>

#include "storetrack/json/text_file.hpp"
#include "storetrack/msg/canfd_codec.hpp"

namespace msg = storetrack::msg;

namespace {

constexpr double kNominalBitRate = 1e6;
constexpr double kDataBitRate = 5e6;
constexpr double kFps = 400.0;
constexpr int kMarks = 23;
constexpr int kSamples = 2000;  // random exposures per case

struct FrameBits {
  int nominal = 0;        // bits at the nominal (arbitration) rate, exact stuffing
  int data = 0;           // bits at the data rate, exact stuffing
  int nominal_worst = 0;  // with worst-case dynamic stuffing
  int data_worst = 0;
  double seconds(bool worst, double data_bit_rate = kDataBitRate) const {
    return (worst ? nominal_worst : nominal) / kNominalBitRate +
           (worst ? data_worst : data) / data_bit_rate;
  }
};

void push_bits(std::vector<int>& bits, std::uint32_t value, int n) {
  for (int i = n - 1; i >= 0; --i)
    bits.push_back((value >> i) & 1u);
}

// Dynamic bit stuffing: returns the stuff bits inserted in bits[0, split) and in [split, end).
std::pair<int, int> count_stuff_bits(const std::vector<int>& bits, std::size_t split) {
  int first = 0, second = 0, run = 0, last = -1;
  for (std::size_t i = 0; i < bits.size(); ++i) {
    if (bits[i] == last) {
      ++run;
    } else {
      last = bits[i];
      run = 1;
    }
    if (run == 5) {  // a complementary stuff bit follows and starts a new run
      (i < split ? first : second)++;
      last = 1 - last;
      run = 1;
    }
  }
  return {first, second};
}

std::uint8_t dlc_of(std::uint8_t len) {
  constexpr std::uint8_t lens[] = {0, 1, 2, 3, 4, 5, 6, 7, 8, 12, 16, 20, 24, 32, 48, 64};
  for (std::uint8_t d = 0; d < 16; ++d)
    if (lens[d] == len) return d;
  return 15;
}

FrameBits canfd_frame_bits(const msg::CanFdFrame& f) {
  std::vector<int> bits;
  bits.push_back(0);                         // SOF
  push_bits(bits, f.can_id >> 18, 11);       // base identifier
  bits.push_back(1);                         // SRR
  bits.push_back(1);                         // IDE
  push_bits(bits, f.can_id & 0x3FFFFu, 18);  // identifier extension
  bits.push_back(0);                         // RRS
  bits.push_back(1);                         // FDF
  bits.push_back(0);                         // res
  bits.push_back(1);                         // BRS: the data rate starts after its sample point
  const std::size_t arbitration_bits = bits.size();
  bits.push_back(0);  // ESI (error active)
  push_bits(bits, dlc_of(f.len), 4);
  for (int i = 0; i < f.len; ++i)
    push_bits(bits, f.data[i], 8);
  const auto [stuff_nominal, stuff_data] = count_stuff_bits(bits, arbitration_bits);
  const int crc_bits = f.len <= 16 ? 17 : 21;
  const int fixed_stuff = 1 + (4 + crc_bits) / 4;  // 6 for CRC-17, 7 for CRC-21
  const int crc_field = 4 + crc_bits + fixed_stuff;
  const int end_nominal = 1 + 1 + 7 + 3;  // ACK slot, ACK delimiter, EOF, intermission
  const int data_fields = static_cast<int>(bits.size() - arbitration_bits) + crc_field + 1;
  const int worst_total = static_cast<int>((bits.size() - 1) / 4);
  const int worst_nominal = static_cast<int>((arbitration_bits - 1) / 4);
  FrameBits fb;
  fb.nominal = static_cast<int>(arbitration_bits) + stuff_nominal + end_nominal;
  fb.data = data_fields + stuff_data;
  fb.nominal_worst = static_cast<int>(arbitration_bits) + worst_nominal + end_nominal;
  fb.data_worst = data_fields + (worst_total - worst_nominal);
  return fb;
}

// Classic CAN 2.0B data frame, 29-bit id, CRC-15 (polynomial 0x4599) over SOF..data.
FrameBits classic_frame_bits(std::uint32_t id, const std::uint8_t* data, int len) {
  std::vector<int> bits;
  bits.push_back(0);
  push_bits(bits, id >> 18, 11);
  bits.push_back(1);  // SRR
  bits.push_back(1);  // IDE
  push_bits(bits, id & 0x3FFFFu, 18);
  bits.push_back(0);  // RTR
  bits.push_back(0);  // r1
  bits.push_back(0);  // r0
  push_bits(bits, static_cast<std::uint32_t>(len), 4);
  for (int i = 0; i < len; ++i)
    push_bits(bits, data[i], 8);
  std::uint32_t crc = 0;
  for (int b : bits) {
    const std::uint32_t next = static_cast<std::uint32_t>(b) ^ ((crc >> 14) & 1u);
    crc = (crc << 1) & 0x7FFFu;
    if (next) crc ^= 0x4599u;
  }
  push_bits(bits, crc, 15);
  const auto [stuff, unused] = count_stuff_bits(bits, bits.size());
  (void)unused;
  const int tail = 1 + 1 + 1 + 7 + 3;  // CRC delimiter, ACK slot, ACK delimiter, EOF, IFS
  FrameBits fb;
  fb.nominal = static_cast<int>(bits.size()) + stuff + tail;
  fb.nominal_worst = static_cast<int>(bits.size()) + static_cast<int>((bits.size() - 1) / 4) + tail;
  return fb;
}

// Deterministic pseudo-random values from raw mt19937_64 output (the standard distributions
// are implementation-defined; the ICD numbers must not depend on the library).
double uniform(std::mt19937_64& rng, double lo, double hi) {
  return lo + (hi - lo) * static_cast<double>(rng() >> 11) * 0x1.0p-53;
}

msg::MarkObservations random_exposure(std::mt19937_64& rng, std::uint8_t camera,
                                      std::uint32_t seq) {
  msg::MarkObservations m;
  m.unit_id = camera / 2;
  m.camera_id = camera;
  m.trigger_seq = seq;
  m.exposure_start_tai_ns = 1'800'000'000'000'000'000 + static_cast<std::int64_t>(seq) * 2'500'000;
  m.exposure_start_mono_ns = 5'000'000'000'000 + static_cast<std::int64_t>(seq) * 2'500'000;
  m.exposure_duration_ns = 200'000;
  m.clock_state = 2;
  m.flags = 0;
  m.mark_count = kMarks;
  for (int i = 0; i < kMarks; ++i) {
    msg::MarkObservation& o = m.marks[static_cast<std::size_t>(i)];
    o.x_px = static_cast<float>(uniform(rng, 0.0, 1919.0));
    o.y_px = static_cast<float>(uniform(rng, 0.0, 1023.0));
    o.sigma_px = static_cast<float>(uniform(rng, 0.01, 0.1));
    o.peak = static_cast<std::uint16_t>(uniform(rng, 60.0, 255.0));
    o.diameter_px = static_cast<float>(uniform(rng, 4.0, 16.0));
    o.flags = uniform(rng, 0.0, 1.0) < 0.05 ? msg::mark_flags::kSaturated : 0;
  }
  return m;
}

struct CaseResult {
  int cameras = 0;
  double frames_per_exposure = 0;
  double bytes_per_exposure = 0;               // data bytes incl. padding, all cameras
  double seconds_mean = 0, seconds_worst = 0;  // bus time per trigger, all cameras
  double bits_nominal = 0, bits_data = 0;      // mean per trigger
  // Per data length: frames, sums of exact nominal/data bits, worst-case nominal/data bits.
  std::map<int, std::array<double, 5>> by_len;
};

CaseResult canfd_case(int cameras, double data_bit_rate) {
  std::mt19937_64 rng(20261122u + static_cast<unsigned>(cameras));
  CaseResult r;
  r.cameras = cameras;
  std::array<msg::CanFdFrame, msg::kCanFdMaxFramesPerMessage> frames;
  for (int k = 0; k < kSamples; ++k) {
    for (int c = 0; c < cameras; ++c) {
      const auto m =
          random_exposure(rng, static_cast<std::uint8_t>(c), static_cast<std::uint32_t>(k));
      const int n = msg::encode_canfd(m, frames);
      for (int i = 0; i < n; ++i) {
        const FrameBits fb = canfd_frame_bits(frames[static_cast<std::size_t>(i)]);
        r.frames_per_exposure += 1;
        r.bytes_per_exposure += frames[static_cast<std::size_t>(i)].len;
        r.seconds_mean += fb.seconds(false, data_bit_rate);
        r.seconds_worst += fb.seconds(true, data_bit_rate);
        r.bits_nominal += fb.nominal;
        r.bits_data += fb.data;
        auto& row = r.by_len[frames[static_cast<std::size_t>(i)].len];
        row[0] += 1;
        row[1] += fb.nominal;
        row[2] += fb.data;
        row[3] = fb.nominal_worst;
        row[4] = fb.data_worst;
      }
    }
  }
  for (double* v : {&r.frames_per_exposure, &r.bytes_per_exposure, &r.seconds_mean,
                    &r.seconds_worst, &r.bits_nominal, &r.bits_data})
    *v /= kSamples;
  return r;
}

[[gnu::format(printf, 1, 2)]] std::string fmt(const char* format, ...) {
  char buf[64];
  va_list args;
  va_start(args, format);
  std::vsnprintf(buf, sizeof buf, format, args);
  va_end(args);
  return buf;
}

std::string render() {
  std::ostringstream o;
  o << "Computed by `storetrack-canfd-busload` (common/msg/tools/canfd_busload.cpp) from frames "
       "encoded by `encode_canfd`, "
    << kSamples << " random exposures per case, " << kMarks << " marks per camera, "
    << fmt("%.0f", kFps) << " fps, nominal (arbitration) rate "
    << fmt("%.0f", kNominalBitRate / 1e6) << " Mbit/s, data rate "
    << fmt("%.0f", kDataBitRate / 1e6)
    << " Mbit/s. \"exact\" counts the dynamic stuff bits of the actual bit sequences, \"worst\" "
       "assumes a stuff bit after every 4 bits.\n\n";
  o << "| Cameras | Data rate | Frames / trigger | Data bytes / trigger | Nominal-rate bits / "
       "trigger | "
       "Data-rate bits / trigger | Bus time / trigger (exact) | Bus time (worst) | "
       "Bus load (exact) | Bus load (worst) |\n";
  o << "|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|\n";
  const double period = 1.0 / kFps;
  const std::pair<int, double> cases[] = {
      {1, kDataBitRate}, {2, kDataBitRate}, {4, kDataBitRate}, {4, 8e6}};
  for (const auto& [cameras, data_bit_rate] : cases) {
    const CaseResult r = canfd_case(cameras, data_bit_rate);
    o << "| " << cameras << " | " << fmt("%.0f Mbit/s", data_bit_rate / 1e6) << " | "
      << fmt("%.0f", r.frames_per_exposure) << " | " << fmt("%.0f", r.bytes_per_exposure) << " | "
      << fmt("%.1f", r.bits_nominal) << " | " << fmt("%.1f", r.bits_data) << " | "
      << fmt("%.1f us", r.seconds_mean * 1e6) << " | " << fmt("%.1f us", r.seconds_worst * 1e6)
      << " | " << fmt("%.1f %%", 100.0 * r.seconds_mean / period) << " | "
      << fmt("%.1f %%", 100.0 * r.seconds_worst / period) << " |\n";
  }
  // Anatomy of the frames of one camera's exposure.
  {
    const CaseResult one = canfd_case(1, kDataBitRate);
    o << "\nFrames of one " << kMarks << "-mark exposure (4.4 gives the fields):\n\n"
      << "| Data bytes (DLC) | Frames / exposure | Nominal-rate bits exact (worst) | "
         "Data-rate bits exact (worst) | Frame time exact (worst) |\n"
      << "|---:|---:|---:|---:|---:|\n";
    for (const auto& [len, row] : one.by_len) {
      const double nominal = row[1] / row[0], data = row[2] / row[0];
      o << "| " << len << " | " << fmt("%.0f", row[0] / kSamples) << " | "
        << fmt("%.1f (%.0f)", nominal, row[3]) << " | " << fmt("%.1f (%.0f)", data, row[4]) << " | "
        << fmt("%.1f us (%.1f us)", 1e6 * (nominal / kNominalBitRate + data / kDataBitRate),
               1e6 * (row[3] / kNominalBitRate + row[4] / kDataBitRate))
        << " |\n";
    }
  }
  // UnitHealth: 1 Hz per unit, negligible but shown.
  {
    msg::UnitHealth h;
    h.unit_id = 0;
    std::array<msg::CanFdFrame, msg::kCanFdMaxFramesPerMessage> frames;
    const int n = msg::encode_canfd(h, frames);
    double t = 0;
    for (int i = 0; i < n; ++i)
      t += canfd_frame_bits(frames[static_cast<std::size_t>(i)]).seconds(true);
    o << "\nUnitHealth: " << n << " frames, " << fmt("%.1f us", t * 1e6)
      << " worst case per report; at 1 Hz per unit " << fmt("%.4f %%", 100.0 * t)
      << " bus load per unit.\n";
  }
  // Classic CAN 1 Mbit/s, hypothetical mapping: one 8-byte frame per mark word (camera, trigger
  // sequence and mark index in the 29-bit id) plus 3 frames per camera exposure for the 24
  // bytes of times/state.
  {
    std::mt19937_64 rng(7u);
    double mean = 0, worst = 0;
    for (int k = 0; k < kSamples; ++k) {
      const auto m = random_exposure(rng, 0, static_cast<std::uint32_t>(k));
      std::uint64_t word = 0;
      msg::pack_mark(m.marks[0], word);
      std::uint8_t data[8];
      for (int b = 0; b < 8; ++b)
        data[b] = static_cast<std::uint8_t>(word >> (56 - 8 * b));
      const FrameBits fb = classic_frame_bits(
          msg::canid::make(2, 1, 0, 0, static_cast<std::uint8_t>(k & 0x7)), data, 8);
      mean += fb.nominal;
      worst += fb.nominal_worst;
    }
    mean /= kSamples;
    worst /= kSamples;
    const double frames_per_s_worst = kNominalBitRate / worst;
    const double header_frames = 3;
    const double marks_per_trigger_100 = frames_per_s_worst / kFps - header_frames;
    const double marks_1cam_at_50 = 0.5 * frames_per_s_worst / kFps - header_frames;
    const double fps_2cam = frames_per_s_worst / (2 * (kMarks + header_frames));
    const double fps_2cam_50 = 0.5 * fps_2cam;
    const double bytes_per_frame_fd_stream = 61, bytes_per_frame_classic_stream = 5;
    (void)bytes_per_frame_fd_stream;
    const double stream = msg::kMarkObservationsFixedBytes + kMarks * msg::kMarkObservationBytes +
                          msg::kCanFdTransferCrcBytes;
    const double classic_same_framing = std::ceil(stream / bytes_per_frame_classic_stream);
    o << "\nClassic CAN, 1 Mbit/s, 29-bit id, 8 data bytes: " << fmt("%.1f", mean)
      << " bits per frame exact (" << fmt("%.0f", worst) << " worst case), i.e. at most "
      << fmt("%.0f", frames_per_s_worst) << " frames/s. With this ICD's fragment framing "
      << "(3-byte header, 5 stream bytes per frame) one " << kMarks << "-mark exposure needs "
      << fmt("%.0f", classic_same_framing)
      << " frames = " << fmt("%.2f ms", 1e3 * classic_same_framing / frames_per_s_worst)
      << " of bus time, more than the " << fmt("%.1f ms", 1e3 / kFps)
      << " frame period: classic CAN cannot carry even one camera at 400 fps. With a dedicated "
      << "classic mapping (one mark word per frame, indices in the identifier, 3 frames of "
      << "exposure times) it carries at most " << fmt("%.0f", marks_per_trigger_100)
      << " marks per trigger summed over all cameras at 100 % load ("
      << fmt("%.0f", marks_1cam_at_50) << " at a 50 % load limit), or 2 cameras x " << kMarks
      << " marks at " << fmt("%.0f", fps_2cam) << " fps (" << fmt("%.0f", fps_2cam_50)
      << " fps at 50 % load). What it does carry comfortably: UnitHealth (1 Hz), trigger/clock "
      << "status, and a reduced-rate pose output.\n";
  }
  return o.str();
}

const std::string kBegin = "<!-- BEGIN GENERATED canfd:busload -->\n";
const std::string kEnd = "<!-- END GENERATED canfd:busload -->";

int check_or_update(const std::string& path, bool update) {
  std::string text;
  try {
    text = storetrack::jsonfile::read_text_file(path);
  } catch (const storetrack::jsonfile::FileReadError& e) {
    std::fprintf(stderr, "%s\n", e.what());
    return 2;
  }
  const auto b = text.find(kBegin);
  const auto e = text.find(kEnd);
  if (b == std::string::npos || e == std::string::npos || e < b) {
    std::fprintf(stderr, "%s lacks the canfd:busload markers\n", path.c_str());
    return 1;
  }
  const std::string current = text.substr(b + kBegin.size(), e - b - kBegin.size());
  const std::string fresh = render();
  if (current == fresh) {
    std::printf("%s: CAN FD bus load block is up to date\n", path.c_str());
    return 0;
  }
  if (!update) {
    std::fprintf(stderr,
                 "%s: CAN FD bus load block differs from the computed one; run "
                 "storetrack-canfd-busload --update-icd %s\n--- in file:\n%s\n--- computed:\n%s\n",
                 path.c_str(), path.c_str(), current.c_str(), fresh.c_str());
    return 1;
  }
  std::ofstream out(path);
  out << text.substr(0, b + kBegin.size()) << fresh << text.substr(e);
  std::printf("updated %s\n", path.c_str());
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  if (argc == 3 && std::string(argv[1]) == "--check-icd") return check_or_update(argv[2], false);
  if (argc == 3 && std::string(argv[1]) == "--update-icd") return check_or_update(argv[2], true);
  if (argc != 1) {
    std::fprintf(stderr, "usage: %s [--check-icd FILE | --update-icd FILE]\n", argv[0]);
    return 2;
  }
  std::fputs(render().c_str(), stdout);
  return 0;
}
