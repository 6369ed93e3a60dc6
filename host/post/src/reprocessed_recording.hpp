// storetrack-post --output-ch10: the reprocessed run as a NEW Chapter 10 recording, written by
// the host's own writer (output::Chapter10Writer: the same packets, TMATS, crash safety and
// continuation files as a live recording), so that it can itself be reprocessed. It holds:
// TMATS comments saying it is reprocessed (the source files and their SHA-256, the
// storetrack-post version, the inputs substituted); the replayed samples on the sample channel
// (their exposure times are the recorded ones); the raw channel copied record by record; the
// inputs the replay used (substitutes included) with their SHA-256, and a command line naming
// them (docs/post-processing.md "A new recording").
#pragma once

#include <cstddef>
#include <map>
#include <string>
#include <vector>

#include "differences.hpp"
#include "host_options.hpp"
#include "host_setup.hpp"
#include "recording.hpp"
#include "storetrack/msg/messages.hpp"
#include "storetrack/output/chapter10_writer.hpp"

namespace storetrack::post {

/// Keeps what an InputReader returned, by kind: the bytes the replay actually used.
class UsedInputs {
 public:
  hostapp::InputReader recording(hostapp::InputReader read);
  const std::map<output::RecordedInputKind, output::RecordedInputFile>& files() const {
    return files_;
  }

 private:
  std::map<output::RecordedInputKind, output::RecordedInputFile> files_;
};

/// `args` (a host command line) with `option`'s value set to `value` (replaced where given,
/// appended where not).
std::vector<std::string> command_line_with(std::vector<std::string> args, const std::string& option,
                                           const std::string& value);

/// The writer's configuration for the reprocessed recording: the host configuration `used`
/// (test point, packet limits), the store, the raw channel on, refusing an existing path; the
/// inputs in the source's order with the used bytes in place of the recorded ones, and the
/// command line naming the substitutes; the provenance in TMATS.
output::Chapter10Config reprocessed_config(const Recording& source,
                                           const hostapp::HostOptions& used,
                                           const hostapp::InputFiles& in, const UsedInputs& inputs,
                                           const Substituted& what);

/// Writes the reprocessed recording as the replay goes: each raw record copied, then the samples
/// the replay wrote since. The writer's errors are counted by it (counters()).
class ReprocessedRecording {
 public:
  /// Creates `path`; 0, or -errno (-EEXIST: it exists).
  int open(const std::string& path, const output::Chapter10Config& config);
  bool is_open() const { return open_; }
  void copy(const ch10read::RawObservation& record);
  /// `samples`: all the replay wrote so far; those not yet recorded are.
  void record_new(const std::vector<msg::FtiSample>& samples);
  /// Flushes and closes; 0 when every record and sample reached a file.
  int close();
  const output::Chapter10Writer& writer() const { return writer_; }
  /// Replaces the writer's system calls (before open()); fault injection in tests.
  void set_file_ops(const output::Chapter10FileOps& ops) { writer_.set_file_ops(ops); }

 private:
  output::Chapter10Writer writer_;
  bool open_ = false;
  std::size_t samples_recorded_ = 0;
};

}  // namespace storetrack::post
