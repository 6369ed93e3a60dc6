// A recording as storetrack-post reads it: one host run's Chapter 10 files, in the order the host
// wrote them (continuation files after the first), with what a replay needs: the raw channel
// (every observation message and the aligner's clock events), the live samples, and the inputs
// the host ran with.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "storetrack/output/chapter10_reader.hpp"

namespace storetrack::post {

struct RecordedSample {
  std::string file;
  std::size_t packet_offset = 0;
  std::uint16_t store_id = 0;       ///< the message's subchannel
  std::vector<std::uint8_t> block;  ///< the FTI parameter block as recorded
};

/// What a reader can say about one file's integrity (storetrack-post --report).
struct FileIntegrity {
  std::string file;
  std::size_t file_bytes = 0, bytes_in_whole_packets = 0;
  std::size_t packets = 0;
  std::size_t header_checksum_errors = 0, data_checksum_errors = 0;
  /// Packets missing inside the file: per channel, the sequence numbers' skips (mod 256).
  std::size_t sequence_gap_packets = 0;
  /// Raw records the host's receiver marked refused (data error) or cut (format error).
  std::size_t raw_data_errors = 0, raw_format_errors = 0;
  bool torn = false;        ///< ends inside a packet, or parsing stopped (stop_reason)
  std::string stop_reason;  ///< e.g. "header checksum mismatch at offset N"
};

struct Recording {
  std::vector<std::string> files;
  std::vector<ch10read::RawObservation> records;  ///< the raw channel, in file order
  std::vector<RecordedSample> samples;            ///< the live run's samples, in file order
  std::vector<ch10read::RecordedInput> inputs;    ///< of the first file (each file repeats them)
  std::vector<std::string> torn;                  ///< "file: offset" of files cut in a packet
  std::vector<std::string> gaps;  ///< "file: ..." raw packets missing before a file (not written)
  std::vector<FileIntegrity> integrity;  ///< one per file, in order
};

/// Reads the files of one host run, in order. Throws std::runtime_error naming the file (and
/// the packet offset) for an unreadable file, a file without the raw channel or without its
/// inputs (an older recording), a malformed record, or files of different runs (their inputs
/// differ), and for files out of the order the host wrote them (the raw channel's loop times go
/// back) or with a file missing between two (the raw channel's packet numbers skip, and so do
/// the files' setup records). Raw packets missing between two consecutive files (the host could
/// not write them) are named in `gaps`. A file that ends inside a packet (a crash) is read to its
/// last whole packet and named in `torn`.
Recording read_recording(const std::vector<std::string>& paths);

/// The recorded input of `kind` (output::RecordedInputKind), or nullptr.
const ch10read::RecordedInput* find_input(const Recording& r, int kind);
/// The recorded input of `kind` recorded under `name` (the path the host read it at), or nullptr.
const ch10read::RecordedInput* find_input(const Recording& r, int kind, const std::string& name);

}  // namespace storetrack::post
