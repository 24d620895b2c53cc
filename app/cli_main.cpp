#include "app/cli_main.hpp"

#include <CLI/CLI.hpp>
#include <algorithm>
#include <array>
#include <charconv>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <iterator>
#include <optional>
#include <ostream>
#include <span>

#include "app/cli_cmd.hpp"
#include "app/cli_monitor.hpp"
#include "app/cli_node_table.hpp"
#include "app/cli_progress.hpp"
#include "app/cli_reply.hpp"
#include "app/cli_session.hpp"
#include "canopen/ascii_value.hpp"
#include "logging/command_line_common.hpp"

namespace canbridge::cli {

namespace {

constexpr std::array<std::string_view, 9> kCommands = {
    "nodes", "sdo", "nmt", "set-node-id", "flash", "dump", "capture", "stats", "cmd"};

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
  std::vector<NodeRow> gateways;
  std::string answer;
  rc = s.call(net_given ? std::to_string(common.net) + " nodes" : "nodes", answer,
              [&](std::string_view rest) {
                if (auto row = parse_node_row(rest)) {
                  rows.push_back(std::move(*row));
                  return true;
                }
                auto gateway = parse_gateway_state(rest);
                if (gateway) gateways.push_back(std::move(*gateway));
                return gateway.has_value();
              });
  if (rc != exit_code::ok) return rc;
  print_node_table(s.io().out, rows);
  // A gateway that is down is no failure of `nodes`: its nodes are listed, lost, from the
  // surface's own table, and the operator is told why.
  for (const auto& gateway : gateways) {
    s.io().out << "gateway " << field(gateway, "name") << ": " << field(gateway, "state")
               << " (its nodes are shown lost, as the surface last knew them)\n";
  }
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
  if (rc != exit_code::ok) return rc;
  // The new id is the node's id on its module's bus; which id the surface addresses it by is the
  // gateway's map's to say (the endpoint's answer): on net 0 it often keeps its surface id.
  std::ostream& out = s.io().out;
  out << "node " << node;
  if (common.net != 0) out << " of net " << common.net;
  out << " renamed to " << (common.net == 0 ? "local id " : "") << new_id;
  if (answer == "OK") {
    out << "; its surface id was not reported (canbridge nodes shows it)\n";
  } else if (answer == "-") {
    out << "; it has no surface id now (reach it on its module's network, --net)\n";
  } else {
    out << "; the surface addresses it as node " << answer << "\n";
  }
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

// The options every operator command takes, registered on the command itself (the leaf: `nodes`,
// `sdo read`, ...), so that its `--help` lists them; returns --net's (whether it was given changes
// what `nodes` asks).
CLI::Option* add_common_options(CLI::App& app, CommonOptions& common) {
  app.add_option("--endpoint", common.endpoint,
                 "Unix socket PATH or HOST:PORT (default: -c's endpoint, else " +
                     std::string(kDefaultEndpoint) + ")")
      ->type_name("PATH|HOST:PORT");
  app.add_option("--token-file", common.token_file, "token for a TCP endpoint (sent with auth)")
      ->type_name("FILE");
  app.add_option("-c,--config", common.config,
                 "a surface's file (its command_endpoint), or for stats a gateway's "
                 "(its stats_endpoint)")
      ->type_name("FILE");
  auto* net_option =
      app.add_option("--net", common.net, "CiA 309-3 network: 0 the surface's, N a module's")
          ->type_name("N")
          ->capture_default_str()
          ->check(CLI::Validator(
              [](std::string& text) -> std::string {
                const auto n = parse_unsigned(text, 0);
                return n && *n <= 0xFFFF ? "" : "'" + text + "' is not a network 0..65535";
              },
              "0..65535"));
  app.add_option("--timeout", common.timeout_s, "seconds to wait for an answer")
      ->type_name("SECONDS")
      ->capture_default_str()
      ->check(CLI::Validator(
          [](std::string& text) -> std::string {
            double value = 0;
            const auto [end, ec] = std::from_chars(text.data(), text.data() + text.size(), value);
            const bool number = ec == std::errc{} && end == text.data() + text.size();
            return number && value > 0 && value <= 86400
                       ? ""
                       : "'" + text + "' is not a number of seconds above 0 and at most 86400";
          },
          "0..86400"));
  return net_option;
}

// CLI11 reads a subcommand's options only after its name: the command's words (`nodes`,
// `sdo read`) go first and every other word follows in the order given, so that an option may
// stand before, between or after them. An unknown `sdo` command is named here, in one line
// (CLI11 would only say that a subcommand is required).
std::vector<std::string> command_words_first(const std::vector<std::string>& args) {
  std::vector<std::string> command, rest;
  bool positional_only = false;
  for (std::size_t i = 0; i < args.size(); ++i) {
    const std::string& word = args[i];
    const bool option = !positional_only && word.size() >= 2 && word.front() == '-';
    if (word == "--") positional_only = true;
    if (option || positional_only) {
      rest.push_back(word);
      if (option && word.find('=') == std::string::npos && is_client_option_with_value(word) &&
          i + 1 < args.size()) {
        rest.push_back(args[++i]);
      }
      continue;
    }
    const bool wants_word = command.empty() || (command.size() == 1 && command[0] == "sdo");
    (wants_word ? command : rest).push_back(word);
  }
  const bool help = std::find(args.begin(), args.end(), "--help") != args.end() ||
                    std::find(args.begin(), args.end(), "-h") != args.end();
  if (!command.empty() && command[0] == "sdo" && !help) {
    if (command.size() < 2) throw UsageError{"sdo needs a command: read or write"};
    if (command[1] != "read" && command[1] != "write") {
      throw UsageError{"unknown sdo command '" + command[1] + "': expected read or write"};
    }
  }
  command.insert(command.end(), rest.begin(), rest.end());
  return command;
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
  return run_client(args, out, err, terminal, std::cin);
}

int run_client(const std::vector<std::string>& args, std::ostream& out, std::ostream& err,
               bool terminal, std::istream& in) {
  CLI::App app{"canbridge: operator commands against a surface's command endpoint", "canbridge"};
  app.require_subcommand(1, 1);
  CommonOptions common;
  const char* const node_help = "the node's id on the network (--net), 1..127";

  auto* nodes = app.add_subcommand("nodes", "the live node table");
  auto* net_option = add_common_options(*nodes, common);
  auto* stats = app.add_subcommand(
      "stats", "statistics as JSON (a surface's endpoint, or a gateway's stats_endpoint)");
  add_common_options(*stats, common);

  SdoArgs sdo_args;
  auto* sdo = app.add_subcommand("sdo", "read or write an object of a node");
  sdo->require_subcommand(1, 1);
  auto* sdo_read = sdo->add_subcommand("read", "NODE INDEX SUB [TYPE]: print the value");
  sdo_read->add_option("NODE", sdo_args.node, node_help)->required();
  sdo_read->add_option("INDEX", sdo_args.index, "the object's index, hex (0x optional)")
      ->required();
  sdo_read->add_option("SUB", sdo_args.sub, "the sub-index, 0..255 (0x for hex)")->required();
  sdo_read->add_option("TYPE", sdo_args.type,
                       "datatype: b u8..u64 i8..i64 x8..x64 r32 r64 vs os us d hex "
                       "(default: hex bytes)");
  sdo_read->add_option("--file", sdo_args.file, "write the value (base64 decoded) to F")
      ->type_name("F");
  add_common_options(*sdo_read, common);
  auto* sdo_write = sdo->add_subcommand("write", "NODE INDEX SUB TYPE VALUE|--file F");
  sdo_write->add_option("NODE", sdo_args.node, node_help)->required();
  sdo_write->add_option("INDEX", sdo_args.index, "the object's index, hex (0x optional)")
      ->required();
  sdo_write->add_option("SUB", sdo_args.sub, "the sub-index, 0..255 (0x for hex)")->required();
  sdo_write
      ->add_option("TYPE", sdo_args.type,
                   "datatype: b u8..u64 i8..i64 x8..x64 r32 r64 vs os us d hex")
      ->required();
  sdo_write->add_option("VALUE", sdo_args.value, "the value, in TYPE's notation (or --file)");
  sdo_write->add_option("--file", sdo_args.file, "write the bytes of F (types d, os, us)")
      ->type_name("F");
  add_common_options(*sdo_write, common);

  std::string nmt_command, node_text, new_id, image;
  auto* nmt = app.add_subcommand("nmt", "start|stop|preop|reset|reset-comm NODE|all");
  nmt->add_option("COMMAND", nmt_command, "start, stop, preop, reset or reset-comm")->required();
  nmt->add_option("NODE", node_text, "1..127, or all (broadcast)")->required();
  add_common_options(*nmt, common);
  auto* set_node_id = app.add_subcommand("set-node-id", "NODE NEW: rename a node (fpga kind)");
  set_node_id->add_option("NODE", node_text, node_help)->required();
  set_node_id->add_option("NEW", new_id, "the new id, 1..127")->required();
  add_common_options(*set_node_id, common);
  auto* flash = app.add_subcommand("flash", "NODE IMAGE: firmware download through the loader");
  flash->add_option("NODE", node_text, node_help)->required();
  flash->add_option("IMAGE", image, "the image file, read by the surface process")->required();
  add_common_options(*flash, common);

  MonitorOptions monitor;
  auto* dump = app.add_subcommand("dump", "live monitor, decoded in CANopen terms");
  dump->add_option("--module", monitor.module, "only frames of module M (0: the surface bus)")
      ->type_name("M");
  dump->add_option("--node", monitor.node, "only frames of node N")->type_name("N");
  dump->add_option("--kind", monitor.kinds, "only these kinds (repeatable): " + kind_names())
      ->type_name("KIND");
  dump->add_flag("--raw", monitor.raw, "candump format instead of decoded text");
  dump->add_option("--count", monitor.count, "stop after this many frames (default: never)")
      ->type_name("N");
  add_common_options(*dump, common);
  auto* capture = app.add_subcommand("capture", "record the live frames to a file");
  capture->add_option("-w", monitor.file, "the file (pcap, LINKTYPE_CAN_SOCKETCAN)")
      ->type_name("FILE")
      ->required();
  capture->add_flag("-l", monitor.candump_log, "candump log format instead of pcap");
  capture->add_option("--module", monitor.module, "only frames of module M")->type_name("M");
  capture->add_option("--count", monitor.count, "stop after this many frames (default: never)")
      ->type_name("N");
  add_common_options(*capture, common);
  std::vector<std::string> raw_lines;
  auto* cmd = app.add_subcommand(
      "cmd",
      "[LINE...]: raw CiA 309-3 lines, as cocomm sends them; each answer printed as it came");
  cmd->add_option("LINE", raw_lines,
                  "one request each, e.g. \"4 read 0x1017 0 u16\" (\"[<n>] \" put before a line "
                  "without a sequence); none: the lines of standard input");
  // The lines name their networks themselves: --net would have nothing to apply to.
  cmd->remove_option(add_common_options(*cmd, common));
  app.footer(
      "Each command takes --endpoint, --token-file, -c, --net (not cmd) and --timeout, before or "
      "after its name; 'canbridge COMMAND --help' lists them. Exit status: 0 done, 1 refused or "
      "failed (SDO abort), 2 usage, 3 unknown network or node, 4 time-out, 5 endpoint "
      "unreachable, 6 outcome unknown (it may have been executed: read the object back); cmd: "
      "that of its first ERROR answer.");

  std::vector<std::string> ordered;
  try {
    ordered = command_words_first(args);
  } catch (const UsageError& e) {
    err << "canbridge: " << e.message << "\nrun 'canbridge sdo --help' for the usage\n";
    return exit_code::usage;
  }
  std::vector<std::string> reversed(ordered.rbegin(), ordered.rend());
  try {
    app.parse(reversed);
  } catch (const CLI::CallForHelp&) {
    out << app.help();
    return exit_code::ok;
  } catch (const CLI::ParseError& e) {
    // One line naming what is wrong, and where the usage is: never the whole help.
    std::string command = "canbridge";
    const CLI::App* leaf = &app;  // the command the error is about: its extras are its own
    while (!leaf->get_subcommands().empty()) {
      leaf = leaf->get_subcommands().front();
      command += " " + leaf->get_name();
    }
    err << "canbridge: " << logging::usage_message(*leaf, e) << "\nrun '" << command
        << " --help' for the usage\n";
    return exit_code::usage;
  }
  try {
    const Io io{out, err, terminal};
    const Connect connect = [&](int& exit) { return Session::open(common, io, exit); };
    if (nodes->parsed()) return run_nodes(connect, common, net_option->count() > 0);
    if (stats->parsed()) {
      common.stats = true;
      return run_stats(connect);
    }
    if (sdo_read->parsed()) return run_sdo_read(connect, common, sdo_args);
    if (sdo_write->parsed()) return run_sdo_write(connect, common, sdo_args);
    if (nmt->parsed()) return run_nmt(connect, common, nmt_command, node_text);
    if (set_node_id->parsed()) return run_set_node_id(connect, common, node_text, new_id);
    if (flash->parsed()) return run_flash(connect, common, node_text, image);
    if (cmd->parsed()) return run_cmd(connect, raw_lines, in);
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
