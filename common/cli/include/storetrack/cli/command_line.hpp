#pragma once
// A program's command line: options bound to variables, checks, subcommands (CLI11 underneath,
// compiled once in storetrack_cli; see CMakeLists.txt for why it is wrapped).
//
//   storetrack::cli::Command cli{"storetrack-x: what it does"};
//   cli.option("--rate-hz", rate_hz, "trigger rate").positive().show_default();
//   if (const int rc = cli.parse(argc, argv); rc >= 0) return rc;   // help (0) or usage error (2)
//
// Option types: bool (flags: flag()), the integer types, double, float, std::string and
// std::vector of them; another type is a link error (add it to the explicit instantiations in
// command_line.cpp).
#include <cstdint>
#include <initializer_list>
#include <memory>
#include <string>
#include <type_traits>

namespace CLI {
class App;
class Option;
}  // namespace CLI

namespace storetrack::cli {

/// Exit status of a command line that did not parse (the usage message is printed first).
inline constexpr int kExitUsage = 2;

/// One option of a Command (a handle: the Command owns the option); setters chain.
class Option {
 public:
  explicit Option(CLI::Option* impl) : impl_(impl) {}
  Option& required();
  Option& existing_file();
  Option& existing_directory();
  /// lo <= value <= hi (integer bounds: the help says INT, real ones FLOAT).
  template <class Number>
  Option& range(Number lo, Number hi) {
    if constexpr (std::is_integral_v<Number>) {
      return integer_range(lo, hi);
    } else {
      return real_range(lo, hi);
    }
  }
  Option& positive();      ///< value > 0
  Option& non_negative();  ///< value >= 0
  Option& one_of(std::initializer_list<const char*> choices);
  Option& delimiter(char separator);  ///< "a,b,c" as three values of a vector option
  Option& expected(int count);        ///< exactly this many values
  Option& show_default();             ///< print the variable's value as the default in --help

 private:
  Option& integer_range(long long lo, long long hi);
  Option& real_range(double lo, double hi);
  CLI::Option* impl_;
};

class Command {
 public:
  explicit Command(const std::string& description);
  ~Command();
  Command(const Command&) = delete;
  Command& operator=(const Command&) = delete;

  /// `name`: "--long", "-s,--long", or a positional name without dashes.
  template <class T>
  Option option(const std::string& name, T& value, const std::string& help);
  Option flag(const std::string& name, bool& value, const std::string& help);

  /// A subcommand; it lives as long as this command.
  Command& subcommand(const std::string& name, const std::string& description);
  void require_subcommand(int count);

  /// After parse(): was this option given (on this command)?
  bool given(const std::string& name) const;
  /// After parse(): was this (sub)command on the command line?
  bool parsed() const;
  bool got_subcommand(const std::string& name) const;

  /// -1: parsed, go on; 0: --help printed; kExitUsage: the error and usage printed (stderr).
  int parse(int argc, char** argv);

 private:
  explicit Command(CLI::App* subcommand);
  std::unique_ptr<CLI::App> owned_;
  CLI::App* app_;
  struct Children;
  std::unique_ptr<Children> children_;
};

}  // namespace storetrack::cli
