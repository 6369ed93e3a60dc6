// The replay fuzzers' files: one directory per process under /dev/shm (else /tmp) that exists
// only while an input runs, so nothing is left behind however libFuzzer ends (it exits without
// running atexit handlers at -max_total_time).
#pragma once

#include <sys/stat.h>
#include <unistd.h>

#include <cstdio>
#include <cstdlib>
#include <string>
#include <string_view>
#include <vector>

namespace storetrack::fuzz {

class ScratchDirectory {
 public:
  explicit ScratchDirectory(const std::string& tag) {
    path_ = std::string(access("/dev/shm", W_OK) == 0 ? "/dev/shm" : "/tmp") + "/storetrack_fuzz_" +
            tag + "_" + std::to_string(getpid());
    if (mkdir(path_.c_str(), 0700) != 0) std::abort();
  }
  ~ScratchDirectory() {
    for (const std::string& f : files_)
      unlink(f.c_str());
    rmdir(path_.c_str());
  }
  ScratchDirectory(const ScratchDirectory&) = delete;
  ScratchDirectory& operator=(const ScratchDirectory&) = delete;

  const std::string& path() const { return path_; }

  void write(const char* name, std::string_view bytes) {
    files_.push_back(path_ + "/" + name);
    std::FILE* f = std::fopen(files_.back().c_str(), "wb");
    if (f == nullptr) std::abort();
    if (!bytes.empty() && std::fwrite(bytes.data(), 1, bytes.size(), f) != bytes.size())
      std::abort();
    if (std::fclose(f) != 0) std::abort();
  }

 private:
  std::string path_;
  std::vector<std::string> files_;
};

}  // namespace storetrack::fuzz
