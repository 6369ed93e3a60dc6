// Modbus TCP health/configuration server (libmodbus 3.1.6), in its own thread.
//
// Serves the register map of register_map.hpp: input registers from the shared UnitCounters
// (refreshed before every request), holding registers from the ConfigStore. Function codes
// other than 0x03/0x04/0x06/0x10 are refused with ILLEGAL FUNCTION before libmodbus sees them;
// writes outside maintenance mode get SERVER DEVICE FAILURE; writes are range-checked against
// the table (ILLEGAL DATA VALUE). Malformed requests close that client's connection only.
#pragma once

#include <atomic>
#include <cstdint>
#include <string>
#include <thread>

#include "storetrack/health/unit_state.hpp"

namespace storetrack::health {

struct ModbusServerConfig {
  std::string address = "127.0.0.1";  ///< listen address; never all interfaces by default
  int port = 1502;                    ///< 0: any free port (tests), see bound_port()
  bool maintenance = false;           ///< allow configuration writes
  int max_clients = 4;
};

struct ModbusServerStats {
  std::uint64_t requests = 0;
  std::uint64_t refused_function = 0;
  std::uint64_t refused_write_locked = 0;
  std::uint64_t refused_value = 0;
  std::uint64_t malformed = 0;
  std::uint64_t writes_accepted = 0;
  std::uint64_t connections = 0;
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
  void run();
  void handle(int client_fd);

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
      refused_value_{0}, malformed_{0}, writes_accepted_{0}, connections_{0};
};

}  // namespace storetrack::health
