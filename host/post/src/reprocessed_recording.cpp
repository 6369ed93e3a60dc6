#include "reprocessed_recording.hpp"

#include <array>
#include <cerrno>
#include <fstream>
#include <stdexcept>
#include <utility>

#include "storetrack/digest/sha256.hpp"

#ifndef STORETRACK_POST_VERSION
#error "STORETRACK_POST_VERSION: set by host/post/CMakeLists.txt"
#endif

namespace storetrack::post {

using output::RecordedInputKind;

hostapp::InputReader UsedInputs::recording(hostapp::InputReader read) {
  return [this, read = std::move(read)](RecordedInputKind kind, const std::string& path) {
    std::string text = read(kind, path);
    files_[kind] = {kind, path, {text.begin(), text.end()}};
    return text;
  };
}

std::vector<std::string> command_line_with(std::vector<std::string> args, const std::string& option,
                                           const std::string& value) {
  for (std::size_t i = 0; i < args.size(); ++i) {
    if (args[i] == option && i + 1 < args.size()) {
      args[i + 1] = value;
      return args;
    }
    if (args[i].rfind(option + "=", 0) == 0) {
      args[i] = option + "=" + value;
      return args;
    }
  }
  args.push_back(option);
  args.push_back(value);
  return args;
}

namespace {

// The source file's SHA-256, read in pieces (a recording may be large).
std::string file_sha256(const std::string& path) {
  std::ifstream f(path, std::ios::binary);
  if (!f) throw std::runtime_error(path + ": cannot read it again to state its SHA-256");
  digest::Sha256Builder sha;
  std::array<char, 1 << 16> buffer{};
  while (f.read(buffer.data(), buffer.size()) || f.gcount() > 0)
    sha.add({reinterpret_cast<const std::uint8_t*>(buffer.data()),
             static_cast<std::size_t>(f.gcount())});
  if (f.bad()) throw std::runtime_error(path + ": read error while computing its SHA-256");
  return digest::to_hex(sha.finish());
}

// Each argument followed by a NUL, as the host records its command line.
std::vector<std::uint8_t> nul_ended(const std::vector<std::string>& args) {
  std::vector<std::uint8_t> bytes;
  for (const std::string& a : args) {
    bytes.insert(bytes.end(), a.begin(), a.end());
    bytes.push_back(0);
  }
  return bytes;
}

struct Substitute {
  bool substituted;
  RecordedInputKind kind;
  const char* option;
  const std::string* path;
};

std::vector<Substitute> substitutes(const hostapp::HostOptions& used, const Substituted& what) {
  return {
      {what.calibration, RecordedInputKind::kCalibration, "--calibration", &used.calibration_path},
      {what.pylon_survey, RecordedInputKind::kPylonSurvey, "--pylon-survey", &used.pylon_path},
      {what.store_survey, RecordedInputKind::kStoreSurvey, "--store-survey", &used.store_path},
      {what.config, RecordedInputKind::kHostConfig, "--config", &used.config_path}};
}

// The used bytes of each input in the source's order (an input only a substitute brought, e.g. a
// configuration the live run had none of, after them), the command line naming the substitutes
// where the source had its own (the host records the clearance geometry after it).
std::vector<output::RecordedInputFile> used_input_files(const Recording& source,
                                                        const hostapp::HostOptions& used,
                                                        const UsedInputs& inputs,
                                                        const Substituted& what) {
  std::vector<std::string> args = used.command_line;
  for (const Substitute& s : substitutes(used, what))
    if (s.substituted) args = command_line_with(std::move(args), s.option, *s.path);
  std::map<RecordedInputKind, output::RecordedInputFile> pending = inputs.files();
  std::vector<output::RecordedInputFile> files;
  bool command_line = false;
  for (const ch10read::RecordedInput& recorded : source.inputs) {
    const auto kind = static_cast<RecordedInputKind>(recorded.kind);
    if (kind == RecordedInputKind::kCommandLine) {
      files.push_back({RecordedInputKind::kCommandLine, "argv", nul_ended(args)});
      command_line = true;
    } else if (const auto it = pending.find(kind); it != pending.end()) {
      files.push_back(std::move(it->second));
      pending.erase(it);
    } else {
      files.push_back({kind, recorded.name, recorded.bytes});
    }
  }
  for (auto& [kind, file] : pending)
    files.push_back(std::move(file));
  if (!command_line) files.push_back({RecordedInputKind::kCommandLine, "argv", nul_ended(args)});
  return files;
}

std::vector<std::string> provenance(const Recording& source, const hostapp::HostOptions& used,
                                    const UsedInputs& inputs, const Substituted& what) {
  std::vector<std::string> lines{"reprocessed recording: written by storetrack-post " +
                                 std::string(STORETRACK_POST_VERSION) + " from " +
                                 std::to_string(source.files.size()) + " source file(s)"};
  for (const std::string& f : source.files)
    lines.push_back("reprocessed from '" + f + "' sha256 " + file_sha256(f));
  std::string list;
  for (const Substitute& s : substitutes(used, what)) {
    if (!s.substituted) continue;
    const auto it = inputs.files().find(s.kind);
    list += std::string(list.empty() ? "" : ", ") + output::to_string(s.kind) + " '" + *s.path +
            "'" +
            (it == inputs.files().end()
                 ? std::string()
                 : " sha256 " + digest::to_hex(digest::sha256(it->second.bytes)));
  }
  lines.push_back("reprocessed with substituted inputs: " +
                  (list.empty() ? std::string("none (the recorded inputs)") : list));
  return lines;
}

// The writer's form of a raw record (the reader's fields; the length is the bytes').
msg::RawObservation writer_record(const ch10read::RawObservation& r) {
  msg::RawObservation w{};
  w.source_kind = static_cast<std::uint8_t>(r.source_kind);
  w.arrival_tai_ns = r.arrival_tai_ns;
  w.source_address = r.source_address;
  w.source_port = r.source_port;
  w.unit_id = static_cast<std::uint8_t>(r.unit_id);
  w.camera_id = static_cast<std::uint8_t>(r.camera_id);
  w.flags = r.flags;
  w.decode_error = static_cast<std::uint8_t>(r.decode_error);
  w.received_bytes = r.received_bytes;
  w.host_mono_ns = r.host_mono_ns;
  w.message_bytes = static_cast<std::uint16_t>(r.bytes.size());
  return w;
}

}  // namespace

output::Chapter10Config reprocessed_config(const Recording& source,
                                           const hostapp::HostOptions& used,
                                           const hostapp::InputFiles& in, const UsedInputs& inputs,
                                           const Substituted& what) {
  output::Chapter10Config c = used.cfg.ch10;
  c.stores = {{used.cfg.processor.store_id, in.store.name}};
  c.raw_observations = true;
  c.existing = output::Chapter10Existing::kRefuse;
  // Not a live recorder: no power loss to survive packet by packet, and it would cost the
  // reprocessing most of its speed. The file is whole when close() returns.
  c.sync = output::Chapter10Sync::kNone;
  c.inputs = used_input_files(source, used, inputs, what);
  c.comments = provenance(source, used, inputs, what);
  return c;
}

int ReprocessedRecording::open(const std::string& path, const output::Chapter10Config& config) {
  const int rc = writer_.open(path, config);
  open_ = rc == 0;
  return rc;
}

void ReprocessedRecording::copy(const ch10read::RawObservation& record) {
  if (open_) writer_.write_raw(writer_record(record), record.bytes);  // errors: counted
}

void ReprocessedRecording::record_new(const std::vector<msg::FtiSample>& samples) {
  for (; open_ && samples_recorded_ < samples.size(); ++samples_recorded_)
    writer_.write(samples[samples_recorded_]);  // errors: counted
}

int ReprocessedRecording::close() {
  if (!open_) return 0;
  open_ = false;
  const int rc = writer_.close();
  const output::Chapter10Counters& c = writer_.counters();
  const bool all = c.messages_dropped == 0 && c.raw_messages_dropped == 0 && c.raw_refused == 0;
  return rc != 0 ? rc : (all ? 0 : -EIO);
}

}  // namespace storetrack::post
