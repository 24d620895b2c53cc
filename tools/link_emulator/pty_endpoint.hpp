// A pseudo-terminal endpoint: a raw pty whose slave device a program opens through a symlink as
// if it were a serial port, while the emulator reads and writes the master side.
#pragma once

#include <boost/asio/io_context.hpp>
#include <boost/asio/posix/stream_descriptor.hpp>
#include <string>

namespace canbridge::emulator {

class PtyEndpoint {
 public:
  // Opens the pty, makes it raw and points `link_path` at the slave device (an old symlink there
  // is replaced; any other file is an error). Throws std::system_error (startup only).
  PtyEndpoint(boost::asio::io_context& io, std::string link_path);
  // Removes the symlink.
  ~PtyEndpoint();
  PtyEndpoint(const PtyEndpoint&) = delete;
  PtyEndpoint& operator=(const PtyEndpoint&) = delete;

  boost::asio::posix::stream_descriptor& master() { return master_; }
  const std::string& device() const { return device_; }  // e.g. /dev/pts/5
  const std::string& link_path() const { return link_path_; }

 private:
  boost::asio::posix::stream_descriptor master_;
  // Linux returns EIO on the master (and drops what was written) while no one has the slave
  // open, e.g. before the client program started or between its close and reopen. Holding the
  // slave open here keeps the master usable all the time; the client's open/close then is just
  // one more reference.
  int slave_keepalive_ = -1;
  std::string device_;
  std::string link_path_;
};

}  // namespace canbridge::emulator
