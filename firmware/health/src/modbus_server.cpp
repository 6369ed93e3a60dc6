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
  // libmodbus only answers here (requests are read by run()); it sleeps for the response
  // timeout before flushing after some malformed requests: keep that short.
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

// One client connection. Requests are read without blocking into `buf` and answered only once
// whole (the MBAP header's length says when), so a client that sends a byte now and then holds
// nobody else: libmodbus's own modbus_receive() waits for the rest of a request on the socket.
struct ModbusHealthServer::Client {
  int fd = -1;
  std::array<std::uint8_t, MODBUS_TCP_MAX_ADU_LENGTH> buf{};
  std::size_t have = 0;
  std::int64_t last_activity_ns = 0;
  std::int64_t partial_since_ns = 0;  // first byte of the request being read
};

void ModbusHealthServer::run() {
  std::vector<Client> clients;
  clients.reserve(static_cast<std::size_t>(config_.max_clients));
  while (running_.load()) {
    fd_set readable;
    FD_ZERO(&readable);
    FD_SET(listen_fd_, &readable);
    int max_fd = listen_fd_;
    for (const Client& c : clients) {
      FD_SET(c.fd, &readable);
      max_fd = std::max(max_fd, c.fd);
    }
    timeval tv{0, 100'000};  // wake regularly to notice stop() and expire clients
    const int n = select(max_fd + 1, &readable, nullptr, nullptr, &tv);
    if (n < 0 && errno != EINTR) break;
    const std::int64_t now = time::monotonic_now_ns();
    if (n > 0 && FD_ISSET(listen_fd_, &readable)) accept_client(clients, now);
    for (std::size_t i = 0; i < clients.size();) {
      const bool keep =
          n <= 0 || !FD_ISSET(clients[i].fd, &readable) || read_client(clients[i], now);
      if (keep && !expired(clients[i], now)) {
        ++i;
        continue;
      }
      close(clients[i].fd);
      clients.erase(clients.begin() + static_cast<std::ptrdiff_t>(i));
    }
  }
  for (const Client& c : clients)
    close(c.fd);
}

// A new connection always gets in: when every slot is taken, the client that has been quiet
// longest is closed for it (four idle connections used to lock everyone out).
void ModbusHealthServer::accept_client(std::vector<Client>& clients, std::int64_t now) {
  int server = listen_fd_;
  const int fd = modbus_tcp_accept(as_ctx(ctx_), &server);
  if (fd < 0) return;
  if (static_cast<int>(clients.size()) >= config_.max_clients) {
    const auto quietest = std::min_element(
        clients.begin(), clients.end(),
        [](const Client& a, const Client& b) { return a.last_activity_ns < b.last_activity_ns; });
    close(quietest->fd);
    clients.erase(quietest);
    evicted_.fetch_add(1, std::memory_order_relaxed);
  }
  Client c;
  c.fd = fd;
  c.last_activity_ns = now;
  clients.push_back(c);
  connections_.fetch_add(1, std::memory_order_relaxed);
}

bool ModbusHealthServer::expired(const Client& c, std::int64_t now) {
  const std::int64_t idle_ns = std::int64_t{config_.idle_timeout_ms} * 1'000'000;
  const std::int64_t request_ns = std::int64_t{config_.request_timeout_ms} * 1'000'000;
  if (c.have > 0 && now - c.partial_since_ns > request_ns) {
    timeouts_.fetch_add(1, std::memory_order_relaxed);  // half a request: never completed
    return true;
  }
  if (now - c.last_activity_ns > idle_ns) {
    idle_closed_.fetch_add(1, std::memory_order_relaxed);
    return true;
  }
  return false;
}

// Reads what the socket has and answers every whole request in the buffer. Returns false when
// the client is to be closed (it closed, or sent something that is not Modbus TCP).
bool ModbusHealthServer::read_client(Client& c, std::int64_t now) {
  const ssize_t got = recv(c.fd, c.buf.data() + c.have, c.buf.size() - c.have, MSG_DONTWAIT);
  if (got == 0) return false;
  if (got < 0) return errno == EAGAIN || errno == EWOULDBLOCK || errno == EINTR;
  if (c.have == 0) c.partial_since_ns = now;
  c.have += static_cast<std::size_t>(got);
  c.last_activity_ns = now;
  // MBAP header: transaction id (2), protocol id (2, 0), length (2) of unit id + PDU.
  while (c.have >= 7) {
    const std::size_t length = std::size_t{c.buf[4]} << 8 | c.buf[5];
    const std::size_t total = 6 + length;
    if (c.buf[2] != 0 || c.buf[3] != 0 || length < 2 || total > c.buf.size()) {
      malformed_.fetch_add(1, std::memory_order_relaxed);
      return false;
    }
    if (c.have < total) break;
    modbus_set_socket(as_ctx(ctx_), c.fd);
    handle_request(c.buf.data(), static_cast<int>(total));
    std::copy(c.buf.begin() + static_cast<std::ptrdiff_t>(total),
              c.buf.begin() + static_cast<std::ptrdiff_t>(c.have), c.buf.begin());
    c.have -= total;
    c.partial_since_ns = now;
  }
  return true;
}

void ModbusHealthServer::handle_request(const std::uint8_t* query, int rc) {
  requests_.fetch_add(1, std::memory_order_relaxed);
  const int hl = modbus_get_header_length(as_ctx(ctx_));
  modbus_t* ctx = as_ctx(ctx_);
  modbus_mapping_t* map = as_map(mapping_);
  // Refresh the mapping from the shared state just before answering.
  const auto uptime =
      static_cast<std::uint32_t>((time::monotonic_now_ns() - start_mono_ns_) / time::kNsPerSecond);
  fill_input_registers(counters_, uptime, store_.generation(),
                       std::span<std::uint16_t>(map->tab_input_registers,
                                                static_cast<std::size_t>(map->nb_input_registers)));
  store_.read_all(
      std::span<std::uint16_t>(map->tab_registers, static_cast<std::size_t>(map->nb_registers)));
  const std::uint8_t fc = rc > hl ? query[static_cast<std::size_t>(hl)] : 0;
  if (fc == MODBUS_FC_READ_HOLDING_REGISTERS || fc == MODBUS_FC_READ_INPUT_REGISTERS) {
    handle_read(query, rc, fc);
  } else if (fc == MODBUS_FC_WRITE_SINGLE_REGISTER || fc == MODBUS_FC_WRITE_MULTIPLE_REGISTERS) {
    handle_write(query, rc, fc);
  } else if (fc >= 0x80) {
    // No function has the high bit (it marks exception replies). libmodbus's exception reply
    // would carry fc + 0x80 cut to 8 bits, e.g. 0x7F: what a client reads as a normal reply
    // of function 0x7F. The exception reply keeps the bit: the code as sent.
    refused_function_.fetch_add(1, std::memory_order_relaxed);
    const std::uint8_t reply[] = {
        query[0], query[1], 0, 0, 0, 3, query[6], fc, MODBUS_EXCEPTION_ILLEGAL_FUNCTION};
    send(modbus_get_socket(ctx), reply, sizeof reply, MSG_NOSIGNAL);
  } else {
    refused_function_.fetch_add(1, std::memory_order_relaxed);
    modbus_reply_exception(ctx, query, MODBUS_EXCEPTION_ILLEGAL_FUNCTION);
  }
}

void ModbusHealthServer::handle_read(const std::uint8_t* query, int rc, std::uint8_t fc) {
  modbus_t* ctx = as_ctx(ctx_);
  modbus_mapping_t* map = as_map(mapping_);
  const int hl = modbus_get_header_length(ctx);
  const auto at = [&](int off) { return query[static_cast<std::size_t>(hl + off)]; };
  // Checked here so that exceptions are answered at once (libmodbus would sleep+flush). The
  // PDU is exactly fc, address, count: another length is "the implied length is incorrect"
  // (ILLEGAL DATA VALUE, Modbus Application Protocol 1.1b3, section 7).
  const bool whole = rc == hl + 5;
  const int address = whole ? (at(1) << 8 | at(2)) : -1;
  const int count = whole ? (at(3) << 8 | at(4)) : 0;
  const int size =
      fc == MODBUS_FC_READ_HOLDING_REGISTERS ? map->nb_registers : map->nb_input_registers;
  if (address < 0 || count < 1 || count > MODBUS_MAX_READ_REGISTERS) {
    malformed_.fetch_add(1, std::memory_order_relaxed);
    modbus_reply_exception(ctx, query, MODBUS_EXCEPTION_ILLEGAL_DATA_VALUE);
  } else if (address + count > size) {
    refused_value_.fetch_add(1, std::memory_order_relaxed);  // as a write outside the map
    modbus_reply_exception(ctx, query, MODBUS_EXCEPTION_ILLEGAL_DATA_ADDRESS);
  } else {
    modbus_reply(ctx, query, rc, map);
  }
}

void ModbusHealthServer::handle_write(const std::uint8_t* query, int rc, std::uint8_t fc) {
  modbus_t* ctx = as_ctx(ctx_);
  const int hl = modbus_get_header_length(ctx);
  const auto at = [&](int off) { return query[static_cast<std::size_t>(hl + off)]; };
  std::array<std::uint16_t, 128> values{};
  std::size_t count = 0;
  std::uint16_t address = 0;
  bool well_formed = false;
  // Exactly the PDU the function defines (as for reads): libmodbus echoed a 0x06 request's
  // trailing bytes in its reply.
  if (fc == MODBUS_FC_WRITE_SINGLE_REGISTER && rc == hl + 5) {
    address = static_cast<std::uint16_t>(at(1) << 8 | at(2));
    values[0] = static_cast<std::uint16_t>(at(3) << 8 | at(4));
    count = 1;
    well_formed = true;
  } else if (fc == MODBUS_FC_WRITE_MULTIPLE_REGISTERS && rc >= hl + 6) {
    address = static_cast<std::uint16_t>(at(1) << 8 | at(2));
    count = static_cast<std::size_t>(at(3) << 8 | at(4));
    const int bytes = at(5);
    well_formed =
        count >= 1 && count <= 123 && bytes == static_cast<int>(2 * count) && rc == hl + 6 + bytes;
    for (std::size_t k = 0; well_formed && k < count; ++k) {
      values[k] = static_cast<std::uint16_t>(at(6 + 2 * static_cast<int>(k)) << 8 |
                                             at(7 + 2 * static_cast<int>(k)));
    }
  }
  if (!well_formed) {
    malformed_.fetch_add(1, std::memory_order_relaxed);
    modbus_reply_exception(ctx, query, MODBUS_EXCEPTION_ILLEGAL_DATA_VALUE);
    return;
  }
  if (!config_.maintenance) {
    refused_write_locked_.fetch_add(1, std::memory_order_relaxed);
    modbus_reply_exception(ctx, query, MODBUS_EXCEPTION_SLAVE_OR_SERVER_FAILURE);
    return;
  }
  const int w =
      store_.write(address, std::span<const std::uint16_t>(values.data(), count), nullptr);
  if (w == 0) {
    writes_accepted_.fetch_add(1, std::memory_order_relaxed);
    modbus_reply(ctx, query, rc, as_map(mapping_));  // echoes the write, map gets the values
    return;
  }
  if (w == -EBUSY) {
    refused_identity_.fetch_add(1, std::memory_order_relaxed);
    modbus_reply_exception(ctx, query, MODBUS_EXCEPTION_SLAVE_OR_SERVER_BUSY);
    return;
  }
  refused_value_.fetch_add(1, std::memory_order_relaxed);
  modbus_reply_exception(
      ctx, query,
      w == -EFAULT ? MODBUS_EXCEPTION_ILLEGAL_DATA_ADDRESS : MODBUS_EXCEPTION_ILLEGAL_DATA_VALUE);
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
  s.refused_identity = refused_identity_.load();
  s.evicted = evicted_.load();
  s.timeouts = timeouts_.load();
  s.idle_closed = idle_closed_.load();
  return s;
}

}  // namespace storetrack::health
