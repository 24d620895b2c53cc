// An executor for work that must give way to the rest of the event loop (the TLS handshakes of
// peers that have not proven anything yet): its handlers wait in a queue of their own, and at most
// `per_pass` of them run per pass of the loop, each batch behind the handlers that were ready
// before it. A flood of handshakes then costs the established links a bounded delay per pass
// instead of a turn behind every handshake step that happened to be ready at the same time.
#pragma once

#include <boost/asio/any_io_executor.hpp>
#include <boost/asio/execution.hpp>
#include <boost/asio/execution_context.hpp>
#include <cstddef>
#include <cstdint>
#include <deque>
#include <memory>
#include <type_traits>
#include <utility>

namespace canbridge::backbone {

// Not thread-safe: one event loop thread (as every backbone object).
class LowPriorityQueue : public std::enable_shared_from_this<LowPriorityQueue> {
 public:
  class Executor;

  // `inner`: the loop's own executor, where a pass of this queue is posted. `per_pass`: handlers
  // run per pass (at least 1).
  static std::shared_ptr<LowPriorityQueue> create(boost::asio::any_io_executor inner,
                                                  std::size_t per_pass);
  ~LowPriorityQueue();
  LowPriorityQueue(const LowPriorityQueue&) = delete;
  LowPriorityQueue& operator=(const LowPriorityQueue&) = delete;

  // Spawn a coroutine on it (co_spawn) and every completion it awaits comes back through the
  // queue. Copies keep the queue alive, as a strand's do.
  Executor executor();

  struct Counters {
    std::uint64_t run = 0;          // handlers run
    std::uint64_t passes = 0;       // passes that ran at least one
    std::uint64_t deferred = 0;     // passes that left work for a later pass
    std::uint64_t queued_peak = 0;  // the most handlers waiting at once
  };
  const Counters& counters() const noexcept { return counters_; }
  std::size_t queued() const noexcept { return queue_.size(); }

 private:
  struct Work {
    virtual ~Work() = default;
    virtual void run() = 0;
  };
  template <typename Function>
  struct WorkOf final : Work {
    explicit WorkOf(Function f) : function(std::move(f)) {}
    void run() override { std::move(function)(); }
    Function function;
  };
  // The posted pass; when the loop destroys it unrun (shut down), it drops the queued work, whose
  // coroutine frames hold executors of this queue: nothing is kept alive in a cycle.
  struct Pass;

  LowPriorityQueue(boost::asio::any_io_executor inner, std::size_t per_pass);
  void push(std::unique_ptr<Work> work);
  void post_pass();
  void run_pass();
  void abandon();

  boost::asio::any_io_executor inner_;
  std::size_t per_pass_;
  std::deque<std::unique_ptr<Work>> queue_;
  bool pass_posted_ = false;
  Counters counters_;

  friend class Executor;
};

// An Asio executor (usable wherever any_io_executor is): execute() never runs the function in
// place, it queues it for a later pass.
class LowPriorityQueue::Executor {
 public:
  explicit Executor(std::shared_ptr<LowPriorityQueue> queue) noexcept : queue_(std::move(queue)) {}

  boost::asio::execution_context& query(boost::asio::execution::context_t) const noexcept {
    return boost::asio::query(queue_->inner_, boost::asio::execution::context);
  }
  static constexpr boost::asio::execution::blocking_t query(
      boost::asio::execution::blocking_t) noexcept {
    return boost::asio::execution::blocking.never;
  }
  Executor require(boost::asio::execution::blocking_t::never_t) const noexcept { return *this; }

  template <typename Function>
  void execute(Function&& function) const {
    using Decayed = std::decay_t<Function>;
    queue_->push(std::make_unique<WorkOf<Decayed>>(std::forward<Function>(function)));
  }

  friend bool operator==(const Executor& a, const Executor& b) noexcept {
    return a.queue_ == b.queue_;
  }
  friend bool operator!=(const Executor& a, const Executor& b) noexcept { return !(a == b); }

 private:
  std::shared_ptr<LowPriorityQueue> queue_;
};

}  // namespace canbridge::backbone
