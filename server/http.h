// HTTP/1.1 on `hvdb-server --http HOST:PORT` (docs/PROTOCOL.md, "HTTP and WebSocket"): the web
// viewer's static files from the web root, and `/ws`, upgraded to a WebSocket whose messages a
// Session serves like any other connection. Same event loop, limits and tokens as the binary
// protocol.
#ifndef HVDB_SERVER_HTTP_H_
#define HVDB_SERVER_HTTP_H_

#include <atomic>
#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <string_view>
#include <vector>

#include <utility>  // before Asio: Boost 1.74's awaitable.hpp needs std::exchange

#include <boost/asio.hpp>

#include "server/web_checks.h"
#include "storage/status.h"

namespace hvdb::server {

class Server;
class HttpConnection;

class HttpFrontend {
 public:
  // `listen`: HOST:PORT (port 0: any free port). `web_root`: a folder with index.html.
  static Result<std::unique_ptr<HttpFrontend>> Create(Server* server, const std::string& host,
                                                      uint16_t port, std::string web_root,
                                                      std::vector<std::string> origins);
  ~HttpFrontend();
  void Start();
  // Stops accepting and closes the plain HTTP connections (on the io thread; WebSockets are
  // sessions, which the server closes).
  void Stop();
  uint16_t port() const { return port_; }
  const std::string& web_root() const { return web_root_; }

  // For connections.
  Server* server() { return server_; }
  const std::vector<std::string>& origins() const { return origins_; }
  // False once stopping: the caller drops the connection.
  bool Register(const std::shared_ptr<HttpConnection>& c);
  uint64_t NextSeq() { return ++seq_; }
  void Unregister(HttpConnection* c);

 private:
  HttpFrontend(Server* server, std::string web_root, std::vector<std::string> origins);
  void Accept();

  Server* server_;
  std::string web_root_;
  std::vector<std::string> origins_;
  // The acceptor is only touched on this strand (accepts, and Stop from another thread).
  boost::asio::strand<boost::asio::io_context::executor_type> accept_strand_;
  boost::asio::ip::tcp::acceptor acceptor_;
  boost::asio::steady_timer retry_;  // after a failed accept (e.g. out of descriptors)
  uint16_t port_ = 0;
  std::atomic<bool> stopping_{false};
  std::mutex mu_;
  std::map<HttpConnection*, std::weak_ptr<HttpConnection>> connections_;
  std::atomic<uint64_t> seq_{0};
};

}  // namespace hvdb::server

#endif  // HVDB_SERVER_HTTP_H_
