// The accept loop the operator endpoints share, on a real Unix socket: the client limit, the
// refusal past it, a client whose coroutine throws (logged, that client closed, the others
// served), and stop() closing every client so that the loop drains.
#include "bridge/endpoint_server.hpp"

#include <gtest/gtest.h>
#include <unistd.h>

#include <boost/asio/io_context.hpp>
#include <boost/asio/local/stream_protocol.hpp>
#include <boost/asio/read.hpp>
#include <boost/asio/write.hpp>
#include <filesystem>
#include <stdexcept>
#include <string>

#include "tests/support/event_loop.hpp"

namespace canbridge::bridge {
namespace {

namespace asio = boost::asio;
using Local = asio::local::stream_protocol;
using Server = EndpointServer<Local::acceptor, Local::socket>;

class EndpointServerTest : public ::testing::Test {
 protected:
  void SetUp() override {
    std::filesystem::remove(path_);
    // Each client gets "hi\n"; a client that sends 't' makes its coroutine throw.
    server_ = std::make_shared<Server>(
        io_.get_executor(), "test endpoint", 2,
        [this](std::shared_ptr<Local::socket> socket) { return serve(std::move(socket)); },
        [](Local::socket& socket) {
          boost::system::error_code ignored;
          asio::write(socket, asio::buffer(std::string("full\n")), ignored);
        });
    server_->acceptor().open(Local());
    server_->acceptor().bind(Local::endpoint(path_));
    server_->acceptor().listen();
    server_->start();
  }
  void TearDown() override { std::filesystem::remove(path_); }

  asio::awaitable<void> serve(std::shared_ptr<Local::socket> socket) {
    co_await asio::async_write(*socket, asio::buffer(std::string("hi\n")), asio::use_awaitable);
    char byte = 0;
    co_await asio::async_read(*socket, asio::buffer(&byte, 1), asio::use_awaitable);
    if (byte == 't') throw std::runtime_error("the client asked for it");
    ++served_;
  }

  // Connects and reads the first line the server sends.
  std::string first_line(Local::socket& client) {
    client.connect(Local::endpoint(path_));
    std::string line;
    bool done = false;
    auto buffer = std::make_shared<std::array<char, 16>>();
    client.async_read_some(asio::buffer(*buffer), [&](boost::system::error_code ec, std::size_t n) {
      if (!ec) line.assign(buffer->data(), n);
      done = true;
    });
    EXPECT_TRUE(test::run_until(io_, [&] { return done; }));
    return line;
  }

  bool reads_eof(Local::socket& client) {
    bool eof = false;
    char byte = 0;
    client.async_read_some(asio::buffer(&byte, 1), [&](boost::system::error_code ec, std::size_t) {
      eof = ec == asio::error::eof;
    });
    return test::run_until(io_, [&] { return eof; });
  }

  asio::io_context io_;
  std::string path_ = (std::filesystem::temp_directory_path() /
                       ("canbridge-endpoint-server-" + std::to_string(::getpid())))
                          .string();
  std::shared_ptr<Server> server_;
  int served_ = 0;
};

TEST_F(EndpointServerTest, AClientPastTheLimitIsRefusedAndTheOthersServed) {
  Local::socket a(io_), b(io_), c(io_);
  EXPECT_EQ(first_line(a), "hi\n");
  EXPECT_EQ(first_line(b), "hi\n");
  EXPECT_EQ(first_line(c), "full\n");
  EXPECT_TRUE(reads_eof(c));
  EXPECT_EQ(server_->refused(), 1u);
  EXPECT_EQ(server_->clients(), 2u);
  asio::write(a, asio::buffer(std::string("x")));
  ASSERT_TRUE(test::run_until(io_, [&] { return server_->clients() == 1; }));
  EXPECT_EQ(served_, 1);
  Local::socket d(io_);  // the place a served client left is free again
  EXPECT_EQ(first_line(d), "hi\n");
}

TEST_F(EndpointServerTest, AThrowingClientIsClosedAndTheServerGoesOn) {
  Local::socket a(io_), b(io_);
  EXPECT_EQ(first_line(a), "hi\n");
  EXPECT_EQ(first_line(b), "hi\n");
  asio::write(a, asio::buffer(std::string("t")));
  EXPECT_TRUE(reads_eof(a)) << "the failed client's socket is closed";
  EXPECT_TRUE(server_->open());
  asio::write(b, asio::buffer(std::string("x")));
  ASSERT_TRUE(test::run_until(io_, [&] { return served_ == 1; }));
}

TEST_F(EndpointServerTest, StopClosesEveryClientAndTheLoopDrains) {
  Local::socket a(io_), b(io_);
  EXPECT_EQ(first_line(a), "hi\n");
  EXPECT_EQ(first_line(b), "hi\n");
  server_->stop();
  EXPECT_TRUE(reads_eof(a));
  EXPECT_TRUE(reads_eof(b));
  a.close();
  b.close();
  EXPECT_TRUE(test::drains_within(io_, std::chrono::seconds(2)))
      << "a coroutine of the server outlived stop()";
  EXPECT_EQ(server_->clients(), 0u);
}

}  // namespace
}  // namespace canbridge::bridge
