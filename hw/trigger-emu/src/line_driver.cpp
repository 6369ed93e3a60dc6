#include "storetrack/trigger_emu/line_driver.hpp"

#include <fcntl.h>
#include <gpiod.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <stdexcept>

namespace storetrack::trigger_emu {
namespace {
constexpr const char* kConsumer = "storetrack-trigger-emu";
}

GpiodLineDriver::GpiodLineDriver(const std::string& chip, const std::vector<unsigned>& offsets,
                                 bool active_low)
    : bulk_(std::make_unique<gpiod_line_bulk>()), values_(offsets.size(), 0) {
  if (offsets.empty() || offsets.size() > GPIOD_LINE_BULK_MAX_LINES) {
    throw std::runtime_error("trigger-emu: 1.." + std::to_string(GPIOD_LINE_BULK_MAX_LINES) +
                             " lines required");
  }
  chip_ = gpiod_chip_open_lookup(chip.c_str());
  if (chip_ == nullptr) {
    throw std::runtime_error("trigger-emu: cannot open GPIO chip '" + chip +
                             "': " + std::strerror(errno));
  }
  if (gpiod_chip_get_lines(chip_, const_cast<unsigned*>(offsets.data()),
                           static_cast<unsigned>(offsets.size()), bulk_.get()) != 0) {
    const int err = errno;
    gpiod_chip_close(chip_);
    throw std::runtime_error("trigger-emu: no such line(s) on '" + chip +
                             "': " + std::strerror(err));
  }
  const int flags = active_low ? GPIOD_LINE_REQUEST_FLAG_ACTIVE_LOW : 0;
  if (gpiod_line_request_bulk_output_flags(bulk_.get(), kConsumer, flags, values_.data()) != 0) {
    const int err = errno;
    gpiod_chip_close(chip_);
    throw std::runtime_error("trigger-emu: cannot request the lines of '" + chip +
                             "' as outputs (busy?): " + std::strerror(err));
  }
}

GpiodLineDriver::~GpiodLineDriver() {
  if (chip_ != nullptr) {
    set(0);
    gpiod_line_release_bulk(bulk_.get());
    gpiod_chip_close(chip_);
  }
}

int GpiodLineDriver::set(int level) {
  for (int& v : values_)
    v = level ? 1 : 0;
  return gpiod_line_set_value_bulk(bulk_.get(), values_.data()) == 0 ? 0 : -errno;
}

SimPullLineDriver::SimPullLineDriver(const std::string& chip_sysfs_dir,
                                     const std::vector<unsigned>& offsets, bool active_low)
    : active_low_(active_low) {
  if (offsets.empty()) throw std::runtime_error("trigger-emu: at least one line required");
  for (unsigned offset : offsets) {
    const std::string path = chip_sysfs_dir + "/sim_gpio" + std::to_string(offset) + "/pull";
    const int fd = ::open(path.c_str(), O_WRONLY | O_CLOEXEC);
    if (fd < 0) {
      const int err = errno;
      for (int f : fds_)
        ::close(f);
      throw std::runtime_error("trigger-emu: cannot open " + path +
                               " (not a gpio-sim chip?): " + std::strerror(err));
    }
    fds_.push_back(fd);
  }
  set(0);
}

SimPullLineDriver::~SimPullLineDriver() {
  set(0);
  for (int fd : fds_)
    ::close(fd);
}

int SimPullLineDriver::set(int level) {
  const bool high = (level != 0) != active_low_;
  const char* text = high ? "pull-up" : "pull-down";
  const auto len = static_cast<ssize_t>(std::strlen(text));
  for (int fd : fds_) {
    if (::pwrite(fd, text, static_cast<size_t>(len), 0) != len) return -errno;
  }
  return 0;
}

std::string SimPullLineDriver::sysfs_dir_for_chip(const std::string& chip) {
  std::string name = chip;
  if (const auto slash = name.rfind('/'); slash != std::string::npos) name = name.substr(slash + 1);
  return "/sys/bus/gpio/devices/" + name;
}

}  // namespace storetrack::trigger_emu
