// The WebSocket encoding of the wire protocol's messages (docs/PROTOCOL.md, "HTTP and
// WebSocket"): a client's text message is a message in the proto3 JSON mapping, a binary one its
// serialized protobuf; the server sends JSON text, or, for responses with bulk bytes (point
// batches, rendered images), a binary message of a JSON header and 8-byte aligned sections
// that a browser views in place. Pure functions: the transport, the tests and the fuzzer share
// them.
#ifndef HVDB_PROTOCOL_WS_CODEC_H_
#define HVDB_PROTOCOL_WS_CODEC_H_

#include <cstddef>
#include <string>
#include <string_view>

#include <google/protobuf/message.h>

#include "storage/status.h"

namespace hvdb::wire {

// Decodes a client message into *out (a Hello or a Request). Unknown JSON fields, JSON that is
// not such an object and binary that does not parse are InvalidArgument.
Status DecodeWsMessage(bool text, std::string_view data, google::protobuf::Message* out);

// A server message as a WebSocket message: `head` (the whole text message, or the binary
// message's length word, JSON header and padding), then `records_bytes` bytes the caller sends
// from where they lie (a RECORDS batch's records; described in the header as section
// "records"), then `tail` (the other sections, each padded to 8 bytes).
struct WsMessage {
  bool text = true;
  std::string head;
  std::string tail;
};
WsMessage EncodeWsMessage(const google::protobuf::Message& m, size_t records_bytes = 0);

// The proto3 JSON form the server sends (proto field names, defaults included, enums by name).
std::string ToJson(const google::protobuf::Message& m);

}  // namespace hvdb::wire

#endif  // HVDB_PROTOCOL_WS_CODEC_H_
