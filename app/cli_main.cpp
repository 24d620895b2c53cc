#include "app/cli_main.hpp"

#include <CLI/CLI.hpp>
#include <algorithm>
#include <array>
#include <charconv>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <optional>
#include <ostream>
#include <span>

#include "app/cli_monitor.hpp"
#include "app/cli_node_table.hpp"
#include "app/cli_progress.hpp"
#include "app/cli_reply.hpp"
#include "app/cli_session.hpp"
#include "canopen/ascii_value.hpp"
#include "logging/command_line_common.hpp"

namespace canbridge::cli {

namespace {

constexpr std::array<std::string_view, 8> kCommands = {"nodes", "sdo",  "nmt",     "set-node-id",
                                                       "flash", "dump", "capture", "stats"};

constexpr std::array<std::string_view, 19> kDatatypes = {
    "b",   "u8",  "u16", "u32", "u64", "i8", "i16", "i32", "i64", "x8",
    "x16", "x32", "x64", "r32", "r64", "vs", "os",  "us",  "d"};

std::optional<unsigned> parse_unsigned(std::string_view text, int base) {
  if (base == 16 && (text.substr(0, 2) == "0x" || text.substr(0, 2) == "0X")) text.remove_prefix(2);
  if (base == 0) {
    base = 10;
    if (text.substr(0, 2) == "0x" || text.substr(0, 2) == "0X") {
      text.remove_prefix(2);
      base = 16;
    }
  }
  unsigned value = 0;
  if (text.empty()) return std::nullopt;
  const auto [end, ec] = std::from_chars(text.data(), text.data() + text.size(), value, base);
  if (ec != std::errc{} || end != text.data() + text.size()) return std::nullopt;
  return value;
}

unsigned parse_node(const std::string& text, bool allow_all) {
  if (allow_all && text == "all") return 0;
  const auto node = parse_unsigned(text, 0);
  if (!node || *node < 1 || *node > 127) {
    throw UsageError{"node '" + text + "' is not 1..127" + (allow_all ? " or all" : "")};
  }
  return *node;
}

std::string target(const CommonOptions& common, unsigned node) {
  return std::to_string(common.net) + " " + std::to_string(node);
}

char hex_digit(unsigned v) {
  return "0123456789ABCDEF"[v & 0xF];
}

std::string hex16(unsigned v) {
  return std::string("0x") + hex_digit(v >> 12) + hex_digit(v >> 8) + hex_digit(v >> 4) +
         hex_digit(v);
}

std::string read_file(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw UsageError{"cannot read " + path};
  return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

// A vs value goes on the line in double quotes with inner quotes doubled (CiA 309-3).
std::string quote_visible_string(const std::string& value) {
  if (value.size() >= 2 && value.front() == '"' && value.back() == '"') return value;
  std::string q = "\"";
  for (char c : value) {
    q += c;
    if (c == '"') q += '"';
  }
  return q + "\"";
}

struct SdoArgs {
  std::string node, index, sub, type, value, file;
};

std::string object_address(const SdoArgs& a) {
  const auto index = parse_unsigned(a.index, 16);
  const auto sub = parse_unsigned(a.sub, 0);
  if (!index || *index > 0xFFFF) throw UsageError{"index '" + a.index + "' is not hex 0..FFFF"};
  if (!sub || *sub > 0xFF) throw UsageError{"sub-index '" + a.sub + "' is not 0..255"};
  return hex16(*index) + " " + std::to_string(*sub);
}

void check_type(const std::string& type) {
  if (type.empty()) return;
  if (std::find(kDatatypes.begin(), kDatatypes.end(), type) == kDatatypes.end() && type != "hex") {
    throw UsageError{"datatype '" + type +
                     "' is none of b u8 u16 u32 u64 i8 i16 i32 i64 x8 x16 x32 x64 r32 r64 vs os "
                     "us d hex"};
  }
}

int run_nodes(const Connect& connect, const CommonOptions& common, bool net_given) {
  int rc = exit_code::ok;
  const auto session = connect(rc);
  if (!session) return rc;
  Session& s = *session;
  std::vector<NodeRow> rows;
  std::string answer;
  rc = s.call(net_given ? std::to_string(common.net) + " nodes" : "nodes", answer,
              [&](std::string_view rest) {
                auto row = parse_node_row(rest);
                if (row) rows.push_back(std::move(*row));
                return row.has_value();
              });
  if (rc != exit_code::ok) return rc;
  print_node_table(s.io().out, rows);
  return exit_code::ok;
}

// `stats`: the endpoint's one JSON line (a surface's command endpoint or a gateway's
// stats_endpoint), printed as it came.
int run_stats(const Connect& connect) {
  int rc = exit_code::ok;
  const auto session = connect(rc);
  if (!session) return rc;
  Session& s = *session;
  std::string json, answer;
  rc = s.call("stats", answer, [&](std::string_view rest) {
    if (rest.empty() || rest.front() != '{') return false;
    json = rest;
    return true;
  });
  if (rc != exit_code::ok) return rc;
  if (json.empty()) {
    s.io().err << "canbridge: the endpoint answered stats without statistics: " << answer << "\n";
    return exit_code::abort;
  }
  s.io().out << json << "\n";
  return exit_code::ok;
}

int run_sdo_read(const Connect& connect, const CommonOptions& common, const SdoArgs& a) {
  check_type(a.type);
  const unsigned node = parse_node(a.node, false);
  std::string command = target(common, node) + " r " + object_address(a);
  if (!a.type.empty()) command += " " + a.type;
  int rc = exit_code::ok;
  const auto session = connect(rc);
  if (!session) return rc;
  Session& s = *session;
  std::string value;
  rc = s.call(command, value);
  if (rc != exit_code::ok) return rc;
  if (!a.file.empty()) {
    // Domains and strings come back as base64 (d, os, us): the file gets the bytes.
    std::string bytes = value;
    if (a.type == "d" || a.type == "os" || a.type == "us") {
      const auto decoded = canopen::base64_decode(value);
      if (!decoded) {
        s.io().err << "canbridge: the endpoint's value is not base64: " << value << "\n";
        return exit_code::abort;
      }
      bytes.assign(decoded->begin(), decoded->end());
    }
    std::ofstream f(a.file, std::ios::binary);
    f << bytes;
    if (!f) {
      s.io().err << "canbridge: cannot write " << a.file << "\n";
      return exit_code::usage;
    }
    return exit_code::ok;
  }
  s.io().out << value << "\n";
  return exit_code::ok;
}

int run_sdo_write(const Connect& connect, const CommonOptions& common, SdoArgs a) {
  if (a.type.empty()) throw UsageError{"sdo write needs a datatype"};
  check_type(a.type);
  const unsigned node = parse_node(a.node, false);
  std::string value = a.value;
  if (!a.file.empty() == !a.value.empty()) throw UsageError{"give either VALUE or --file F"};
  if (!a.file.empty()) {
    if (a.type != "d" && a.type != "os" && a.type != "us") {
      throw UsageError{"--file needs datatype d, os or us (sent as base64)"};
    }
    const std::string content = read_file(a.file);
    value = canopen::base64_encode(std::span<const std::uint8_t>(
        reinterpret_cast<const std::uint8_t*>(content.data()), content.size()));
  } else if (a.type == "vs") {
    value = quote_visible_string(value);
  }
  int rc = exit_code::ok;
  const auto session = connect(rc);
  if (!session) return rc;
  Session& s = *session;
  std::string answer;
  return s.call(target(common, node) + " w " + object_address(a) + " " + a.type + " " + value,
                answer);
}

int run_nmt(const Connect& connect, const CommonOptions& common, const std::string& command,
            const std::string& node_text) {
  static const std::array<std::pair<std::string_view, std::string_view>, 5> kNmt = {{
      {"start", "start"},
      {"stop", "stop"},
      {"preop", "preop"},
      {"reset", "reset node"},
      {"reset-comm", "reset comm"},
  }};
  const auto it =
      std::find_if(kNmt.begin(), kNmt.end(), [&](const auto& p) { return p.first == command; });
  if (it == kNmt.end()) {
    throw UsageError{"nmt command '" + command + "' is none of start stop preop reset reset-comm"};
  }
  const unsigned node = parse_node(node_text, true);
  int rc = exit_code::ok;
  const auto session = connect(rc);
  if (!session) return rc;
  Session& s = *session;
  std::string answer;
  return s.call(target(common, node) + " " + std::string(it->second), answer);
}

int run_set_node_id(const Connect& connect, const CommonOptions& common,
                    const std::string& node_text, const std::string& new_text) {
  const unsigned node = parse_node(node_text, false);
  const unsigned new_id = parse_node(new_text, false);
  int rc = exit_code::ok;
  const auto session = connect(rc);
  if (!session) return rc;
  Session& s = *session;
  std::string answer;
  rc = s.call(target(common, node) + " set node_id " + std::to_string(new_id), answer, {});
  if (rc == exit_code::ok) s.io().out << "node " << node << " is now node " << new_id << "\n";
  return rc;
}

int run_flash(const Connect& connect, const CommonOptions& common, const std::string& node_text,
              const std::string& image) {
  const unsigned node = parse_node(node_text, false);
  std::error_code ec;
  // The surface process reads the image: it needs a path that does not depend on our cwd.
  const auto path = std::filesystem::absolute(image, ec);
  if (ec || !std::ifstream(path, std::ios::binary)) throw UsageError{"cannot read " + image};
  if (path.string().find_first_of("#\r\n") != std::string::npos) {
    // The endpoint reads '#' as the start of a comment and a line end as the end of the path.
    throw UsageError{"the image path " + path.string() + " contains '#' or a line break"};
  }
  int rc = exit_code::ok;
  const auto session = connect(rc);
  if (!session) return rc;
  Session& s = *session;
  ProgressPrinter progress(s.io().out, s.io().terminal);
  std::string answer;
  rc = s.call(
      target(common, node) + " flash " + path.string(), answer,
      [&](std::string_view rest) {
        auto p = parse_progress(rest);
        if (p) progress.update(*p, std::chrono::steady_clock::now());
        return p.has_value();
      },
      std::max(s.timeout(), std::chrono::milliseconds(600'000)));
  progress.finish();
  if (rc == exit_code::ok) s.io().out << "flashed " << image << " to node " << node << "\n";
  return rc;
}

// The options of every operator command, before or after its name; returns --net's (whether it
// was given changes what `nodes` asks).
CLI::Option* add_common_options(CLI::App& app, CommonOptions& common) {
  app.add_option("--endpoint", common.endpoint,
                 "Unix socket PATH or HOST:PORT (default: -c's command_endpoint.unix_socket, "
                 "else /run/canbridge/surface.sock)");
  app.add_option("--token-file", common.token_file, "token for a TCP endpoint (sent with auth)");
  app.add_option("-c,--config", common.config, "the surface's configuration file");
  auto* net_option = app.add_option("--net", common.net, "CiA 309-3 network (0: the surface's)");
  app.add_option("--timeout", common.timeout_s, "seconds to wait for an answer")
      ->check(CLI::PositiveNumber);
  app.fallthrough();  // common options also after the subcommand
  return net_option;
}

}  // namespace

bool is_client_command(std::string_view name) {
  return std::find(kCommands.begin(), kCommands.end(), name) != kCommands.end();
}

bool is_client_option_with_value(std::string_view option) {
  CLI::App app;
  CommonOptions common;
  add_common_options(app, common);
  const CLI::Option* found = app.get_option_no_throw(std::string(option));
  return found != nullptr && found->get_type_size_min() > 0 && found->get_expected_min() > 0;
}

int run_client(const std::vector<std::string>& args, std::ostream& out, std::ostream& err,
               bool terminal) {
  CLI::App app{"canbridge: operator commands against a surface's command endpoint", "canbridge"};
  app.require_subcommand(1, 1);
  CommonOptions common;
  auto* net_option = add_common_options(app, common);

  auto* nodes = app.add_subcommand("nodes", "the live node table");
  auto* stats = app.add_subcommand(
      "stats", "statistics as JSON (a surface's endpoint, or a gateway's stats_endpoint)");

  SdoArgs sdo_args;
  auto* sdo = app.add_subcommand("sdo", "read or write an object of a node");
  sdo->require_subcommand(1, 1);
  sdo->fallthrough();
  auto* sdo_read = sdo->add_subcommand("read", "NODE INDEX SUB [TYPE]: print the value");
  sdo_read->add_option("NODE", sdo_args.node)->required();
  sdo_read->add_option("INDEX", sdo_args.index, "hex, 0x optional")->required();
  sdo_read->add_option("SUB", sdo_args.sub)->required();
  sdo_read->add_option("TYPE", sdo_args.type, "datatype (default: hex bytes)");
  sdo_read->add_option("--file", sdo_args.file, "write the value (base64 decoded) to F");
  sdo_read->fallthrough();
  auto* sdo_write = sdo->add_subcommand("write", "NODE INDEX SUB TYPE VALUE|--file F");
  sdo_write->add_option("NODE", sdo_args.node)->required();
  sdo_write->add_option("INDEX", sdo_args.index, "hex, 0x optional")->required();
  sdo_write->add_option("SUB", sdo_args.sub)->required();
  sdo_write->add_option("TYPE", sdo_args.type)->required();
  sdo_write->add_option("VALUE", sdo_args.value);
  sdo_write->add_option("--file", sdo_args.file, "write the bytes of F (types d, os, us)");
  sdo_write->fallthrough();

  std::string nmt_command, node_text, new_id, image;
  auto* nmt = app.add_subcommand("nmt", "start|stop|preop|reset|reset-comm NODE|all");
  nmt->add_option("COMMAND", nmt_command)->required();
  nmt->add_option("NODE", node_text)->required();
  auto* set_node_id = app.add_subcommand("set-node-id", "NODE NEW: rename a node (fpga kind)");
  set_node_id->add_option("NODE", node_text)->required();
  set_node_id->add_option("NEW", new_id)->required();
  auto* flash = app.add_subcommand("flash", "NODE IMAGE: firmware download through the loader");
  flash->add_option("NODE", node_text)->required();
  flash->add_option("IMAGE", image)->required();

  MonitorOptions monitor;
  auto* dump = app.add_subcommand("dump", "live monitor, decoded in CANopen terms");
  dump->add_option("--module", monitor.module, "only frames of module M (0: the surface bus)");
  dump->add_option("--node", monitor.node, "only frames of node N");
  dump->add_option("--kind", monitor.kinds, "only these kinds (repeatable): " + kind_names());
  dump->add_flag("--raw", monitor.raw, "candump format instead of decoded text");
  dump->add_option("--count", monitor.count, "stop after this many frames");
  auto* capture = app.add_subcommand("capture", "record the live frames to a file");
  capture->add_option("-w", monitor.file, "the file (pcap, LINKTYPE_CAN_SOCKETCAN)")->required();
  capture->add_flag("-l", monitor.candump_log, "candump log format instead of pcap");
  capture->add_option("--module", monitor.module, "only frames of module M");
  capture->add_option("--count", monitor.count, "stop after this many frames");

  std::vector<std::string> reversed(args.rbegin(), args.rend());
  try {
    app.parse(reversed);
  } catch (const CLI::CallForHelp&) {
    out << app.help();
    return exit_code::ok;
  } catch (const CLI::ParseError& e) {
    err << "canbridge: " << logging::usage_message(app, e) << "\n" << app.help();
    return exit_code::usage;
  }
  try {
    const Io io{out, err, terminal};
    const Connect connect = [&](int& exit) { return Session::open(common, io, exit); };
    if (nodes->parsed()) return run_nodes(connect, common, net_option->count() > 0);
    if (stats->parsed()) return run_stats(connect);
    if (sdo_read->parsed()) return run_sdo_read(connect, common, sdo_args);
    if (sdo_write->parsed()) return run_sdo_write(connect, common, sdo_args);
    if (nmt->parsed()) return run_nmt(connect, common, nmt_command, node_text);
    if (set_node_id->parsed()) return run_set_node_id(connect, common, node_text, new_id);
    if (flash->parsed()) return run_flash(connect, common, node_text, image);
    if (dump->parsed() || capture->parsed()) {
      monitor.capture = capture->parsed();
      return run_monitor(connect, monitor);
    }
    return exit_code::usage;
  } catch (const UsageError& e) {
    err << "canbridge: " << e.message << "\n";
    return exit_code::usage;
  }
}

}  // namespace canbridge::cli
