// libFuzzer target for the HTTP front end's request parsing (docs/PROTOCOL.md, "HTTP and
// WebSocket"): bytes as a client sends them, pipelined requests included, through Beast's parser
// with the server's limits (8 KiB of headers, no body) and then the server's own rules
// (server::CheckRequestHead). What it checks beyond "no crash": a request with any
// Transfer-Encoding, or with two Host headers, is never served; a file it serves lies inside
// the web root; a refusal's log line is printable and short. scripts/test.sh runs it.
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <string>

#include <utility>  // before Asio: Boost 1.74's awaitable.hpp needs std::exchange

#include <boost/beast/http.hpp>

#include "server/web_checks.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  namespace http = boost::beast::http;
  using hvdb::server::HttpVerdict;
  const std::vector<std::string> origins = {"http://viewer.example:3000"};
  std::string_view in(reinterpret_cast<const char*>(data), size);
  // Requests one after another on one connection, as the front end reads them (keep-alive).
  for (int requests = 0; !in.empty() && requests < 16; ++requests) {
    http::request_parser<http::string_body> p;
    p.header_limit(8 * 1024);
    p.body_limit(0);
    p.eager(true);
    boost::beast::error_code ec;
    const size_t used = p.put(boost::asio::buffer(in.data(), in.size()), ec);
    if (ec == http::error::need_more && !p.is_done()) {
      // The end of the input ends the message where the protocol allows it.
      p.put_eof(ec);
    }
    if (ec || !p.is_done()) return 0;  // the front end answers 400/413/431 and closes
    auto req = p.release();
    HttpVerdict v = hvdb::server::CheckRequestHead(req, origins);
    const bool te = req.count(http::field::transfer_encoding) != 0;
    if (v.kind != HttpVerdict::kRefuse && (te || req.count(http::field::host) != 1)) std::abort();
    if (v.kind == HttpVerdict::kRefuse && te && !v.close) std::abort();
    if (v.kind == HttpVerdict::kServeFile &&
        (v.file.empty() || v.file[0] == '/' || v.file.rfind("..", 0) == 0 ||
         v.file.find("/..") != std::string::npos)) {
      std::abort();
    }
    if (v.log.size() > 600) std::abort();
    for (char c : v.log) {
      if (static_cast<unsigned char>(c) < 0x20 || static_cast<unsigned char>(c) >= 0x7f) std::abort();
    }
    if (v.kind == HttpVerdict::kRefuse && v.close) return 0;
    if (used == 0) return 0;
    in.remove_prefix(used);
  }
  return 0;
}
