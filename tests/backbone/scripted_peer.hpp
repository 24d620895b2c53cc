// A scripted far end of one backbone link for protocol tests: it expects envelopes from the side
// under test, replies, waits, loses a write of that side (the link breaks there) and closes, step
// by step, and the test waits for the script's end under one deadline that names the step it
// stalled on.
#pragma once

#include <gtest/gtest.h>

#include <boost/asio/io_context.hpp>
#include <boost/asio/steady_timer.hpp>
#include <chrono>
#include <cstddef>
#include <deque>
#include <functional>
#include <memory>
#include <optional>
#include <span>
#include <string>
#include <system_error>
#include <utility>
#include <vector>

#include "backbone/delimited_codec.hpp"
#include "backbone/message_link.hpp"
#include "tests/backbone/envelopes.hpp"
#include "tests/support/event_loop.hpp"

namespace canbridge::backbone::testing {

// The steps of one link's conversation, in order. Timing bounds (within()) apply to the step
// added last and count from the end of the step before it.
class PeerScript {
 public:
  using Clock = std::chrono::steady_clock;

  // The next envelope the side under test sends must match (tolerated ones are passed over).
  PeerScript& expect(EnvelopeMatch match) {
    return add({Step::expect_step, std::move(match.description), std::move(match.accepts)});
  }
  // Writes `envelope` to the side under test.
  PeerScript& reply(v1::Envelope envelope) {
    Step s{Step::reply_step, "reply " + describe(envelope)};
    s.envelope = std::move(envelope);
    return add(std::move(s));
  }
  // Does nothing for `delay` (what arrives meanwhile waits for the next expect).
  PeerScript& after(Clock::duration delay) {
    Step s{Step::after_step, "wait " + std::to_string(ms(delay)) + " ms"};
    s.delay = delay;
    return add(std::move(s));
  }
  // For `duration`, nothing but tolerated envelopes may arrive: nothing more was sent.
  PeerScript& quiet_for(Clock::duration duration) {
    Step s{Step::quiet_step,
           "nothing but tolerated envelopes for " + std::to_string(ms(duration)) + " ms"};
    s.delay = duration;
    return add(std::move(s));
  }
  // The `n`th envelope the side under test writes from this step on is lost and the link breaks
  // there: the envelopes before it reach the script, it and everything after it do not.
  PeerScript& fail_write(int n) {
    Step s{Step::fail_write_step, "fail write " + std::to_string(n) + " of the side under test"};
    s.count = n;
    return add(std::move(s));
  }
  // Closes the link from the peer's end.
  PeerScript& close() { return add({Step::close_step, "close the link"}); }
  // The link must end (the side under test closes it, or a failed write broke it).
  PeerScript& expect_closed() { return add({Step::expect_closed_step, "the link closes"}); }
  // From here on, envelopes matching `match` that the current expectation does not are passed
  // over (recorded, not checked): keepalives and bare acks an idle side sends when it likes.
  PeerScript& tolerate(EnvelopeMatch match) {
    Step s{Step::tolerate_step, "tolerate " + match.description, std::move(match.accepts)};
    return add(std::move(s));
  }
  PeerScript& tolerate_nothing() { return add({Step::tolerate_step, "tolerate nothing"}); }
  // Runs `action` on the side under test at this point (e.g. queue payloads).
  PeerScript& act(std::string description, std::function<void()> action) {
    Step s{Step::act_step, std::move(description)};
    s.action = std::move(action);
    return add(std::move(s));
  }
  // `condition` must hold when the script gets here.
  PeerScript& check(std::string description, std::function<bool()> condition) {
    Step s{Step::check_step, std::move(description)};
    s.condition = std::move(condition);
    return add(std::move(s));
  }
  // Waits until `condition` holds (re-checked on every event and every few ms).
  PeerScript& wait_for(std::string description, std::function<bool()> condition) {
    Step s{Step::wait_for_step, std::move(description)};
    s.condition = std::move(condition);
    return add(std::move(s));
  }
  // Bounds the time the last step took, from the end of the step before it (an expect: until the
  // envelope arrived; expect_closed: until the link ended).
  PeerScript& within(Clock::duration earliest, Clock::duration latest) {
    steps_.back().earliest = earliest;
    steps_.back().latest = latest;
    return *this;
  }

  struct Step {
    // Named apart from the builder methods above (clang's -Wshadow).
    enum Kind {
      expect_step,
      reply_step,
      after_step,
      quiet_step,
      fail_write_step,
      close_step,
      expect_closed_step,
      tolerate_step,
      act_step,
      check_step,
      wait_for_step
    };
    Kind kind;
    std::string description;
    std::function<bool(const v1::Envelope&)> accepts = nullptr;  // expect, tolerate
    v1::Envelope envelope{};                                     // reply
    Clock::duration delay{};                                     // after, quiet
    int count = 0;                                               // fail_write
    std::function<void()> action = nullptr;                      // act
    std::function<bool()> condition = nullptr;                   // check, wait_for
    std::optional<Clock::duration> earliest{};
    std::optional<Clock::duration> latest{};
  };
  std::vector<Step>& steps() { return steps_; }
  const std::vector<Step>& steps() const { return steps_; }

  static long long ms(Clock::duration d) {
    return std::chrono::duration_cast<std::chrono::milliseconds>(d).count();
  }

 private:
  PeerScript& add(Step step) {
    steps_.push_back(std::move(step));
    return *this;
  }
  std::vector<Step> steps_;
};

// Plays a PeerScript on the far end of a link (the other end belongs to the side under test).
// Starts the link at once; closes it when destroyed.
class ScriptedPeer {
 public:
  using Clock = PeerScript::Clock;

  struct Received {
    v1::Envelope envelope;
    Clock::time_point at;
  };

  ScriptedPeer(std::shared_ptr<MessageLink> far_end, PeerScript script)
      : core_(std::make_shared<Core>(std::move(far_end), std::move(script))) {
    core_->start();
  }
  ~ScriptedPeer() { core_->link->close(); }
  ScriptedPeer(const ScriptedPeer&) = delete;
  ScriptedPeer& operator=(const ScriptedPeer&) = delete;

  // Runs `io` until the script has played to its end (success), a step failed, or `deadline`
  // passed; a failure names the step and what arrived.
  ::testing::AssertionResult finishes(
      boost::asio::io_context& io, std::chrono::milliseconds deadline = std::chrono::seconds(5)) {
    test::run_until(
        io,
        [this] {
          core_->advance();  // wait_for conditions are re-checked on run_until's tick
          return core_->finished() || !core_->failure.empty();
        },
        deadline);
    if (!core_->failure.empty()) return ::testing::AssertionFailure() << core_->failure;
    if (!core_->finished()) {
      return ::testing::AssertionFailure() << core_->where() << ": still waiting after "
                                           << deadline.count() << " ms" << core_->recent();
    }
    return ::testing::AssertionSuccess();
  }

  // Every envelope the side under test sent to this peer, in order (lost writes excluded).
  const std::vector<Received>& received() const { return core_->received; }
  // Envelopes that arrived after the script's last step, not yet seen by any step.
  std::vector<v1::Envelope> unread() const {
    std::vector<v1::Envelope> out;
    for (std::size_t i = core_->inbox_next; i < core_->received.size(); ++i) {
      out.push_back(core_->received[i].envelope);
    }
    return out;
  }
  bool link_open() const { return !core_->closed; }
  MessageLink& link() { return *core_->link; }

 private:
  struct Core : std::enable_shared_from_this<Core> {
    Core(std::shared_ptr<MessageLink> far_end, PeerScript script_in)
        : link(std::move(far_end)),
          script(std::move(script_in)),
          timer(link->executor()),
          step_began(Clock::now()) {}

    void start() {
      std::weak_ptr<Core> weak = weak_from_this();
      link->start(
          [weak](std::span<const std::uint8_t> bytes) {
            if (auto self = weak.lock()) self->on_message(bytes);
          },
          [weak](std::string& out) {
            if (auto self = weak.lock()) self->fill(out);
          },
          [weak](std::error_code) {
            if (auto self = weak.lock()) self->on_closed();
          });
      advance();
    }

    void on_message(std::span<const std::uint8_t> bytes) {
      v1::Envelope envelope;
      if (!envelope.ParseFromArray(bytes.data(), static_cast<int>(bytes.size()))) {
        fail("a message that is not an envelope arrived (" + std::to_string(bytes.size()) +
             " bytes)");
        return;
      }
      if (fail_countdown > 0 && --fail_countdown == 0) {
        // This write of the side under test is lost, and the link breaks with it.
        lost.push_back(std::move(envelope));
        link->close(std::make_error_code(std::errc::broken_pipe));
        return;
      }
      if (fail_countdown == 0 && !lost.empty()) return;  // after the failed write: never arrives
      received.push_back({std::move(envelope), Clock::now()});
      advance();
    }

    void fill(std::string& out) {
      while (!outbox.empty()) {
        out += outbox.front();
        outbox.pop_front();
      }
    }

    void on_closed() {
      if (closed) return;
      closed = true;
      closed_at = Clock::now();
      advance();
    }

    bool finished() const { return next >= script.steps().size(); }

    // Plays steps until one has to wait. Re-entrant calls (an act() whose effect reaches this
    // peer at once) only ask the outer loop to go on.
    void advance() {
      if (advancing) {
        again = true;
        return;
      }
      advancing = true;
      do {
        again = false;
        while (failure.empty() && !finished() && play(script.steps()[next])) {
          ++next;
          step_began = Clock::now();
        }
      } while (again && failure.empty());
      advancing = false;
    }

    // True when `step` is done.
    bool play(PeerScript::Step& step) {
      using Step = PeerScript::Step;
      switch (step.kind) {
        case Step::expect_step:
          while (inbox_next < received.size()) {
            const Received& r = received[inbox_next++];
            if (step.accepts(r.envelope)) return in_time(step, r.at);
            if (tolerated && tolerated(r.envelope)) continue;
            return fail(where() + ": got " + describe(r.envelope));
          }
          if (closed) fail(where() + ": the link closed" + recent());
          return false;
        case Step::expect_closed_step:
          while (inbox_next < received.size()) {
            const Received& r = received[inbox_next++];
            if (tolerated && tolerated(r.envelope)) continue;
            return fail(where() + ": got " + describe(r.envelope));
          }
          return closed && in_time(step, closed_at);
        case Step::reply_step:
          if (closed) return fail(where() + ": the link closed" + recent());
          outbox.emplace_back();
          append_message(outbox.back(), step.envelope);
          link->wake_writer();
          return true;
        case Step::quiet_step:
          while (inbox_next < received.size()) {
            const Received& r = received[inbox_next++];
            if (tolerated && tolerated(r.envelope)) continue;
            return fail(where() + ": got " + describe(r.envelope));
          }
          return waited_for(step.delay);
        case Step::after_step:
          return waited_for(step.delay);
        case Step::fail_write_step:
          fail_countdown = step.count;
          return true;
        case Step::close_step:
          link->close();
          return true;
        case Step::tolerate_step:
          tolerated = step.accepts;
          return true;
        case Step::act_step:
          step.action();
          return true;
        case Step::check_step:
          return step.condition() || fail(where() + ": does not hold");
        case Step::wait_for_step:
          return step.condition();
      }
      return false;
    }

    // True once `delay` has passed since the step began (one timer, armed on the first call).
    bool waited_for(Clock::duration delay) {
      if (waited) {
        waited = false;
        return true;
      }
      if (!timer_armed) {
        timer_armed = true;
        timer.expires_after(delay);
        timer.async_wait([weak = weak_from_this()](boost::system::error_code ec) {
          auto self = weak.lock();
          if (ec || !self) return;
          self->timer_armed = false;
          self->waited = true;
          self->advance();
        });
      }
      return false;
    }

    bool in_time(const PeerScript::Step& step, Clock::time_point at) {
      const auto took = at - step_began;
      if ((step.earliest && took < *step.earliest) || (step.latest && took > *step.latest)) {
        return fail(
            where() + ": took " + std::to_string(PeerScript::ms(took)) + " ms, expected " +
            std::to_string(PeerScript::ms(step.earliest.value_or(Clock::duration::zero()))) + ".." +
            (step.latest ? std::to_string(PeerScript::ms(*step.latest)) : "any") + " ms");
      }
      return true;
    }

    bool fail(std::string why) {
      if (failure.empty()) failure = std::move(why);
      return false;
    }

    std::string where() const {
      const auto& steps = script.steps();
      if (next >= steps.size()) return "after the last step";
      return "step " + std::to_string(next + 1) + " of " + std::to_string(steps.size()) + " (" +
             steps[next].description + ")";
    }

    // The last few envelopes that arrived, for failure messages.
    std::string recent() const {
      if (received.empty()) return "; nothing arrived from the side under test";
      std::string text = "; last arrived:";
      const std::size_t from = received.size() > 5 ? received.size() - 5 : 0;
      for (std::size_t i = from; i < received.size(); ++i) {
        text += "\n  " + describe(received[i].envelope);
      }
      return text;
    }

    std::shared_ptr<MessageLink> link;
    PeerScript script;
    boost::asio::steady_timer timer;
    std::vector<Received> received;
    std::size_t inbox_next = 0;  // received[inbox_next..] not yet seen by a step
    std::vector<v1::Envelope> lost;
    std::deque<std::string> outbox;
    std::function<bool(const v1::Envelope&)> tolerated;
    std::size_t next = 0;  // the step being played
    Clock::time_point step_began;
    Clock::time_point closed_at{};
    std::string failure;
    int fail_countdown = 0;
    bool closed = false;
    bool advancing = false;
    bool again = false;
    bool timer_armed = false;
    bool waited = false;
  };

  std::shared_ptr<Core> core_;
};

}  // namespace canbridge::backbone::testing
