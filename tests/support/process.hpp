// Child programs for system tests: argv in, output collected by a reader thread (so a chatty
// child such as candump never blocks on a full pipe), waits with deadlines, and a guaranteed kill
// on destruction so no test leaves processes behind.
#pragma once

#include <sys/types.h>

#include <chrono>
#include <condition_variable>
#include <mutex>
#include <optional>
#include <string>
#include <thread>
#include <vector>

namespace canbridge::test {

// Which of the child's streams output() holds; the other one goes to /dev/null.
enum class Capture { stdout_and_stderr, stderr_only };

// A child program (posix_spawnp, stdin from /dev/null). Killed (SIGKILL) on destruction.
class ChildProcess {
 public:
  explicit ChildProcess(std::vector<std::string> argv,
                        Capture capture = Capture::stdout_and_stderr);
  ~ChildProcess();
  ChildProcess(const ChildProcess&) = delete;
  ChildProcess& operator=(const ChildProcess&) = delete;

  // Waits until a complete line containing `needle` arrives after the line of the previous match
  // (true), or the timeout passes or the child closes its output (false). No polling: the reader
  // thread signals every chunk it reads.
  bool wait_for_line(const std::string& needle, std::chrono::milliseconds timeout);
  // True once the child closed its output, i.e. exited (the tools used here do not fork).
  bool finished() const;
  // Waits until the child exited; its exit status (128+signal when killed), nullopt on timeout.
  std::optional<int> wait(std::chrono::milliseconds timeout);
  // SIGTERM, then SIGKILL after `grace`; returns the exit status.
  int stop(std::chrono::milliseconds grace = std::chrono::milliseconds(5000));
  // Everything read so far (for checks and failure messages).
  std::string output() const;
  pid_t pid() const { return pid_; }

 private:
  std::optional<int> reap();
  pid_t pid_ = -1;
  int out_fd_ = -1;
  std::thread reader_;
  mutable std::mutex mutex_;
  std::condition_variable changed_;  // output grew or EOF
  std::string output_;
  std::size_t scanned_ = 0;  // wait_for_line resumes here
  bool eof_ = false;
  std::optional<int> status_;
};

struct RunResult {
  int status = -1;
  std::string output;
};
// Runs a program to completion (killed after `timeout`) and returns its exit status and output.
RunResult run(std::vector<std::string> argv,
              std::chrono::milliseconds timeout = std::chrono::milliseconds(10000),
              Capture capture = Capture::stdout_and_stderr);

// The last non-empty line of a child's output (e.g. the counter line a process prints on exit),
// without its newline; "" when there is none.
std::string last_line(const std::string& text);

}  // namespace canbridge::test
