#include "storetrack/cli/command_line.hpp"

#include <CLI/CLI.hpp>
#include <vector>

namespace storetrack::cli {

Option& Option::required() {
  impl_->required();
  return *this;
}
Option& Option::existing_file() {
  impl_->check(CLI::ExistingFile);
  return *this;
}
Option& Option::existing_directory() {
  impl_->check(CLI::ExistingDirectory);
  return *this;
}
Option& Option::integer_range(long long lo, long long hi) {
  impl_->check(CLI::Range(lo, hi));
  return *this;
}
Option& Option::real_range(double lo, double hi) {
  impl_->check(CLI::Range(lo, hi));
  return *this;
}
Option& Option::positive() {
  impl_->check(CLI::PositiveNumber);
  return *this;
}
Option& Option::non_negative() {
  impl_->check(CLI::NonNegativeNumber);
  return *this;
}
Option& Option::one_of(std::initializer_list<const char*> choices) {
  impl_->check(CLI::IsMember(std::vector<std::string>(choices.begin(), choices.end())));
  return *this;
}
Option& Option::delimiter(char separator) {
  impl_->delimiter(separator);
  return *this;
}
Option& Option::expected(int count) {
  impl_->expected(count);
  return *this;
}
Option& Option::show_default() {
  impl_->capture_default_str();
  return *this;
}

// Subcommands are CLI::App objects owned by their parent App; their Command wrappers are owned
// here, in a stable container (Command& handed out must not move).
struct Command::Children {
  std::vector<std::unique_ptr<Command>> list;
};

Command::Command(const std::string& description)
    : owned_(std::make_unique<CLI::App>(description)),
      app_(owned_.get()),
      children_(std::make_unique<Children>()) {}

Command::Command(CLI::App* subcommand)
    : app_(subcommand), children_(std::make_unique<Children>()) {}

Command::~Command() = default;

template <class T>
Option Command::option(const std::string& name, T& value, const std::string& help) {
  return Option(app_->add_option(name, value, help));
}

Option Command::flag(const std::string& name, bool& value, const std::string& help) {
  return Option(app_->add_flag(name, value, help));
}

Command& Command::subcommand(const std::string& name, const std::string& description) {
  CLI::App* sub = app_->add_subcommand(name, description);
  children_->list.push_back(std::unique_ptr<Command>(new Command(sub)));
  return *children_->list.back();
}

void Command::require_subcommand(int count) {
  app_->require_subcommand(count);
}

bool Command::given(const std::string& name) const {
  return app_->count(name) > 0;
}

bool Command::parsed() const {
  return app_->parsed();
}

bool Command::got_subcommand(const std::string& name) const {
  return app_->got_subcommand(name);
}

int Command::parse(int argc, char** argv) {
  try {
    app_->parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    return app_->exit(e) == 0 ? 0 : kExitUsage;
  }
  return -1;
}

// The option types the programs use (header: another type is a link error).
#define STORETRACK_CLI_OPTION_TYPE(T)                                                  \
  template Option Command::option<T>(const std::string&, T&, const std::string&);      \
  template Option Command::option<std::vector<T>>(const std::string&, std::vector<T>&, \
                                                  const std::string&);
STORETRACK_CLI_OPTION_TYPE(std::string)
STORETRACK_CLI_OPTION_TYPE(double)
STORETRACK_CLI_OPTION_TYPE(float)
STORETRACK_CLI_OPTION_TYPE(int)
STORETRACK_CLI_OPTION_TYPE(long)
STORETRACK_CLI_OPTION_TYPE(long long)
STORETRACK_CLI_OPTION_TYPE(unsigned)
STORETRACK_CLI_OPTION_TYPE(unsigned long)
STORETRACK_CLI_OPTION_TYPE(unsigned long long)
STORETRACK_CLI_OPTION_TYPE(std::uint8_t)
STORETRACK_CLI_OPTION_TYPE(std::uint16_t)
STORETRACK_CLI_OPTION_TYPE(std::int16_t)
#undef STORETRACK_CLI_OPTION_TYPE

}  // namespace storetrack::cli
