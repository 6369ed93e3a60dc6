// Independent IRIG 106-17 Chapter 10 file reader, written from the standard (Chapter 11, packet
// formats) and NOT sharing code or structs with Chapter10Writer: tests use it to validate the
// writer's files. It checks sync, lengths, header checksum and data checksum of every packet and
// stops at the first packet that is incomplete (a file cut by a crash) or corrupt, reporting
// everything before it.
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>
#include <optional>
#include <span>
#include <string>
#include <vector>

namespace storetrack::ch10read {

struct Packet {
  std::size_t file_offset = 0;
  std::uint16_t channel_id = 0;
  std::uint32_t packet_length = 0;
  std::uint32_t data_length = 0;
  std::uint8_t data_type_version = 0;
  std::uint8_t sequence_number = 0;
  std::uint8_t packet_flags = 0;
  std::uint8_t data_type = 0;
  std::uint64_t relative_time_counter = 0;  ///< 48 bits, 10 MHz
  bool header_checksum_ok = false;
  int data_checksum_bits = 0;  ///< 0 (none), 8, 16 or 32 (packet flags bits 1-0)
  bool data_checksum_ok = true;
  std::vector<std::uint8_t> data;  ///< data_length bytes: channel-specific data word + data
};

struct File {
  std::vector<Packet> packets;
  std::size_t file_bytes = 0;
  std::size_t bytes_in_whole_packets = 0;
  bool truncated = false;   ///< the file ends inside a packet (crash while writing)
  std::string stop_reason;  ///< empty when the whole file parsed
};

File parse(std::span<const std::uint8_t> bytes);
File read_file(const std::string& path);  ///< throws std::runtime_error if unreadable

struct TimeF1 {
  std::uint32_t csdw = 0;
  int time_source = 0;  ///< CSDW bits 3-0
  int time_format = 0;  ///< CSDW bits 7-4
  bool leap_year = false;
  bool month_year_format = false;
  int year = 0, month = 0, day = 0, day_of_year = 0;
  int hour = 0, minute = 0, second = 0, millisecond = 0;
  /// UTC seconds since 1970 (only when month_year_format).
  std::int64_t utc_epoch_seconds = 0;
};
std::optional<TimeF1> decode_time_f1(const Packet& packet);

struct Message {
  std::uint64_t intra_packet_time = 0;  ///< RTC (low 48 bits of the 8-byte stamp)
  std::uint16_t subchannel = 0;
  bool data_error = false;
  bool format_error = false;
  std::vector<std::uint8_t> bytes;
};
/// Messages of a Message Data Format 0 packet, or nullopt (and `error`) when malformed.
std::optional<std::vector<Message>> decode_message_f0(const Packet& packet,
                                                      std::string* error = nullptr);

/// TMATS text of a Computer-Generated Data Format 1 packet.
std::optional<std::string> decode_tmats(const Packet& packet);

/// The storetrack FTI parameter block (docs/fti-output.md), decoded from its documentation.
struct FtiBlock {
  std::int64_t exposure_mid_tai_ns = 0;
  std::uint32_t trigger_seq = 0;
  int store_id = 0, cameras_used = 0, marks_used = 0, pylon_marks_used = 0;
  std::uint16_t status = 0, version = 0;
  double pose[6] = {};         ///< x y z [m], yaw pitch roll [rad]
  double uncertainty[6] = {};  ///< standard uncertainties of the above
  double correlation[15] = {};
  double budget[5] = {};  ///< centroid, intrinsic, extrinsic, sync, process [m]
  double coverage_factor = 0;
  double clearance_m = 0, u_clearance_m = 0, clearance_lower_bound_m = 0;  ///< [m]
  std::uint16_t clearance_part = 0xFFFF;  ///< aircraft part index (0xFFFF: none)
};
/// Block version 3 only: a block of another version (or too short) is nullopt, with `error`
/// naming the version found.
std::optional<FtiBlock> decode_fti_block(std::span<const std::uint8_t> bytes,
                                         std::string* error = nullptr);

/// One record of the raw channel (RawObservation, docs/icd.md "Recording-only messages"): an
/// observation message as the host received it.
struct RawObservation {
  std::size_t packet_offset = 0;        ///< file offset of the packet that holds it
  std::uint64_t intra_packet_time = 0;  ///< RTC of the arrival
  std::uint16_t subchannel = 0;         ///< the unit id the message claims
  bool data_error = false;              ///< the receiver refused it
  bool format_error = false;            ///< truncated to the receive buffer
  int version = 0;
  int source_kind = 0;  ///< 0 UDP, 1 CAN FD, 2 aligner deadline check, 3 aligner flush
  std::int64_t arrival_tai_ns = 0;
  std::uint32_t source_address = 0;  ///< UDP: IPv4 (a.b.c.d = 0xaabbccdd); CAN: 29-bit identifier
  std::uint16_t source_port = 0;     ///< UDP: port; CAN: interface index
  int unit_id = 0, camera_id = 0;
  std::uint8_t flags = 0;  ///< bit 0 accepted, bit 1 truncated
  int decode_error = 0;
  std::uint32_t received_bytes = 0;
  std::int64_t host_mono_ns = 0;    ///< the host loop's time the aligner was given
  std::vector<std::uint8_t> bytes;  ///< the message as received
};
/// Decodes one raw-channel message body (version 2 only), or nullopt with `error`.
std::optional<RawObservation> decode_raw_observation(std::span<const std::uint8_t> bytes,
                                                     std::string* error = nullptr);
/// The channel TMATS names as the data source `data_source` (R-1\DSI-n:<data_source>,
/// R-1\TK1-n), or -1: FTISAMPLE (the samples), RAWOBS (the raw channel).
int channel_id_of(const File& file, const std::string& data_source);
/// channel_id_of(file, "RAWOBS").
int raw_channel_id(const File& file);
/// Every raw observation of the file in file order (the TMATS-named channel); a malformed packet
/// or record stops the list and sets `error`.
std::vector<RawObservation> raw_observations(const File& file, std::string* error = nullptr);

/// One input the recording carries (RecordedInput, Computer-Generated Data Format 0 packets),
/// its chunks joined.
struct RecordedInput {
  std::uint16_t channel_id = 0;
  int kind = 0;  ///< 0 calibration, 1 pylon survey, 2 store survey, 3 host config, 4 initial
                 ///< marks, 5 command line
  std::array<std::uint8_t, 32> sha256{};  ///< as recorded (the reader does not compute it)
  std::uint32_t total_bytes = 0;
  std::string name;
  std::vector<std::uint8_t> bytes;
  bool complete = false;  ///< every chunk present: bytes.size() == total_bytes
};
/// The inputs of the file in file order; a malformed record or a chunk out of order stops the
/// list and sets `error`.
std::vector<RecordedInput> recorded_inputs(const File& file, std::string* error = nullptr);

}  // namespace storetrack::ch10read
