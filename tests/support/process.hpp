// Runs a child program for system tests: argv in, merged stdout+stderr readable line by line
// with a deadline, and a guaranteed kill on destruction so no test leaves processes behind.
#pragma once

#include <sys/types.h>

#include <chrono>
#include <optional>
#include <string>
#include <vector>

namespace canbridge::test {

class ChildProcess {
 public:
  explicit ChildProcess(std::vector<std::string> argv);
  ~ChildProcess();
  ChildProcess(const ChildProcess&) = delete;
  ChildProcess& operator=(const ChildProcess&) = delete;

  // Reads output until a line containing `needle` arrives (true) or the deadline/EOF (false).
  bool wait_for_line(const std::string& needle, std::chrono::milliseconds timeout);
  // Everything read so far (for failure messages).
  const std::string& output() const { return output_; }
  // Reads what is left until EOF or the deadline.
  void drain(std::chrono::milliseconds timeout);
  // SIGTERM, then SIGKILL after `grace`; returns the exit status (or 128+signal).
  int stop(std::chrono::milliseconds grace = std::chrono::milliseconds(3000));
  // Waits for a normal exit; nullopt on timeout.
  std::optional<int> wait(std::chrono::milliseconds timeout);
  pid_t pid() const { return pid_; }

 private:
  bool read_some(std::chrono::steady_clock::time_point deadline);
  pid_t pid_ = -1;
  int out_fd_ = -1;
  std::string output_;
  std::size_t scanned_ = 0;
  std::optional<int> status_;
};

// Runs a program to completion and returns its exit status and output.
struct RunResult {
  int status = -1;
  std::string output;
};
RunResult run(std::vector<std::string> argv,
              std::chrono::milliseconds timeout = std::chrono::milliseconds(10000));

}  // namespace canbridge::test
