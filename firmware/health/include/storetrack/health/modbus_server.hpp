// Modbus TCP health/configuration server (libmodbus 3.1.6), in its own thread.
//
// Serves the register map of register_map.hpp: input registers from the shared UnitCounters
// (refreshed before every request), holding registers from the ConfigStore. Function codes
// other than 0x03/0x04/0x06/0x10 are refused with ILLEGAL FUNCTION before libmodbus sees them;
// writes outside maintenance mode get SERVER DEVICE FAILURE; writes are range-checked against
// the table (ILLEGAL DATA VALUE), whole and at once (a multi-register write is applied
// completely or not at all); identity writes while running get SERVER DEVICE BUSY. Requests are
// read without blocking and answered when whole: a slow client never holds another; a request
// not completed within request_timeout_ms, or a client quiet for idle_timeout_ms, is closed;
// when every slot is taken, the quietest client makes room for a new one. Malformed requests
// close that client's connection only. Every refusal is counted.
#pragma once

#include <atomic>
#include <cstdint>
#include <string>
#include <thread>
#include <vector>

#include "storetrack/health/unit_state.hpp"

namespace storetrack::health {

struct ModbusServerConfig {
  std::string address = "127.0.0.1";  ///< listen address; never all interfaces by default
  int port = 1502;                    ///< 0: any free port (tests), see bound_port()
  bool maintenance = false;           ///< allow configuration writes
  int max_clients = 4;
  int request_timeout_ms = 1000;  ///< a request's bytes must all arrive within this
  int idle_timeout_ms = 60'000;   ///< a connection quiet for this long is closed
};

struct ModbusServerStats {
  std::uint64_t requests = 0;
  std::uint64_t refused_function = 0;
  std::uint64_t refused_write_locked = 0;
  std::uint64_t refused_value = 0;  ///< a register outside the map (read or write), a bad value
  std::uint64_t malformed = 0;
  std::uint64_t writes_accepted = 0;
  std::uint64_t connections = 0;
  std::uint64_t refused_identity = 0;  ///< unit/camera id writes while running
  std::uint64_t evicted = 0;           ///< quietest client closed to admit a new one
  std::uint64_t timeouts = 0;          ///< requests not completed in time
  std::uint64_t idle_closed = 0;       ///< connections closed for idleness
};

class ModbusHealthServer {
 public:
  ModbusHealthServer(ModbusServerConfig config, const UnitCounters& counters, ConfigStore& store);
  ~ModbusHealthServer();
  ModbusHealthServer(const ModbusHealthServer&) = delete;
  ModbusHealthServer& operator=(const ModbusHealthServer&) = delete;

  /// Binds and starts the thread. Returns 0 or -errno (error() says what).
  int start();
  void stop();
  int bound_port() const { return bound_port_; }
  const std::string& error() const { return error_; }
  ModbusServerStats stats() const;
  bool maintenance() const { return config_.maintenance; }

 private:
  struct Client;
  void run();
  void accept_client(std::vector<Client>& clients, std::int64_t now);
  bool expired(const Client& c, std::int64_t now);
  bool read_client(Client& c, std::int64_t now);
  void handle_request(const std::uint8_t* query, int length);
  void handle_read(const std::uint8_t* query, int length, std::uint8_t fc);
  void handle_write(const std::uint8_t* query, int length, std::uint8_t fc);

  ModbusServerConfig config_;
  const UnitCounters& counters_;
  ConfigStore& store_;
  std::string error_;
  void* ctx_ = nullptr;      ///< modbus_t*
  void* mapping_ = nullptr;  ///< modbus_mapping_t*
  int listen_fd_ = -1;
  int bound_port_ = 0;
  std::int64_t start_mono_ns_ = 0;
  std::thread thread_;
  std::atomic<bool> running_{false};
  std::atomic<std::uint64_t> requests_{0}, refused_function_{0}, refused_write_locked_{0},
      refused_value_{0}, malformed_{0}, writes_accepted_{0}, connections_{0}, refused_identity_{0},
      evicted_{0}, timeouts_{0}, idle_closed_{0};
};

}  // namespace storetrack::health
