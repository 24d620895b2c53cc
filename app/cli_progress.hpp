// Progress of a firmware download as the operator sees it: a bar with bytes/s and time left on a
// terminal, a plain line per step and per tenth otherwise (logs and pipes get no control codes),
// each flushed as it is printed.
#pragma once

#include <chrono>
#include <cstdint>
#include <iosfwd>
#include <string>

#include "app/cli_reply.hpp"

namespace canbridge::cli {

// "[##########..........]  50%  128.0/256.0 KiB  12.5 KiB/s  0:10 left  download"; the rate and
// time left only when `bytes_per_second` > 0.
std::string format_progress_bar(const Progress& progress, double bytes_per_second);
// "download: 131072/262144 bytes (50%), 12.5 KiB/s, 0:10 left".
std::string format_progress_line(const Progress& progress, double bytes_per_second);

class ProgressPrinter {
 public:
  ProgressPrinter(std::ostream& out, bool terminal) : out_(out), terminal_(terminal) {}
  // One PROGRESS line of the endpoint, received at `now`.
  void update(const Progress& progress, std::chrono::steady_clock::time_point now);
  // Ends the bar's line (nothing to do for plain lines).
  void finish();

 private:
  std::ostream& out_;
  bool terminal_;
  bool drawn_ = false;
  std::string step_;
  std::uint64_t step_start_done_ = 0;
  std::chrono::steady_clock::time_point step_start_{};
  std::uint64_t printed_tenth_ = 0;  // plain lines: the last tenth printed, +1
};

}  // namespace canbridge::cli
