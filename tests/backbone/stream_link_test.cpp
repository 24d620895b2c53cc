#include "backbone/stream_link.hpp"

#include <gtest/gtest.h>
#include <spdlog/sinks/ostream_sink.h>
#include <spdlog/spdlog.h>

#include <boost/asio/as_tuple.hpp>
#include <boost/asio/co_spawn.hpp>
#include <boost/asio/read.hpp>
#include <boost/asio/use_awaitable.hpp>
#include <boost/asio/write.hpp>
#include <deque>
#include <sstream>
#include <stdexcept>

#include "tests/backbone/link_test_support.hpp"
#include "tests/backbone/test_support.hpp"
#include "tests/support/spawn_checked.hpp"

namespace canbridge::backbone {
namespace {

namespace asio = boost::asio;
using namespace std::chrono_literals;
using testing::bytes;
using testing::Inbox;
using testing::numbered;
using testing::Outbox;
using testing::run_until;
using testing::tcp_nodelay;
using testing::to_string;

class StreamLinkTest : public ::testing::Test {
 protected:
  void SetUp() override {
    auto sockets = testing::connected_sockets(io);
    a = StreamLink::create(std::move(sockets.client));
    b = StreamLink::create(std::move(sockets.server));
  }
  void TearDown() override {
    if (a) a->close();
    if (b) b->close();
    EXPECT_TRUE(testing::drains_within(io, 2s));
  }

  asio::io_context io;
  std::shared_ptr<StreamLink> a;
  std::shared_ptr<StreamLink> b;
  Outbox a_out, b_out;
  Inbox a_in, b_in;
};

TEST_F(StreamLinkTest, TenThousandMessagesArriveInOrderAndIntact) {
  constexpr std::uint32_t kCount = 10'000;
  a->start(a_in.on_message(), a_out.source(), a_in.on_closed());
  b->start(b_in.on_message(), b_out.source(), b_in.on_closed());
  for (std::uint32_t i = 0; i < kCount; ++i) {
    a_out.pending.push_back(numbered(i));
    a->wake_writer();
    if (i % 97 == 0) io.poll();  // let writes happen while messages keep coming
  }
  ASSERT_TRUE(run_until(io, [&] { return b_in.messages.size() == kCount; }));
  for (std::uint32_t i = 0; i < kCount; ++i) {
    ASSERT_EQ(b_in.messages[i], numbered(i)) << "message " << i;
  }
  ASSERT_TRUE(run_until(io, [&] { return a->counters().tx_bytes == b->counters().rx_bytes; }));
  EXPECT_EQ(b->counters().rx_messages, kCount);
  EXPECT_LT(a->counters().tx_writes, kCount);  // batched
  EXPECT_GT(a->counters().tx_writes, 0u);
  EXPECT_TRUE(a->is_open());
  EXPECT_EQ(b_in.closed_calls, 0);
}

TEST_F(StreamLinkTest, MessagesQueuedDuringAWriteGoOutInOneWrite) {
  a->start(a_in.on_message(), a_out.source(), a_in.on_closed());
  b->start(b_in.on_message(), b_out.source(), b_in.on_closed());
  ASSERT_TRUE(run_until(io, [&] { return a_out.source_calls == 1; }));  // idle, nothing to send

  a_out.pending.push_back(numbered(0));
  a->wake_writer();
  ASSERT_TRUE(run_until(io, [&] { return a_out.source_calls == 2; }));
  // The source has just handed over message 0 and the writer started its write; everything
  // queued now, however many wakes, must wait for that write and then go out together.
  for (std::uint32_t i = 1; i <= 100; ++i) {
    a_out.pending.push_back(numbered(i));
    a->wake_writer();
  }
  ASSERT_TRUE(run_until(io, [&] {
    return b_in.messages.size() == 101 && a->counters().tx_writes == 2 && a_out.source_calls == 4;
  }));
  io.poll();
  EXPECT_EQ(a->counters().tx_writes, 2u);
  EXPECT_EQ(a_out.source_calls, 4);  // the 100 wakes did not cause 100 source calls
  for (std::uint32_t i = 0; i <= 100; ++i) EXPECT_EQ(b_in.messages[i], numbered(i));
}

TEST_F(StreamLinkTest, AnIdleWriterSendsFromWakeWriterWithoutATurnOfTheLoop) {
  a->start(a_in.on_message(), a_out.source(), a_in.on_closed());
  b->start(b_in.on_message(), b_out.source(), b_in.on_closed());
  ASSERT_TRUE(run_until(io, [&] { return a_out.source_calls == 1; }));  // idle
  a_out.pending.push_back("now");
  a->wake_writer();
  EXPECT_EQ(a_out.source_calls, 2);
  EXPECT_EQ(a->counters().tx_writes, 1u);  // sent before any handler ran
  ASSERT_TRUE(run_until(io, [&] { return b_in.messages.size() == 1; }));
  EXPECT_EQ(b_in.messages[0], "now");
}

TEST_F(StreamLinkTest, SourceThrowingInsideWakeWriterDropsTheLinkOnce) {
  int calls = 0;
  a->start(
      a_in.on_message(),
      [&](std::string&) {
        if (++calls > 1) throw std::runtime_error("fill failed");
      },
      a_in.on_closed());
  b->start(b_in.on_message(), b_out.source(), b_in.on_closed());
  ASSERT_TRUE(run_until(io, [&] { return calls == 1; }));
  EXPECT_NO_THROW(a->wake_writer());  // the caller is not the one that failed
  EXPECT_EQ(a_in.closed_calls, 0);    // never from inside wake_writer()
  ASSERT_TRUE(run_until(io, [&] { return a_in.closed_calls == 1 && b_in.closed_calls == 1; }));
  EXPECT_EQ(a_in.reason, errc::handler_failed);
  EXPECT_EQ(b_in.reason, errc::peer_closed);
  a->wake_writer();  // harmless once closed
  EXPECT_EQ(calls, 2);
}

TEST_F(StreamLinkTest, BothDirectionsAtOnce) {
  a->start(a_in.on_message(), a_out.source(), a_in.on_closed());
  b->start(b_in.on_message(), b_out.source(), b_in.on_closed());
  for (std::uint32_t i = 0; i < 1000; ++i) {
    a_out.pending.push_back(numbered(i));
    b_out.pending.push_back(numbered(i + 5000));
    a->wake_writer();
    b->wake_writer();
  }
  ASSERT_TRUE(
      run_until(io, [&] { return a_in.messages.size() == 1000 && b_in.messages.size() == 1000; }));
  EXPECT_EQ(b_in.messages.back(), numbered(999));
  EXPECT_EQ(a_in.messages.back(), numbered(5999));
}

TEST_F(StreamLinkTest, SourceIsCalledOnStartSoQueuedMessagesGoOut) {
  a_out.pending.push_back("hello");
  a->start(a_in.on_message(), a_out.source(), a_in.on_closed());  // no wake_writer()
  b->start(b_in.on_message(), b_out.source(), b_in.on_closed());
  ASSERT_TRUE(run_until(io, [&] { return b_in.messages.size() == 1; }));
  EXPECT_EQ(b_in.messages[0], "hello");
}

TEST_F(StreamLinkTest, ZeroLengthMessagesAreDelivered) {
  a->start(a_in.on_message(), a_out.source(), a_in.on_closed());
  b->start(b_in.on_message(), b_out.source(), b_in.on_closed());
  a_out.pending = {"", "x", ""};
  a->wake_writer();
  ASSERT_TRUE(run_until(io, [&] { return b_in.messages.size() == 3; }));
  EXPECT_EQ(b_in.messages, (std::vector<std::string>{"", "x", ""}));
}

TEST_F(StreamLinkTest, PeerCloseEndsTheLinkOnceWithPeerClosed) {
  a->start(a_in.on_message(), a_out.source(), a_in.on_closed());
  b->start(b_in.on_message(), b_out.source(), b_in.on_closed());
  std::error_code waited;
  bool wait_done = false;
  test::spawn_checked(io, [&, link = b]() -> asio::awaitable<void> {
    waited = co_await link->async_wait_closed();
    wait_done = true;
  });
  io.poll();
  EXPECT_FALSE(wait_done);

  a->close();
  ASSERT_TRUE(run_until(io, [&] { return b_in.closed_calls == 1 && wait_done; }));
  EXPECT_EQ(b_in.reason, errc::peer_closed);
  EXPECT_EQ(waited, errc::peer_closed);
  EXPECT_EQ(b->counters().close_reason, errc::peer_closed);
  EXPECT_FALSE(b->is_open());
  EXPECT_EQ(a_in.closed_calls, 1);
  EXPECT_EQ(a_in.reason, errc::closed);
  a->close();  // idempotent
  b->close();
  EXPECT_TRUE(testing::drains_within(io, 2s));
  EXPECT_EQ(a_in.closed_calls, 1);
  EXPECT_EQ(b_in.closed_calls, 1);
  EXPECT_EQ(b->counters().close_reason, errc::peer_closed);  // the first reason sticks
}

TEST_F(StreamLinkTest, CloseFromInsideTheMessageHandlerStopsDelivery) {
  a->start(a_in.on_message(), a_out.source(), a_in.on_closed());
  int delivered = 0;
  b->start(
      [&](std::span<const std::uint8_t>) {
        ++delivered;
        b->close();
        b->close();
      },
      b_out.source(), b_in.on_closed());
  a_out.pending = {"1", "2", "3"};
  a->wake_writer();
  ASSERT_TRUE(run_until(io, [&] { return b_in.closed_calls == 1; }));
  EXPECT_EQ(delivered, 1);
  EXPECT_EQ(b_in.reason, errc::closed);
}

// A receiver that cannot take more (its bus is backed up) pauses: what was already read waits,
// nothing more is read, and its own writes go on; on resume everything follows in order.
TEST_F(StreamLinkTest, PauseFromInsideTheHandlerHoldsTheRestUntilResumed) {
  a->start(a_in.on_message(), a_out.source(), a_in.on_closed());
  b->start(
      [&](std::span<const std::uint8_t> m) {
        b_in.messages.push_back(to_string(m));
        if (b_in.messages.size() == 1) b->pause_reading(true);
      },
      b_out.source(), b_in.on_closed());
  a_out.pending = {"1", "2", "3"};  // one write: b reads them together
  a->wake_writer();
  b_out.pending = {"x"};
  b->wake_writer();  // the paused side still writes
  ASSERT_TRUE(
      run_until(io, [&] { return a_in.messages.size() == 1 && b_in.messages.size() == 1; }));
  a_out.pending = {"4"};
  a->wake_writer();
  ASSERT_TRUE(run_until(io, [&] { return a->counters().tx_writes == 2; }));
  io.poll();
  EXPECT_TRUE(b->reading_paused());
  EXPECT_EQ(b_in.messages, std::vector<std::string>{"1"});
  b->pause_reading(false);
  ASSERT_TRUE(run_until(io, [&] { return b_in.messages.size() == 4; }));
  EXPECT_EQ(b_in.messages, (std::vector<std::string>{"1", "2", "3", "4"}));
  EXPECT_EQ(a_in.messages, std::vector<std::string>{"x"});
  EXPECT_TRUE(b->is_open());
}

TEST_F(StreamLinkTest, WaitingForCloseAfterItHappenedCompletesAtOnce) {
  b->start(b_in.on_message(), b_out.source(), b_in.on_closed());
  b->close();
  ASSERT_TRUE(run_until(io, [&] { return b_in.closed_calls == 1; }));
  std::error_code waited;
  test::spawn_checked(io, [&, link = b]() -> asio::awaitable<void> {
    waited = co_await link->async_wait_closed();
  });
  ASSERT_TRUE(run_until(io, [&] { return bool(waited); }));
  EXPECT_EQ(waited, errc::closed);
}

TEST_F(StreamLinkTest, ClosingBeforeStartStillReportsOnce) {
  b->close();
  b->start(b_in.on_message(), b_out.source(), b_in.on_closed());
  ASSERT_TRUE(run_until(io, [&] { return b_in.closed_calls == 1; }));
  EXPECT_EQ(b_in.reason, errc::closed);
  EXPECT_EQ(b_out.source_calls, 0);
}

TEST_F(StreamLinkTest, ThrowingHandlerDropsTheLink) {
  a->start(a_in.on_message(), a_out.source(), a_in.on_closed());
  b->start([](std::span<const std::uint8_t>) { throw std::runtime_error("parse failed"); },
           b_out.source(), b_in.on_closed());
  a_out.pending = {"boom"};
  a->wake_writer();
  ASSERT_TRUE(run_until(io, [&] { return b_in.closed_calls == 1 && a_in.closed_calls == 1; }));
  EXPECT_EQ(b_in.reason, errc::handler_failed);
  EXPECT_EQ(a_in.reason, errc::peer_closed);
}

TEST_F(StreamLinkTest, HandlersCapturingTheLinkDoNotKeepItAlive) {
  std::weak_ptr<StreamLink> weak = b;
  b->start([link = b](std::span<const std::uint8_t>) { link->wake_writer(); },
           [link = b](std::string&) {}, [link = b](std::error_code) {});
  b->close();
  b.reset();
  EXPECT_TRUE(run_until(io, [&] { return weak.expired(); }));
}

// What the handlers of one read's messages queue goes out in one write once they have all been
// handed over, not one write for the first and another for the rest.
TEST_F(StreamLinkTest, AWakeFromInsideTheHandlerIsServedOnceTheBatchIsHandedOver) {
  a->start(a_in.on_message(), a_out.source(), a_in.on_closed());
  ASSERT_TRUE(run_until(io, [&] { return a_out.source_calls == 1; }));  // idle
  constexpr std::uint32_t kCount = 50;
  for (std::uint32_t i = 0; i < kCount; ++i) a_out.pending.push_back(numbered(i));
  a->wake_writer();  // one inline send: b reads all of it at once
  b->start(
      [&](std::span<const std::uint8_t> m) {
        b_out.pending.push_back("ack " + to_string(m).substr(0, 4));
        b->wake_writer();
      },
      b_out.source(), b_in.on_closed());
  ASSERT_TRUE(run_until(io, [&] { return a_in.messages.size() == kCount; }));
  EXPECT_EQ(b->counters().tx_writes, 1u);
  for (std::uint32_t i = 0; i < kCount; ++i) {
    EXPECT_EQ(a_in.messages[i], "ack " + numbered(i).substr(0, 4));
  }
}

// A large read is handed over in batches of about 4 KiB, each followed by the write of what its
// messages queued: a side busy with one long read (thousands of frames to write to its bus) still
// answers, and its keepalives go out, while it works through the rest.
TEST_F(StreamLinkTest, ALargeReadIsHandedOverInBatchesEachFollowedByItsWrite) {
  a->start(a_in.on_message(), a_out.source(), a_in.on_closed());
  constexpr std::size_t kCount = 600;  // 101 bytes each on the wire: about 60 KB, one read
  ASSERT_TRUE(run_until(io, [&] { return a_out.source_calls == 1; }));  // idle
  for (std::size_t i = 0; i < kCount; ++i) a_out.pending.push_back(std::string(100, 'x'));
  a->wake_writer();  // sent inline, before b reads anything
  ASSERT_EQ(a->counters().tx_bytes, kCount * 101);
  struct Seen {
    std::uint64_t batch;
    std::uint64_t writes;  // b's completed writes when the message was handed over
  };
  std::vector<Seen> seen;
  b->start(
      [&](std::span<const std::uint8_t>) {
        seen.push_back({b->input_batches(), b->counters().tx_writes});
        b_out.pending.push_back("ack");
        b->wake_writer();
      },
      b_out.source(), b_in.on_closed());
  ASSERT_TRUE(run_until(io, [&] { return seen.size() == kCount; }));
  const std::uint64_t batches = seen.back().batch - seen.front().batch + 1;
  EXPECT_GE(batches, kCount * 101 / (4 * 1024));
  std::uint64_t written_between = 0;
  for (std::size_t i = 1; i < kCount; ++i) {
    if (seen[i].batch == seen[i - 1].batch) {
      EXPECT_EQ(seen[i].writes, seen[i - 1].writes) << "a write inside a batch, message " << i;
    } else if (seen[i].writes > seen[i - 1].writes) {
      ++written_between;
    }
  }
  // Every batch's acks before the next batch (a boundary between two reads may leave them to
  // the resumed writer, which runs between the reads).
  EXPECT_GE(written_between + 2, batches);
  ASSERT_TRUE(run_until(io, [&] { return a_in.messages.size() == kCount; }));  // every ack
}

// Bytes in the socket that the reader has not handed over, or holds while paused, are input
// waiting: the peer sent them, though this side has not run to read them.
TEST_F(StreamLinkTest, InputWaitingSeesBytesTheReaderHasNotHandedOver) {
  a->start(a_in.on_message(), a_out.source(), a_in.on_closed());
  ASSERT_TRUE(run_until(io, [&] { return a_out.source_calls == 1; }));  // idle
  EXPECT_FALSE(b->input_waiting());
  a_out.pending.push_back("first");
  a_out.pending.push_back("second");
  a->wake_writer();  // inline: in b's socket now
  EXPECT_TRUE(b->input_waiting());
  b->start(
      [&](std::span<const std::uint8_t> m) {
        b_in.messages.push_back(to_string(m));
        if (b_in.messages.size() == 1) b->pause_reading(true);
      },
      b_out.source(), b_in.on_closed());
  ASSERT_TRUE(run_until(io, [&] { return b_in.messages.size() == 1; }));
  EXPECT_TRUE(b->input_waiting());  // "second", read and held
  b->pause_reading(false);
  ASSERT_TRUE(run_until(io, [&] { return b_in.messages.size() == 2; }));
  EXPECT_FALSE(b->input_waiting());
}

TEST_F(StreamLinkTest, TcpNoDelayIsSetOnBothEnds) {
  EXPECT_NE(tcp_nodelay(a->native_handle()), 0);
  EXPECT_NE(tcp_nodelay(b->native_handle()), 0);
}

// A raw peer talks to a StreamLink that has a small maximum message size.
class RawPeerTest : public ::testing::Test {
 protected:
  void SetUp() override {
    auto sockets = testing::connected_sockets(io);
    raw = std::make_unique<asio::ip::tcp::socket>(std::move(sockets.client));
    StreamLinkOptions options;
    options.max_message_size = 1024;
    link = StreamLink::create(std::move(sockets.server), options);
    link->start(in.on_message(), out.source(), in.on_closed());
  }
  void TearDown() override {
    link->close();
    raw->close();
    EXPECT_TRUE(testing::drains_within(io, 2s));
  }

  // True once the raw peer sees the connection end (EOF or reset).
  bool raw_peer_sees_close() {
    bool ended = false;
    test::spawn_checked(io, [&]() -> asio::awaitable<void> {
      std::array<char, 64> buf;
      for (;;) {
        auto [ec, n] =
            co_await raw->async_read_some(asio::buffer(buf), asio::as_tuple(asio::use_awaitable));
        if (ec) break;
      }
      ended = true;
    });
    return run_until(io, [&] { return ended; });
  }

  asio::io_context io;
  std::unique_ptr<asio::ip::tcp::socket> raw;
  std::shared_ptr<StreamLink> link;
  Outbox out;
  Inbox in;
};

TEST_F(RawPeerTest, GarbageIsCountedAndDropsTheLink) {
  std::string stream;
  append_delimited(stream, bytes(std::string("ok")));
  stream += std::string(16, '\xFF');  // a length prefix that never ends
  asio::write(*raw, asio::buffer(stream));
  ASSERT_TRUE(run_until(io, [&] { return in.closed_calls == 1; }));
  EXPECT_EQ(in.reason, errc::malformed_length);
  EXPECT_EQ(in.messages, std::vector<std::string>{"ok"});  // what came before is still delivered
  EXPECT_EQ(link->counters().malformed, 1u);
  EXPECT_EQ(link->counters().oversize, 0u);
  EXPECT_EQ(link->counters().close_reason, errc::malformed_length);
  EXPECT_TRUE(raw_peer_sees_close());
  io.poll();
  EXPECT_EQ(in.closed_calls, 1);
}

TEST_F(RawPeerTest, OversizeAnnouncedLengthDropsTheLink) {
  std::string prefix;
  append_delimited(prefix, bytes(std::string(1025, 'x')));
  prefix.resize(2);  // only the prefix: the link must not wait for the body
  asio::write(*raw, asio::buffer(prefix));
  ASSERT_TRUE(run_until(io, [&] { return in.closed_calls == 1; }));
  EXPECT_EQ(in.reason, errc::message_too_large);
  EXPECT_EQ(link->counters().oversize, 1u);
  EXPECT_EQ(link->counters().malformed, 0u);
  EXPECT_TRUE(in.messages.empty());
  EXPECT_TRUE(raw_peer_sees_close());
}

TEST_F(RawPeerTest, MessageAtTheLimitIsAccepted) {
  std::string stream;
  append_delimited(stream, bytes(std::string(1024, 'y')));
  asio::write(*raw, asio::buffer(stream));
  ASSERT_TRUE(run_until(io, [&] { return in.messages.size() == 1; }));
  EXPECT_EQ(in.messages[0], std::string(1024, 'y'));
  EXPECT_TRUE(link->is_open());
}

TEST_F(RawPeerTest, MessageTrickledByteByByteIsReassembled) {
  std::string stream;
  append_delimited(stream, bytes(std::string(300, 'z')));
  for (char c : stream) {
    asio::write(*raw, asio::buffer(&c, 1));
    io.poll();
  }
  ASSERT_TRUE(run_until(io, [&] { return in.messages.size() == 1; }));
  EXPECT_EQ(in.messages[0], std::string(300, 'z'));
  EXPECT_EQ(link->counters().rx_bytes, stream.size());
}

// A flood of hostile connections to one server, each sending garbage: the links share the
// server's StreamLinkWarnings, so the log says it once and the counters keep the number.
TEST(StreamLinkWarningsTest, LinksSharingWarningsWarnOnceForTheirSide) {
  std::ostringstream log;
  auto previous = spdlog::default_logger();
  auto capture = std::make_shared<spdlog::logger>(
      "capture", std::make_shared<spdlog::sinks::ostream_sink_st>(log));
  capture->set_level(spdlog::level::info);
  spdlog::set_default_logger(capture);

  asio::io_context io;
  StreamLinkOptions options;
  options.warnings = std::make_shared<StreamLinkWarnings>();
  constexpr int kLinks = 5;
  std::vector<std::unique_ptr<asio::ip::tcp::socket>> peers;
  std::vector<std::shared_ptr<StreamLink>> links;
  std::vector<Inbox> inboxes(kLinks);
  Outbox out;
  for (int i = 0; i < kLinks; ++i) {
    auto sockets = testing::connected_sockets(io);
    peers.push_back(std::make_unique<asio::ip::tcp::socket>(std::move(sockets.client)));
    links.push_back(StreamLink::create(std::move(sockets.server), options));
    links.back()->start(inboxes[i].on_message(), out.source(), inboxes[i].on_closed());
    const std::string garbage(16, '\xFF');  // a length prefix that never ends
    asio::write(*peers.back(), asio::buffer(garbage));
  }
  const bool all_closed = run_until(io, [&] {
    for (const auto& in : inboxes) {
      if (in.closed_calls != 1) return false;
    }
    return true;
  });
  spdlog::set_default_logger(previous);
  ASSERT_TRUE(all_closed);
  std::uint64_t malformed = 0;
  for (const auto& l : links) malformed += l->counters().malformed;
  EXPECT_EQ(malformed, std::uint64_t{kLinks});
  EXPECT_TRUE(options.warnings->malformed);
  const std::string text = log.str();
  std::size_t warnings = 0;
  for (auto at = text.find("dropping"); at != std::string::npos;
       at = text.find("dropping", at + 1)) {
    ++warnings;
  }
  EXPECT_EQ(warnings, 1u) << text;
  for (auto& p : peers) p->close();
  EXPECT_TRUE(testing::drains_within(io, 2s));
}

}  // namespace
}  // namespace canbridge::backbone
