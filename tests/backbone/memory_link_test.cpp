// The in-memory link pair: whole messages in order, posted delivery, backpressure through a
// bounded amount in flight, and closes that reach the other end with a reason.
#include "backbone/memory_link.hpp"

#include <gtest/gtest.h>

#include <boost/asio/co_spawn.hpp>
#include <boost/asio/io_context.hpp>
#include <stdexcept>

#include "coro/spawn_owned.hpp"
#include "tests/backbone/link_test_support.hpp"
#include "tests/backbone/test_support.hpp"

namespace canbridge::backbone {
namespace {

namespace asio = boost::asio;
using namespace std::chrono_literals;
using testing::bytes;
using testing::Inbox;
using testing::numbered;
using testing::Outbox;
using testing::run_until;

class MemoryLinkTest : public ::testing::Test {
 protected:
  void make(MemoryLinkOptions options = {}) {
    auto pair = make_memory_link_pair(io.get_executor(), options);
    a = pair.a;
    b = pair.b;
  }
  void start_both() {
    a->start(a_in.on_message(), a_out.source(), a_in.on_closed());
    b->start(b_in.on_message(), b_out.source(), b_in.on_closed());
  }
  // Runs every handler there is; true once nothing is left to do.
  bool settle() { return testing::drains_within(io, 2s); }
  void TearDown() override {
    if (a) a->close();
    if (b) b->close();
    EXPECT_TRUE(settle());
  }

  asio::io_context io;
  std::shared_ptr<MemoryLink> a;
  std::shared_ptr<MemoryLink> b;
  Outbox a_out, b_out;
  Inbox a_in, b_in;
};

TEST_F(MemoryLinkTest, MessagesCrossWholeAndInOrderInBatches) {
  make();
  start_both();
  constexpr std::uint32_t kCount = 10'000;
  for (std::uint32_t i = 0; i < kCount; ++i) {
    a_out.pending.push_back(numbered(i));
    a->wake_writer();
    if (i % 97 == 0) io.poll();  // writes happen while messages keep coming
  }
  ASSERT_TRUE(run_until(io, [&] { return b_in.messages.size() == kCount; }));
  for (std::uint32_t i = 0; i < kCount; ++i) {
    ASSERT_EQ(b_in.messages[i], numbered(i)) << "message " << i;
  }
  EXPECT_EQ(b->counters().rx_messages, kCount);
  EXPECT_EQ(a->counters().tx_bytes, b->counters().rx_bytes);
  EXPECT_LT(a->counters().tx_writes, kCount / 50);  // many messages per write
  EXPECT_GT(a->counters().tx_writes, 0u);
  EXPECT_EQ(b->counters().tx_writes, 0u);
  EXPECT_EQ(a_in.messages.size(), 0u);
  EXPECT_TRUE(a->is_open() && b->is_open());
}

TEST_F(MemoryLinkTest, ZeroLengthAndLargeMessagesStayWhole) {
  make();
  start_both();
  const std::string large(200'000, 'L');  // above the capacity: one batch may exceed it
  a_out.pending = {"", large, "", "x"};
  a->wake_writer();
  ASSERT_TRUE(run_until(io, [&] { return b_in.messages.size() == 4; }));
  EXPECT_EQ(b_in.messages, (std::vector<std::string>{"", large, "", "x"}));
}

// Nothing runs inside a call on either end: every handler comes on a later turn of the loop.
TEST_F(MemoryLinkTest, NoHandlerRunsInsideACallOnEitherEnd) {
  make();
  int depth = 0;  // > 0 while the test is inside a call on a link
  int reentered = 0;
  auto guarded = [&](auto&& call) {
    ++depth;
    call();
    --depth;
  };
  int a_source_calls = 0;
  std::vector<std::string> b_got;
  int closed = 0;
  a->start([&](std::span<const std::uint8_t>) { reentered += depth; },
           [&](std::string& out) {
             reentered += depth;
             if (++a_source_calls == 2) append_delimited(out, bytes(std::string("ping")));
           },
           [&](std::error_code) {
             reentered += depth;
             ++closed;
           });
  b->start(
      [&](std::span<const std::uint8_t> m) {
        reentered += depth;
        b_got.push_back(testing::to_string(m));
        // Inside b's handler: a's handlers must not run from here either.
        guarded([&] {
          b->wake_writer();
          a->wake_writer();
          a->close();
        });
      },
      [&](std::string&) { reentered += depth; },
      [&](std::error_code) {
        reentered += depth;
        ++closed;
      });
  EXPECT_EQ(a_source_calls, 0);  // start() asks the source on a later turn
  io.poll();
  EXPECT_EQ(a_source_calls, 1);
  guarded([&] { a->wake_writer(); });
  EXPECT_EQ(a_source_calls, 1);  // not from inside wake_writer()
  EXPECT_TRUE(settle());
  EXPECT_EQ(b_got, std::vector<std::string>{"ping"});
  EXPECT_EQ(closed, 2);
  EXPECT_EQ(reentered, 0);
}

TEST_F(MemoryLinkTest, ClosingOneEndDeliversWhatWasWrittenThenEndsTheOther) {
  make();
  start_both();
  a_out.pending = {"last", "words"};
  a->wake_writer();
  ASSERT_TRUE(run_until(io, [&] { return a->counters().tx_writes == 1; }));
  a->close(make_error_code(errc::refused_by_peer));
  EXPECT_FALSE(a->is_open());
  EXPECT_EQ(a_in.closed_calls, 0);  // never from inside close()
  EXPECT_TRUE(settle());
  EXPECT_EQ(b_in.messages, (std::vector<std::string>{"last", "words"}));
  EXPECT_EQ(a_in.closed_calls, 1);
  EXPECT_EQ(b_in.closed_calls, 1);
  EXPECT_EQ(a_in.reason, errc::refused_by_peer);  // the closer's own reason
  EXPECT_EQ(b_in.reason, errc::peer_closed);      // what the far end sees, as at a TCP EOF
  EXPECT_EQ(b->counters().close_reason, errc::peer_closed);
  EXPECT_FALSE(b->is_open());
  a->close();
  b->close();
  EXPECT_TRUE(settle());
  EXPECT_EQ(a_in.closed_calls, 1);
  EXPECT_EQ(b_in.closed_calls, 1);
  EXPECT_EQ(a->counters().close_reason, errc::refused_by_peer);  // the first reason sticks
}

TEST_F(MemoryLinkTest, BothEndsClosingAtOnceReportEachOnce) {
  make();
  start_both();
  a->close();
  b->close();
  a->close();
  EXPECT_TRUE(settle());
  EXPECT_EQ(a_in.closed_calls, 1);
  EXPECT_EQ(b_in.closed_calls, 1);
  EXPECT_EQ(a_in.reason, errc::closed);
  EXPECT_EQ(b_in.reason, errc::closed);
}

TEST_F(MemoryLinkTest, AsyncWaitClosedCompletesWithTheReason) {
  make();
  start_both();
  std::string why = "pending";
  std::error_code waited;
  coro::spawn_owned(
      io,
      [](std::shared_ptr<MemoryLink> link, std::error_code& out) -> asio::awaitable<void> {
        out = co_await link->async_wait_closed();
      }(b, waited),
      [&](const std::string& failure) { why = failure; });
  io.poll();
  EXPECT_EQ(why, "pending");
  a->close();
  EXPECT_TRUE(settle());
  EXPECT_EQ(why, "");
  EXPECT_EQ(waited, errc::peer_closed);
}

// Like TCP: a reader that pauses stops draining, the amount in flight reaches the bound and the
// other end's writer stops asking its source; on resume everything follows in order.
TEST_F(MemoryLinkTest, PausedReaderBacksUpTheFarWriterUntilItDrains) {
  MemoryLinkOptions options;
  options.capacity_bytes = 4096;
  make(options);
  constexpr std::uint32_t kCount = 2000;
  std::uint32_t next = 0;
  int source_calls = 0;
  a->start(
      a_in.on_message(),
      [&](std::string& out) {  // a producer with plenty queued: 8 messages per write
        ++source_calls;
        for (int k = 0; k < 8 && next < kCount; ++k) append_delimited(out, bytes(numbered(next++)));
      },
      a_in.on_closed());
  b->start(b_in.on_message(), b_out.source(), b_in.on_closed());
  b->pause_reading(true);
  EXPECT_TRUE(settle());  // the writer stopped by itself: nothing is left to run
  EXPECT_TRUE(a->writer_blocked());
  EXPECT_TRUE(b_in.messages.empty());
  EXPECT_GE(b->unread_bytes(), options.capacity_bytes);
  EXPECT_LT(b->unread_bytes(), options.capacity_bytes + 8 * 310);  // the bound plus one batch
  EXPECT_LT(next, kCount / 4);
  const int calls_while_blocked = source_calls;
  a->wake_writer();  // a blocked writer stays blocked however often it is woken
  EXPECT_TRUE(settle());
  EXPECT_EQ(source_calls, calls_while_blocked);

  // The paused side still writes.
  b_out.pending = {"still writing"};
  b->wake_writer();
  EXPECT_TRUE(settle());
  EXPECT_EQ(a_in.messages, std::vector<std::string>{"still writing"});

  b->pause_reading(false);
  ASSERT_TRUE(run_until(io, [&] { return b_in.messages.size() == kCount; }));
  for (std::uint32_t i = 0; i < kCount; ++i) ASSERT_EQ(b_in.messages[i], numbered(i)) << i;
  EXPECT_FALSE(a->writer_blocked());
  EXPECT_EQ(b->unread_bytes(), 0u);
}

TEST_F(MemoryLinkTest, PauseFromInsideTheHandlerHoldsTheRestUntilResumed) {
  make();
  a->start(a_in.on_message(), a_out.source(), a_in.on_closed());
  b->start(
      [&](std::span<const std::uint8_t> m) {
        b_in.messages.push_back(testing::to_string(m));
        if (b_in.messages.size() == 1) b->pause_reading(true);
      },
      b_out.source(), b_in.on_closed());
  a_out.pending = {"1", "2", "3"};
  a->wake_writer();
  EXPECT_TRUE(settle());
  EXPECT_EQ(b_in.messages, std::vector<std::string>{"1"});
  b->pause_reading(false);
  EXPECT_TRUE(settle());
  EXPECT_EQ(b_in.messages, (std::vector<std::string>{"1", "2", "3"}));
}

// A paused reader never reaches the end of the stream; its writes find the end gone instead.
TEST_F(MemoryLinkTest, WritingToAClosedEndResetsAPausedReader) {
  make();
  start_both();
  b->pause_reading(true);
  a->close();
  EXPECT_TRUE(settle());
  EXPECT_EQ(b_in.closed_calls, 0);  // paused: it has not read to the end
  b_out.pending = {"one"};
  b->wake_writer();
  EXPECT_TRUE(settle());
  EXPECT_EQ(b_in.closed_calls, 0);  // the first write is taken, as by a kernel before the RST
  b_out.pending = {"two"};
  b->wake_writer();
  EXPECT_TRUE(settle());
  EXPECT_EQ(b_in.closed_calls, 1);
  EXPECT_EQ(b_in.reason, std::errc::connection_reset);
}

TEST_F(MemoryLinkTest, ThrowingHandlerDropsTheLinkAndTheFarEndSeesIt) {
  make();
  a->start(a_in.on_message(), a_out.source(), a_in.on_closed());
  b->start([](std::span<const std::uint8_t>) { throw std::runtime_error("parse failed"); },
           b_out.source(), b_in.on_closed());
  a_out.pending = {"boom", "never"};
  a->wake_writer();
  EXPECT_TRUE(settle());
  EXPECT_EQ(b_in.closed_calls, 1);
  EXPECT_EQ(b_in.reason, errc::handler_failed);
  EXPECT_EQ(a_in.closed_calls, 1);
  EXPECT_EQ(a_in.reason, errc::peer_closed);
  EXPECT_EQ(b->counters().rx_messages, 1u);
}

TEST_F(MemoryLinkTest, ThrowingSourceDropsTheLink) {
  make();
  a->start(
      a_in.on_message(), [](std::string&) { throw std::runtime_error("fill failed"); },
      a_in.on_closed());
  b->start(b_in.on_message(), b_out.source(), b_in.on_closed());
  EXPECT_TRUE(settle());
  EXPECT_EQ(a_in.closed_calls, 1);
  EXPECT_EQ(a_in.reason, errc::handler_failed);
  EXPECT_EQ(b_in.reason, errc::peer_closed);
}

TEST_F(MemoryLinkTest, ClosingBeforeStartStillReportsOnce) {
  make();
  b->close();
  b->start(b_in.on_message(), b_out.source(), b_in.on_closed());
  EXPECT_EQ(b_in.closed_calls, 0);
  EXPECT_TRUE(settle());
  EXPECT_EQ(b_in.closed_calls, 1);
  EXPECT_EQ(b_in.reason, errc::closed);
  EXPECT_EQ(b_out.source_calls, 0);
}

TEST_F(MemoryLinkTest, MessagesWrittenBeforeTheReaderStartsWaitForIt) {
  make();
  a->start(a_in.on_message(), a_out.source(), a_in.on_closed());
  a_out.pending = {"early"};
  a->wake_writer();
  EXPECT_TRUE(settle());
  EXPECT_EQ(b->unread_bytes(), 6u);
  b->start(b_in.on_message(), b_out.source(), b_in.on_closed());
  EXPECT_TRUE(settle());
  EXPECT_EQ(b_in.messages, std::vector<std::string>{"early"});
}

TEST_F(MemoryLinkTest, DroppingAnEndEndsTheOther) {
  make();
  b->start(b_in.on_message(), b_out.source(), b_in.on_closed());
  a.reset();
  EXPECT_TRUE(settle());
  EXPECT_EQ(b_in.closed_calls, 1);
  EXPECT_EQ(b_in.reason, errc::peer_closed);
}

TEST_F(MemoryLinkTest, HandlersCapturingTheLinkDoNotKeepItAlive) {
  make();
  std::weak_ptr<MemoryLink> weak = b;
  b->start([link = b](std::span<const std::uint8_t>) { link->wake_writer(); },
           [link = b](std::string&) {}, [link = b](std::error_code) {});
  b->close();
  b.reset();
  EXPECT_TRUE(settle());
  EXPECT_TRUE(weak.expired());
}

TEST_F(MemoryLinkTest, ReportsItsOptions) {
  MemoryLinkOptions options;
  options.crc_framed = true;
  options.name = "pair";
  make(options);
  EXPECT_TRUE(a->crc_framed());
  EXPECT_TRUE(b->crc_framed());
  EXPECT_EQ(a->peer_name(), "pair/b");
  EXPECT_EQ(b->peer_name(), "pair/a");
  EXPECT_EQ(a->executor(), asio::any_io_executor(io.get_executor()));
  EXPECT_FALSE(a->started());
}

}  // namespace
}  // namespace canbridge::backbone
