#include "config/remote_access_reader.hpp"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstring>
#include <map>
#include <set>
#include <string_view>

#include "backbone/pre_shared_keys.hpp"
#include "config/backbone_auth_reader.hpp"

namespace canbridge::config {

namespace {

// A token shorter than this is guessable: `openssl rand -hex 32` writes 64 characters.
constexpr std::size_t kMinTokenChars = 16;
constexpr std::size_t kMaxTokenFileBytes = 4096;
// sockaddr_un::sun_path holds 108 bytes, the terminating zero included.
constexpr std::size_t kMaxSocketPath = 107;

std::string_view trimmed(std::string_view s) {
  const auto first = s.find_first_not_of(" \t\r");
  if (first == std::string_view::npos) return {};
  const auto last = s.find_last_not_of(" \t\r");
  return s.substr(first, last - first + 1);
}

void read_client(YamlReader& in, const YAML::Node& item, const std::string& path,
                 bridge::CommandEndpointOptions& out, std::map<std::string, std::string>& tokens) {
  if (!item.IsMap()) {
    return in.problem(item, path, "must be a mapping with name, role and token_file");
  }
  in.only_keys(item, path, {"name", "role", "token_file"});
  bridge::EndpointClient client;
  bool ok = true;
  if (auto name = in.string(item, "name", path, true)) {
    client.name = *name;
    const bool taken =
        std::any_of(out.clients.begin(), out.clients.end(),
                    [&](const bridge::EndpointClient& c) { return c.name == *name; });
    if (name->empty()) {
      in.problem(item["name"], path + ".name", "must not be empty");
      ok = false;
    } else if (taken) {
      in.problem(item["name"], path + ".name", "'" + *name + "' is the name of another client");
      ok = false;
    }
  } else {
    ok = false;
  }
  if (auto role = in.string(item, "role", path, true)) {
    if (*role == "control") {
      client.role = bridge::EndpointRole::control;
    } else if (*role != "monitor") {
      in.problem(item["role"], path + ".role",
                 "'" + *role +
                     "' is not one of monitor (nodes, dump, capture, reads), control "
                     "(also writes, NMT, flash, LSS, set-node-id)");
      ok = false;
    }
  } else {
    ok = false;
  }
  const auto file = in.file_path(item, "token_file", path, true);
  if (file) {
    TokenFileResult token = read_token_file(*file);
    if (!token.problem.empty()) {
      in.problem(item["token_file"], path + ".token_file", token.problem);
      ok = false;
    }
    client.token = std::move(token.token);
  }
  if (!file || !ok) return;
  // One token, two clients: which role a session gets would be anyone's guess.
  if (auto [it, fresh] = tokens.emplace(client.token, client.name); !fresh) {
    return in.problem(item["token_file"], path + ".token_file",
                      *file + ": the same token as client '" + it->second + "'");
  }
  out.clients.push_back(std::move(client));
}

void read_command_endpoint(YamlReader& in, const YAML::Node& root,
                           bridge::CommandEndpointOptions& out) {
  const YAML::Node block = root["command_endpoint"];
  if (!block) return;
  const std::string p = "command_endpoint";
  if (!block.IsMap()) {
    return in.problem(block, p,
                      "must be a mapping, e.g. {unix_socket: /run/canbridge/surface.sock} ({} for "
                      "the defaults)");
  }
  in.only_keys(block, p,
               {"unix_socket", "tcp_port", "tcp_address", "sdo_timeout_ms", "sdo_block",
                "error_detail", "clients", "max_clients", "monitor_queue_frames"});
  if (auto socket = in.string(block, "unix_socket", p, false)) {
    if (!socket->empty() && socket->front() != '/') {
      in.problem(block["unix_socket"], p + ".unix_socket",
                 "'" + *socket + "' must be an absolute path (or \"\" for no Unix socket)");
    } else if (socket->size() > kMaxSocketPath) {
      in.problem(
          block["unix_socket"], p + ".unix_socket",
          "longer than a Unix socket path may be (" + std::to_string(kMaxSocketPath) + " bytes)");
    } else {
      out.unix_socket = *socket;
    }
  }
  if (auto port = in.integer(block, "tcp_port", p, 0, 65535)) {
    out.tcp_port = static_cast<std::uint16_t>(*port);
  }
  if (auto address = in.string(block, "tcp_address", p, false)) {
    // Tokens travel in clear text: the endpoint never leaves the machine (docs/security.md).
    if (!is_loopback_host(*address)) {
      in.problem(block["tcp_address"], p + ".tcp_address",
                 "'" + *address +
                     "' is not a loopback address (127.0.0.0/8, ::1, localhost): the endpoint's "
                     "tokens and commands are not encrypted; reach it over ssh instead");
    } else {
      out.tcp_address = *address;
    }
  }
  if (auto v = in.integer(block, "sdo_timeout_ms", p, 1, 600000)) {
    out.sdo_timeout = std::chrono::milliseconds(*v);
  }
  if (auto v = in.boolean(block, "sdo_block", p)) out.sdo_block = *v;
  if (auto v = in.boolean(block, "error_detail", p)) out.error_detail = *v;
  if (auto v = in.integer(block, "max_clients", p, 1, 1024)) {
    out.max_clients = static_cast<std::size_t>(*v);
  }
  if (auto v = in.integer(block, "monitor_queue_frames", p, 1, 1 << 22)) {
    out.monitor_queue_frames = static_cast<std::size_t>(*v);
  }
  std::map<std::string, std::string> tokens;  // token -> client name
  if (auto clients = in.list(block, "clients", p)) {
    for (std::size_t i = 0; i < clients->size(); ++i) {
      read_client(in, (*clients)[i], item_path(p, "clients", i), out, tokens);
    }
  }
  if (out.tcp_port != 0 && !block["clients"]) {
    in.problem(block["tcp_port"], p + ".tcp_port",
               "a TCP endpoint needs clients: (name, role, token_file): no one could "
               "authenticate");
  }
  if (out.unix_socket.empty() && out.tcp_port == 0 && block["unix_socket"]) {
    in.problem(block["unix_socket"], p + ".unix_socket",
               "\"\" and no tcp_port: the endpoint would listen nowhere (leave command_endpoint "
               "out instead)");
  }
}

// The networks the operator numbered: modules of configured gateways, each once, every module's
// effective number (listed, else module id + 1) unique.
void read_networks(YamlReader& in, const YAML::Node& root, SurfaceOptions& out) {
  auto list = in.list(root, "networks", "");
  std::set<std::uint32_t> modules;
  for (const AcceptedGatewayOptions& g : out.gateways) {
    modules.insert(g.modules.begin(), g.modules.end());
  }
  std::map<std::uint32_t, std::size_t> listed;  // module -> its item
  if (list) {
    for (std::size_t i = 0; i < list->size(); ++i) {
      const YAML::Node item = (*list)[i];
      const std::string path = item_path("", "networks", i);
      if (!item.IsMap()) {
        in.problem(item, path, "must be a mapping {module: <id>, net: <1..65535>}");
        continue;
      }
      in.only_keys(item, path, {"module", "net"});
      auto module = in.integer(item, "module", path, 0, 0xFFFFFFFELL, true);
      // 0 is the default network: the surface's own, addressed with surface node ids.
      auto net = in.integer(item, "net", path, 1, 65535, true);
      if (!module || !net) continue;
      const auto m = static_cast<std::uint32_t>(*module);
      if (!modules.contains(m)) {
        in.problem(
            item["module"], path + ".module",
            "module " + std::to_string(m) + " is not a module of any gateway under gateways");
        continue;
      }
      if (auto [it, fresh] = listed.emplace(m, i); !fresh) {
        in.problem(item["module"], path + ".module",
                   "module " + std::to_string(m) + " has its network in networks[" +
                       std::to_string(it->second) + "] already");
        continue;
      }
      out.remote.networks.emplace_back(m, static_cast<std::uint32_t>(*net));
    }
  }
  std::map<std::uint32_t, std::uint32_t> owner;  // net -> module
  for (std::uint32_t m : modules) {
    std::uint64_t net = std::uint64_t{m} + 1;
    for (const auto& [module, n] : out.remote.networks) {
      if (module == m) net = n;
    }
    // Reported at the item that numbers it (or the item that took the number from it), else at
    // the block or the file.
    const auto at_item = [&](std::uint32_t module) { return listed.find(module); };
    auto item = at_item(m);
    const auto problem = [&](const std::string& message) {
      if (item == listed.end()) {
        return in.problem(root["networks"] ? root["networks"] : root, "networks", message);
      }
      in.problem((*list)[item->second]["net"], item_path("", "networks", item->second) + ".net",
                 message);
    };
    if (net > 65535) {
      problem("module " + std::to_string(m) + "'s default network (module id + 1 = " +
              std::to_string(net) + ") is beyond 65535: give it one under networks");
      continue;
    }
    if (auto [it, fresh] = owner.emplace(static_cast<std::uint32_t>(net), m); !fresh) {
      if (item == listed.end()) item = at_item(it->second);
      problem("network " + std::to_string(net) + " would be both module " +
              std::to_string(it->second) + "'s and module " + std::to_string(m) +
              "'s (a module not listed has network module id + 1): give each its own");
    }
  }
}

}  // namespace

TokenFileResult read_token_file(const std::string& path) {
  // O_NONBLOCK: a FIFO opens at once and is refused as no regular file, instead of holding
  // startup until something writes to it.
  const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC | O_NONBLOCK | O_NOCTTY);
  if (fd < 0) {
    return {{},
            path + ": cannot be read (" + std::strerror(errno) +
                "; make one: (umask 077; openssl rand -hex 32 > FILE); docs/security.md)"};
  }
  struct stat status {};
  std::string text;
  std::string problem;
  if (::fstat(fd, &status) != 0) {
    problem = path + ": cannot be read (" + std::strerror(errno) + ")";
  } else if (auto p = backbone::check_key_file_permissions(status, ::geteuid(), path)) {
    problem = p->message;
  } else {
    char buffer[kMaxTokenFileBytes + 1];
    const ssize_t n = ::read(fd, buffer, sizeof buffer);
    if (n < 0) {
      problem = path + ": cannot be read (" + std::strerror(errno) + ")";
    } else if (static_cast<std::size_t>(n) > kMaxTokenFileBytes) {
      problem = path + ": longer than a token file may be (" + std::to_string(kMaxTokenFileBytes) +
                " bytes)";
    } else {
      text.assign(buffer, static_cast<std::size_t>(n));
    }
  }
  ::close(fd);
  if (!problem.empty()) return {{}, problem};
  std::string_view rest = text;
  while (!rest.empty()) {
    const auto end = rest.find('\n');
    const std::string_view line = trimmed(rest.substr(0, end));
    rest = end == std::string_view::npos ? std::string_view{} : rest.substr(end + 1);
    if (line.empty() || line.front() == '#') continue;
    if (line.size() < kMinTokenChars || line.find_first_of(" \t") != std::string_view::npos) {
      return {{},
              path + ": the token must be one word of at least " + std::to_string(kMinTokenChars) +
                  " characters (make one: (umask 077; openssl rand -hex 32 > FILE))"};
    }
    return {std::string(line), {}};
  }
  return {{}, path + ": holds no token (make one: (umask 077; openssl rand -hex 32 > FILE))"};
}

void read_surface_remote(YamlReader& in, const YAML::Node& root, SurfaceOptions& out) {
  if (root["command_endpoint"]) {
    out.command_endpoint.emplace();
    read_command_endpoint(in, root, *out.command_endpoint);
  }
  read_networks(in, root, out);
}

void read_gateway_remote(YamlReader& in, const YAML::Node& root,
                         bridge::GatewayRemoteOptions& out) {
  const YAML::Node block = root["remote"];
  if (!block) return;
  const std::string p = "remote";
  if (!block.IsMap()) {
    return in.problem(block, p,
                      "must be a mapping, e.g. {sdo_timeout_ms: 1000} ({} for the defaults)");
  }
  in.only_keys(block, p,
               {"sdo_timeout_ms", "flash_block_size", "flash_answer_timeout_ms", "boot_timeout_ms",
                "max_queued_per_node"});
  using std::chrono::milliseconds;
  if (auto v = in.integer(block, "sdo_timeout_ms", p, 1, 600000))
    out.sdo_timeout = milliseconds(*v);
  if (auto v = in.integer(block, "flash_block_size", p, 1, 127)) {
    out.flash_block_size = static_cast<std::uint8_t>(*v);
  }
  if (auto v = in.integer(block, "flash_answer_timeout_ms", p, 1, 600000)) {
    out.flash_answer_timeout = milliseconds(*v);
  }
  if (auto v = in.integer(block, "boot_timeout_ms", p, 1, 600000)) {
    out.boot_timeout = milliseconds(*v);
  }
  if (auto v = in.integer(block, "max_queued_per_node", p, 1, 65536)) {
    out.max_queued_per_node = static_cast<std::size_t>(*v);
  }
}

}  // namespace canbridge::config
