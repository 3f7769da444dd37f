// What a connection's bytes become. A transport turns its bytes into one Hello and then
// Request messages, and Response messages into its bytes; the Session (server/session.h) serves
// the requests the same way whatever carried them (decode at the edge). Two transports: framed
// protobuf over a TCP or Unix stream socket (docs/PROTOCOL.md, "Framing") and WebSocket messages
// from a browser (docs/PROTOCOL.md, "HTTP and WebSocket").
#ifndef HVDB_SERVER_TRANSPORT_H_
#define HVDB_SERVER_TRANSPORT_H_

#include <deque>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include <utility>  // before Asio: Boost 1.74's awaitable.hpp needs std::exchange

#include <boost/asio.hpp>
#include <google/protobuf/message.h>

#include "protocol/wire.h"
#include "storage/point.h"
#include "storage/status.h"

namespace hvdb::server {

using Strand = boost::asio::strand<boost::asio::io_context::executor_type>;
// Either stream transport: Asio's generic stream socket holds a TCP or a Unix-domain socket.
using StreamSocket = boost::asio::generic::stream_protocol::socket;

// An outbound message as the transport sends it: `head` (a frame header and protobuf, or a
// WebSocket message), then, for a RECORDS batch, `count` point records sent from where they
// lie (scatter/gather), then bulk sections (`tail`, WebSocket only).
struct OutFrame {
  std::string head;
  std::vector<Point> records;  // a reusable buffer: the first `count` are sent
  size_t count = 0;
  std::string tail;
  bool text = false;  // a WebSocket text message
  uint64_t watch = 0;       // the watch request whose event this is (its own queue is bounded)
  size_t watch_cost = 0;    // and the event's Session::WatchCost
  size_t bytes() const { return head.size() + count * sizeof(Point) + tail.size(); }
};

class Transport {
 public:
  virtual ~Transport() = default;
  // Reads the next message into *hello (before the handshake, when hello != nullptr) or
  // *request. Calls `done` on the strand: `ec` set when the connection ended (close quietly);
  // else a failed `st` when the message could not be decoded or was too long (answer MALFORMED
  // and close); `bytes` read.
  using ReadDone = std::function<void(boost::system::error_code ec, Status st, size_t bytes)>;
  virtual void Read(wire::Hello* hello, wire::Request* request, ReadDone done) = 0;
  // One message (a Response or HelloReply) and, for a RECORDS batch, its records.
  virtual OutFrame Encode(const google::protobuf::Message& m, std::vector<Point> records,
                          size_t count) = 0;
  // Writes out[0, k) for a k >= 1 it chooses (a gather write of several frames where the
  // transport can); `done(ec, k, bytes)` on the strand.
  using WriteDone = std::function<void(boost::system::error_code ec, size_t frames, size_t bytes)>;
  virtual void Write(const std::deque<OutFrame>& out, WriteDone done) = 0;
  // Closes the connection (on the strand); pending operations complete with an error.
  virtual void Close() = 0;
  // The OS socket of a stream transport (the fast path's handshake passes the ring's
  // descriptor on it); -1 for others.
  virtual int native_handle() = 0;
};

// The largest Hello a transport reads (before the Hello nothing larger is buffered).
inline constexpr uint32_t kMaxHelloBytes = 64u << 10;

std::shared_ptr<Transport> MakeStreamTransport(StreamSocket socket, Strand strand,
                                               uint32_t max_frame_bytes);

}  // namespace hvdb::server

#endif  // HVDB_SERVER_TRANSPORT_H_
