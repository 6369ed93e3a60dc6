// ObservationLink: how a unit's messages leave it (UDP datagrams, CAN FD transfers).
//
// send() never blocks the capture loop: a link that cannot take a whole message right now
// drops it, counts it, and returns -EAGAIN. Counters are atomics so the health server may read
// them from its own thread while the capture loop sends.
#pragma once

#include <atomic>
#include <cstdint>

#include "storetrack/msg/messages.hpp"

namespace storetrack::link {

/// A snapshot of a link's counters.
struct LinkStats {
  std::uint64_t observations_sent = 0;  ///< whole MarkObservations messages handed to the kernel
  std::uint64_t health_sent = 0;
  std::uint64_t tx_errors = 0;          ///< failed sends other than back-pressure
  std::uint64_t dropped_exposures = 0;  ///< MarkObservations dropped by back-pressure or bus-off
  std::uint64_t partial_exposures = 0;  ///< CAN: transfer cut after some frames were queued
  std::uint64_t encode_errors = 0;      ///< message could not be encoded (-ERANGE)
  std::uint64_t bus_off_events = 0;     ///< CAN controller went bus-off
  std::uint64_t error_frames = 0;       ///< CAN error frames received
  bool bus_off = false;                 ///< CAN: currently bus-off
  bool link_down = false;               ///< interface down / unreachable at the last send
  int last_errno = 0;
};

/// Lock-free counters shared by one writer (capture loop) and readers (health thread).
struct AtomicLinkStats {
  std::atomic<std::uint64_t> observations_sent{0};
  std::atomic<std::uint64_t> health_sent{0};
  std::atomic<std::uint64_t> tx_errors{0};
  std::atomic<std::uint64_t> dropped_exposures{0};
  std::atomic<std::uint64_t> partial_exposures{0};
  std::atomic<std::uint64_t> encode_errors{0};
  std::atomic<std::uint64_t> bus_off_events{0};
  std::atomic<std::uint64_t> error_frames{0};
  std::atomic<bool> bus_off{false};
  std::atomic<bool> link_down{false};
  std::atomic<int> last_errno{0};

  static void bump(std::atomic<std::uint64_t>& c) { c.fetch_add(1, std::memory_order_relaxed); }
  LinkStats snapshot() const {
    LinkStats s;
    s.observations_sent = observations_sent.load(std::memory_order_relaxed);
    s.health_sent = health_sent.load(std::memory_order_relaxed);
    s.tx_errors = tx_errors.load(std::memory_order_relaxed);
    s.dropped_exposures = dropped_exposures.load(std::memory_order_relaxed);
    s.partial_exposures = partial_exposures.load(std::memory_order_relaxed);
    s.encode_errors = encode_errors.load(std::memory_order_relaxed);
    s.bus_off_events = bus_off_events.load(std::memory_order_relaxed);
    s.error_frames = error_frames.load(std::memory_order_relaxed);
    s.bus_off = bus_off.load(std::memory_order_relaxed);
    s.link_down = link_down.load(std::memory_order_relaxed);
    s.last_errno = last_errno.load(std::memory_order_relaxed);
    return s;
  }
};

class ObservationLink {
 public:
  virtual ~ObservationLink() = default;
  /// Opens the socket. Returns 0 or -errno (error() says what).
  virtual int open() = 0;
  virtual void close() = 0;
  /// 0: sent whole; -EAGAIN: dropped whole by back-pressure (counted); other -errno: failed.
  virtual int send(const msg::MarkObservations& m) = 0;
  virtual int send(const msg::UnitHealth& m) = 0;
  /// Services the link between frames (CAN: drain error frames). Never blocks.
  virtual void service() {}
  virtual LinkStats stats() const = 0;
  virtual const char* name() const = 0;
  virtual const char* error() const = 0;
};

}  // namespace storetrack::link
