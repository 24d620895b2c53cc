#include "logging/log_setup.hpp"

#include <spdlog/pattern_formatter.h>
#include <spdlog/sinks/stdout_color_sinks.h>
#include <spdlog/sinks/stdout_sinks.h>
#include <spdlog/spdlog.h>
#include <sys/stat.h>
#include <unistd.h>

#include <charconv>
#include <cstdlib>

namespace canbridge::logging {

namespace {

// The text line every executable writes (the colour only on a terminal).
constexpr const char* kTextPattern = "%Y-%m-%d %H:%M:%S.%e %^%l%$ %v";
// journald adds the time and reads the priority from the "<N>" prefix (sd-daemon(3)); the level
// name stays so a grep of `journalctl` output finds "warning" lines as in a text log.
constexpr const char* kJournalPattern = "%*%l %v";

// sd-daemon's "<N>" of a message's level (priority_prefix).
class JournalPriority final : public spdlog::custom_flag_formatter {
 public:
  void format(const spdlog::details::log_msg& msg, const std::tm&,
              spdlog::memory_buf_t& dest) override {
    const std::string_view prefix = priority_prefix(msg.level);
    dest.append(prefix.data(), prefix.data() + prefix.size());
  }
  std::unique_ptr<custom_flag_formatter> clone() const override {
    return std::make_unique<JournalPriority>();
  }
};

std::optional<std::uint64_t> decimal(std::string_view text) {
  std::uint64_t value = 0;
  if (text.empty()) return std::nullopt;
  const auto [end, ec] = std::from_chars(text.data(), text.data() + text.size(), value);
  if (ec != std::errc{} || end != text.data() + text.size()) return std::nullopt;
  return value;
}

}  // namespace

std::optional<LogFormat> parse_log_format(std::string_view name) {
  if (name == "auto") return LogFormat::automatic;
  if (name == "text") return LogFormat::text;
  if (name == "journal") return LogFormat::journal;
  return std::nullopt;
}

std::optional<spdlog::level::level_enum> parse_level(std::string_view name) {
  // spdlog's own from_str maps every unknown name to "off": a typo must not silence the log.
  if (name == "trace") return spdlog::level::trace;
  if (name == "debug") return spdlog::level::debug;
  if (name == "info") return spdlog::level::info;
  if (name == "warn") return spdlog::level::warn;
  if (name == "error") return spdlog::level::err;
  if (name == "off") return spdlog::level::off;
  return std::nullopt;
}

std::optional<spdlog::level::level_enum> level_from_verbosity(int count) {
  if (count <= 0) return std::nullopt;
  return count == 1 ? spdlog::level::debug : spdlog::level::trace;
}

bool journal_stream_names(std::string_view journal_stream, std::uint64_t device,
                          std::uint64_t inode) {
  const std::size_t colon = journal_stream.find(':');
  if (colon == std::string_view::npos) return false;
  const auto dev = decimal(journal_stream.substr(0, colon));
  const auto ino = decimal(journal_stream.substr(colon + 1));
  return dev && ino && *dev == device && *ino == inode;
}

bool stderr_is_journal() {
  const char* value = std::getenv("JOURNAL_STREAM");
  if (value == nullptr) return false;
  struct stat st {};
  if (::fstat(STDERR_FILENO, &st) != 0) return false;
  // Inherited by a child whose stderr goes elsewhere, the variable no longer matches.
  return journal_stream_names(value, st.st_dev, st.st_ino);
}

LogFormat resolve(LogFormat requested) {
  if (requested != LogFormat::automatic) return requested;
  return stderr_is_journal() ? LogFormat::journal : LogFormat::text;
}

std::unique_ptr<spdlog::formatter> make_formatter(LogFormat resolved) {
  auto formatter = std::make_unique<spdlog::pattern_formatter>();
  if (resolved == LogFormat::journal) {
    formatter->add_flag<JournalPriority>('*').set_pattern(kJournalPattern);
  } else {
    formatter->set_pattern(kTextPattern);
  }
  return formatter;
}

std::string_view priority_prefix(spdlog::level::level_enum level) {
  switch (level) {
    case spdlog::level::critical:
      return "<2>";
    case spdlog::level::err:
      return "<3>";
    case spdlog::level::warn:
      return "<4>";
    case spdlog::level::debug:
    case spdlog::level::trace:
      return "<7>";
    default:
      return "<6>";
  }
}

std::string prefix_lines(LogFormat resolved, spdlog::level::level_enum level,
                         std::string_view text) {
  if (text.empty()) return {};
  if (resolved != LogFormat::journal) {
    std::string out(text);
    if (out.back() != '\n') out += '\n';
    return out;
  }
  const std::string_view prefix = priority_prefix(level);
  std::string out;
  while (!text.empty()) {
    const std::size_t end = text.find('\n');
    const std::string_view line = text.substr(0, end);
    out.append(prefix).append(line).append("\n");
    text.remove_prefix(end == std::string_view::npos ? text.size() : end + 1);
  }
  return out;
}

void setup_logging(LogFormat format, spdlog::level::level_enum level) {
  const LogFormat resolved = resolve(format);
  // stdout stays for what a program prints for its users and tests (ready lines, tables).
  spdlog::sink_ptr sink;
  if (resolved == LogFormat::journal) {
    sink = std::make_shared<spdlog::sinks::stderr_sink_mt>();  // journald colours by priority
  } else {
    sink = std::make_shared<spdlog::sinks::stderr_color_sink_mt>();
  }
  auto logger = std::make_shared<spdlog::logger>("canbridge", std::move(sink));
  logger->set_formatter(make_formatter(resolved));
  logger->set_level(level);
  spdlog::set_default_logger(logger);
  // set_level on the registry applies to the default logger and to later ones alike.
  spdlog::set_level(level);
}

}  // namespace canbridge::logging
