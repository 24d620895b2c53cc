// Benchmark client for remote_sdo_bench.sh: the same SDO work done two ways and timed.
//
//   endpoint: through the surface's CiA 309-3 endpoint (Unix socket), so the gateway runs the
//             transfer on its module bus (one backbone request, one result);
//   master:   by a master on the surface bus (raw SocketCAN, canopen::SdoTransfer), every SDO
//             frame tunnelled transparently across the backbone.
//
//   remote_sdo_probe endpoint       --socket P --net N --node L --op segdown|blockdown --size B
//   remote_sdo_probe endpoint-reads --socket P --targets NET:NODE,... --count C [--parallel]
//   remote_sdo_probe endpoint-flash --socket P --net N --node L --image F
//   remote_sdo_probe master         --interface IF --node S --op segdown|blockdown --size B
//   remote_sdo_probe master-reads   --interface IF --nodes S,... --count C [--parallel]
//   remote_sdo_probe master-flash   --interface IF --node S --image F
//   common: [--timeout-ms 5000] [--seed 1]
//
// Prints key=value lines: ok (1/0), ms (the operation's wall time, process start excluded),
// and on failure `error=` with the abort code or the step that failed. Reads: 0x1018:01 of each
// target in turn; --parallel keeps one request in flight per target (endpoint: one connection
// per target), otherwise one at a time. Flash (master): the seed-003 loader sequence a master
// runs itself: 1F51h:01 = 0, loader boot-up 0x720+N, block download of 1F50h:01, 1F56h:01 check
// against the image's CRC-32 trailer, 1F51h:01 = 1, application boot-up 0x700+N.
#include <linux/can.h>
#include <linux/can/raw.h>
#include <net/if.h>
#include <poll.h>
#include <sys/ioctl.h>
#include <sys/socket.h>
#include <sys/un.h>
#include <unistd.h>

#include <cerrno>
#include <chrono>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <functional>
#include <iterator>
#include <memory>
#include <optional>
#include <random>
#include <span>
#include <stdexcept>
#include <string>
#include <vector>

#include "canopen/sdo_transfer.hpp"

namespace {

using Clock = std::chrono::steady_clock;
using canbridge::can::Frame;
using canbridge::canopen::SdoTransfer;
using canbridge::canopen::SdoTransferOptions;

struct Options {
  std::string mode, socket, interface, op, image;
  std::uint32_t net = 0, node = 0;
  std::size_t size = 65536, count = 100;
  std::vector<std::pair<std::uint32_t, std::uint32_t>> targets;  // endpoint reads
  std::vector<std::uint32_t> nodes;                              // master reads
  bool parallel = false;
  int timeout_ms = 5000;
  std::uint32_t seed = 1;
};

[[noreturn]] void usage(const std::string& why) {
  std::fprintf(stderr, "remote_sdo_probe: %s (see the comment at the top of the source)\n",
               why.c_str());
  std::exit(2);
}

std::vector<std::string> split(const std::string& s, char sep) {
  std::vector<std::string> out;
  std::size_t start = 0;
  for (;;) {
    const auto at = s.find(sep, start);
    out.push_back(s.substr(start, at - start));
    if (at == std::string::npos) return out;
    start = at + 1;
  }
}

Options parse(int argc, char** argv) {
  if (argc < 2) usage("no mode");
  Options o;
  o.mode = argv[1];
  for (int i = 2; i < argc; ++i) {
    const std::string flag = argv[i];
    if (flag == "--parallel") {
      o.parallel = true;
      continue;
    }
    if (i + 1 >= argc) usage("missing value of " + flag);
    const std::string v = argv[++i];
    if (flag == "--socket")
      o.socket = v;
    else if (flag == "--interface")
      o.interface = v;
    else if (flag == "--op")
      o.op = v;
    else if (flag == "--image")
      o.image = v;
    else if (flag == "--net")
      o.net = std::stoul(v, nullptr, 0);
    else if (flag == "--node")
      o.node = std::stoul(v, nullptr, 0);
    else if (flag == "--size")
      o.size = std::stoul(v, nullptr, 0);
    else if (flag == "--count")
      o.count = std::stoul(v, nullptr, 0);
    else if (flag == "--timeout-ms")
      o.timeout_ms = std::stoi(v);
    else if (flag == "--seed")
      o.seed = std::stoul(v, nullptr, 0);
    else if (flag == "--nodes") {
      for (const auto& n : split(v, ',')) o.nodes.push_back(std::stoul(n, nullptr, 0));
    } else if (flag == "--targets") {
      for (const auto& t : split(v, ',')) {
        const auto parts = split(t, ':');
        if (parts.size() != 2) usage("bad target " + t);
        o.targets.emplace_back(std::stoul(parts[0]), std::stoul(parts[1]));
      }
    } else {
      usage("unknown option " + flag);
    }
  }
  return o;
}

std::vector<std::uint8_t> pseudo_random(std::size_t size, std::uint32_t seed) {
  std::mt19937 gen(seed);
  std::vector<std::uint8_t> v(size);
  for (auto& b : v) b = static_cast<std::uint8_t>(gen());
  return v;
}

std::vector<std::uint8_t> read_file(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) usage("cannot read " + path);
  return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

std::string base64(const std::vector<std::uint8_t>& data) {
  static constexpr char kAlphabet[] =
      "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
  std::string out;
  std::size_t i = 0;
  for (; i + 2 < data.size(); i += 3) {
    const std::uint32_t v = (data[i] << 16) | (data[i + 1] << 8) | data[i + 2];
    for (int s = 18; s >= 0; s -= 6) out += kAlphabet[(v >> s) & 0x3F];
  }
  const std::size_t rest = data.size() - i;
  if (rest > 0) {
    const std::uint32_t v = (data[i] << 16) | (rest == 2 ? data[i + 1] << 8 : 0);
    out += kAlphabet[(v >> 18) & 0x3F];
    out += kAlphabet[(v >> 12) & 0x3F];
    out += rest == 2 ? kAlphabet[(v >> 6) & 0x3F] : '=';
    out += '=';
  }
  return out;
}

double ms_since(Clock::time_point t0) {
  return std::chrono::duration<double, std::milli>(Clock::now() - t0).count();
}

int report(bool ok, double ms, const std::string& error, const std::string& extra = "") {
  std::printf("ok=%d\nms=%.1f\n", ok ? 1 : 0, ms);
  if (!error.empty()) std::printf("error=%s\n", error.c_str());
  if (!extra.empty()) std::printf("%s", extra.c_str());
  return ok ? 0 : 1;
}

// --- the endpoint
// ---------------------------------------------------------------------------------

class Endpoint {
 public:
  explicit Endpoint(const std::string& path) {
    sockaddr_un a{};
    a.sun_family = AF_UNIX;
    if (path.size() >= sizeof a.sun_path) usage("socket path too long");
    std::memcpy(a.sun_path, path.c_str(), path.size() + 1);
    fd_ = ::socket(AF_UNIX, SOCK_STREAM | SOCK_CLOEXEC, 0);
    if (fd_ < 0 || ::connect(fd_, reinterpret_cast<sockaddr*>(&a), sizeof a) != 0) {
      std::fprintf(stderr, "remote_sdo_probe: connect %s: %s\n", path.c_str(),
                   std::strerror(errno));
      std::exit(1);
    }
  }
  ~Endpoint() { ::close(fd_); }
  int fd() const { return fd_; }
  void send(const std::string& text) {
    std::size_t done = 0;
    while (done < text.size()) {
      const ssize_t n = ::send(fd_, text.data() + done, text.size() - done, MSG_NOSIGNAL);
      if (n < 0 && errno == EINTR) continue;
      if (n < 0) throw std::runtime_error(std::string("send: ") + std::strerror(errno));
      done += static_cast<std::size_t>(n);
    }
  }
  // A complete line already buffered, without CR LF.
  std::optional<std::string> buffered_line() {
    const auto lf = buffer_.find('\n');
    if (lf == std::string::npos) return std::nullopt;
    std::string l = buffer_.substr(0, lf);
    buffer_.erase(0, lf + 1);
    if (!l.empty() && l.back() == '\r') l.pop_back();
    return l;
  }
  // Reads what is there (after poll said so); false once closed.
  bool fill() {
    char chunk[65536];
    const ssize_t n = ::recv(fd_, chunk, sizeof chunk, 0);
    if (n <= 0) return n < 0 && (errno == EINTR || errno == EAGAIN);
    buffer_.append(chunk, static_cast<std::size_t>(n));
    return true;
  }
  // The next line, waiting up to `timeout`.
  std::optional<std::string> line(std::chrono::milliseconds timeout) {
    const auto deadline = Clock::now() + timeout;
    for (;;) {
      if (auto l = buffered_line()) return l;
      const auto left =
          std::chrono::duration_cast<std::chrono::milliseconds>(deadline - Clock::now());
      if (left.count() <= 0) return std::nullopt;
      pollfd p{fd_, POLLIN, 0};
      if (::poll(&p, 1, static_cast<int>(left.count())) <= 0) continue;
      if (!fill()) return std::nullopt;
    }
  }

 private:
  int fd_ = -1;
  std::string buffer_;
};

std::string ask(Endpoint& e, const std::string& request, std::chrono::milliseconds timeout) {
  e.send(request + "\n");
  return e.line(timeout).value_or("<no answer>");
}

int endpoint_download(const Options& o) {
  Endpoint e(o.socket);
  const auto timeout = std::chrono::milliseconds(o.timeout_ms);
  const std::string block = o.op == "blockdown" ? "1" : "0";
  if (ask(e, "set sdo_block " + block, timeout) != "OK") return report(false, 0, "set sdo_block");
  if (ask(e, "set sdo_timeout " + std::to_string(o.timeout_ms), timeout) != "OK") {
    return report(false, 0, "set sdo_timeout");
  }
  const std::string request = "[1] " + std::to_string(o.net) + " " + std::to_string(o.node) +
                              " w 0x2100 0 d " + base64(pseudo_random(o.size, o.seed));
  const auto t0 = Clock::now();
  const std::string answer = ask(e, request, std::chrono::minutes(10));
  const double ms = ms_since(t0);
  return report(answer == "[1] OK", ms, answer == "[1] OK" ? "" : answer);
}

int endpoint_reads(const Options& o) {
  if (o.targets.empty()) usage("no --targets");
  const auto timeout = std::chrono::milliseconds(o.timeout_ms) + std::chrono::seconds(10);
  const std::size_t lanes = o.parallel ? o.targets.size() : 1;
  std::vector<std::unique_ptr<Endpoint>> clients;
  for (std::size_t i = 0; i < lanes; ++i) clients.push_back(std::make_unique<Endpoint>(o.socket));
  // Request k goes to target k % targets, on lane k % lanes.
  std::vector<std::size_t> next(lanes), outstanding(lanes, 0);
  for (std::size_t l = 0; l < lanes; ++l) next[l] = l;
  std::size_t answered = 0, failed = 0;
  std::string first_error;
  const auto request = [&](std::size_t lane) {
    const std::size_t k = next[lane];
    const auto [net, node] = o.targets[k % o.targets.size()];
    clients[lane]->send("[" + std::to_string(k) + "] " + std::to_string(net) + " " +
                        std::to_string(node) + " r 0x1018 1 u32\n");
    next[lane] += lanes;
    outstanding[lane] = 1;
  };
  const auto t0 = Clock::now();
  for (std::size_t l = 0; l < lanes && next[l] < o.count; ++l) request(l);
  while (answered + failed < o.count) {
    std::vector<pollfd> fds;
    for (auto& c : clients) fds.push_back({c->fd(), POLLIN, 0});
    if (::poll(fds.data(), fds.size(), static_cast<int>(timeout.count())) <= 0) {
      return report(false, ms_since(t0), "timeout after " + std::to_string(answered) + " reads");
    }
    for (std::size_t l = 0; l < lanes; ++l) {
      if ((fds[l].revents & POLLIN) == 0) continue;
      if (!clients[l]->fill()) return report(false, ms_since(t0), "endpoint closed");
      while (auto line = clients[l]->buffered_line()) {
        if (line->find("ERROR") != std::string::npos) {
          ++failed;
          if (first_error.empty()) first_error = *line;
        } else {
          ++answered;
        }
        outstanding[l] = 0;
        if (next[l] < o.count) request(l);
      }
    }
  }
  const double ms = ms_since(t0);
  return report(failed == 0, ms, first_error,
                "reads=" + std::to_string(answered) + "\nfailed=" + std::to_string(failed) + "\n");
}

int endpoint_flash(const Options& o) {
  Endpoint e(o.socket);
  const auto t0 = Clock::now();
  e.send("[1] " + std::to_string(o.net) + " " + std::to_string(o.node) + " flash " + o.image +
         "\n");
  std::size_t progress = 0;
  for (;;) {
    const auto line = e.line(std::chrono::minutes(10));
    if (!line) return report(false, ms_since(t0), "no answer");
    if (line->starts_with("[1] PROGRESS")) {
      ++progress;
      continue;
    }
    const bool ok = *line == "[1] OK";
    return report(ok, ms_since(t0), ok ? "" : *line,
                  "progress_lines=" + std::to_string(progress) + "\n");
  }
}

// --- the master on the surface bus
// ----------------------------------------------------------------

class CanSocket {
 public:
  CanSocket(const std::string& interface, const std::vector<std::uint32_t>& ids) {
    fd_ = ::socket(PF_CAN, SOCK_RAW | SOCK_CLOEXEC, CAN_RAW);
    if (fd_ < 0) throw std::runtime_error("socket(PF_CAN)");
    std::vector<can_filter> filters;
    for (const auto id : ids) filters.push_back({id, CAN_SFF_MASK | CAN_EFF_FLAG | CAN_RTR_FLAG});
    ::setsockopt(fd_, SOL_CAN_RAW, CAN_RAW_FILTER, filters.data(),
                 static_cast<socklen_t>(filters.size() * sizeof(can_filter)));
    ifreq ifr{};
    std::snprintf(ifr.ifr_name, IFNAMSIZ, "%s", interface.c_str());
    if (::ioctl(fd_, SIOCGIFINDEX, &ifr) < 0) throw std::runtime_error("no interface " + interface);
    sockaddr_can a{};
    a.can_family = AF_CAN;
    a.can_ifindex = ifr.ifr_ifindex;
    if (::bind(fd_, reinterpret_cast<sockaddr*>(&a), sizeof a) != 0) {
      throw std::runtime_error("bind " + interface);
    }
  }
  ~CanSocket() { ::close(fd_); }
  int fd() const { return fd_; }
  void send(const Frame& f) {
    can_frame raw{};
    raw.can_id = f.id;
    raw.can_dlc = f.len;
    std::memcpy(raw.data, f.data.data(), f.len);
    for (;;) {
      if (::write(fd_, &raw, sizeof raw) == sizeof raw) return;
      if (errno != ENOBUFS && errno != EAGAIN && errno != EINTR) {
        throw std::runtime_error(std::string("write: ") + std::strerror(errno));
      }
      pollfd p{fd_, POLLOUT, 0};
      ::poll(&p, 1, 10);  // the queue drains as the bus takes frames
    }
  }
  std::optional<Frame> receive() {
    can_frame raw{};
    if (::read(fd_, &raw, sizeof raw) != sizeof raw) return std::nullopt;
    return Frame::from_span(raw.can_id & CAN_SFF_MASK,
                            std::span<const std::uint8_t>(raw.data, raw.can_dlc));
  }

 private:
  int fd_ = -1;
};

// Runs `transfers` at once (one per node) on `socket` until each finishes.
void run_transfers(CanSocket& socket, std::vector<SdoTransfer>& transfers) {
  std::vector<Frame> out;
  const auto flush = [&] {
    for (const auto& f : out) socket.send(f);
    out.clear();
  };
  for (auto& t : transfers) t.start(Clock::now(), out);
  flush();
  for (;;) {
    auto deadline = Clock::time_point::max();
    bool open = false;
    for (auto& t : transfers) {
      if (t.finished()) continue;
      open = true;
      deadline = std::min(deadline, t.deadline());
    }
    if (!open) return;
    const auto wait =
        std::chrono::duration_cast<std::chrono::milliseconds>(deadline - Clock::now());
    pollfd p{socket.fd(), POLLIN, 0};
    const int ready = ::poll(&p, 1, static_cast<int>(std::max<long long>(0, wait.count()) + 1));
    const auto now = Clock::now();
    if (ready > 0) {
      if (const auto f = socket.receive()) {
        for (auto& t : transfers) {
          if (!t.finished()) t.on_frame(*f, now, out);
        }
      }
    }
    for (auto& t : transfers) {
      if (!t.finished() && now >= t.deadline()) t.on_timeout(now, out);
    }
    flush();
  }
}

// "0x05040000 SDO protocol timed out" (SdoAbort codes are the error values).
std::string describe(const SdoTransfer& t) {
  const std::error_code e = t.result().error;
  if (!e) return "";
  char code[16];
  std::snprintf(code, sizeof code, "0x%08X ", static_cast<unsigned>(e.value()));
  return code + e.message();
}

int master_download(const Options& o) {
  const auto node = static_cast<std::uint8_t>(o.node);
  CanSocket socket(o.interface, {0x580u + node});
  SdoTransferOptions opt;
  opt.timeout = std::chrono::milliseconds(o.timeout_ms);
  opt.block_size = o.op == "blockdown" ? 127 : 0;
  std::vector<SdoTransfer> t;
  t.push_back(SdoTransfer::download(node, {0x2100, 0}, pseudo_random(o.size, o.seed), opt));
  const auto t0 = Clock::now();
  run_transfers(socket, t);
  const double ms = ms_since(t0);
  return report(!t[0].result().error, ms, describe(t[0]),
                "bytes_done=" + std::to_string(t[0].bytes_done()) + "\n");
}

int master_reads(const Options& o) {
  if (o.nodes.empty()) usage("no --nodes");
  std::vector<std::uint32_t> ids;
  for (const auto n : o.nodes) ids.push_back(0x580u + n);
  CanSocket socket(o.interface, ids);
  SdoTransferOptions opt;
  opt.timeout = std::chrono::milliseconds(o.timeout_ms);
  std::size_t done = 0, failed = 0;
  std::string first_error;
  const auto t0 = Clock::now();
  while (done + failed < o.count) {
    // Parallel: one read per node at once (a round); otherwise one read.
    std::vector<SdoTransfer> round;
    const std::size_t width = o.parallel ? o.nodes.size() : 1;
    for (std::size_t i = 0; i < width && done + failed + round.size() < o.count; ++i) {
      const std::size_t k = done + failed + round.size();
      round.push_back(SdoTransfer::upload(static_cast<std::uint8_t>(o.nodes[k % o.nodes.size()]),
                                          {0x1018, 1}, opt));
    }
    run_transfers(socket, round);
    for (const auto& t : round) {
      if (t.result().error) {
        ++failed;
        if (first_error.empty()) first_error = describe(t);
      } else {
        ++done;
      }
    }
  }
  const double ms = ms_since(t0);
  return report(failed == 0, ms, first_error,
                "reads=" + std::to_string(done) + "\nfailed=" + std::to_string(failed) + "\n");
}

// Waits up to `timeout` for `frame` on `socket` (whose filter lets it through).
bool await_frame(CanSocket& socket, const Frame& frame, std::chrono::milliseconds timeout) {
  const auto deadline = Clock::now() + timeout;
  for (;;) {
    const auto left =
        std::chrono::duration_cast<std::chrono::milliseconds>(deadline - Clock::now());
    if (left.count() <= 0) return false;
    pollfd p{socket.fd(), POLLIN, 0};
    if (::poll(&p, 1, static_cast<int>(left.count())) <= 0) continue;
    if (const auto f = socket.receive(); f && *f == frame) return true;
  }
}

int master_flash(const Options& o) {
  const auto node = static_cast<std::uint8_t>(o.node);
  const auto image = read_file(o.image);
  if (image.size() < 5) usage("image too short");
  std::uint32_t crc = 0;
  for (int i = 0; i < 4; ++i) crc |= std::uint32_t{image[image.size() - 4 + i]} << (8 * i);
  CanSocket sdo(o.interface, {0x580u + node});
  CanSocket boot(o.interface, {0x700u + node, 0x720u + node});
  SdoTransferOptions opt;
  opt.timeout = std::chrono::milliseconds(o.timeout_ms);
  const auto step = [&](SdoTransfer t) {
    std::vector<SdoTransfer> v;
    v.push_back(std::move(t));
    run_transfers(sdo, v);
    return v[0];
  };
  const auto t0 = Clock::now();
  const auto fail = [&](const std::string& what, const std::string& why) {
    return report(false, ms_since(t0), what + ": " + why);
  };
  auto t = step(SdoTransfer::download(node, {0x1F51, 1}, {0x00}, opt));
  if (t.result().error) return fail("stop", describe(t));
  if (!await_frame(boot, Frame::standard(0x720u + node, {0x00}), std::chrono::seconds(10))) {
    return fail("loader boot-up", "none");
  }
  SdoTransferOptions block = opt;
  block.block_size = 127;
  t = step(SdoTransfer::download(node, {0x1F50, 1}, image, block));
  if (t.result().error) {
    return fail("download", describe(t) + " after " + std::to_string(t.bytes_done()) + " bytes");
  }
  t = step(SdoTransfer::upload(node, {0x1F56, 1}, opt));
  if (t.result().error) return fail("identification", describe(t));
  const auto& id = t.result().data;
  std::uint32_t got = 0;
  for (std::size_t i = 0; i < id.size() && i < 4; ++i) got |= std::uint32_t{id[i]} << (8 * i);
  if (got != crc) return fail("identification", "1F56h differs from the image's CRC");
  t = step(SdoTransfer::download(node, {0x1F51, 1}, {0x01}, opt));
  if (t.result().error) return fail("start", describe(t));
  if (!await_frame(boot, Frame::standard(0x700u + node, {0x00}), std::chrono::seconds(10))) {
    return fail("application boot-up", "none");
  }
  return report(true, ms_since(t0), "");
}

}  // namespace

int main(int argc, char** argv) {
  const Options o = parse(argc, argv);
  try {
    if (o.mode == "endpoint") return endpoint_download(o);
    if (o.mode == "endpoint-reads") return endpoint_reads(o);
    if (o.mode == "endpoint-flash") return endpoint_flash(o);
    if (o.mode == "master") return master_download(o);
    if (o.mode == "master-reads") return master_reads(o);
    if (o.mode == "master-flash") return master_flash(o);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "remote_sdo_probe: %s\n", e.what());
    return 1;
  }
  usage("unknown mode " + o.mode);
}
