// PDO Packets across the bridge (issue 6, docs/pdop.md): four simulated fpga nodes on two pdop
// module buses (vcan1 = module 1, vcan2 = module 2) behind ONE canbridge gateway, a canbridge
// surface on vcan0, a TCP backbone on loopback. Real processes, real SocketCAN; configs in this
// directory. What a master on vcan0 must see:
//  - TPDOP: every node's 256-byte samples, re-segmented under its surface id, whole and in
//    order. Checked with a small reassembler written here from docs/pdop.md sections 2 and 3
//    (deliberately not bridge::PdopReassembler, which is under test inside the bridge).
//  - RPDOP: a 1 KiB packet from the master (bridge::PdopSegmenter driven over a raw socket) is
//    taken by the surface (store and forward: the surface acknowledges it, and gives the final
//    status-1 acknowledgement only after the node accepted the packet), and the gateway segments
//    it toward the node within the node's own credit. The module bus is recorded with kernel
//    receive timestamps and replayed to check the credit, fragment by fragment.
//  - No discards in the final counter lines of the gateway and the surface.
// Everything awaited is a frame or a log line, with a deadline; nothing sleeps.
//
// Surface ids (gateway.yaml): module 1 local 1, 2 -> 1, 2; module 2 local 1, 2 -> 3, 4.
#include <gtest/gtest.h>
#include <linux/can.h>
#include <linux/can/raw.h>
#include <net/if.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <cerrno>
#include <condition_variable>
#include <cstring>
#include <functional>
#include <iostream>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <regex>
#include <sstream>
#include <system_error>
#include <thread>
#include <vector>

#include "routing/pdop_segmenter.hpp"
#include "tests/support/raw_can.hpp"
#include "tests/support/rig_processes.hpp"
#include "tests/support/sdo_master.hpp"

namespace canbridge {
namespace {

using namespace std::chrono_literals;
using can::Frame;
using test::RawCanSocket;
using test::RigProcesses;
using test::SdoMaster;
using test::SdoOutcome;
using Steady = std::chrono::steady_clock;
using KernelTime = std::chrono::system_clock::time_point;  // SO_TIMESTAMPNS: CLOCK_REALTIME

const std::string kDir = std::string(CANBRIDGE_SOURCE_DIR) + "/tests/system_pdop/";

// Upper bound of one awaited event in the (slow) UML guest; the events come much sooner.
constexpr auto kEvent = 10s;

struct Node {
  const char* name;
  std::uint8_t surface;
  std::uint8_t local;
  int module;  // module id, also the vcan number
};
// rig.yaml and gateway.yaml as the master must see them.
const std::array<Node, 4> kNodes = {{
    {"m1-fpga-1", 1, 1, 1},
    {"m1-fpga-2", 2, 2, 1},
    {"m2-fpga-1", 3, 1, 2},
    {"m2-fpga-2", 4, 2, 2},
}};

// The sample streams of rig.yaml: (surface node, TPDO) and the period of its pdop_sample.
struct SampleStream {
  std::uint8_t node;
  unsigned tpdo;
  std::chrono::milliseconds period;
};
const std::array<SampleStream, 5> kStreams = {{
    {1, 1, 20ms},
    {1, 2, 30ms},
    {2, 1, 20ms},
    {3, 1, 20ms},
    {4, 2, 20ms},
}};
constexpr std::size_t kSampleBytes = 256;
constexpr auto kStreamWindow = 3s;

// The RPDOP target: module 2, local 1, surface 3 (local and surface id differ).
constexpr std::uint8_t kTargetSurface = 3;
constexpr std::uint8_t kTargetLocal = 1;
constexpr std::uint8_t kWindow = 4;  // the node's window (rig.yaml), and the master's
constexpr std::size_t kRpdopBytes = 1024;
constexpr std::uint32_t kRpdopFragments = kRpdopBytes / 8;
constexpr std::uint16_t kPacketCount = 0x5F00;  // sub n: RPDOP packets received on RPDO n

long long ms(std::chrono::nanoseconds d) {
  return std::chrono::duration_cast<std::chrono::milliseconds>(d).count();
}
double ms_exact(std::chrono::nanoseconds d) {
  return std::chrono::duration<double, std::milli>(d).count();
}

// Every "<label> N" in a counter line, e.g. all "kernel-drops N" of the gateway's buses.
std::vector<long long> counters(const std::string& line, const std::string& label) {
  std::vector<long long> found;
  const std::regex pattern(label + " ([0-9]+)");
  for (auto it = std::sregex_iterator(line.begin(), line.end(), pattern);
       it != std::sregex_iterator(); ++it) {
    found.push_back(std::stoll((*it)[1].str()));
  }
  return found;
}

// Every frame of one bus that passes `filters`, with the kernel's receive timestamp, read by a
// thread of its own in batches (recvmmsg: the surface bus carries ~8,000 frames/s here). Waits are
// woken by each batch. The socket's own overflows (SO_RXQ_OVFL) are counted: a frame the test
// lost is not a frame the bridge lost, and a check on a gappy log would blame the bridge.
class BusLog {
 public:
  struct Entry {
    KernelTime at;
    Frame frame;
  };
  struct Found {
    Entry entry;
    std::size_t index;  // position in the log; search on from index + 1
  };

  explicit BusLog(const std::string& interface, const std::vector<can_filter>& filters = {})
      : fd_(open(interface, filters)), reader_([this](std::stop_token stop) { read(stop); }) {}
  ~BusLog() {
    reader_.request_stop();
    reader_.join();
    ::close(fd_);
  }
  BusLog(const BusLog&) = delete;
  BusLog& operator=(const BusLog&) = delete;

  // Writes one frame (data or remote), waiting up to a second for room; throws on error.
  void send(const Frame& frame) {
    can_frame cf{};
    cf.can_id = frame.id | (frame.is_remote() ? CAN_RTR_FLAG : 0u);
    cf.len = frame.len;
    std::memcpy(cf.data, frame.data.data(), frame.len);
    const auto deadline = Steady::now() + 1s;
    for (;;) {
      const ssize_t n = ::write(fd_, &cf, sizeof cf);
      if (n == static_cast<ssize_t>(sizeof cf)) return;
      const int error = n < 0 ? errno : EIO;
      if ((error != EAGAIN && error != ENOBUFS && error != EINTR) || Steady::now() > deadline) {
        throw std::system_error(error, std::system_category(), "CAN write " + to_string(frame));
      }
      pollfd p{fd_, POLLOUT, 0};
      ::poll(&p, 1, 10);
    }
  }

  std::size_t mark() const {
    std::lock_guard lock(mutex_);
    return entries_.size();
  }
  // The first entry at or after position `from` that matches, waiting up to `timeout` for it.
  std::optional<Found> wait_for(std::size_t from, const std::function<bool(const Entry&)>& match,
                                std::chrono::nanoseconds timeout) {
    std::unique_lock lock(mutex_);
    std::optional<Found> found;
    std::size_t next = from;
    changed_.wait_for(lock, timeout, [&] {
      for (; next < entries_.size(); ++next) {
        if (match(entries_[next])) {
          found = Found{entries_[next], next};
          return true;
        }
      }
      return false;
    });
    return found;
  }
  std::optional<Found> wait_for_frame(std::size_t from, const Frame& frame,
                                      std::chrono::nanoseconds timeout) {
    return wait_for(
        from, [&](const Entry& e) { return e.frame == frame; }, timeout);
  }
  std::vector<Entry> entries(std::size_t from = 0) const {
    std::lock_guard lock(mutex_);
    return {entries_.begin() + static_cast<std::ptrdiff_t>(std::min(from, entries_.size())),
            entries_.end()};
  }
  // Frames the kernel dropped because this socket's queue was full.
  std::uint32_t drops() const {
    std::lock_guard lock(mutex_);
    return drops_;
  }

 private:
  static int open(const std::string& interface, const std::vector<can_filter>& filters) {
    const int fd = ::socket(PF_CAN, SOCK_RAW | SOCK_NONBLOCK | SOCK_CLOEXEC, CAN_RAW);
    if (fd < 0) throw std::system_error(errno, std::system_category(), "socket(PF_CAN)");
    const int on = 1;
    // 8 MiB of receive queue: more than the whole test's frames on any bus; FORCE needs root
    // (the rig's guest), plain SO_RCVBUF is capped by rmem_max.
    const int bytes = 8 << 20;
    if (::setsockopt(fd, SOL_SOCKET, SO_RCVBUFFORCE, &bytes, sizeof bytes) != 0) {
      ::setsockopt(fd, SOL_SOCKET, SO_RCVBUF, &bytes, sizeof bytes);
    }
    int error = 0;
    if (::setsockopt(fd, SOL_SOCKET, SO_TIMESTAMPNS, &on, sizeof on) != 0 ||
        ::setsockopt(fd, SOL_SOCKET, SO_RXQ_OVFL, &on, sizeof on) != 0 ||
        (!filters.empty() &&
         ::setsockopt(fd, SOL_CAN_RAW, CAN_RAW_FILTER, filters.data(),
                      static_cast<socklen_t>(filters.size() * sizeof(can_filter))) != 0)) {
      error = errno;
    }
    sockaddr_can addr{};
    addr.can_family = AF_CAN;
    addr.can_ifindex = static_cast<int>(::if_nametoindex(interface.c_str()));
    if (error == 0 && addr.can_ifindex == 0) error = ENODEV;
    if (error == 0 && ::bind(fd, reinterpret_cast<const sockaddr*>(&addr), sizeof addr) != 0) {
      error = errno;
    }
    if (error != 0) {
      ::close(fd);
      throw std::system_error(error, std::system_category(), "CAN socket on " + interface);
    }
    return fd;
  }

  void read(const std::stop_token& stop) {
    constexpr std::size_t kBatch = 64;
    std::array<can_frame, kBatch> frames{};
    std::array<iovec, kBatch> iov{};
    std::array<std::array<char, CMSG_SPACE(sizeof(timespec)) + CMSG_SPACE(sizeof(std::uint32_t))>,
               kBatch>
        control{};
    std::array<mmsghdr, kBatch> msgs{};
    std::vector<Entry> batch;
    while (!stop.stop_requested()) {
      // The timeout only bounds how late the stop request is seen; frames wake it at once.
      pollfd p{fd_, POLLIN, 0};
      if (::poll(&p, 1, 50) <= 0) continue;
      for (std::size_t i = 0; i < kBatch; ++i) {
        iov[i] = {&frames[i], sizeof(can_frame)};
        msgs[i] = {};
        msgs[i].msg_hdr.msg_iov = &iov[i];
        msgs[i].msg_hdr.msg_iovlen = 1;
        msgs[i].msg_hdr.msg_control = control[i].data();
        msgs[i].msg_hdr.msg_controllen = control[i].size();
      }
      const int n = ::recvmmsg(fd_, msgs.data(), kBatch, MSG_DONTWAIT, nullptr);
      if (n <= 0) continue;  // EAGAIN, ENETDOWN, EINTR: poll again
      batch.clear();
      std::optional<std::uint32_t> dropped;
      for (int i = 0; i < n; ++i) {
        if (msgs[i].msg_len != sizeof(can_frame)) continue;
        Entry e{KernelTime{}, Frame{}};
        for (cmsghdr* c = CMSG_FIRSTHDR(&msgs[i].msg_hdr); c != nullptr;
             c = CMSG_NXTHDR(&msgs[i].msg_hdr, c)) {
          if (c->cmsg_level != SOL_SOCKET) continue;
          if (c->cmsg_type == SO_TIMESTAMPNS) {
            timespec ts;
            std::memcpy(&ts, CMSG_DATA(c), sizeof ts);
            e.at = KernelTime{std::chrono::duration_cast<KernelTime::duration>(
                std::chrono::seconds(ts.tv_sec) + std::chrono::nanoseconds(ts.tv_nsec))};
          } else if (c->cmsg_type == SO_RXQ_OVFL) {
            std::uint32_t count;
            std::memcpy(&count, CMSG_DATA(c), sizeof count);
            dropped = count;  // cumulative for the socket
          }
        }
        const can_frame& cf = frames[static_cast<std::size_t>(i)];
        e.frame.flags =
            static_cast<std::uint8_t>(((cf.can_id & CAN_EFF_FLAG) ? can::FrameFlags::extended : 0) |
                                      ((cf.can_id & CAN_RTR_FLAG) ? can::FrameFlags::remote : 0));
        e.frame.id = cf.can_id & ((cf.can_id & CAN_EFF_FLAG) ? CAN_EFF_MASK : CAN_SFF_MASK);
        e.frame.len = std::min<std::uint8_t>(cf.len, 8);
        std::memcpy(e.frame.data.data(), cf.data, e.frame.len);
        batch.push_back(e);
      }
      {
        std::lock_guard lock(mutex_);
        entries_.insert(entries_.end(), batch.begin(), batch.end());
        if (dropped) drops_ = std::max(drops_, *dropped);
      }
      changed_.notify_all();
    }
  }

  int fd_;
  mutable std::mutex mutex_;
  std::condition_variable changed_;
  std::vector<Entry> entries_;
  std::uint32_t drops_ = 0;
  std::jthread reader_;  // last: started after the members it uses exist
};

// The processes of the suite: surface, gateway (connecting straight to the surface's port),
// simulated nodes.
test::RigOptions rig_options() {
  return {.canbridge = CANBRIDGE_BIN,
          .sim = CANBRIDGE_SIM_BIN,
          .link_emulator = "",  // none: the gateway connects to the surface's port
          .link_emulator_args = {},
          .config_dir = kDir,
          .port_placeholder = "${SURFACE_PORT}",
          .surface_name = "pdop-surface",
          .gateway_name = "pdop-gateway",
          .sim_ready = "ready 4 nodes on 2 buses",
          .event_timeout = kEvent};
}

bool any_failure() {
  return ::testing::UnitTest::GetInstance()->failed_test_count() > 0;
}

// --- an independent TPDOP receiver (docs/pdop.md sections 2 and 3) ---------------------------

// One (node, TPDO) stream as a master reassembles it, checking each packet against the sample
// layout of the pdop_sample traffic (sim/sim_node.cpp): a 4-byte little-endian sequence number,
// then bytes (seq + i) mod 256. The window starts at an arbitrary frame, so the stream first
// waits for the end of a packet (a c = 0 fragment) and starts with the packet after it; from
// then on every rule of section 3 is checked and every violation recorded.
class SampleStreamCheck {
 public:
  void on_fragment(bool toggle, bool continued, std::span<const std::uint8_t> data) {
    ++frames_;
    if (data.empty() && !continued) {
      fail("zero-length TPDOP frame (a protocol error, section 2)");
      state_ = State::idle;
      return;
    }
    switch (state_) {
      case State::joining:
        if (!continued) state_ = State::idle;
        return;
      case State::resync:
        if (!continued) state_ = State::idle;
        return;
      case State::idle:
        if (toggle) {
          fail("t = 1 with no packet open: first fragment missing");
          state_ = continued ? State::resync : State::idle;
          return;
        }
        bytes_.clear();
        interleaved_ = interleaved_same_node_ = false;
        break;
      case State::assembling:
        if (toggle != expected_toggle_) {
          fail("toggle error after " + std::to_string(bytes_.size() / 8) + " fragments");
          state_ = continued ? State::resync : State::idle;
          return;
        }
        break;
    }
    if (continued && data.size() < 8) {
      fail("short fragment of " + std::to_string(data.size()) + " bytes with c = 1");
      state_ = State::resync;
      return;
    }
    bytes_.insert(bytes_.end(), data.begin(), data.end());
    if (bytes_.size() > 4096) {
      fail("packet grows past 4096 bytes");
      state_ = continued ? State::resync : State::idle;
      return;
    }
    if (continued) {
      state_ = State::assembling;
      expected_toggle_ = !toggle;
      return;
    }
    state_ = State::idle;
    on_packet();
  }

  // Another stream's fragment arrived while this one had a packet open.
  void interleaved_by(bool same_node) {
    if (state_ != State::assembling) return;
    interleaved_ = true;
    interleaved_same_node_ = interleaved_same_node_ || same_node;
  }

  std::size_t packets() const { return packets_; }
  // Complete packets whose fragments were interleaved with another stream's (of the same node).
  std::size_t interleaved() const { return interleaved_packets_; }
  std::size_t interleaved_same_node() const { return interleaved_same_node_packets_; }
  std::size_t frames() const { return frames_; }
  std::size_t errors() const { return errors_; }
  std::optional<std::uint32_t> first() const { return first_; }
  std::optional<std::uint32_t> last() const { return last_; }
  const std::vector<std::string>& first_errors() const { return first_errors_; }

 private:
  enum class State { joining, idle, assembling, resync };

  void on_packet() {
    ++packets_;
    interleaved_packets_ += interleaved_ ? 1 : 0;
    interleaved_same_node_packets_ += interleaved_same_node_ ? 1 : 0;
    if (bytes_.size() != kSampleBytes) {
      fail("packet of " + std::to_string(bytes_.size()) + " bytes");
      return;
    }
    std::uint32_t seq = 0;
    for (std::size_t i = 0; i < 4; ++i) seq |= std::uint32_t{bytes_[i]} << (8 * i);
    for (std::size_t i = 4; i < bytes_.size(); ++i) {
      if (bytes_[i] != static_cast<std::uint8_t>(seq + i)) {
        fail("sample " + std::to_string(seq) + ": byte " + std::to_string(i) + " is " +
             std::to_string(bytes_[i]));
        break;
      }
    }
    if (last_ && seq != *last_ + 1) {
      fail("sample " + std::to_string(seq) + " after " + std::to_string(*last_) +
           (seq <= *last_ ? " (repeat)" : " (gap)"));
    }
    if (!first_) first_ = seq;
    last_ = seq;
  }
  void fail(const std::string& what) {
    ++errors_;
    if (first_errors_.size() < 5) first_errors_.push_back(what);
  }

  State state_ = State::joining;
  bool expected_toggle_ = false;
  std::vector<std::uint8_t> bytes_;
  bool interleaved_ = false, interleaved_same_node_ = false;
  std::size_t frames_ = 0, packets_ = 0, errors_ = 0;
  std::size_t interleaved_packets_ = 0, interleaved_same_node_packets_ = 0;
  std::optional<std::uint32_t> first_, last_;
  std::vector<std::string> first_errors_;
};

// The master's 1 KiB packet: every 8-byte fragment differs from the others and from its
// neighbours, so a repeated or skipped fragment shows in the bytes too.
std::vector<std::uint8_t> rpdop_packet() {
  std::vector<std::uint8_t> v(kRpdopBytes);
  for (std::size_t i = 0; i < v.size(); ++i)
    v[i] = static_cast<std::uint8_t>(i * 7 + i / 256 + 0x5A);
  return v;
}

// `received` of an acknowledgement (docs/pdop.md section 4.1).
std::uint32_t received_of(const Frame& ack) {
  return static_cast<std::uint32_t>(ack.data[2] | ack.data[3] << 8);
}

// --- the suite ---------------------------------------------------------------------------------

class PdopSystem : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    surface_log_ = std::make_unique<BusLog>("vcan0");
    // The module bus of the RPDOP target: its RPDO1 fragments (any t/c, data frames only), its
    // acknowledgement identifier (data and remote) and its SDO; the sample streams stay out.
    module_log_ = std::make_unique<BusLog>(
        "vcan2", std::vector<can_filter>{
                     {0x200u | kTargetLocal, 0x79Fu | CAN_EFF_FLAG | CAN_RTR_FLAG},
                     {0x680u | kTargetLocal, CAN_SFF_MASK | CAN_EFF_FLAG},
                     {0x600u | kTargetLocal, CAN_SFF_MASK | CAN_EFF_FLAG | CAN_RTR_FLAG},
                     {0x580u | kTargetLocal, CAN_SFF_MASK | CAN_EFF_FLAG | CAN_RTR_FLAG},
                 });
    processes_ = std::make_unique<RigProcesses>(rig_options());
    bring_up();
  }
  static void TearDownTestSuite() {
    if (processes_) {
      processes_->stop();
      processes_->print_logs(any_failure());
    }
    processes_.reset();
    module_log_.reset();
    surface_log_.reset();
  }
  void SetUp() override {
    ASSERT_TRUE(operational_) << "the set-up failed (see the first failure)";
    ASSERT_NO_FATAL_FAILURE(processes_->expect_running());
  }

  // Processes, every node's heartbeat under its surface id, then NMT start broadcast from vcan0
  // (it crosses the bridge to every module) and every node operational.
  static void bring_up() {
    ASSERT_NO_FATAL_FAILURE(processes_->start());
    for (const Node& n : kNodes) {
      ASSERT_TRUE(
          surface_log_->wait_for_frame(0, Frame::standard(0x700u + n.surface, {0x7F}), kEvent))
          << n.name << ": no pre-operational heartbeat on 0x" << std::hex << 0x700 + n.surface;
    }
    const std::size_t mark = surface_log_->mark();
    const auto sent = Steady::now();
    surface_log_->send(Frame::standard(0x000, {0x01, 0x00}));
    for (const Node& n : kNodes) {
      ASSERT_TRUE(
          surface_log_->wait_for_frame(mark, Frame::standard(0x700u + n.surface, {0x05}), kEvent))
          << n.name << ": not operational after NMT start (all nodes)";
    }
    std::cout << "[  nmt     ] every node operational " << ms(Steady::now() - sent)
              << " ms after NMT start\n";
    operational_ = true;
  }

  // 5F00h:01 of the RPDOP target by SDO through the bridge (its surface id).
  // On failure, `outcome->failure` also lists the SDO frames both logs saw meanwhile.
  static std::optional<std::uint32_t> rpdo1_packets(SdoOutcome* outcome) {
    const std::size_t surface_mark = surface_log_->mark();
    const std::size_t module_mark = module_log_->mark();
    // Opened now (it holds no older frames to skip), and only for the node's SDO: unfiltered, a
    // reader that loses the CPU for a few ms overflows on the sample streams.
    RawCanSocket socket("vcan0", {0x580u + kTargetSurface});
    SdoMaster master(socket);
    const auto value = master.read_u32(kTargetSurface, kPacketCount, 1, outcome);
    if (!value) {
      std::ostringstream trace;
      const auto list = [&](const char* bus, const std::vector<BusLog::Entry>& log,
                            std::uint32_t request, std::uint32_t response) {
        for (const auto& e : log) {
          if (e.frame.id != request && e.frame.id != response) continue;
          trace << "\n  " << bus << " "
                << std::chrono::duration_cast<std::chrono::microseconds>(e.at.time_since_epoch())
                       .count()
                << " us " << to_string(e.frame);
        }
      };
      list("vcan0", surface_log_->entries(surface_mark), 0x600u + kTargetSurface,
           0x580u + kTargetSurface);
      list("vcan2", module_log_->entries(module_mark), 0x600u + kTargetLocal,
           0x580u + kTargetLocal);
      outcome->failure += "; SDO frames seen:" + trace.str();
    }
    return value;
  }

  static inline std::unique_ptr<BusLog> surface_log_;
  static inline std::unique_ptr<BusLog> module_log_;
  static inline std::unique_ptr<RigProcesses> processes_;
  static inline bool operational_ = false;
  static inline long long rpdop_complete_ = 0;  // RPDOP packets the master completed
};

// The set-up itself: the packet counter the RPDOP test relies on is readable through the bridge.
TEST_F(PdopSystem, PacketCounterIsReadableBySdo) {
  SdoOutcome o;
  EXPECT_TRUE(rpdo1_packets(&o)) << describe(o);
}

// (a) TPDOP: every (surface node, TPDO) stream, read on vcan0 for kStreamWindow of kernel time.
TEST_F(PdopSystem, SampleStreamsArriveWholeInOrderAndUnderSurfaceIds) {
  const std::size_t from = surface_log_->mark();
  const KernelTime begin = std::chrono::system_clock::now();
  const KernelTime end = begin + kStreamWindow;
  ASSERT_TRUE(surface_log_->wait_for(
      from, [&](const BusLog::Entry& e) { return e.at >= end; }, kStreamWindow + kEvent))
      << "vcan0 fell silent";
  const auto log = surface_log_->entries(from);

  std::map<std::pair<std::uint8_t, unsigned>, SampleStreamCheck> streams;
  for (const SampleStream& s : kStreams) streams[{s.node, s.tpdo}];
  std::size_t foreign = 0, in_window = 0;
  for (const auto& e : log) {
    if (e.at < begin || e.at >= end) continue;
    ++in_window;
    const Frame& f = e.frame;
    if (f.is_extended() || f.is_remote()) continue;
    const unsigned function = f.id >> 7;
    if (function != 3 && function != 5 && function != 7 && function != 9) continue;
    const auto node = static_cast<std::uint8_t>(f.id & 0x1F);
    const unsigned tpdo = (function - 1) / 2;
    auto it = streams.find({node, tpdo});
    if (it == streams.end()) {
      if (++foreign <= 5) ADD_FAILURE() << "TPDO frame of no sample stream: " << to_string(f);
      continue;
    }
    for (auto& [key, other] : streams) {
      if (key != it->first) other.interleaved_by(key.first == node);
    }
    it->second.on_fragment((f.id & 0x40) != 0, (f.id & 0x20) != 0, f.payload());
  }

  std::cout << "[  tpdop   ] " << in_window << " frames on vcan0 in " << ms(end - begin) << " ms:";
  for (const SampleStream& s : kStreams) {
    const SampleStreamCheck& c = streams[{s.node, s.tpdo}];
    std::cout << " node " << int(s.node) << " TPDO" << s.tpdo << " " << c.packets()
              << " packets (samples " << (c.first() ? std::to_string(*c.first()) : "-") << ".."
              << (c.last() ? std::to_string(*c.last()) : "-") << ", " << c.interleaved()
              << " interleaved with another stream, " << c.interleaved_same_node()
              << " with the same node's other TPDO, " << c.errors() << " errors);";
  }
  std::cout << "\n";

  ASSERT_EQ(surface_log_->drops(), 0u)
      << "the test's own vcan0 socket overflowed: the log has gaps the bridge did not make";
  for (const SampleStream& s : kStreams) {
    SCOPED_TRACE("surface node " + std::to_string(s.node) + " TPDO" + std::to_string(s.tpdo));
    const SampleStreamCheck& c = streams[{s.node, s.tpdo}];
    EXPECT_EQ(c.errors(), 0u) << [&] {
      std::string all;
      for (const auto& e : c.first_errors()) all += "\n  " + e;
      return "first errors:" + all;
    }();
    const auto expected = static_cast<std::size_t>(0.8 * ms(kStreamWindow) / s.period.count());
    EXPECT_GE(c.packets(), expected) << c.frames() << " fragments";
  }
}

// (b) RPDOP: 1 KiB from a master on vcan0 to surface node 3 (module 2, local 1) on RPDO1.
TEST_F(PdopSystem, KilobyteRpdopIsStoredForwardedAndPacedByTheNode) {
  SdoOutcome sdo;
  const auto before = rpdo1_packets(&sdo);
  ASSERT_TRUE(before) << "5F00h:01 before: " << describe(sdo);

  // The master: the real sender core on a raw socket that sees the acknowledgement range only
  // (the segmenter looks at nothing else; the sample streams would only cost it time).
  BusLog master_io("vcan0", {{0x680, 0x7E0u | CAN_EFF_FLAG | CAN_RTR_FLAG}});
  bridge::PdopSegmenterOptions options;
  options.window = kWindow;
  bridge::PdopSegmenter master(options);
  const auto packet = rpdop_packet();

  const std::size_t surface_mark = surface_log_->mark();
  const std::size_t module_mark = module_log_->mark();
  std::size_t next = master_io.mark();
  bridge::PdopSegmenter::Output out;
  const auto flush = [&] {
    for (const Frame& f : out.frames) master_io.send(f);
    out.frames.clear();
  };
  const auto started = Steady::now();
  master.submit(kTargetSurface, 1, packet, 1, started, out);
  flush();
  const auto give_up = started + kEvent;
  while (out.outcomes.empty() && Steady::now() < give_up) {
    const auto deadline = std::min(master.next_deadline().value_or(give_up), give_up);
    const auto ack = master_io.wait_for(
        next, [](const BusLog::Entry&) { return true; },
        std::max(Steady::duration::zero(), deadline - Steady::now()));
    if (ack) {
      next = ack->index + 1;
      master.on_frame(ack->entry.frame, Steady::now(), out);
    }
    if (master.next_deadline() && *master.next_deadline() <= Steady::now()) {
      master.tick(Steady::now(), out);
    }
    flush();
  }
  ASSERT_EQ(out.outcomes.size(), 1u) << "no outcome within " << ms(kEvent) << " ms";
  const bridge::PdopOutcome outcome = out.outcomes.front();
  EXPECT_EQ(outcome.result, bridge::PdopResult::complete) << to_string(outcome);
  if (outcome.result == bridge::PdopResult::complete) ++rpdop_complete_;
  EXPECT_EQ(outcome.fragments, kRpdopFragments) << to_string(outcome);

  const auto after = rpdo1_packets(&sdo);
  ASSERT_TRUE(after) << "5F00h:01 after: " << describe(sdo);
  EXPECT_EQ(*after, *before + 1) << "RPDO1 packets the node received";

  // The surface bus: the surface's acknowledgements to the master (0x680 + surface id).
  const auto is_final = [](std::uint32_t id) {
    return [id](const BusLog::Entry& e) {
      return e.frame.id == id && !e.frame.is_remote() && e.frame.len == 5 && e.frame.data[0] == 1 &&
             e.frame.data[1] == 1;
    };
  };
  const auto surface_final =
      surface_log_->wait_for(surface_mark, is_final(0x680u + kTargetSurface), kEvent);
  ASSERT_TRUE(surface_final) << "no status-1 acknowledgement on vcan0";
  // Window acknowledgements (received < all) grant the relay's credit, the window. The master
  // asks (remote frame) when no acknowledgement came for ack_timeout, e.g. while the gateway
  // still segments; an answer then is "in progress, all received, credit 0" (forwarded, outcome
  // not known yet) or, once known, the status 1 again (section 4.3: the packet finished last).
  std::size_t surface_progress = 0, surface_finals = 0, surface_answers = 0, master_requests = 0;
  for (const auto& e : surface_log_->entries(surface_mark)) {
    const Frame& f = e.frame;
    if (f.id != 0x680u + kTargetSurface) continue;
    if (f.is_remote()) {
      ++master_requests;
      continue;
    }
    if (f.len == 5 && f.data[0] == 1 && f.data[1] == 0 && received_of(f) < kRpdopFragments) {
      ++surface_progress;
      EXPECT_EQ(f.data[4], kWindow) << "window acknowledgement on vcan0: " << to_string(f);
    } else if (f.len == 5 && f.data[0] == 1 && f.data[1] == 0) {
      ++surface_answers;
      EXPECT_EQ(f.data[4], 0) << "all fragments taken, yet credit: " << to_string(f);
    } else if (f.len == 5 && f.data[0] == 1 && f.data[1] == 1) {
      ++surface_finals;
      EXPECT_EQ(received_of(f), kRpdopFragments) << to_string(f);
    } else {
      ADD_FAILURE() << "unexpected frame on vcan0: " << to_string(f);
    }
  }
  EXPECT_EQ(master_requests, outcome.ack_requests) << "the master's requests seen on vcan0";
  EXPECT_LE(surface_answers + surface_finals, 1 + master_requests)
      << "acknowledgements on vcan0 after the last fragment: one final, one per request";

  // The module bus, replayed in order: the gateway's fragments against the node's credit.
  const auto node_final =
      module_log_->wait_for(module_mark, is_final(0x680u + kTargetLocal), kEvent);
  ASSERT_TRUE(node_final) << "no status-1 acknowledgement of the node on vcan2";
  std::uint32_t limit = kWindow;  // before the node's first acknowledgement
  std::uint32_t next_fragment = 0;
  // Set by the first acknowledgement after a request: the next fragment is `resume_at`.
  bool resuming = false;
  std::uint32_t resume_at = 0;
  bool request_out = false;
  std::size_t fragments = 0, node_progress = 0, requests = 0, violations = 0, bad_frames = 0;
  std::uint32_t most_outstanding = 0, acked = 0;
  std::optional<KernelTime> first_fragment;
  for (const auto& e : module_log_->entries(module_mark)) {
    if (e.at > node_final->entry.at) break;
    const Frame& f = e.frame;
    if (f.id == 0x680u + kTargetLocal) {
      if (f.is_remote()) {
        ++requests;
        request_out = true;
        continue;
      }
      if (f.len != 5 || f.data[0] != 1) continue;  // another RPDO's (none is sent here)
      const std::uint32_t received = received_of(f);
      if (f.data[1] >= 0x80) ADD_FAILURE() << "node abort on vcan2: " << to_string(f);
      if (f.data[1] == 0) ++node_progress;
      if (request_out) {
        resuming = true;
        resume_at = received;
        request_out = false;
      }
      acked = received;
      limit = received + f.data[4];
      continue;
    }
    if ((f.id & 0x79F) != (0x200u | kTargetLocal)) continue;  // its SDO (for failure traces)
    const bool toggle = (f.id & 0x40) != 0, continued = (f.id & 0x20) != 0;
    if (f.len == 0 && !continued) {
      ADD_FAILURE() << "sender abort on vcan2: " << to_string(f);
      continue;
    }
    const std::uint32_t k = resuming ? resume_at : next_fragment;
    resuming = false;
    next_fragment = k + 1;
    ++fragments;
    if (!first_fragment) first_fragment = e.at;
    most_outstanding = std::max(most_outstanding, k + 1 - acked);
    if (k >= limit && ++violations <= 5) {
      ADD_FAILURE() << "fragment " << k << " sent with limit " << limit << " (received + credit "
                    << "of the node's last acknowledgement)";
    }
    const bool last = k == kRpdopFragments - 1;
    const bool shape_ok = k < kRpdopFragments && toggle == (k % 2 == 1) && continued == !last &&
                          f.len == 8 &&
                          std::equal(f.data.begin(), f.data.begin() + 8, packet.begin() + 8 * k);
    if (!shape_ok && ++bad_frames <= 5) {
      ADD_FAILURE() << "fragment " << k << " on vcan2 is not the packet's: " << to_string(f);
    }
  }
  EXPECT_EQ(next_fragment, kRpdopFragments) << "the gateway's last fragment index + 1";
  EXPECT_EQ(received_of(node_final->entry.frame), kRpdopFragments);
  EXPECT_EQ(violations, 0u) << "fragments beyond the node's credit";
  // Store and forward: the master hears "complete" only after the node said so (both kernel
  // receive timestamps, CLOCK_REALTIME of one kernel).
  EXPECT_LT(node_final->entry.at, surface_final->entry.at)
      << "the surface confirmed the packet before the node had it";

  // When the master's first fragment (k = 0: t = 0, c = 1) was on vcan0.
  const auto master_first = surface_log_->wait_for_frame(
      surface_mark, Frame::from_span(0x220u | kTargetSurface, std::span(packet).first(8)), 0s);
  std::cout << "[  rpdop   ] " << kRpdopBytes << " bytes to node " << int(kTargetSurface) << ": "
            << to_string(outcome) << "; vcan0: " << surface_progress << " window acks with credit "
            << int(kWindow) << ", " << master_requests << " requests of the master answered by "
            << surface_answers << " 'all in, credit 0' + " << surface_finals
            << " status 1; vcan2: " << fragments << " fragments from the gateway, " << node_progress
            << " in-progress acks of the node, " << requests << " requests, at most "
            << most_outstanding << " fragments outstanding";
  if (master_first && first_fragment) {
    std::cout << "; master's first fragment on vcan0 -> gateway's on vcan2 "
              << ms_exact(*first_fragment - master_first->entry.at) << " ms";
  }
  std::cout << "; node's final ack on vcan2 -> surface's on vcan0 "
            << ms_exact(surface_final->entry.at - node_final->entry.at) << " ms\n";
  ASSERT_EQ(module_log_->drops(), 0u) << "the test's own vcan2 socket overflowed";
  ASSERT_EQ(surface_log_->drops(), 0u) << "the test's own vcan0 socket overflowed";
}

// (c) Last: the processes stop; the final counter lines show nothing discarded, every TPDOP
// packet the gateway reassembled reached the surface, and the RPDOP packets of this run completed.
TEST_F(PdopSystem, FinalCountersShowNoDiscards) {
  processes_->stop();
  const std::string& gateway = processes_->gateway_final;
  const std::string& surface = processes_->surface_final;
  std::cout << "[  final   ] " << gateway << "\n[  final   ] " << surface << "\n";
  ASSERT_NE(gateway.find("gateway pdop-gateway:"), std::string::npos) << gateway;
  ASSERT_NE(surface.find("surface pdop-surface:"), std::string::npos) << surface;
  for (const auto* line : {&gateway, &surface}) {
    const auto drops = counters(*line, "kernel-drops");
    EXPECT_FALSE(drops.empty()) << *line;
    for (long long d : drops) EXPECT_EQ(d, 0) << "kernel-drops: " << *line;
    // Not "conflated": heartbeat states are latest-value data, conflated whenever two of a node
    // wait together (the slow guest), and packets never pass the frame queue.
    for (const char* label :
         {"process-dropped", "discarded", "dropped-frames", "malformed", "failed", "refused"}) {
      for (long long d : counters(*line, label)) EXPECT_EQ(d, 0) << label << ": " << *line;
    }
  }
  // "pdop packets N": reassembled at the gateway, re-segmented at the surface. The nodes stop
  // first, so nothing is in flight when the gateway stops.
  const auto reassembled = counters(gateway, "\\bpdop packets");  // not "rpdop packets"
  const auto delivered = counters(surface, "\\bpdop packets");
  ASSERT_EQ(reassembled.size(), 1u) << gateway;
  ASSERT_EQ(delivered.size(), 1u) << surface;
  EXPECT_GT(reassembled[0], 0) << gateway;
  EXPECT_EQ(delivered[0], reassembled[0]) << "TPDOP packets: gateway vs surface";
  // "rpdop packets N complete M" (gateway) and "rpdop forwarded N complete M" (surface).
  const std::vector<long long> done{rpdop_complete_};
  EXPECT_EQ(counters(gateway, "rpdop packets"), done) << gateway;
  EXPECT_EQ(counters(surface, "rpdop forwarded"), done) << surface;
  EXPECT_EQ(counters(gateway, "complete"), done) << gateway;
  EXPECT_EQ(counters(surface, "complete"), done) << surface;
}

}  // namespace
}  // namespace canbridge
