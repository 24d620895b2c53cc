#include "tests/support/rig_processes.hpp"

#include <gtest/gtest.h>
#include <stdlib.h>

#include <cerrno>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <iterator>
#include <regex>
#include <system_error>

#include "tools/link_emulator/command_line.hpp"

namespace canbridge::test {
namespace {

std::string make_temp_dir() {
  std::string path = ::testing::TempDir() + "rig_processes.XXXXXX";
  if (::mkdtemp(path.data()) == nullptr) {
    throw std::system_error(errno, std::system_category(), "mkdtemp " + path);
  }
  return path;
}

}  // namespace

void RigProcesses::start() {
  const RigOptions& o = options_;
  dir_ = make_temp_dir();
  surface = std::make_unique<ChildProcess>(
      std::vector<std::string>{o.canbridge, "surface", "--config", o.config_dir + "surface.yaml"});
  ASSERT_TRUE(surface->wait_for_line("listening on 127.0.0.1:", o.event_timeout))
      << surface->output();
  std::smatch port;
  const std::string out = surface->output();
  ASSERT_TRUE(std::regex_search(out, port, std::regex("listening on 127\\.0\\.0\\.1:([0-9]+)")))
      << out;
  std::string gateway_port = port[1].str();

  if (!o.link_emulator.empty()) {
    std::vector<std::string> argv{o.link_emulator, "--a", "tcp-listen:127.0.0.1:0", "--b",
                                  "tcp-connect:127.0.0.1:" + gateway_port};
    argv.insert(argv.end(), o.link_emulator_args.begin(), o.link_emulator_args.end());
    emulator = std::make_unique<ChildProcess>(argv);
    ASSERT_TRUE(emulator->wait_for_line("link-emulator: ready", o.event_timeout))
        << emulator->output();
    emulator_ready = std::chrono::steady_clock::now();
    const auto ready = canbridge::emulator::find_ready_line(emulator->output());
    ASSERT_TRUE(ready) << emulator->output();
    const auto link_port = canbridge::emulator::endpoint_port(ready->a);
    ASSERT_TRUE(link_port) << ready->a;
    gateway_port = std::to_string(*link_port);
  }

  // gateway.yaml with the port the gateway connects to in place of the placeholder.
  std::ifstream in(o.config_dir + "gateway.yaml");
  std::string config((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  const std::string placeholder = "127.0.0.1:" + o.port_placeholder;
  const auto at = config.find(placeholder);
  ASSERT_NE(at, std::string::npos) << "gateway.yaml lost its " << placeholder;
  config.replace(at, placeholder.size(), "127.0.0.1:" + gateway_port);
  std::ofstream(dir_ + "/gateway.yaml") << config;
  ASSERT_NO_FATAL_FAILURE(start_gateway());

  sim = std::make_unique<ChildProcess>(
      std::vector<std::string>{o.sim, o.config_dir + "rig.yaml", "--stats-seconds", "0"});
  ASSERT_TRUE(sim->wait_for_line("canbridge-sim: " + o.sim_ready, o.event_timeout))
      << sim->output();
  if (emulator) {
    const auto since = std::chrono::steady_clock::now() - emulator_ready;
    std::cout << "[  rig     ] all processes ready "
              << std::chrono::duration_cast<std::chrono::milliseconds>(since).count()
              << " ms after the emulator\n";
  }
}

void RigProcesses::start_gateway() {
  const RigOptions& o = options_;
  gateway = std::make_unique<ChildProcess>(
      std::vector<std::string>{o.canbridge, "gateway", "--config", dir_ + "/gateway.yaml"});
  ASSERT_TRUE(gateway->wait_for_line("surface '" + o.surface_name + "' ready", o.event_timeout))
      << gateway->output() << surface->output() << (emulator ? emulator->output() : "");
  ASSERT_TRUE(surface->wait_for_line("gateway '" + o.gateway_name + "' ready", o.event_timeout))
      << surface->output();
}

void RigProcesses::restart_gateway() {
  if (gateway) logs_ += "--- gateway (before its restart)\n" + gateway->output();
  ASSERT_NO_FATAL_FAILURE(start_gateway());
}

void RigProcesses::expect_running() const {
  for (const auto* p : {&surface, &emulator, &gateway, &sim}) {
    if (p == &emulator && options_.link_emulator.empty()) continue;
    ASSERT_TRUE(*p) << "not started";
    ASSERT_FALSE((*p)->finished()) << (*p)->output();
  }
}

void RigProcesses::stop() {
  const auto stop_one = [this](std::unique_ptr<ChildProcess>& p, const char* name,
                               std::string& last) {
    if (!p) return;
    EXPECT_EQ(p->stop(), 0) << name << ":\n" << p->output();
    last = last_line(p->output());
    logs_ += std::string("--- ") + name + "\n" + p->output();
    p.reset();
  };
  std::string ignored;
  stop_one(sim, "canbridge-sim", ignored);
  stop_one(gateway, "gateway", gateway_final);
  stop_one(surface, "surface", surface_final);
  stop_one(emulator, "link emulator", ignored);
  if (!dir_.empty()) std::filesystem::remove_all(dir_);
  dir_.clear();
}

void RigProcesses::print_logs(bool failed) const {
  const char* show = std::getenv("CANBRIDGE_SHOW_LOGS");
  if (failed || (show != nullptr && std::string(show) == "1")) std::cout << logs_;
}

}  // namespace canbridge::test
