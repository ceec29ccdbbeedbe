#include "app/flags.h"

#include <sstream>

#include "util/strings.h"

namespace octoscope::app {

Flags::Flags(std::string usage, std::string summary)
    : usage_(std::move(usage)), summary_(std::move(summary)) {}

std::string Flags::command() const {
  const size_t first = usage_.find(' ');
  if (first == std::string::npos) return usage_;
  return usage_.substr(0, usage_.find(' ', first + 1));
}

void Flags::AddValue(std::string name, std::string value_name, std::string help,
                     std::string default_text) {
  order_.push_back(name);
  specs_[name] = Spec{true, std::move(value_name), std::move(help), std::move(default_text)};
}

void Flags::AddSwitch(std::string name, std::string help) {
  order_.push_back(name);
  specs_[name] = Spec{false, "", std::move(help), ""};
}

void Flags::SetPositionals(std::string synopsis, int min_count, int max_count) {
  positional_synopsis_ = std::move(synopsis);
  min_positionals_ = min_count;
  max_positionals_ = max_count;
}

Status Flags::Parse(std::span<const std::string> args) {
  for (size_t i = 0; i < args.size(); ++i) {
    const std::string& arg = args[i];
    if (arg == "--help" || arg == "-h") {
      help_ = true;
      return Status::Ok();
    }
    if (arg.size() > 2 && arg.compare(0, 2, "--") == 0) {
      // "--name=value" or "--name value" or "--switch".
      std::string name = arg.substr(2);
      std::optional<std::string> inline_value;
      if (size_t eq = name.find('='); eq != std::string::npos) {
        inline_value = name.substr(eq + 1);
        name.resize(eq);
      }
      auto it = specs_.find(name);
      if (it == specs_.end()) return InvalidArgumentError("unknown option --" + name);
      if (!it->second.takes_value) {
        if (inline_value) return InvalidArgumentError("--" + name + " takes no value");
        values_[name] = "";
        continue;
      }
      if (inline_value) {
        values_[name] = *inline_value;
      } else if (i + 1 < args.size()) {
        values_[name] = args[++i];
      } else {
        return InvalidArgumentError("--" + name + " needs a value (" + it->second.value_name + ")");
      }
      all_values_[name].push_back(values_[name]);
      continue;
    }
    positionals_.push_back(arg);
  }
  int n = static_cast<int>(positionals_.size());
  if (n < min_positionals_) return InvalidArgumentError("missing " + positional_synopsis_);
  if (n > max_positionals_) {
    return InvalidArgumentError("unexpected argument '" +
                                Printable(positionals_[max_positionals_]) + "'");
  }
  return Status::Ok();
}

std::string Flags::Help() const {
  std::ostringstream out;
  out << "usage: " << usage_ << "\n\n" << summary_ << "\n";
  if (!order_.empty()) out << "\noptions:\n";
  for (const std::string& name : order_) {
    const Spec& spec = specs_.at(name);
    std::string left = "  --" + name + (spec.takes_value ? " " + spec.value_name : "");
    out << left;
    out << std::string(left.size() < 28 ? 28 - left.size() : 1, ' ') << spec.help;
    if (!spec.default_text.empty()) out << " (default: " << spec.default_text << ")";
    out << "\n";
  }
  out << "  --help                    show this help\n";
  return out.str();
}

bool Flags::Has(const std::string& name) const { return values_.count(name) != 0; }

std::vector<std::string> Flags::GetAll(const std::string& name) const {
  auto it = all_values_.find(name);
  return it == all_values_.end() ? std::vector<std::string>{} : it->second;
}

std::optional<std::string> Flags::Get(const std::string& name) const {
  auto it = values_.find(name);
  if (it == values_.end()) return std::nullopt;
  return it->second;
}

Result<int64_t> Flags::GetInt(const std::string& name, int64_t fallback, int64_t min,
                              int64_t max) const {
  auto text = Get(name);
  if (!text) return fallback;
  auto value = ParseInt64(*text);
  if (!value)
    return InvalidArgumentError("--" + name + ": '" + Printable(*text) + "' is not an integer");
  if (*value < min || *value > max) {
    return InvalidArgumentError("--" + name + ": " + std::to_string(*value) + " is outside [" +
                                std::to_string(min) + ", " + std::to_string(max) + "]");
  }
  return *value;
}

Result<double> Flags::GetDouble(const std::string& name, double fallback) const {
  auto text = Get(name);
  if (!text) return fallback;
  auto value = ParseDouble(*text);
  if (!value)
    return InvalidArgumentError("--" + name + ": '" + Printable(*text) + "' is not a number");
  return *value;
}

}  // namespace octoscope::app
