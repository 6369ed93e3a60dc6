#include "recording.hpp"

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

}  // namespace

Recording read_recording(const std::vector<std::string>& paths) {
  Recording out;
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

}  // namespace storetrack::post
