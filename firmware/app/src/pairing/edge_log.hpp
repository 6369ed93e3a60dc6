// EdgeLog: every trigger edge the unit read, one CSV line each (trigger.edges_csv), for the
// bench: the line's own count, its time, the sequence number the pairer gave it, the verdict.
#pragma once

#include <cstdio>
#include <string>

#include "storetrack/trigger/frame_pairer.hpp"
#include "storetrack/trigger/trigger_line.hpp"

namespace storetrack::unit {

class EdgeLog {
 public:
  EdgeLog() = default;
  ~EdgeLog() { close(); }
  EdgeLog(const EdgeLog&) = delete;
  EdgeLog& operator=(const EdgeLog&) = delete;

  /// Creates `path` with its header line. Returns false with `error` (path: reason).
  bool open(const std::string& path, std::string& error);
  bool is_open() const { return file_ != nullptr; }
  /// One line; an extra edge has no sequence number (-1). stdio's buffer: no allocation.
  void write(const trigger::TriggerEdge& edge, trigger::EdgeVerdict verdict,
             std::uint32_t sequence);
  void close();

 private:
  std::FILE* file_ = nullptr;
};

}  // namespace storetrack::unit
