#include "canopen/ascii_command.hpp"

#include <algorithm>
#include <array>
#include <cstdio>

#include "canopen/ascii_value.hpp"

namespace canbridge::canopen {

namespace {

constexpr std::size_t kMaxAuthToken = 4096;
constexpr std::uint32_t kMaxNet = 0xFFFF;  // as CANopenNode's gateway
constexpr std::uint32_t kMaxNode = 127;

bool is_separator(char c) {
  return c == ' ' || c == '\t';
}

bool is_digit(char c) {
  return c >= '0' && c <= '9';
}

std::string lower(std::string_view text) {
  std::string out(text);
  for (char& c : out) {
    if (c >= 'A' && c <= 'Z') c = static_cast<char>(c - 'A' + 'a');
  }
  return out;
}

// The line without its comment: `#` outside double quotes starts one (a quoted visible string
// may hold `#`; a doubled quote inside it toggles twice, so it keeps the state).
std::string_view strip_comment(std::string_view line) {
  bool quoted = false;
  for (std::size_t i = 0; i < line.size(); ++i) {
    if (line[i] == '"') quoted = !quoted;
    if (line[i] == '#' && !quoted) return line.substr(0, i);
  }
  return line;
}

// Walks the tokens of a line; the rest of the line stays available for values that hold spaces
// (vs, hex, paths).
class Tokens {
 public:
  explicit Tokens(std::string_view text) : text_(text) {}

  std::string_view next() {
    skip_spaces();
    const std::size_t start = pos_;
    while (pos_ < text_.size() && !is_separator(text_[pos_])) ++pos_;
    return text_.substr(start, pos_ - start);
  }
  std::string_view peek() {
    const std::size_t saved = pos_;
    const auto token = next();
    pos_ = saved;
    return token;
  }
  std::string_view rest() {
    skip_spaces();
    auto out = text_.substr(pos_);
    while (!out.empty() && is_separator(out.back())) out.remove_suffix(1);
    pos_ = text_.size();
    return out;
  }
  bool at_end() {
    skip_spaces();
    return pos_ >= text_.size();
  }

 private:
  void skip_spaces() {
    while (pos_ < text_.size() && is_separator(text_[pos_])) ++pos_;
  }
  std::string_view text_;
  std::size_t pos_ = 0;
};

struct Failure {
  AsciiError error;
  std::string detail;
};

class Parser {
 public:
  explicit Parser(std::string_view line) : tokens_(line) {}

  AsciiParse run(std::string_view raw) {
    if (auto failure = parse(raw)) {
      result_.error = failure->error;
      result_.detail = std::move(failure->detail);
    }
    return std::move(result_);
  }

 private:
  using Outcome = std::optional<Failure>;
  static Outcome syntax(std::string detail) {
    return Failure{AsciiError::syntax, std::move(detail)};
  }

  Outcome parse(std::string_view raw) {
    for (std::size_t i = 0; i < raw.size(); ++i) {
      const auto c = static_cast<unsigned char>(raw[i]);
      if ((c < 0x20 && c != '\t') || c == 0x7F) {
        char buf[64];
        std::snprintf(buf, sizeof buf, "control byte 0x%02X at column %zu", c, i + 1);
        return syntax(buf);
      }
    }
    if (tokens_.at_end()) return std::nullopt;  // blank or comment only
    AsciiCommand& cmd = result_.command;
    std::string_view token = tokens_.next();
    if (token.front() == '[') {
      if (token.size() < 3 || token.back() != ']') {
        return syntax("sequence " + ascii_excerpt(token) + ": expected [<number>]");
      }
      const auto seq = parse_ascii_unsigned(token.substr(1, token.size() - 2), 0xFFFFFFFFu);
      if (!seq) return syntax("sequence " + ascii_excerpt(token) + ": not a 32-bit number");
      cmd.sequence = static_cast<std::uint32_t>(*seq);
      if (tokens_.at_end()) return syntax("missing command after the sequence");
      token = tokens_.next();
    }
    // Up to two numbers before the command: [[<net>] <node>], or [<net>] for network commands.
    std::vector<std::uint32_t> numbers;
    while (!token.empty() && is_digit(token.front())) {
      if (numbers.size() == 2) return syntax("more than two numbers before the command");
      if (token.size() > kMaxAsciiToken)
        return syntax("number " + ascii_excerpt(token) + " too long");
      const auto n = parse_ascii_unsigned(token, 0xFFFFFFFFu);
      if (!n) return syntax("net or node " + ascii_excerpt(token) + ": not a number");
      numbers.push_back(static_cast<std::uint32_t>(*n));
      if (tokens_.at_end()) return syntax("missing command after " + ascii_excerpt(token));
      token = tokens_.next();
    }
    if (token.size() > kMaxAsciiToken)
      return syntax("command " + ascii_excerpt(token) + " too long");
    const std::string word = lower(token);
    if (word == "r" || word == "read") return read(numbers);
    if (word == "w" || word == "write") return write(numbers);
    if (word == "start") return nmt(numbers, AsciiNmt::start);
    if (word == "stop") return nmt(numbers, AsciiNmt::stop);
    if (word == "preop" || word == "preoperational") return nmt(numbers, AsciiNmt::preoperational);
    if (word == "reset") {
      const std::string what = lower(tokens_.next());
      if (what == "node") return nmt(numbers, AsciiNmt::reset_node);
      if (what == "comm" || what == "communication") {
        return nmt(numbers, AsciiNmt::reset_communication);
      }
      return syntax("reset " + ascii_excerpt(what) + ": expected node or comm[unication]");
    }
    if (word == "set") return set(numbers);
    if (word == "help") return help(numbers);
    if (word == "auth") return auth(numbers);
    if (word == "nodes") {
      cmd.verb = AsciiVerb::nodes;
      if (auto f = net_only(numbers)) return f;
      return end();
    }
    if (word == "stats") {
      cmd.verb = AsciiVerb::stats;
      if (!numbers.empty()) return syntax("stats takes no net or node");
      return end();
    }
    if (word == "flash") return flash(numbers);
    if (word == "monitor") return monitor(numbers);
    if (word.rfind("lss_", 0) == 0 || word.rfind("_lss_", 0) == 0) return lss(numbers, word);
    return Failure{AsciiError::request_not_supported, "unknown command " + ascii_excerpt(token)};
  }

  // The numbers before a node command: <node> or <net> <node>.
  Outcome net_node(const std::vector<std::uint32_t>& numbers) {
    AsciiCommand& cmd = result_.command;
    if (numbers.size() == 2) {
      if (numbers[0] > kMaxNet) {
        return Failure{AsciiError::unsupported_net, "net " + std::to_string(numbers[0])};
      }
      cmd.net = numbers[0];
    }
    if (!numbers.empty()) {
      const std::uint32_t node = numbers.back();
      if (node > kMaxNode) {
        return Failure{AsciiError::unsupported_node, "node " + std::to_string(node)};
      }
      cmd.node = node;
    }
    return std::nullopt;
  }

  // The numbers before a network command: at most <net>.
  Outcome net_only(const std::vector<std::uint32_t>& numbers) {
    if (numbers.size() > 1) return syntax("a network command takes no node");
    if (numbers.size() == 1) {
      if (numbers[0] > kMaxNet) {
        return Failure{AsciiError::unsupported_net, "net " + std::to_string(numbers[0])};
      }
      result_.command.net = numbers[0];
    }
    return std::nullopt;
  }

  Outcome no_numbers(const std::vector<std::uint32_t>& numbers, std::string_view what) {
    if (!numbers.empty()) return syntax(std::string(what) + " takes no net or node");
    return std::nullopt;
  }

  Outcome end() {
    if (!tokens_.at_end()) return syntax("unexpected " + ascii_excerpt(tokens_.peek()));
    return std::nullopt;
  }

  // A number token that must fit [min, max]; `what` names it in the error.
  Outcome number(std::string_view what, std::uint64_t min, std::uint64_t max, std::uint32_t& out) {
    const std::string_view token = tokens_.next();
    if (token.empty()) return syntax("missing " + std::string(what));
    if (token.size() > kMaxAsciiToken) return syntax(std::string(what) + " too long");
    const auto n = parse_ascii_unsigned(token, 0xFFFFFFFFu);
    if (!n) return syntax(std::string(what) + " " + ascii_excerpt(token) + ": not a number");
    if (*n < min || *n > max) {
      return syntax(std::string(what) + " " + ascii_excerpt(token) + " out of range " +
                    std::to_string(min) + ".." + std::to_string(max));
    }
    out = static_cast<std::uint32_t>(*n);
    return std::nullopt;
  }

  Outcome index_sub() {
    AsciiCommand& cmd = result_.command;
    std::uint32_t value = 0;
    if (auto f = number("index", 0, 0xFFFF, value)) return f;
    cmd.index = static_cast<std::uint16_t>(value);
    if (auto f = number("subindex", 0, 0xFF, value)) return f;
    cmd.sub = static_cast<std::uint8_t>(value);
    return std::nullopt;
  }

  Outcome datatype(bool required) {
    const std::string_view token = tokens_.next();
    if (token.empty()) {
      if (required) return syntax("missing datatype");
      return std::nullopt;
    }
    const auto type = parse_ascii_type(lower(token.substr(0, kMaxAsciiToken + 1)));
    if (!type) return syntax("unknown datatype " + ascii_excerpt(token));
    result_.command.type = type;
    return std::nullopt;
  }

  Outcome read(const std::vector<std::uint32_t>& numbers) {
    result_.command.verb = AsciiVerb::read;
    if (auto f = net_node(numbers)) return f;
    if (auto f = index_sub()) return f;
    if (auto f = datatype(false)) return f;
    return end();
  }

  Outcome write(const std::vector<std::uint32_t>& numbers) {
    AsciiCommand& cmd = result_.command;
    cmd.verb = AsciiVerb::write;
    if (auto f = net_node(numbers)) return f;
    if (auto f = index_sub()) return f;
    if (auto f = datatype(true)) return f;
    auto value = parse_ascii_value(*cmd.type, tokens_.rest());
    if (!value.ok()) return syntax(value.error);
    cmd.value = std::move(value.bytes);
    return std::nullopt;
  }

  Outcome nmt(const std::vector<std::uint32_t>& numbers, AsciiNmt which) {
    result_.command.verb = AsciiVerb::nmt;
    result_.command.nmt = which;
    if (auto f = net_node(numbers)) return f;
    return end();
  }

  Outcome set(const std::vector<std::uint32_t>& numbers) {
    AsciiCommand& cmd = result_.command;
    const std::string what = lower(tokens_.next().substr(0, kMaxAsciiToken + 1));
    if (what == "node_id") {
      cmd.verb = AsciiVerb::set_node_id;
      if (auto f = net_node(numbers)) return f;
      if (auto f = number("new node id", 1, kMaxNode, cmd.number)) return f;
      return end();
    }
    if (auto f = net_only(numbers)) return f;
    if (what == "network") {
      cmd.verb = AsciiVerb::set_network;
      if (auto f = number("network", 0, kMaxNet, cmd.number)) return f;
    } else if (what == "node") {
      cmd.verb = AsciiVerb::set_node;
      if (auto f = number("node", 1, kMaxNode, cmd.number)) return f;
    } else if (what == "sdo_timeout") {
      cmd.verb = AsciiVerb::set_sdo_timeout;
      if (auto f = number("sdo_timeout", 1, 0xFFFF, cmd.number)) return f;
    } else if (what == "sdo_block") {
      cmd.verb = AsciiVerb::set_sdo_block;
      if (auto f = number("sdo_block", 0, 1, cmd.number)) return f;
    } else if (what == "error_detail") {
      cmd.verb = AsciiVerb::set_error_detail;
      if (auto f = number("error_detail", 0, 1, cmd.number)) return f;
    } else if (what.empty()) {
      return syntax("set: missing what to set");
    } else {
      return Failure{AsciiError::request_not_supported, "set " + ascii_excerpt(what)};
    }
    return end();
  }

  Outcome help(const std::vector<std::uint32_t>& numbers) {
    result_.command.verb = AsciiVerb::help;
    if (auto f = no_numbers(numbers, "help")) return f;
    const std::string topic = lower(tokens_.next().substr(0, kMaxAsciiToken + 1));
    if (!topic.empty() && topic != "datatype" && topic != "lss") {
      return syntax("help " + ascii_excerpt(topic) + ": expected datatype or lss");
    }
    result_.command.text = topic;
    return end();
  }

  Outcome auth(const std::vector<std::uint32_t>& numbers) {
    result_.command.verb = AsciiVerb::auth;
    if (auto f = no_numbers(numbers, "auth")) return f;
    const std::string_view token = tokens_.next();
    if (token.empty()) return syntax("auth: missing token");
    if (token.size() > kMaxAuthToken) return syntax("auth: token too long");
    result_.command.text = std::string(token);
    return end();
  }

  Outcome flash(const std::vector<std::uint32_t>& numbers) {
    result_.command.verb = AsciiVerb::flash;
    if (auto f = net_node(numbers)) return f;
    const std::string_view path = tokens_.rest();
    if (path.empty()) return syntax("flash: missing file path");
    result_.command.text = std::string(path);
    return std::nullopt;
  }

  Outcome monitor(const std::vector<std::uint32_t>& numbers) {
    result_.command.verb = AsciiVerb::monitor;
    if (auto f = no_numbers(numbers, "monitor")) return f;
    if (tokens_.at_end()) return std::nullopt;
    const std::string_view option = tokens_.next();
    constexpr std::string_view kModule = "module=";
    if (option.size() > kMaxAsciiToken || option.substr(0, kModule.size()) != kModule) {
      return syntax("monitor: expected module=<m>, not " + ascii_excerpt(option));
    }
    const auto module = parse_ascii_unsigned(option.substr(kModule.size()), 0xFFFFFFFFu);
    if (!module) return syntax("monitor: module " + ascii_excerpt(option) + ": not a number");
    result_.command.module = static_cast<std::uint32_t>(*module);
    return end();
  }

  Outcome lss(const std::vector<std::uint32_t>& numbers, const std::string& word) {
    AsciiCommand& cmd = result_.command;
    cmd.verb = AsciiVerb::lss;
    cmd.text = word;
    if (auto f = net_only(numbers)) return f;
    std::uint32_t value = 0;
    if (word == "lss_switch_glob") {
      if (auto f = number("mode", 0, 1, value)) return f;
      cmd.args.push_back(value);
    } else if (word == "lss_switch_sel") {
      for (const char* what : {"vendor id", "product code", "revision number", "serial number"}) {
        if (auto f = number(what, 0, 0xFFFFFFFFu, value)) return f;
        cmd.args.push_back(value);
      }
    } else if (word == "lss_set_node") {
      if (auto f = number("node", 1, 0xFF, value)) return f;
      if (value > kMaxNode && value != 0xFF) {
        return syntax("lss_set_node: node " + std::to_string(value) + " is not 1..127 or 255");
      }
      cmd.args.push_back(value);
    } else if (word == "lss_inquire_addr") {
      if (!tokens_.at_end()) {
        if (auto f = number("LSS sub", 0, 3, value)) return f;
        cmd.args.push_back(value);
      }
    } else if (word != "lss_store" && word != "lss_get_node") {
      return Failure{AsciiError::request_not_supported, "LSS command " + ascii_excerpt(word)};
    }
    return end();
  }

  Tokens tokens_;
  AsciiParse result_;
};

}  // namespace

std::string_view ascii_error_text(AsciiError error) {
  switch (error) {
    case AsciiError::request_not_supported:
      return "Request not supported.";
    case AsciiError::syntax:
      return "Syntax error.";
    case AsciiError::internal_state:
      return "Request not processed due to internal state.";
    case AsciiError::timeout:
      return "Time-out.";
    case AsciiError::no_default_net:
      return "No default net set.";
    case AsciiError::no_default_node:
      return "No default node set.";
    case AsciiError::unsupported_net:
      return "Unsupported net.";
    case AsciiError::unsupported_node:
      return "Unsupported node.";
    case AsciiError::outcome_unknown:
      return "Outcome unknown, may have been executed.";
    case AsciiError::lost_connection:
      return "Lost connection.";
    case AsciiError::authentication_required:
      return "Authentication required.";
    case AsciiError::not_permitted:
      return "Not permitted for role monitor.";
  }
  return "-";
}

AsciiParse parse_ascii_command(std::string_view line) {
  if (!line.empty() && line.back() == '\r') line.remove_suffix(1);
  const std::string_view command = strip_comment(line);
  return Parser(command).run(command);
}

std::vector<std::string> ascii_help(std::string_view topic) {
  if (topic == "datatype") {
    return {
        "Datatypes:",
        "b                  # Boolean.",
        "i8, i16, i32, i64  # Signed integers.",
        "u8, u16, u32, u64  # Unsigned integers.",
        "x8, x16, x32, x64  # Unsigned integers, displayed as hexadecimal, non-standard.",
        "r32, r64           # Real numbers.",
        "vs                 # Visible string (between double quotes if multi-word).",
        "os, us             # Octet, unicode string, (mime-base64 (RFC2045) based, line).",
        "d                  # domain (mime-base64 (RFC2045) based, one line).",
        "hex                # Hexadecimal data, optionally space separated, non-standard.",
    };
  }
  if (topic == "lss") {
    return {
        "LSS commands (canbridge: on a module's network whose gateway serves LSS):",
        "[<net>] lss_switch_glob <0|1>                      # Switch state global.",
        "[<net>] lss_switch_sel <vendor> <product> <rev> <serial>  # Switch state selective.",
        "[<net>] lss_set_node <node>                        # Configure node-ID.",
        "[<net>] lss_store                                  # Store configuration.",
        "[<net>] lss_inquire_addr [<0..3>]                  # Inquire LSS address.",
        "[<net>] lss_get_node                               # Inquire node-ID.",
    };
  }
  return {
      "Command strings start with '[<sequence>]' (optional) followed by:",
      "[[<net>] <node>] r[ead] <index> <subindex> [<datatype>]        # SDO upload.",
      "[[<net>] <node>] w[rite] <index> <subindex> <datatype> <value> # SDO download.",
      "[[<net>] <node>] start                   # NMT Start node.",
      "[[<net>] <node>] stop                    # NMT Stop node.",
      "[[<net>] <node>] preop[erational]        # NMT Set node to pre-operational.",
      "[[<net>] <node>] reset node              # NMT Reset node.",
      "[[<net>] <node>] reset comm[unication]   # NMT Reset communication.",
      "[<net>] set network <value>              # Set default net.",
      "[<net>] set node <value>                 # Set default node.",
      "[<net>] set sdo_timeout <value>          # Configure SDO client time-out in ms.",
      "[<net>] set sdo_block <0|1>              # Enable/disable SDO block transfer.",
      "help [datatype|lss]                      # Print this or datatype or lss help.",
      "canbridge's extensions:",
      "auth <token>                             # TCP: authenticate (first line).",
      "[<net>] nodes                            # The gateways' node tables.",
      "[[<net>] <node>] flash <path>            # Firmware download of a file on the surface.",
      "[[<net>] <node>] set node_id <new>       # Rename a node (fpga set-node-id).",
      "set error_detail <0|1>                   # canbridge's reason after an error's text.",
      "monitor [module=<m>]                     # Live frames until the client closes.",
      "stats                                    # Statistics: one JSON line, then OK.",
      "Net 0 is the surface's network (surface node ids); a module's network has its own",
      "number (default module id + 1) and local node ids. Responses end with CR LF.",
  };
}

}  // namespace canbridge::canopen
