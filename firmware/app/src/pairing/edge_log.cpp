#include "pairing/edge_log.hpp"

#include <cerrno>
#include <cstring>

namespace storetrack::unit {

bool EdgeLog::open(const std::string& path, std::string& error) {
  file_ = std::fopen(path.c_str(), "w");
  if (file_ == nullptr) {
    error = path + ": " + std::strerror(errno);
    return false;
  }
  std::fprintf(file_, "line_count,t_mono_ns,trigger_seq,verdict\n");
  return true;
}

void EdgeLog::write(const trigger::TriggerEdge& edge, trigger::EdgeVerdict verdict,
                    std::uint32_t sequence) {
  if (file_ == nullptr) return;
  std::fprintf(file_, "%u,%lld,%lld,%s\n", edge.line_count, static_cast<long long>(edge.t_mono_ns),
               verdict == trigger::EdgeVerdict::kExtra ? -1LL : static_cast<long long>(sequence),
               verdict == trigger::EdgeVerdict::kExtra    ? "extra"
               : verdict == trigger::EdgeVerdict::kResync ? "resync"
                                                          : "accepted");
}

void EdgeLog::close() {
  if (file_ != nullptr) {
    std::fclose(file_);
    file_ = nullptr;
  }
}

}  // namespace storetrack::unit
