// A deliberately plain client of the surface's CiA 309-3 text endpoint for system tests: raw bytes
// over a Unix socket (optionally one write(2) per byte), lines read with deadlines, independent of
// canbridge's own client code so that the endpoint is tested against the protocol text alone.
#pragma once

#include <chrono>
#include <optional>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

namespace canbridge::test {

class EndpointClient {
 public:
  // Connects to the Unix socket at `path`; throws std::system_error when it cannot.
  explicit EndpointClient(const std::string& path);
  ~EndpointClient();
  EndpointClient(const EndpointClient&) = delete;
  EndpointClient& operator=(const EndpointClient&) = delete;

  // Writes all of `bytes` at once, or one write(2) per byte so the server sees every split.
  void send(std::string_view bytes);
  void send_byte_by_byte(std::string_view bytes);
  // Closes the sending side only, as `printf ... | socat` does at the end of its input.
  void shutdown_send();
  // The next response line without its line end, nullopt when none completes within `timeout`
  // or the server closed. Every line must end with CR LF: a bare LF is counted in bare_lf().
  std::optional<std::string> line(std::chrono::milliseconds timeout);
  // Lines up to and including the first that starts with `last`; the last element is that line
  // (absent when the timeout passed first, so callers check back() against `last`).
  std::vector<std::string> lines_until(std::string_view last, std::chrono::milliseconds timeout);
  // Sends `request` + LF and returns the next line (empty string on timeout).
  std::string ask(const std::string& request, std::chrono::milliseconds timeout);
  int bare_lf() const { return bare_lf_; }
  // After a multi-line answer (help), whose inner lines end with LF alone: what was counted.
  int take_bare_lf() { return std::exchange(bare_lf_, 0); }
  // True once the server closed the connection (read returned 0).
  bool closed() const { return closed_; }

 private:
  int fd_ = -1;
  std::string buffer_;
  int bare_lf_ = 0;
  bool closed_ = false;
};

}  // namespace canbridge::test
