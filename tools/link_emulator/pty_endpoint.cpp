#include "tools/link_emulator/pty_endpoint.hpp"

#include <fcntl.h>
#include <pty.h>
#include <sys/stat.h>
#include <termios.h>
#include <unistd.h>

#include <array>
#include <cerrno>
#include <string_view>
#include <system_error>

namespace canbridge::emulator {

namespace {

[[noreturn]] void throw_errno(const std::string& what) {
  throw std::system_error(errno, std::generic_category(), what);
}

// Closes the descriptors if the constructor throws half-way.
struct FdGuard {
  int fd = -1;
  ~FdGuard() {
    if (fd >= 0) ::close(fd);
  }
  int release() {
    const int released = fd;
    fd = -1;
    return released;
  }
};

}  // namespace

PtyEndpoint::PtyEndpoint(boost::asio::io_context& io, std::string link_path)
    : master_(io), link_path_(std::move(link_path)) {
  FdGuard master;
  FdGuard slave;
  if (::openpty(&master.fd, &slave.fd, nullptr, nullptr, nullptr) != 0) throw_errno("openpty");
  ::fcntl(master.fd, F_SETFD, FD_CLOEXEC);
  ::fcntl(slave.fd, F_SETFD, FD_CLOEXEC);
  // Raw: no echo back into the master, no line editing, no CR/LF translation, all 8 bits.
  termios mode{};
  if (::tcgetattr(slave.fd, &mode) != 0) throw_errno("tcgetattr " + link_path_);
  ::cfmakeraw(&mode);
  if (::tcsetattr(slave.fd, TCSANOW, &mode) != 0) throw_errno("tcsetattr " + link_path_);
  std::array<char, 128> name{};
  if (::ptsname_r(master.fd, name.data(), name.size()) != 0) throw_errno("ptsname");
  device_ = name.data();

  struct stat existing {};
  if (::lstat(link_path_.c_str(), &existing) == 0) {
    if (!S_ISLNK(existing.st_mode)) {
      throw std::system_error(std::make_error_code(std::errc::file_exists),
                              link_path_ + " exists and is not a symlink");
    }
    ::unlink(link_path_.c_str());  // left behind by an emulator that was killed
  }
  if (::symlink(device_.c_str(), link_path_.c_str()) != 0) throw_errno("symlink " + link_path_);
  master_.assign(master.release());
  slave_keepalive_ = slave.release();
}

PtyEndpoint::~PtyEndpoint() {
  // Only our own link: another emulator may have taken the path over meanwhile.
  std::array<char, 128> target{};
  const ssize_t length = ::readlink(link_path_.c_str(), target.data(), target.size() - 1);
  if (length > 0 && device_ == std::string_view(target.data(), static_cast<std::size_t>(length))) {
    ::unlink(link_path_.c_str());
  }
  boost::system::error_code ignored;
  master_.close(ignored);
  ::close(slave_keepalive_);
}

}  // namespace canbridge::emulator
