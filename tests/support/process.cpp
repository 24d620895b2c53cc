#include "tests/support/process.hpp"

#include <elf.h>
#include <fcntl.h>
#include <signal.h>
#include <spawn.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cerrno>
#include <cstdint>
#include <cstring>
#include <fstream>
#include <sstream>
#include <string_view>
#include <system_error>

extern char** environ;

namespace canbridge::test {
namespace {

#ifdef CANBRIDGE_TARGET_LAUNCHER
// The ELF machine this test program was compiled for.
constexpr std::uint16_t kOwnElfMachine =
#if defined(__aarch64__)
    EM_AARCH64;
#elif defined(__arm__)
    EM_ARM;
#else
    0;  // no other cross target: nothing is launched through the emulator
#endif

// True when `path` is an ELF executable for the machine this program was built for.
bool is_target_program(const std::string& path) {
  std::ifstream file(path, std::ios::binary);
  unsigned char header[20] = {};
  if (!file.read(reinterpret_cast<char*>(header), sizeof header)) return false;
  if (std::memcmp(header, ELFMAG, SELFMAG) != 0) return false;
  const auto machine = static_cast<std::uint16_t>(header[18] | (header[19] << 8));  // e_machine, LE
  return machine == kOwnElfMachine;
}
#endif

// In a cross-built tree (CANBRIDGE_TARGET_LAUNCHER: the emulator ctest runs the tests with, e.g.
// "qemu-arm -L /usr/arm-linux-gnueabihf -E LD_LIBRARY_PATH=..."), a test that spawns one of the
// tree's own programs spawns a target binary, which the build machine's kernel execs only where
// binfmt_misc is set up for qemu (not in containers and CI). Such a child runs through the same
// emulator as the test; the build machine's tools (candump, sh) are spawned as they are.
std::vector<std::string> through_target_launcher(std::vector<std::string> argv) {
#ifdef CANBRIDGE_TARGET_LAUNCHER
  if (!argv.empty() && argv[0].find('/') != std::string::npos && is_target_program(argv[0])) {
    std::vector<std::string> launched;
    std::istringstream words(CANBRIDGE_TARGET_LAUNCHER);
    for (std::string word; words >> word;) launched.push_back(word);
    launched.insert(launched.end(), argv.begin(), argv.end());
    return launched;
  }
#endif
  return argv;
}

}  // namespace

ChildProcess::ChildProcess(std::vector<std::string> argv, Capture capture) {
  argv = through_target_launcher(std::move(argv));
  int fds[2];
  if (::pipe2(fds, O_CLOEXEC) != 0) throw std::system_error(errno, std::system_category(), "pipe");
  posix_spawn_file_actions_t actions;
  posix_spawn_file_actions_init(&actions);
  posix_spawn_file_actions_addopen(&actions, STDIN_FILENO, "/dev/null", O_RDONLY, 0);
  if (capture == Capture::stderr_only) {
    posix_spawn_file_actions_addopen(&actions, STDOUT_FILENO, "/dev/null", O_WRONLY, 0);
  } else {
    posix_spawn_file_actions_adddup2(&actions, fds[1], STDOUT_FILENO);
  }
  posix_spawn_file_actions_adddup2(&actions, fds[1], STDERR_FILENO);
  std::vector<char*> args;
  for (std::string& a : argv) args.push_back(a.data());
  args.push_back(nullptr);
  const int rc = ::posix_spawnp(&pid_, args[0], &actions, nullptr, args.data(), environ);
  posix_spawn_file_actions_destroy(&actions);
  ::close(fds[1]);
  if (rc != 0) {
    ::close(fds[0]);
    throw std::system_error(rc, std::system_category(), "posix_spawnp " + argv[0]);
  }
  out_fd_ = fds[0];
  reader_ = std::thread([this] {
    char buf[65536];
    for (;;) {
      const ssize_t n = ::read(out_fd_, buf, sizeof buf);
      if (n < 0 && errno == EINTR) continue;
      {
        std::lock_guard lock(mutex_);
        if (n <= 0) {
          eof_ = true;
        } else {
          output_.append(buf, static_cast<std::size_t>(n));
        }
      }
      changed_.notify_all();
      if (n <= 0) return;
    }
  });
}

ChildProcess::~ChildProcess() {
  if (!status_) {
    ::kill(pid_, SIGKILL);
    reap();
  }
  if (reader_.joinable()) reader_.join();
  ::close(out_fd_);
}

bool ChildProcess::wait_for_line(const std::string& needle, std::chrono::milliseconds timeout) {
  std::unique_lock lock(mutex_);
  bool found = false;
  const auto match = [&] {
    // Only complete lines count, unless the child is gone: then whatever it left is final.
    const std::size_t complete = eof_ ? output_.size() : output_.rfind('\n') + 1;
    if (complete <= scanned_) return eof_;
    const std::string_view text(output_.data() + scanned_, complete - scanned_);
    const std::size_t at = text.find(needle);
    if (at != std::string_view::npos) {
      const std::size_t line_end = text.find('\n', at);
      scanned_ += line_end == std::string_view::npos ? text.size() : line_end + 1;
      found = true;
      return true;
    }
    return eof_;
  };
  changed_.wait_for(lock, timeout, match);
  return found;
}

bool ChildProcess::finished() const {
  std::lock_guard lock(mutex_);
  return eof_;
}

std::optional<int> ChildProcess::reap() {
  if (status_) return status_;
  int status = 0;
  while (::waitpid(pid_, &status, 0) < 0) {
    if (errno != EINTR) return std::nullopt;
  }
  status_ = WIFEXITED(status) ? WEXITSTATUS(status) : 128 + WTERMSIG(status);
  return status_;
}

std::optional<int> ChildProcess::wait(std::chrono::milliseconds timeout) {
  if (status_) return status_;
  {
    std::unique_lock lock(mutex_);
    if (!changed_.wait_for(lock, timeout, [this] { return eof_; })) return std::nullopt;
  }
  return reap();
}

int ChildProcess::stop(std::chrono::milliseconds grace) {
  if (status_) return *status_;
  ::kill(pid_, SIGTERM);
  if (auto s = wait(grace)) return *s;
  ::kill(pid_, SIGKILL);
  return reap().value_or(-1);
}

std::string ChildProcess::output() const {
  std::lock_guard lock(mutex_);
  return output_;
}

RunResult run(std::vector<std::string> argv, std::chrono::milliseconds timeout, Capture capture) {
  ChildProcess child(std::move(argv), capture);
  RunResult r;
  auto status = child.wait(timeout);
  r.status = status ? *status : child.stop();
  r.output = child.output();
  return r;
}

std::string last_line(const std::string& text) {
  const std::size_t end = text.find_last_not_of('\n');
  if (end == std::string::npos) return "";
  const std::size_t begin = text.rfind('\n', end);
  return text.substr(begin == std::string::npos ? 0 : begin + 1, end + 1 - (begin + 1));
}

}  // namespace canbridge::test
