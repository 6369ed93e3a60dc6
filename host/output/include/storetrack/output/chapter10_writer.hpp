// IRIG 106-17 Chapter 10 file writer (recorder side of the FTI output).
//
// File = TMATS setup record (Computer-Generated Data Format 1, channel 0) first, then
// Time Data Format 1 packets (one per UTC second of exposure time) and Message Data Format 0
// packets carrying FTI parameter blocks, one subchannel per store. Every packet is built whole in
// memory and written with ONE write() on an O_APPEND descriptor, then fdatasync()ed (policy), so a
// crash or power loss loses at most the packet being written and the file stays readable up to
// the last whole packet. Layout byte by byte: docs/fti-output.md.
#pragma once

#include <climits>
#include <cstdint>
#include <string>
#include <vector>

#include "storetrack/msg/messages.hpp"
#include "storetrack/time/time.hpp"

namespace storetrack::output {

struct Chapter10StoreInfo {
  std::uint8_t store_id = 1;  ///< FtiSample::store_id, also the message subchannel id
  std::string name = "store";
};

enum class Chapter10Sync : std::uint8_t {
  kEveryPacket,  ///< fdatasync after every packet: power loss loses at most the last packet
  kNone,         ///< leave flushing to the kernel (tests, tmpfs)
};

struct Chapter10Config {
  std::uint16_t time_channel_id = 1;
  std::uint16_t message_channel_id = 2;
  std::vector<Chapter10StoreInfo> stores{Chapter10StoreInfo{}};
  bool data_checksum = true;                     ///< 32-bit data checksum trailer on every packet
  int max_messages_per_packet = 10;              ///< messages batched into one F0 packet
  std::int64_t max_packet_span_ns = 50'000'000;  ///< ... or this much exposure time
  Chapter10Sync sync = Chapter10Sync::kEveryPacket;
  std::string program_name = "storetrack";
  std::string test_point = "simulated";
};

struct Chapter10Counters {
  std::uint64_t packets_written = 0;
  std::uint64_t time_packets = 0;
  std::uint64_t message_packets = 0;
  std::uint64_t messages_written = 0;
  std::uint64_t bytes_written = 0;
  std::uint64_t write_errors = 0;
  std::uint64_t sync_errors = 0;
  std::uint64_t samples_out_of_order = 0;  ///< exposure time went backwards: written anyway
};

class Chapter10Writer {
 public:
  Chapter10Writer() = default;
  ~Chapter10Writer();
  Chapter10Writer(const Chapter10Writer&) = delete;
  Chapter10Writer& operator=(const Chapter10Writer&) = delete;

  /// Creates (truncates) `path` and writes the TMATS record (RTC 0). The 10 MHz relative time
  /// counter (RTC) is (t_tai - epoch) / 100 ns; the epoch is `rtc_epoch_tai_ns`, or, when that is
  /// kRtcEpochFirstSample, the start of the UTC second of the first sample. Returns 0 or -errno.
  static constexpr time::TaiNs kRtcEpochFirstSample = INT64_MIN;
  int open(const std::string& path, const Chapter10Config& config,
           time::TaiNs rtc_epoch_tai_ns = kRtcEpochFirstSample);
  /// Queues one sample for the message channel; writes a Time packet first when the sample's
  /// exposure time enters a new UTC second, and a message packet when the batch is full.
  /// Returns 0 or -errno of the failing write (also counted).
  int write(const msg::FtiSample& sample);
  /// Writes any queued messages as a packet now.
  int flush();
  /// Flushes and closes. Safe to call twice.
  int close();

  const Chapter10Counters& counters() const { return counters_; }
  /// Relative time counter value of a TAI instant.
  std::uint64_t rtc_of(time::TaiNs t_tai) const;

 private:
  int write_packet(std::uint16_t channel_id, std::uint8_t data_type, std::uint64_t rtc,
                   const std::vector<std::uint8_t>& body);
  int write_time_packet(std::int64_t utc_second);
  std::string tmats_text() const;

  int fd_ = -1;
  Chapter10Config config_;
  time::TaiNs start_tai_ns_ = 0;
  std::vector<std::uint8_t> sequence_;  // per channel id (index)
  std::int64_t last_time_packet_utc_s_ = INT64_MIN;
  time::TaiNs last_sample_tai_ns_ = INT64_MIN;
  std::vector<std::uint8_t> pending_body_;  // message F0 body without CSDW
  int pending_messages_ = 0;
  time::TaiNs pending_first_tai_ns_ = 0;
  std::vector<std::uint8_t> packet_;
  Chapter10Counters counters_;
};

/// UTC calendar fields of a TAI instant (TAI - 37 s, docs/conventions.md "Time").
struct UtcCalendar {
  int year, month, day, hour, minute, second, millisecond;
};
UtcCalendar utc_calendar_from_tai(time::TaiNs t_tai);

}  // namespace storetrack::output
