#include "app/reload_on_hangup.hpp"

#include <spdlog/spdlog.h>

#include <csignal>
#include <optional>

#include "config/loader.hpp"  // config::ConfigError
#include "logging/log_setup.hpp"

namespace canbridge::bridge {

namespace {

// Through the loader's bounds: a config replaced by a FIFO or a huge file must not hang or
// swell the running process at a SIGHUP. What is wrong is logged by the caller.
std::optional<std::string> read_text(const std::string& path, std::string* problem = nullptr) {
  try {
    return config::read_config_text(path);
  } catch (const config::ConfigError& e) {
    if (problem) *problem = e.problems().front().message;
    return std::nullopt;
  }
}

}  // namespace

ReloadOnHangup::ReloadOnHangup(boost::asio::any_io_executor executor, HangupReloadSource source,
                               const config::LogOptions& running, ParseLog parse,
                               std::function<void(std::chrono::seconds)> set_stats_interval)
    : signals_(std::move(executor), SIGHUP),
      source_(std::move(source)),
      running_{running.level, running.stats_interval, source_.log_level_fixed},
      parse_(std::move(parse)),
      set_stats_interval_(std::move(set_stats_interval)) {
  // Read again rather than passed in: the loader read this file a moment ago.
  if (!source_.config_path.empty()) started_text_ = read_text(source_.config_path).value_or("");
  wait();
}

void ReloadOnHangup::wait() {
  signals_.async_wait([this](boost::system::error_code ec, int) {
    if (ec) return;
    reload();
    wait();
  });
}

void ReloadOnHangup::reload() {
  const std::string& file = source_.config_path;
  if (file.empty()) {
    spdlog::warn("SIGHUP: no config file to re-read");
    return;
  }
  std::string problem;
  const std::optional<std::string> text = read_text(file, &problem);
  if (!text) {
    spdlog::error("config reload from {} failed, keeping the running settings: {}", file, problem);
    return;
  }
  config::LogOptions reloaded;
  try {
    reloaded = parse_(*text, file);
  } catch (const config::ConfigError& e) {
    spdlog::error("config reload from {} failed, keeping the running settings ({} problem(s)):",
                  file, e.problems().size());
    for (const config::ConfigProblem& p : e.problems()) spdlog::error("  {}", p.to_string());
    return;
  } catch (const std::exception& e) {
    spdlog::error("config reload from {} failed, keeping the running settings: {}", file, e.what());
    return;
  }
  const ReloadPlan plan = plan_reload(running_, reloaded, changed_sections(started_text_, *text));
  const std::string applied = applied_line(plan, running_, file);
  if (plan.stats_interval) {
    set_stats_interval_(*plan.stats_interval);
    running_.stats_interval = *plan.stats_interval;
  }
  // The two lines at info: written before a quieter level applies, after a louder one, so they
  // show whenever either level shows info.
  const bool info_shows_now = spdlog::should_log(spdlog::level::info);
  if (info_shows_now) {
    spdlog::info("{}", applied);
    spdlog::info("{}", restart_line(plan));
  }
  if (plan.level) {
    spdlog::set_level(logging::parse_level(*plan.level).value_or(spdlog::level::info));
    running_.level = *plan.level;
  }
  if (!info_shows_now) {
    spdlog::info("{}", applied);
    spdlog::info("{}", restart_line(plan));
  }
}

}  // namespace canbridge::bridge
