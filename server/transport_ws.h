// The WebSocket transport: a browser's messages (docs/PROTOCOL.md, "HTTP and WebSocket"),
// decoded by protocol/ws_codec.h into the same requests the stream transport yields.
#ifndef HVDB_SERVER_TRANSPORT_WS_H_
#define HVDB_SERVER_TRANSPORT_WS_H_

#include <memory>

#include "server/transport.h"

#include <boost/beast/core/tcp_stream.hpp>
#include <boost/beast/websocket/stream.hpp>

namespace hvdb::server {

using WebSocket = boost::beast::websocket::stream<boost::beast::tcp_stream>;

// `ws` has completed its handshake; its executor is `strand`.
std::shared_ptr<Transport> MakeWebSocketTransport(std::unique_ptr<WebSocket> ws, Strand strand);

}  // namespace hvdb::server

#endif  // HVDB_SERVER_TRANSPORT_WS_H_
