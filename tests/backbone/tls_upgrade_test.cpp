// TLS 1.3 on TCP backbones, end to end over loopback: PSK and certificate handshakes, who each
// end says it talks to, refusals on both ends, rotation, plain/TLS mix-ups, cancellation, and
// the TcpClient running the upgrade. Certificates are made here with the openssl CLI in a
// temporary directory; keys are random per run. Nothing secret is committed.
#include "backbone/tls_upgrade.hpp"

#include <gtest/gtest.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <openssl/rand.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <unistd.h>

#include <boost/asio/as_tuple.hpp>
#include <boost/asio/bind_cancellation_slot.hpp>
#include <boost/asio/cancellation_signal.hpp>
#include <boost/asio/co_spawn.hpp>
#include <boost/asio/use_awaitable.hpp>
#include <chrono>
#include <cstdlib>
#include <filesystem>
#include <optional>
#include <stdexcept>

#include "backbone/tcp_client.hpp"
#include "backbone/tls_identity.hpp"
#include "tests/backbone/link_test_support.hpp"
#include "tests/backbone/test_support.hpp"

namespace canbridge::backbone {
namespace {

namespace asio = boost::asio;
using asio::ip::tcp;
using namespace std::chrono_literals;
using testing::Inbox;
using testing::Outbox;
using testing::run_until;

constexpr auto kNoError = asio::as_tuple(asio::use_awaitable);

PreSharedKey random_key() {
  std::array<std::uint8_t, kPreSharedKeySize> bytes{};
  if (RAND_bytes(bytes.data(), static_cast<int>(bytes.size())) != 1) {
    throw std::runtime_error("RAND_bytes failed");
  }
  return PreSharedKey(bytes);
}

// Rethrows what a test coroutine threw, so a failure inside one fails the test.
void rethrow(std::exception_ptr e) {
  if (e) std::rethrow_exception(e);
}

// A private CA and leaf certificates, made once for the suite with the openssl CLI (Ed25519:
// fast), deleted afterwards.
class Certificates {
 public:
  Certificates() {
    dir_ = std::filesystem::temp_directory_path() /
           ("canbridge_tls_test_" + std::to_string(::getpid()));
    std::filesystem::create_directories(dir_);
    make_ca("ca");
    make_ca("other-ca");
    make_leaf("gw1", "gw1", "ca", "clientAuth");
    make_leaf("intruder", "intruder", "ca", "clientAuth");
    make_leaf("gw1-other-ca", "gw1", "other-ca", "clientAuth");
    make_leaf("surface", "surface", "ca", "serverAuth");
    make_leaf("not-surface", "not-surface", "ca", "serverAuth");
  }
  ~Certificates() { std::filesystem::remove_all(dir_); }

  std::string path(const std::string& file) const { return (dir_ / file).string(); }

  TlsCertificates credentials(const std::string& leaf, bool server,
                              std::vector<std::string> accepted) const {
    TlsCertificates c;
    c.server = server;
    c.certificate_file = path(leaf + ".crt");
    c.private_key_file = path(leaf + ".key.pem");
    c.ca_file = path("ca.crt");
    c.accepted_names = std::move(accepted);
    return c;
  }

 private:
  void run(const std::string& command) const {
    const std::string line =
        "cd '" + dir_.string() + "' && umask 077 && " + command + " >/dev/null 2>&1";
    if (std::system(line.c_str()) != 0) throw std::runtime_error("failed: " + command);
  }
  void make_ca(const std::string& name) const {
    run("openssl req -x509 -newkey ed25519 -nodes -keyout " + name + ".key -out " + name +
        ".crt -days 30 -subj '/CN=" + name +
        "' -addext basicConstraints=critical,CA:TRUE -addext keyUsage=critical,keyCertSign");
  }
  void make_leaf(const std::string& file, const std::string& name, const std::string& ca,
                 const std::string& usage) const {
    run("openssl req -newkey ed25519 -nodes -keyout " + file + ".key.pem -out " + file +
        ".csr -subj '/CN=" + name + "'");
    run("printf 'basicConstraints=CA:FALSE\\nkeyUsage=critical,digitalSignature\\n"
        "extendedKeyUsage=" +
        usage + "\\nsubjectAltName=DNS:" + name + "\\n' > " + file + ".ext");
    run("openssl x509 -req -in " + file + ".csr -CA " + ca + ".crt -CAkey " + ca +
        ".key -CAcreateserial -out " + file + ".crt -days 30 -extfile " + file + ".ext");
  }

  std::filesystem::path dir_;
};

// Both ends of one handshake over loopback, each end's result, then (if both made a link) a
// message each way.
class TlsTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() { certificates_ = new Certificates(); }
  static void TearDownTestSuite() {
    delete certificates_;
    certificates_ = nullptr;
  }
  static const Certificates& certs() { return *certificates_; }

  void TearDown() override {
    for (auto* result : {&server_result, &client_result}) {
      if (*result && (*result)->link) (*result)->link->close();
    }
    EXPECT_TRUE(testing::drains_within(io, 2s));
  }

  // Accepts one connection and upgrades it with `server`; connects and upgrades with `client`
  // (null: a plain socket kept in plain_client). Runs until both ends have a result.
  void handshake(const std::shared_ptr<TlsUpgrade>& server,
                 const std::shared_ptr<TlsUpgrade>& client) {
    asio::co_spawn(io, accept_and_upgrade(server), rethrow);
    asio::co_spawn(io, connect_and_upgrade(client), rethrow);
    if (!client) return;  // the test drives the plain client itself
    ASSERT_TRUE(run_until(
        io, [&] { return server_result && client_result; }, 5s));
  }

  asio::awaitable<void> accept_and_upgrade(std::shared_ptr<TlsUpgrade> server) {
    auto [ec, socket] = co_await acceptor.async_accept(kNoError);
    if (ec) throw std::runtime_error("accept: " + ec.message());
    server_result = co_await server->upgrade(std::move(socket), link_options);
  }

  asio::awaitable<void> connect_and_upgrade(std::shared_ptr<TlsUpgrade> client) {
    auto [ec] = co_await plain_client.async_connect(acceptor.local_endpoint(), kNoError);
    if (ec) throw std::runtime_error("connect: " + ec.message());
    plain_connected = true;
    if (client) client_result = co_await client->upgrade(std::move(plain_client), link_options);
  }

  // Both links carry a message each way.
  void expect_messages_cross() {
    ASSERT_TRUE(server_result->link && client_result->link);
    server_in = {};
    client_in = {};
    for (std::uint32_t i = 0; i < 500; ++i) client_out.pending.push_back(testing::numbered(i));
    server_out.pending.push_back("pong");
    server_result->link->start(server_in.on_message(), server_out.source(), server_in.on_closed());
    client_result->link->start(client_in.on_message(), client_out.source(), client_in.on_closed());
    client_result->link->wake_writer();
    ASSERT_TRUE(run_until(
        io, [&] { return server_in.messages.size() == 500 && client_in.messages.size() == 1; }));
    for (std::uint32_t i = 0; i < 500; ++i) EXPECT_EQ(server_in.messages[i], testing::numbered(i));
    EXPECT_EQ(client_in.messages[0], "pong");
  }

  // The client end was refused: no link, or (TLS 1.3 lets the client finish before the server
  // has checked its certificate) a link that ends refused before delivering anything.
  void expect_client_refused() {
    ASSERT_TRUE(client_result);
    if (!client_result->link) {
      EXPECT_TRUE(client_result->error);
      return;
    }
    client_out.pending.push_back("hello");
    client_result->link->start(client_in.on_message(), client_out.source(), client_in.on_closed());
    ASSERT_TRUE(run_until(io, [&] { return client_in.closed_calls == 1; }));
    EXPECT_EQ(client_in.reason, make_error_code(errc::refused_by_peer))
        << client_in.reason.message();
    EXPECT_TRUE(client_in.messages.empty());
  }

  static TlsSurfacePsk surface_psk(std::string name, std::vector<PreSharedKey> keys) {
    TlsSurfacePsk psk;
    psk.gateways.emplace(std::move(name), std::move(keys));
    return psk;
  }
  static TlsGatewayPsk gateway_psk(std::string name, std::vector<PreSharedKey> keys) {
    return TlsGatewayPsk{std::move(name), std::move(keys), "surface", nullptr};
  }

  asio::io_context io;
  StreamLinkOptions link_options;  // of both ends' links
  tcp::acceptor acceptor{io, tcp::endpoint(asio::ip::address_v4::loopback(), 0)};
  tcp::socket plain_client{io};
  bool plain_connected = false;
  // What the links under test send and receive; members, as the links outlive a test's body.
  Outbox server_out, client_out;
  Inbox server_in, client_in;
  std::optional<UpgradeResult> server_result, client_result;
  const PreSharedKey key = random_key();
  const PreSharedKey other_key = random_key();

 private:
  static Certificates* certificates_;
};

Certificates* TlsTest::certificates_ = nullptr;

TEST(TlsIdentity, PskIdentityIsNameSlashHexKeyIdAndParsesBack) {
  const PreSharedKey key = random_key();
  const std::string identity = psk_identity("gw/1", key);
  ASSERT_EQ(identity.size(), 4 + 1 + 16);
  EXPECT_EQ(identity.substr(0, 5), "gw/1/");
  const auto parsed = parse_psk_identity(identity);
  ASSERT_TRUE(parsed);
  EXPECT_EQ(parsed->gateway_name, "gw/1");
  EXPECT_EQ(parsed->key_id, key_id(key));
}

TEST(TlsIdentity, MalformedIdentitiesAreRejected) {
  for (const char* bad : {"", "gw1", "/0011223344556677", "gw1/001122334455667",
                          "gw1/00112233445566778", "gw1/00112233445566zz"}) {
    EXPECT_FALSE(parse_psk_identity(bad)) << bad;
  }
}

TEST_F(TlsTest, PskLinkCarriesMessagesBothWaysAndEachEndNamesItsPeer) {
  auto surface = TlsUpgrade::create(surface_psk("gw1", {key}));
  auto gateway = TlsUpgrade::create(gateway_psk("gw1", {key}));
  handshake(surface, gateway);
  ASSERT_TRUE(server_result->link) << server_result->error.message();
  ASSERT_TRUE(client_result->link) << client_result->error.message();
  EXPECT_TRUE(server_result->link->is_tls());
  EXPECT_EQ(server_result->link->authenticated_peer(), "gw1");
  EXPECT_EQ(client_result->link->authenticated_peer(), "surface");
  // Under TLS too, the socket below sends each write at once (no Nagle delay) on both ends.
  for (const auto& link : {server_result->link, client_result->link}) {
    int nodelay = 0;
    socklen_t length = sizeof nodelay;
    ASSERT_EQ(::getsockopt(link->native_handle(), IPPROTO_TCP, TCP_NODELAY, &nodelay, &length), 0);
    EXPECT_NE(nodelay, 0);
  }
  EXPECT_EQ(surface->counters().succeeded, 1u);
  EXPECT_EQ(gateway->counters().succeeded, 1u);
  expect_messages_cross();
}

// More than a megabyte each way, more than both socket buffers hold, while one end does not read:
// OpenSSL finds the socket full in the middle of records (the write is finished later with the same
// bytes), reads several records per receive, and every message still arrives once, in order, on a
// link that stays up.
TEST_F(TlsTest, PskLinkCarriesABulkTransferBothWaysThroughFullSockets) {
  auto surface = TlsUpgrade::create(surface_psk("gw1", {key}));
  auto gateway = TlsUpgrade::create(gateway_psk("gw1", {key}));
  handshake(surface, gateway);
  ASSERT_TRUE(server_result->link && client_result->link);
  constexpr std::uint32_t kMessages = 4000;  // 1.2 MB: the two 256 KiB buffers fill
  const auto message = [](std::uint32_t i) { return testing::numbered(i) + std::string(300, 'x'); };
  for (std::uint32_t i = 0; i < kMessages; ++i) {
    client_out.pending.push_back(message(i));
    server_out.pending.push_back(message(i));
  }
  auto& server = *server_result->link;
  auto& client = *client_result->link;
  server.start(server_in.on_message(), server_out.source(), server_in.on_closed());
  server.pause_reading(true);  // the client's writes back up in the sockets
  client.start(client_in.on_message(), client_out.source(), client_in.on_closed());
  client.wake_writer();
  server.wake_writer();
  ASSERT_TRUE(
      run_until(io, [&] { return server.input_waiting() && client_in.messages.size() > 0; }));
  io.poll();
  EXPECT_LT(server_in.messages.size(), kMessages);
  server.pause_reading(false);
  ASSERT_TRUE(run_until(io,
                        [&] {
                          return server_in.messages.size() == kMessages &&
                                 client_in.messages.size() == kMessages;
                        }))
      << "server got " << server_in.messages.size() << ", client got " << client_in.messages.size();
  for (std::uint32_t i = 0; i < kMessages; ++i) {
    ASSERT_EQ(server_in.messages[i], message(i)) << i;
    ASSERT_EQ(client_in.messages[i], message(i)) << i;
  }
  EXPECT_EQ(server_in.closed_calls + client_in.closed_calls, 0);
}

TEST_F(TlsTest, PskWrongKeyIsRefusedByBothEnds) {
  auto surface = TlsUpgrade::create(surface_psk("gw1", {key}));
  auto gateway = TlsUpgrade::create(gateway_psk("gw1", {other_key}));
  handshake(surface, gateway);
  EXPECT_FALSE(server_result->link);
  EXPECT_EQ(server_result->error, TlsFailure::unknown_identity);
  EXPECT_FALSE(client_result->link);
  EXPECT_EQ(client_result->error, TlsFailure::refused_by_peer) << client_result->error.message();
  EXPECT_EQ(surface->counters()[TlsFailure::unknown_identity], 1u);
  EXPECT_EQ(surface->counters().succeeded, 0u);
}

TEST_F(TlsTest, PskUnknownGatewayNameIsRefused) {
  auto surface = TlsUpgrade::create(surface_psk("gw1", {key}));
  auto intruder = TlsUpgrade::create(gateway_psk("intruder", {key}));
  handshake(surface, intruder);
  EXPECT_FALSE(server_result->link);
  EXPECT_EQ(server_result->error, TlsFailure::unknown_identity);
  EXPECT_FALSE(client_result->link);
  EXPECT_EQ(surface->counters()[TlsFailure::unknown_identity], 1u);
}

TEST_F(TlsTest, PskRotationSurfaceWithTwoKeysAcceptsAGatewayProvingWithEither) {
  auto surface = TlsUpgrade::create(surface_psk("gw1", {key, other_key}));
  for (const auto& gateway_keys : {std::vector{key}, std::vector{other_key, key}}) {
    server_result.reset();
    client_result.reset();
    plain_client = tcp::socket(io);
    handshake(surface, TlsUpgrade::create(gateway_psk("gw1", gateway_keys)));
    ASSERT_TRUE(server_result->link) << server_result->error.message();
    ASSERT_TRUE(client_result->link) << client_result->error.message();
    EXPECT_EQ(server_result->link->authenticated_peer(), "gw1");
    expect_messages_cross();
    server_result->link->close();
    client_result->link->close();
  }
  EXPECT_EQ(surface->counters().succeeded, 2u);
}

// Keys watched in their files (app/tls_setup: KeyFileWatch) rotate without a new TlsUpgrade:
// each handshake asks both ends for the keys as they are then.
TEST_F(TlsTest, PskRotationWithWatchedKeysNeedsNoRestartOfEitherEnd) {
  std::vector<PreSharedKey> surface_file{key};
  std::vector<PreSharedKey> gateway_file{key};
  TlsSurfacePsk surface_psk_watched = surface_psk("gw1", {key});
  surface_psk_watched.current_keys = [&](const std::string& gateway) {
    return gateway == "gw1" ? surface_file : std::vector<PreSharedKey>{};
  };
  TlsGatewayPsk gateway_psk_watched = gateway_psk("gw1", {key});
  gateway_psk_watched.current_keys = [&] { return gateway_file; };
  auto surface = TlsUpgrade::create(std::move(surface_psk_watched));
  auto gateway = TlsUpgrade::create(std::move(gateway_psk_watched));
  const auto connect = [&] {
    server_result.reset();
    client_result.reset();
    plain_client = tcp::socket(io);
    handshake(surface, gateway);
  };
  // 1: the gateway moves to the new key before the surface knows it: refused.
  gateway_file = {other_key, key};
  connect();
  EXPECT_FALSE(server_result->link);
  EXPECT_EQ(server_result->error, TlsFailure::unknown_identity);
  // 2: the surface's file gains the new key: accepted, proving with the new key.
  surface_file = {key, other_key};
  connect();
  ASSERT_TRUE(server_result->link) << server_result->error.message();
  ASSERT_TRUE(client_result->link) << client_result->error.message();
  server_result->link->close();
  client_result->link->close();
  // 3: the old key leaves the surface's file: a gateway still proving with it is refused.
  surface_file = {other_key};
  gateway_file = {key};
  connect();
  EXPECT_FALSE(server_result->link);
  EXPECT_EQ(surface->counters().succeeded, 1u);
}

TEST_F(TlsTest, CertificatesGoodPairWorksAndNamesThePeers) {
  auto surface = TlsUpgrade::create(certs().credentials("surface", true, {"gw1", "gw2"}));
  auto gateway = TlsUpgrade::create(certs().credentials("gw1", false, {"surface"}));
  handshake(surface, gateway);
  ASSERT_TRUE(server_result->link) << server_result->error.message();
  ASSERT_TRUE(client_result->link) << client_result->error.message();
  EXPECT_EQ(server_result->link->authenticated_peer(), "gw1");
  EXPECT_EQ(client_result->link->authenticated_peer(), "surface");
  expect_messages_cross();
}

TEST_F(TlsTest, CertificatesGatewayCertificateFromAnotherCaIsRefused) {
  auto surface = TlsUpgrade::create(certs().credentials("surface", true, {"gw1"}));
  TlsCertificates foreign = certs().credentials("gw1-other-ca", false, {"surface"});
  auto gateway = TlsUpgrade::create(foreign);
  handshake(surface, gateway);
  EXPECT_FALSE(server_result->link);
  EXPECT_EQ(server_result->error, TlsFailure::certificate_rejected)
      << server_result->error.message();
  expect_client_refused();
}

TEST_F(TlsTest, CertificatesGatewayWithANameNotConfiguredIsRefused) {
  auto surface = TlsUpgrade::create(certs().credentials("surface", true, {"gw1"}));
  auto intruder = TlsUpgrade::create(certs().credentials("intruder", false, {"surface"}));
  handshake(surface, intruder);
  EXPECT_FALSE(server_result->link);
  EXPECT_EQ(server_result->error, TlsFailure::name_not_accepted) << server_result->error.message();
  EXPECT_EQ(surface->counters()[TlsFailure::name_not_accepted], 1u);
  expect_client_refused();
}

TEST_F(TlsTest, CertificatesSurfaceWithTheWrongNameIsRefusedByTheGateway) {
  auto impostor = TlsUpgrade::create(certs().credentials("not-surface", true, {"gw1"}));
  auto gateway = TlsUpgrade::create(certs().credentials("gw1", false, {"surface"}));
  handshake(impostor, gateway);
  EXPECT_FALSE(client_result->link);
  EXPECT_EQ(client_result->error, TlsFailure::name_not_accepted) << client_result->error.message();
  EXPECT_EQ(gateway->counters()[TlsFailure::name_not_accepted], 1u);
  EXPECT_FALSE(server_result->link);
}

TEST_F(TlsTest, PskGatewayRefusesASurfaceThatAnswersWithACertificateInsteadOfTheKey) {
  auto certificate_surface = TlsUpgrade::create(certs().credentials("surface", true, {"gw1"}));
  auto gateway = TlsUpgrade::create(gateway_psk("gw1", {key}));
  handshake(certificate_surface, gateway);
  EXPECT_FALSE(client_result->link);
  EXPECT_TRUE(client_result->error);
  EXPECT_EQ(gateway->counters().succeeded, 0u);
  EXPECT_FALSE(server_result->link);
}

TEST_F(TlsTest, PrivateKeyReadableByOthersIsRefusedAtStartNamingTheFix) {
  TlsCertificates c = certs().credentials("gw1", false, {"surface"});
  const std::string open_copy = certs().path("gw1-open.key.pem");
  std::filesystem::copy_file(c.private_key_file, open_copy,
                             std::filesystem::copy_options::overwrite_existing);
  ASSERT_EQ(::chmod(open_copy.c_str(), 0644), 0);
  c.private_key_file = open_copy;
  try {
    TlsUpgrade::create(c);
    FAIL() << "a private key with mode 0644 was accepted";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("chmod 600"), std::string::npos) << e.what();
  }
}

TEST_F(TlsTest, PlainClientAgainstTlsServerIsRefused) {
  auto surface = TlsUpgrade::create(surface_psk("gw1", {key}));
  handshake(surface, nullptr);  // the client stays a plain socket; wrap it as a plain link:
  ASSERT_TRUE(run_until(io, [&] { return plain_connected; }));
  auto plain = StreamLink::create(std::move(plain_client));
  client_out.pending.push_back("hello, I am gw1");
  plain->start(client_in.on_message(), client_out.source(), client_in.on_closed());
  ASSERT_TRUE(
      run_until(io, [&] { return server_result.has_value() && client_in.closed_calls == 1; }));
  EXPECT_FALSE(server_result->link);
  EXPECT_EQ(server_result->error, TlsFailure::not_tls) << server_result->error.message();
  EXPECT_EQ(surface->counters()[TlsFailure::not_tls], 1u);
  EXPECT_TRUE(client_in.messages.empty());
}

TEST_F(TlsTest, TlsClientAgainstPlainServerFailsCleanly) {
  auto gateway = TlsUpgrade::create(gateway_psk("gw1", {key}));
  std::shared_ptr<StreamLink> plain_server;
  server_out.pending.push_back("welcome");
  acceptor.async_accept([&](boost::system::error_code ec, tcp::socket socket) {
    ASSERT_FALSE(ec);
    plain_server = StreamLink::create(std::move(socket));
    plain_server->start(server_in.on_message(), server_out.source(), server_in.on_closed());
  });
  asio::co_spawn(io, connect_and_upgrade(gateway), rethrow);
  ASSERT_TRUE(run_until(io, [&] { return client_result.has_value(); }));
  EXPECT_FALSE(client_result->link);
  EXPECT_TRUE(client_result->error);
  EXPECT_EQ(gateway->counters().failed_total(), 1u);
  server_result = UpgradeResult{plain_server, {}};  // closed by TearDown
}

TEST_F(TlsTest, StalledServerHandshakeEndsPromptlyWhenCancelled) {
  auto surface = TlsUpgrade::create(surface_psk("gw1", {key}));
  asio::cancellation_signal cancel;
  std::optional<UpgradeResult> result;
  acceptor.async_accept([&](boost::system::error_code ec, tcp::socket socket) {
    ASSERT_FALSE(ec);
    asio::co_spawn(
        io, surface->upgrade(std::move(socket), {}),
        asio::bind_cancellation_slot(cancel.slot(), [&](std::exception_ptr e, UpgradeResult r) {
          rethrow(e);
          result = std::move(r);
        }));
  });
  plain_client.connect(acceptor.local_endpoint());  // and never sends a byte
  for (int i = 0; i < 20; ++i) io.poll();
  ASSERT_FALSE(result) << "the handshake ended without a ClientHello";
  const auto start = std::chrono::steady_clock::now();
  cancel.emit(asio::cancellation_type::terminal);
  ASSERT_TRUE(run_until(
      io, [&] { return result.has_value(); }, 1s));
  EXPECT_LT(std::chrono::steady_clock::now() - start, 500ms);
  EXPECT_FALSE(result->link);
  EXPECT_EQ(result->error, TlsFailure::cancelled);
  EXPECT_EQ(result->error, std::errc::operation_canceled);
  EXPECT_EQ(surface->counters()[TlsFailure::cancelled], 1u);
}

// TcpClient runs the upgrade after connecting: a link over TLS, or backing off when refused.
class TlsClientTest : public TlsTest {
 protected:
  asio::awaitable<void> serve(std::shared_ptr<TlsUpgrade> server) {
    for (;;) {
      auto [ec, socket] = co_await acceptor.async_accept(kNoError);
      if (ec) co_return;
      auto result = co_await server->upgrade(std::move(socket), {});
      if (result.link) served.push_back(result.link);
    }
  }
  std::shared_ptr<TcpClient> client(const std::shared_ptr<TlsUpgrade>& upgrade) {
    ClientOptions options;
    options.backoff_min = 5ms;
    options.backoff_max = 20ms;
    options.connect_timeout = 2s;
    options.upgrade = upgrade->link_upgrade();
    auto c = TcpClient::create(io.get_executor(), "127.0.0.1", acceptor.local_endpoint().port(),
                               options);
    c->start([this](std::shared_ptr<StreamLink> link) {
      connected.push_back(link);
      link->start(inbox.on_message(), outbox.source(), inbox.on_closed());
    });
    return c;
  }
  void TearDown() override {
    boost::system::error_code ignored;
    acceptor.close(ignored);
    for (auto& link : served) link->close();
    for (auto& link : connected) link->close();
    TlsTest::TearDown();
  }

  std::vector<std::shared_ptr<StreamLink>> served, connected;
  Inbox inbox;
  Outbox outbox;
};

TEST_F(TlsClientTest, ConnectsOverTlsWithTheSurfaceAsAuthenticatedPeer) {
  auto surface = TlsUpgrade::create(surface_psk("gw1", {key}));
  asio::co_spawn(io, serve(surface), rethrow);
  auto c = client(TlsUpgrade::create(gateway_psk("gw1", {key})));
  ASSERT_TRUE(run_until(io, [&] { return !connected.empty() && !served.empty(); }));
  EXPECT_TRUE(connected[0]->is_tls());
  EXPECT_EQ(connected[0]->authenticated_peer(), "surface");
  EXPECT_EQ(served[0]->authenticated_peer(), "gw1");
  c->stop();
}

TEST_F(TlsClientTest, RefusedHandshakesBackOffAndRetryWithoutALink) {
  auto surface = TlsUpgrade::create(surface_psk("gw1", {key}));
  asio::co_spawn(io, serve(surface), rethrow);
  auto c = client(TlsUpgrade::create(gateway_psk("gw1", {other_key})));
  ASSERT_TRUE(run_until(io, [&] { return c->counters().connect_failures >= 3; }));
  EXPECT_TRUE(connected.empty());
  EXPECT_TRUE(served.empty());
  EXPECT_EQ(c->counters().connects, 0u);
  EXPECT_GE(surface->counters()[TlsFailure::unknown_identity], 3u);
  c->stop();
}

TEST_F(TlsClientTest, StopCancelsAHandshakeTheServerNeverAnswers) {
  // A listener that accepts and never speaks: the client's handshake waits for a ServerHello.
  std::vector<tcp::socket> silent;
  std::function<void()> accept_one = [&] {
    acceptor.async_accept([&](boost::system::error_code ec, tcp::socket socket) {
      if (ec) return;
      silent.push_back(std::move(socket));
      accept_one();
    });
  };
  accept_one();
  auto c = client(TlsUpgrade::create(gateway_psk("gw1", {key})));
  ASSERT_TRUE(run_until(io, [&] { return c->counters().attempts == 1 && !silent.empty(); }));
  for (int i = 0; i < 20; ++i) io.poll();
  c->stop();
  boost::system::error_code ignored;
  acceptor.close(ignored);
  for (auto& s : silent) s.close(ignored);
  EXPECT_TRUE(testing::drains_within(io, 1s));
  EXPECT_TRUE(connected.empty());
}

}  // namespace
}  // namespace canbridge::backbone
