// Startup input with a system limit is refused at load, promptly and with file, line and field:
// config files that are no regular file of at most 1 MiB (/dev/zero, a FIFO, a huge file), and
// fields the kernel would refuse only later (interface names, paths, Unix socket paths, ports).
#include <gtest/gtest.h>
#include <sys/stat.h>
#include <unistd.h>

#include <chrono>
#include <fstream>
#include <sstream>
#include <string>

#include "app/cli_main.hpp"
#include "app/cli_reply.hpp"
#include "config/loader.hpp"
#include "sim/rig_file.hpp"
#include "tests/config/fixtures.hpp"
#include "tests/support/config_problems.hpp"
#include "tests/support/process.hpp"
#include "tests/support/temp_key_dir.hpp"
#include "yaml/yaml_reader.hpp"

namespace canbridge::config {
namespace {

using test::dump;
using test::has;
using test::kConfigFixtures;
using test::problems_of;

// A bound, not a wait: reading a bad file must not take the time of reading it.
constexpr auto kPromptly = std::chrono::milliseconds(100);

// The one problem `load` throws, and how long `load` took to throw it.
struct Refusal {
  std::vector<ConfigProblem> problems;
  std::chrono::steady_clock::duration took{};
};

Refusal refusal_of(auto&& load) {
  const auto start = std::chrono::steady_clock::now();
  Refusal r;
  r.problems = problems_of(load);
  r.took = std::chrono::steady_clock::now() - start;
  return r;
}

std::string write_file(const test::TempKeyDir& dir, const std::string& name,
                       const std::string& text) {
  const std::string path = dir.path() + "/" + name;
  std::ofstream(path, std::ios::binary) << text;
  return path;
}

void expect_file_refused(const Refusal& r, const std::string& path, const std::string& what) {
  ASSERT_EQ(r.problems.size(), 1u) << dump(r.problems);
  EXPECT_EQ(r.problems[0].file, path);
  EXPECT_NE(r.problems[0].message.find(what), std::string::npos) << dump(r.problems);
  // Every refusal names the limit, so the operator knows what a good file is.
  EXPECT_NE(r.problems[0].message.find("regular file of at most 1 MiB (1048576 bytes)"),
            std::string::npos)
      << dump(r.problems);
  EXPECT_LT(r.took, kPromptly) << dump(r.problems);
}

TEST(BoundedInput, DevZeroIsRefusedAtOnceNotReadUntilMemoryRunsOut) {
  const Refusal surface = refusal_of([] { load_surface("/dev/zero"); });
  expect_file_refused(surface, "/dev/zero", "is a character device");
  const Refusal gateway = refusal_of([] { load_gateway("/dev/zero"); });
  expect_file_refused(gateway, "/dev/zero", "is a character device");
  const Refusal rig = refusal_of([] { sim::load_rig("/dev/zero"); });
  expect_file_refused(rig, "/dev/zero", "is a character device");
}

TEST(BoundedInput, AFifoIsRefusedWithoutWaitingForAWriter) {
  test::TempKeyDir dir;
  const std::string fifo = dir.path() + "/surface.yaml";
  ASSERT_EQ(::mkfifo(fifo.c_str(), 0600), 0);
  const Refusal r = refusal_of([&] { load_surface(fifo); });
  expect_file_refused(r, fifo, "is a FIFO");
}

TEST(BoundedInput, AHundredMegabyteFileIsRefusedWithoutBeingRead) {
  test::TempKeyDir dir;
  const std::string big = write_file(dir, "gateway.yaml", "role: gateway\n");
  ASSERT_EQ(::truncate(big.c_str(), 100'000'000), 0);  // sparse: no disk, no time
  const Refusal r = refusal_of([&] { load_gateway(big); });
  expect_file_refused(r, big, "is 100000000 bytes");
}

TEST(BoundedInput, ADirectoryIsRefused) {
  test::TempKeyDir dir;
  const Refusal r = refusal_of([&] { load_surface(dir.path()); });
  expect_file_refused(r, dir.path(), "is a directory");
}

TEST(BoundedInput, OneMebibyteIsReadAndOneByteMoreIsRefused) {
  test::TempKeyDir dir;
  const std::string limit = write_file(dir, "limit.yaml", std::string(kMaxConfigFileBytes, '#'));
  EXPECT_EQ(read_config_file(limit).size(), kMaxConfigFileBytes);
  const std::string over = write_file(dir, "over.yaml", std::string(kMaxConfigFileBytes + 1, '#'));
  const Refusal r = refusal_of([&] { read_config_file(over); });
  expect_file_refused(r, over, "is 1048577 bytes");
}

// The roles keep their config's text for as long as they run (a reload reports what changed): it
// must cost what the file holds, not the 1 MiB bound (issue 29: the gateway's own memory).
TEST(BoundedInput, TheTextReadKeepsNoRoomForTheBound) {
  test::TempKeyDir dir;
  const std::string sample(3000, '#');
  const std::string text = read_config_file(write_file(dir, "small.yaml", sample));
  EXPECT_EQ(text, sample);
  EXPECT_LT(text.capacity(), 2 * sample.size());
  // Longer than one read's chunk, still exactly what the file holds.
  const std::string longer(100 * 1024 + 7, '#');
  EXPECT_EQ(read_config_file(write_file(dir, "longer.yaml", longer)), longer);
}

TEST(BoundedInput, AMissingFileSaysWhy) {
  const auto ps = problems_of([] { load_surface("/nonexistent/surface.yaml"); });
  ASSERT_EQ(ps.size(), 1u);
  EXPECT_EQ(ps[0].message, "cannot open the file: No such file or directory");
}

// The tester's case: a 16-byte bus failed only when the interface was opened ("Invalid
// argument", no file or line).
TEST(BoundedInput, ASixteenByteInterfaceNameIsRefusedAtItsLine) {
  test::TempKeyDir dir;
  const std::string path = write_file(dir, "surface.yaml",
                                      "role: surface\n"
                                      "bus: canbridge_vcan16\n"
                                      "backbone: {listen: 127.0.0.1:7000, auth: {mode: plain}}\n"
                                      "gateways: [{name: gateway, modules: [1]}]\n");
  const Refusal r = refusal_of([&] { load_surface(path); });
  ASSERT_EQ(r.problems.size(), 1u) << dump(r.problems);
  EXPECT_TRUE(has(r.problems, 2, "bus",
                  "'canbridge_vcan16' is 16 bytes: SocketCAN interface names are at most 15 "
                  "characters (IFNAMSIZ - 1)"))
      << dump(r.problems);
  EXPECT_EQ(r.problems[0].file, path);
  EXPECT_LT(r.took, kPromptly);
  // Fifteen bytes is the limit, not beyond it.
  const auto fifteen = parse_surface(
      "role: surface\nbus: canbridge_vcan1\n"
      "backbone: {listen: 127.0.0.1:7000, auth: {mode: plain}}\n"
      "gateways: [{name: gateway, modules: [1]}]\n",
      "fifteen.yaml");
  EXPECT_EQ(fifteen.bus, "canbridge_vcan1");
}

TEST(BoundedInput, EverySystemLimitOfAGatewayIsReportedAtOnce) {
  const auto ps = problems_of([] { load_gateway(kConfigFixtures + "gateway_system_limits.yaml"); });
  const std::string all = dump(ps);
  EXPECT_EQ(ps.size(), 4u) << all;
  EXPECT_TRUE(has(ps, 4, "backbone.connect", "port '65536' must be 0..65535")) << all;
  EXPECT_TRUE(has(ps, 7, "modules[0].bus", "is 16 bytes: SocketCAN interface names are at most 15"))
      << all;
  EXPECT_TRUE(has(ps, 9, "modules[1].bus", "'vcan 2' is no interface name the kernel takes"))
      << all;
  EXPECT_TRUE(has(ps, 10, "stats_endpoint", "longer than a Unix socket path may be (107 bytes)"))
      << all;
}

TEST(BoundedInput, EverySystemLimitOfASurfaceIsReportedAtOnce) {
  const auto ps = problems_of([] { load_surface(kConfigFixtures + "surface_system_limits.yaml"); });
  const std::string all = dump(ps);
  EXPECT_EQ(ps.size(), 2u) << all;
  EXPECT_TRUE(has(ps, 2, "bus",
                  "'a_forty_character_interface_name_xxxxxxx' is 40 bytes: SocketCAN interface "
                  "names are at most 15"))
      << all;
  EXPECT_TRUE(has(ps, 5, "backbone.listen", "port '70000' must be 0..65535")) << all;
}

TEST(BoundedInput, InterfaceNamesTheKernelRefusesAreRefusedAtLoad) {
  for (const std::string bus : {"\".\"", "\"..\"", "can/1", "\"can:1\"", "\"can\\0\""}) {
    const auto ps = problems_of([&] {
      parse_gateway(
          "role: gateway\nbackbone: {connect: 127.0.0.1:7000, auth: {mode: plain}}\n"
          "modules: [{id: 1, bus: " +
              bus + "}]\n",
          "g.yaml");
    });
    EXPECT_TRUE(has(ps, 3, "modules[0].bus", "is no interface name the kernel takes"))
        << bus << "\n"
        << dump(ps);
  }
}

TEST(BoundedInput, PathsBeyondPathMaxOrWithANulAreRefusedAtLoad) {
  const std::string head = "role: gateway\nbackbone:\n  auth: {mode: plain}\n  serial: {device: ";
  const std::string tail = "}\nmodules: [{id: 1, bus: vcan1}]\n";
  const std::string longest = "/" + std::string(kMaxPathBytes - 1, 'd');
  EXPECT_EQ(parse_gateway(head + longest + tail, "g.yaml").serial->device, longest);
  const auto too_long = problems_of([&] { parse_gateway(head + longest + "d" + tail, "g.yaml"); });
  EXPECT_TRUE(has(too_long, 4, "backbone.serial.device",
                  "is 4096 bytes: paths are at most 4095 (PATH_MAX - 1)"))
      << dump(too_long);
  const auto nul = problems_of([&] { parse_gateway(head + "\"/dev/tty\\0S1\"" + tail, "g.yaml"); });
  EXPECT_TRUE(has(nul, 4, "backbone.serial.device", "contains a NUL byte")) << dump(nul);
}

// The other files a config names are read at load too: a FIFO or a device there must not hold
// startup either. Each refusal names the field's line.
TEST(BoundedInput, KeyTokenAndCertificateFilesThatAreNoRegularFilesAreRefusedPromptly) {
  test::TempKeyDir dir;
  const std::string fifo = dir.path() + "/fifo";
  ASSERT_EQ(::mkfifo(fifo.c_str(), 0600), 0);
  const Refusal key = refusal_of([&] {
    parse_gateway(
        "role: gateway\nbackbone:\n  connect: 10.0.0.1:7000\n"
        "  auth: {mode: psk, key_file: " +
            fifo + "}\nmodules: [{id: 1, bus: vcan1}]\n",
        "g.yaml");
  });
  EXPECT_TRUE(has(key.problems, 4, "backbone.auth.key_file", "not a regular file"))
      << dump(key.problems);
  EXPECT_LT(key.took, kPromptly);
  const Refusal token = refusal_of([&] {
    parse_surface(
        "role: surface\nbus: vcan0\n"
        "backbone: {listen: 127.0.0.1:7000, auth: {mode: plain}}\n"
        "gateways: [{name: gateway, modules: [1]}]\n"
        "command_endpoint:\n  tcp_port: 7001\n"
        "  clients: [{name: op, role: control, token_file: " +
            fifo + "}]\n",
        "s.yaml");
  });
  EXPECT_TRUE(has(token.problems, 7, "command_endpoint.clients[0].token_file", "regular file"))
      << dump(token.problems);
  EXPECT_LT(token.took, kPromptly);
  const std::string key_pem = dir.key("surface.key.pem");
  const std::string crt = write_file(dir, "surface.crt", "-----BEGIN CERTIFICATE-----\n");
  const Refusal ca = refusal_of([&] {
    parse_surface(
        "role: surface\nbus: vcan0\nbackbone:\n  listen: 0.0.0.0:7000\n"
        "  auth: {mode: certificates, certificate: " +
            crt + ", private_key: " + key_pem +
            ", ca: /dev/zero}\ngateways: [{name: tool, modules: [1]}]\n",
        "s.yaml");
  });
  EXPECT_TRUE(
      has(ca.problems, 5, "backbone.auth.ca", "/dev/zero: must be a regular file of at most 1 MiB"))
      << dump(ca.problems);
  EXPECT_LT(ca.took, kPromptly);
}

// The CLI reads -c for its command endpoint: through the same bounds.
TEST(BoundedInput, TheCliRefusesDevZeroAsItsConfig) {
  std::ostringstream out;
  std::ostringstream err;
  const auto start = std::chrono::steady_clock::now();
  const int exit = cli::run_client({"nodes", "-c", "/dev/zero"}, out, err, false);
  EXPECT_LT(std::chrono::steady_clock::now() - start, kPromptly);
  EXPECT_EQ(exit, cli::exit_code::usage);
  EXPECT_NE(err.str().find("/dev/zero: is a character device: a configuration file must be a "
                           "regular file of at most 1 MiB"),
            std::string::npos)
      << err.str();
}

// The tester's command, through the real program: exit 2 with the message, not 2.9 GB.
TEST(BoundedInput, CanbridgeSurfaceWithDevZeroExitsTwoPromptly) {
  const auto start = std::chrono::steady_clock::now();
  const test::RunResult r = test::run({CANBRIDGE_BIN, "surface", "--config", "/dev/zero"},
                                      std::chrono::milliseconds(10000));
  const auto took = std::chrono::steady_clock::now() - start;
  EXPECT_EQ(r.status, 2) << r.output;
  EXPECT_NE(r.output.find("/dev/zero: is a character device"), std::string::npos) << r.output;
  // Loose enough for a loaded machine's process start; a read of /dev/zero would meet the
  // 10-second kill instead.
  EXPECT_LT(took, std::chrono::seconds(3)) << r.output;
}

}  // namespace
}  // namespace canbridge::config
