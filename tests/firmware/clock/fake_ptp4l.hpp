// A fake ptp4l for tests: a UNIX datagram server thread at a path, answering each GET with
// what a responder returns (by default ptp4l's own captured replies, ptp4l_captures.hpp, with
// the request's sequenceId), to the sender's address as ptp4l does.
#pragma once

#include <poll.h>
#include <sys/socket.h>
#include <sys/un.h>
#include <unistd.h>

#include <atomic>
#include <cstdio>
#include <cstdlib>
#include <functional>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include "ptp4l_captures.hpp"

namespace storetrack::clock::test {

using Datagram = std::vector<std::uint8_t>;
using Responder = std::function<std::vector<Datagram>(const Datagram& request)>;

inline std::uint16_t management_id(const Datagram& request) {
  return static_cast<std::uint16_t>(request[52] << 8 | request[53]);
}

inline Datagram with_sequence(Datagram reply, const Datagram& request) {
  reply[30] = request[30];  // sequenceId, header offset 30 (IEEE 1588-2008 13.3.1)
  reply[31] = request[31];
  return reply;
}

/// ptp4l's answers for a slave of a present master: UNCALIBRATED, offset 616 ns.
inline std::vector<Datagram> ptp4l_answers(const Datagram& request) {
  switch (management_id(request)) {
    case 0x2004:
      return {with_sequence(from_hex(kSlavePortDataSetUncalibrated), request)};
    case 0xC000: {
      // A fresh Sync behind every answer, as a live ptp4l has: ingress_time (data bytes 8..15)
      // advanced by 125 ms per reply from the captured value.
      static std::atomic<std::uint64_t> syncs{0};
      Datagram reply = with_sequence(from_hex(kSlaveTimeStatusNp), request);
      std::uint64_t ingress = 0;
      for (int i = 0; i < 8; ++i)
        ingress = ingress << 8 | reply[54 + 8 + static_cast<std::size_t>(i)];
      ingress += ++syncs * 125'000'000u;
      for (int i = 7; i >= 0; --i, ingress >>= 8)
        reply[54 + 8 + static_cast<std::size_t>(i)] = static_cast<std::uint8_t>(ingress);
      return {reply};
    }
    case 0x2003:
      return {with_sequence(from_hex(kSlaveTimePropertiesDataSet), request)};
  }
  return {};
}

class FakePtp4l {
 public:
  FakePtp4l(const std::string& path, Responder responder) : responder_(std::move(responder)) {
    fd_ = ::socket(AF_UNIX, SOCK_DGRAM, 0);
    sockaddr_un a{};
    a.sun_family = AF_UNIX;
    std::snprintf(a.sun_path, sizeof a.sun_path, "%s", path.c_str());
    if (::bind(fd_, reinterpret_cast<sockaddr*>(&a), sizeof a) != 0) std::abort();
    thread_ = std::thread([this] { serve(); });
  }
  ~FakePtp4l() {
    stop_ = true;
    thread_.join();
    ::close(fd_);
  }
  void set_responder(Responder r) {
    std::lock_guard<std::mutex> lock(mutex_);
    responder_ = std::move(r);
  }
  int requests() const { return requests_.load(); }

 private:
  void serve() {
    while (!stop_) {
      pollfd p{fd_, POLLIN, 0};
      if (::poll(&p, 1, 20) <= 0) continue;
      Datagram request(1500);
      sockaddr_un from{};
      socklen_t from_length = sizeof from;
      const ssize_t n = ::recvfrom(fd_, request.data(), request.size(), 0,
                                   reinterpret_cast<sockaddr*>(&from), &from_length);
      if (n < 54) continue;
      request.resize(static_cast<std::size_t>(n));
      ++requests_;
      std::vector<Datagram> replies;
      {
        std::lock_guard<std::mutex> lock(mutex_);
        replies = responder_(request);
      }
      for (const Datagram& r : replies)
        ::sendto(fd_, r.data(), r.size(), 0, reinterpret_cast<sockaddr*>(&from), from_length);
    }
  }

  int fd_ = -1;
  std::mutex mutex_;
  Responder responder_;
  std::atomic<bool> stop_{false};
  std::atomic<int> requests_{0};
  std::thread thread_;
};

}  // namespace storetrack::clock::test
