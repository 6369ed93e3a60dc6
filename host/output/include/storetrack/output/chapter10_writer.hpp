// IRIG 106-17 Chapter 10 file writer (recorder side of the FTI output).
//
// File = TMATS setup record (Computer-Generated Data Format 1, channel 0) first, then the
// recorded inputs (Computer-Generated Data Format 0, channel 4: calibration, surveys, host
// configuration... byte for byte with their SHA-256), then Time Data Format 1 packets (one per
// UTC second of exposure time), Message Data Format 0 packets carrying FTI parameter blocks, one
// subchannel per store (channel 2), and, when enabled, Message Data Format 0 packets carrying
// every observation message the host received as it arrived (channel 3, RawObservation). Every
// packet is built whole in memory and written with ONE write() on an O_APPEND descriptor, then
// fdatasync()ed (policy), so a crash or power loss loses at most the packet being written and the
// file stays readable up to the last whole packet. Layout byte by byte: docs/fti-output.md.
//
// A recording is never overwritten: an existing path is refused or a new numbered file is
// created next to it (out.ch10 -> out.001.ch10). A failed write is cut back to the last whole
// packet; a file that failed (write, fdatasync or truncate error) is closed and the recording
// continues in the next numbered file, which starts with its own TMATS and time packet.
// docs/reliability.md, "Recording".
#pragma once

#include <sys/types.h>

#include <climits>
#include <cstddef>
#include <cstdint>
#include <span>
#include <string>
#include <vector>

#include "storetrack/msg/messages.hpp"
#include "storetrack/time/time.hpp"

namespace storetrack::output {

struct Chapter10StoreInfo {
  std::uint8_t store_id = 1;  ///< FtiSample::store_id, also the message subchannel id
  std::string name = "store";
};

/// What a recorded input is (RecordedInput.kind, docs/fti-output.md).
enum class RecordedInputKind : std::uint8_t {
  kCalibration = 0,
  kPylonSurvey = 1,
  kStoreSurvey = 2,
  kHostConfig = 3,
  kInitialMarks = 4,
  kCommandLine = 5,
  kClearanceGeometry = 6,  ///< the clearance geometry file (docs/clearance.md)
  kClearanceMesh = 7,      ///< an STL file it names; name: the path the geometry resolves
};
const char* to_string(RecordedInputKind kind);

/// One input file the recording carries (at the start of every file, continuation files too).
struct RecordedInputFile {
  RecordedInputKind kind = RecordedInputKind::kCalibration;
  std::string name;                 ///< the path as given (at most 1024 bytes are recorded)
  std::vector<std::uint8_t> bytes;  ///< the content, byte for byte
};

enum class Chapter10Sync : std::uint8_t {
  kEveryPacket,  ///< fdatasync after every packet: power loss loses at most the last packet
  kNone,         ///< leave flushing to the kernel (tests, tmpfs)
};

/// What open() does when the path already exists.
enum class Chapter10Existing : std::uint8_t {
  kNumberNewFile,  ///< record to the first free out.NNN.ch10 instead (NNN = 001 .. 999)
  kRefuse,         ///< fail with -EEXIST
};

/// The CSDW message count is 16 bits (Message Data Format 0, bits 15-0).
constexpr int kMaxChapter10MessagesPerPacket = 0xFFFF;
/// Numbered files out.001.ch10 .. out.999.ch10.
constexpr int kMaxChapter10FileNumber = 999;

struct Chapter10Config {
  std::uint16_t time_channel_id = 1;
  std::uint16_t message_channel_id = 2;
  std::uint16_t raw_channel_id = 3;     ///< RawObservation messages (when raw_observations)
  std::uint16_t inputs_channel_id = 4;  ///< RecordedInput packets (when inputs is not empty)
  /// The raw channel is described in TMATS and write_raw() records; off: write_raw() refuses.
  bool raw_observations = false;
  int max_raw_messages_per_packet = 64;  ///< raw messages per F0 packet, 1 .. 65535 (clamped)
  /// Observations held while the RTC epoch is unknown (no sample yet); past this many the epoch
  /// is taken from the first observation's arrival instead.
  int max_held_raw_messages = 8192;
  /// Inputs written at the start of every file; their SHA-256 is computed by open().
  std::vector<RecordedInputFile> inputs;
  std::vector<Chapter10StoreInfo> stores{Chapter10StoreInfo{}};
  bool data_checksum = true;                     ///< 32-bit data checksum trailer on every packet
  int max_messages_per_packet = 10;              ///< messages per F0 packet, 1 .. 65535 (clamped)
  std::int64_t max_packet_span_ns = 50'000'000;  ///< ... or this much exposure time
  Chapter10Sync sync = Chapter10Sync::kEveryPacket;
  Chapter10Existing existing = Chapter10Existing::kNumberNewFile;
  std::string program_name = "storetrack";
  std::string test_point = "simulated";
  /// More TMATS comments (G\COM), after the writer's own: a reprocessed recording's provenance
  /// (storetrack-post --output-ch10). A ';' (the attribute terminator) is written as ','.
  std::vector<std::string> comments;
};

struct Chapter10Counters {
  std::uint64_t packets_written = 0;
  std::uint64_t time_packets = 0;
  std::uint64_t message_packets = 0;
  std::uint64_t messages_written = 0;
  std::uint64_t bytes_written = 0;
  std::uint64_t write_errors = 0;          ///< failed or short write() of a packet
  std::uint64_t sync_errors = 0;           ///< fdatasync() failed: the file is not trusted further
  std::uint64_t samples_out_of_order = 0;  ///< exposure time went backwards: written anyway
  std::uint64_t files_opened = 0;          ///< the first file and every continuation file
  std::uint64_t numbered_instead_of_existing = 0;  ///< the requested path existed
  std::uint64_t continuation_files = 0;            ///< opened because the previous file failed
  std::uint64_t truncations = 0;      ///< partial packet bytes cut back after a failed write
  std::uint64_t truncate_errors = 0;  ///< ... and that cut failed (the file was left)
  std::uint64_t close_errors = 0;
  std::uint64_t directory_sync_errors = 0;  ///< fsync of the directory after creating a file
  std::uint64_t open_errors = 0;            ///< a continuation file could not be created
  std::uint64_t packets_dropped = 0;        ///< packets in no file (message and time packets)
  std::uint64_t messages_dropped = 0;       ///< samples in no file
  // The raw channel (RawObservation messages), apart from the samples.
  std::uint64_t raw_packets = 0;           ///< raw-channel packets written
  std::uint64_t raw_messages_written = 0;  ///< observations in those packets
  std::uint64_t raw_bytes_written = 0;     ///< observation bytes (as received) in those packets
  std::uint64_t raw_packets_dropped = 0;   ///< raw-channel packets that reached no file
  std::uint64_t raw_messages_dropped = 0;  ///< observations in those packets
  std::uint64_t raw_refused = 0;    ///< write_raw() refused: channel off, or the message too long
  std::uint64_t input_packets = 0;  ///< RecordedInput packets written (every file repeats them)
};

/// The system calls the writer makes on an open file; tests replace them to inject faults.
struct Chapter10FileOps {
  ssize_t (*write)(int fd, const void* data, std::size_t size);
  int (*fdatasync)(int fd);
  int (*ftruncate)(int fd, off_t length);
  int (*close)(int fd);
  int (*fsync_directory)(int dir_fd);  ///< after creating a file, on its directory
};
Chapter10FileOps posix_chapter10_file_ops();

/// `path` with a 3-digit number before its extension: out.ch10, 1 -> out.001.ch10.
std::string numbered_chapter10_path(const std::string& path, int number);

class Chapter10Writer {
 public:
  Chapter10Writer() = default;
  ~Chapter10Writer();
  Chapter10Writer(const Chapter10Writer&) = delete;
  Chapter10Writer& operator=(const Chapter10Writer&) = delete;

  /// Creates `path` (never an existing file: config.existing) and writes the TMATS record
  /// (RTC 0). The 10 MHz relative time counter (RTC) is (t_tai - epoch) / 100 ns; the epoch is
  /// `rtc_epoch_tai_ns`, or, when that is kRtcEpochFirstSample, the start of the UTC second of the
  /// first sample. Returns 0 or -errno (-EEXIST: refused, or no free number).
  static constexpr time::TaiNs kRtcEpochFirstSample = INT64_MIN;
  int open(const std::string& path, const Chapter10Config& config,
           time::TaiNs rtc_epoch_tai_ns = kRtcEpochFirstSample);
  /// Queues one sample for the message channel; writes a Time packet first when the sample's
  /// exposure time enters a new UTC second, and a message packet when the batch is full.
  /// Returns 0 or -errno of the failing write (also counted).
  int write(const msg::FtiSample& sample);
  /// Queues one received observation message (`message`: its bytes as received, at most
  /// msg::kRawObservationMaxTailBytes; `record.message_bytes` must equal its size) for the raw
  /// channel; a packet is written when the batch is full or spans max_packet_span_ns of arrival
  /// time. Returns 0, -EINVAL (raw channel off, or the sizes disagree: counted raw_refused) or
  /// -errno of the failing write (also counted).
  int write_raw(const msg::RawObservation& record, std::span<const std::uint8_t> message);
  /// Writes any queued messages (samples and raw observations) as packets now.
  int flush();
  /// Flushes, fdatasyncs and closes; returns the first error. Safe to call twice.
  int close();

  const Chapter10Counters& counters() const { return counters_; }
  /// Every file written, in order (the first, then continuation files).
  const std::vector<std::string>& files() const { return files_; }
  /// Replaces the system calls (before open()); fault injection in tests.
  void set_file_ops(const Chapter10FileOps& ops) { ops_ = ops; }
  /// Relative time counter value of a TAI instant.
  std::uint64_t rtc_of(time::TaiNs t_tai) const;

 private:
  std::vector<std::uint8_t> build_packet(std::uint16_t channel_id, std::uint8_t data_type,
                                         std::uint64_t rtc, const std::vector<std::uint8_t>& body);
  enum class Payload : std::uint8_t { kSetup, kTime, kSamples, kRaw };
  int write_packet(std::uint16_t channel_id, std::uint8_t data_type, std::uint64_t rtc,
                   const std::vector<std::uint8_t>& body, int messages, Payload payload);
  int flush_samples();
  int flush_raw(bool force);
  void set_epoch_from(time::TaiNs t);
  int append(const std::vector<std::uint8_t>& packet, bool& written);
  std::vector<std::uint8_t> time_body(std::int64_t utc_second) const;
  int write_time_packet(std::int64_t utc_second);
  int write_file_header(bool repeat_time_packet);
  int create_file(int number);
  int start_continuation_file(bool repeat_time_packet);
  void abandon_file();
  int close_file();
  std::string tmats_text() const;

  Chapter10FileOps ops_ = posix_chapter10_file_ops();
  int fd_ = -1;
  bool opened_ = false;                  // open() succeeded; the writer keeps going until close()
  std::string requested_path_;           // as given to open()
  std::vector<std::string> files_;       // every file created, in order
  std::uint64_t file_bytes_ = 0;         // whole packets in the current file
  std::uint64_t file_data_packets_ = 0;  // message packets in the current file
  int next_number_ = 1;                  // first number to try for the next numbered file
  std::int64_t current_utc_s_ = INT64_MIN;        // UTC second of the sample being written
  std::int64_t failed_reopen_utc_s_ = INT64_MIN;  // one failed continuation try per second
  Chapter10Config config_;
  time::TaiNs start_tai_ns_ = 0;
  std::vector<std::uint8_t> sequence_;  // per channel id (index)
  std::int64_t last_time_packet_utc_s_ = INT64_MIN;
  time::TaiNs last_sample_tai_ns_ = INT64_MIN;
  std::vector<std::uint8_t> pending_body_;  // message F0 body without CSDW
  int pending_messages_ = 0;
  time::TaiNs pending_first_tai_ns_ = 0;
  // Raw channel: message F0 body without CSDW; the 8-byte time stamps are filled in at flush
  // (the RTC epoch may not be known yet when the first observations arrive).
  std::vector<std::uint8_t> pending_raw_body_;
  struct HeldRaw {
    std::size_t offset;         // of its intra-packet header in pending_raw_body_
    time::TaiNs arrival;        // its time stamp, once the epoch is known
    std::size_t message_bytes;  // as received
  };
  std::vector<HeldRaw> pending_raw_;
  std::vector<std::vector<std::uint8_t>> input_bodies_;  // CG F0 bodies of the inputs
  Chapter10Counters counters_;
};

/// UTC calendar fields of a TAI instant (TAI - 37 s, docs/conventions.md "Time").
struct UtcCalendar {
  int year, month, day, hour, minute, second, millisecond;
};
UtcCalendar utc_calendar_from_tai(time::TaiNs t_tai);

}  // namespace storetrack::output
