// Reads Chapter 10 files with the INDEPENDENT reader (storetrack::ch10read) and prints, per
// file, one JSON line: packets, data checksum errors, whether and why parsing stopped, the bytes
// after the last whole packet and the trigger sequence numbers of every message.
#include <cstdio>
#include <exception>
#include <string>

#include <nlohmann/json.hpp>

#include "storetrack/output/chapter10_reader.hpp"

int main(int argc, char** argv) {
  namespace r = storetrack::ch10read;
  for (int i = 1; i < argc; ++i) {
    nlohmann::json j;
    j["path"] = argv[i];
    try {
      const r::File f = r::read_file(argv[i]);
      std::size_t checksum_errors = 0, bad_messages = 0;
      nlohmann::json seqs = nlohmann::json::array();
      for (const auto& p : f.packets) {
        if (!p.data_checksum_ok) ++checksum_errors;
        if (p.data_type != 0x30) continue;
        const auto msgs = r::decode_message_f0(p);
        if (!msgs) {
          ++bad_messages;
          continue;
        }
        for (const auto& m : *msgs) {
          const auto b = r::decode_fti_block(m.bytes);
          if (b) seqs.push_back(b->trigger_seq);
        }
      }
      j["packets"] = f.packets.size();
      j["first_data_type"] = f.packets.empty() ? -1 : f.packets.front().data_type;
      j["data_checksum_errors"] = checksum_errors;
      j["bad_message_packets"] = bad_messages;
      j["truncated"] = f.truncated;
      j["stop_reason"] = f.stop_reason;
      j["trailing_bytes"] = f.file_bytes - f.bytes_in_whole_packets;
      j["trigger_seqs"] = seqs;
    } catch (const std::exception& e) {
      j["error"] = e.what();
    }
    std::printf("%s\n", j.dump().c_str());
  }
  return 0;
}
