// The sd_notify path of real canbridge processes, as systemd would see it: the test owns the
// notify sockets and sets NOTIFY_SOCKET and WATCHDOG_USEC=200000 (keep-alives every 100 ms) in
// each child's environment. READY=1 comes once the role is listening (the test connects right
// then) or connecting, keep-alives follow, a SIGSTOPped process sends none and resumes after
// SIGCONT, and SIGTERM brings STOPPING=1 before a clean exit.
#include <arpa/inet.h>
#include <gtest/gtest.h>
#include <netinet/in.h>
#include <signal.h>
#include <sys/socket.h>
#include <sys/un.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cstdlib>
#include <cstring>
#include <fstream>
#include <memory>
#include <regex>

#include "tests/support/notify_listener.hpp"
#include "tests/support/process.hpp"
#include "tests/support/temp_key_dir.hpp"

namespace canbridge {
namespace {

using namespace std::chrono_literals;
using test::ChildProcess;
using test::NotifyListener;

constexpr auto kWatchdogTimeout = 200ms;  // WATCHDOG_USEC; keep-alives every 100 ms
constexpr auto kEvent = 10s;              // upper bound of every awaited step

// In a directory of this process's own: the rig's guests share the host's /tmp, and tests that
// run at the same time must not read each other's configs.
std::string write_file(const std::string& name, const std::string& text) {
  static test::TempKeyDir dir;
  return dir.file(name, text, 0644);
}

// A canbridge role whose service manager is `listener`.
std::unique_ptr<ChildProcess> start_role(const std::string& role, const std::string& config,
                                         const NotifyListener& listener) {
  ::setenv("NOTIFY_SOCKET", listener.address().c_str(), 1);
  ::setenv("WATCHDOG_USEC", std::to_string(kWatchdogTimeout.count() * 1000).c_str(), 1);
  auto child = std::make_unique<ChildProcess>(
      std::vector<std::string>{CANBRIDGE_BIN, role, "--config", config});
  ::unsetenv("NOTIFY_SOCKET");
  ::unsetenv("WATCHDOG_USEC");
  return child;
}

// The next message that starts with `prefix`, or "" when none came in time.
std::string await_message(NotifyListener& listener, const std::string& prefix) {
  const auto deadline = std::chrono::steady_clock::now() + kEvent;
  while (std::chrono::steady_clock::now() < deadline) {
    auto m = listener.receive(std::chrono::duration_cast<std::chrono::milliseconds>(
        deadline - std::chrono::steady_clock::now()));
    if (!m) break;
    if (m->rfind(prefix, 0) == 0) return *m;
  }
  return "";
}

bool connects_tcp(int port) {
  const int fd = ::socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
  sockaddr_in a{};
  a.sin_family = AF_INET;
  a.sin_port = htons(static_cast<std::uint16_t>(port));
  a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  const bool ok = ::connect(fd, reinterpret_cast<const sockaddr*>(&a), sizeof a) == 0;
  ::close(fd);
  return ok;
}

bool connects_unix(const std::string& path) {
  const int fd = ::socket(AF_UNIX, SOCK_STREAM | SOCK_CLOEXEC, 0);
  sockaddr_un a{};
  a.sun_family = AF_UNIX;
  std::strncpy(a.sun_path, path.c_str(), sizeof a.sun_path - 1);
  const bool ok = ::connect(fd, reinterpret_cast<const sockaddr*>(&a), sizeof a) == 0;
  ::close(fd);
  return ok;
}

std::string surface_config() {
  return write_file("surface.yaml",
                    "role: surface\nname: svc-surface\nbus: vcan0\nbackbone:\n"
                    "  listen: 127.0.0.1:0\n  auth: {mode: plain}\n"
                    "gateways: [{name: svc-gateway, modules: [1]}]\n"
                    "command_endpoint:\n  unix_socket: " +
                        ::testing::TempDir() +
                        "svc-surface.sock\n"
                        "log: {level: info, stats_interval_s: 0}\n");
}

// The port the surface logged it listens on (port 0 in the config: the kernel picked it).
int listening_port(ChildProcess& surface) {
  if (!surface.wait_for_line("listening on 127.0.0.1:", kEvent)) return -1;
  std::smatch m;
  const std::string out = surface.output();
  if (!std::regex_search(out, m, std::regex("listening on 127\\.0\\.0\\.1:([0-9]+)"))) return -1;
  return std::stoi(m[1].str());
}

TEST(ServiceNotify, ReadyOnceListeningOrConnectingThenKeepAlivesThenStopping) {
  NotifyListener surface_manager(::testing::TempDir() + "surface.notify");
  NotifyListener gateway_manager("@canbridge-svc-gateway-" + std::to_string(::getpid()));

  auto surface = start_role("surface", surface_config(), surface_manager);
  const std::string ready = await_message(surface_manager, "READY=1");
  ASSERT_EQ(ready, "READY=1\nSTATUS=surface svc-surface: bus vcan0 open, backbone listening")
      << surface->output();
  // Ready means ready: the listener accepts and the command endpoint answers right now.
  const int port = listening_port(*surface);
  ASSERT_GT(port, 0) << surface->output();
  EXPECT_TRUE(connects_tcp(port));
  EXPECT_TRUE(connects_unix(::testing::TempDir() + "svc-surface.sock"));

  const std::string gateway_cfg = write_file(
      "gateway.yaml",
      "role: gateway\nname: svc-gateway\nbackbone:\n  connect: 127.0.0.1:" + std::to_string(port) +
          "\n  auth: {mode: plain}\n  reconnect_min_ms: 20\n"
          "modules:\n  - {id: 1, bus: vcan1}\n"
          "log: {level: info, stats_interval_s: 0}\n");
  auto gateway = start_role("gateway", gateway_cfg, gateway_manager);
  EXPECT_EQ(await_message(gateway_manager, "READY=1"),
            "READY=1\nSTATUS=gateway svc-gateway: 1 module(s) open, backbone connecting")
      << gateway->output();
  ASSERT_TRUE(surface->wait_for_line("gateway 'svc-gateway' ready", kEvent)) << surface->output();

  // Keep-alives from both, every 100 ms.
  for (NotifyListener* manager : {&surface_manager, &gateway_manager}) {
    EXPECT_TRUE(manager->wait_for("WATCHDOG=1", kEvent));
    EXPECT_TRUE(manager->wait_for("WATCHDOG=1", kEvent));
  }

  ::kill(gateway->pid(), SIGTERM);
  EXPECT_EQ(await_message(gateway_manager, "STOPPING=1"), "STOPPING=1\nSTATUS=stopping");
  EXPECT_EQ(gateway->wait(kEvent), 0) << gateway->output();
  ::kill(surface->pid(), SIGTERM);
  EXPECT_EQ(await_message(surface_manager, "STOPPING=1"), "STOPPING=1\nSTATUS=stopping");
  EXPECT_EQ(surface->wait(kEvent), 0) << surface->output();
  // Nothing after STOPPING: systemd no longer expects keep-alives.
  EXPECT_EQ(surface_manager.drain(), 0);
}

TEST(ServiceNotify, AStoppedProcessStopsPettingAndResumesWhenContinued) {
  NotifyListener manager("@canbridge-svc-surface-" + std::to_string(::getpid()));
  auto surface = start_role("surface", surface_config(), manager);
  ASSERT_NE(await_message(manager, "READY=1"), "") << surface->output();
  ASSERT_TRUE(manager.wait_for("WATCHDOG=1", kEvent));

  ASSERT_EQ(::kill(surface->pid(), SIGSTOP), 0);
  siginfo_t info{};
  ASSERT_EQ(::waitid(P_PID, static_cast<id_t>(surface->pid()), &info, WSTOPPED), 0);
  manager.drain();  // what it sent before it stopped
  // Two watchdog timeouts without a keep-alive: systemd would have killed it.
  EXPECT_EQ(manager.receive(2 * kWatchdogTimeout), std::nullopt);

  ASSERT_EQ(::kill(surface->pid(), SIGCONT), 0);
  EXPECT_TRUE(manager.wait_for("WATCHDOG=1", kEvent));
  EXPECT_EQ(surface->stop(), 0) << surface->output();
}

}  // namespace
}  // namespace canbridge
