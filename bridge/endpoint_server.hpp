// The accept loop the operator endpoints share (command, stats, metrics): a client limit, one
// owned coroutine per client, and an ordered stop; each endpoint supplies only how to serve one
// client and how to refuse one past the limit.
#pragma once

#include <spdlog/spdlog.h>

#include <boost/asio/awaitable.hpp>
#include <boost/asio/steady_timer.hpp>
#include <chrono>
#include <cstddef>
#include <functional>
#include <list>
#include <memory>
#include <string>
#include <utility>

#include "coro/no_error.hpp"
#include "coro/spawn_owned.hpp"

namespace canbridge::bridge {

// Closes what a client is served on: a socket, or a stream around one (beast's tcp_stream).
template <typename Stream>
void close_client(Stream& stream) {
  boost::system::error_code ignored;
  if constexpr (requires { stream.socket(); }) {
    stream.socket().close(ignored);
  } else {
    stream.close(ignored);
  }
}

// A client limit that several servers of one endpoint share (the command endpoint's Unix socket
// and TCP port): max_clients counts the clients of both, not of each.
struct ClientSlots {
  std::size_t max = 0;
  std::size_t used = 0;
};

// `Acceptor` is an asio acceptor (TCP or Unix); `Stream` what a client is served on, made from
// the accepted socket (the socket itself, or a beast::tcp_stream around it). Not thread-safe: use
// it on its executor's thread. Its coroutines hold it by shared_ptr, so the endpoint that made it
// may go once stop() has run.
template <typename Acceptor, typename Stream>
class EndpointServer : public std::enable_shared_from_this<EndpointServer<Acceptor, Stream>> {
 public:
  using Socket = typename Acceptor::protocol_type::socket;
  // Serves one client until it is done; the server closes the stream afterwards.
  using Serve = std::function<boost::asio::awaitable<void>(std::shared_ptr<Stream>)>;
  // Tells a client past the limit why it is closed (a few bytes on a fresh socket; may be empty).
  using Refuse = std::function<void(Socket&)>;

  EndpointServer(const boost::asio::any_io_executor& executor, std::string name,
                 std::size_t max_clients, Serve serve, Refuse refuse = {})
      : EndpointServer(executor, std::move(name),
                       std::make_shared<ClientSlots>(ClientSlots{max_clients, 0}), std::move(serve),
                       std::move(refuse)) {}
  // The same with a limit shared with other servers.
  EndpointServer(const boost::asio::any_io_executor& executor, std::string name,
                 std::shared_ptr<ClientSlots> slots, Serve serve, Refuse refuse = {})
      : acceptor_(executor),
        name_(std::move(name)),
        slots_(std::move(slots)),
        serve_(std::move(serve)),
        refuse_(std::move(refuse)) {}

  // Open, bind and listen on this before start().
  Acceptor& acceptor() { return acceptor_; }

  // Starts accepting. The accept loop is owned: if it ends while the server is open (it threw),
  // the reason is logged and the server stops rather than stay bound without answering.
  void start() {
    open_ = true;
    coro::spawn_owned(acceptor_.get_executor(), accept(),
                      [self = this->shared_from_this()](const std::string& why) {
                        if (!self->open_) return;
                        spdlog::error("{}: stopped accepting: {}", self->name_,
                                      why.empty() ? std::string("the accept loop ended") : why);
                        self->stop();
                      });
  }

  // Closes the listener and every client; their coroutines end at their next wait. Idempotent.
  void stop() {
    open_ = false;
    boost::system::error_code ignored;
    acceptor_.close(ignored);
    for (auto& client : clients_) close_client(*client);
  }

  bool open() const { return open_; }
  std::size_t clients() const { return clients_.size(); }
  std::uint64_t refused() const { return refused_; }

 private:
  boost::asio::awaitable<void> accept() {
    auto self = this->shared_from_this();
    while (open_) {
      auto [ec, socket] = co_await acceptor_.async_accept(coro::kNoError);
      if (!open_) break;
      if (ec) {
        if (!warned_accept_) {
          warned_accept_ = true;
          spdlog::warn("{}: accept failed: {} (further failures are not logged)", name_,
                       ec.message());
        }
        // EMFILE and the like would fail again at once: give the loop a breath.
        boost::asio::steady_timer pause(acceptor_.get_executor(), std::chrono::milliseconds(100));
        co_await pause.async_wait(coro::kNoError);
        continue;
      }
      if (slots_->used >= slots_->max) {
        ++refused_;
        if (refuse_) refuse_(socket);
        continue;  // the socket closes as it goes out of scope
      }
      clients_.push_back(std::make_shared<Stream>(std::move(socket)));
      ++slots_->used;
      const auto client = clients_.back();
      // A client's coroutine belongs to the server: its end, even by an exception, closes that
      // client and is logged; the other clients and the accept loop go on.
      coro::spawn_owned(acceptor_.get_executor(), serve_(client),
                        [self, client](const std::string& why) {
                          if (!why.empty())
                            spdlog::error("{}: a client failed: {}", self->name_, why);
                          close_client(*client);
                          self->clients_.remove(client);
                          --self->slots_->used;
                        });
    }
  }

  Acceptor acceptor_;
  std::string name_;
  std::shared_ptr<ClientSlots> slots_;
  Serve serve_;
  Refuse refuse_;
  std::list<std::shared_ptr<Stream>> clients_;
  std::uint64_t refused_ = 0;
  bool open_ = false;
  bool warned_accept_ = false;
};

}  // namespace canbridge::bridge
