#include "app/cli_monitor.hpp"

#include <charconv>
#include <csignal>
#include <cstdio>
#include <ctime>
#include <fstream>
#include <ostream>

#include "app/cli_reply.hpp"
#include "can/candump_log.hpp"
#include "can/pcap_writer.hpp"
#include "canopen/frame_decoder.hpp"

namespace canbridge::cli {

namespace {

volatile std::sig_atomic_t stop_requested = 0;

void request_stop(int) {
  stop_requested = 1;
}

// SIGINT/SIGTERM interrupt the wait for the next line (no SA_RESTART) and are remembered for a
// signal that arrives between two waits, so the capture file is flushed and closed instead of
// the process dying with a partial buffer.
void stop_on_signals() {
  stop_requested = 0;
  struct sigaction action {};
  action.sa_handler = request_stop;
  sigemptyset(&action.sa_mask);
  action.sa_flags = 0;
  sigaction(SIGINT, &action, nullptr);
  sigaction(SIGTERM, &action, nullptr);
}

// "12:34:56.123456" (UTC): the time of day of a monitor frame.
std::string time_of_day(std::chrono::nanoseconds t) {
  const auto us = std::chrono::duration_cast<std::chrono::microseconds>(t).count();
  const std::time_t secs = static_cast<std::time_t>(us / 1'000'000);
  std::tm tm{};
  gmtime_r(&secs, &tm);
  char buf[32];
  std::snprintf(buf, sizeof buf, "%02d:%02d:%02d.%06lld", tm.tm_hour, tm.tm_min, tm.tm_sec,
                static_cast<long long>(us % 1'000'000));
  return buf;
}

// The profile of each module from the node table, so pdop/qd COB-IDs decode right. A failure
// here is not fatal: every module is then read as cia301.
void learn_layouts(Session& session, canopen::FrameDecoder& decoder) {
  std::string answer;
  std::vector<NodeRow> rows;
  const int rc = session.call("nodes", answer, [&](std::string_view rest) {
    auto row = parse_node_row(rest);
    if (row) rows.push_back(std::move(*row));
    return row.has_value();
  });
  if (rc != exit_code::ok) return;
  for (const auto& row : rows) {
    const auto layout = canopen::parse_bus_layout(field(row, "profile"));
    unsigned module = 0;
    const std::string text = field(row, "module");
    const auto [end, ec] = std::from_chars(text.data(), text.data() + text.size(), module);
    if (layout && ec == std::errc{} && end == text.data() + text.size()) {
      decoder.set_layout(module, *layout);
    }
  }
}

}  // namespace

std::string kind_names() {
  return canopen::frame_kind_names();
}

std::string interface_name(unsigned module) {
  return module == 0 ? "surface" : "module" + std::to_string(module);
}

int run_monitor(const Connect& connect, const MonitorOptions& options) {
  canopen::FrameFilter filter;
  filter.module = options.module;
  if (options.node) {
    if (*options.node < 1 || *options.node > canopen::kMaxNodeId) {
      throw UsageError{"--node " + std::to_string(*options.node) + " is not 1..127"};
    }
    filter.node = static_cast<canopen::NodeId>(*options.node);
  }
  for (const auto& name : options.kinds) {
    const auto kind = canopen::parse_frame_kind(name);
    if (!kind) throw UsageError{"--kind " + name + " is none of " + kind_names()};
    filter.kinds.push_back(*kind);
  }
  std::ofstream file;
  if (options.capture) {
    file.open(options.file, std::ios::binary | std::ios::trunc);
    if (!file) throw UsageError{"cannot write " + options.file};
  }
  int rc = exit_code::ok;
  const auto session = connect(rc);
  if (!session) return rc;
  Io& io = session->io();
  canopen::FrameDecoder decoder;
  if (!options.capture && !options.raw) learn_layouts(*session, decoder);

  std::string answer;
  rc = session->call(
      options.module ? "monitor module=" + std::to_string(*options.module) : std::string("monitor"),
      answer);
  if (rc != exit_code::ok) return rc;
  stop_on_signals();

  std::optional<can::PcapWriter> pcap;
  if (options.capture && !options.candump_log) pcap.emplace(file);
  std::uint64_t shown = 0;
  std::string line;
  while ((options.count == 0 || shown < options.count) && stop_requested == 0) {
    // A quiet bus is no error: wait as long as it takes.
    const auto ec = session->connection().read_line(line, std::chrono::hours(24));
    if (ec == std::errc::timed_out) continue;
    if (ec) {
      file.flush();
      return session->report_read_error(ec);
    }
    if (auto dropped = parse_dropped(line)) {
      io.err << "canbridge: the endpoint dropped " << *dropped
             << " frames (this client fell behind)\n";
      continue;
    }
    const auto m = parse_monitor_frame(line);
    if (!m) continue;  // a line of a later protocol version
    if (options.module && m->module != *options.module) continue;
    if (options.capture) {
      if (pcap) {
        pcap->write(m->frame);
      } else {
        file << can::format_candump_line(m->frame, interface_name(m->module)) << "\n";
      }
      file.flush();  // a capture read while it grows, or cut by a signal, is whole up to here
      ++shown;
      continue;
    }
    const auto decoded = decoder.decode(m->frame, m->module);
    if (!filter.matches(decoded, m->module)) continue;
    ++shown;
    if (options.raw) {
      io.out << can::format_candump_line(m->frame, interface_name(m->module)) << "\n";
    } else {
      std::string cansend = can::format_cansend_frame(m->frame);
      cansend.resize(std::max<std::size_t>(cansend.size(), 21), ' ');
      io.out << time_of_day(m->frame.timestamp) << " " << interface_name(m->module) << " " << m->dir
             << " " << cansend << " " << decoded.text << "\n";
    }
    io.out.flush();
  }
  return exit_code::ok;
}

}  // namespace canbridge::cli
