// Output side of the trigger emulator: sets all trigger lines to one logical level at once.
// Two backends:
//  - GpiodLineDriver: a real GPIO chip's output lines through libgpiod 1.6 (bench: the emulator
//    board's outputs wired to the unit's trigger inputs);
//  - SimPullLineDriver: a gpio-sim chip's lines driven from OUTSIDE, through the sysfs
//    `sim_gpioN/pull` attributes - the simulated "wire" into the unit's input lines, so the unit
//    under test can request those lines as inputs and see real edge events (VM rig).
#pragma once

#include <memory>
#include <string>
#include <vector>

struct gpiod_chip;
struct gpiod_line_bulk;

namespace storetrack::trigger_emu {

class LineDriver {
 public:
  virtual ~LineDriver() = default;
  /// Logical level (1 = asserted) on every line; 0 or -errno.
  virtual int set(int level) = 0;
};

class GpiodLineDriver final : public LineDriver {
 public:
  /// chip: name, path, label or number (gpiod_chip_open_lookup). Throws std::runtime_error.
  GpiodLineDriver(const std::string& chip, const std::vector<unsigned>& offsets, bool active_low);
  ~GpiodLineDriver() override;
  GpiodLineDriver(const GpiodLineDriver&) = delete;
  GpiodLineDriver& operator=(const GpiodLineDriver&) = delete;
  int set(int level) override;

 private:
  gpiod_chip* chip_ = nullptr;
  std::unique_ptr<gpiod_line_bulk> bulk_;
  std::vector<int> values_;
};

class SimPullLineDriver final : public LineDriver {
 public:
  /// chip_sysfs_dir: the gpio-sim chip's device directory holding sim_gpio<offset>/pull (e.g.
  /// /sys/bus/gpio/devices/gpiochip1). Throws std::runtime_error when an attribute is missing.
  SimPullLineDriver(const std::string& chip_sysfs_dir, const std::vector<unsigned>& offsets,
                    bool active_low);
  ~SimPullLineDriver() override;
  SimPullLineDriver(const SimPullLineDriver&) = delete;
  SimPullLineDriver& operator=(const SimPullLineDriver&) = delete;
  int set(int level) override;

  /// sysfs directory of a gpio chip given as "gpiochipN" or "/dev/gpiochipN".
  static std::string sysfs_dir_for_chip(const std::string& chip);

 private:
  std::vector<int> fds_;
  bool active_low_;
};

}  // namespace storetrack::trigger_emu
