#include "server/transport_ws.h"

#include <algorithm>

#include <boost/beast/core/flat_buffer.hpp>
#include <boost/beast/websocket.hpp>

#include "protocol/ws_codec.h"
#include "server/server.h"

namespace hvdb::server {

namespace asio = boost::asio;
namespace beast = boost::beast;
namespace websocket = beast::websocket;

namespace {

class WsTransport : public Transport, public std::enable_shared_from_this<WsTransport> {
 public:
  WsTransport(std::unique_ptr<WebSocket> ws, Strand strand)
      : ws_(std::move(ws)), strand_(std::move(strand)), max_message_(ws_->read_message_max()) {}

  void Read(wire::Hello* hello, wire::Request* request, ReadDone done) override {
    // Before the Hello only a Hello's worth (as on the stream transport).
    ws_->read_message_max(hello != nullptr ? std::min<size_t>(max_message_, kMaxHelloBytes)
                                           : max_message_);
    auto self = shared_from_this();
    ws_->async_read(buf_, asio::bind_executor(strand_, [self, hello, request, done = std::move(
                                                                                 done)](
                                                           boost::system::error_code ec, size_t n) {
      // A message over --max-frame-bytes: Beast has already closed with 1009 (message too big).
      if (ec) return done(ec, Status::OK(), 0);
      auto data = self->buf_.cdata();
      std::string_view bytes(static_cast<const char*>(data.data()), data.size());
      google::protobuf::Message* target = hello != nullptr
                                              ? static_cast<google::protobuf::Message*>(hello)
                                              : request;
      Status st = wire::DecodeWsMessage(self->ws_->got_text(), bytes, target);
      if (!st.ok() && hello != nullptr) {
        st = Status::InvalidArgument("the first message must be a Hello: " + st.message());
      }
      self->buf_.consume(self->buf_.size());
      // A large message's buffer is not kept for the connection's lifetime.
      if (self->buf_.capacity() > (64u << 10)) self->buf_.shrink_to_fit();
      if (!st.ok()) self->malformed_ = true;
      done({}, st, n);
    }));
  }

  OutFrame Encode(const google::protobuf::Message& m, std::vector<Point> records,
                  size_t count) override {
    wire::WsMessage w = wire::EncodeWsMessage(m, count * sizeof(Point));
    OutFrame f;
    f.head = std::move(w.head);
    f.tail = std::move(w.tail);
    f.text = w.text;
    if (count > 0) {
      f.records = std::move(records);
      f.count = count;
    }
    return f;
  }

  void Write(const std::deque<OutFrame>& out, WriteDone done) override {
    // One message per write: a WebSocket message cannot hold several responses.
    const OutFrame& f = out.front();
    std::vector<asio::const_buffer> bufs{asio::buffer(f.head)};
    if (f.count > 0) bufs.push_back(asio::buffer(f.records.data(), f.count * sizeof(Point)));
    if (!f.tail.empty()) bufs.push_back(asio::buffer(f.tail));
    ws_->text(f.text);
    auto self = shared_from_this();
    ws_->async_write(bufs, asio::bind_executor(strand_, [self, done = std::move(done)](
                                                            boost::system::error_code ec,
                                                            size_t n) { done(ec, 1, n); }));
  }

  void Close() override {
    if (closing_) return;
    closing_ = true;
    // A close frame (1008 after a message that could not be decoded), then the socket. A peer
    // that does not answer, or does not read what was sent before (the close frame queues
    // behind a pending write), is cut off after 2 s: a stopping server waits for this.
    auto self = shared_from_this();
    close_timer_ = std::make_unique<asio::steady_timer>(strand_, std::chrono::seconds(2));
    close_timer_->async_wait([self](boost::system::error_code ec) {
      if (!ec) beast::get_lowest_layer(*self->ws_).close();
    });
    ws_->async_close(malformed_ ? websocket::close_code::policy_error : websocket::close_code::normal,
                     asio::bind_executor(strand_, [self](boost::system::error_code ec) {
                       Log(LogLevel::kDebug, "WebSocket closed" +
                                                 (ec ? " (" + ec.message() + ")" : std::string()));
                       self->close_timer_->cancel();
                       beast::get_lowest_layer(*self->ws_).close();
                     }));
  }

  int native_handle() override { return -1; }

 private:
  std::unique_ptr<WebSocket> ws_;
  Strand strand_;
  beast::flat_buffer buf_;
  const size_t max_message_;
  bool malformed_ = false;
  bool closing_ = false;
  std::unique_ptr<boost::asio::steady_timer> close_timer_;
};

}  // namespace

std::shared_ptr<Transport> MakeWebSocketTransport(std::unique_ptr<WebSocket> ws, Strand strand) {
  return std::make_shared<WsTransport>(std::move(ws), std::move(strand));
}

}  // namespace hvdb::server
