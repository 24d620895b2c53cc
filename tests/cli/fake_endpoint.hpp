// A scripted command endpoint for the client subcommands' tests: a Unix or TCP socket server on
// its own thread that expects the client's lines in order and answers each with canned lines,
// independent of the real endpoint's code.
#pragma once

#include <string>
#include <thread>
#include <vector>

namespace canbridge::test {

struct EndpointStep {
  std::string expect;                // the client's line (without LF)
  std::vector<std::string> replies;  // sent as "<reply>\r\n" each
};

using Script = std::vector<EndpointStep>;

class FakeEndpoint {
 public:
  enum class Transport { unix_socket, tcp };
  // Listens at once (a client may connect as soon as this returns). After the script the server
  // closes the connection when `close_at_end`, else waits for the client to close it.
  explicit FakeEndpoint(std::vector<EndpointStep> script,
                        Transport transport = Transport::unix_socket, bool close_at_end = true);
  ~FakeEndpoint();
  FakeEndpoint(const FakeEndpoint&) = delete;
  FakeEndpoint& operator=(const FakeEndpoint&) = delete;

  // "--endpoint" value: the socket path or 127.0.0.1:PORT.
  const std::string& address() const { return address_; }
  // Joins the server thread; the lines the client sent, in order.
  std::vector<std::string> received();

 private:
  void serve();
  std::vector<EndpointStep> script_;
  bool close_at_end_;
  int listen_fd_ = -1;
  std::string dir_;
  std::string address_;
  std::vector<std::string> received_;
  std::thread thread_;
};

}  // namespace canbridge::test
