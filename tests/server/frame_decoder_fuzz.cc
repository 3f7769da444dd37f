// libFuzzer target for the server's input path: frame splitting, message decoding and the
// conversions that validate requests (docs/PROTOCOL.md). Built with clang when HVDB_FUZZ=ON;
// scripts/test.sh runs it for a short while on tests/server/fuzz_corpus/.
#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

#include "protocol/wire.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  using namespace hvdb;
  wire::FrameReader reader(1u << 20);
  reader.Feed(data, size);
  std::string payload, error;
  bool first = true;
  while (reader.Next(&payload, &error) == wire::FrameReader::Result::kFrame) {
    if (first) {
      wire::Hello hello;
      (void)hello.ParseFromString(payload);
      first = false;
      continue;
    }
    wire::Request req;
    if (!req.ParseFromString(payload)) continue;
    switch (req.body_case()) {
      case wire::Request::kQuery: {
        auto region = wire::FromWire(req.query().region());
        if (region.ok()) {
          wire::Region back;
          wire::ToWire(*region, &back);
        }
        break;
      }
      case wire::Request::kEdit: {
        auto txn = wire::FromWire(req.edit());
        if (txn.ok()) {
          wire::Edit back;
          wire::ToWire(*txn, &back);
        }
        break;
      }
      case wire::Request::kIngest: {
        std::vector<Point> pts;
        if (wire::DecodeColumns(req.ingest().points(), &pts).ok()) {
          wire::PointColumns back;
          wire::EncodeColumns(pts, &back);
        }
        break;
      }
      case wire::Request::kCreate:
        for (const auto& c : req.create().cameras()) (void)wire::FromWire(c);
        break;
      default:
        break;
    }
  }
  return 0;
}
