#include "storetrack/health/modbus_server.hpp"

#include <arpa/inet.h>
#include <modbus/modbus.h>
#include <sys/select.h>
#include <sys/socket.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <cerrno>
#include <cstring>
#include <vector>

#include "storetrack/time/time.hpp"

namespace storetrack::health {
namespace {

modbus_t* as_ctx(void* p) {
  return static_cast<modbus_t*>(p);
}
modbus_mapping_t* as_map(void* p) {
  return static_cast<modbus_mapping_t*>(p);
}

}  // namespace

ModbusHealthServer::ModbusHealthServer(ModbusServerConfig config, const UnitCounters& counters,
                                       ConfigStore& store)
    : config_(std::move(config)), counters_(counters), store_(store) {}

ModbusHealthServer::~ModbusHealthServer() {
  stop();
}

int ModbusHealthServer::start() {
  if (running_.load()) return 0;
  in_addr probe{};
  if (inet_pton(AF_INET, config_.address.c_str(), &probe) != 1) {
    error_ = "modbus: listen address '" + config_.address + "' is not an IPv4 address";
    return -EINVAL;
  }
  modbus_t* ctx = modbus_new_tcp(config_.address.c_str(), config_.port);
  if (ctx == nullptr) {
    error_ = "modbus: modbus_new_tcp failed: " + std::string(modbus_strerror(errno));
    return -ENOMEM;
  }
  ctx_ = ctx;
  // A client that sends half a request must not hold the server thread.
  modbus_set_indication_timeout(ctx, 1, 0);
  modbus_set_byte_timeout(ctx, 0, 500'000);
  // libmodbus sleeps for the response timeout before flushing after some malformed requests;
  // keep that short so one bad client cannot stall the others.
  modbus_set_response_timeout(ctx, 0, 20'000);
  mapping_ = modbus_mapping_new(0, 0, register_count(RegisterKind::kHolding),
                                register_count(RegisterKind::kInput));
  if (mapping_ == nullptr) {
    error_ = "modbus: cannot allocate the register mapping";
    stop();
    return -ENOMEM;
  }
  listen_fd_ = modbus_tcp_listen(ctx, config_.max_clients);
  if (listen_fd_ < 0) {
    const int err = errno;
    error_ = "modbus: cannot listen on " + config_.address + ":" + std::to_string(config_.port) +
             ": " + std::strerror(err);
    stop();
    return -err;
  }
  sockaddr_in bound{};
  socklen_t len = sizeof bound;
  getsockname(listen_fd_, reinterpret_cast<sockaddr*>(&bound), &len);
  bound_port_ = ntohs(bound.sin_port);
  start_mono_ns_ = time::monotonic_now_ns();
  running_.store(true);
  thread_ = std::thread([this] { run(); });
  return 0;
}

void ModbusHealthServer::stop() {
  running_.store(false);
  if (thread_.joinable()) thread_.join();
  if (listen_fd_ >= 0) {
    close(listen_fd_);
    listen_fd_ = -1;
  }
  if (mapping_ != nullptr) {
    modbus_mapping_free(as_map(mapping_));
    mapping_ = nullptr;
  }
  if (ctx_ != nullptr) {
    modbus_set_socket(as_ctx(ctx_), -1);  // client sockets are ours, already closed
    modbus_free(as_ctx(ctx_));
    ctx_ = nullptr;
  }
}

void ModbusHealthServer::run() {
  std::vector<int> clients;
  while (running_.load()) {
    fd_set readable;
    FD_ZERO(&readable);
    FD_SET(listen_fd_, &readable);
    int max_fd = listen_fd_;
    for (int c : clients) {
      FD_SET(c, &readable);
      max_fd = std::max(max_fd, c);
    }
    timeval tv{0, 200'000};  // wake regularly to notice stop()
    const int n = select(max_fd + 1, &readable, nullptr, nullptr, &tv);
    if (n < 0) {
      if (errno == EINTR) continue;
      break;
    }
    if (n == 0) continue;
    if (FD_ISSET(listen_fd_, &readable)) {
      int server = listen_fd_;
      const int c = modbus_tcp_accept(as_ctx(ctx_), &server);
      if (c >= 0) {
        if (static_cast<int>(clients.size()) >= config_.max_clients) {
          close(c);
        } else {
          clients.push_back(c);
          connections_.fetch_add(1, std::memory_order_relaxed);
        }
      }
    }
    for (std::size_t i = 0; i < clients.size();) {
      const int c = clients[i];
      if (!FD_ISSET(c, &readable)) {
        ++i;
        continue;
      }
      modbus_set_socket(as_ctx(ctx_), c);
      std::array<std::uint8_t, MODBUS_TCP_MAX_ADU_LENGTH> query{};
      const int rc = modbus_receive(as_ctx(ctx_), query.data());
      if (rc < 0) {
        // Peer closed, or a malformed / truncated request: drop this client only.
        if (errno != ECONNRESET) malformed_.fetch_add(1, std::memory_order_relaxed);
        close(c);
        clients.erase(clients.begin() + static_cast<std::ptrdiff_t>(i));
        continue;
      }
      if (rc > 0) {
        requests_.fetch_add(1, std::memory_order_relaxed);
        const int hl = modbus_get_header_length(as_ctx(ctx_));
        modbus_t* ctx = as_ctx(ctx_);
        modbus_mapping_t* map = as_map(mapping_);
        // Refresh the mapping from the shared state just before answering.
        const auto uptime = static_cast<std::uint32_t>((time::monotonic_now_ns() - start_mono_ns_) /
                                                       time::kNsPerSecond);
        fill_input_registers(
            counters_, uptime, store_.generation(),
            std::span<std::uint16_t>(map->tab_input_registers,
                                     static_cast<std::size_t>(map->nb_input_registers)));
        store_.read_all(std::span<std::uint16_t>(map->tab_registers,
                                                 static_cast<std::size_t>(map->nb_registers)));
        const std::uint8_t fc = rc > hl ? query[static_cast<std::size_t>(hl)] : 0;
        const auto at = [&](int off) { return query[static_cast<std::size_t>(hl + off)]; };
        if (fc == MODBUS_FC_READ_HOLDING_REGISTERS || fc == MODBUS_FC_READ_INPUT_REGISTERS) {
          // Checked here so that exceptions are answered at once (libmodbus would sleep+flush).
          const int address = rc >= hl + 5 ? (at(1) << 8 | at(2)) : -1;
          const int count = rc >= hl + 5 ? (at(3) << 8 | at(4)) : 0;
          const int size =
              fc == MODBUS_FC_READ_HOLDING_REGISTERS ? map->nb_registers : map->nb_input_registers;
          if (address < 0 || count < 1 || count > MODBUS_MAX_READ_REGISTERS) {
            malformed_.fetch_add(1, std::memory_order_relaxed);
            modbus_reply_exception(ctx, query.data(), MODBUS_EXCEPTION_ILLEGAL_DATA_VALUE);
          } else if (address + count > size) {
            modbus_reply_exception(ctx, query.data(), MODBUS_EXCEPTION_ILLEGAL_DATA_ADDRESS);
          } else {
            modbus_reply(ctx, query.data(), rc, map);
          }
        } else if (fc == MODBUS_FC_WRITE_SINGLE_REGISTER ||
                   fc == MODBUS_FC_WRITE_MULTIPLE_REGISTERS) {
          std::array<std::uint16_t, 128> values{};
          std::size_t count = 0;
          std::uint16_t address = 0;
          bool well_formed = false;
          if (fc == MODBUS_FC_WRITE_SINGLE_REGISTER && rc >= hl + 5) {
            address = static_cast<std::uint16_t>(at(1) << 8 | at(2));
            values[0] = static_cast<std::uint16_t>(at(3) << 8 | at(4));
            count = 1;
            well_formed = true;
          } else if (fc == MODBUS_FC_WRITE_MULTIPLE_REGISTERS && rc >= hl + 6) {
            address = static_cast<std::uint16_t>(at(1) << 8 | at(2));
            count = static_cast<std::size_t>(at(3) << 8 | at(4));
            const int bytes = at(5);
            well_formed = count >= 1 && count <= 123 && bytes == static_cast<int>(2 * count) &&
                          rc >= hl + 6 + bytes;
            for (std::size_t k = 0; well_formed && k < count; ++k) {
              values[k] = static_cast<std::uint16_t>(at(6 + 2 * static_cast<int>(k)) << 8 |
                                                     at(7 + 2 * static_cast<int>(k)));
            }
          }
          if (!well_formed) {
            malformed_.fetch_add(1, std::memory_order_relaxed);
            modbus_reply_exception(ctx, query.data(), MODBUS_EXCEPTION_ILLEGAL_DATA_VALUE);
          } else if (!config_.maintenance) {
            refused_write_locked_.fetch_add(1, std::memory_order_relaxed);
            modbus_reply_exception(ctx, query.data(), MODBUS_EXCEPTION_SLAVE_OR_SERVER_FAILURE);
          } else {
            const int w = store_.write(
                address, std::span<const std::uint16_t>(values.data(), count), nullptr);
            if (w == -EFAULT) {
              refused_value_.fetch_add(1, std::memory_order_relaxed);
              modbus_reply_exception(ctx, query.data(), MODBUS_EXCEPTION_ILLEGAL_DATA_ADDRESS);
            } else if (w < 0) {
              refused_value_.fetch_add(1, std::memory_order_relaxed);
              modbus_reply_exception(ctx, query.data(), MODBUS_EXCEPTION_ILLEGAL_DATA_VALUE);
            } else {
              writes_accepted_.fetch_add(1, std::memory_order_relaxed);
              modbus_reply(ctx, query.data(), rc, map);  // echoes the write, map gets the values
            }
          }
        } else {
          refused_function_.fetch_add(1, std::memory_order_relaxed);
          modbus_reply_exception(ctx, query.data(), MODBUS_EXCEPTION_ILLEGAL_FUNCTION);
        }
      }
      ++i;
    }
  }
  for (int c : clients)
    close(c);
}

ModbusServerStats ModbusHealthServer::stats() const {
  ModbusServerStats s;
  s.requests = requests_.load();
  s.refused_function = refused_function_.load();
  s.refused_write_locked = refused_write_locked_.load();
  s.refused_value = refused_value_.load();
  s.malformed = malformed_.load();
  s.writes_accepted = writes_accepted_.load();
  s.connections = connections_.load();
  return s;
}

}  // namespace storetrack::health
