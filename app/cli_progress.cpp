#include "app/cli_progress.hpp"

#include <cstdio>
#include <ostream>

namespace canbridge::cli {

namespace {

unsigned percent(const Progress& p) {
  return p.total == 0 ? 0u : static_cast<unsigned>(p.done * 100 / p.total);
}

std::string rate_and_left(const Progress& p, double bytes_per_second, const char* separator) {
  if (bytes_per_second <= 0) return {};
  char buf[64];
  const double left =
      p.total > p.done ? static_cast<double>(p.total - p.done) / bytes_per_second : 0.0;
  const auto secs = static_cast<unsigned long long>(left + 0.5);
  std::snprintf(buf, sizeof buf, "%s%.1f KiB/s%s%llu:%02llu left", separator,
                bytes_per_second / 1024.0, separator, secs / 60, secs % 60);
  return buf;
}

}  // namespace

std::string format_progress_bar(const Progress& p, double bytes_per_second) {
  constexpr unsigned kWidth = 20;
  const unsigned filled = p.total == 0 ? 0u : static_cast<unsigned>(p.done * kWidth / p.total);
  std::string bar = "[" + std::string(std::min(filled, kWidth), '#') +
                    std::string(kWidth - std::min(filled, kWidth), '.') + "]";
  char buf[96];
  std::snprintf(buf, sizeof buf, " %3u%%  %.1f/%.1f KiB", percent(p),
                static_cast<double>(p.done) / 1024.0, static_cast<double>(p.total) / 1024.0);
  return bar + buf + rate_and_left(p, bytes_per_second, "  ") + "  " + p.step;
}

std::string format_progress_line(const Progress& p, double bytes_per_second) {
  return p.step + ": " + std::to_string(p.done) + "/" + std::to_string(p.total) + " bytes (" +
         std::to_string(percent(p)) + "%)" + rate_and_left(p, bytes_per_second, ", ");
}

void ProgressPrinter::update(const Progress& p, std::chrono::steady_clock::time_point now) {
  const bool new_step = p.step != step_;
  if (new_step) {
    step_ = p.step;
    step_start_ = now;
    step_start_done_ = p.done;
    printed_tenth_ = 0;
  }
  // The rate over the step so far: a flash erase pause shows as a falling rate, not a stall.
  const double elapsed = std::chrono::duration<double>(now - step_start_).count();
  const double rate = elapsed > 0 && p.done > step_start_done_
                          ? static_cast<double>(p.done - step_start_done_) / elapsed
                          : 0.0;
  if (terminal_) {
    out_ << "\r" << format_progress_bar(p, rate) << "\x1b[K" << std::flush;
    drawn_ = true;
    return;
  }
  const std::uint64_t tenth = p.total == 0 ? 0 : p.done * 10 / p.total;
  if (new_step || tenth + 1 > printed_tenth_) {
    printed_tenth_ = tenth + 1;
    // Flushed: on a pipe or a file stdout is block-buffered, and a supervising script would see
    // no progress at all until the download ended.
    out_ << format_progress_line(p, rate) << "\n" << std::flush;
  }
}

void ProgressPrinter::finish() {
  if (drawn_) out_ << "\n" << std::flush;
  drawn_ = false;
}

}  // namespace canbridge::cli
