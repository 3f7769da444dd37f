// libFuzzer target for both input paths: the server's (frame splitting, message decoding and the
// conversions that validate requests) and the client's (frames with attachments, responses and
// their point batches). docs/PROTOCOL.md. Built with clang when HVDB_FUZZ=ON;
// scripts/test.sh runs it for a short while on tests/server/fuzz_corpus/.
#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

#include "protocol/wire.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  using namespace hvdb;
  // The client's side: frames that may carry attachments, decoded as responses.
  {
    wire::FrameReader reader(1u << 20);
    reader.Feed(data, size);
    std::string payload, error, attachment;
    while (reader.Next(&payload, &error, &attachment) == wire::FrameReader::Result::kFrame) {
      wire::Response r;
      if (!r.ParseFromString(payload) || !r.has_batch()) continue;
      std::vector<Point> pts;
      const wire::PointBatch& b = r.batch();
      if (b.encoding() == wire::RECORDS) {
        if (attachment.size() == static_cast<size_t>(b.record_count()) * kPointRecordSize) {
          pts.resize(b.record_count());
          DecodePoints(reinterpret_cast<const uint8_t*>(attachment.data()), pts.size(), pts.data());
        }
      } else if (b.encoding() == wire::DRACO) {
        (void)wire::DecodeDraco(b.draco(), &pts);
      } else if (b.encoding() == wire::HVDB7) {
        (void)wire::DecodeHvdb7(b.hvdb7(), &pts);
      } else {
        (void)wire::DecodeColumns(b.columns(), &pts);
      }
    }
  }
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
