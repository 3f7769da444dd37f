// A synchronous WebSocket client of hvdb-server's browser transport, for tests.
#ifndef HVDB_TESTS_SERVER_WS_CLIENT_H_
#define HVDB_TESTS_SERVER_WS_CLIENT_H_

#include <gtest/gtest.h>

#include <string>
#include <utility>  // before Asio: Boost 1.74's awaitable.hpp needs std::exchange

#include <boost/asio.hpp>
#include <boost/beast/core.hpp>
#include <boost/beast/http.hpp>
#include <boost/beast/websocket.hpp>
#include <nlohmann/json.hpp>

namespace hvdb::testing {

namespace ws_detail {
namespace asio = boost::asio;
namespace beast = boost::beast;
namespace http = beast::http;
namespace websocket = beast::websocket;
using asio::ip::tcp;
using nlohmann::json;

class Ws {
 public:
  // Connects and upgrades; the handshake's HTTP status (101 when it worked).
  unsigned Open(uint16_t port, const std::string& origin = "") {
    ws_.next_layer().connect({asio::ip::address_v4::loopback(), port});
    if (!origin.empty()) {
      ws_.set_option(websocket::stream_base::decorator(
          [origin](websocket::request_type& r) { r.set(http::field::origin, origin); }));
    }
    websocket::response_type res;
    beast::error_code ec;
    ws_.handshake(res, "127.0.0.1:" + std::to_string(port), "/ws", ec);
    return res.result_int();
  }
  void Text(const std::string& s) {
    ws_.text(true);
    ws_.write(asio::buffer(s));
  }
  void Binary(const std::string& s) {
    ws_.binary(true);
    ws_.write(asio::buffer(s));
  }
  // The next message; false when the connection closed (close_code() says how).
  bool Read(std::string* out, bool* text) {
    beast::flat_buffer b;
    beast::error_code ec;
    ws_.read(b, ec);
    if (ec) return false;
    *out = beast::buffers_to_string(b.data());
    *text = ws_.got_text();
    return true;
  }
  json ReadJson() {
    std::string s;
    bool text = false;
    EXPECT_TRUE(Read(&s, &text));
    EXPECT_TRUE(text) << "expected a text message";
    return text ? json::parse(s) : json();
  }
  int close_code() const { return ws_.reason().code; }
  json Hello(const std::string& token = "") {
    Text(json{{"protocol_version", 2}, {"client_name", "test"}, {"token", token}}.dump());
    return ReadJson();
  }

 private:
  asio::io_context io_;
  websocket::stream<tcp::socket> ws_{io_};
};

}  // namespace ws_detail

using ws_detail::Ws;

}  // namespace hvdb::testing

#endif  // HVDB_TESTS_SERVER_WS_CLIENT_H_
