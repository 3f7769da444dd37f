// The HTTP front end's checks of what a request names (server/http.h): the file under the web
// root, the page's origin, the Host header. Pure functions, in a library of their own so that
// the fuzzer and the tests link them without the server.
#ifndef HVDB_SERVER_WEB_CHECKS_H_
#define HVDB_SERVER_WEB_CHECKS_H_

#include <string>
#include <string_view>
#include <vector>

#include <boost/beast/http/message.hpp>
#include <boost/beast/http/string_body.hpp>

namespace hvdb::server {

// The file a request target names, relative to the web root ("index.html" for "/"), or "" when
// the target is not a plain path inside it: "..", a leading dot in a component (hidden files,
// "."), a backslash, a NUL or a bad percent escape. Query and fragment are ignored.
std::string WebPath(std::string_view target);
// Whether a WebSocket request from a page at `origin` may connect: no Origin (not a browser),
// the server's own `host` (the Host header), or one of `allowed` ("http://HOST:PORT").
bool OriginAllowed(std::string_view origin, std::string_view host,
                   const std::vector<std::string>& allowed);
// Whether a request's Host header names this server: an IP address, "localhost", or the host of
// one of `allowed`. Anything else is a name that may have been re-pointed at this address by
// its owner (DNS rebinding), whose pages would then pass the same-origin check.
bool HostAllowed(std::string_view host, const std::vector<std::string>& allowed);
// The Content-Type of a file by its extension.
const char* ContentType(std::string_view path);

// "http://HOST[:PORT]" -> "host:port" (default ports made explicit); "" if not such an origin.
std::string OriginHostPort(std::string_view origin);

// A header value or name as it may go into the log or a reply: bytes outside printable ASCII
// (and the backslash) as \xNN, cut once `max` characters are written, the full length noted.
std::string Printable(std::string_view value, size_t max = 200);

// What the front end does with a parsed request head (server/http.cc), decided here so that the
// fuzzer and the tests reach every rule without a socket.
struct HttpVerdict {
  enum Kind { kServeFile, kUpgrade, kRefuse } kind = kRefuse;
  std::string file;   // kServeFile: the path under the web root
  int status = 400;   // kRefuse: the HTTP status
  std::string reply;  // kRefuse: the response body
  std::string log;    // kRefuse: a warning for the log ("" for none); values made Printable
  bool close = true;  // kRefuse: close the connection after the reply
};
// The rules, in order: no Transfer-Encoding at all (requests have no body, and a coding this
// server does not parse would let the body pass for the next request: RFC 9112 6.3), one Host
// and at most one Origin, a Host that names this server, then /ws (an upgrade from an allowed
// origin) or a GET/HEAD of a file path.
HttpVerdict CheckRequestHead(const boost::beast::http::request<boost::beast::http::string_body>& req,
                             const std::vector<std::string>& origins);

}  // namespace hvdb::server

#endif  // HVDB_SERVER_WEB_CHECKS_H_
