#include "app/reload_plan.hpp"

#include <yaml-cpp/yaml.h>

#include <algorithm>

namespace canbridge::bridge {

namespace {

// A node as text that ignores layout, comments, flow or block style and the order of map keys.
std::string canonical(const YAML::Node& node) {
  switch (node.Type()) {
    case YAML::NodeType::Scalar:
      return "'" + node.Scalar() + "'";
    case YAML::NodeType::Sequence: {
      std::string out = "[";
      for (const auto& item : node) out += canonical(item) + ",";
      return out + "]";
    }
    case YAML::NodeType::Map: {
      std::vector<std::pair<std::string, std::string>> entries;
      for (const auto& entry : node) {
        entries.emplace_back(canonical(entry.first), canonical(entry.second));
      }
      std::sort(entries.begin(), entries.end());
      std::string out = "{";
      for (const auto& [key, value] : entries) out += key + ":" + value + ",";
      return out + "}";
    }
    default:
      return "~";
  }
}

// Each top-level key with its section in canonical form, in file order; nullopt when the text is
// not a YAML map.
std::optional<std::vector<std::pair<std::string, std::string>>> sections(std::string_view text) {
  try {
    const YAML::Node root = YAML::Load(std::string(text));
    if (!root.IsMap()) return std::nullopt;
    std::vector<std::pair<std::string, std::string>> out;
    for (const auto& entry : root) {
      out.emplace_back(entry.first.as<std::string>(), canonical(entry.second));
    }
    return out;
  } catch (const YAML::Exception&) {
    return std::nullopt;
  }
}

std::string seconds_text(std::chrono::seconds s) {
  return std::to_string(s.count());
}

}  // namespace

std::vector<std::string> changed_sections(std::string_view started, std::string_view reloaded) {
  const auto before = sections(started);
  const auto after = sections(reloaded);
  std::vector<std::string> changed;
  const auto add = [&](const std::string& key) {
    if (std::find(changed.begin(), changed.end(), key) == changed.end()) changed.push_back(key);
  };
  const auto find = [](const auto& list, const std::string& key) -> const std::string* {
    if (!list) return nullptr;
    for (const auto& [k, v] : *list) {
      if (k == key) return &v;
    }
    return nullptr;
  };
  for (const auto* list : {&before, &after}) {
    if (!*list) continue;
    for (const auto& [key, value] : **list) {
      const std::string* a = find(before, key);
      const std::string* b = find(after, key);
      if (a == nullptr || b == nullptr || *a != *b) add(key);
    }
  }
  return changed;
}

ReloadPlan plan_reload(const RunningLogSettings& running, const config::LogOptions& reloaded,
                       const std::vector<std::string>& changed) {
  ReloadPlan plan;
  if (reloaded.level != running.level) {
    if (running.level_fixed) {
      plan.ignored_level = reloaded.level;
    } else {
      plan.level = reloaded.level;
    }
  }
  if (reloaded.stats_interval != running.stats_interval) {
    plan.stats_interval = reloaded.stats_interval;
  }
  // log holds only what applies at once; every other section is read at start only.
  for (const std::string& section : changed) {
    if (section != "log") plan.restart_sections.push_back(section);
  }
  return plan;
}

std::string applied_line(const ReloadPlan& plan, const RunningLogSettings& running,
                         const std::string& file) {
  std::string line = "config reloaded from " + file + ": ";
  std::vector<std::string> parts;
  if (plan.level) parts.push_back("log.level " + *plan.level + " (was " + running.level + ")");
  if (plan.stats_interval) {
    parts.push_back("log.stats_interval_s " + seconds_text(*plan.stats_interval) + " (was " +
                    seconds_text(running.stats_interval) + ")");
  }
  if (parts.empty()) {
    line += "nothing to apply (log.level " + running.level + ", log.stats_interval_s " +
            seconds_text(running.stats_interval) + ")";
  } else {
    for (std::size_t i = 0; i < parts.size(); ++i) line += (i == 0 ? "" : ", ") + parts[i];
  }
  if (plan.ignored_level) {
    line += "; log.level " + *plan.ignored_level + " not applied: the command line set " +
            running.level;
  }
  return line;
}

std::string restart_line(const ReloadPlan& plan) {
  if (plan.restart_sections.empty()) {
    return "config reload: no other setting changed (nothing needs a restart)";
  }
  std::string names;
  for (std::size_t i = 0; i < plan.restart_sections.size(); ++i) {
    names += (i == 0 ? "" : ", ") + plan.restart_sections[i];
  }
  return "config reload: " + names + " changed: restart to apply";
}

}  // namespace canbridge::bridge
