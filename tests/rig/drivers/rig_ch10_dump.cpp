// rig_ch10_dump [--raw] FILE: reads a Chapter 10 file with the project's INDEPENDENT reader
// (host/output chapter10_reader, written from IRIG 106 and sharing nothing with the writer) and
// prints what it found as JSON for the in-VM end-to-end check (guest/check_e2e.py): packet
// counts by data type, header / data checksum errors, truncation, and every FTI parameter
// block (trigger_seq, status, pose, standard uncertainties, coverage factor), the recorded
// inputs (kind, name, size, SHA-256 as recorded) and the raw channel's count; with --raw also
// every raw observation (arrival, source, verdict, the message bytes in hex). Also used by
// tests/integration/host_kill.
// Exit 0 when the file was read (whatever its content), 1 when it cannot be read.
#include <cstdio>
#include <exception>
#include <map>
#include <nlohmann/json.hpp>
#include <string>

#include "storetrack/output/chapter10_reader.hpp"

int main(int argc, char** argv) {
  const bool raw = argc == 3 && std::string(argv[1]) == "--raw";
  if (argc != 2 && !raw) {
    std::fprintf(stderr, "usage: rig_ch10_dump [--raw] FILE.ch10\n");
    return 2;
  }
  const char* path = argv[argc - 1];
  namespace rd = storetrack::ch10read;
  rd::File file;
  try {
    file = rd::read_file(path);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "rig_ch10_dump: %s\n", e.what());
    return 1;
  }
  nlohmann::json out;
  std::map<std::string, int> by_type;
  int header_errors = 0, data_errors = 0, message_errors = 0, block_errors = 0;
  std::string first_block_error;
  nlohmann::json samples = nlohmann::json::array();
  const int raw_channel = rd::raw_channel_id(file);  // its messages are not FTI samples
  for (const rd::Packet& p : file.packets) {
    char type[8];
    std::snprintf(type, sizeof(type), "0x%02x", p.data_type);
    ++by_type[type];
    if (!p.header_checksum_ok) ++header_errors;
    if (!p.data_checksum_ok) ++data_errors;
    if (p.data_type != 0x30 || p.channel_id == raw_channel) continue;
    std::string error;
    const auto messages = rd::decode_message_f0(p, &error);
    if (!messages) {
      ++message_errors;
      continue;
    }
    for (const rd::Message& m : *messages) {
      std::string block_error;
      const auto b = rd::decode_fti_block(m.bytes, &block_error);
      if (!b) {
        if (block_errors++ == 0) first_block_error = block_error;  // e.g. another block version
        continue;
      }
      samples.push_back({{"trigger_seq", b->trigger_seq},
                         {"exposure_mid_tai_ns", b->exposure_mid_tai_ns},
                         {"status", b->status},
                         {"cameras_used", b->cameras_used},
                         {"marks_used", b->marks_used},
                         {"pylon_marks_used", b->pylon_marks_used},
                         {"pose", b->pose},
                         {"uncertainty", b->uncertainty},
                         {"coverage_factor", b->coverage_factor},
                         {"clearance_m", b->clearance_m},
                         {"clearance_lower_bound_m", b->clearance_lower_bound_m},
                         {"clearance_part", b->clearance_part},
                         {"data_error", m.data_error}});
    }
  }
  out["file_bytes"] = file.file_bytes;
  out["bytes_in_whole_packets"] = file.bytes_in_whole_packets;
  out["first_data_type"] = file.packets.empty() ? -1 : file.packets.front().data_type;
  out["packets"] = file.packets.size();
  out["packets_by_type"] = by_type;
  out["header_checksum_errors"] = header_errors;
  out["data_checksum_errors"] = data_errors;
  out["message_decode_errors"] = message_errors;
  out["fti_block_errors"] = block_errors;
  out["fti_block_first_error"] = first_block_error;
  out["truncated"] = file.truncated;
  out["stop_reason"] = file.stop_reason;
  out["samples"] = samples;
  auto hex = [](const auto& bytes) {
    std::string s;
    char b[3];
    for (const std::uint8_t x : bytes) {
      std::snprintf(b, sizeof b, "%02x", x);
      s += b;
    }
    return s;
  };
  std::string inputs_error;
  nlohmann::json inputs = nlohmann::json::array();
  for (const rd::RecordedInput& in : rd::recorded_inputs(file, &inputs_error))
    inputs.push_back({{"kind", in.kind},
                      {"name", in.name},
                      {"total_bytes", in.total_bytes},
                      {"complete", in.complete},
                      {"sha256", hex(in.sha256)},
                      {"bytes_hex", hex(in.bytes)}});
  out["recorded_inputs"] = inputs;
  out["recorded_inputs_error"] = inputs_error;
  out["raw_channel_id"] = raw_channel;
  std::string raw_error;
  const auto observations = rd::raw_observations(file, &raw_error);
  out["raw_observation_count"] = observations.size();
  out["raw_observations_error"] = raw_channel < 0 ? "" : raw_error;
  if (raw) {
    nlohmann::json list = nlohmann::json::array();
    for (const rd::RawObservation& r : observations)
      list.push_back({{"arrival_tai_ns", r.arrival_tai_ns},
                      {"intra_packet_time", r.intra_packet_time},
                      {"source_kind", r.source_kind},
                      {"source_address", r.source_address},
                      {"source_port", r.source_port},
                      {"unit_id", r.unit_id},
                      {"camera_id", r.camera_id},
                      {"flags", r.flags},
                      {"decode_error", r.decode_error},
                      {"received_bytes", r.received_bytes},
                      {"host_mono_ns", r.host_mono_ns},
                      {"bytes_hex", hex(r.bytes)}});
    out["raw_observations"] = list;
  }
  std::printf("%s\n", out.dump(1).c_str());
  return 0;
}
