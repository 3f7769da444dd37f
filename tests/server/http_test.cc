// The HTTP front end and the WebSocket transport (docs/PROTOCOL.md, "HTTP and WebSocket"): a
// real hvdb-server process with --http, driven by Beast's HTTP and WebSocket clients; and the
// pure parts (paths, origins, the message codec) directly.
#include <sys/socket.h>

#include <gtest/gtest.h>

#include <array>
#include <cstring>
#include <fstream>
#include <random>
#include <set>
#include <thread>

#include <utility>  // before Asio: Boost 1.74's awaitable.hpp needs std::exchange

#include <boost/asio.hpp>
#include <boost/beast/core.hpp>
#include <boost/beast/http.hpp>
#include <boost/beast/websocket.hpp>
#include <nlohmann/json.hpp>

#include "client/client.h"
#include "protocol/ws_codec.h"
#include "server/http.h"
#include "tests/server/server_process.h"
#include "tests/server/ws_client.h"
#include "tests/storage/test_util.h"

namespace hvdb {
namespace {

namespace asio = boost::asio;
namespace beast = boost::beast;
namespace http = beast::http;
namespace websocket = beast::websocket;
using asio::ip::tcp;
using nlohmann::json;
using testing::RandomPoints;
using testing::ServerProcess;
using testing::TempDir;

constexpr double kFps = 10.0;

// ---- The pure parts ----

TEST(WebPath, PlainPathsOnly) {
  EXPECT_EQ(server::WebPath("/"), "index.html");
  EXPECT_EQ(server::WebPath("/?dataset=x&t=1"), "index.html");
  EXPECT_EQ(server::WebPath("/src/main.js"), "src/main.js");
  EXPECT_EQ(server::WebPath("//src//main.js#x"), "src/main.js");
  EXPECT_EQ(server::WebPath("/a%20b.js"), "a b.js");
  EXPECT_EQ(server::WebPath("/src/"), "src/index.html");
  for (const char* bad : {"", "src/main.js", "/../etc/passwd", "/src/../../x", "/%2e%2e/x",
                          "/.git/config", "/a/.hidden", "/a%5cb", "/a%00b", "/a%zz", "/a%4"}) {
    EXPECT_EQ(server::WebPath(bad), "") << bad;
  }
}

TEST(OriginAllowed, SameOriginOrListed) {
  EXPECT_TRUE(server::OriginAllowed("", "127.0.0.1:8080", {}));  // not a browser
  EXPECT_TRUE(server::OriginAllowed("http://127.0.0.1:8080", "127.0.0.1:8080", {}));
  EXPECT_TRUE(server::OriginAllowed("http://Example.org", "example.org", {}));
  EXPECT_FALSE(server::OriginAllowed("http://evil.example:8080", "127.0.0.1:8080", {}));
  EXPECT_FALSE(server::OriginAllowed("null", "127.0.0.1:8080", {}));
  EXPECT_FALSE(server::OriginAllowed("http://127.0.0.1:8081", "127.0.0.1:8080", {}));
  EXPECT_TRUE(server::OriginAllowed("http://viewer.example:3000", "127.0.0.1:8080",
                                    {"http://viewer.example:3000"}));
  EXPECT_TRUE(server::OriginAllowed("https://viewer.example", "127.0.0.1:8080",
                                    {"https://viewer.example:443"}));
}

TEST(HostAllowed, AddressesLocalhostOrListedNames) {
  EXPECT_TRUE(server::HostAllowed("127.0.0.1:8080", {}));
  EXPECT_TRUE(server::HostAllowed("localhost:8080", {}));
  EXPECT_TRUE(server::HostAllowed("[::1]:8080", {}));
  EXPECT_TRUE(server::HostAllowed("192.168.1.7", {}));
  // A name could have been re-pointed at this address by a site's owner (DNS rebinding).
  EXPECT_FALSE(server::HostAllowed("evil.example:8080", {}));
  EXPECT_FALSE(server::HostAllowed("", {}));
  EXPECT_FALSE(server::HostAllowed("[::1", {}));
  EXPECT_TRUE(server::HostAllowed("viewer.example:8080", {"http://viewer.example:3000"}));
}

TEST(WsCodec, DecodesJsonAndProtobufRequests) {
  wire::Request r;
  ASSERT_TRUE(wire::DecodeWsMessage(
                  true, R"({"id": "7", "query": {"dataset": "d", "lod": 2, "encoding": "COLUMNS"}})", &r)
                  .ok());
  EXPECT_EQ(r.id(), 7u);
  EXPECT_EQ(r.query().lod(), 2u);
  // lowerCamelCase names, numbers for 64-bit integers.
  ASSERT_TRUE(wire::DecodeWsMessage(true, R"({"id": 8, "graphCut": {"outBit": 3}})", &r).ok());
  EXPECT_EQ(r.graph_cut().out_bit(), 3u);
  std::string bin;
  r.SerializeToString(&bin);
  wire::Request back;
  ASSERT_TRUE(wire::DecodeWsMessage(false, bin, &back).ok());
  EXPECT_EQ(back.graph_cut().out_bit(), 3u);
  for (const char* bad : {R"({"id": 1, "qurey": {}})", "[1,2]", "{", R"({"id": -1})",
                          R"({"id": 1, "query": {"encoding": "NOPE"}})"}) {
    Status st = wire::DecodeWsMessage(true, bad, &r);
    EXPECT_TRUE(st.IsInvalidArgument()) << bad;
  }
  EXPECT_FALSE(wire::DecodeWsMessage(false, std::string("\xff\xff\xff", 3), &r).ok());
}

TEST(WsCodec, BulkBytesBecomeAlignedSections) {
  std::mt19937_64 rng(5);
  for (size_t n : {size_t{1}, size_t{3}, size_t{1000}}) {
    auto pts = RandomPoints(rng, n, 2);
    wire::Response r;
    r.set_id(42);
    r.mutable_batch()->set_splat_scale(2);
    wire::EncodeColumns(pts, r.mutable_batch()->mutable_columns());
    wire::WsMessage m = wire::EncodeWsMessage(r);
    ASSERT_FALSE(m.text);
    ASSERT_EQ(m.head.size() % 8, 0u);
    uint32_t j;
    std::memcpy(&j, m.head.data(), 4);
    json h = json::parse(m.head.substr(4, j));
    EXPECT_EQ(h["response"]["id"], "42");
    EXPECT_EQ(h["response"]["batch"]["columns"]["count"], n);
    EXPECT_EQ(h["response"]["batch"]["columns"]["position"], "");
    const std::string whole = m.head + m.tail;
    const wire::PointColumns& c = r.batch().columns();
    std::map<std::string, const std::string*> want = {
        {"id", &c.id()},       {"position", &c.position()}, {"frame", &c.frame()},
        {"color", &c.color()}, {"covariance", &c.covariance()}, {"normal", &c.normal()},
        {"label", &c.label()}, {"camera", &c.camera()},     {"flags", &c.flags()}};
    ASSERT_EQ(h["payload"].size(), want.size());
    for (const auto& s : h["payload"]) {
      size_t off = s["offset"], len = s["length"];
      EXPECT_EQ(off % 8, 0u);
      ASSERT_LE(off + len, whole.size());
      EXPECT_EQ(whole.substr(off, len), *want.at(s["field"].get<std::string>()));
    }
    EXPECT_EQ(whole.size() % 8, 0u);
  }
  // Records go between the header and the tail, as the transport sends them.
  wire::Response rec;
  rec.mutable_batch()->set_encoding(wire::RECORDS);
  rec.mutable_batch()->set_record_count(3);
  wire::WsMessage m = wire::EncodeWsMessage(rec, 3 * 64);
  uint32_t j;
  std::memcpy(&j, m.head.data(), 4);
  json h = json::parse(m.head.substr(4, j));
  EXPECT_EQ(h["payload"][0]["field"], "records");
  EXPECT_EQ(h["payload"][0]["offset"], m.head.size());
  // Everything else is one JSON text message.
  wire::Response pong;
  pong.set_id(1);
  pong.mutable_pong();
  EXPECT_TRUE(wire::EncodeWsMessage(pong).text);
}

// ---- Against a server ----

class HttpServerTest : public ::testing::Test {
 protected:
  void Start(std::vector<std::string> extra = {}) {
    root_ = dir_.path() + "/web";
    std::filesystem::create_directories(root_ + "/src");
    std::filesystem::create_directories(root_ + "/node_modules/gl-matrix");
    std::ofstream(root_ + "/index.html") << "<!doctype html><title>hvdb</title>";
    std::ofstream(root_ + "/src/main.js") << "export const x = 1;";
    std::filesystem::create_directories(root_ + "/wasm");
    std::ofstream(root_ + "/wasm/hvdb7.wasm") << std::string("\0asm", 4);
    std::ofstream(root_ + "/.secret") << "no";
    std::ofstream(dir_.path() + "/outside.txt") << "no";
    std::filesystem::create_symlink(dir_.path() + "/outside.txt", root_ + "/link.txt");
    std::vector<std::string> args = {"--http", "127.0.0.1:0", "--web-root", root_};
    args.insert(args.end(), extra.begin(), extra.end());
    server_ = std::make_unique<ServerProcess>(dir_.path() + "/data", args);
    ASSERT_TRUE(server_->running());
    ASSERT_NE(server_->http_port(), 0);
  }
  // One HTTP request on a new connection (a WebSocket upgrade from `origin` if one is given).
  http::response<http::string_body> Get(const std::string& target, http::verb verb = http::verb::get,
                                        const std::string& body = "", const std::string& origin = "",
                                        const std::string& host = "") {
    asio::io_context io;
    tcp::socket s(io);
    s.connect({asio::ip::address_v4::loopback(), server_->http_port()});
    http::request<http::string_body> req{verb, target, 11};
    req.set(http::field::host,
            host.empty() ? "127.0.0.1:" + std::to_string(server_->http_port()) : host);
    if (!body.empty()) {
      req.body() = body;
      req.prepare_payload();
    }
    if (!origin.empty()) {
      req.set(http::field::origin, origin);
      req.set(http::field::upgrade, "websocket");
      req.set(http::field::connection, "upgrade");
      req.set(http::field::sec_websocket_key, "dGhlIHNhbXBsZSBub25jZQ==");
      req.set(http::field::sec_websocket_version, "13");
    }
    http::write(s, req);
    beast::flat_buffer buf;
    http::response_parser<http::string_body> p;
    p.skip(verb == http::verb::head);
    http::read(s, buf, p);
    return p.release();
  }
  std::unique_ptr<client::Connection> Client() {
    client::Options o;
    o.port = server_->port();
    auto c = client::Connection::Connect(o);
    EXPECT_TRUE(c.ok()) << c.status().ToString();
    return std::move(c).value();
  }
  TempDir dir_;
  std::string root_;
  std::unique_ptr<ServerProcess> server_;
};

using testing::Ws;

TEST_F(HttpServerTest, ServesTheViewerFilesAndNothingElse) {
  Start();
  auto r = Get("/");
  EXPECT_EQ(r.result_int(), 200);
  EXPECT_EQ(r.body(), "<!doctype html><title>hvdb</title>");
  EXPECT_EQ(r[http::field::content_type], "text/html; charset=utf-8");
  EXPECT_NE(std::string(r["Content-Security-Policy"]).find("default-src 'self'"), std::string::npos);
  r = Get("/src/main.js?v=1");
  EXPECT_EQ(r.result_int(), 200);
  EXPECT_EQ(r[http::field::content_type], "text/javascript; charset=utf-8");
  EXPECT_EQ(Get("/src/main.js", http::verb::head)[http::field::content_length], "19");
  // The page's hvdb7 decoder: served as WebAssembly, and the policy lets the page compile it
  // (and only that: no 'unsafe-eval').
  r = Get("/wasm/hvdb7.wasm");
  EXPECT_EQ(r.result_int(), 200);
  EXPECT_EQ(r[http::field::content_type], "application/wasm");
  const std::string csp(Get("/")["Content-Security-Policy"]);
  EXPECT_NE(csp.find("script-src 'self' 'wasm-unsafe-eval'"), std::string::npos) << csp;
  EXPECT_EQ(csp.find("'unsafe-eval'"), std::string::npos) << csp;
  EXPECT_EQ(Get("/missing.js").result_int(), 404);
  EXPECT_EQ(Get("/../outside.txt").result_int(), 400);
  EXPECT_EQ(Get("/%2e%2e/outside.txt").result_int(), 400);
  EXPECT_EQ(Get("/.secret").result_int(), 400);
  EXPECT_EQ(Get("/link.txt").result_int(), 404);  // a symbolic link out of the root
  EXPECT_EQ(Get("/", http::verb::delete_).result_int(), 405);
  EXPECT_EQ(Get("/", http::verb::post, "x=1").result_int(), 413);
  EXPECT_EQ(Get("/ws").result_int(), 426);
  // DNS rebinding: a page of evil.example, its name now pointing here, is same-origin with
  // itself; the Host header gives it away.
  const std::string evil = "evil.example:" + std::to_string(server_->http_port());
  EXPECT_EQ(Get("/", http::verb::get, "", "", evil).result_int(), 403);
  EXPECT_EQ(Get("/ws", http::verb::get, "", "http://" + evil, evil).result_int(), 403);
  EXPECT_EQ(Get("/", http::verb::get, "", "", "localhost:1").result_int(), 200);
}

TEST_F(HttpServerTest, MalformedHttpGetsAnErrorAndTheServerGoesOn) {
  Start();
  for (const std::string& junk : {std::string("GARBAGE\r\n\r\n"),
                                  "GET / HTTP/1.1\r\nHost: x\r\nX: " + std::string(10000, 'a') + "\r\n\r\n",
                                  std::string("\x16\x03\x01\x02\x00\x01\x00", 7)}) {
    asio::io_context io;
    tcp::socket s(io);
    s.connect({asio::ip::address_v4::loopback(), server_->http_port()});
    asio::write(s, asio::buffer(junk));
    std::string reply(64, '\0');
    beast::error_code ec;
    size_t n = s.read_some(asio::buffer(reply), ec);
    EXPECT_EQ(reply.substr(0, 9), "HTTP/1.1 ") << junk.substr(0, 20) << " got " << n;
  }
  EXPECT_EQ(Get("/").result_int(), 200);
}

TEST_F(HttpServerTest, WebSocketSpeaksTheProtocol) {
  Start();
  auto c = Client();
  DatasetInfo info;
  info.name = "v";
  info.fps = kFps;
  ASSERT_TRUE(c->CreateDataset(info).ok());
  std::mt19937_64 rng(11);
  auto pts = RandomPoints(rng, 5000, 3);
  ASSERT_TRUE(c->Ingest("v", 3, pts).ok());

  Ws ws;
  ASSERT_EQ(ws.Open(server_->http_port()), 101u);
  json hello = ws.Hello();
  EXPECT_EQ(hello["protocol_version"], 2);
  EXPECT_EQ(hello["role"], "ROLE_READ_WRITE");
  ws.Text(R"({"id": 1, "describe": {"dataset": "v"}})");
  json d = ws.ReadJson();
  EXPECT_EQ(d["id"], "1");
  EXPECT_EQ(d["info"]["frame_count"], 4);
  // A binary (protobuf) request works the same.
  wire::Request list;
  list.set_id(2);
  list.mutable_list();
  std::string bin;
  list.SerializeToString(&bin);
  ws.Binary(bin);
  EXPECT_EQ(ws.ReadJson()["datasets"]["names"][0], "v");

  // The frame as columns, progressively: every point once, fields exactly as stored.
  const double t = 3 / kFps;
  ws.Text(json{{"id", 3},
               {"query", {{"dataset", "v"},
                          {"region", {{"window", {{"lo", {-1e30, -1e30, -1e30, t}},
                                                  {"hi", {1e30, 1e30, 1e30, t}}}}}},
                          {"progressive", true}}}}
              .dump());
  // Ingest assigns ids: points are known by their position.
  std::map<std::array<float, 3>, Point> want;
  for (const Point& p : pts) want[{p.x, p.y, p.z}] = p;
  std::set<uint64_t> seen;
  for (;;) {
    std::string msg;
    bool text = false;
    ASSERT_TRUE(ws.Read(&msg, &text));
    if (text) {
      json done = json::parse(msg);
      ASSERT_TRUE(done.contains("done")) << msg;
      EXPECT_EQ(done["done"]["points"], std::to_string(pts.size()));
      break;
    }
    uint32_t j;
    std::memcpy(&j, msg.data(), 4);
    json h = json::parse(msg.substr(4, j));
    const size_t n = h["response"]["batch"]["columns"]["count"];
    std::map<std::string, std::string> col;
    for (const auto& s : h["payload"]) {
      size_t off = s["offset"], len = s["length"];
      ASSERT_EQ(off % 8, 0u);
      col[s["field"]] = msg.substr(off, len);
    }
    ASSERT_EQ(col["position"].size(), 12 * n);
    for (size_t i = 0; i < n; ++i) {
      uint64_t id;
      float xyz[3];
      std::memcpy(&id, col["id"].data() + 8 * i, 8);
      std::memcpy(xyz, col["position"].data() + 12 * i, 12);
      auto it = want.find({xyz[0], xyz[1], xyz[2]});
      ASSERT_TRUE(it != want.end());
      EXPECT_TRUE(seen.insert(id).second);
      uint32_t label;
      std::memcpy(&label, col["label"].data() + 4 * i, 4);
      EXPECT_EQ(label, it->second.label);
      EXPECT_EQ(static_cast<uint8_t>(col["color"][3 * i + 1]), it->second.g);
    }
  }
  EXPECT_EQ(seen.size(), pts.size());

  // Errors are responses, the connection stays.
  ws.Text(R"({"id": 4, "describe": {"dataset": "nope"}})");
  EXPECT_EQ(ws.ReadJson()["error"]["code"], "UNKNOWN_DATASET");
  // A render comes as one binary message with its PNG as a section.
  ws.Text(json{{"id", 5},
               {"render", {{"dataset", "v"},
                           {"region", {{"window", {{"lo", {-1e30, -1e30, -1e30, t}},
                                                   {"hi", {1e30, 1e30, 1e30, t}}}}}},
                           {"renderer", "RENDERER_CPU"},
                           {"view", {{"look_at", {{"eye", {0, 0, -30}}, {"target", {0, 0, 0}},
                                                  {"up", {0, -1, 0}}, {"fov_y_deg", 40},
                                                  {"width", 64}, {"height", 48}}}}}}}}
              .dump());
  std::string msg;
  bool text = true;
  ASSERT_TRUE(ws.Read(&msg, &text));
  ASSERT_FALSE(text) << msg;
  uint32_t j;
  std::memcpy(&j, msg.data(), 4);
  json h = json::parse(msg.substr(4, j));
  EXPECT_EQ(h["response"]["render"]["width"], 64);
  ASSERT_EQ(h["payload"][0]["field"], "png");
  EXPECT_EQ(msg.substr(h["payload"][0]["offset"].get<size_t>() + 1, 3), "PNG");
}

TEST_F(HttpServerTest, BadMessagesCloseOnlyTheirConnection) {
  Start({"--max-frame-bytes", "4096"});
  Ws good;
  ASSERT_EQ(good.Open(server_->http_port()), 101u);
  good.Hello();
  struct Case {
    std::string msg;
    bool text;
    int close_code;
  };
  for (const Case& k : std::vector<Case>{{R"({"id": 1, "qurey": {}})", true, 1008},
                                         {"{not json", true, 1008},
                                         {std::string("\xff\xff\xff\x01", 4), false, 1008},
                                         {std::string(5000, 'x'), true, 1009}}) {
    Ws bad;
    ASSERT_EQ(bad.Open(server_->http_port()), 101u);
    bad.Hello();
    k.text ? bad.Text(k.msg) : bad.Binary(k.msg);
    std::string reply;
    bool text = false;
    if (k.close_code == 1008) {
      ASSERT_TRUE(bad.Read(&reply, &text));
      json e = json::parse(reply);
      EXPECT_EQ(e["id"], "0");
      EXPECT_EQ(e["error"]["code"], "MALFORMED");
    }
    EXPECT_FALSE(bad.Read(&reply, &text));
    EXPECT_EQ(bad.close_code(), k.close_code);
  }
  // A first message that is not a Hello.
  Ws nohello;
  ASSERT_EQ(nohello.Open(server_->http_port()), 101u);
  nohello.Text(R"({"id": 1, "list": {}})");
  EXPECT_EQ(nohello.ReadJson()["error"]["code"], "MALFORMED");
  good.Text(R"({"id": 9, "list": {}})");
  EXPECT_EQ(good.ReadJson()["id"], "9");
}

// Frames that break RFC 6455 itself (Beast's parser rejects them): the connection is failed,
// the server goes on.
TEST_F(HttpServerTest, BrokenWebSocketFramesCloseTheirConnection) {
  Start();
  const std::vector<std::string> frames = {
      std::string("\x81\x05hello", 7),                  // unmasked: clients must mask
      std::string("\x83\x80\x01\x02\x03\x04", 6),      // reserved opcode 3
      std::string("\xf1\x80\x01\x02\x03\x04", 6),      // RSV bits without an extension
      std::string("\x89\xfe\x01\x00\x01\x02\x03\x04", 8),  // a ping longer than 125 bytes
  };
  for (const std::string& raw : frames) {
    asio::io_context io;
    tcp::socket s(io);
    s.connect({asio::ip::address_v4::loopback(), server_->http_port()});
    const std::string upgrade =
        "GET /ws HTTP/1.1\r\nHost: 127.0.0.1\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
        "Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\nSec-WebSocket-Version: 13\r\n\r\n";
    asio::write(s, asio::buffer(upgrade));
    asio::streambuf head;
    asio::read_until(s, head, "\r\n\r\n");
    std::string status(asio::buffers_begin(head.data()), asio::buffers_begin(head.data()) + 12);
    ASSERT_EQ(status, "HTTP/1.1 101");
    asio::write(s, asio::buffer(raw));
    // The server fails the connection: a close frame (status 1002), then EOF; never a hang.
    s.non_blocking(false);
    struct timeval tv{5, 0};
    ::setsockopt(s.native_handle(), SOL_SOCKET, SO_RCVTIMEO, &tv, sizeof(tv));
    std::string rest;
    beast::error_code ec;
    char buf[256];
    for (;;) {
      size_t n = s.read_some(asio::buffer(buf), ec);
      if (ec) break;
      rest.append(buf, n);
    }
    EXPECT_TRUE(ec == asio::error::eof || ec == asio::error::connection_reset) << ec.message();
  }
  Ws good;
  ASSERT_EQ(good.Open(server_->http_port()), 101u);
  EXPECT_EQ(good.Hello()["protocol_version"], 2);
}

TEST_F(HttpServerTest, ForeignOriginsAreRefused) {
  Start({"--http-origin", "http://viewer.example:3000"});
  EXPECT_EQ(Get("/ws", http::verb::get, "", "http://evil.example").result_int(), 403);
  EXPECT_EQ(Get("/ws", http::verb::get, "", "null").result_int(), 403);
  Ws own;
  EXPECT_EQ(own.Open(server_->http_port(),
                     "http://127.0.0.1:" + std::to_string(server_->http_port())),
            101u);
  Ws listed;
  EXPECT_EQ(listed.Open(server_->http_port(), "http://viewer.example:3000"), 101u);
}

TEST_F(HttpServerTest, TokensAndRolesAsOnTheSocket) {
  const std::string tokens = dir_.path() + "/tokens";
  std::ofstream(tokens) << "readonly-token-0123456789 ro\n";
  Start({"--token-file", tokens});
  Ws anon;
  ASSERT_EQ(anon.Open(server_->http_port()), 101u);
  EXPECT_EQ(anon.Hello()["error"]["code"], "PERMISSION_DENIED");
  Ws ro;
  ASSERT_EQ(ro.Open(server_->http_port()), 101u);
  EXPECT_EQ(ro.Hello("readonly-token-0123456789")["role"], "ROLE_READ_ONLY");
  ro.Text(R"({"id": 1, "create": {"name": "x", "fps": 10}})");
  EXPECT_EQ(ro.ReadJson()["error"]["code"], "PERMISSION_DENIED");
  ro.Text(R"({"id": 2, "list": {}})");
  EXPECT_EQ(ro.ReadJson()["id"], "2");
}

TEST_F(HttpServerTest, StopsPromptlyWithAPeerThatStoppedReading) {
  Start();
  auto c = Client();
  DatasetInfo info;
  info.name = "big";
  info.fps = kFps;
  ASSERT_TRUE(c->CreateDataset(info).ok());
  std::mt19937_64 rng(3);
  ASSERT_TRUE(c->Ingest("big", 0, RandomPoints(rng, 300000, 0)).ok());
  c.reset();
  // 300 000 points as columns (~19 MB): more than the sockets buffer, so the server's writes
  // block on a client that does not read, and its close frame queues behind them.
  Ws stalled;
  ASSERT_EQ(stalled.Open(server_->http_port()), 101u);
  stalled.Hello();
  stalled.Text(R"({"id": 1, "query": {"dataset": "big", "region": {"window": {"lo": [-1e30, -1e30, -1e30, -1e30], "hi": [1e30, 1e30, 1e30, 1e30]}}}})");
  std::this_thread::sleep_for(std::chrono::milliseconds(500));
  auto start = std::chrono::steady_clock::now();
  int status = server_->Stop(SIGTERM);
  double s = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  EXPECT_TRUE(WIFEXITED(status) && WEXITSTATUS(status) == 0) << status;
  EXPECT_LT(s, 10.0) << "a WebSocket peer that does not read held up the shutdown";
}

TEST(HttpServerStart, NonLoopbackNeedsTokensAndAWebRoot) {
  TempDir dir;
  ServerProcess open_to_all(dir.path() + "/a", {"--http", "0.0.0.0:0"});
  EXPECT_FALSE(open_to_all.running());
  ServerProcess no_root(dir.path() + "/b", {"--http", "127.0.0.1:0", "--web-root",
                                            dir.path() + "/nothing"});
  EXPECT_FALSE(no_root.running());
  // Malformed options are refused at start, not taken for something else.
  ServerProcess bad_origin(dir.path() + "/c", {"--http", "127.0.0.1:0", "--http-origin", "ftp://x"});
  EXPECT_FALSE(bad_origin.running());
  ServerProcess bad_address(dir.path() + "/d", {"--http", "localhost-8080"});
  EXPECT_FALSE(bad_address.running());
}

}  // namespace
}  // namespace hvdb
