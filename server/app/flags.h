// Flags: a small, strict command-line parser for the octoscope subcommands. Each subcommand
// declares its flags (with help text); parsing rejects unknown flags, missing values and
// malformed numbers with a message naming the flag, and renders --help from the declarations.
//
// Thread safety: not thread-safe; used by one thread at start-up.
#ifndef OCTOSCOPE_APP_FLAGS_H_
#define OCTOSCOPE_APP_FLAGS_H_

#include <cstdint>
#include <map>
#include <optional>
#include <span>
#include <string>
#include <vector>

#include "util/result.h"

namespace octoscope::app {

class Flags {
 public:
  // `usage` is the synopsis line ("octoscope info INPUT [options]"); `summary` one paragraph.
  Flags(std::string usage, std::string summary);

  // Declares `--name VALUE` (takes a value) or `--name` (a switch).
  void AddValue(std::string name, std::string value_name, std::string help,
                std::string default_text = "");
  void AddSwitch(std::string name, std::string help);
  // Declares the positional arguments (for the help text) and how many are required.
  void SetPositionals(std::string synopsis, int min_count, int max_count);

  // Parses `args` (without the program and subcommand names). "--help"/"-h" sets help_requested().
  Status Parse(std::span<const std::string> args);

  // The command as the usage line names it: its first two words ("octoscope info").
  std::string command() const;

  bool help_requested() const { return help_; }
  std::string Help() const;

  bool Has(const std::string& name) const;  // Given on the command line.
  // The last value given (a flag given twice keeps the last), or every value in order.
  std::optional<std::string> Get(const std::string& name) const;
  std::vector<std::string> GetAll(const std::string& name) const;
  // Typed getters: `fallback` when absent, an error naming the flag when malformed.
  Result<int64_t> GetInt(const std::string& name, int64_t fallback, int64_t min, int64_t max) const;
  Result<double> GetDouble(const std::string& name, double fallback) const;
  const std::vector<std::string>& positionals() const { return positionals_; }

 private:
  struct Spec {
    bool takes_value;
    std::string value_name;
    std::string help;
    std::string default_text;
  };

  std::string usage_;
  std::string summary_;
  std::map<std::string, Spec> specs_;
  std::vector<std::string> order_;
  std::string positional_synopsis_;
  int min_positionals_ = 0;
  int max_positionals_ = 0;
  bool help_ = false;
  std::map<std::string, std::string> values_;
  std::map<std::string, std::vector<std::string>> all_values_;
  std::vector<std::string> positionals_;
};

}  // namespace octoscope::app

#endif  // OCTOSCOPE_APP_FLAGS_H_
