#include "recording.hpp"

#include <map>
#include <stdexcept>

#include "storetrack/digest/sha256.hpp"

namespace storetrack::post {

namespace {

[[noreturn]] void refuse(const std::string& file, const std::string& why) {
  throw std::runtime_error(file + ": " + why);
}

void read_samples(const std::string& path, const ch10read::File& file, Recording& out) {
  const int channel = ch10read::channel_id_of(file, "FTISAMPLE");
  if (channel < 0) refuse(path, "no sample channel in TMATS (no R-1\\DSI-n:FTISAMPLE)");
  for (const ch10read::Packet& p : file.packets) {
    if (p.channel_id != channel || p.data_type != 0x30) continue;
    std::string why;
    const auto messages = ch10read::decode_message_f0(p, &why);
    if (!messages)
      refuse(path, "sample packet at offset " + std::to_string(p.file_offset) + ": " + why);
    for (const ch10read::Message& m : *messages)
      out.samples.push_back({path, p.file_offset, m.subchannel, m.bytes});
  }
}

bool same_inputs(const std::vector<ch10read::RecordedInput>& a,
                 const std::vector<ch10read::RecordedInput>& b) {
  if (a.size() != b.size()) return false;
  for (std::size_t i = 0; i < a.size(); ++i)
    if (a[i].kind != b[i].kind || a[i].sha256 != b[i].sha256) return false;
  return true;
}

// Where a file sits in its run: the writer numbers each channel's packets across all files of
// a run (8 bits), so the setup record (TMATS, one at the start of every file) counts the files,
// and the raw channel's numbers go on from file to file (a failed packet is retried in the
// continuation file). The host's loop time never goes back.
struct FilePlace {
  int tmats_seq = -1;
  bool any_raw = false;
  std::uint8_t first_seq = 0, last_seq = 0;
  std::size_t first_offset = 0, last_offset = 0;
  std::int64_t first_mono_ns = 0, last_mono_ns = 0;
};

FilePlace place_of(const ch10read::File& file,
                   const std::vector<ch10read::RawObservation>& records) {
  FilePlace e;
  const int channel = ch10read::raw_channel_id(file);
  for (const ch10read::Packet& p : file.packets) {
    if (p.channel_id == 0 && e.tmats_seq < 0) e.tmats_seq = p.sequence_number;
    if (p.channel_id != channel) continue;
    if (!e.any_raw) {
      e.first_seq = p.sequence_number;
      e.first_offset = p.file_offset;
    }
    e.any_raw = true;
    e.last_seq = p.sequence_number;
    e.last_offset = p.file_offset;
  }
  if (!records.empty()) {
    e.first_mono_ns = records.front().host_mono_ns;
    e.last_mono_ns = records.back().host_mono_ns;
  }
  return e;
}

// Refuses a file that does not follow `prev` in its run; returns a note when raw packets are
// missing between two consecutive files (packets the host could not write: the replay then
// lacks their observations).
std::string check_follows(const std::string& prev, const FilePlace& a, const std::string& path,
                          const FilePlace& b) {
  if (b.first_mono_ns < a.last_mono_ns)
    refuse(path, "its first raw record (packet at offset " + std::to_string(b.first_offset) +
                     ") is " + std::to_string((a.last_mono_ns - b.first_mono_ns) / 1000) +
                     " us earlier than the last of " + prev +
                     ": the files are not in the order the host wrote them (give the first "
                     "file, then its continuation files, in order)");
  const auto expected = static_cast<std::uint8_t>(a.last_seq + 1);
  if (b.first_seq == expected) return "";
  const std::string gap = "its first raw channel packet (offset " + std::to_string(b.first_offset) +
                          ") has sequence number " + std::to_string(b.first_seq) +
                          ", the last of " + prev + " (offset " + std::to_string(a.last_offset) +
                          ") " + std::to_string(a.last_seq) + ": " +
                          std::to_string(static_cast<std::uint8_t>(b.first_seq - expected)) +
                          " (mod 256) raw packet(s) missing between them";
  if (b.tmats_seq != static_cast<std::uint8_t>(a.tmats_seq + 1))
    refuse(path, gap + ", and its setup record is the run's file " + std::to_string(b.tmats_seq) +
                     " (mod 256) after file " + std::to_string(a.tmats_seq) +
                     ": a continuation file missing from the list (give every file of the run, "
                     "in order)");
  return path + ": " + gap + " (the next file of the run: packets the host could not write)";
}

FileIntegrity integrity_of(const std::string& path, const ch10read::File& file,
                           const std::vector<ch10read::RawObservation>& records) {
  FileIntegrity f;
  f.file = path;
  f.file_bytes = file.file_bytes;
  f.bytes_in_whole_packets = file.bytes_in_whole_packets;
  f.packets = file.packets.size();
  f.torn = file.truncated || !file.stop_reason.empty();
  f.stop_reason = file.stop_reason;
  std::map<std::uint16_t, std::uint8_t> last_seq;  // per channel
  for (const ch10read::Packet& p : file.packets) {
    if (!p.header_checksum_ok) ++f.header_checksum_errors;
    if (!p.data_checksum_ok) ++f.data_checksum_errors;
    if (const auto it = last_seq.find(p.channel_id); it != last_seq.end())
      f.sequence_gap_packets += static_cast<std::uint8_t>(p.sequence_number - it->second - 1);
    last_seq[p.channel_id] = p.sequence_number;
  }
  for (const ch10read::RawObservation& r : records) {
    if (r.data_error) ++f.raw_data_errors;
    if (r.format_error) ++f.raw_format_errors;
  }
  return f;
}

}  // namespace

Recording read_recording(const std::vector<std::string>& paths) {
  Recording out;
  FilePlace previous;
  std::string previous_path;
  for (const std::string& path : paths) {
    const ch10read::File file = ch10read::read_file(path);  // throws when unreadable
    if (file.packets.empty()) refuse(path, "no Chapter 10 packet (" + file.stop_reason + ")");
    if (file.truncated || !file.stop_reason.empty())
      out.torn.push_back(
          path + ": " + (file.stop_reason.empty() ? "ends inside a packet" : file.stop_reason) +
          " (" + std::to_string(file.bytes_in_whole_packets) + " bytes in whole packets)");
    if (ch10read::raw_channel_id(file) < 0)
      refuse(path,
             "no raw observation channel (recorded before raw recording, or with "
             "recording.raw_observations off): it cannot be reprocessed");
    std::string why;
    auto inputs = ch10read::recorded_inputs(file, &why);
    if (!why.empty()) refuse(path, why);
    if (inputs.empty())
      refuse(path,
             "no recorded inputs (calibration, surveys, configuration, command line): it "
             "cannot be reprocessed");
    for (const auto& in : inputs) {
      if (!in.complete) refuse(path, "recorded input '" + in.name + "' incomplete");
      if (digest::sha256(in.bytes) != in.sha256)
        refuse(path, "recorded input '" + in.name + "' does not match its recorded SHA-256");
    }
    if (out.files.empty()) {
      out.inputs = std::move(inputs);
    } else if (!same_inputs(out.inputs, inputs)) {
      refuse(path, "its recorded inputs differ from " + out.files.front() +
                       "'s: not a continuation of the same host run");
    }
    auto records = ch10read::raw_observations(file, &why);
    if (!why.empty()) refuse(path, why);
    out.integrity.push_back(integrity_of(path, file, records));
    const FilePlace place = place_of(file, records);
    if (place.any_raw && previous.any_raw)
      if (std::string gap = check_follows(previous_path, previous, path, place); !gap.empty())
        out.gaps.push_back(std::move(gap));
    if (place.any_raw) {
      previous = place;
      previous_path = path;
    }
    out.records.insert(out.records.end(), std::make_move_iterator(records.begin()),
                       std::make_move_iterator(records.end()));
    read_samples(path, file, out);
    out.files.push_back(path);
  }
  return out;
}

const ch10read::RecordedInput* find_input(const Recording& r, int kind) {
  for (const auto& in : r.inputs)
    if (in.kind == kind) return &in;
  return nullptr;
}

const ch10read::RecordedInput* find_input(const Recording& r, int kind, const std::string& name) {
  for (const auto& in : r.inputs)
    if (in.kind == kind && in.name == name) return &in;
  return nullptr;
}

}  // namespace storetrack::post
