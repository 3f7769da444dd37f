// hvdb-server against hostile and careless clients (docs/PROTOCOL.md, "Limits"): a real server
// process, raw sockets and WebSockets that do what a well-behaved client would not. Each test
// reproduces one finding of a probe of the server: memory per connection and per server,
// pings, token files, HTTP request smuggling and duplicate headers, connections that never say
// Hello, parameter ranges, and what the log shows.
#include <arpa/inet.h>
#include <fcntl.h>
#include <netinet/in.h>
#include <sys/socket.h>

#include <gtest/gtest.h>

#include <cerrno>
#include <chrono>
#include <cstring>
#include <fstream>
#include <iterator>
#include <random>
#include <thread>

#include <utility>  // before Asio: Boost 1.74's awaitable.hpp needs std::exchange

#include <boost/asio.hpp>
#include <boost/beast/core.hpp>
#include <boost/beast/http.hpp>
#include <boost/beast/websocket.hpp>

#include "client/client.h"
#include "server/web_checks.h"
#include "tests/server/frames.h"
#include "tests/server/query_util.h"
#include "tests/server/server_child.h"
#include "tests/server/server_process.h"
#include "tests/storage/test_util.h"

namespace hvdb {
namespace {

namespace asio = boost::asio;
namespace beast = boost::beast;
namespace http = beast::http;
namespace websocket = beast::websocket;
using testing::RandomPoints;
using testing::ServerChild;
using testing::ServerProcess;
using testing::TempDir;

constexpr double kFps = 10.0;
constexpr long kMiB = 1024;  // RSS is in KiB

// A blocking loopback TCP socket with a small receive buffer (a client that reads nothing
// holds little in its own kernel buffer, so what it asked for piles up in the server).
class Sock {
 public:
  explicit Sock(uint16_t port, int rcvbuf = 4096) {
    fd_ = ::socket(AF_INET, SOCK_STREAM, 0);
    ::setsockopt(fd_, SOL_SOCKET, SO_RCVBUF, &rcvbuf, sizeof(rcvbuf));
    sockaddr_in a{};
    a.sin_family = AF_INET;
    a.sin_port = htons(port);
    a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    connected_ = ::connect(fd_, reinterpret_cast<sockaddr*>(&a), sizeof(a)) == 0;
    timeval tv{5, 0};
    ::setsockopt(fd_, SOL_SOCKET, SO_RCVTIMEO, &tv, sizeof(tv));
    ::setsockopt(fd_, SOL_SOCKET, SO_SNDTIMEO, &tv, sizeof(tv));
  }
  ~Sock() { ::close(fd_); }
  Sock(const Sock&) = delete;
  Sock& operator=(const Sock&) = delete;
  bool connected() const { return connected_; }
  // Bytes written within the send timeout (less than all when the server stopped reading).
  size_t Write(const std::string& s) {
    size_t done = 0;
    while (done < s.size()) {
      ssize_t n = ::send(fd_, s.data() + done, s.size() - done, MSG_NOSIGNAL);
      if (n <= 0) break;
      done += static_cast<size_t>(n);
    }
    return done;
  }
  void ReceiveTimeout(int ms) {
    timeval tv{ms / 1000, (ms % 1000) * 1000};
    ::setsockopt(fd_, SOL_SOCKET, SO_RCVTIMEO, &tv, sizeof(tv));
  }
  void SendTimeout(int ms) {
    timeval tv{ms / 1000, (ms % 1000) * 1000};
    ::setsockopt(fd_, SOL_SOCKET, SO_SNDTIMEO, &tv, sizeof(tv));
  }
  // Everything until the server closes (or 5 s pass without a byte); closed() tells which.
  std::string ReadAll() {
    std::string buf;
    char tmp[65536];
    for (;;) {
      ssize_t n = ::recv(fd_, tmp, sizeof(tmp), 0);
      if (n <= 0) {
        // A reset counts: the server closed with requests of ours still unread.
        closed_ = n == 0 || errno == ECONNRESET;
        break;
      }
      buf.append(tmp, static_cast<size_t>(n));
    }
    return buf;
  }
  bool closed() const { return closed_; }
  // The Response frames until the server closes; the first frame (the HelloReply) left out
  // when `after_hello`.
  std::vector<wire::Response> Responses(bool after_hello) {
    std::vector<std::string> frames = testing::FramePayloads(ReadAll());
    std::vector<wire::Response> out;
    for (size_t i = after_hello ? 1 : 0; i < frames.size(); ++i) {
      wire::Response r;
      EXPECT_TRUE(r.ParseFromString(frames[i]));
      out.push_back(r);
    }
    return out;
  }
  int fd() const { return fd_; }

 private:
  int fd_;
  bool connected_ = false;
  bool closed_ = false;
};

std::string HelloFrame(const std::string& token = "") {
  wire::Hello h;
  h.set_protocol_version(wire::kProtocolVersion);
  h.set_token(token);
  return wire::Frame(h);
}

// A query for everything in the dataset.
wire::Request WholeQuery(uint64_t id, const std::string& ds, wire::PointEncoding enc) {
  wire::Request q;
  q.set_id(id);
  q.mutable_query()->set_dataset(ds);
  q.mutable_query()->set_encoding(enc);
  auto* w = q.mutable_query()->mutable_region()->mutable_window();
  for (int i = 0; i < 4; ++i) {
    w->add_lo(-1e30);
    w->add_hi(1e30);
  }
  return q;
}

std::unique_ptr<client::Connection> Connect(uint16_t port, const std::string& token = "") {
  client::Options o;
  o.port = port;
  o.token = token;
  o.prefer_local = false;  // one connection each, where it was opened
  o.request_timeout = std::chrono::milliseconds(30000);
  auto c = client::Connection::Connect(o);
  EXPECT_TRUE(c.ok()) << c.status().ToString();
  return c.ok() ? std::move(c).value() : nullptr;
}

size_t Count(const std::string& s, const std::string& what) {
  size_t n = 0;
  for (size_t at = s.find(what); at != std::string::npos; at = s.find(what, at + 1)) ++n;
  return n;
}

// The dataset `d`: `frames` frames of 100 000 random points.
void LoadDataset(client::Connection& c, uint32_t frames, uint64_t seed) {
  DatasetInfo info;
  info.name = "d";
  info.fps = kFps;
  ASSERT_TRUE(c.CreateDataset(info).ok());
  std::mt19937_64 rng(seed);
  for (uint32_t f = 0; f < frames; ++f) ASSERT_TRUE(c.Ingest("d", f, RandomPoints(rng, 100000, f)).ok());
}

// A server with a dataset `d` of 8 frames x 100 000 points (51 MB of records; each whole query
// makes ~50 batches).
class HardeningTest : public ::testing::Test {
 protected:
  void Start(std::vector<std::string> extra = {}) {
    data_ = dir_.path() + "/data";
    extra.insert(extra.end(), {"--http", "127.0.0.1:0"});
    server_ = std::make_unique<ServerProcess>(data_, extra);
    ASSERT_TRUE(server_->running()) << "hvdb-server did not start";
  }
  void Load() {
    auto c = Connect(server_->port());
    ASSERT_TRUE(c);
    LoadDataset(*c, 8, 37);
  }
  // RSS once it has stopped growing (the server makes batches for a while after the sends).
  long SettledRss() {
    long last = server_->RssKib();
    for (int i = 0; i < 20; ++i) {
      std::this_thread::sleep_for(std::chrono::milliseconds(250));
      long now = server_->RssKib();
      if (now - last < 512) return now;
      last = now;
    }
    return last;
  }
  TempDir dir_;
  std::string data_;
  std::unique_ptr<ServerProcess> server_;
};

// ---- Finding 1: memory per connection, whatever the transport, encoding or pipelining ----

// A WebSocket client that asks and never reads.
class WsSink {
 public:
  bool Open(uint16_t port) {
    beast::error_code ec;
    ws_.next_layer().connect({asio::ip::address_v4::loopback(), port}, ec);
    if (ec) return false;
    int rcv = 4096;
    ::setsockopt(ws_.next_layer().native_handle(), SOL_SOCKET, SO_RCVBUF, &rcv, sizeof(rcv));
    ws_.handshake("127.0.0.1:" + std::to_string(port), "/ws", ec);
    if (ec) return false;
    ws_.text(true);
    ws_.write(asio::buffer(std::string(R"({"protocol_version": 2, "client_name": "sink"})")), ec);
    beast::flat_buffer b;
    ws_.read(b, ec);  // the HelloReply
    return !ec;
  }
  void Send(const std::string& text) {
    beast::error_code ec;
    ws_.write(asio::buffer(text), ec);
  }

 private:
  asio::io_context io_;
  websocket::stream<asio::ip::tcp::socket> ws_{io_};
};

std::string WsWholeQuery(int id) {
  return "{\"id\":" + std::to_string(id) +
         R"(,"query":{"dataset":"d","region":{"window":{"lo":[-1e30,-1e30,-1e30,-1e30],)"
         R"("hi":[1e30,1e30,1e30,1e30]}},"lod":0,"encoding":"COLUMNS"}})";
}

TEST_F(HardeningTest, PipelinedQueriesOfClientsThatDoNotReadHoldABoundedBuffer) {
  Start();
  Load();
  const long before = SettledRss();
  // 20 WebSocket clients and 10 TCP clients (RECORDS), 32 whole-dataset queries each, never
  // reading. Before the fix every query got its first two batches at once: ~60 MiB a client.
  std::vector<std::unique_ptr<WsSink>> ws;
  for (int i = 0; i < 20; ++i) {
    ws.push_back(std::make_unique<WsSink>());
    ASSERT_TRUE(ws.back()->Open(server_->http_port()));
    for (int q = 1; q <= 32; ++q) ws.back()->Send(WsWholeQuery(q));
  }
  std::vector<std::unique_ptr<Sock>> tcp;
  for (int i = 0; i < 10; ++i) {
    tcp.push_back(std::make_unique<Sock>(server_->port()));
    ASSERT_TRUE(tcp.back()->connected());
    std::string bytes = HelloFrame();
    for (int q = 1; q <= 32; ++q) bytes += wire::Frame(WholeQuery(q, "d", wire::RECORDS));
    tcp.back()->Write(bytes);
  }
  const long during = SettledRss();
  std::printf("30 non-reading clients: RSS %+ld KiB\n", during - before);
  // Others are served meanwhile.
  auto c = Connect(server_->port());
  ASSERT_TRUE(c);
  EXPECT_TRUE(c->Ping().ok());
  // 30 connections x at most 8 MiB (docs/PROTOCOL.md), and a margin for the allocator.
  EXPECT_LT(during - before, 30 * 10 * kMiB) << "before " << before << " KiB, during " << during;
  // Their memory goes back to the OS when they close.
  ws.clear();
  tcp.clear();
  std::this_thread::sleep_for(std::chrono::seconds(2));
  const long after = SettledRss();
  std::printf("after they closed: RSS %+ld KiB\n", after - before);
  EXPECT_LT(after - before, 48 * kMiB) << "before " << before << " KiB, after " << after;
}

TEST_F(HardeningTest, TheServerWideBudgetHoldsWithManyConnections) {
  // 40 connections of 6-8 MiB each would be ~300 MiB; the budget keeps them near 32 MiB (plus
  // one batch for each connection that holds nothing, so that none is starved).
  Start({"--memory-budget", "32"});
  Load();
  const long before = SettledRss();
  std::vector<std::unique_ptr<Sock>> tcp;
  for (int i = 0; i < 40; ++i) {
    tcp.push_back(std::make_unique<Sock>(server_->port()));
    std::string bytes = HelloFrame();
    for (int q = 1; q <= 32; ++q) {
      bytes += wire::Frame(WholeQuery(q, "d", q % 2 ? wire::RECORDS : wire::COLUMNS));
    }
    tcp.back()->Write(bytes);
  }
  const long during = SettledRss();
  std::printf("40 non-reading clients, --memory-budget 32: RSS %+ld KiB\n", during - before);
  EXPECT_LT(during - before, (32 + 40 * 1 + 48) * kMiB)
      << "before " << before << " KiB, during " << during;
  // A client that reads is still served in full.
  auto c = Connect(server_->port());
  ASSERT_TRUE(c);
  EXPECT_EQ(testing::All(*c, "d", testing::FrameWindow(2, kFps)).size(), 100000u);
}

TEST(HardeningBudget, ClientsThatHoldTheBudgetWithoutReadingAreClosed) {
  // 20 non-readers hold more than the 16 MiB budget: after 5 s without reading a byte they are
  // closed until the server is under its budget again; a client that reads is never closed.
  TempDir dir;
  ServerChild server("b", {"--data", dir.path() + "/data", "--memory-budget", "16"}, dir.path());
  ASSERT_EQ(server.Start(), "");
  const uint16_t port = static_cast<uint16_t>(std::stoi(server.Address().substr(10)));
  auto c = Connect(port);
  ASSERT_TRUE(c);
  LoadDataset(*c, 4, 38);
  std::vector<std::unique_ptr<Sock>> tcp;
  for (int i = 0; i < 20; ++i) {
    tcp.push_back(std::make_unique<Sock>(port));
    std::string bytes = HelloFrame();
    for (int q = 1; q <= 8; ++q) bytes += wire::Frame(WholeQuery(q, "d", wire::COLUMNS));
    tcp.back()->Write(bytes);
  }
  for (int i = 0; i < 4; ++i) {
    EXPECT_EQ(testing::All(*c, "d", testing::FrameWindow(static_cast<uint32_t>(i), kFps)).size(),
              100000u);
    std::this_thread::sleep_for(std::chrono::seconds(2));
  }
  EXPECT_TRUE(c->Ping().ok());
  const std::string log = server.Log();
  const size_t closed = static_cast<size_t>(Count(log, "while the server's memory budget is crowded"));
  std::printf("%zu of 20 stalled clients closed\n", closed);
  EXPECT_GE(closed, 1u) << log;
}

TEST_F(HardeningTest, ClientsThatCloseMidQueryLeaveNothingInTheBudget) {
  // Each connection that closes while a task of its query is under way must give back what it
  // was counted for: 40 such closes would otherwise leave a 16 MiB budget full for good, and
  // every later query would wait forever.
  Start({"--memory-budget", "16"});
  Load();
  for (int i = 0; i < 40; ++i) {
    auto c = Connect(server_->port());
    ASSERT_TRUE(c);
    auto q = c->Query("d", testing::EverythingWindow(), {});
    ASSERT_TRUE(q.ok());
    Batch b;
    ASSERT_TRUE((*q)->Next(&b).ok());
  }  // the connection closes with the query streaming
  // And 100 that ask and hang up at once, while their next batches are being made.
  for (int i = 0; i < 100; ++i) {
    Sock s(server_->port(), 1 << 16);
    s.Write(HelloFrame() + wire::Frame(WholeQuery(1, "d", wire::RECORDS)));
    std::this_thread::sleep_for(std::chrono::milliseconds(i % 7));
  }
  auto watcher = Connect(server_->port());
  ASSERT_TRUE(watcher);
  uint64_t buffered = 0;
  EXPECT_TRUE(testing::WaitUntil(std::chrono::milliseconds(5000), [&] {
    auto st = watcher->Stats();
    buffered = st.ok() ? st->buffered_bytes() : ~0ull;
    return buffered == 0;
  })) << buffered << " bytes still counted with no client holding results";
  client::Options o;
  o.port = server_->port();
  o.prefer_local = false;
  o.request_timeout = std::chrono::milliseconds(10000);
  auto c = client::Connection::Connect(o);
  ASSERT_TRUE(c.ok());
  for (uint32_t f = 0; f < 3; ++f) {
    EXPECT_EQ(testing::All(**c, "d", testing::FrameWindow(f, kFps)).size(), 100000u);
  }
}

TEST_F(HardeningTest, ConnectionsBeforeTheirHelloCannotAnnounceLargeFrames) {
  Start();
  const long before = SettledRss();
  // 64 connections announcing 16 MiB first frames: refused at the header, nothing allocated.
  std::vector<std::unique_ptr<Sock>> socks;
  for (int i = 0; i < 64; ++i) {
    socks.push_back(std::make_unique<Sock>(server_->port()));
    std::string header(4, '\0');
    const uint32_t len = 16u << 20;
    std::memcpy(header.data(), &len, 4);
    socks.back()->Write(header + "x");
  }
  const long during = SettledRss();
  std::printf("64 large first frames: RSS %+ld KiB\n", during - before);
  EXPECT_LT(during - before, 32 * kMiB);
  auto r = socks.front()->Responses(false);
  ASSERT_FALSE(r.empty());
  EXPECT_EQ(r[0].error().code(), wire::MALFORMED);
}

// ---- Finding 2: pings are flow-controlled like everything else ----

TEST_F(HardeningTest, PingPayloadsOverTheLimitAreRefused) {
  Start();
  // 8 MiB payloads are refused (at most 64 KiB is echoed) and the connection stays usable.
  Sock s(server_->port(), 1 << 20);
  wire::Request big;
  big.set_id(1);
  big.mutable_ping()->set_payload(std::string(8u << 20, 'p'));
  wire::Request small;
  small.set_id(2);
  small.mutable_ping()->set_payload("ok");
  s.Write(HelloFrame() + wire::Frame(big) + wire::Frame(small));
  ::shutdown(s.fd(), SHUT_WR);
  auto r = s.Responses(true);
  ASSERT_EQ(r.size(), 2u);
  EXPECT_EQ(r[0].error().code(), wire::INVALID_PARAMETER) << r[0].DebugString();
  EXPECT_EQ(r[1].pong().payload(), "ok");
}

TEST_F(HardeningTest, PingsOfAClientThatDoesNotReadDoNotGrowTheServer) {
  Start();
  const long before = SettledRss();
  // 64 KiB pings, 64 MiB of them, never read: the server stops reading once its buffer for
  // the connection is full, so the sender blocks and the server does not grow.
  Sock flood(server_->port());
  flood.SendTimeout(1000);
  std::string bytes = HelloFrame();
  for (int i = 0; i < 1024; ++i) {
    wire::Request p;
    p.set_id(static_cast<uint64_t>(i + 1));
    p.mutable_ping()->set_payload(std::string(64u << 10, 'x'));
    bytes += wire::Frame(p);
  }
  const size_t sent = flood.Write(bytes);
  std::printf("ping flood: %zu of %zu bytes taken\n", sent, bytes.size());
  EXPECT_LT(sent, bytes.size() / 2) << "the server read all the pings of a client that reads nothing";
  const long during = SettledRss();
  std::printf("ping flood: RSS %+ld KiB\n", during - before);
  EXPECT_LT(during - before, 24 * kMiB) << "before " << before << " KiB, during " << during;
}

// ---- Finding 3: token files that grant nothing, or grant twice ----

TEST(HardeningStart, TokenFilesWithoutTokensOrWithDuplicatesAreRefused) {
  TempDir dir;
  auto write = [&](const std::string& name, const std::string& text) {
    std::ofstream(dir.path() + "/" + name) << text;
    return dir.path() + "/" + name;
  };
  const std::string empty = write("empty", "");
  const std::string comments = write("comments", "# nobody\n\n   # still nobody\n");
  const std::string dup = write("dup", "aaaaaaaaaaaaaaaaaaaa ro\nbbbbbbbbbbbbbbbbbbbb rw\n"
                                       "aaaaaaaaaaaaaaaaaaaa rw\n");
  ::mkdir((dir.path() + "/folder").c_str(), 0755);
  for (const std::string& file : {empty, comments, std::string("/dev/null"), dir.path() + "/folder"}) {
    SCOPED_TRACE(file);
    ServerChild s("t", {"--data", dir.path() + "/data", "--token-file", file}, dir.path());
    const std::string why = s.Start();
    EXPECT_NE(why.find(file), std::string::npos) << "started, or did not name the file: " << why;
  }
  ServerChild d("d", {"--data", dir.path() + "/data", "--token-file", dup}, dir.path());
  const std::string why = d.Start();
  EXPECT_NE(why.find("line 3"), std::string::npos) << why;
  EXPECT_NE(why.find("line 1"), std::string::npos) << why;
}

TEST(HardeningStart, FailedTokenAttemptsAreLoggedWithoutTheToken) {
  TempDir dir;
  const std::string tokens = dir.path() + "/tokens";
  std::ofstream(tokens) << "good-token-0123456789 rw\n";
  ServerChild s("t", {"--data", dir.path() + "/data", "--token-file", tokens}, dir.path());
  ASSERT_EQ(s.Start(), "");
  const uint16_t port = static_cast<uint16_t>(std::stoi(s.Address().substr(10)));
  {
    Sock bad(port);
    bad.Write(HelloFrame("guessed-token-abcdefgh"));
    auto r = bad.Responses(false);
    ASSERT_FALSE(r.empty());
    EXPECT_EQ(r[0].error().code(), wire::PERMISSION_DENIED);
  }
  EXPECT_TRUE(testing::WaitUntil(std::chrono::milliseconds(3000), [&] {
    return s.Log().find("missing or unknown token") != std::string::npos;
  })) << s.Log();
  EXPECT_EQ(s.Log().find("guessed-token"), std::string::npos) << "the log shows the token";
  EXPECT_TRUE(Connect(port, "good-token-0123456789"));
}

// ---- Finding 4: HTTP request smuggling and duplicate headers ----

std::string HttpExchange(uint16_t port, const std::string& request) {
  Sock s(port);
  s.Write(request);
  ::shutdown(s.fd(), SHUT_WR);
  return s.ReadAll();
}

TEST_F(HardeningTest, TransferEncodingsAreRefusedAndTheBodyIsNotTakenForARequest) {
  Start();
  for (const char* te : {"chunked, identity", "gzip", "xchunked", "identity", "chunked"}) {
    SCOPED_TRACE(te);
    // The "body" is a second request: a server that ignored the coding would answer it too.
    const std::string smuggled = "GET /index.html HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n";
    const std::string body = std::string(te) == "chunked" ? "0\r\n\r\n" + smuggled : smuggled;
    std::string out = HttpExchange(server_->http_port(),
                                   std::string("POST / HTTP/1.1\r\nHost: 127.0.0.1\r\n") +
                                       "Transfer-Encoding: " + te + "\r\n\r\n" + body);
    EXPECT_EQ(Count(out, "HTTP/1.1 "), 1u) << out;
    EXPECT_EQ(out.rfind("HTTP/1.1 400", 0), 0u) << out;
  }
}

TEST_F(HardeningTest, DuplicateHostOrOriginHeadersAreRefused) {
  Start();
  std::string out = HttpExchange(server_->http_port(),
                                 "GET / HTTP/1.1\r\nHost: 127.0.0.1\r\nHost: evil.example\r\n\r\n");
  EXPECT_EQ(out.rfind("HTTP/1.1 400", 0), 0u) << out;
  out = HttpExchange(server_->http_port(),
                     "GET /ws HTTP/1.1\r\nHost: 127.0.0.1\r\nOrigin: http://127.0.0.1\r\n"
                     "Origin: http://evil.example\r\nConnection: Upgrade\r\nUpgrade: websocket\r\n"
                     "Sec-WebSocket-Version: 13\r\nSec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\n\r\n");
  EXPECT_EQ(out.rfind("HTTP/1.1 400", 0), 0u) << out;
  // One Host still works.
  out = HttpExchange(server_->http_port(), "GET / HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n");
  EXPECT_EQ(out.rfind("HTTP/1.1 200", 0), 0u) << out;
}

TEST(HttpHeadCheck, RulesInOrder) {
  auto head = [](const std::string& text) {
    http::request_parser<http::string_body> p;
    p.eager(true);
    beast::error_code ec;
    p.put(asio::buffer(text), ec);
    EXPECT_FALSE(ec) << ec.message();
    return p.release();
  };
  auto v = server::CheckRequestHead(head("GET / HTTP/1.1\r\nHost: 127.0.0.1:8080\r\n\r\n"), {});
  EXPECT_EQ(v.kind, server::HttpVerdict::kServeFile);
  EXPECT_EQ(v.file, "index.html");
  v = server::CheckRequestHead(
      head("GET / HTTP/1.1\r\nHost: 127.0.0.1\r\nTransfer-Encoding: gzip\r\n\r\n"), {});
  EXPECT_EQ(v.kind, server::HttpVerdict::kRefuse);
  EXPECT_EQ(v.status, 400);
  EXPECT_TRUE(v.close);
  v = server::CheckRequestHead(head("GET / HTTP/1.1\r\n\r\n"), {});
  EXPECT_EQ(v.status, 400);  // no Host
  // A refused host is logged escaped and cut.
  v = server::CheckRequestHead(
      head("GET / HTTP/1.1\r\nHost: " + std::string(5000, 'h') + "\xff.example\r\n\r\n"), {});
  EXPECT_EQ(v.status, 403);
  EXPECT_LT(v.log.size(), 300u) << v.log;
  EXPECT_NE(v.log.find("(5009 bytes)"), std::string::npos) << v.log;
}

TEST(Printable, EscapesAndCuts) {
  EXPECT_EQ(server::Printable("plain"), "plain");
  EXPECT_EQ(server::Printable(std::string("a\x01\xff\\b", 5)), "a\\x01\\xff\\x5cb");
  EXPECT_EQ(server::Printable("abcdef", 3), "abc... (6 bytes)");
}

// ---- Finding 5: connections that never say Hello ----

TEST_F(HardeningTest, SilentConnectionsDoNotKeepOthersOut) {
  Start();
  // More silent sockets than --max-connections (256), on both ports.
  std::vector<std::unique_ptr<Sock>> squatters;
  for (int i = 0; i < 270; ++i) {
    squatters.push_back(std::make_unique<Sock>(server_->port()));
    squatters.push_back(std::make_unique<Sock>(server_->http_port()));
  }
  std::this_thread::sleep_for(std::chrono::milliseconds(200));
  auto start = std::chrono::steady_clock::now();
  auto c = Connect(server_->port());
  ASSERT_TRUE(c);
  EXPECT_TRUE(c->Ping().ok());
  EXPECT_LT(std::chrono::steady_clock::now() - start, std::chrono::seconds(2));
  std::string page = HttpExchange(server_->http_port(), "GET / HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n");
  EXPECT_EQ(page.rfind("HTTP/1.1 200", 0), 0u) << page.substr(0, 200);
}

TEST_F(HardeningTest, AuthenticatedConnectionsAreLimited) {
  Start({"--max-connections", "3"});
  std::vector<std::unique_ptr<client::Connection>> in;
  for (int i = 0; i < 3; ++i) in.push_back(Connect(server_->port()));
  for (auto& c : in) ASSERT_TRUE(c);
  Sock fourth(server_->port());
  fourth.Write(HelloFrame());
  auto r = fourth.Responses(false);
  ASSERT_FALSE(r.empty());
  EXPECT_EQ(r[0].error().code(), wire::OVERLOADED) << r[0].DebugString();
  in.pop_back();
  EXPECT_TRUE(testing::WaitUntil(std::chrono::milliseconds(3000), [&] {
    client::Options o;
    o.port = server_->port();
    o.prefer_local = false;
    return client::Connection::Connect(o).ok();
  }));
}

// ---- Findings 7: parameter ranges, and an empty request closes the connection ----

TEST_F(HardeningTest, DatasetParametersOutOfRangeAreRefused) {
  Start();
  auto c = Connect(server_->port());
  ASSERT_TRUE(c);
  DatasetInfo info;
  info.name = "frames";
  info.fps = kFps;
  info.frame_count = 4294967295u;
  auto r = c->CreateDataset(info);
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.status().ToString().find("frame count"), std::string::npos) << r.status().ToString();
  info.name = "slow";
  info.frame_count = 0;
  info.fps = 1e-300;
  r = c->CreateDataset(info);
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.status().ToString().find("fps"), std::string::npos) << r.status().ToString();
  info.fps = kFps;
  info.frame_count = 99'999'999;
  EXPECT_TRUE(c->CreateDataset(info).ok());
  auto list = c->ListDatasets();
  ASSERT_TRUE(list.ok());
  EXPECT_EQ(*list, std::vector<std::string>{"slow"});
}

TEST_F(HardeningTest, AnEmptyRequestIsMalformedAndClosesTheConnection) {
  Start();
  Sock s(server_->port());
  wire::Request empty;
  empty.set_id(3);
  s.Write(HelloFrame() + wire::Frame(empty));
  auto r = s.Responses(true);  // until the server closes (this side still could write)
  EXPECT_TRUE(s.closed()) << "the connection stayed open after MALFORMED";
  ASSERT_EQ(r.size(), 1u);
  EXPECT_EQ(r[0].error().code(), wire::MALFORMED);
}

}  // namespace
}  // namespace hvdb
