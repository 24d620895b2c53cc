#include "bridge/bus_writer.hpp"

#include <boost/asio/as_tuple.hpp>
#include <boost/asio/use_awaitable.hpp>
#include <exception>

#include "coro/spawn_owned.hpp"

namespace canbridge::bridge {

namespace asio = boost::asio;

namespace {
BusWriteQueue::Options with_capacity(BusWriteQueue::Options options, const can::Bus& bus) {
  options.bus_capacity = bus.send_room();
  return options;
}
}  // namespace

BusWriter::BusWriter(asio::any_io_executor executor, can::Bus& bus, BusWriteQueue::Options options,
                     Written on_written, BacklogChanged on_backlog_changed)
    : bus_(bus),
      queue_(with_capacity(options, bus)),
      on_written_(std::move(on_written)),
      on_backlog_changed_(std::move(on_backlog_changed)),
      wake_(std::move(executor), asio::steady_timer::time_point::max()) {}

void BusWriter::start() {
  coro::spawn_owned(wake_.get_executor(), run(), [this](const std::string& why) {
    if (stopped_) return;
    if (on_end_) on_end_(why.empty() ? "the bus closed" : why);
  });
}

void BusWriter::stop() {
  stopped_ = true;
  wake_.cancel();
}

// Hands what fits now (out_) to the bus, wakes the writer coroutine for what waits, and reports a
// change of backlog: the common end of write() and write_each().
void BusWriter::finish_write(bool was_backlogged) {
  send(out_);
  if (!queue_.empty() && idle_) {
    idle_ = false;
    wake_.cancel();
  }
  after_change(was_backlogged);
}

bool BusWriter::write(const can::Frame& frame, BusWriteQueue::Lane lane) {
  return write(std::span<const can::Frame>(&frame, 1), lane);
}

bool BusWriter::write(std::span<const can::Frame> unit, BusWriteQueue::Lane lane) {
  const bool was_backlogged = queue_.backlogged();
  out_.clear();
  const bool accepted = queue_.offer(unit, lane, bus_.send_room(), out_);
  finish_write(was_backlogged);
  return accepted;
}

std::size_t BusWriter::write_each(std::span<const can::Frame> frames,
                                  std::vector<can::Frame>* accepted) {
  const bool was_backlogged = queue_.backlogged();
  out_.clear();
  const std::size_t room = bus_.send_room();
  std::size_t dropped = 0;
  for (const can::Frame& frame : frames) {
    // out_ never holds more than `room`: offer() appends only what fits in what is left.
    if (!queue_.offer(std::span<const can::Frame>(&frame, 1), bus_lane_of(frame),
                      room - out_.size(), out_)) {
      ++dropped;
    } else if (accepted != nullptr) {
      accepted->push_back(frame);
    }
  }
  finish_write(was_backlogged);
  return dropped;
}

asio::awaitable<void> BusWriter::run() {
  while (!stopped_) {
    if (queue_.empty()) {
      idle_ = true;
      co_await wake_.async_wait(asio::as_tuple(asio::use_awaitable));
      idle_ = false;
      continue;
    }
    if (std::error_code ec = co_await bus_.wait_send_room(queue_.head_frames())) {
      if (stopped_) co_return;
      const bool was_backlogged = queue_.backlogged();
      queue_.clear();  // the bus closed: nothing waiting can go any more (counted)
      after_change(was_backlogged);
      co_return;
    }
    if (stopped_) co_return;
    const bool was_backlogged = queue_.backlogged();
    out_.clear();
    queue_.take(bus_.send_room(), out_);
    send(out_);
    after_change(was_backlogged);
  }
}

void BusWriter::send(const std::vector<can::Frame>& frames) {
  if (frames.empty()) return;
  // The queue handed out only what the bus said it had room for: one batch send takes it all
  // (unless the bus closed meanwhile).
  const std::size_t sent = bus_.send(std::span<const can::Frame>(frames));
  refused_ += frames.size() - sent;
  if (sent != 0 && on_written_) on_written_(std::span<const can::Frame>(frames.data(), sent));
}

std::size_t BusWriter::withdraw(const std::function<bool(const can::Frame&)>& withdrawn) {
  const bool was_backlogged = queue_.backlogged();
  const std::size_t removed = queue_.withdraw_single_frames(withdrawn);
  after_change(was_backlogged);
  return removed + bus_.withdraw_queued(withdrawn);
}

void BusWriter::after_change(bool was_backlogged) {
  if (queue_.backlogged() != was_backlogged && on_backlog_changed_) {
    on_backlog_changed_(queue_.backlogged());
  }
}

}  // namespace canbridge::bridge
