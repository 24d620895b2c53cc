// The one log setup of every canbridge executable: the same line format everywhere, as text with
// timestamps for a terminal or a file, or journald style (sd-daemon priority prefixes, no
// timestamps) when systemd's journal reads stderr.
#pragma once

#include <spdlog/common.h>
#include <spdlog/formatter.h>

#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <string_view>

namespace canbridge::logging {

enum class LogFormat {
  automatic,  // journal when stderr is the journal (JOURNAL_STREAM), else text
  text,       // "2026-12-02 09:30:00.123 info message"
  journal,    // "<6>info message": journald takes the priority from the prefix and adds the time
};

// "auto", "text", "journal"; nullopt for anything else.
std::optional<LogFormat> parse_log_format(std::string_view name);

// The level names of the command line and of the config files' log.level.
inline constexpr std::string_view kLevelNames = "trace, debug, info, warn, error, off";
std::optional<spdlog::level::level_enum> parse_level(std::string_view name);
// -v once: debug; twice or more: trace; never: nullopt (the configured level stays).
std::optional<spdlog::level::level_enum> level_from_verbosity(int count);

// Whether systemd's JOURNAL_STREAM value ("DEVICE:INODE", both decimal) names the file with
// this device and inode number: then that stream is the journal (systemd.exec(5)).
bool journal_stream_names(std::string_view journal_stream, std::uint64_t device,
                          std::uint64_t inode);
// Whether stderr is connected to the journal now (JOURNAL_STREAM matches fstat of fd 2).
bool stderr_is_journal();
// `automatic` resolved against where stderr goes; text and journal stay.
LogFormat resolve(LogFormat requested);

// The line formatter of a resolved format (text or journal).
std::unique_ptr<spdlog::formatter> make_formatter(LogFormat resolved);

// sd-daemon's "<N>" of a level, as the journal format writes it: syslog priorities (2 critical,
// 3 error, 4 warning, 6 info, 7 debug and trace).
std::string_view priority_prefix(spdlog::level::level_enum level);

// Text a program writes to stderr itself, not through the logger (a usage error, a config error,
// the exception that ended a role), in a resolved format: in journal, every line starts with
// `level`'s prefix, so that the journal files each line of a multi-line config error at that
// priority, not at the stream's default (info); in text, unchanged. A last line without '\n'
// gets one.
std::string prefix_lines(LogFormat resolved, spdlog::level::level_enum level,
                         std::string_view text);

// Makes the default logger write to stderr in `format` (resolved here) at `level`.
void setup_logging(LogFormat format, spdlog::level::level_enum level = spdlog::level::info);

}  // namespace canbridge::logging
