// libFuzzer target for the browser's input path (docs/PROTOCOL.md, "HTTP and WebSocket"): a
// WebSocket message decoded as a Hello or a Request (JSON text or protobuf binary), the
// conversions that validate a decoded request, the server's re-encoding, and the HTTP front
// end's path and origin checks. The first byte picks text or binary. scripts/test.sh runs it.
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <string>
#include <string_view>

#include "protocol/wire.h"
#include "protocol/ws_codec.h"
#include "server/web_checks.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  using namespace hvdb;
  if (size == 0) return 0;
  const bool text = (data[0] & 1) != 0;
  std::string_view msg(reinterpret_cast<const char*>(data + 1), size - 1);
  wire::Hello hello;
  (void)wire::DecodeWsMessage(text, msg, &hello);
  wire::Request req;
  if (wire::DecodeWsMessage(text, msg, &req).ok()) {
    // What decodes re-encodes, its JSON form decodes, and from then on the form is stable
    // (the first round may normalise, e.g. -0 to 0).
    std::string json = wire::ToJson(req);
    wire::Request again, third;
    if (!wire::DecodeWsMessage(true, json, &again).ok()) std::abort();
    const std::string json2 = wire::ToJson(again);
    if (!wire::DecodeWsMessage(true, json2, &third).ok()) std::abort();
    if (wire::ToJson(third) != json2) std::abort();
    if (req.has_query()) (void)wire::FromWire(req.query().region());
    if (req.has_edit()) (void)wire::FromWire(req.edit());
    if (req.has_ingest()) {
      std::vector<Point> pts;
      (void)wire::DecodeColumns(req.ingest().points(), &pts);
    }
  }
  // The HTTP front end's checks never let a path out of the web root.
  std::string path = server::WebPath(msg);
  if (!path.empty() && (path[0] == '/' || path.find("..") == 0 || path.find("/..") != std::string::npos)) {
    std::abort();
  }
  (void)server::OriginAllowed(msg, "127.0.0.1:8080", {"http://viewer.example:3000"});
  (void)server::HostAllowed(msg, {"http://viewer.example:3000"});
  return 0;
}
