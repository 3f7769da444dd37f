#include "server/http.h"

#include <chrono>
#include <filesystem>
#include <optional>

#include <boost/beast/core.hpp>
#include <boost/beast/http.hpp>
#include <boost/beast/websocket.hpp>

#include "server/server.h"
#include "server/session.h"
#include "server/transport_ws.h"

namespace hvdb::server {

namespace asio = boost::asio;
namespace beast = boost::beast;
namespace http = beast::http;
namespace websocket = beast::websocket;
using tcp = asio::ip::tcp;

namespace {

constexpr auto kHttpIdle = std::chrono::seconds(30);
constexpr uint32_t kMaxHeaderBytes = 8 * 1024;
// What the page may load and talk to: only this server (no CDN, no third-party script).
// 'wasm-unsafe-eval' lets the page compile WebAssembly (its hvdb7 decoder, web/wasm/) and
// nothing else: eval() and inline scripts stay refused.
constexpr const char* kContentSecurityPolicy =
    "default-src 'self'; script-src 'self' 'wasm-unsafe-eval'; worker-src 'self'; "
    "connect-src 'self'; img-src 'self' data: blob:; style-src 'self'; "
    "object-src 'none'; base-uri 'none'; frame-ancestors 'none'";

}  // namespace

// One HTTP connection: requests in turn (keep-alive), until it closes, times out or becomes a
// WebSocket.
class HttpConnection : public std::enable_shared_from_this<HttpConnection> {
 public:
  HttpConnection(HttpFrontend* front, tcp::socket socket, Strand strand)
      : front_(front), stream_(std::move(socket)), strand_(std::move(strand)) {}

  void Run(bool refuse) {
    auto self = shared_from_this();
    asio::dispatch(strand_, [self, refuse] {
      if (refuse) {
        return self->Reply(http::status::service_unavailable,
                           "the server is at its connection limit; retry later", 11, false);
      }
      self->ReadRequest();
    });
  }

  void Close() {
    auto self = shared_from_this();
    asio::post(strand_, [self] { self->Shutdown(); });
  }

  // Waiting for a request (not serving one, not a WebSocket's handshake): such a connection
  // may be closed to make room for a new one when the front end is full.
  bool idle() const { return idle_; }
  // When it began to wait (a counter of the front end's): the longest waiting goes first.
  uint64_t waiting_since() const { return waiting_since_; }
  // Closes it if it is still waiting for a request once on its strand (it may have got one).
  void Evict() {
    auto self = shared_from_this();
    asio::post(strand_, [self] {
      if (self->idle_) self->Shutdown();
    });
  }

 private:
  void ReadRequest() {
    waiting_since_ = front_->NextSeq();
    idle_ = true;
    parser_.emplace();
    parser_->header_limit(kMaxHeaderBytes);
    parser_->body_limit(0);
    stream_.expires_after(kHttpIdle);
    auto self = shared_from_this();
    http::async_read(stream_, buffer_, *parser_,
                     asio::bind_executor(strand_, [self](beast::error_code ec, size_t) {
                       self->OnRequest(ec);
                     }));
  }

  void OnRequest(beast::error_code ec) {
    idle_ = false;
    if (ec == http::error::end_of_stream || ec == beast::error::timeout ||
        ec == asio::error::operation_aborted || ec == asio::error::connection_reset ||
        ec == asio::error::eof) {
      return Shutdown();
    }
    if (ec == http::error::body_limit) {
      return Reply(http::status::payload_too_large, "requests may not have a body", 11, false);
    }
    if (ec == http::error::header_limit) {
      return Reply(http::status::request_header_fields_too_large,
                   "request headers are limited to 8 KiB", 11, false);
    }
    if (ec) return Reply(http::status::bad_request, "malformed HTTP request: " + ec.message(), 11, false);
    req_ = parser_->release();
    const unsigned version = req_.version();
    const bool keep = req_.keep_alive();
    HttpVerdict v = CheckRequestHead(req_, front_->origins());
    switch (v.kind) {
      case HttpVerdict::kUpgrade:
        return Upgrade();
      case HttpVerdict::kServeFile:
        return ServeFile(v.file, version, keep);
      case HttpVerdict::kRefuse:
        if (!v.log.empty()) Log(LogLevel::kWarn, v.log);
        return Reply(static_cast<http::status>(v.status), v.reply, version, keep && !v.close);
    }
  }

  void ServeFile(const std::string& rel, unsigned version, bool keep) {
    namespace fs = std::filesystem;
    std::error_code fec;
    fs::path full = fs::weakly_canonical(fs::path(front_->web_root()) / rel, fec);
    const std::string root = front_->web_root();
    // Symbolic links may not lead out of the web root.
    if (fec || full.string().rfind(root + "/", 0) != 0 || !fs::is_regular_file(full, fec)) {
      return Reply(http::status::not_found, "not found: " + rel, version, keep);
    }
    http::file_body::value_type body;
    beast::error_code ec;
    body.open(full.c_str(), beast::file_mode::scan, ec);
    if (ec) return Reply(http::status::not_found, "cannot read " + rel, version, keep);
    const uint64_t size = body.size();
    if (req_.method() == http::verb::head) {
      auto res = std::make_shared<http::response<http::empty_body>>(http::status::ok, version);
      Headers(*res, ContentType(rel), keep);
      res->content_length(size);
      return Write(res);
    }
    auto res = std::make_shared<http::response<http::file_body>>(
        std::piecewise_construct, std::make_tuple(std::move(body)),
        std::make_tuple(http::status::ok, version));
    Headers(*res, ContentType(rel), keep);
    res->content_length(size);
    Write(res);
  }

  template <typename Response>
  void Headers(Response& res, const char* type, bool keep) {
    res.set(http::field::server, "hvdb-server");
    res.set(http::field::content_type, type);
    res.set(http::field::cache_control, "no-cache");
    res.set("X-Content-Type-Options", "nosniff");
    res.set("Content-Security-Policy", kContentSecurityPolicy);
    res.keep_alive(keep);
  }

  void Reply(http::status status, const std::string& text, unsigned version, bool keep) {
    auto res = std::make_shared<http::response<http::string_body>>(status, version);
    Headers(*res, "text/plain; charset=utf-8", keep);
    res->body() = text + "\n";
    res->prepare_payload();
    Write(res);
  }

  template <typename Response>
  void Write(std::shared_ptr<Response> res) {
    auto self = shared_from_this();
    http::async_write(stream_, *res,
                      asio::bind_executor(strand_, [self, res](beast::error_code ec, size_t) {
                        if (ec || !res->keep_alive()) return self->Shutdown();
                        self->ReadRequest();
                      }));
  }

  void Upgrade() {
    stream_.expires_never();  // the session's own timers take over
    auto ws = std::make_unique<WebSocket>(std::move(stream_));
    ws->set_option(websocket::stream_base::timeout::suggested(beast::role_type::server));
    ws->set_option(websocket::stream_base::decorator([](websocket::response_type& r) {
      r.set(http::field::server, "hvdb-server");
    }));
    ws->read_message_max(front_->server()->config().max_frame_bytes);
    // Whole messages as single frames: Beast's default splits writes into 4 KiB frames, 256
    // frames (and completions) for one 1 MiB batch.
    ws->auto_fragment(false);
    WebSocket* raw = ws.get();
    auto self = shared_from_this();
    auto owned = std::make_shared<std::unique_ptr<WebSocket>>(std::move(ws));
    raw->async_accept(req_, asio::bind_executor(strand_, [self, owned](beast::error_code ec) {
      self->front_->Unregister(self.get());
      if (ec) {
        Log(LogLevel::kInfo, "WebSocket handshake failed: " + ec.message());
        return;
      }
      Server* server = self->front_->server();
      auto transport = MakeWebSocketTransport(std::move(*owned), self->strand_);
      server->Admit(std::make_shared<Session>(server, self->strand_, std::move(transport),
                                              /*unix_socket=*/false, /*loopback=*/false));
    }));
  }

  void Shutdown() {
    if (done_) return;
    done_ = true;
    Log(LogLevel::kDebug, "HTTP connection closed");
    beast::error_code ignored;
    stream_.socket().shutdown(tcp::socket::shutdown_both, ignored);
    stream_.close();
    front_->Unregister(this);
  }

  HttpFrontend* front_;
  beast::tcp_stream stream_;
  Strand strand_;
  beast::flat_buffer buffer_;
  std::optional<http::request_parser<http::string_body>> parser_;
  http::request<http::string_body> req_;
  bool done_ = false;
  std::atomic<bool> idle_{false};
  std::atomic<uint64_t> waiting_since_{0};
};

HttpFrontend::HttpFrontend(Server* server, std::string web_root, std::vector<std::string> origins)
    : server_(server),
      web_root_(std::move(web_root)),
      origins_(std::move(origins)),
      accept_strand_(asio::make_strand(server->io())),
      acceptor_(accept_strand_),
      retry_(accept_strand_) {}

HttpFrontend::~HttpFrontend() = default;

Result<std::unique_ptr<HttpFrontend>> HttpFrontend::Create(Server* server, const std::string& host,
                                                           uint16_t port, std::string web_root,
                                                           std::vector<std::string> origins) {
  namespace fs = std::filesystem;
  std::error_code fec;
  fs::path root = fs::canonical(web_root, fec);
  if (fec || !fs::is_regular_file(root / "index.html")) {
    return Status::InvalidArgument("--web-root " + web_root + ": no index.html there (give "
                                   "the web/ folder of the source or of the installed package)");
  }
  if (!fs::is_directory(root / "node_modules" / "gl-matrix")) {
    Log(LogLevel::kWarn, "--web-root " + root.string() + " has no node_modules/gl-matrix: the "
                         "page will not load until `npm ci --prefix " + root.string() + "` ran");
  }
  for (const std::string& o : origins) {
    if (OriginHostPort(o).empty()) {
      return Status::InvalidArgument("--http-origin '" + o + "': expected http(s)://HOST[:PORT]");
    }
  }
  std::unique_ptr<HttpFrontend> f(new HttpFrontend(server, root.string(), std::move(origins)));
  boost::system::error_code ec;
  auto addr = asio::ip::make_address(host, ec);
  if (ec) return Status::InvalidArgument("--http: '" + host + "' is not an IP address");
  tcp::endpoint ep(addr, port);
  f->acceptor_.open(ep.protocol(), ec);
  if (!ec) f->acceptor_.set_option(tcp::acceptor::reuse_address(true), ec);
  if (!ec) f->acceptor_.bind(ep, ec);
  if (!ec) f->acceptor_.listen(asio::socket_base::max_listen_connections, ec);
  if (ec) return Status::IOError("--http " + host + ":" + std::to_string(port) + ": " + ec.message());
  f->port_ = f->acceptor_.local_endpoint().port();
  return f;
}

void HttpFrontend::Start() {
  asio::dispatch(accept_strand_, [this] { Accept(); });
}

// On accept_strand_.
void HttpFrontend::Accept() {
  Strand strand = asio::make_strand(server_->io());
  acceptor_.async_accept(strand, [this, strand](boost::system::error_code ec, tcp::socket socket) {
    if (stopping_) return;  // the socket, if any, closes with it
    if (ec) {
      // Out of descriptors and the like: try again shortly rather than spin.
      Log(LogLevel::kWarn, "accept on --http: " + ec.message());
      retry_.expires_after(std::chrono::milliseconds(100));
      retry_.async_wait([this](boost::system::error_code wec) {
        if (!wec && !stopping_) Accept();
      });
      return;
    }
    boost::system::error_code ignored;
    socket.set_option(tcp::no_delay(true), ignored);
    auto c = std::make_shared<HttpConnection>(this, std::move(socket), strand);
    bool refuse = false;
    std::shared_ptr<HttpConnection> evicted;
    {
      std::lock_guard<std::mutex> l(mu_);
      if (connections_.size() >= server_->config().max_connections) {
        // Full: the connection that has waited longest for a request makes room (a silent
        // socket cannot keep the page from loading); refused only if all are busy.
        for (auto& [p, w] : connections_) {
          auto other = w.lock();
          if (other && other->idle() &&
              (!evicted || other->waiting_since() < evicted->waiting_since())) {
            evicted = other;
          }
        }
        refuse = !evicted;
      }
    }
    if (evicted) evicted->Evict();
    if (Register(c)) c->Run(refuse);
    Accept();
  });
}

bool HttpFrontend::Register(const std::shared_ptr<HttpConnection>& c) {
  std::lock_guard<std::mutex> l(mu_);
  if (stopping_) return false;  // Stop has taken its list: this one would linger
  connections_[c.get()] = c;
  return true;
}

void HttpFrontend::Unregister(HttpConnection* c) {
  std::lock_guard<std::mutex> l(mu_);
  connections_.erase(c);
}

void HttpFrontend::Stop() {
  {
    std::lock_guard<std::mutex> l(mu_);
    if (stopping_.exchange(true)) return;
  }
  asio::dispatch(accept_strand_, [this] {
    boost::system::error_code ignored;
    acceptor_.close(ignored);
    retry_.cancel();
  });
  std::vector<std::shared_ptr<HttpConnection>> all;
  {
    std::lock_guard<std::mutex> l(mu_);
    for (auto& [p, w] : connections_) {
      if (auto c = w.lock()) all.push_back(c);
    }
  }
  for (auto& c : all) c->Close();
}

}  // namespace hvdb::server
