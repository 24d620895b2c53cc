#include "app/cli_session.hpp"

#include <yaml-cpp/yaml.h>

#include <fstream>
#include <ostream>

#include "app/cli_reply.hpp"
#include "config/loader.hpp"

namespace canbridge::cli {

std::string resolve_endpoint(const CommonOptions& options, std::string& problem) {
  if (!options.endpoint.empty()) return options.endpoint;
  if (options.config.empty()) return kDefaultEndpoint;
  try {
    // Only the endpoint's keys: the client must not need the rest of a valid configuration.
    // Read through the loader's bounds, so that -c /dev/zero is refused, not read forever.
    const YAML::Node root = YAML::Load(config::read_config_text(options.config));
    const bool gateway = root.IsMap() && root["role"] && root["role"].IsScalar() &&
                         root["role"].as<std::string>() == "gateway";
    if (gateway) {
      // A gateway has no command endpoint; `stats` reads its stats_endpoint.
      const YAML::Node stats = root["stats_endpoint"];
      if (options.stats && stats && stats.IsScalar() && !stats.as<std::string>().empty()) {
        return stats.as<std::string>();
      }
      problem = options.config + " is a gateway's configuration: " +
                (options.stats ? std::string("it sets no stats_endpoint; set one or give "
                                             "--endpoint")
                               : std::string("operator commands go to a surface's command "
                                             "endpoint; give the surface's file or --endpoint"));
      return {};
    }
    const YAML::Node endpoint = root.IsMap() ? root["command_endpoint"] : YAML::Node();
    const YAML::Node socket = endpoint && endpoint.IsMap() ? endpoint["unix_socket"] : YAML::Node();
    if (!socket) return kDefaultEndpoint;  // the surface's default too
    const std::string path = socket.as<std::string>();
    if (path.empty()) {
      problem = options.config + ": command_endpoint.unix_socket is \"\" (no Unix socket); " +
                "give --endpoint HOST:PORT";
    }
    return path;
  } catch (const YAML::Exception& e) {
    problem = options.config + ": " + e.what();
    return {};
  } catch (const config::ConfigError& e) {
    problem = e.problems().front().to_string();
    return {};
  }
}

namespace {

std::string read_token(const std::string& file, std::string& problem) {
  std::ifstream in(file);
  std::string token;
  if (!in || !std::getline(in, token)) {
    problem = "cannot read the token file " + file;
    return {};
  }
  while (!token.empty() && (token.back() == '\r' || token.back() == ' ')) token.pop_back();
  return token;
}

}  // namespace

std::unique_ptr<Session> Session::open(const CommonOptions& options, Io io, int& exit) {
  std::string problem;
  const std::string endpoint = resolve_endpoint(options, problem);
  if (!problem.empty()) {
    io.err << "canbridge: " << problem << "\n";
    exit = exit_code::usage;
    return nullptr;
  }
  const EndpointAddress address = parse_endpoint(endpoint);
  std::string token;
  if (!options.token_file.empty()) {
    token = read_token(options.token_file, problem);
    if (!problem.empty()) {
      io.err << "canbridge: " << problem << "\n";
      exit = exit_code::usage;
      return nullptr;
    }
  }
  std::error_code ec;
  auto connection = EndpointConnection::open(address, ec);
  if (!connection) {
    io.err << "canbridge: cannot connect to the command endpoint " << endpoint << ": "
           << ec.message() << (address.tcp ? "" : " (is the surface running? see --endpoint, -c)")
           << "\n";
    exit = exit_code::unreachable;
    return nullptr;
  }
  const auto timeout = std::chrono::milliseconds(static_cast<long long>(options.timeout_s * 1000));
  std::unique_ptr<Session> session(new Session(std::move(connection), io, endpoint, timeout));
  if (address.tcp && !token.empty()) {
    std::string answer;
    exit = session->call("auth " + token, answer);
    if (exit != exit_code::ok) return nullptr;
  }
  exit = exit_code::ok;
  return session;
}

int Session::report_read_error(std::error_code ec) {
  if (ec == std::errc::timed_out) {
    io_.err << "canbridge: no answer from " << endpoint_ << " within " << timeout_.count()
            << " ms\n";
    return exit_code::timeout;
  }
  if (ec == std::errc::interrupted) return exit_code::ok;  // the operator stopped us
  io_.err << "canbridge: the command endpoint " << endpoint_
          << (ec == std::errc::connection_reset ? " closed the connection"
                                                : " failed: " + ec.message())
          << "\n";
  return exit_code::unreachable;
}

int Session::call(std::string_view command, std::string& answer, const LineHandler& intermediate,
                  std::chrono::milliseconds timeout) {
  const unsigned seq = next_seq_++;
  if (timeout.count() <= 0) timeout = timeout_;
  if (auto ec = connection_->send_line("[" + std::to_string(seq) + "] " + std::string(command))) {
    return report_read_error(ec);
  }
  std::string line;
  for (;;) {
    if (auto ec = connection_->read_line(line, timeout)) return report_read_error(ec);
    const auto rest = answer_to(line, seq);
    if (!rest) {
      // An unnumbered error is the endpoint refusing before it parsed us (e.g. 401 on TCP).
      if (auto error = parse_error(line)) {
        io_.err << "canbridge: " << describe(*error)
                << (error->code == 401 && !error->sdo_abort ? " (give --token-file)" : "") << "\n";
        return exit_code_for(*error);
      }
      continue;
    }
    if (auto error = parse_error(*rest)) {
      io_.err << "canbridge: " << describe(*error) << "\n";
      return exit_code_for(*error);
    }
    if (intermediate && intermediate(*rest)) continue;
    answer = std::string(*rest);
    return exit_code::ok;
  }
}

}  // namespace canbridge::cli
