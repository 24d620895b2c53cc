#include "logging/log_setup.hpp"

#include <gtest/gtest.h>
#include <spdlog/details/log_msg.h>
#include <stdlib.h>
#include <sys/stat.h>

#include <regex>
#include <string>

namespace canbridge::logging {
namespace {

std::string formatted(LogFormat format, spdlog::level::level_enum level, const std::string& text) {
  const auto formatter = make_formatter(format);
  const spdlog::details::log_msg msg(spdlog::source_loc{}, "canbridge", level, text);
  spdlog::memory_buf_t out;
  formatter->format(msg, out);
  return std::string(out.data(), out.size());
}

TEST(LogFormat, JournalLinesCarryThePriorityAndNoTimestamp) {
  struct Row {
    spdlog::level::level_enum level;
    std::string line;
  };
  const std::vector<Row> table = {
      {spdlog::level::critical, "<2>critical gateway down\n"},
      {spdlog::level::err, "<3>error gateway down\n"},
      {spdlog::level::warn, "<4>warning gateway down\n"},
      {spdlog::level::info, "<6>info gateway down\n"},
      {spdlog::level::debug, "<7>debug gateway down\n"},
      {spdlog::level::trace, "<7>trace gateway down\n"},
  };
  for (const Row& row : table) {
    EXPECT_EQ(formatted(LogFormat::journal, row.level, "gateway down"), row.line);
  }
}

TEST(LogFormat, TextLinesStartWithDateAndTime) {
  const std::string line = formatted(LogFormat::text, spdlog::level::warn, "link lost");
  EXPECT_TRUE(std::regex_match(
      line, std::regex(R"(\d{4}-\d\d-\d\d \d\d:\d\d:\d\d\.\d{3} warning link lost\n)")))
      << line;
}

// What a program writes itself (a config error of several lines): each line at the priority,
// as the journal files it; text as it was, with the last line ended.
TEST(LogFormat, TextWrittenOutsideTheLoggerGetsThePriorityOnEveryLine) {
  const std::string error =
      "canbridge: invalid configuration (2 problems)\n  a.yaml:3: log.level: 'loud'\n"
      "  a.yaml:9: bus: missing";
  EXPECT_EQ(prefix_lines(LogFormat::journal, spdlog::level::err, error),
            "<3>canbridge: invalid configuration (2 problems)\n<3>  a.yaml:3: log.level: "
            "'loud'\n<3>  a.yaml:9: bus: missing\n");
  EXPECT_EQ(prefix_lines(LogFormat::journal, spdlog::level::warn, "one\n"), "<4>one\n");
  EXPECT_EQ(prefix_lines(LogFormat::journal, spdlog::level::err, "a\n\nb\n"), "<3>a\n<3>\n<3>b\n");
  EXPECT_EQ(prefix_lines(LogFormat::text, spdlog::level::err, error), error + "\n");
  EXPECT_EQ(prefix_lines(LogFormat::text, spdlog::level::err, "done\n"), "done\n");
  EXPECT_EQ(prefix_lines(LogFormat::journal, spdlog::level::err, ""), "");
}

TEST(LogFormat, NamesOfFormatsAndLevels) {
  EXPECT_EQ(parse_log_format("auto"), LogFormat::automatic);
  EXPECT_EQ(parse_log_format("text"), LogFormat::text);
  EXPECT_EQ(parse_log_format("journal"), LogFormat::journal);
  EXPECT_EQ(parse_log_format("json"), std::nullopt);
  EXPECT_EQ(parse_level("warn"), spdlog::level::warn);
  EXPECT_EQ(parse_level("error"), spdlog::level::err);
  EXPECT_EQ(parse_level("off"), spdlog::level::off);
  EXPECT_EQ(parse_level("loud"), std::nullopt);  // spdlog's from_str would say "off"
  EXPECT_EQ(level_from_verbosity(0), std::nullopt);
  EXPECT_EQ(level_from_verbosity(1), spdlog::level::debug);
  EXPECT_EQ(level_from_verbosity(3), spdlog::level::trace);
}

TEST(JournalStream, MatchesOnlyTheDeviceAndInodeItNames) {
  EXPECT_TRUE(journal_stream_names("8:12345", 8, 12345));
  EXPECT_FALSE(journal_stream_names("8:12345", 8, 12346));
  EXPECT_FALSE(journal_stream_names("9:12345", 8, 12345));
  EXPECT_FALSE(journal_stream_names("", 8, 12345));
  EXPECT_FALSE(journal_stream_names("8", 8, 12345));
  EXPECT_FALSE(journal_stream_names("8:12345x", 8, 12345));
  EXPECT_FALSE(journal_stream_names(":12345", 0, 12345));
}

TEST(JournalStream, AutoPicksJournalOnlyWhenStderrIsTheNamedStream) {
  struct stat st {};
  ASSERT_EQ(::fstat(2, &st), 0);
  const std::string own = std::to_string(st.st_dev) + ":" + std::to_string(st.st_ino);
  ASSERT_EQ(::setenv("JOURNAL_STREAM", own.c_str(), 1), 0);
  EXPECT_TRUE(stderr_is_journal());
  EXPECT_EQ(resolve(LogFormat::automatic), LogFormat::journal);
  EXPECT_EQ(resolve(LogFormat::text), LogFormat::text);
  // Inherited by a process whose stderr goes elsewhere: no longer the journal.
  const std::string other = std::to_string(st.st_dev) + ":" + std::to_string(st.st_ino + 1);
  ASSERT_EQ(::setenv("JOURNAL_STREAM", other.c_str(), 1), 0);
  EXPECT_FALSE(stderr_is_journal());
  EXPECT_EQ(resolve(LogFormat::automatic), LogFormat::text);
  ASSERT_EQ(::unsetenv("JOURNAL_STREAM"), 0);
  EXPECT_EQ(resolve(LogFormat::automatic), LogFormat::text);
  EXPECT_EQ(resolve(LogFormat::journal), LogFormat::journal);
}

}  // namespace
}  // namespace canbridge::logging
