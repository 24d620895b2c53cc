#include "backbone/low_priority_executor.hpp"

#include <algorithm>
#include <boost/asio/post.hpp>

namespace canbridge::backbone {

namespace asio = boost::asio;

struct LowPriorityQueue::Pass {
  explicit Pass(std::shared_ptr<LowPriorityQueue> q) : queue(std::move(q)) {}
  Pass(Pass&& other) noexcept : queue(std::move(other.queue)) {}
  Pass(const Pass&) = delete;
  Pass& operator=(const Pass&) = delete;
  Pass& operator=(Pass&&) = delete;
  ~Pass() {
    if (queue) queue->abandon();
  }
  void operator()() {
    auto q = std::move(queue);  // ran: nothing to abandon
    q->run_pass();
  }
  std::shared_ptr<LowPriorityQueue> queue;
};

std::shared_ptr<LowPriorityQueue> LowPriorityQueue::create(asio::any_io_executor inner,
                                                           std::size_t per_pass) {
  return std::shared_ptr<LowPriorityQueue>(new LowPriorityQueue(std::move(inner), per_pass));
}

LowPriorityQueue::LowPriorityQueue(asio::any_io_executor inner, std::size_t per_pass)
    : inner_(std::move(inner)), per_pass_(std::max<std::size_t>(per_pass, 1)) {}

LowPriorityQueue::~LowPriorityQueue() = default;

LowPriorityQueue::Executor LowPriorityQueue::executor() {
  return Executor(shared_from_this());
}

void LowPriorityQueue::push(std::unique_ptr<Work> work) {
  queue_.push_back(std::move(work));
  counters_.queued_peak = std::max<std::uint64_t>(counters_.queued_peak, queue_.size());
  post_pass();
}

void LowPriorityQueue::post_pass() {
  if (pass_posted_) return;
  pass_posted_ = true;
  // post, never dispatch: the pass goes behind everything the loop has ready now.
  asio::post(inner_, Pass(shared_from_this()));
}

void LowPriorityQueue::run_pass() {
  pass_posted_ = false;
  ++counters_.passes;
  // Only what was queued before this pass: a handler that queues more (a coroutine's next step
  // completing in place) waits for the next pass like everything else.
  std::size_t budget = std::min(per_pass_, queue_.size());
  while (budget-- > 0 && !queue_.empty()) {
    std::unique_ptr<Work> work = std::move(queue_.front());
    queue_.pop_front();
    ++counters_.run;
    work->run();
  }
  if (!queue_.empty()) {
    ++counters_.deferred;
    post_pass();
  }
}

void LowPriorityQueue::abandon() {
  pass_posted_ = false;
  // Destroyed outside the member: destroying a coroutine's handler posts the unwinding of its
  // frame back to this executor (Asio does so), which queues it and posts a pass again; the loop
  // destroys that pass in turn, and the chain ends with the frames.
  auto dropped = std::move(queue_);
  queue_.clear();
  dropped.clear();
}

}  // namespace canbridge::backbone
