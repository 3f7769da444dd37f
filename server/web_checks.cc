#include "server/web_checks.h"

#include <algorithm>
#include <cctype>

#include <utility>  // before Asio: Boost 1.74's awaitable.hpp needs std::exchange

#include <boost/asio/ip/address.hpp>
#include <boost/beast/websocket/rfc6455.hpp>

namespace hvdb::server {

namespace asio = boost::asio;

namespace {

int HexValue(char c) {
  if (c >= '0' && c <= '9') return c - '0';
  if (c >= 'a' && c <= 'f') return c - 'a' + 10;
  if (c >= 'A' && c <= 'F') return c - 'A' + 10;
  return -1;
}

std::string Lower(std::string_view s) {
  std::string out(s);
  for (char& c : out) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  return out;
}

}  // namespace

std::string OriginHostPort(std::string_view origin) {
  std::string o = Lower(origin);
  std::string port;
  if (o.rfind("http://", 0) == 0) {
    o = o.substr(7);
    port = "80";
  } else if (o.rfind("https://", 0) == 0) {
    o = o.substr(8);
    port = "443";
  } else {
    return "";
  }
  if (o.empty() || o.find('/') != std::string::npos) return "";
  // A port after the last colon that is not inside an IPv6 literal's brackets.
  auto colon = o.rfind(':');
  if (colon != std::string::npos && o.find(']', colon) == std::string::npos) return o;
  return o + ":" + port;
}

std::string WebPath(std::string_view target) {
  target = target.substr(0, target.find_first_of("?#"));
  if (target.empty() || target[0] != '/') return "";
  std::string decoded;
  for (size_t i = 0; i < target.size(); ++i) {
    if (target[i] != '%') {
      decoded.push_back(target[i]);
      continue;
    }
    if (i + 2 >= target.size()) return "";
    int hi = HexValue(target[i + 1]), lo = HexValue(target[i + 2]);
    if (hi < 0 || lo < 0) return "";
    decoded.push_back(static_cast<char>(hi * 16 + lo));
    i += 2;
  }
  std::string out;
  size_t at = 0;
  while (at < decoded.size()) {
    size_t end = decoded.find('/', at);
    if (end == std::string::npos) end = decoded.size();
    std::string_view part(decoded.data() + at, end - at);
    at = end + 1;
    if (part.empty()) continue;
    if (part[0] == '.' || part.find('\\') != std::string_view::npos ||
        part.find('\0') != std::string_view::npos) {
      return "";
    }
    if (!out.empty()) out += '/';
    out += part;
  }
  if (out.empty() || decoded.back() == '/') out += out.empty() ? "index.html" : "/index.html";
  return out;
}

bool OriginAllowed(std::string_view origin, std::string_view host,
                   const std::vector<std::string>& allowed) {
  if (origin.empty()) return true;  // not a browser: tokens protect the data
  std::string o = OriginHostPort(origin);
  if (o.empty()) return false;  // "null" (a file:// page, a sandbox) and other schemes
  std::string h = Lower(host);
  if (!h.empty() && (h == o || h + ":80" == o)) return true;
  for (const std::string& a : allowed) {
    if (OriginHostPort(a) == o) return true;
  }
  return false;
}

bool HostAllowed(std::string_view host, const std::vector<std::string>& allowed) {
  std::string h = Lower(host);
  // Without the port: "[v6]:port", "v4:port", "name:port".
  std::string name = h;
  if (!h.empty() && h[0] == '[') {
    auto end = h.find(']');
    if (end == std::string::npos) return false;
    name = h.substr(1, end - 1);
  } else if (auto colon = h.rfind(':'); colon != std::string::npos) {
    name = h.substr(0, colon);
  }
  if (name.empty()) return false;
  if (name == "localhost") return true;
  boost::system::error_code ec;
  asio::ip::make_address(name, ec);
  if (!ec) return true;
  for (const std::string& a : allowed) {
    std::string o = OriginHostPort(a);
    std::string oname = o.substr(0, o.rfind(':'));
    if (!oname.empty() && oname == name) return true;
  }
  return false;
}

const char* ContentType(std::string_view path) {
  auto dot = path.rfind('.');
  std::string ext = dot == std::string_view::npos ? "" : Lower(path.substr(dot + 1));
  if (ext == "html") return "text/html; charset=utf-8";
  if (ext == "js" || ext == "mjs") return "text/javascript; charset=utf-8";
  if (ext == "css") return "text/css; charset=utf-8";
  if (ext == "json" || ext == "map") return "application/json";
  if (ext == "wasm") return "application/wasm";  // the page's hvdb7 decoder (web/wasm/)
  if (ext == "png") return "image/png";
  if (ext == "svg") return "image/svg+xml";
  if (ext == "ico") return "image/x-icon";
  if (ext == "md" || ext == "txt") return "text/plain; charset=utf-8";
  return "application/octet-stream";
}

std::string Printable(std::string_view value, size_t max) {
  static const char* kHex = "0123456789abcdef";
  std::string out;
  size_t i = 0;
  for (; i < value.size() && out.size() < max; ++i) {
    const unsigned char c = static_cast<unsigned char>(value[i]);
    if (c >= 0x20 && c < 0x7f && c != '\\') {
      out += static_cast<char>(c);
    } else {
      out += "\\x";
      out += kHex[c >> 4];
      out += kHex[c & 15];
    }
  }
  if (i < value.size()) out += "... (" + std::to_string(value.size()) + " bytes)";
  return out;
}

HttpVerdict CheckRequestHead(const boost::beast::http::request<boost::beast::http::string_body>& req,
                             const std::vector<std::string>& origins) {
  namespace http = boost::beast::http;
  HttpVerdict v;
  auto refuse = [&](int status, std::string reply, std::string log = {}) {
    v.kind = HttpVerdict::kRefuse;
    v.status = status;
    v.reply = std::move(reply);
    v.log = std::move(log);
    return v;
  };
  if (req.count(http::field::transfer_encoding) != 0) {
    const auto te = req[http::field::transfer_encoding];
    return refuse(400, "requests may not have a body, so no Transfer-Encoding is accepted",
                  "refused a request with Transfer-Encoding: " +
                      Printable(std::string_view(te.data(), te.size())));
  }
  if (req.count(http::field::host) != 1) {
    return refuse(400, "a request has exactly one Host header");
  }
  if (req.count(http::field::origin) > 1) {
    return refuse(400, "a request has at most one Origin header");
  }
  const auto host_field = req[http::field::host];
  const std::string_view host(host_field.data(), host_field.size());
  if (!HostAllowed(host, origins)) {
    return refuse(403,
                  "this server does not answer to the host name '" + Printable(host) +
                      "': use its IP address or localhost, or allow the name with hvdb-server "
                      "--http-origin http://NAME:PORT",
                  "refused a request for host " + Printable(host));
  }
  const std::string_view target(req.target().data(), req.target().size());
  const std::string_view path = target.substr(0, target.find_first_of("?#"));
  const bool keep = req.keep_alive();
  if (path == "/ws") {
    if (!boost::beast::websocket::is_upgrade(req)) {
      v = refuse(426, "/ws is the WebSocket endpoint: connect with a WebSocket");
      v.close = !keep;
      return v;
    }
    const auto origin_field = req[http::field::origin];
    const std::string_view origin(origin_field.data(), origin_field.size());
    if (!OriginAllowed(origin, host, origins)) {
      return refuse(403,
                    "origin " + Printable(origin) +
                        " may not connect (allow it with hvdb-server --http-origin)",
                    "refused a WebSocket from origin " + Printable(origin));
    }
    v.kind = HttpVerdict::kUpgrade;
    return v;
  }
  if (req.method() != http::verb::get && req.method() != http::verb::head) {
    v = refuse(405, "only GET and HEAD");
    v.close = !keep;
    return v;
  }
  v.file = WebPath(target);
  if (v.file.empty()) {
    v = refuse(400, "bad path");
    v.close = !keep;
    return v;
  }
  v.kind = HttpVerdict::kServeFile;
  return v;
}

}  // namespace hvdb::server
